"""Event streams in and out: numpy structured arrays, ``.npy``, ``.npz`` and AEDAT4.

This is the edge of `spikejax.vision` (DESIGN rule 4): recordings come in
the layouts users have, are checked on the host, and leave as a fixed-capacity
`spikejax.vision.events.Events` pytree with the number of events that
did not fit beside it.

The common layout is the one Tonic uses: a numpy structured array with fields
``x``, ``y``, ``t``, ``p``, time stamps in integer microseconds. Polarity comes
in three encodings, all accepted: ``bool`` (``True`` = ON), ``0``/``1`` and
``-1``/``+1``; they are mapped to the ``{-1, +1}`` of `Events`. Anything
else (a ``2``, or a stream mixing ``0`` and ``-1``) is rejected.

Functions:

* `normalize`: check a structured array and return it in the canonical
  layout `EVENT_DTYPE` (``x``, ``y`` int16, ``t`` int64 us, ``p`` int8 +-1).
* `from_structured` / `to_structured`: array <-> `Events`.
* `read` / `load`: a file (``.npz``, ``.npy``, ``.aedat4``) to the
  canonical array / to `Events` (a `Recording`).
* `save`: `Events` or a structured array to ``.npz``, ``.npy``
  or ``.aedat4``.
* `to_slots`: cut a recording into time slots of a fixed event capacity,
  the input of the slot-by-slot detectors; `slot_index` and `slot_grid`
  cut a long recording a stretch at a time, in bounded memory.
* `check_fits`: refuse, with the size, what would not fit in memory.

Conventions: ``sensor_size`` is ``(width, height)`` in pixels, as Tonic's
``sensor_size[:2]``. `Events` holds ``t`` in float32 seconds, so
absolute time stamps (AEDAT4 stores Unix microseconds) are made relative to a
``t0`` (by default the first event), which every function here returns or
accepts so that a round trip restores the original stamps exactly. Float32
seconds resolve 1 us up to about 16 s after ``t0`` and 8 us at 100 s.

Bad input raises `spikejax.errors.UserError` with a one-line message
naming the problem and the index of the first offending event; `read` names
the file too (a file that is not what its suffix says, a directory, a
malformed ``sensor_size``, time stamps that do not fit int64).
"""

from __future__ import annotations

import os
import struct
import zipfile
from pathlib import Path
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

from spikejax.errors import UserError
from spikejax.vision.events import Events

__all__ = [
    "EVENT_DTYPE",
    "Recording",
    "Slots",
    "from_structured",
    "load",
    "normalize",
    "read",
    "check_fits",
    "save",
    "slot_grid",
    "slot_index",
    "to_slots",
    "to_structured",
]

EVENT_DTYPE = np.dtype([("x", "<i2"), ("y", "<i2"), ("t", "<i8"), ("p", "i1")])
"""The canonical host layout: pixel column, row, time stamp (us), polarity (+-1)."""

DVS128 = (128, 128)
_SUFFIXES = (".npz", ".npy", ".aedat4")


class Recording(NamedTuple):
    """A recording loaded into a fixed-capacity buffer.

    Attributes:
        events: the first ``capacity`` events, ``t`` in seconds after ``t0``.
        overflow: number of events that did not fit (0 when all fit).
        sensor_size: ``(width, height)`` in pixels.
        t0: absolute time of ``t = 0``, microseconds (int).
    """

    events: Events
    overflow: int
    sensor_size: tuple[int, int]
    t0: int


class Slots(NamedTuple):
    """A recording cut into time slots, one `Events` row per slot.

    Attributes:
        events: `Events` with leaves of shape ``(n_slots, capacity)``,
            ``t`` in seconds after ``t0``.
        overflow: ``(n_slots,)`` int, events of each slot that did not fit.
        start: ``(n_slots,)`` float, each slot's start, seconds after ``t0``.
        t0: absolute time of ``t = 0``, microseconds.
    """

    events: Events
    overflow: np.ndarray
    start: np.ndarray
    t0: int


