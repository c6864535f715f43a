"""Output directories: an unusable ``--out`` is refused before any work, and a refusal leaves nothing behind.

One mechanism, `spikejax.commands.output_directory`, used by ``detect pipe`` and
the reproductions; counts below 1 are refused by the ``count`` flag type, and
``--cpu-devices`` beyond the machine's cores warns in one line.
"""

import os
import subprocess
import sys

import numpy as np
import pytest

from spikejax.commands import MARKER, output_directory
from spikejax.errors import UserError
from spikejax.vision import io


def _cli(*args, timeout=120):
    return subprocess.run(
        [sys.executable, "-m", "spikejax.cli", *args], capture_output=True, text=True, timeout=timeout
    )


def _recording(path):
    a = np.zeros(40, io.EVENT_DTYPE)
    a["x"], a["y"], a["t"], a["p"] = np.arange(40) % 16, 3, np.arange(40) * 500, 1
    return io.save(path, a, (16, 16))


def _one_line(run, message):
    assert run.returncode == 2, run.stderr
    assert run.stderr.splitlines() == [run.stderr.strip()] and "Traceback" not in run.stderr
    assert message in run.stderr, run.stderr


def test_unusable_outputs_are_refused_by_the_real_cli_before_reading(tmp_path):
    (tmp_path / "afile").write_text("x")
    foreign = tmp_path / "mine"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("keep me")
    other = tmp_path / "other"
    other.mkdir()
    (other / MARKER).write_text("reproduce gaits\n")
    (other / "gait_convergence.csv").write_text("n_gaits\n")
    cases = [
        (tmp_path / "afile", "--out {}: is a file, not a directory"),
        (tmp_path / "afile" / "sub", "--out {}: {} is a file, not a directory"),
        (foreign, "--out {}: the directory is not empty and is not an earlier output of spikejax detect pipe"),
        (other, "--out {}: the directory holds the output of spikejax reproduce gaits, not of spikejax detect pipe"),
    ]
    for out, message in cases:
        # The recording does not exist: the output directory is refused before it is looked at.
        run = _cli("detect", "pipe", str(tmp_path / "missing.npz"), "--out", str(out))
        _one_line(run, "spikejax detect pipe: error: " + message.format(out, tmp_path / "afile"))
    assert (foreign / "notes.txt").read_text() == "keep me" and sorted(os.listdir(foreign)) == ["notes.txt"]


def test_a_refused_input_leaves_no_output_directory(tmp_path):
    out = tmp_path / "new" / "out"
    _one_line(_cli("detect", "pipe", str(tmp_path / "missing.npz"), "--out", str(out)), "missing.npz: no such file")
    assert not (tmp_path / "new").exists()
    _one_line(_cli("detect", "pipe", str(_recording(tmp_path / "r.npz")), "--out", str(out), "--v-th", "-1"), "--v-th")
    assert not (tmp_path / "new").exists()
    _one_line(_cli("reproduce", "gaits", "--out", str(out), "--trials", "0"), "argument --trials: must be at least 1")
    assert not (tmp_path / "new").exists()


def test_an_earlier_run_of_the_same_command_is_used_again(tmp_path):
    path = _recording(tmp_path / "r.npz")
    out = tmp_path / "out"
    args = ("detect", "pipe", str(path), "--shapes", "lines", "--no-progress", "--out", str(out))
    first = _cli(*args)
    assert first.returncode == 0, first.stderr
    assert (out / MARKER).read_text() == "detect pipe\n"
    csv = (out / "detections.csv").read_bytes()
    again = _cli(*args)
    assert again.returncode == 0 and again.stdout == first.stdout
    assert (out / "detections.csv").read_bytes() == csv and (out / MARKER).read_text() == "detect pipe\n"


def test_a_reproduction_refuses_a_foreign_directory_before_its_sweeps(tmp_path):
    (tmp_path / "data.csv").write_text("1,2\n")
    run = _cli("reproduce", "gaits", "--out", str(tmp_path), "--trials", "2", "--no-progress")
    _one_line(run, f"spikejax reproduce gaits: error: --out {tmp_path}: the directory is not empty")
    assert sorted(os.listdir(tmp_path)) == ["data.csv"]


