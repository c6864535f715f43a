"""The sweep engine: rows against per-trial closed forms, chunking, resuming, bad files."""

from __future__ import annotations

import itertools
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from spikejax import cli
from spikejax.errors import UserError
from spikejax.sweep import load_sweep, read_results, run_sweep, trial_key

TESTS = Path(__file__).resolve().parent
VALUE_RTOL = 1e-6  # float32 arithmetic, eager against jitted and vmapped

TOY = """\
[sweep]
name = "toy"
trial = "_sweep_trials:toy_trial"
seeds = 3
base_seed = 7
chunk_size = 4

[fixed]
scale = 2.0
offset = 0.5

[grid]
a = [1.0, -2.5]
n = [1, 2, 3]
flag = [false, true]
"""
TOY_AXES = {"a": [1.0, -2.5], "n": [1, 2, 3], "flag": [False, True]}
TOY_TRIALS = 2 * 3 * 2 * 3

SLOW = """\
[sweep]
name = "slow"
trial = "_sweep_trials:slow_trial"
seeds = 10

[grid]
a = [1.0, 2.0, 3.0]
n = [1, 2]
"""
SLOW_TRIALS = 60


@pytest.fixture(autouse=True)
def _trials_importable(monkeypatch):
    monkeypatch.syspath_prepend(str(TESTS))


def _write(directory: Path, text: str, name: str = "sweep.toml") -> Path:
    path = directory / name
    path.write_text(text)
    return path


def _run(path: Path, out: Path, **overrides) -> bytes:
    run_sweep(load_sweep(path, **overrides), out, progress=False)
    return (out / "results.csv").read_bytes()


def _metadata(out: Path) -> dict:
    return json.loads((out / "metadata.json").read_text())


def _cli_env(**extra: str) -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(TESTS), env.get("PYTHONPATH", "")])
    env.update(extra)
    return env


def _cli_command(path: Path, out: Path, *flags: str) -> list[str]:
    return [sys.executable, "-m", "spikejax.cli", "sweep", str(path), "--out", str(out), *flags]


# ------------------------------------------------------------------------ results


def test_rows_equal_per_trial_closed_form(tmp_path):
    _run(_write(tmp_path, TOY), tmp_path / "out")
    table = read_results(tmp_path / "out")

    assert list(table) == ["trial", "seed", "a", "n", "flag", "value", "count", "draw", "positive"]
    assert len(table["trial"]) == TOY_TRIALS
    rows = [(point, seed) for point in itertools.product(*TOY_AXES.values()) for seed in range(3)]
    for i, ((a, n, flag), seed) in enumerate(rows):
        draw = jax.random.uniform(jax.random.fold_in(jax.random.key(7), seed))
        value = 2.0 * (-1 if flag else 1) * (a * n + 0.5) + np.sin(np.float32(draw))
        assert (table["trial"][i], table["seed"][i]) == (i, seed)
        assert (table["a"][i], table["n"][i], table["flag"][i]) == (a, n, flag)
        assert table["draw"][i] == np.float32(draw)
        np.testing.assert_allclose(table["value"][i], value, rtol=VALUE_RTOL)
        assert table["count"][i] == n * 10 + 1
        assert table["positive"][i] == (table["value"][i] > 0)
    assert table["value"].dtype == np.float32 and table["count"].dtype == np.int32
    assert table["positive"].dtype == np.bool_ and table["a"].dtype == np.float64


def test_same_seed_same_draw_at_every_grid_point(tmp_path):
    _run(_write(tmp_path, TOY), tmp_path / "out")
    table = read_results(tmp_path / "out")

    draws = table["draw"].reshape(-1, 3)
    np.testing.assert_array_equal(draws, np.broadcast_to(draws[0], draws.shape))
    assert draws[0, 1] == jax.random.uniform(trial_key(7, 1))


@pytest.mark.parametrize("chunk_size", [1, 3, 7, TOY_TRIALS, 10_000])
def test_table_does_not_depend_on_chunk_size(tmp_path, chunk_size):
    path = _write(tmp_path, TOY)
    reference = _run(path, tmp_path / "reference", chunk_size=5)

    assert _run(path, tmp_path / "out", chunk_size=chunk_size) == reference


