"""A sweep's output directory: the one place that knows the files, their names and their layout.

The output directory holds::

    results.csv          the table: a header, then the finished rows in trial order
    metadata.json        the sweep file (text and parsed), its fingerprint, the
                         columns, versions, git commit, devices, times, trials done
    parts/rows-S-E-H.csv the rows S .. E-1 of one chunk, without a header; H is
                         the SHA-256 of the file's bytes
    .lock                locked while a run is going on

A row is its cells (`spikejax.sweep.table`) joined by commas, ended by a
newline; the header is written by ``csv``. Nothing is ever half-written:
every file is written to a temporary file in its directory, flushed, fsync'ed
and renamed over its name (``os.replace``). A chunk's part is written as soon
as the chunk is done; ``results.csv`` and ``metadata.json`` are rebuilt from the
parts during the run (as often as costs at most a tenth of the run time) and
at the end.

Parts prove themselves. A part's name says which rows it holds and the
checksum of its bytes; both are written in one rename, so a part is whole or
absent. Every run scans the parts and keeps only those that hold exactly
``E - S`` newline-ended rows whose bytes have the named checksum; any other
(cut short, emptied, garbled) is renamed ``*.damaged``, named on stderr, and
its trials are computed again. A part written before parts carried a checksum
(``rows-S-E.csv``) is kept when it holds ``E - S`` rows, numbered ``S .. E-1``,
each with one cell per column that reads back as the engine writes it. Every
run also rebuilds ``results.csv`` unless it is byte for byte the header and the
parts. Reading a table (`read_results`) accepts only the cells the engine
writes (`spikejax.sweep.table`) and names the file, line and column of any
other.

Resources. Before a run writes anything, the output path is checked (a
directory or a new path, writable, holding nothing but an earlier run of a
sweep), and the table's size is estimated against the free space of its disk.
A disk that fills up during a run stops it with one line: every file is still
whole, and the sweep resumes once space is freed.

Resuming. The same sweep, run again after a run stopped however it stopped
(SIGKILL included), skips the trials in the parts and runs the others, with
any chunk size; the final ``results.csv`` is byte for byte the one of an
uninterrupted run, whether its chunks ran in this process or as Ray tasks
(`spikejax.sweep.cluster`: the driver alone writes, and a task runs its chunk
on one device). It must run on as many devices as the first run did (each
run's count is in ``metadata.json``): a chunk split over devices is compiled
apart and can differ in the last bits (some RoboBee learning flights did). The
sweep's fingerprint (`spikejax.sweep.SweepSpec.fingerprint`) keeps the results
of another sweep out of a directory. Resuming assumes that the trial's code is
the same; ``metadata.json`` records each run's git commit.
"""

from __future__ import annotations

import contextlib
import csv
import datetime
import hashlib
import importlib.metadata
import io
import json
import math
import os
import re
import shutil
import subprocess
import sys
import time
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any, NamedTuple

import jax
import numpy as np

from spikejax.errors import UserError
from spikejax.files import atomic_file
from spikejax.sweep.spec import SweepSpec
from spikejax.sweep.table import NONFINITE, Column, bad_cell, parse_column

__all__ = [
    "Store",
    "check_columns",
    "check_out",
    "check_space",
    "existing",
    "opened",
    "read_results",
    "recorded_columns",
    "results_path",
]

_RESULTS = "results.csv"
_METADATA = "metadata.json"
_PARTS = "parts"
_LOCK = ".lock"
_PART_NAME = re.compile(r"rows-(\d+)-(\d+)(?:-([0-9a-f]{64}))?\.csv")
_DAMAGED = ".damaged"
# The fewest bytes a result cell of each kind takes ("true", "0", "0.0"), for the size estimate.
_LEAST_CELL_BYTES = {"bool": 4, "int": 1, "float": 3}
_METADATA_FORMAT = 1
_PUBLISH_SHARE = 0.1


def _atomic_file(path: Path):
    """`spikejax.files.atomic_file`, with what to do when the disk fills mid-sweep."""
    return atomic_file(
        path, when_full="the results written so far are whole; free some space and run the sweep again to resume"
    )


