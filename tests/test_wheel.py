"""The wheel: built from this tree and installed in a fresh virtual environment, it runs a small reproduction.

The new environment gets its dependencies (JAX, MuJoCo, ...) from the running
interpreter's site-packages through a ``.pth`` file, so nothing is downloaded;
spikejax and robots come from the wheel alone. The reproduction runs from a
directory outside the source tree with ``PYTHONPATH`` unset, so the sweep files
can only come from the installed package data.
"""

import csv
import importlib.util
import json
import os
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SWEEPS = sorted(p.name for p in (ROOT / "sweeps").glob("*.toml"))
# What a build writes into its source tree, and what a build does not need.
NOT_COPIED = shutil.ignore_patterns(
    ".git", ".venv", "build", "dist", "*.egg-info", "results", "__pycache__", ".pytest_cache", ".ipynb_checkpoints"
)


def _can_build_without_isolation() -> bool:
    """Whether this environment's setuptools builds the wheel (pyproject.toml asks for >= 68; before 70.1 the
    ``wheel`` package provides ``bdist_wheel``)."""
    if importlib.util.find_spec("setuptools") is None:
        return False
    import setuptools

    version = tuple(int(part) for part in setuptools.__version__.split(".")[:2])
    return version >= (68, 0) and (version >= (70, 1) or importlib.util.find_spec("wheel") is not None)


def _run(args, **kwargs):
    done = subprocess.run([str(a) for a in args], capture_output=True, text=True, timeout=600, **kwargs)
    assert done.returncode == 0, f"{' '.join(map(str, args))}\n{done.stdout}\n{done.stderr}"
    return done


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    """The wheel, built from a copy of the source tree (the build writes build/ and *.egg-info into it)."""
    tmp = tmp_path_factory.mktemp("wheel")
    source = tmp / "source"
    shutil.copytree(ROOT, source, symlinks=True, ignore=NOT_COPIED)
    # With this environment's setuptools if it can, else in an isolated one with setuptools from the index.
    isolation = ["--no-build-isolation"] if _can_build_without_isolation() else []
    _run([sys.executable, "-m", "pip", "wheel", "--no-deps", *isolation, "--wheel-dir", tmp / "dist", source])
    (built,) = (tmp / "dist").glob("spikejax-*.whl")
    return built


def test_the_wheel_holds_the_sweep_files(wheel):
    with zipfile.ZipFile(wheel) as archive:
        names = set(archive.namelist())
        assert {f"robots/sweeps/{name}" for name in SWEEPS} <= names
        for name in SWEEPS:
            assert archive.read(f"robots/sweeps/{name}") == (ROOT / "sweeps" / name).read_bytes(), name
        points = archive.read(next(n for n in names if n.endswith(".dist-info/entry_points.txt"))).decode()
    assert "reproduce.gaits = robots.hexapod.reproduce:gaits_command" in points


def test_installed_wheel_reproduces_gaits_outside_the_source_tree(wheel, tmp_path):
    venv = tmp_path / "venv"
    _run([sys.executable, "-m", "venv", "--without-pip", venv])
    python = venv / "bin" / "python"
    # pip of this environment, run by the new interpreter: the new environment is still empty here, so
    # nothing of this one (its spikejax included) is taken for installed.
    _run([sys.executable, "-m", "pip", "--python", python, "install", "--no-deps", "--no-index", wheel])
    site = Path(_run([python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"]).stdout.strip())
    ours = dict.fromkeys([sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]])
    (site / "dependencies.pth").write_text("".join(f"{path}\n" for path in ours))

    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    work = tmp_path / "elsewhere"
    work.mkdir()
    where = _run(
        [
            python,
            "-c",
            "import importlib.metadata as m, robots, robots.common, spikejax; "
            "print(spikejax.__file__); print(robots.__file__); print(robots.common.SWEEPS); "
            "print(m.distribution('spikejax').locate_file(''))",
        ],
        cwd=work,
        env=env,
    ).stdout.split()
    for path in map(Path, where):
        assert path.resolve().is_relative_to(venv.resolve()), where
        assert not path.resolve().is_relative_to(ROOT), where

    out = work / "gaits"
    run = _run(
        [venv / "bin" / "spikejax", "reproduce", "gaits", "--out", out, "--trials", "5", "--no-progress"],
        cwd=work,
        env=env,
    )
    lines = run.stdout.splitlines()
    head = next(i for i, line in enumerate(lines) if line.split()[:4] == ["gaits", "interleaved", "blocked", "paper"])
    assert [line.split()[0] for line in lines[head + 1 : head + 4]] == ["1", "2", "3"]
    assert lines[head + 4].startswith("within a shared budget of 150 presentations: 1 gait(s)")
    with open(out / "gait_convergence.csv") as file:
        rows = list(csv.DictReader(file))
    assert [(r["n_gaits"], r["trials"]) for r in rows] == [("1", "5"), ("2", "5"), ("3", "5")]
    assert (out / "gait_convergence.png").stat().st_size > 10_000
    for name in ("gait_convergence", "gait_convergence_blocked"):
        metadata = json.loads((out / "sweeps" / name / "metadata.json").read_text())
        assert Path(metadata["sweep_file"]).is_relative_to(venv.resolve())