def _first(mask: np.ndarray) -> int:
    return int(np.flatnonzero(mask)[0])


def _polarity(p: np.ndarray) -> np.ndarray:
    """Map a bool, 0/1 or -1/+1 polarity column to int8 -1/+1 (see module notes)."""
    if p.dtype == np.bool_:
        return np.where(p, 1, -1).astype(np.int8)
    if np.issubdtype(p.dtype, np.floating):
        bad = ~np.isfinite(p)
        if bad.any():
            i = _first(bad)
            raise UserError(f"polarity is {p[i]} at event {i}")
    elif not np.issubdtype(p.dtype, np.integer):
        raise UserError(f"polarity field has dtype {p.dtype}; expected bool or integers")
    unknown = (p != -1) & (p != 0) & (p != 1)
    if unknown.any():
        i = _first(unknown)
        raise UserError(f"unknown polarity encoding: p={p[i]} at event {i}; expected bool, 0/1 or -1/+1")
    negative, zero = p == -1, p == 0
    if negative.any() and zero.any():
        raise UserError(
            "unknown polarity encoding: p mixes 0 and -1 "
            f"(first -1 at event {_first(negative)}, first 0 at event {_first(zero)}); "
            "expected bool, 0/1 or -1/+1"
        )
    return np.where(p == 1, 1, -1).astype(np.int8)


def _integral(name: str, values: np.ndarray) -> np.ndarray:
    """Check a coordinate or time column is finite and integer-valued; return int64."""
    if values.dtype.kind not in "iuf":
        raise UserError(f"field {name!r} has dtype {values.dtype}; expected numbers")
    if np.issubdtype(values.dtype, np.floating):
        bad = ~np.isfinite(values)
        if bad.any():
            i = _first(bad)
            raise UserError(f"{name} is {values[i]} at event {i}")
        bad = values != np.round(values)
        if bad.any():
            i = _first(bad)
            raise UserError(f"{name}={values[i]} at event {i} is not a whole number")
        bad = (values < -(2.0**63)) | (values >= 2.0**63)
    elif np.issubdtype(values.dtype, np.unsignedinteger) and values.dtype.itemsize >= 8:
        bad = values > np.iinfo(np.int64).max
    else:
        bad = np.zeros(values.shape, bool)
    if bad.any():
        # A cast would wrap around (and could hide time stamps going backwards).
        i = _first(bad)
        raise UserError(f"{name}={values[i]} at event {i} does not fit a signed 64-bit integer")
    return values.astype(np.int64)


def normalize(events: np.ndarray, sensor_size: tuple[int, int] = DVS128) -> np.ndarray:
    """Check a structured event array and return it in `EVENT_DTYPE`.

    Args:
        events: numpy structured array, shape ``(n,)``, with fields ``x``,
            ``y``, ``t`` (microseconds, non-decreasing) and ``p`` (bool, 0/1 or
            -1/+1). Extra fields are ignored.
        sensor_size: ``(width, height)``; every ``0 <= x < width``, ``0 <= y < height``.

    Returns:
        A new array of dtype `EVENT_DTYPE`, polarity mapped to ``-1/+1``.

    Raises:
        UserError: a missing field, a NaN, a coordinate outside the sensor,
            time stamps going backwards or an unknown polarity encoding, naming
            the first offending event.
    """
    events = np.asarray(events)
    width, height = _check_sensor_size(sensor_size)
    names = events.dtype.names
    if names is None:
        raise UserError(f"events must be a structured array with fields x, y, t, p, not {events.dtype}")
    missing = [f for f in ("x", "y", "t", "p") if f not in names]
    if missing:
        raise UserError(f"events lack field(s) {', '.join(missing)} (fields: {', '.join(names)})")
    events = events.reshape(-1)
    out = np.empty(events.shape[0], EVENT_DTYPE)
    for name, size in (("x", width), ("y", height)):
        values = _integral(name, events[name])
        bad = (values < 0) | (values >= size)
        if bad.any():
            i = _first(bad)
            raise UserError(f"{name}={values[i]} at event {i} is outside the {width}x{height} sensor")
        out[name] = values
    t = _integral("t", events["t"])
    back = np.diff(t) < 0
    if back.any():
        i = _first(back) + 1
        raise UserError(f"time stamps go backwards at event {i} (t={t[i]} us after {t[i - 1]} us)")
    out["t"] = t
    out["p"] = _polarity(events["p"])
    return out