def test_output_directory_marks_shares_and_cleans_up(tmp_path):
    with output_directory(tmp_path / "a", command="reproduce gaits") as out:
        (out / "gait_convergence.csv").write_text("x")
    assert (tmp_path / "a" / MARKER).read_text() == "reproduce gaits\n"
    with pytest.raises(UserError, match="holds the output of spikejax reproduce gaits"):
        with output_directory(tmp_path / "a", command="reproduce robobee"):
            pass
    with output_directory(tmp_path / "a", command="reproduce gait-choices", shared_with=("reproduce gaits",)):
        pass
    assert (tmp_path / "a" / MARKER).read_text() == "reproduce gaits\nreproduce gait-choices\n"
    # A failure inside the block removes a directory it created, if nothing was written there.
    with pytest.raises(UserError, match="bad input"):
        with output_directory(tmp_path / "b" / "c", command="detect pipe") as out:
            (out / "sweeps" / "x").mkdir(parents=True)
            raise UserError("bad input")
    assert not (tmp_path / "b").exists()
    # Something written stays.
    with pytest.raises(KeyboardInterrupt):
        with output_directory(tmp_path / "d", command="detect pipe") as out:
            (out / "part.csv").write_text("1")
            raise KeyboardInterrupt
    assert (tmp_path / "d" / "part.csv").exists()
    # An empty directory that exists is used and marked; on a failure it is left as it was, empty.
    (tmp_path / "e").mkdir()
    with pytest.raises(UserError):
        with output_directory(tmp_path / "e", command="detect pipe"):
            assert (tmp_path / "e" / MARKER).is_file()
            raise UserError("x")
    assert (tmp_path / "e").is_dir() and os.listdir(tmp_path / "e") == []


@pytest.mark.skipif(os.geteuid() == 0, reason="root may write anywhere")
def test_a_directory_that_is_not_writable_is_refused(tmp_path):
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o555)
    try:
        with pytest.raises(UserError, match=r"locked: the directory is not writable"):
            with output_directory(locked, command="detect pipe"):
                pass
        with pytest.raises(UserError, match=r"cannot create it, .*locked is not writable"):
            with output_directory(locked / "sub", command="detect pipe"):
                pass
    finally:
        locked.chmod(0o755)


def test_a_failed_write_of_the_marker_is_one_line(tmp_path, monkeypatch):
    # What a read-only file system or a full disk gives when the marker is written.
    import builtins

    real = builtins.open

    def refusing(file, mode="r", *a, **k):
        if str(file).endswith(MARKER) and "a" in mode:
            raise PermissionError(13, "Permission denied")
        return real(file, mode, *a, **k)

    monkeypatch.setattr(builtins, "open", refusing)
    with pytest.raises(UserError, match=r"^--out .*new: cannot write to it \(Permission denied\)$"):
        with output_directory(tmp_path / "new", command="detect pipe"):
            pass
    assert not (tmp_path / "new").exists()


def test_cpu_devices_beyond_the_cores_warn_in_one_line():
    cores = os.cpu_count() or 1
    code = f"from spikejax.devices import cpu_devices_for_run; print(cpu_devices_for_run({cores + 1}))"
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0 and run.stdout == f"{cores + 1}\n"
    lines = [line for line in run.stderr.splitlines() if line.startswith("warning:")]
    assert lines == [
        f"warning: {cores + 1} CPU devices asked for, but this machine has {cores} core{'s' * (cores > 1)}; "
        "the devices share them (no faster than one device per core)"
    ]


def test_writes_output_checks_an_optional_out_before_the_run_and_keeps_the_signature(tmp_path):
    import inspect

    from spikejax.commands import writes_output
    from spikejax.errors import UserError

    calls = []

    @writes_output("bench toy")
    def run(*, out: str | None = None, trials: int | None = None) -> int:
        calls.append(out)
        (out / "table.csv").write_text("x\n") if out is not None else None
        return 0

    assert list(inspect.signature(run).parameters) == ["out", "trials"]
    assert run(out=None, trials=1) == 0 and calls == [None]
    assert run(out=str(tmp_path / "new"), trials=1) == 0
    assert calls[-1] == tmp_path / "new" and (tmp_path / "new" / "table.csv").exists()
    assert run(out=str(tmp_path / "new"), trials=1) == 0  # its own earlier output is used again
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("mine")
    with pytest.raises(UserError, match="not an earlier output of spikejax bench toy"):
        run(out=str(foreign), trials=1)
    assert len(calls) == 3 and sorted(p.name for p in foreign.iterdir()) == ["notes.txt"]