def test_one_compilation_for_all_chunks(tmp_path):
    import _sweep_trials

    path = _write(tmp_path, TOY.replace("toy_trial", "counting_trial").replace("scale = 2.0\n", ""))
    _sweep_trials.TRACES.clear()
    _run(path, tmp_path / "out", chunk_size=5)

    # One trace to find the result columns, one to compile: none per chunk.
    assert len(_sweep_trials.TRACES) == 2


STATIC = """\
[sweep]
name = "static"
trial = "_sweep_trials:shaped_trial"
seeds = 3
chunk_size = 4

[fixed]
scale = 2.0

[grid]
a = [1.0, -2.5]
size = [1, 4]
n = [1, 2]
"""


@pytest.mark.parametrize("chunk_size", [1, 4, 100])
def test_static_grid_axis_compiles_once_per_value(tmp_path, chunk_size):
    import _sweep_trials

    _sweep_trials.TRACES.clear()
    _run(_write(tmp_path, STATIC), tmp_path / "out", chunk_size=chunk_size)
    table = read_results(tmp_path / "out")

    # One trace for the result columns, then one compilation per static value, in grid order.
    assert _sweep_trials.TRACES == [1, 1, 4]
    assert list(table)[:5] == ["trial", "seed", "a", "size", "n"]
    rows = [(point, seed) for point in itertools.product([1.0, -2.5], [1, 4], [1, 2]) for seed in range(3)]
    for i, ((a, size, n), seed) in enumerate(rows):
        draw = np.float32(jnp.mean(jax.random.uniform(trial_key(0, seed), (size,))))
        assert (table["a"][i], table["size"][i], table["n"][i], table["seed"][i]) == (a, size, n, seed)
        assert table["count"][i] == n * 10 + size
        np.testing.assert_allclose(table["draw"][i], draw, rtol=VALUE_RTOL)
        np.testing.assert_allclose(table["value"][i], 2.0 * a * n + np.sin(draw), rtol=VALUE_RTOL)


def test_keys_are_not_reused(tmp_path):
    with jax.debug_key_reuse(True):
        _run(_write(tmp_path, TOY), tmp_path / "out")


def test_dict_results_keep_the_trials_order(tmp_path):
    path = _write(tmp_path, TOY.replace("toy_trial", "dict_trial").replace("scale = 2.0\n", ""))
    run_sweep(load_sweep(path), tmp_path / "out", progress=False)

    assert list(read_results(tmp_path / "out"))[-2:] == ["zeta", "alpha"]


def test_seeds_override(tmp_path):
    _run(_write(tmp_path, TOY), tmp_path / "out", seeds=2)
    table = read_results(tmp_path / "out")

    assert len(table["trial"]) == 2 * 3 * 2 * 2
    np.testing.assert_array_equal(table["seed"], np.tile([0, 1], 12))


def test_nan_results_are_reported_with_their_trials(tmp_path, capsys):
    path = _write(tmp_path, TOY.replace("toy_trial", "nan_trial").replace("scale = 2.0\n", ""))

    assert cli.main(["sweep", str(path), "--out", str(tmp_path / "out"), "--no-progress"]) == 0

    table = read_results(tmp_path / "out")
    nan_trials = np.flatnonzero(np.isnan(table["value"])).tolist()
    assert nan_trials == list(range(18, 36))
    err = capsys.readouterr().err
    assert "NaN" in err and "18, 19, 20" in err
    assert _metadata(tmp_path / "out")["nan_trials"] == nan_trials


def test_metadata_records_the_sweep_and_the_environment(tmp_path):
    path = _write(tmp_path, TOY)
    _run(path, tmp_path / "out")

    metadata = _metadata(tmp_path / "out")
    assert metadata["sweep_text"] == TOY
    assert metadata["sweep"]["grid"]["n"] == [1, 2, 3]
    assert metadata["total_trials"] == metadata["done_trials"] == TOY_TRIALS
    assert metadata["started"] and metadata["finished"]
    assert set(metadata["versions"]) >= {"spikejax", "jax", "jaxlib", "numpy"}
    assert metadata["devices"] and "git_commit" in metadata
    assert metadata["fingerprint"] == load_sweep(path).fingerprint


# ----------------------------------------------------------------------- resuming