def _check_sensor_size(sensor_size) -> tuple[int, int]:
    """``(width, height)`` as two whole numbers >= 1 (a one-line UserError naming what was given otherwise)."""
    shown = _shown(sensor_size)
    try:
        values = np.asarray(sensor_size)
        if values.ndim != 1 or len(values) != 2 or values.dtype.kind not in "iuf":
            raise TypeError
        width, height = (float(v) for v in values)
    except (TypeError, ValueError):
        raise UserError(f"sensor_size must be (width, height), two whole numbers, not {shown}") from None
    for v in (width, height):
        if not (np.isfinite(v) and v == round(v) and 1 <= v < 2**31):
            raise UserError(f"sensor_size must be two whole numbers >= 1, not {shown}")
    return int(width), int(height)


def _shown(value) -> str:
    """A short, one-line rendering of a value for a message."""
    text = " ".join(repr(value.tolist() if isinstance(value, np.ndarray) else value).split())
    return text if len(text) <= 60 else text[:57] + "..."


def from_structured(
    events: np.ndarray,
    sensor_size: tuple[int, int] = DVS128,
    *,
    capacity: int | None = None,
    t0: int | None = None,
) -> tuple[Events, int]:
    """A structured array (Tonic's layout) as a fixed-capacity `Events`.

    Args:
        events: structured array with fields ``x``, ``y``, ``t`` (us), ``p``;
            checked by `normalize`.
        sensor_size: ``(width, height)``.
        capacity: slots of the buffer (default: the number of events).
        t0: time stamp (us) that becomes ``t = 0`` (default: the first event's).

    Returns:
        ``(events, overflow)``: the first ``capacity`` events with ``t`` in
        seconds after ``t0``, and the number that did not fit.

    Examples:
        >>> a = np.array([(3, 4, 1000, 1), (5, 6, 1500, 0)],
        ...              dtype=[("x", int), ("y", int), ("t", int), ("p", int)])
        >>> ev, overflow = from_structured(a, capacity=4)
        >>> ev.p.tolist(), ev.t.tolist(), overflow
        ([1, -1, 0, 0], [0.0, 0.0005000000237487257, 0.0, 0.0], 0)
    """
    a = normalize(events, sensor_size)
    return _to_events(a, len(a) if capacity is None else capacity, _t0(a, t0))


def _t0(a: np.ndarray, t0: int | None) -> int:
    if t0 is not None:
        return int(t0)
    return int(a["t"][0]) if len(a) else 0


def _to_events(a: np.ndarray, capacity: int, t0: int) -> tuple[Events, int]:
    if capacity < 0:
        raise UserError(f"capacity must be >= 0, not {capacity}")
    n = min(len(a), capacity)
    pad = capacity - n

    def column(values, dtype):
        return jnp.asarray(np.concatenate([values[:n].astype(dtype), np.zeros(pad, dtype)]))

    seconds = (a["t"][:n] - t0).astype(np.float64) * 1e-6
    events = Events(
        x=column(a["x"], np.int32),
        y=column(a["y"], np.int32),
        t=column(seconds, np.float32),
        p=column(a["p"], np.int32),
        valid=jnp.asarray(np.arange(capacity) < n),
    )
    return events, len(a) - n


