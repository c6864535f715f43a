"""Fuzz: randomly damaged event files given to ``spikejax detect pipe``.

Each case (seeded, so that a failure can be replayed by its number) damages one
recording: truncated, bit-flipped, columns of the wrong dtype, shuffled or
repeated time stamps, NaN, huge values, a malformed sensor size, the wrong
suffix. ``detect pipe`` must then either print exactly what it prints for the
undamaged recording (the damage was harmless: a dtype that holds the same
numbers, a flipped bit in a zip field nobody reads) or exit with status 2 and
one error line, never a traceback.
"""

import io as pyio
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

import numpy as np
import pytest

from spikejax import cli
from spikejax.vision import io

N_CASES = 40
SEED = 13
ARGS = ["--shapes", "lines", "--v-th", "6", "--slot", "0.02", "--capacity", "128", "--no-progress"]


def _recording() -> np.ndarray:
    """Two vertical edges of opposite polarity sweeping right over a 128 x 128 sensor, 60 ms."""
    rng = np.random.default_rng(0)
    rows = []
    for k in range(600):
        t = k * 100
        x = 30 + t // 2000
        edge = k % 2
        rows.append((x + 12 * edge, rng.integers(0, 128), t, 1 if edge == 0 else -1))
    return io.normalize(np.array(rows, [("x", int), ("y", int), ("t", int), ("p", int)]), (128, 128))


def _npz_bytes(columns: dict) -> bytes:
    buf = pyio.BytesIO()
    np.savez(buf, **columns)
    return buf.getvalue()


def _columns(a: np.ndarray) -> dict:
    return dict(x=a["x"], y=a["y"], t=a["t"], p=a["p"], sensor_size=np.array([128, 128]))


def _npy_bytes(array: np.ndarray) -> bytes:
    buf = pyio.BytesIO()
    np.save(buf, array)
    return buf.getvalue()


def _aedat4_bytes(a: np.ndarray) -> bytes:
    with tempfile.TemporaryDirectory() as tmp:
        return io.save(Path(tmp) / "r.aedat4", a, (128, 128)).read_bytes()


def _damage(rng: np.random.Generator, a: np.ndarray) -> tuple[str, str, bytes]:
    """One damaged file: ``(what was done, suffix, bytes)``."""
    kind = rng.choice(["truncate", "flip", "dtype", "times", "nan", "huge", "size", "suffix"])
    cols = _columns(a)
    n = len(a)
    if kind == "truncate":
        suffix = str(rng.choice([".npz", ".npy", ".aedat4"]))
        data = {".npz": lambda: _npz_bytes(cols), ".npy": lambda: _npy_bytes(a), ".aedat4": lambda: _aedat4_bytes(a)}
        data = data[suffix]()
        cut = int(rng.integers(0, len(data)))
        return f"truncated at byte {cut}", suffix, data[:cut]
    if kind == "flip":
        data = bytearray(_npz_bytes(cols))
        for _ in range(int(rng.integers(1, 4))):
            i = int(rng.integers(0, len(data)))
            data[i] ^= 1 << int(rng.integers(0, 8))
        return "bits flipped", ".npz", bytes(data)
    if kind == "dtype":
        field = str(rng.choice(["x", "y", "t", "p"]))
        change = rng.choice(["float", "fraction", "str", "complex", "bool", "int32", "uint64", "float32"])
        v = cols[field]
        cols[field] = {
            "float": lambda: v.astype(np.float64),
            "fraction": lambda: v + 0.5,
            "str": lambda: v.astype(str),
            "complex": lambda: v.astype(np.complex128),
            "bool": lambda: v != 0,
            "int32": lambda: v.astype(np.int32),
            "uint64": lambda: v.astype(np.uint64) if v.min() >= 0 else v.astype(np.float64),
            "float32": lambda: v.astype(np.float32),
        }[change]()
        return f"{field} as {change}", ".npz", _npz_bytes(cols)
    if kind == "times":
        t = cols["t"].copy()
        how = rng.choice(["shuffle", "swap", "reverse", "repeat"])
        if how == "shuffle":
            rng.shuffle(t)
        elif how == "swap":
            i = int(rng.integers(0, n - 1))
            t[i], t[i + 1] = t[i + 1], t[i]
        elif how == "reverse":
            t = t[::-1].copy()
        else:  # equal stamps are allowed (non-decreasing): harmless only if they stay in order
            t[1:] = np.maximum.accumulate(t[1:])
        cols["t"] = t
        return f"times {how}", ".npz", _npz_bytes(cols)
    if kind == "nan":
        field = str(rng.choice(["x", "y", "t", "p"]))
        v = cols[field].astype(np.float64)
        v[int(rng.integers(0, n))] = rng.choice([np.nan, np.inf, -np.inf])
        cols[field] = v
        return f"non-finite {field}", ".npz", _npz_bytes(cols)
    if kind == "huge":
        # Values no recording holds: coordinates far off the sensor, a span of 2**55 us or more.
        field = str(rng.choice(["x", "y", "t"]))
        v = cols[field].astype(np.int64)
        if field == "t":
            choice = int(rng.integers(0, 3))
            if choice == 2:  # beyond int64, as uint64
                v = v.astype(np.uint64)
                v[-1] = np.uint64(2**63 + 7)
            else:
                v[-1] = [2**62, 2**55][choice]
        else:
            v[int(rng.integers(0, n))] = rng.choice([10**9, -(10**9), 2**40])
        cols[field] = v
        return f"huge {field}", ".npz", _npz_bytes(cols)
    if kind == "size":
        size = [
            np.array(128),
            np.array([128]),
            np.array([0, 128]),
            np.array([128.5, 128]),
            np.array([-1, 5]),
            np.array([10**6, 10**6]),
            np.array([64, 64]),
            np.array([128, 128, 2]),
            np.array(["128", "128"]),
        ][int(rng.integers(0, 9))]
        cols["sensor_size"] = size
        return f"sensor_size {size.tolist()!r}", ".npz", _npz_bytes(cols)
    # Wrong suffix: the bytes of one format under another's name.
    data, wrong = [
        (_npz_bytes(cols), ".npy"),
        (_npy_bytes(a), ".npz"),
        (_npz_bytes(cols), ".aedat4"),
        (b"x,y,t,p\n1,2,3,1\n", ".npz"),
        (_npz_bytes(cols), ".csv"),
        (b"", ".npy"),
        (_aedat4_bytes(a), ".npz"),
    ][int(rng.integers(0, 7))]
    return f"suffix {wrong}", wrong, data