def test_resume_after_sigkill_gives_the_uninterrupted_table(tmp_path):
    path = _write(tmp_path, SLOW)
    out = tmp_path / "out"
    command = _cli_command(path, out, "--chunk-size", "2")
    killed = subprocess.Popen(
        command, cwd=tmp_path, env=_cli_env(SWEEP_TEST_SLEEP="0.03", CI="true"), stderr=subprocess.DEVNULL
    )
    try:
        deadline = time.monotonic() + 60
        while len(list((out / "parts").glob("rows-*.csv"))) < 3 and time.monotonic() < deadline:
            time.sleep(0.005)
        assert killed.poll() is None, "the sweep ended before it could be killed"
    finally:
        killed.send_signal(signal.SIGKILL)
        killed.wait()
    done_before = len(list((out / "parts").glob("rows-*.csv"))) * 2
    assert 0 < done_before < SLOW_TRIALS

    resumed = subprocess.run(command, cwd=tmp_path, env=_cli_env(), capture_output=True, text=True)

    assert resumed.returncode == 0, resumed.stderr
    assert (out / "results.csv").read_bytes() == _run(path, tmp_path / "uninterrupted")
    np.testing.assert_array_equal(read_results(out)["trial"], np.arange(SLOW_TRIALS))
    assert _metadata(out)["runs"][-1]["computed_trials"] == SLOW_TRIALS - done_before
    assert not list(out.rglob("*.tmp"))