def _remove_temporaries(*directories: Path) -> None:
    for directory in directories:
        for temporary in directory.glob(".*.tmp"):
            with contextlib.suppress(OSError):
                temporary.unlink()


@contextlib.contextmanager
def _locked(out: Path) -> Iterator[None]:
    try:
        import fcntl
    except ImportError:  # no advisory locks on this OS: runs are not guarded
        yield
        return
    with open(out / _LOCK, "a") as lock:
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise UserError(f"another sweep is running in {out}") from None
        yield


class _Part(NamedTuple):
    start: int
    end: int
    path: Path


def _named_parts(parts_dir: Path) -> list[tuple[_Part, str | None]]:
    """The files named as parts, with the checksum their name gives (None: a part of an older table)."""
    if not parts_dir.is_dir():
        return []
    named = []
    for path in parts_dir.iterdir():
        match = _PART_NAME.fullmatch(path.name)
        if match:
            named.append((_Part(int(match[1]), int(match[2]), path), match[3]))
    named.sort()
    return named


def _part_damage(part: _Part, checksum: str | None, columns: list[Column] | None) -> str | None:
    """Why ``part`` does not hold what its name says (None: it does)."""
    try:
        data = part.path.read_bytes()
    except OSError as err:
        return f"cannot be read: {err.strerror or err}"
    rows = part.end - part.start
    if not data:
        return "it is empty"
    if not data.endswith(b"\n"):
        return "it is cut mid-line"
    held = data.count(b"\n")
    if held != rows:
        return f"it holds {held} rows, its name says {rows}"
    if checksum is not None:
        return None if hashlib.sha256(data).hexdigest() == checksum else "its checksum differs"
    # A part of an older table, without a checksum: every cell must read back.
    if columns is None:
        return "it has no checksum and there are no columns to check it against"
    try:
        lines = data.decode("utf-8").split("\n")[:-1]
    except UnicodeDecodeError:
        return "it is not UTF-8 text"
    for i, line in enumerate(lines):
        row = line.split(",")
        if len(row) != len(columns):
            return f"row {i + 1} has {len(row)} cells, not {len(columns)}"
        if row[0] != str(part.start + i):
            return f"row {i + 1} is trial {row[0]!r}, not {part.start + i}"
        for text, column in zip(row, columns):
            if bad_cell(text, column.dtype) is not None:
                return f"row {i + 1}, column {column.name}: {text!r} is {bad_cell(text, column.dtype)}"
    return None


def _scan_parts(
    parts_dir: Path, n_trials: float, columns: list[Column] | None = None, *, set_aside: bool = False
) -> list[_Part]:
    """The finished chunks whose files prove themselves, in trial order.

    With ``set_aside``, a damaged part is renamed ``*.damaged`` and named on stderr;
    either way its trials count as missing. Without ``columns`` no part is verified.
    """
    named = _named_parts(parts_dir)
    previous_end = 0
    for part, _ in named:
        if part.start < previous_end or part.end <= part.start or part.end > n_trials:
            raise UserError(f"{parts_dir} holds a part that does not fit this sweep: {part.path.name}")
        previous_end = part.end
    if columns is None:
        return [part for part, _ in named]
    parts = []
    for part, checksum in named:
        damage = _part_damage(part, checksum, columns)
        if damage is None:
            parts.append(part)
        elif set_aside:
            aside = part.path.with_name(part.path.name + _DAMAGED)
            try:
                os.replace(part.path, aside)
            except OSError as err:
                raise UserError(f"cannot set aside the damaged part {part.path}: {err.strerror or err}") from None
            print(
                f"warning: {part.path} is damaged ({damage}): moved to {aside.name}, "
                f"its trials {part.start}..{part.end - 1} are computed again",
                file=sys.stderr,
                flush=True,
            )
    return parts


def _missing_ranges(parts: list[_Part], n_trials: int) -> list[tuple[int, int]]:
    missing, position = [], 0
    for part in parts:
        if part.start > position:
            missing.append((position, part.start))
        position = part.end
    if position < n_trials:
        missing.append((position, n_trials))
    return missing


def _write_part(parts_dir: Path, start: int, end: int, rows: str) -> _Part:
    data = rows.encode()
    path = parts_dir / f"rows-{start:09d}-{end:09d}-{hashlib.sha256(data).hexdigest()}.csv"
    with _atomic_file(path) as file:
        file.write(data)
    return _Part(start, end, path)


