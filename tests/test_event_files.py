"""Event recordings: errors that name the file and the problem, and recordings longer than memory.

A file that is not what its suffix says, a directory, a malformed ``sensor_size``
or time stamps beyond int64 are one line naming the file; a sparse recording of
2,000 s is detected in bounded memory (slots cut a chunk at a time, empty
stretches skipped, the result the same), and what cannot fit is refused with
the size named.
"""

import subprocess
import sys

import numpy as np
import pytest

from spikejax.errors import UserError
from spikejax.vision import detect as detect_module
from spikejax.vision import io
from spikejax.vision.detect import detect


def _events(n=60, width=16):
    a = np.zeros(n, io.EVENT_DTYPE)
    a["x"], a["y"], a["t"], a["p"] = np.arange(n) % width, 3, np.arange(n) * 100, 1
    return a


def _columns(**changes):
    a = _events(3)
    cols = dict(x=a["x"], y=a["y"], t=a["t"], p=a["p"], sensor_size=np.array([16, 16]))
    cols.update(changes)
    return {k: v for k, v in cols.items() if v is not None}


def _npz(path, **changes):
    np.savez(path, **_columns(**changes))
    return path


def test_a_text_file_renamed_npz_is_called_not_an_npz_file(tmp_path):
    (tmp_path / "notes.npz").write_text("t,x,y,p\n0,1,2,1\n")
    with pytest.raises(UserError) as err:
        io.read(tmp_path / "notes.npz")
    assert (
        str(err.value)
        == f"{tmp_path / 'notes.npz'}: not an .npz file (a zip archive of arrays); its first bytes are b't,x,y,p\\n'"
    )
    assert "pickle" not in str(err.value)
    (tmp_path / "notes.npy").write_text("hello")
    with pytest.raises(
        UserError, match=r"notes\.npy: not an \.npy file \(a NumPy array\); its first bytes are b'hello'$"
    ):
        io.read(tmp_path / "notes.npy")
    (tmp_path / "empty.npz").write_bytes(b"")
    with pytest.raises(UserError, match=r"empty\.npz: empty file, not an \.npz file"):
        io.read(tmp_path / "empty.npz")


def test_a_directory_is_called_a_directory(tmp_path):
    for name in ("rec.npz", "rec"):
        (tmp_path / name).mkdir()
        with pytest.raises(UserError) as err:
            io.read(tmp_path / name)
        assert str(err.value) == f"{tmp_path / name}: is a directory, not an event file"


@pytest.mark.parametrize(
    "size, message",
    [
        (np.array(128), "sensor_size must be (width, height), not 128"),
        (np.array([128]), "sensor_size must be (width, height), not [128]"),
        (np.array([[16, 16]]), "sensor_size must be (width, height), not [[16, 16]]"),
        (np.array([16.5, 16]), "sensor_size must be two whole numbers >= 1, not [16.5, 16.0]"),
        (np.array([16, -4]), "sensor_size must be two whole numbers >= 1, not [16, -4]"),
        (np.array([np.nan, 16]), "sensor_size must be two whole numbers >= 1, not [nan, 16.0]"),
        (np.array(["a", "b"]), "sensor_size must be (width, height), two whole numbers, not ['a', 'b']"),
    ],
)
def test_a_malformed_sensor_size_in_a_file_is_named(size, message, tmp_path):
    path = _npz(tmp_path / "r.npz", sensor_size=size)
    with pytest.raises(UserError) as err:
        io.read(path)
    assert str(err.value) == f"{path}: {message}"


def test_tonic_sensor_size_with_polarity_channels_is_read(tmp_path):
    _, size = io.read(_npz(tmp_path / "r.npz", sensor_size=np.array([16, 8, 2])))
    assert size == (16, 8)


def test_uint64_stamps_beyond_int64_are_an_error_not_a_wrap_around(tmp_path):
    # Wrapped to int64, 2**63 + 5 becomes negative and the stamps would seem to go backwards, or
    # (after the last event) a huge stamp would pass as a small one.
    t = np.array([1, 2, 2**63 + 5], np.uint64)
    path = _npz(tmp_path / "r.npz", t=t)
    with pytest.raises(UserError) as err:
        io.read(path)
    assert str(err.value) == f"{path}: t=9223372036854775813 at event 2 does not fit a signed 64-bit integer"
    ok = _npz(tmp_path / "ok.npz", t=np.array([1, 2, 3], np.uint64))
    assert io.read(ok)[0]["t"].tolist() == [1, 2, 3]
    with pytest.raises(UserError, match=r"t=1e\+19 at event 1 does not fit a signed 64-bit integer"):
        io.read(_npz(tmp_path / "f.npz", t=np.array([1, 1e19, 1e19])))


