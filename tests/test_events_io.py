"""Event conversion: structured arrays, .npy, .npz and AEDAT4 in and out, and bad input."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from spikejax.errors import UserError
from spikejax.vision import io

TONIC = [("x", "<i2"), ("y", "<i2"), ("t", "<i8"), ("p", "?")]


def _tonic(n=50, seed=0, size=(128, 96)):
    rng = np.random.default_rng(seed)
    a = np.empty(n, TONIC)
    a["x"] = rng.integers(0, size[0], n)
    a["y"] = rng.integers(0, size[1], n)
    a["t"] = 1_700_000_000_000_000 + np.cumsum(rng.integers(0, 500, n))  # Unix us, as AEDAT4 stores
    a["p"] = rng.random(n) < 0.5
    return a


@pytest.mark.parametrize(
    "p, expected",
    [
        (np.array([True, False, True]), [1, -1, 1]),
        (np.array([1, 0, 1], np.uint8), [1, -1, 1]),
        (np.array([1, -1, -1], np.int64), [1, -1, -1]),
        (np.array([1.0, 0.0, 0.0]), [1, -1, -1]),
        (np.array([1, 1, 1]), [1, 1, 1]),
    ],
)
def test_polarity_encodings_map_to_signed(p, expected):
    a = np.empty(3, [("x", int), ("y", int), ("t", int), ("p", p.dtype)])
    a["x"], a["y"], a["t"], a["p"] = [0, 1, 2], [3, 4, 5], [10, 20, 30], p
    ev, overflow = io.from_structured(a)
    assert ev.p.tolist() == expected and overflow == 0


def test_structured_round_trip_restores_stamps_exactly():
    a = _tonic(200)
    ev, overflow = io.from_structured(a, (128, 96), capacity=256)
    assert overflow == 0 and int(ev.count()) == 200
    assert float(ev.t[0]) == 0.0  # relative to the first event
    back = io.to_structured(ev, t0=int(a["t"][0]), polarity="bool")
    for name in ("x", "y", "t", "p"):
        np.testing.assert_array_equal(back[name], a[name])


def test_slots_of_a_stream_read_row_by_row():
    a = _tonic(200)
    rows = [
        io.from_structured(a[k * 50 : (k + 1) * 50], (128, 96), capacity=64, t0=int(a["t"][0]))[0] for k in range(4)
    ]
    slots = jax.tree.map(lambda *v: jnp.stack(v), *rows)  # leaves (4, 64), the last 14 slots of each row empty
    back = io.to_structured(slots, t0=int(a["t"][0]), polarity="bool")
    for name in ("x", "y", "t", "p"):
        np.testing.assert_array_equal(back[name], a[name])
    with pytest.raises(UserError, match="one stream"):
        io.to_structured(jax.tree.map(lambda v: v[None], slots))


def test_capacity_overflow_is_counted_and_first_events_kept(tmp_path):
    a = _tonic(30)
    ev, overflow = io.from_structured(a, (128, 96), capacity=20)
    assert overflow == 10
    np.testing.assert_array_equal(ev.x, a["x"][:20])
    rec = io.load(io.save(tmp_path / "cap.npz", a, (128, 96)), capacity=25)
    assert rec.overflow == 5 and rec.events.capacity == 25 and rec.sensor_size == (128, 96)


@pytest.mark.parametrize("suffix", [".npz", ".npy", ".aedat4"])
def test_file_round_trip(tmp_path, suffix):
    a = _tonic(5000, seed=1)  # > one 4096-event AEDAT4 packet
    path = io.save(tmp_path / f"rec{suffix}", a, (128, 96))
    b, size = io.read(path, None if suffix != ".npy" else (128, 96))
    assert size == (128, 96)
    np.testing.assert_array_equal(b["x"], a["x"])
    np.testing.assert_array_equal(b["y"], a["y"])
    np.testing.assert_array_equal(b["t"], a["t"])
    np.testing.assert_array_equal(b["p"], np.where(a["p"], 1, -1))


def test_events_pytree_saved_with_t0(tmp_path):
    a = _tonic(40)
    rec = io.load(io.save(tmp_path / "a.npz", a, (128, 96)))
    path = io.save(tmp_path / "b.aedat4", rec.events, rec.sensor_size, t0=rec.t0)
    np.testing.assert_array_equal(io.read(path)[0]["t"], a["t"])


def test_aedat4_written_file_is_read_by_the_aedat_package(tmp_path):
    aedat = pytest.importorskip("aedat")
    a = _tonic(10)
    path = io.save(tmp_path / "a.aedat4", a, (128, 96))
    decoder = aedat.Decoder(str(path))
    assert decoder.id_to_stream() == {0: {"type": "events", "width": 128, "height": 96}}
    (packet,) = list(decoder)
    np.testing.assert_array_equal(packet["events"]["t"], a["t"])
    np.testing.assert_array_equal(packet["events"]["on"], a["p"])


def test_npz_with_one_structured_array(tmp_path):
    a = _tonic(12)
    np.savez(tmp_path / "s.npz", events=a)
    b, size = io.read(tmp_path / "s.npz")
    assert size == (128, 128)  # no size in the file: the DVS128's
    np.testing.assert_array_equal(b["x"], a["x"])


def _with(field, index, value, dtype=None):
    a = _tonic(20)
    if dtype is not None:
        b = np.empty(len(a), [(n, dtype if n == field else a.dtype[n]) for n in a.dtype.names])
        for n in a.dtype.names:
            b[n] = a[n]
        a = b
    a[field][index] = value
    return a


@pytest.mark.parametrize(
    "events, message",
    [
        (_with("x", 7, 128), "x=128 at event 7 is outside the 128x96 sensor"),
        (_with("y", 3, -1), "y=-1 at event 3 is outside the 128x96 sensor"),
        (_with("t", 5, 0), "time stamps go backwards at event 5"),
        (_with("t", 4, np.nan, "f8"), "t is nan at event 4"),
        (_with("x", 2, 1.5, "f8"), "x=1.5 at event 2 is not a whole number"),
        (_with("p", 9, 2, "i8"), "unknown polarity encoding: p=2 at event 9"),
        (_with("p", 9, np.nan, "f8"), "polarity is nan at event 9"),
    ],
)
def test_bad_events_name_the_problem(events, message):
    with pytest.raises(UserError, match=message.replace("(", r"\(")):
        io.normalize(events, (128, 96))


def test_polarity_mixing_zero_and_minus_one_is_rejected():
    a = _with("p", 4, -1, "i8")
    a["p"][:4] = 1
    a["p"][6] = 0
    with pytest.raises(UserError, match=r"mixes 0 and -1 \(first -1 at event 4, first 0 at event"):
        io.normalize(a, (128, 96))


def test_missing_field():
    a = np.zeros(3, [("x", int), ("y", int), ("t", int)])
    with pytest.raises(UserError, match="lack field.*p"):
        io.normalize(a)


@pytest.mark.parametrize("suffix", [".npz", ".npy", ".aedat4"])
def test_truncated_file(tmp_path, suffix):
    path = io.save(tmp_path / f"a{suffix}", _tonic(500), (128, 96))
    raw = path.read_bytes()
    path.write_bytes(raw[: len(raw) - 37])
    with pytest.raises(UserError, match="truncated"):
        io.read(path, (128, 96))


def test_not_an_aedat4_file(tmp_path):
    (tmp_path / "x.aedat4").write_bytes(b"#!AER-DAT2.0\r\n" + b"\0" * 64)
    with pytest.raises(UserError, match="wrong magic number"):
        io.read(tmp_path / "x.aedat4")


def test_aedat4_events_outside_stated_sensor(tmp_path):
    path = io.save(tmp_path / "a.aedat4", _tonic(20, size=(128, 96)), (128, 96))
    raw = bytearray(path.read_bytes())
    # The stated sensor height becomes 10: the decoder then reports rows past it.
    at = raw.index(b'"sizeY" type="int">96<')
    raw[at : at + len(b'"sizeY" type="int">96<')] = b'"sizeY" type="int">10<'
    path.write_bytes(bytes(raw))
    with pytest.raises(UserError, match=r"y=\d+ at event \d+ is outside the 128x10 sensor"):
        io.read(path)


def test_unknown_suffix_and_missing_file(tmp_path):
    with pytest.raises(UserError, match="unknown event file type '.txt'"):
        io.read(tmp_path / "a.txt")
    with pytest.raises(UserError, match="no such file"):
        io.read(tmp_path / "a.npz")


def test_slots_partition_events_and_count_overflow():
    a = np.zeros(7, io.EVENT_DTYPE)
    a["t"] = [1000, 1100, 1200, 1300, 2500, 4000, 4100]  # us
    a["x"] = np.arange(7)
    a["p"] = 1
    s = io.to_slots(a, slot=1e-3, capacity=3)
    assert s.events.x.shape == (4, 3)  # slots [0,1), [1,2), [2,3), [3,4) ms after t0
    np.testing.assert_array_equal(s.overflow, [1, 0, 0, 0])
    np.testing.assert_array_equal(s.events.valid.sum(1), [3, 1, 0, 2])
    np.testing.assert_array_equal(s.events.x[0], [0, 1, 2])
    np.testing.assert_array_equal(s.events.x[3, :2], [5, 6])
    np.testing.assert_allclose(s.start, [0, 1e-3, 2e-3, 3e-3])


def test_slots_boundaries_are_exact_in_microseconds():
    # Frame-difference events share their frame's stamp, which falls on slot boundaries:
    # 0.01 s is not exact in binary, but 10,000 us is.
    a = np.zeros(30, io.EVENT_DTYPE)
    a["t"] = 1_700_000_000_000_000 + np.repeat(np.arange(10) * 10_000, 3)
    a["p"] = 1
    s = io.to_slots(a, slot=0.01, capacity=4)
    np.testing.assert_array_equal(s.events.valid.sum(1), np.full(10, 3))
    s = io.to_slots(a, slot=0.03, capacity=9)
    np.testing.assert_array_equal(s.events.valid.sum(1), [9, 9, 9, 3])


def test_npy_outside_the_assumed_dvs128_hints_at_the_size(tmp_path):
    np.save(tmp_path / "big.npy", _tonic(20, size=(240, 180)))
    with pytest.raises(UserError, match="outside the 128x128 sensor .*states no sensor size"):
        io.read(tmp_path / "big.npy")
    assert io.read(tmp_path / "big.npy", (240, 180))[1] == (240, 180)