def to_structured(events: Events, *, t0: int = 0, polarity: str = "signed") -> np.ndarray:
    """The valid events of an `Events` as a structured array.

    Args:
        events: one stream (leaves of shape ``(capacity,)``), or a sequence of
            slots of one stream (leaves ``(n_slots, capacity)``, e.g. from
            `spikejax.vision.dvs.difference_events`), read row by row.
        t0: absolute time (us) of ``t = 0``; added back to the stamps.
        polarity: ``"signed"`` for ``-1/+1`` (`EVENT_DTYPE`) or ``"bool"``
            for Tonic's ``False/True``.

    Returns:
        Array with fields ``x``, ``y``, ``t`` (int64 us, rounded to the
        nearest microsecond) and ``p``, in slot order.
    """
    if np.ndim(events.x) not in (1, 2):
        raise UserError(
            f"to_structured takes one stream, as (capacity,) or (slots, capacity) arrays; "
            f"got event arrays of shape {np.shape(events.x)}"
        )
    if polarity not in ("signed", "bool"):
        raise UserError(f"polarity must be 'signed' or 'bool', not {polarity!r}")
    keep = np.asarray(events.valid, bool).reshape(-1)

    def column(values, dtype=None):
        return np.asarray(values, dtype).reshape(-1)[keep]

    dtype = EVENT_DTYPE if polarity == "signed" else np.dtype([*EVENT_DTYPE.descr[:3], ("p", "?")])
    out = np.empty(int(keep.sum()), dtype)
    out["x"] = column(events.x)
    out["y"] = column(events.y)
    out["t"] = np.rint(column(events.t, np.float64) * 1e6).astype(np.int64) + int(t0)
    p = column(events.p)
    out["p"] = p if polarity == "signed" else p > 0
    return out


# --- files -------------------------------------------------------------------