def _table_size(header: str, parts: list[_Part]) -> int:
    return len(header.encode()) + sum(part.path.stat().st_size for part in parts)


def _table_is_whole(out: Path, header: str, parts: list[_Part]) -> bool:
    """Whether ``results.csv`` is byte for byte the header and the parts."""
    results = out / _RESULTS
    try:
        if results.stat().st_size != _table_size(header, parts):
            return False
        with open(results, "rb") as table:
            if table.read(len(header.encode())) != header.encode():
                return False
            for part in sorted(parts):
                with open(part.path, "rb") as source:
                    while block := source.read(1 << 20):
                        if table.read(len(block)) != block:
                            return False
    except OSError:
        return False
    return True


def _write_table(out: Path, header: str, parts: list[_Part]) -> None:
    with _atomic_file(out / _RESULTS) as file:
        file.write(header.encode())
        for part in sorted(parts):
            with open(part.path, "rb") as source:
                shutil.copyfileobj(source, file)


def _nonfinite_trials(results: Path, columns: list[Column], first_result: int) -> tuple[list[int], list[int]]:
    """The trials with a NaN result, and those with a NaN or infinite result or the ``nonfinite`` flag set.

    Read off the table: float cells ``nan``, ``inf``, ``-inf``; a bool result named
    `spikejax.sweep.table.NONFINITE` that is ``true``.
    """
    floats = {i for i, column in enumerate(columns) if i >= first_result and column.dtype.startswith("float")}
    flag = next(
        (i for i, c in enumerate(columns) if i >= first_result and c.name == NONFINITE and c.dtype == "bool"), None
    )
    markers = (b"nan", b"inf", b"true")
    nan_trials, nonfinite = [], []
    with open(results, "rb") as file:
        next(file)
        for line in file:
            if not any(marker in line for marker in markers):
                continue
            cells = line.rstrip(b"\n").split(b",")
            bad = [cells[i] for i in floats if cells[i] in (b"nan", b"inf", b"-inf")]
            if b"nan" in bad:
                nan_trials.append(int(cells[0]))
            if bad or (flag is not None and cells[flag] == b"true"):
                nonfinite.append(int(cells[0]))
    return nan_trials, nonfinite


def _header(columns: list[Column]) -> str:
    buffer = io.StringIO()
    csv.writer(buffer, lineterminator="\n").writerow(column.name for column in columns)
    return buffer.getvalue()


def _rows(cells: list[list[str]]) -> str:
    return "".join(",".join(row) + "\n" for row in zip(*cells))


def _now() -> str:
    return datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")


def check_out(out: Path) -> None:
    """Raises a UserError unless ``out`` can take a sweep: a new path, or a directory we may write in
    that is empty or holds an earlier run of a sweep. Nothing is created."""
    existing_path = next((p for p in (out, *out.parents) if p.exists()), None)
    if existing_path is not None and not existing_path.is_dir():
        if existing_path == out:
            raise UserError(f"--out {out} is a file, not a directory")
        raise UserError(f"--out {out} is below {existing_path}, which is a file")
    if existing_path is not None and not os.access(existing_path, os.W_OK | os.X_OK):
        raise UserError(f"--out {out}: cannot write in {existing_path} (permission denied)")
    if existing_path == out and not (out / _METADATA).exists():
        try:
            entries = os.listdir(out)
        except OSError as err:
            raise UserError(f"--out {out}: cannot list it: {err.strerror or err}") from None
        others = [name for name in entries if name not in (_PARTS, _LOCK) and not name.endswith(".tmp")]
        if others:
            raise UserError(
                f"--out {out} is a non-empty directory that holds no sweep ({sorted(others)[0]}, ...): "
                "choose a new or empty directory, or the directory of an earlier run of this sweep"
            )