def test_chunks_split_over_two_cpu_devices_give_the_same_table(tmp_path):
    """``--cpu-devices 2``: chunks of 3 trials are padded to 4 and split in two; the table is unchanged."""
    path = _write(tmp_path, TOY)
    out = tmp_path / "out"
    run = subprocess.run(
        _cli_command(path, out, "--chunk-size", "3", "--cpu-devices", "2", "--no-progress"),
        cwd=tmp_path,
        env=_cli_env(),
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert run.returncode == 0, run.stderr
    assert (out / "results.csv").read_bytes() == _run(path, tmp_path / "one_device", chunk_size=3)
    assert _metadata(out)["runs"][-1]["devices"] == 2


def test_a_table_is_resumed_on_as_many_devices_as_it_was_started(tmp_path, capsys):
    """A split program can differ in the last bits, so devices are not mixed within a table."""
    path = _write(tmp_path, SLOW)
    out = tmp_path / "out"
    run_sweep(load_sweep(path, chunk_size=2), out, progress=False)
    metadata = _metadata(out)
    metadata["runs"][-1]["devices"] = 2
    (out / "metadata.json").write_text(json.dumps(metadata))
    next(iter((out / "parts").glob("rows-*.csv"))).unlink()
    assert cli.main(["sweep", str(path), "--out", str(out), "--no-progress"]) == 2
    assert "computed on 2 device(s) and JAX presents 1: resume it where JAX presents 2 (on a CPU: --cpu-devices 2)" in (
        capsys.readouterr().err
    )


def test_resume_fills_holes_with_another_chunk_size(tmp_path):
    path = _write(tmp_path, TOY)
    out = tmp_path / "out"
    reference = _run(path, out, chunk_size=3)
    parts = sorted((out / "parts").glob("rows-*.csv"))
    for part in (parts[1], parts[2], parts[-1]):
        part.unlink()
    (out / "results.csv").unlink()
    (out / "parts" / ".rows-000000003-000000006.csv.1.0.tmp").write_text("half a ro")

    assert _run(path, out, chunk_size=5) == reference
    assert _metadata(out)["runs"][-1]["computed_trials"] == 9
    assert not list(out.rglob("*.tmp"))


def test_finished_sweep_is_not_recomputed(tmp_path, monkeypatch):
    path = _write(tmp_path, TOY.replace("toy_trial", "guarded_trial").replace("scale = 2.0\n", ""))
    out = tmp_path / "out"
    reference = _run(path, out)
    parts = {part: part.stat().st_mtime_ns for part in (out / "parts").iterdir()}
    monkeypatch.setenv("SWEEP_TEST_FORBID", "1")

    assert _run(path, out, chunk_size=1) == reference
    assert {part: part.stat().st_mtime_ns for part in (out / "parts").iterdir()} == parts
    assert _metadata(out)["runs"][-1]["computed_trials"] == 0


def test_running_sweep_holds_its_directory(tmp_path):
    fcntl = pytest.importorskip("fcntl")
    path = _write(tmp_path, TOY)
    out = tmp_path / "out"
    _run(path, out, seeds=1)
    with open(out / ".lock") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        with pytest.raises(UserError, match="another sweep is running"):
            _run(path, out, seeds=1)


# ---------------------------------------------------------------------- bad input

BAD_FILES = {
    "unknown key": (TOY.replace("seeds = 3", "sede = 3\nseeds = 3"), "unknown key 'sede' in [sweep]"),
    "wrong type": (TOY.replace("seeds = 3", 'seeds = "10"'), "[sweep] seeds must be an integer >= 1, got '10'"),
    "missing key": (TOY.replace('name = "toy"\n', ""), "missing key 'name' in [sweep]"),
    "unknown section": (TOY + "[gird]\nx = 1\n", "unknown section [gird]"),
    "syntax error": (TOY.replace("seeds = 3", "seeds = "), "invalid TOML: Invalid value (at line 4"),
    "no module": (TOY.replace("_sweep_trials:", "no_such_module_xyz:"), "cannot import module 'no_such_module_xyz'"),
    "no function": (TOY.replace("toy_trial", "no_such_trial"), "has no function 'no_such_trial'"),
    "bad trial path": (TOY.replace("_sweep_trials:toy_trial", "toy_trial"), 'must be a string "module:function"'),
    "empty grid": (TOY.split("[grid]")[0] + "[grid]\n", "[grid] is empty"),
    "no grid": (TOY.split("[grid]")[0], "missing the [grid] section"),
    "empty axis": (TOY.replace("n = [1, 2, 3]", "n = []"), "[grid] n must be a non-empty list of numbers"),
    "not numbers": (TOY.replace("n = [1, 2, 3]", 'n = ["1"]'), "[grid] n must hold numbers"),
    "float for int": (TOY.replace("n = [1, 2, 3]", "n = [1.5]"), "[grid] n must hold int values"),
    "grid key not a param": (
        TOY.replace("n = [1, 2, 3]", "m = [1, 2, 3]"),
        "[grid] key 'm' is neither a field of ToyParams (fields: a, n, flag, offset) nor a keyword-only parameter",
    ),
    "fixed key unknown": (
        TOY.replace("scale = 2.0", "scael = 2.0"),
        "[fixed] 'scael' is neither a field of ToyParams",
    ),
    "no default": (
        TOY.replace("toy_trial", "required_trial").split("[fixed]")[0] + "[grid]\na = [1.0]\n",
        "RequiredParams.b has no default",
    ),
    "missing static": (
        TOY.replace("toy_trial", "needs_static_trial").replace("scale = 2.0\n", ""),
        "needs the keyword-only argument 'size'",
    ),
    "no params annotation": (
        TOY.replace("toy_trial", "unannotated_trial").replace("scale = 2.0\n", ""),
        "must be annotated with a NamedTuple class",
    ),
    "vector result": (
        TOY.replace("toy_trial", "vector_trial").replace("scale = 2.0\n", ""),
        "result 'v' of the trial _sweep_trials:vector_trial must be a scalar",
    ),
    "list result": (
        TOY.replace("toy_trial", "list_trial").replace("scale = 2.0\n", ""),
        "must return a NamedTuple or a dict of scalars",
    ),
}


def _assert_one_line_error(rc: int, err: str, expected: str) -> None:
    assert rc == 2
    assert "Traceback" not in err
    assert len(err.splitlines()) == 1, err
    assert err.startswith("spikejax sweep: error: ")
    assert expected in err


@pytest.mark.parametrize("case", list(BAD_FILES))
def test_bad_file_is_one_line_error_before_anything_runs(tmp_path, capsys, case):
    text, expected = BAD_FILES[case]
    path = _write(tmp_path, text)
    out = tmp_path / "out"

    rc = cli.main(["sweep", str(path), "--out", str(out)])

    _assert_one_line_error(rc, capsys.readouterr().err, expected)
    assert not out.exists()


@pytest.mark.parametrize(
    ("overrides", "expected"),
    [
        ({"seeds": 0}, "--seeds must be an integer >= 1, got 0"),
        ({"chunk_size": -3}, "--chunk-size must be an integer >= 1, got -3"),
    ],
)
def test_bad_overrides_are_one_line_errors(tmp_path, overrides, expected):
    path = _write(tmp_path, TOY)

    with pytest.raises(UserError) as err:
        load_sweep(path, **overrides)

    assert str(err.value) == expected


@pytest.mark.parametrize(
    ("flags", "expected"),
    [
        (["--seeds", "0"], "argument --seeds: must be at least 1, got 0"),
        (["--chunk-size", "-3"], "argument --chunk-size: must be at least 1, got -3"),
        (["--cpu-devices", "0"], "argument --cpu-devices: must be at least 1, got 0"),
    ],
)
def test_bad_flags_are_one_line_errors_before_anything_runs(tmp_path, capsys, flags, expected):
    path = _write(tmp_path, TOY)

    with pytest.raises(SystemExit) as done:
        cli.main(["sweep", str(path), "--out", str(tmp_path / "out"), *flags])

    err = capsys.readouterr().err
    assert done.value.code == 2
    assert "Traceback" not in err
    assert len(err.splitlines()) == 1, err
    assert err.startswith(f"spikejax sweep: error: {expected}")
    assert not (tmp_path / "out").exists()


def test_missing_file_is_one_line_error(tmp_path, capsys):
    rc = cli.main(["sweep", str(tmp_path / "nope.toml"), "--out", str(tmp_path / "out")])

    _assert_one_line_error(rc, capsys.readouterr().err, "sweep file not found")


@pytest.mark.parametrize(
    ("change", "expected"),
    [
        (lambda text: text.replace("n = [1, 2, 3]", "n = [1, 2]"), "[grid] n is [1, 2, 3] there, [1, 2] here"),
        (lambda text: text.replace("offset = 0.5", "offset = 1.5"), "[fixed] offset is 0.5 there, 1.5 here"),
        (lambda text: text.replace("seeds = 3", "seeds = 4"), "[sweep] seeds is 3 there, 4 here"),
    ],
)
def test_results_of_another_sweep_are_not_touched(tmp_path, capsys, change, expected):
    out = tmp_path / "out"
    _run(_write(tmp_path, TOY), out)
    before = {path: path.read_bytes() for path in out.rglob("*") if path.is_file()}
    other = _write(tmp_path, change(TOY), "other.toml")

    rc = cli.main(["sweep", str(other), "--out", str(out), "--chunk-size", "2"])

    err = capsys.readouterr().err
    _assert_one_line_error(rc, err, "holds the results of a different sweep")
    assert expected in err
    assert {path: path.read_bytes() for path in out.rglob("*") if path.is_file()} == before


def test_chunk_size_alone_does_not_make_another_sweep(tmp_path):
    path = _write(tmp_path, TOY)
    changed = _write(tmp_path, TOY.replace("chunk_size = 4", "chunk_size = 9"), "other.toml")

    assert load_sweep(path).fingerprint == load_sweep(changed).fingerprint
    assert load_sweep(path).fingerprint != load_sweep(path, seeds=4).fingerprint


@pytest.mark.parametrize("case", ["unknown key", "no module"])
def test_bad_file_from_the_command_line(tmp_path, case):
    text, expected = BAD_FILES[case]
    out = tmp_path / "out"

    done = subprocess.run(
        _cli_command(_write(tmp_path, text), out), cwd=tmp_path, env=_cli_env(), capture_output=True, text=True
    )

    _assert_one_line_error(done.returncode, done.stderr, expected)
    assert not out.exists()


def test_trial_rejecting_a_fixed_value_is_a_one_line_error(tmp_path):
    """A trial's own ValueError for a bad static value is reported like any bad sweep file."""
    path = tmp_path / "bad.toml"
    path.write_text(
        '[sweep]\nname = "x"\ntrial = "robots.hexapod.trial:convergence_trial"\nseeds = 2\n'
        '[fixed]\nschedule = "zigzag"\n[grid]\nn_gaits = [1]\n'
    )
    run = subprocess.run(
        [sys.executable, "-m", "spikejax.cli", "sweep", str(path), "--out", str(tmp_path / "out")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert run.returncode == 2
    assert "Traceback" not in run.stderr and run.stderr.count("\n") == 1
    assert "schedule must be 'interleaved' or 'blocked'" in run.stderr
    assert not (tmp_path / "out").exists()