def _suffix(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix not in _SUFFIXES:
        raise UserError(f"{path}: unknown event file type {suffix!r}; expected one of {', '.join(_SUFFIXES)}")
    return suffix


def read(path, sensor_size: tuple[int, int] | None = None) -> tuple[np.ndarray, tuple[int, int]]:
    """Read an event file into the canonical structured array.

    ``.npz``: arrays ``x``, ``y``, ``t``, ``p`` (as `save` writes them,
    optionally ``sensor_size``), or a single structured array with those
    fields. ``.npy``: a structured array. ``.aedat4``: the first event stream
    of the file, read with the ``aedat`` package (uncompressed, LZ4 or Zstd).

    Args:
        path: the file.
        sensor_size: ``(width, height)``; overrides the size the file states.
            Without either, the DVS128's ``(128, 128)``.

    Returns:
        ``(events, sensor_size)``, events in `EVENT_DTYPE`, checked by
        `normalize`.

    Raises:
        UserError: a missing, truncated or unreadable file, or bad events.
    """
    path = Path(path)
    if path.is_dir():
        raise UserError(f"{path}: is a directory, not an event file")
    suffix = _suffix(path)
    if not path.is_file():
        raise UserError(f"{path}: no such file" if not path.exists() else f"{path}: not a regular file")
    stated = None
    if suffix == ".aedat4":
        array, stated = _read_aedat4(path)
    else:
        _check_magic(path, suffix)
        try:
            loaded = np.load(path, allow_pickle=False)
        except (ValueError, OSError, EOFError, zipfile.BadZipFile) as err:
            raise _unreadable(path, suffix, err) from None
        if suffix == ".npy":
            array = loaded
        else:
            with loaded:
                try:
                    array, stated = _from_npz(loaded)
                except UserError as err:
                    raise UserError(f"{path}: {err}") from None
                except (ValueError, OSError, EOFError, zipfile.BadZipFile) as err:
                    raise _unreadable(path, suffix, err) from None
    size = sensor_size if sensor_size is not None else stated if stated is not None else DVS128
    try:
        return normalize(array, size), _check_sensor_size(size)
    except UserError as err:
        hint = ""
        if sensor_size is None and stated is None and "outside the" in str(err):
            hint = " (the file states no sensor size, so the DVS128's was assumed; give the size)"
        raise UserError(f"{path}: {err}{hint}") from None


def _unreadable(path: Path, suffix: str, err: Exception) -> UserError:
    if "pickle" in str(err):
        return UserError(f"{path}: holds Python objects (pickled data), not arrays of numbers; they are not read")
    detail = " ".join(str(err).split()) or err.__class__.__name__
    return UserError(f"{path}: truncated or unreadable {suffix} file ({detail})")


_MAGIC = {".npz": (b"PK\x03\x04", b"PK\x05\x06"), ".npy": (b"\x93NUMPY",)}
_WHAT = {".npz": "an .npz file (a zip archive of arrays)", ".npy": "an .npy file (a NumPy array)"}


def _check_magic(path: Path, suffix: str) -> None:
    """Refuse a file that does not start as its suffix says (a text file renamed ``.npz``)."""
    try:
        with open(path, "rb") as f:
            head = f.read(8)
    except OSError as err:
        raise UserError(f"{path}: cannot read it ({err.strerror or err.__class__.__name__})") from None
    if not head:
        raise UserError(f"{path}: empty file, not {_WHAT[suffix]}")
    if not any(head.startswith(m) for m in _MAGIC[suffix]):
        other = [s for s, magic in _MAGIC.items() if any(head.startswith(m) for m in magic)]
        found = f"it is {_WHAT[other[0]]}, named {suffix}" if other else f"its first bytes are {head[:8]!r}"
        raise UserError(f"{path}: not {_WHAT[suffix]}; {found}")


def _stated_size(value) -> tuple[int, int]:
    """The ``sensor_size`` an .npz states: ``(width, height)``, or Tonic's ``(width, height, 2)``."""
    value = np.asarray(value)
    if value.ndim != 1 or len(value) not in (2, 3):
        raise UserError(f"sensor_size must be (width, height), not {_shown(value)}")
    return _check_sensor_size(value[:2])


def _from_npz(npz) -> tuple[np.ndarray, tuple[int, int] | None]:
    keys = set(npz.files)
    stated = _stated_size(npz["sensor_size"]) if "sensor_size" in keys else None
    if {"x", "y", "t", "p"} <= keys:
        columns = {k: np.asarray(npz[k]).reshape(-1) for k in ("x", "y", "t", "p")}
        lengths = {k: len(v) for k, v in columns.items()}
        if len(set(lengths.values())) != 1:
            raise UserError(f"arrays x, y, t, p differ in length ({lengths})")
        array = np.empty(lengths["x"], [(k, v.dtype) for k, v in columns.items()])
        for k, v in columns.items():
            array[k] = v
        return array, stated
    structured = [k for k in npz.files if npz[k].dtype.names is not None]
    if len(structured) == 1:
        return npz[structured[0]], stated
    raise UserError(f"expected arrays x, y, t, p or one structured array; found {', '.join(sorted(keys)) or 'nothing'}")


def _read_aedat4(path: Path) -> tuple[np.ndarray, tuple[int, int]]:
    try:
        import aedat
    except ImportError:
        raise UserError("reading .aedat4 needs the 'aedat' package: pip install 'spikejax[aedat]'") from None
    try:
        decoder = aedat.Decoder(str(path))
        streams = {i: s for i, s in decoder.id_to_stream().items() if s.get("type") == "events"}
        if not streams:
            raise UserError(f"{path}: no event stream in this AEDAT4 file")
        stream_id = min(streams)
        chunks = [packet["events"] for packet in decoder if packet["stream_id"] == stream_id]
    except RuntimeError as err:
        raise UserError(f"{path}: truncated or corrupt AEDAT4 file ({err})") from None
    size = (int(streams[stream_id]["width"]), int(streams[stream_id]["height"]))
    array = np.empty(sum(len(c) for c in chunks), [("x", "<i8"), ("y", "<i8"), ("t", "<i8"), ("p", "?")])
    offset = 0
    for chunk in chunks:
        block = array[offset : offset + len(chunk)]
        block["x"], block["y"], block["t"], block["p"] = chunk["x"], chunk["y"], chunk["t"], chunk["on"]
        offset += len(chunk)
    return array, size


def load(
    path,
    *,
    sensor_size: tuple[int, int] | None = None,
    capacity: int | None = None,
    t0: int | None = None,
) -> Recording:
    """Read an event file (see `read`) into a fixed-capacity `Events`.

    Args:
        path: ``.npz``, ``.npy`` or ``.aedat4`` file.
        sensor_size: ``(width, height)``, overriding what the file states.
        capacity: slots (default: the number of events in the file).
        t0: time stamp (us) that becomes ``t = 0`` (default: the first event's).

    Returns:
        A `Recording`; its ``overflow`` counts the events past ``capacity``.
    """
    a, size = read(path, sensor_size)
    t0 = _t0(a, t0)
    events, overflow = _to_events(a, len(a) if capacity is None else capacity, t0)
    return Recording(events, overflow, size, t0)


def save(path, events, sensor_size: tuple[int, int] = DVS128, *, t0: int = 0) -> Path:
    """Write events to ``.npz``, ``.npy`` or ``.aedat4`` (chosen by the suffix).

    Args:
        path: destination file.
        events: an `Events` (one stream, as `to_structured` takes
            it; ``t0`` added back to its stamps) or a structured array with fields ``x``, ``y``, ``t``, ``p``.
        sensor_size: ``(width, height)``, stored in ``.npz`` and ``.aedat4``.
        t0: absolute time (us) of ``t = 0`` of an `Events`.

    Returns:
        The path written.

    Notes:
        ``.npz`` holds arrays ``x``, ``y``, ``t`` (int64 us), ``p`` (int8 +-1)
        and ``sensor_size``; ``.npy`` one `EVENT_DTYPE` array (no sensor
        size). ``.aedat4`` is written uncompressed, one events stream of
        packets of at most 4096 events, with no file data table (the format's
        ``file_data_position = -1``, as a streaming writer leaves it).
    """
    path = Path(path)
    suffix = _suffix(path)
    size = _check_sensor_size(sensor_size)
    a = normalize(to_structured(events, t0=t0) if isinstance(events, Events) else events, size)
    if suffix == ".npz":
        np.savez(path, x=a["x"], y=a["y"], t=a["t"], p=a["p"], sensor_size=np.array(size))
    elif suffix == ".npy":
        np.save(path, a)
    else:
        _write_aedat4(path, a, size)
    return path


# AEDAT4 (https://docs.inivation.com/software/software-advanced-usage/file-formats/aedat-4.0.html):
# the magic line, a u32 length and an IOHeader flatbuffer, then packets of
# (u32 stream id, u32 length, size-prefixed flatbuffer). The flatbuffers are
# laid out by hand here so that writing needs no flatbuffers package.
_AEDAT4_MAGIC = b"#!AER-DAT4.0\r\n"
_AEDAT4_DESCRIPTION = (
    '<dv version="2.0"><node name="outInfo" path="/mainloop/output_file/outInfo/">'
    '<node name="0" path="/mainloop/output_file/outInfo/0/">'
    '<attr key="compression" type="string">NONE</attr>'
    '<attr key="originalModuleName" type="string">spikejax</attr>'
    '<attr key="originalOutputName" type="string">events</attr>'
    '<attr key="typeDescription" type="string">Array of events (polarity ON/OFF).</attr>'
    '<attr key="typeIdentifier" type="string">EVTS</attr>'
    '<node name="info" path="/mainloop/output_file/outInfo/0/info/">'
    '<attr key="sizeX" type="int">{width}</attr><attr key="sizeY" type="int">{height}</attr>'
    '<attr key="source" type="string">spikejax</attr></node></node></node></dv>'
)
_AEDAT4_EVENT = np.dtype(
    {"names": ["t", "x", "y", "on"], "formats": ["<i8", "<i2", "<i2", "u1"], "offsets": [0, 8, 10, 12], "itemsize": 16}
)


def _align(buf: bytearray, alignment: int, remainder: int = 0) -> None:
    while len(buf) % alignment != remainder:
        buf += b"\0"


def _aedat4_ioheader(description: str) -> bytes:
    """Flatbuffer table IOHeader {compression: int32, file_data_position: int64, description: string}."""
    text = description.encode()
    buf = bytearray(b"\0\0\0\0IOHE")  # root offset, file identifier
    vtable = len(buf)
    buf += struct.pack("<5H", 10, 20, 4, 8, 16)  # vtable size, table size, field offsets
    _align(buf, 8)
    table = len(buf)
    buf += struct.pack("<iiq", table - vtable, 0, -1)  # vtable offset, compression None, no data table
    buf += struct.pack("<I", 4)  # offset to the string, which follows at once
    buf += struct.pack("<I", len(text)) + text + b"\0"
    _align(buf, 4)
    struct.pack_into("<I", buf, 0, table)
    return bytes(buf)


def _aedat4_events_packet(a: np.ndarray) -> bytes:
    """Size-prefixed flatbuffer table EventPacket {elements: [Event]}, identifier EVTS."""
    buf = bytearray(b"\0\0\0\0\0\0\0\0EVTS")  # size prefix, root offset, file identifier
    vtable = len(buf)
    buf += struct.pack("<3H", 6, 8, 4)
    _align(buf, 8)
    table = len(buf)
    buf += struct.pack("<i", table - vtable)
    field = len(buf)
    buf += b"\0\0\0\0"
    _align(buf, 8, 4)  # Event structs (16 bytes) start 8-aligned after the u32 length
    vector = len(buf)
    records = np.zeros(len(a), _AEDAT4_EVENT)
    records["t"], records["x"], records["y"], records["on"] = a["t"], a["x"], a["y"], a["p"] > 0
    buf += struct.pack("<I", len(a)) + records.tobytes()
    struct.pack_into("<I", buf, field, vector - field)
    struct.pack_into("<I", buf, 4, table - 4)
    struct.pack_into("<I", buf, 0, len(buf) - 4)
    return bytes(buf)


def _write_aedat4(path: Path, a: np.ndarray, size: tuple[int, int], packet: int = 4096) -> None:
    header = _aedat4_ioheader(_AEDAT4_DESCRIPTION.format(width=size[0], height=size[1]))
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as f:
        f.write(_AEDAT4_MAGIC + struct.pack("<I", len(header)) + header)
        for start in range(0, len(a), packet):
            body = _aedat4_events_packet(a[start : start + packet])
            f.write(struct.pack("<II", 0, len(body)) + body)
    os.replace(tmp, path)


# --- slots -------------------------------------------------------------------


def check_fits(nbytes: float, what: str) -> None:
    """Refuse (a one-line UserError naming the size) what would need more than half of this machine's memory."""
    try:
        memory = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return
    if nbytes > 0.5 * memory:
        raise UserError(f"{what} would need {_bytes(nbytes)} of memory, more than this machine has ({_bytes(memory)})")


def _bytes(n: float) -> str:
    for unit in ("bytes", "KB", "MB", "GB", "TB", "PB"):
        if n < 1000 or unit == "PB":
            return f"{n:.0f} {unit}" if unit == "bytes" else f"{n:.1f} {unit}"
        n /= 1000
    return f"{n:.1f} PB"  # pragma: no cover


SLOT_EVENT_BYTES = 17
"""Host bytes per event place of a slot (x, y, t, p as 32-bit numbers, and the valid flag)."""


def slot_index(events: np.ndarray, slot: float, t0: int | None = None) -> np.ndarray:
    """The slot of each event: ``k`` for ``t0 + k * slot <= t < t0 + (k + 1) * slot`` (``slot`` in s, > 0).

    Args:
        events: array in `EVENT_DTYPE`, time stamps non-decreasing.
        slot: slot length, seconds.
        t0: start of slot 0, us (default: the first event's stamp).

    Returns:
        ``(n,)`` int64, non-decreasing.
    """
    if not slot > 0:
        raise UserError(f"slot length must be > 0 s, not {slot}")
    t0 = _t0(events, t0)
    t = events["t"]
    if len(t) and (int(t[-1]) - t0 >= 2**62 or int(t[0]) - t0 <= -(2**62)):
        raise UserError(
            f"the recording spans {int(t[-1]) - int(t[0])} us, more than 2^62 us: too long to cut into slots"
        )
    slot_us = slot * 1e6
    if abs(slot_us - round(slot_us)) < 1e-6:
        # Whole microseconds: integer division, so that an event stamped exactly
        # on a boundary opens the next slot whatever the float rounding.
        return (t - t0) // int(round(slot_us))
    return np.floor((t - t0) / slot_us).astype(np.int64)


def slot_grid(
    events: np.ndarray, index: np.ndarray, capacity: int, n_slots: int, *, t0: int, first: int = 0
) -> tuple[Events, np.ndarray]:
    """Slots ``first .. first + n_slots - 1`` of a recording as `Events` rows of ``capacity`` places.

    Args:
        events: array in `EVENT_DTYPE`.
        index: the slot of each event (`slot_index`).
        capacity: event places per slot; the first events of a slot in time order are kept.
        n_slots: number of slots.
        t0: absolute time (us) of ``t = 0``.
        first: the first slot's index.

    Returns:
        ``(events, overflow)``: leaves ``(n_slots, capacity)``, and ``(n_slots,)`` events that did not fit.
    """
    if capacity <= 0:
        raise UserError(f"capacity must be > 0, not {capacity}")
    check_fits(n_slots * capacity * SLOT_EVENT_BYTES, f"{n_slots} slots of {capacity} events")
    lo, hi = np.searchsorted(index, [first, first + n_slots])
    local = index[lo:hi] - first
    part = events[lo:hi]
    counts = np.bincount(local, minlength=n_slots)
    start = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    rank = np.arange(len(local)) - start[local]
    fits = rank < capacity
    rows, cols, src = local[fits], rank[fits], np.flatnonzero(fits)
    seconds = (part["t"][src] - t0).astype(np.float64) * 1e-6

    def grid(values, dtype):
        out = np.zeros((n_slots, capacity), dtype)
        out[rows, cols] = values
        return jnp.asarray(out)

    valid = np.zeros((n_slots, capacity), bool)
    valid[rows, cols] = True
    batch = Events(
        x=grid(part["x"][src], np.int32),
        y=grid(part["y"][src], np.int32),
        t=grid(seconds, np.float32),
        p=grid(part["p"][src], np.int32),
        valid=jnp.asarray(valid),
    )
    return batch, np.maximum(counts - capacity, 0)


def to_slots(
    events: np.ndarray,
    slot: float,
    capacity: int,
    *,
    t0: int | None = None,
    n_slots: int | None = None,
) -> Slots:
    """Cut a canonical event array into consecutive time slots of fixed capacity.

    Slot ``k`` holds the events with ``t0 + k * slot <= t < t0 + (k + 1) * slot``
    (``slot`` in seconds), the first ``capacity`` of them in time order; the
    rest are counted in ``overflow[k]``. This is the "for each time slot" of
    Alg. 2 of the snake pipe-tracking paper.

    Every slot is held at once (``n_slots x capacity`` places): slots that would
    need more than half of the machine's memory are refused with the size.
    `slot_index` and `slot_grid` cut a long recording a stretch at a time, as
    `spikejax.vision.detect.detect` does.

    Args:
        events: array in `EVENT_DTYPE` (from `read` or `normalize`).
        slot: slot length, seconds (> 0).
        capacity: event slots per time slot.
        t0: start of the first slot, us (default: the first event's stamp).
        n_slots: number of slots (default: enough to hold the last event).

    Returns:
        `Slots`, events batched with a leading slot axis.
    """
    if capacity <= 0:
        raise UserError(f"capacity must be > 0, not {capacity}")
    t0 = _t0(events, t0)
    index = slot_index(events, slot, t0)
    if n_slots is None:
        n_slots = int(index[-1]) + 1 if len(events) else 0
    lo, hi = np.searchsorted(index, [0, n_slots])
    batch, overflow = slot_grid(events[lo:hi], index[lo:hi], capacity, n_slots, t0=t0)
    return Slots(batch, overflow, np.arange(n_slots) * slot, t0)