def check_space(out: Path, spec: SweepSpec, columns: list[Column]) -> None:
    """Raises a UserError if the table of ``spec`` cannot fit on the disk of ``out``.

    The estimate is a lower bound: each cell its fewest bytes (the trial and seed
    numbers their digits, the grid's cells their text), times two, as the table is
    kept both in the parts and in ``results.csv``; what ``out`` holds already counts.
    """
    from spikejax.sweep.table import key_columns

    first_result = len(key_columns(spec))
    row = len(columns)  # the commas and the newline
    for axis in spec.axes:
        row += min(len(str(value)) for value in axis.values)
    for column in columns[first_result:]:
        kind = "bool" if column.dtype == "bool" else "float" if column.dtype.startswith("float") else "int"
        row += _LEAST_CELL_BYTES[kind]
    points = spec.n_trials // spec.seeds
    table = spec.n_trials * row + _digits(spec.n_trials) + points * _digits(spec.seeds)
    needed = 2 * table
    held = sum(p.path.stat().st_size for p in _scan_parts(out / _PARTS, math.inf)) * 2
    needed -= held
    where = next((p for p in (out, *out.parents) if p.exists()), Path("."))
    free = shutil.disk_usage(where).free
    if needed > free:
        raise UserError(
            f"the table of {spec.n_trials:,} trials needs at least {_size(needed)} on disk (parts and "
            f"{_RESULTS}), and {where} has {_size(free)} free: run fewer seeds or grid points, or use another --out"
        )


def _digits(n: int) -> int:
    """The characters of the decimal numbers 0 .. n-1 together."""
    total, width, low = 0, 1, 0
    while low < n:
        high = min(n, 10**width)
        total += (high - low) * width
        low, width = high, width + 1
    return total


def _size(n: float) -> str:
    for unit in ("B", "kB", "MB", "GB", "TB", "PB"):
        if n < 1000 or unit == "PB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000
    return f"{n:.1f} PB"


_METADATA_KEYS = {"fingerprint": str, "canonical": dict, "columns": list, "runs": list, "total_trials": int}


def _read_metadata(out: Path) -> dict[str, Any] | None:
    """The metadata of the sweep in ``out``; None where ``out`` holds no sweep yet."""
    if out.exists() and not out.is_dir():
        raise UserError(f"--out {out} is not a directory")
    path = out / _METADATA
    if not path.exists():
        # An empty parts/ is what a run killed before its first write leaves behind.
        if (out / _RESULTS).exists() or _named_parts(out / _PARTS):
            raise UserError(f"{out} holds {_RESULTS} or {_PARTS}/ but no {_METADATA}: choose another --out directory")
        return None
    try:
        metadata = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as err:
        reason = str(err).splitlines()[0] if str(err).strip() else type(err).__name__
        raise UserError(f"cannot read {path}: {reason}") from None
    if not isinstance(metadata, dict) or metadata.get("format") != _METADATA_FORMAT:
        raise UserError(f"{path} is not the metadata of a spikejax sweep: choose another --out directory")
    for key, kind in _METADATA_KEYS.items():
        if not isinstance(metadata.get(key), kind):
            raise UserError(f"{path} is damaged: '{key}' is missing or not a {kind.__name__}")
    columns = metadata["columns"]
    if not all(isinstance(c, list) and len(c) == 2 and all(isinstance(x, str) for x in c) for c in columns) or not all(
        isinstance(run, dict) for run in metadata["runs"]
    ):
        raise UserError(f"{path} is damaged: its columns or runs are not as a sweep writes them")
    try:
        for _, dtype in columns:
            np.dtype(dtype)
    except TypeError:
        raise UserError(f"{path} is damaged: a column has no numpy dtype") from None
    return metadata


def _check_same_sweep(out: Path, spec: SweepSpec, metadata: Mapping[str, Any]) -> None:
    if metadata.get("fingerprint") in (spec.fingerprint, spec.legacy_fingerprint):
        return
    old, new = metadata.get("canonical", {}), spec.canonical

    def section(canonical: Any, name: str) -> dict[str, Any]:
        value = canonical.get(name, {}) if isinstance(canonical, dict) else {}
        if name == "grid" and isinstance(value, list):
            value = {axis[0]: axis[1] for axis in value if isinstance(axis, list) and len(axis) == 2}
        return value if isinstance(value, dict) else {}

    def shown(values: dict[str, Any], key: str) -> str:
        return repr(values[key]) if key in values else "not set"

    differences = []
    for name in ("sweep", "fixed", "grid"):
        before, now = section(old, name), section(new, name)
        for key in [*now, *(key for key in before if key not in now)]:
            if before.get(key, ...) != now.get(key, ...):
                differences.append(f"[{name}] {key} is {shown(before, key)} there, {shown(now, key)} here")
    if not differences and list(section(old, "grid")) != list(section(new, "grid")):
        differences.append("[grid] has its axes in another order")
    raise UserError(
        f"{out} holds the results of a different sweep ({'; '.join(differences) or 'fingerprints differ'}): "
        f"choose another --out directory, or delete {out} to start over"
    )


