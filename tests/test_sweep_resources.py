"""Disk full, a table too large for the disk, equivalent sweep files, unusable output paths."""

from __future__ import annotations

import errno
import json
import os
import subprocess

import pytest
from test_sweep import TESTS, TOY, _assert_one_line_error, _cli_command, _cli_env, _run, _write

from spikejax import cli
from spikejax.sweep import load_sweep, read_results


@pytest.fixture(autouse=True)
def _trials_importable(monkeypatch):
    monkeypatch.syspath_prepend(str(TESTS))


def _metadata(out):
    return json.loads((out / "metadata.json").read_text())


def test_disk_full_mid_sweep_is_one_line_and_the_sweep_resumes(tmp_path, capsys, monkeypatch):
    path = _write(tmp_path, TOY)
    reference = _run(path, tmp_path / "reference")
    out = tmp_path / "out"
    real_fsync, calls = os.fsync, []

    def fsync(fd):
        calls.append(fd)
        if len(calls) > 6:  # the disk fills up after a few files: every write from then on fails
            raise OSError(errno.ENOSPC, "No space left on device")
        real_fsync(fd)

    monkeypatch.setattr(os, "fsync", fsync)
    rc = cli.main(["sweep", str(path), "--out", str(out), "--no-progress"])
    monkeypatch.setattr(os, "fsync", real_fsync)

    _assert_one_line_error(rc, capsys.readouterr().err, f"no space left on the disk of {out}")
    done = len(read_results(out)["trial"])  # the table is whole, with the trials done so far
    assert 0 < done < 36 and not list(out.rglob("*.tmp"))

    assert cli.main(["sweep", str(path), "--out", str(out), "--no-progress"]) == 0  # space freed
    assert (out / "results.csv").read_bytes() == reference


def test_a_table_too_large_for_the_disk_is_refused_before_anything_runs(tmp_path):
    path = _write(tmp_path, TOY.replace("seeds = 3", f"seeds = {2**31 - 1}"))

    run = subprocess.run(
        _cli_command(path, tmp_path / "out"),
        env=_cli_env(SWEEP_TEST_FORBID=""),
        capture_output=True,
        text=True,
    )

    _assert_one_line_error(run.returncode, run.stderr, "the table of 25,769,803,764 trials needs at least ")
    assert "TB on disk (parts and results.csv), and " in run.stderr and " free: run fewer seeds" in run.stderr
    assert not (tmp_path / "out").exists()


FLOAT_FIELD = TOY.replace("offset = 0.5", "offset = 2.0").replace("a = [1.0, -2.5]", "a = [1.0, -2.0]")


def test_equivalent_sweep_files_are_one_sweep(tmp_path, monkeypatch):
    """``offset = 2`` and ``a = [1, -2]`` of float fields are ``2.0`` and ``[1.0, -2.0]``."""
    as_floats = _write(tmp_path, FLOAT_FIELD)
    as_ints = _write(
        tmp_path, FLOAT_FIELD.replace("offset = 2.0", "offset = 2").replace("[1.0, -2.0]", "[1, -2]"), "i.toml"
    )
    assert load_sweep(as_floats).fingerprint == load_sweep(as_ints).fingerprint
    out = tmp_path / "out"
    reference = _run(as_ints, out)

    assert _run(as_floats, out) == reference
    assert _metadata(out)["runs"][-1]["computed_trials"] == 0


def test_a_table_fingerprinted_as_written_still_resumes(tmp_path):
    """Directories of earlier versions record the fingerprint of the values as the file writes them."""
    path = _write(tmp_path, FLOAT_FIELD.replace("offset = 2.0", "offset = 2"))
    out = tmp_path / "out"
    reference = _run(path, out)
    metadata = _metadata(out)
    spec = load_sweep(path)
    assert spec.legacy_fingerprint != spec.fingerprint
    metadata["fingerprint"] = spec.legacy_fingerprint
    (out / "metadata.json").write_text(json.dumps(metadata))

    assert _run(path, out) == reference