def test_pickled_objects_are_named_as_such(tmp_path):
    np.save(tmp_path / "obj.npy", np.array([1, None], object), allow_pickle=True)
    with pytest.raises(UserError, match=r"obj\.npy: holds Python objects \(pickled data\), not arrays of numbers"):
        io.read(tmp_path / "obj.npy")


def test_the_real_cli_names_the_file_in_one_line(tmp_path):
    (tmp_path / "notes.npz").write_text("just text")
    run = subprocess.run(
        [sys.executable, "-m", "spikejax.cli", "detect", "pipe", str(tmp_path / "notes.npz")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert run.returncode == 2 and run.stdout == ""
    assert run.stderr == (
        f"spikejax detect pipe: error: {tmp_path / 'notes.npz'}: not an .npz file (a zip archive of arrays); "
        "its first bytes are b'just tex'\n"
    )


def _sparse(gap_us):
    """Two short bursts of a vertical edge pair, ``gap_us`` apart."""
    burst = []
    for k in range(300):
        x = 4 + (k % 2) * 6
        burst.append((x, k % 16, k * 20, 1 if x == 4 else -1))
    a = np.array(burst, [("x", int), ("y", int), ("t", int), ("p", int)])
    b = a.copy()
    b["t"] += gap_us
    return io.normalize(np.concatenate([a, b]), (16, 16))


@pytest.mark.parametrize("mode", ["sync", "async"])
def test_skipping_empty_stretches_gives_the_result_of_computing_them(mode, monkeypatch):
    events = _sparse(1_000_000)  # 1 s apart: 50 slots, most of them empty
    params = detect_module.detector_params(v_th=3)
    kw = dict(mode=mode, slot=0.02, sub_slots=2, capacity=64, circles=False, chunk=4, params=params)
    calls = []
    run = detect_module._run_jit
    monkeypatch.setattr(detect_module, "_run_jit", lambda *a: calls.append(1) or run(*a))
    skipped = detect(events, (16, 16), **kw)
    assert (n_skipped := len(calls)) < 6  # of 13 chunks of 4 slots, the empty ones (at rest) are not computed
    monkeypatch.setattr(detect_module, "_can_skip", lambda det, state: False)  # compute every slot
    computed = detect(events, (16, 16), **kw)
    assert len(calls) == n_skipped + 13
    assert skipped.table() == computed.table() and [round(r["t"], 2) for r in skipped.table()] == [0.02, 1.02]
    np.testing.assert_array_equal(skipped.bodies.valid, computed.bodies.valid)
    np.testing.assert_array_equal(skipped.bodies.t, computed.bodies.t)
    np.testing.assert_array_equal(skipped.overflow, computed.overflow)


def test_a_sparse_2000_s_recording_runs_in_bounded_memory_and_to_slots_names_the_size():
    events = _sparse(2_000_000_000)  # 2,000 s: 100,001 slots of 20 ms, 500,005 parts of 4,096 events
    found = detect(events, (16, 16), circles=False, params=detect_module.detector_params(v_th=3))
    assert len(found.overflow) == 100_001 and found.overflow.sum() == 0
    first, last = found.table()[0], found.table()[-1]
    assert first["t"] < 0.1 and last["t"] > 2000.0
    # All slots at once, as detect cut them before, would need 35 GB; slots of 1 us, 139 TB.
    with pytest.raises(UserError, match=r"^2000005981 slots of 4096 events would need 139\.3 TB of memory, more than"):
        io.to_slots(events, 1e-6, 4096)


def test_spans_and_sensors_beyond_memory_are_refused_with_the_size():
    events = _sparse(2**61)
    with pytest.raises(
        UserError, match=r"^the results of \d+ slots of 20 ms \(\d+ s of recording\) would need [\d.]+ PB"
    ):
        detect(events, (16, 16), circles=False)
    with pytest.raises(
        UserError, match=r"^the Hough grids of a 100000x100000 sensor would need [\d.]+ TB of memory, more than"
    ):
        detect(events[:1], (100_000, 100_000))


def test_a_file_of_the_other_numpy_format_is_named(tmp_path):
    a = _events(3)
    np.save(tmp_path / "r.npy", a)
    (tmp_path / "r.npz").write_bytes((tmp_path / "r.npy").read_bytes())
    with pytest.raises(UserError) as err:
        io.read(tmp_path / "r.npz")
    assert str(err.value) == (
        f"{tmp_path / 'r.npz'}: not an .npz file (a zip archive of arrays); it is an .npy file (a NumPy array), named .npz"
    )