def _json_safe(value: Any) -> Any:
    return json.loads(json.dumps(value, default=str))


def _new_metadata(spec: SweepSpec, columns: list[Column]) -> dict[str, Any]:
    return {
        "format": _METADATA_FORMAT,
        "name": spec.name,
        "fingerprint": spec.fingerprint,
        "canonical": spec.canonical,
        "sweep_file": str(spec.path.resolve()),
        "sweep_text": spec.text,
        "sweep": _json_safe(spec.document),
        "columns": [list(column) for column in columns],
        "total_trials": spec.n_trials,
        "done_trials": 0,
        "started": _now(),
        "finished": None,
        "nan_trials": [],
        "nonfinite_trials": [],
        "runs": [],
    }


def _environment() -> dict[str, Any]:
    from spikejax import __version__

    versions = {"spikejax": __version__, "python": sys.version.split()[0]}
    for package in ("jax", "jaxlib", "numpy"):
        try:
            versions[package] = importlib.metadata.version(package)
        except importlib.metadata.PackageNotFoundError:
            versions[package] = None
    return {
        "versions": versions,
        "git_commit": _git_commit(),
        "backend": jax.default_backend(),
        "devices": [str(device) for device in jax.devices()],
    }


def _git_commit() -> str | None:
    """The commit of the working tree that holds spikejax, with ``+dirty`` if it has changes."""
    where = Path(__file__).resolve().parent
    try:
        head = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=where, capture_output=True, text=True, timeout=10, check=True
        ).stdout.strip()
        changes = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=where,
            capture_output=True,
            text=True,
            timeout=10,
            check=True,
        ).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return None
    return f"{head}+dirty" if changes else head


def _write_metadata(out: Path, metadata: Mapping[str, Any]) -> None:
    with _atomic_file(out / _METADATA) as file:
        file.write((json.dumps(metadata, indent=2, default=str) + "\n").encode())


def _check_same_devices(out: Path, metadata: Mapping[str, Any], have: int | None = None) -> None:
    """A table is finished on as many devices as it was started on (see "Resuming" above).

    ``have``: the devices a chunk is split over (None: ``jax.device_count()``; a Ray run's
    tasks use one each).
    """
    used = {run.get("devices", 1) for run in metadata["runs"] if run.get("computed_trials")}
    have = jax.device_count() if have is None else have
    if used and used != {have}:
        raise UserError(
            f"{out} was computed on {', '.join(map(str, sorted(used)))} device(s) and JAX presents {have}: "
            f"resume it where JAX presents {min(used)} (on a CPU: --cpu-devices {min(used)}), as a split program "
            "can differ in the last bits"
        )


def results_path(out: Path) -> Path:
    """The table of the output directory ``out``."""
    return out / _RESULTS


def existing(out: Path, spec: SweepSpec, devices: int | None = None) -> tuple[dict[str, Any] | None, bool]:
    """What ``out`` holds of ``spec``: its metadata (None: nothing yet), and whether trials are missing.

    ``devices`` is the number of devices this run splits a chunk over (None: ``jax.device_count()``).

    Raises:
        UserError: ``out`` is not a directory, holds another sweep or files of no
            sweep, holds a part that does not fit, or is to be resumed on another
            number of devices than it was computed on.
    """
    check_out(out)
    metadata = _read_metadata(out)
    if metadata is not None:
        _check_same_sweep(out, spec, metadata)
    columns = recorded_columns(metadata) if metadata is not None else None
    missing = _missing_ranges(_scan_parts(out / _PARTS, spec.n_trials, columns), spec.n_trials)
    if metadata is not None and missing:
        _check_same_devices(out, metadata, devices)
    return metadata, bool(missing)