def _detect(path, capsys) -> tuple[int, str, str]:
    try:
        rc = cli.main(["detect", "pipe", str(path), *ARGS])
    except SystemExit as exit_:  # an argparse error
        rc = exit_.code
    out, err = capsys.readouterr()
    return rc, out.replace(str(path), "FILE"), err


@pytest.fixture(scope="module")
def undamaged(tmp_path_factory):
    return _recording()


def test_damaged_event_files_give_the_exact_result_or_one_line(undamaged, tmp_path, capsys):
    clean = tmp_path / "clean.npz"
    clean.write_bytes(_npz_bytes(_columns(undamaged)))
    rc, expected, err = _detect(clean, capsys)
    assert rc == 0 and err == "" and "body" in expected, (rc, err)
    rng = np.random.default_rng(SEED)
    outcomes = {"same": 0, "refused": 0}
    for case in range(N_CASES):
        what, suffix, data = _damage(rng, undamaged)
        path = tmp_path / f"case{case}{suffix}"
        path.write_bytes(data)
        try:
            rc, out, err = _detect(path, capsys)
        except Exception as exc:  # a traceback: the damage escaped as an exception
            raise AssertionError(f"case {case} ({what}): {type(exc).__name__}: {exc}") from exc
        if rc == 0:
            assert out == expected and err == "", f"case {case} ({what}): a different result without an error"
            outcomes["same"] += 1
        else:
            lines = err.splitlines()
            assert rc == 2 and len(lines) == 1 and lines[0].startswith("spikejax detect pipe: error: "), (
                f"case {case} ({what}): rc {rc}, stderr {err!r}"
            )
            assert "Traceback" not in err and out == "", f"case {case} ({what})"
            outcomes["refused"] += 1
    # Both outcomes occur: the fuzz is neither all harmless nor all fatal.
    assert outcomes["same"] >= 2 and outcomes["refused"] >= 20, outcomes


def test_a_zip_with_a_bad_crc_is_refused_in_one_line(undamaged, tmp_path, capsys):
    data = bytearray(_npz_bytes(_columns(undamaged)))
    with zipfile.ZipFile(pyio.BytesIO(bytes(data))) as z:
        info = z.getinfo("x.npy")
    body = info.header_offset + 30 + len(info.filename) + len(info.extra) + 200  # inside x's data
    data[body] ^= 0xFF
    path = tmp_path / "crc.npz"
    path.write_bytes(bytes(data))
    rc, out, err = _detect(path, capsys)
    assert rc == 2 and out == ""
    assert (
        err == f"spikejax detect pipe: error: {path}: truncated or unreadable .npz file (Bad CRC-32 for file 'x.npy')\n"
    )


@pytest.mark.slow  # about 15 s of processes; the same damage in process above, the real CLI's errors in test_outputs.py
def test_damaged_files_through_the_real_cli(undamaged, tmp_path):
    # The same check in a process of its own for a few cases: the exit status and stderr are the program's.
    clean = tmp_path / "clean.npz"
    clean.write_bytes(_npz_bytes(_columns(undamaged)))
    cases = [("clean", clean)]
    rng = np.random.default_rng(SEED + 1)
    while len(cases) < 4:
        what, suffix, data = _damage(rng, undamaged)
        path = tmp_path / f"case{len(cases)}{suffix}"
        path.write_bytes(data)
        cases.append((what, path))
    expected = None
    for what, path in cases:
        run = subprocess.run(
            [sys.executable, "-m", "spikejax.cli", "detect", "pipe", str(path), *ARGS],
            capture_output=True,
            text=True,
            timeout=120,
        )
        out = run.stdout.replace(str(path), "FILE")
        if expected is None:
            assert run.returncode == 0, run.stderr
            expected = out
        elif run.returncode == 0:
            assert out == expected, what
        else:
            assert run.returncode == 2 and len(run.stderr.splitlines()) == 1, (what, run.stderr)
            assert run.stderr.startswith("spikejax detect pipe: error: ") and "Traceback" not in run.stderr