def test_a_refused_resume_names_the_key_that_differs(tmp_path, capsys):
    out = tmp_path / "out"
    _run(_write(tmp_path, TOY), out)
    other = _write(tmp_path, TOY.replace("scale = 2.0", "scale = 3.0"), "other.toml")

    rc = cli.main(["sweep", str(other), "--out", str(out)])

    _assert_one_line_error(rc, capsys.readouterr().err, "([fixed] scale is 2.0 there, 3.0 here)")


def _file(tmp_path):
    (tmp_path / "file").write_text("x")
    return tmp_path / "file"


def _below_file(tmp_path):
    return _file(tmp_path) / "sub" / "out"


def _not_a_sweep(tmp_path):
    (tmp_path / "notes").mkdir()
    (tmp_path / "notes" / "todo.txt").write_text("x")
    return tmp_path / "notes"


@pytest.mark.parametrize(
    ("make", "expected"),
    [
        (_file, "--out {out} is a file, not a directory"),
        (_below_file, "--out {out} is below {tmp}/file, which is a file"),
        (_not_a_sweep, "--out {out} is a non-empty directory that holds no sweep (todo.txt, ...)"),
    ],
)
def test_an_unusable_output_path_is_refused_before_any_work(tmp_path, capsys, monkeypatch, make, expected):
    monkeypatch.setenv("SWEEP_TEST_FORBID", "1")  # the trial must not even be traced
    out = make(tmp_path)
    before = sorted(tmp_path.rglob("*"))
    path = _write(tmp_path, TOY.replace("toy_trial", "guarded_trial").replace("scale = 2.0\n", ""))

    rc = cli.main(["sweep", str(path), "--out", str(out)])

    _assert_one_line_error(rc, capsys.readouterr().err, expected.format(out=out, tmp=tmp_path))
    assert sorted(p for p in tmp_path.rglob("*") if p != path) == before


@pytest.mark.skipif(os.geteuid() == 0, reason="root may write anywhere")
def test_an_output_path_that_cannot_be_written_is_refused(tmp_path, capsys):
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    try:
        rc = cli.main(["sweep", str(_write(tmp_path, TOY)), "--out", str(locked / "out")])
        _assert_one_line_error(rc, capsys.readouterr().err, f"cannot write in {locked} (permission denied)")
        assert not (locked / "out").exists()
    finally:
        locked.chmod(0o700)


def test_an_output_path_the_os_denies_is_refused_before_any_work(tmp_path, capsys, monkeypatch):
    """Root may write anywhere: the OS's answer is simulated here, the message and the order are real."""
    monkeypatch.setenv("SWEEP_TEST_FORBID", "1")
    monkeypatch.setattr(os, "access", lambda path, mode: False)
    path = _write(tmp_path, TOY.replace("toy_trial", "guarded_trial").replace("scale = 2.0\n", ""))

    rc = cli.main(["sweep", str(path), "--out", str(tmp_path / "out" / "sub")])

    _assert_one_line_error(rc, capsys.readouterr().err, f"cannot write in {tmp_path} (permission denied)")
    assert not (tmp_path / "out").exists()


def test_an_earlier_run_killed_before_its_first_write_is_a_usable_output(tmp_path):
    out = tmp_path / "out"
    (out / "parts").mkdir(parents=True)
    (out / ".lock").write_text("")
    path = _write(tmp_path, TOY)

    assert _run(path, out) == _run(path, tmp_path / "reference")


def test_an_unusable_output_path_from_the_command_line_comes_before_the_trial(tmp_path):
    """The real CLI: ``--out`` is checked before the trial's module is imported."""
    out = _file(tmp_path)
    path = _write(tmp_path, TOY.replace("_sweep_trials:toy_trial", "no_such_module_xyz:trial"))

    run = subprocess.run(_cli_command(path, out), env=_cli_env(), capture_output=True, text=True)

    _assert_one_line_error(run.returncode, run.stderr, f"--out {out} is a file, not a directory")
    assert out.read_text() == "x"