def recorded_columns(metadata: Mapping[str, Any]) -> list[Column]:
    """The columns of the table, as the metadata records them."""
    return [Column(*column) for column in metadata["columns"]]


def check_columns(out: Path, metadata: Mapping[str, Any] | None, columns: list[Column]) -> None:
    """Raises a UserError if ``out`` holds a table with other ``columns``."""
    if metadata is not None and [list(column) for column in columns] != metadata["columns"]:
        raise UserError(
            f"{out} holds results with other columns than the trial now returns: "
            f"choose another --out directory, or delete {out} to start over"
        )


class Store:
    """The parts on disk, and the table and metadata published from them, during one run.

    Attributes:
        out: the output directory.
        n_trials: the rows of the finished table.
        metadata: what ``metadata.json`` holds.
        run: this run's record, the last of ``metadata["runs"]``.
    """

    def __init__(self, out: Path, n_trials: int, header: str, parts: list[_Part], metadata: dict[str, Any]):
        self.out = out
        self.n_trials = n_trials
        self.metadata = metadata
        self.run = metadata["runs"][-1]
        self._header = header
        self._parts = parts
        self._publish_cost = 0.0
        self._last_published = -math.inf
        self._table_checked = False

    @property
    def done(self) -> int:
        """The trials in the parts."""
        return sum(part.end - part.start for part in self._parts)

    @property
    def metadata_path(self) -> Path:
        """The path of ``metadata.json``."""
        return self.out / _METADATA

    def missing(self) -> list[tuple[int, int]]:
        """The ranges ``(start, end)`` of the trials no part holds, in trial order."""
        return _missing_ranges(self._parts, self.n_trials)

    def begin_compute(self, devices: int) -> None:
        """Records that this run computes trials, split over ``devices`` devices."""
        self.run["devices"] = devices
        self.run["compile_seconds"] = 0.0

    def add_compile_seconds(self, seconds: float) -> None:
        """Adds ``seconds`` spent compiling to this run's record."""
        self.run["compile_seconds"] = round(self.run["compile_seconds"] + seconds, 3)

    def add(self, start: int, end: int, cells: list[list[str]]) -> None:
        """Writes the rows ``start .. end-1`` (their cells, column by column) as a part."""
        self._parts.append(_write_part(self.out / _PARTS, start, end, _rows(cells)))
        # Rebuilding the table costs O(rows so far): do it only as often as costs a tenth of the time.
        if time.perf_counter() - self._last_published >= self._publish_cost / _PUBLISH_SHARE:
            self.publish()
        self.run["computed_trials"] += end - start

    def publish(self) -> None:
        """Rebuilds ``results.csv`` from the parts (where it is not whole) and writes ``metadata.json``."""
        began = time.perf_counter()
        results = self.out / _RESULTS
        if not self._table_checked:
            # The first time in a run, the table is checked byte for byte against the parts.
            if (self._parts or results.exists()) and not _table_is_whole(self.out, self._header, self._parts):
                _write_table(self.out, self._header, self._parts)
            self._table_checked = True
        elif self._parts and (not results.exists() or results.stat().st_size != _table_size(self._header, self._parts)):
            _write_table(self.out, self._header, self._parts)
        self.metadata["done_trials"] = self.done
        _write_metadata(self.out, self.metadata)
        self._last_published = time.perf_counter()
        self._publish_cost = self._last_published - began

    def finish(self, columns: list[Column], first_result: int) -> tuple[list[int], list[int]]:
        """Records the finished table and its non-finite results, publishes.

        Returns:
            The trials with a NaN result, and the trials with a NaN or infinite
            result or the ``nonfinite`` flag set (as ``metadata.json`` records them,
            ``nan_trials`` and ``nonfinite_trials``).
        """
        nan_trials, nonfinite = _nonfinite_trials(self.out / _RESULTS, columns, first_result)
        self.metadata["nan_trials"] = nan_trials
        self.metadata["nonfinite_trials"] = nonfinite
        self.run["finished"] = _now()
        self.metadata["finished"] = self.metadata.get("finished") or _now()
        self.publish()
        return nan_trials, nonfinite


