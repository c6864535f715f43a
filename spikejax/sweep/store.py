"""A sweep's output directory: the one place that knows the files, their names and their layout.

The output directory holds::

    results.csv          the table: a header, then the finished rows in trial order
    metadata.json        the sweep file (text and parsed), its fingerprint, the
                         columns, versions, git commit, devices, times, trials done
    parts/rows-S-E.csv   the rows S .. E-1 of one chunk, without a header
    .lock                locked while a run is going on

A row is its cells (`spikejax.sweep.table`) joined by commas, ended by a
newline; the header is written by ``csv``. Nothing is ever half-written:
every file is written to a temporary file in its directory, flushed, fsync'ed
and renamed over its name (``os.replace``). A chunk's part is written as soon
as the chunk is done; ``results.csv`` and ``metadata.json`` are rebuilt from the
parts during the run (as often as costs at most a tenth of the run time) and
at the end.

Resuming. The same sweep, run again after a run stopped however it stopped
(SIGKILL included), skips the trials in the parts and runs the others, with
any chunk size; the final ``results.csv`` is byte for byte the one of an
uninterrupted run. It must run on as many devices as the first run did (each
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
import importlib.metadata
import io
import itertools
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
from typing import Any, BinaryIO, NamedTuple

import jax
import numpy as np

from spikejax.errors import UserError
from spikejax.sweep.spec import SweepSpec
from spikejax.sweep.table import NAN, Column, parse_column

__all__ = ["Store", "check_columns", "existing", "opened", "read_results", "recorded_columns", "results_path"]

_RESULTS = "results.csv"
_METADATA = "metadata.json"
_PARTS = "parts"
_LOCK = ".lock"
_PART_NAME = re.compile(r"rows-(\d+)-(\d+)\.csv")
_METADATA_FORMAT = 1
_PUBLISH_SHARE = 0.1


_temporary_names = itertools.count()


@contextlib.contextmanager
def _atomic_file(path: Path) -> Iterator[BinaryIO]:
    """Write ``path`` whole or not at all: temporary file, fsync, rename."""
    temporary = path.parent / f".{path.name}.{os.getpid()}.{next(_temporary_names)}.tmp"
    try:
        with open(temporary, "xb") as file:
            yield file
            file.flush()
            os.fsync(file.fileno())
        os.replace(temporary, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(temporary)
        raise
    _fsync_directory(path.parent)


def _fsync_directory(directory: Path) -> None:
    # The rename is durable only once the directory entry is; not every OS can open one.
    with contextlib.suppress(OSError, AttributeError):
        fd = os.open(directory, os.O_RDONLY | os.O_DIRECTORY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


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


def _scan_parts(parts_dir: Path, n_trials: float) -> list[_Part]:
    """The finished chunks, in trial order."""
    if not parts_dir.is_dir():
        return []
    parts = []
    for path in parts_dir.iterdir():
        match = _PART_NAME.fullmatch(path.name)
        if match:
            parts.append(_Part(int(match[1]), int(match[2]), path))
    parts.sort()
    previous_end = 0
    for part in parts:
        if part.start < previous_end or part.end <= part.start or part.end > n_trials:
            raise UserError(f"{parts_dir} holds a part that does not fit this sweep: {part.path.name}")
        previous_end = part.end
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
    path = parts_dir / f"rows-{start:09d}-{end:09d}.csv"
    with _atomic_file(path) as file:
        file.write(rows.encode())
    return _Part(start, end, path)


def _table_size(header: str, parts: list[_Part]) -> int:
    return len(header.encode()) + sum(part.path.stat().st_size for part in parts)


def _write_table(out: Path, header: str, parts: list[_Part]) -> None:
    with _atomic_file(out / _RESULTS) as file:
        file.write(header.encode())
        for part in sorted(parts):
            with open(part.path, "rb") as source:
                shutil.copyfileobj(source, file)


def _nan_trials(results: Path, first_result: int) -> list[int]:
    """The trials with a NaN result, read off the table."""
    nan = NAN.encode()
    trials = []
    with open(results, "rb") as file:
        next(file)
        for line in file:
            if nan in line:
                cells = line.rstrip(b"\n").split(b",")
                if nan in cells[first_result:]:
                    trials.append(int(cells[0]))
    return trials


def _header(columns: list[Column]) -> str:
    buffer = io.StringIO()
    csv.writer(buffer, lineterminator="\n").writerow(column.name for column in columns)
    return buffer.getvalue()


def _rows(cells: list[list[str]]) -> str:
    return "".join(",".join(row) + "\n" for row in zip(*cells))


def _now() -> str:
    return datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")


def _read_metadata(out: Path) -> dict[str, Any] | None:
    """The metadata of the sweep in ``out``; None where ``out`` holds no sweep yet."""
    if out.exists() and not out.is_dir():
        raise UserError(f"--out {out} is not a directory")
    path = out / _METADATA
    if not path.exists():
        # An empty parts/ is what a run killed before its first write leaves behind.
        if (out / _RESULTS).exists() or _scan_parts(out / _PARTS, math.inf):
            raise UserError(f"{out} holds {_RESULTS} or {_PARTS}/ but no {_METADATA}: choose another --out directory")
        return None
    try:
        metadata = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as err:
        raise UserError(f"cannot read {path}: {err}") from None
    if not isinstance(metadata, dict) or metadata.get("format") != _METADATA_FORMAT:
        raise UserError(f"{path} is not the metadata of a spikejax sweep: choose another --out directory")
    return metadata


def _check_same_sweep(out: Path, spec: SweepSpec, metadata: Mapping[str, Any]) -> None:
    if metadata.get("fingerprint") == spec.fingerprint:
        return
    old, new = metadata.get("canonical", {}), spec.canonical
    differences = [
        f"[sweep] {key} is {old.get('sweep', {}).get(key)!r} there, {new['sweep'][key]!r} here"
        for key in new["sweep"]
        if old.get("sweep", {}).get(key) != new["sweep"][key]
    ]
    differences += [f"[{section}] differs" for section in ("fixed", "grid") if old.get(section) != new[section]]
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


def _check_same_devices(out: Path, metadata: Mapping[str, Any]) -> None:
    """A table is finished on as many devices as it was started on (see "Resuming" above)."""
    used = {run.get("devices", 1) for run in metadata["runs"] if run.get("computed_trials")}
    have = jax.device_count()
    if used and used != {have}:
        raise UserError(
            f"{out} was computed on {', '.join(map(str, sorted(used)))} device(s) and JAX presents {have}: "
            f"resume it where JAX presents {min(used)} (on a CPU: --cpu-devices {min(used)}), as a split program "
            "can differ in the last bits"
        )


def results_path(out: Path) -> Path:
    """The table of the output directory ``out``."""
    return out / _RESULTS


def existing(out: Path, spec: SweepSpec) -> tuple[dict[str, Any] | None, bool]:
    """What ``out`` holds of ``spec``: its metadata (None: nothing yet), and whether trials are missing.

    Raises:
        UserError: ``out`` is not a directory, holds another sweep or files of no
            sweep, holds a part that does not fit, or is to be resumed on another
            number of devices than it was computed on.
    """
    metadata = _read_metadata(out)
    if metadata is not None:
        _check_same_sweep(out, spec, metadata)
    missing = _missing_ranges(_scan_parts(out / _PARTS, spec.n_trials), spec.n_trials)
    if metadata is not None and missing:
        _check_same_devices(out, metadata)
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
        if self._parts and (not results.exists() or results.stat().st_size != _table_size(self._header, self._parts)):
            _write_table(self.out, self._header, self._parts)
        self.metadata["done_trials"] = self.done
        _write_metadata(self.out, self.metadata)
        self._last_published = time.perf_counter()
        self._publish_cost = self._last_published - began

    def finish(self, first_result: int) -> list[int]:
        """Records the finished table and its NaN results, publishes; returns the trials with a NaN result."""
        nan_trials = _nan_trials(self.out / _RESULTS, first_result)
        self.metadata["nan_trials"] = nan_trials
        self.run["finished"] = _now()
        self.metadata["finished"] = self.metadata["finished"] or _now()
        self.publish()
        return nan_trials


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
    (out / _PARTS).mkdir(parents=True, exist_ok=True)
    with _locked(out):
        _remove_temporaries(out, out / _PARTS)
        parts = _scan_parts(out / _PARTS, spec.n_trials)
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
        UserError: ``out_dir`` holds no sweep results.

    Example:
        >>> table = read_results("out/gaits")                  # doctest: +SKIP
        >>> table["converged"][table["n_gaits"] == 3].mean()   # doctest: +SKIP
    """
    out = Path(out_dir)
    metadata = _read_metadata(out)
    if metadata is None or not (out / _RESULTS).exists():
        raise UserError(f"no sweep results in {out}")
    columns = recorded_columns(metadata)
    with open(out / _RESULTS, newline="", encoding="utf-8") as file:
        reader = csv.reader(file)
        header = next(reader)
        rows = list(reader)
    if header != [column.name for column in columns]:
        raise UserError(f"{out / _RESULTS} does not have the columns of {out / _METADATA}")
    texts = list(zip(*rows)) if rows else [() for _ in columns]
    return {column.name: parse_column(column_texts, column.dtype) for column, column_texts in zip(columns, texts)}