@contextlib.contextmanager
def opened(
    out: Path, spec: SweepSpec, metadata: dict[str, Any] | None, columns: list[Column], chunk_size: int
) -> Iterator[Store]:
    """``out`` locked for one run of ``spec``, with the run recorded in its metadata and published.

    Args:
        out: the output directory; created if missing.
        spec: the sweep.
        metadata: what `existing` found (None: a new sweep).
        columns: the table's columns.
        chunk_size: the run's chunk size, for its record.

    Raises:
        UserError: another run holds ``out``.
    """
    try:
        (out / _PARTS).mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise UserError(f"cannot create --out {out}: {err.strerror or err}") from None
    with _locked(out):
        _remove_temporaries(out, out / _PARTS)
        parts = _scan_parts(out / _PARTS, spec.n_trials, columns, set_aside=True)
        metadata = metadata or _new_metadata(spec, columns)
        environment = _environment()
        metadata.update(environment)
        run = {"started": _now(), "finished": None, "chunk_size": chunk_size, "computed_trials": 0}
        run.update(environment)
        metadata["runs"].append(run)
        store = Store(out, spec.n_trials, _header(columns), parts, metadata)
        store.publish()
        yield store


def read_results(out_dir: str | os.PathLike[str]) -> dict[str, np.ndarray]:
    """The table of a sweep's output directory, one array per column.

    Args:
        out_dir: the directory given to `spikejax.sweep.run_sweep` (``--out``).

    Returns:
        Column name -> array of the finished rows in trial order, with the
        columns' dtypes (``trial`` and ``seed`` int64; grid axes int64, float64 or
        bool; results as the trial returns them, floats as float32 or float64).

    Raises:
        UserError: ``out_dir`` holds no sweep results, or a table that is not as
            the engine writes it: a cell of another form (``TRUE`` for ``true``),
            a row with too few or too many cells, rows out of order, or, for a
            finished sweep, another number of rows than it has trials (the message names the
            file, and the line and column where there is one).

    Example:
        >>> table = read_results("out/gaits")                  # doctest: +SKIP
        >>> table["converged"][table["n_gaits"] == 3].mean()   # doctest: +SKIP
    """
    out = Path(out_dir)
    metadata = _read_metadata(out)
    if metadata is None or not (out / _RESULTS).exists():
        raise UserError(f"no sweep results in {out}")
    columns = recorded_columns(metadata)
    path = out / _RESULTS
    try:
        with open(path, newline="", encoding="utf-8") as file:
            reader = csv.reader(file)
            header = next(reader, None)
            rows = list(reader)
    except (OSError, UnicodeDecodeError, csv.Error) as err:
        raise UserError(f"cannot read {path}: {err}") from None
    if header != [column.name for column in columns]:
        raise UserError(f"{path} does not have the columns of {out / _METADATA}")
    for line, row in enumerate(rows, start=2):
        if len(row) != len(columns):
            raise UserError(f"{path}, line {line}: {len(row)} cells, the table has {len(columns)} columns")
    texts = list(zip(*rows)) if rows else [() for _ in columns]
    table = {}
    for column, column_texts in zip(columns, texts):
        try:
            table[column.name] = parse_column(column_texts, column.dtype)
        except UserError:
            line = next(i for i, text in enumerate(column_texts, start=2) if bad_cell(text, column.dtype))
            text = column_texts[line - 2]
            raise UserError(
                f"{path}, line {line}, column {column.name}: {text!r} is {bad_cell(text, column.dtype)} "
                "(the table holds only what the engine writes)"
            ) from None
    # A finished table has every row; one being written (or stopped by a full disk between its two
    # files) holds the rows done so far, each checked above.
    done = metadata.get("done_trials")
    if done == metadata["total_trials"] and len(rows) != done:
        raise UserError(
            f"{path} holds {len(rows)} rows and {out / _METADATA} says {done} trials are done: "
            "run the sweep again to rebuild the table from its parts"
        )
    if len(rows) > 1 and not np.all(np.diff(table["trial"]) > 0):
        line = int(np.argmax(np.diff(table["trial"]) <= 0)) + 3
        raise UserError(f"{path}, line {line}: the trials are not in order (the engine writes them in trial order)")
    return table
