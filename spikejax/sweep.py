"""Sweeps: a grid of trial parameters times a range of seeds, run chunk by chunk.

A sweep file (TOML) names a trial function, the values it holds fixed, a grid of
values and a number of seeds. ``spikejax sweep FILE --out DIR`` (or
:func:`load_sweep` then :func:`run_sweep`) runs every trial of the grid times the
seeds and writes one row per trial to ``DIR/results.csv``::

    [sweep]
    name = "gait_convergence"
    trial = "robots.hexapod.trial:convergence_trial"   # "module:function"
    seeds = 1000           # seeds 0 .. seeds-1 at every grid point
    base_seed = 0          # optional, default 0; 0 <= base_seed < 2**32
    chunk_size = 4096      # optional, default 1024: trials per compiled batch

    [fixed]                # optional: the same in every trial
    steps_per_gait = 100

    [grid]                 # full cartesian product of the axes, in file order
    n_gaits = [1, 2, 3]

A trial function runs one trial; the engine adds the batch with ``jax.vmap``::

    class GaitParams(NamedTuple):       # traced parameters, each a scalar
        n_gaits: int = 3
        alpha: float = 2.0

    class GaitResult(NamedTuple):       # scalar results: the table's columns
        converged: jax.Array
        iterations: jax.Array

    def convergence_trial(params: GaitParams, key: jax.Array, *,
                          steps_per_gait: int = 100) -> GaitResult: ...

The first parameter's annotation names the params NamedTuple. A ``[grid]`` key
is one of its fields (traced: one compiled program serves every value) or a
keyword-only parameter of the function (static: the engine compiles one
program per combination of the static axes' values, so they may shape the
program, e.g. the size of a network). A ``[fixed]`` key is either a field (passed as a traced
value, the same in every trial) or a keyword-only parameter of the function
(passed as a static Python value, which may shape the program). The other fields
take their defaults. Fields are passed as int32, float32 or bool arrays: by their
annotation where it is ``int``, ``float`` or ``bool``, else by the type of the
value. The function returns a NamedTuple (or a dict) of scalars.

Example:
    >>> spec = load_sweep("sweeps/gaits.toml", seeds=10)      # doctest: +SKIP
    >>> table = read_results(run_sweep(spec, "out/gaits").parent)  # doctest: +SKIP
    >>> table["converged"].mean()                              # doctest: +SKIP

Notes:
    Rows and keys. Trials are numbered ``trial = point * seeds + seed``: ``point``
    counts the grid points in the order of ``itertools.product`` over the axes in
    file order (the last axis fastest), and ``seed`` runs over ``0 .. seeds-1``.
    A trial's key is :func:`trial_key`, ``jax.random.fold_in(jax.random.key(
    base_seed), seed)``. It depends on the seed alone: every grid point sees the
    same random numbers for the same seed (common random numbers, which make the
    differences between grid points less noisy), and no trial depends on the
    chunk size or on the other trials of its batch.

    Columns: ``trial``, ``seed``, the grid axes in file order, then the result
    fields in the order the trial returns them. Integers are written in decimal,
    booleans as ``true``/``false``, floats as the shortest decimal that reads
    back to the same value of the column's dtype (``nan``, ``inf`` included).

    The output directory holds::

        results.csv          the table: a header, then the finished rows in trial order
        metadata.json        the sweep file (text and parsed), its fingerprint, the
                             columns, versions, git commit, devices, times, trials done
        parts/rows-S-E.csv   the rows S .. E-1 of one chunk, without a header
        .lock                locked while a run is going on

    Nothing is ever half-written: every file is written to a temporary file in
    its directory, flushed, fsync'ed and renamed over its name (``os.replace``).
    A chunk's part is written as soon as the chunk is done; ``results.csv`` and
    ``metadata.json`` are rebuilt from the parts during the run (as often as
    costs at most a tenth of the run time) and at the end.

    Resuming. The same command, run again after a run stopped however it stopped
    (SIGKILL included), skips the trials in the parts and runs the others, with
    any chunk size; the final ``results.csv`` is byte for byte the one of an
    uninterrupted run. It must run on as many devices as the first run did
    (each run's count is in ``metadata.json``): a chunk split over devices is
    compiled apart and can differ in the last bits. The sweep's fingerprint, a hash of ``[sweep]``, ``[fixed]``
    and ``[grid]`` as parsed (seeds as overridden, chunk size left out), keeps the
    results of another sweep out of a directory. Resuming assumes that the trial's
    code is the same; ``metadata.json`` records each run's git commit.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import dataclasses
import datetime
import functools
import hashlib
import importlib
import importlib.metadata
import inspect
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
import tomllib
import typing
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import Any, BinaryIO, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from tqdm import tqdm

from spikejax.devices import cpu_devices_for_run
from spikejax.errors import UserError

__all__ = [
    "Axis",
    "SweepSpec",
    "load_sweep",
    "main",
    "read_results",
    "run_sweep",
    "trial_key",
]

_SECTIONS = ("sweep", "fixed", "grid")
_SWEEP_KEYS = ("name", "trial", "seeds", "base_seed", "chunk_size")
_REQUIRED_SWEEP_KEYS = ("name", "trial", "seeds")
_DEFAULT_CHUNK_SIZE = 1024
# Seeds are passed to the compiled batch as int32.
_MAX_SEEDS = 2**31 - 1
# jax.random.key(s) keeps only the low 32 bits of s: larger base seeds would repeat keys.
_MAX_BASE_SEED = 2**32 - 1
_INT32_MIN, _INT32_MAX = -(2**31), 2**31 - 1
_KIND_DTYPES = {"bool": np.dtype(np.bool_), "int": np.dtype(np.int32), "float": np.dtype(np.float32)}
# Grid values are written as the file gives them, so the table keeps Python's precision.
_AXIS_TABLE_DTYPES = {"bool": "bool", "int": "int64", "float": "float64"}
_TRIAL_PATH = re.compile(r"[A-Za-z_]\w*(\.[A-Za-z_]\w*)*:[A-Za-z_]\w*(\.[A-Za-z_]\w*)*")

_RESULTS = "results.csv"
_METADATA = "metadata.json"
_PARTS = "parts"
_LOCK = ".lock"
_PART_NAME = re.compile(r"rows-(\d+)-(\d+)\.csv")
_METADATA_FORMAT = 1
_PUBLISH_SHARE = 0.1
_NAN_TRIALS_LISTED = 20


# --------------------------------------------------------------------------- spec


class Axis(NamedTuple):
    """One axis of a sweep's grid.

    Attributes:
        name: the params field it sweeps.
        values: the values as the sweep file gives them.
        kind: ``"bool"``, ``"int"`` or ``"float"``: the trial receives them as
            bool, int32 or float32 (traced axes), or as Python values (static axes).
        static: the axis is a keyword-only parameter of the trial, passed as a
            Python value; each combination of static values is compiled apart.
    """

    name: str
    values: tuple[bool | int | float, ...]
    kind: str
    static: bool = False

    def array(self) -> np.ndarray:
        """The values as the trial receives them, shape ``(len(values),)``."""
        return np.asarray(self.values, dtype=_KIND_DTYPES[self.kind])


@dataclasses.dataclass(frozen=True, eq=False)
class SweepSpec:
    """A validated sweep: what :func:`load_sweep` returns and :func:`run_sweep` runs.

    Attributes:
        path: the sweep file.
        text: the sweep file's text.
        document: the sweep file as parsed.
        name: ``[sweep] name``.
        trial_path: ``[sweep] trial``, ``"module:function"``.
        seeds: seeds per grid point (the file's, or the override).
        base_seed: the root of every trial's key (see :func:`trial_key`).
        chunk_size: trials per compiled batch (the file's, or the override).
        trial: the trial function.
        params_type: the NamedTuple class of the trial's traced parameters.
        axes: the grid, in file order.
        traced: the params fields off the grid (from ``[fixed]`` or their
            defaults), as the arrays the trial receives.
        static: the keyword-only arguments from ``[fixed]``.
    """

    path: Path
    text: str
    document: Mapping[str, Any]
    name: str
    trial_path: str
    seeds: int
    base_seed: int
    chunk_size: int
    trial: Callable[..., Any]
    params_type: type
    axes: tuple[Axis, ...]
    traced: Mapping[str, np.ndarray]
    static: Mapping[str, Any]

    @property
    def grid_shape(self) -> tuple[int, ...]:
        """The number of values on each axis."""
        return tuple(len(axis.values) for axis in self.axes)

    @property
    def n_trials(self) -> int:
        """The number of rows of the table: grid points times seeds."""
        return math.prod(self.grid_shape) * self.seeds

    @property
    def canonical(self) -> dict[str, Any]:
        """What defines the trials: ``[sweep]`` (chunk size left out), ``[fixed]``, ``[grid]``.

        The form is the one JSON gives back, so that it compares equal to the copy
        in ``metadata.json``.
        """
        canonical = {
            "sweep": {
                "name": self.name,
                "trial": self.trial_path,
                "seeds": self.seeds,
                "base_seed": self.base_seed,
            },
            "fixed": dict(self.document.get("fixed", {})),
            "grid": [[axis.name, list(axis.values)] for axis in self.axes],
        }
        return json.loads(_canonical_json(canonical))

    @property
    def fingerprint(self) -> str:
        """SHA-256 of :attr:`canonical`: equal fingerprints, equal trials."""
        return hashlib.sha256(_canonical_json(self.canonical).encode()).hexdigest()


def _canonical_json(value: Any) -> str:
    return json.dumps(value, sort_keys=True, separators=(",", ":"), default=str)


def trial_key(base_seed: int, seed: int | jax.Array) -> jax.Array:
    """The key of the trials of seed ``seed``, at every grid point.

    Args:
        base_seed: the sweep's ``base_seed``, ``0 <= base_seed < 2**32``.
        seed: the seed number, ``0 .. seeds-1`` (an int or an int32 array).

    Returns:
        ``jax.random.fold_in(jax.random.key(base_seed), seed)``, a typed key.

    Example:
        >>> u = jax.random.uniform(trial_key(0, 3))  # the draw of seed 3, anywhere
    """
    return jax.random.fold_in(jax.random.key(base_seed), seed)


def load_sweep(
    path: str | os.PathLike[str],
    seeds: int | None = None,
    chunk_size: int | None = None,
) -> SweepSpec:
    """Read and validate a sweep file; compile nothing.

    Args:
        path: the sweep file (TOML, see the module's docstring).
        seeds: overrides ``[sweep] seeds`` when given.
        chunk_size: overrides ``[sweep] chunk_size`` when given.

    Returns:
        The validated sweep, with its trial function imported.

    Raises:
        UserError: the file is missing or not valid TOML, a section or key is
            unknown or missing, a value has the wrong type, the trial cannot be
            imported or does not follow the trial contract, or the grid does not
            fit the trial's params. The message names the problem in one line.
    """
    _check_int(seeds, "--seeds", 1, _MAX_SEEDS, optional=True)
    _check_int(chunk_size, "--chunk-size", 1, None, optional=True)
    path = Path(path)
    text = _read_text(path)
    try:
        document = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise UserError(f"{path}: invalid TOML: {err}") from None
    try:
        return _build_spec(path, text, document, seeds, chunk_size)
    except UserError as err:
        raise UserError(f"{path}: {err}") from None


def _read_text(path: Path) -> str:
    try:
        return path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise UserError(f"sweep file not found: {path}") from None
    except IsADirectoryError:
        raise UserError(f"sweep file is a directory: {path}") from None
    except UnicodeDecodeError as err:
        raise UserError(f"{path}: not UTF-8 text: {err}") from None
    except OSError as err:
        raise UserError(f"cannot read sweep file {path}: {err.strerror}") from None


def _build_spec(
    path: Path,
    text: str,
    document: dict[str, Any],
    seeds: int | None,
    chunk_size: int | None,
) -> SweepSpec:
    _check_sections(document)
    sweep = document["sweep"]
    _check_known_keys(sweep, _SWEEP_KEYS, "[sweep]")
    for key in _REQUIRED_SWEEP_KEYS:
        if key not in sweep:
            raise UserError(f"missing key '{key}' in [sweep]")
    name = sweep["name"]
    if not isinstance(name, str) or not name:
        raise UserError(f"[sweep] name must be a non-empty string, got {name!r}")
    trial_path = sweep["trial"]
    if not isinstance(trial_path, str) or not _TRIAL_PATH.fullmatch(trial_path):
        raise UserError(f"[sweep] trial must be a string \"module:function\", got {trial_path!r}")
    file_seeds = _check_int(sweep["seeds"], "[sweep] seeds", 1, _MAX_SEEDS)
    base_seed = _check_int(sweep.get("base_seed", 0), "[sweep] base_seed", 0, _MAX_BASE_SEED)
    file_chunk_size = _check_int(sweep.get("chunk_size", _DEFAULT_CHUNK_SIZE), "[sweep] chunk_size", 1, None)
    grid = _check_grid(document["grid"])
    fixed = document.get("fixed", {})

    trial = _import_trial(trial_path)
    params_type, keyword_only, takes_any_keyword = _trial_signature(trial, trial_path)
    field_kinds = _declared_kinds(params_type)
    fields = params_type._fields
    axes = []
    for key, values in grid.items():
        if key in fields and key in keyword_only:
            raise UserError(
                f"[grid] '{key}' is both a field of {params_type.__name__} and a keyword-only parameter of {trial_path}"
            )
        if key in fields:
            axes.append(Axis(key, tuple(values), _field_kind(field_kinds[key], values, "[grid]", key, params_type)))
        elif key in keyword_only or takes_any_keyword:
            axes.append(Axis(key, tuple(values), _value_kind(values, f"[grid] {key}"), static=True))
        else:
            raise UserError(
                f"[grid] key '{key}' is neither a field of {params_type.__name__} "
                f"(fields: {', '.join(fields) or 'none'}) nor a keyword-only parameter of {trial_path} "
                f"(keyword-only: {', '.join(keyword_only) or 'none'})"
            )
    axes = tuple(axes)
    traced, static = _split_fixed(fixed, grid, params_type, field_kinds, keyword_only, takes_any_keyword, trial_path)
    traced = _with_defaults(traced, grid, params_type, field_kinds)
    for name_, parameter in keyword_only.items():
        if parameter.default is inspect.Parameter.empty and name_ not in static:
            raise UserError(f"the trial {trial_path} needs the keyword-only argument '{name_}': set it in [fixed]")
    return SweepSpec(
        path=path,
        text=text,
        document=document,
        name=name,
        trial_path=trial_path,
        seeds=file_seeds if seeds is None else seeds,
        base_seed=base_seed,
        chunk_size=file_chunk_size if chunk_size is None else chunk_size,
        trial=trial,
        params_type=params_type,
        axes=axes,
        traced=traced,
        static=static,
    )


def _check_sections(document: dict[str, Any]) -> None:
    for key, value in document.items():
        if key not in _SECTIONS:
            what = f"section [{key}]" if isinstance(value, dict) else f"top-level key '{key}'"
            raise UserError(f"unknown {what} (known sections: [sweep], [fixed], [grid])")
        if not isinstance(value, dict):
            raise UserError(f"[{key}] must be a table, got {key} = {value!r}")
    for section in ("sweep", "grid"):
        if section not in document:
            raise UserError(f"missing the [{section}] section")


def _check_known_keys(table: Mapping[str, Any], known: tuple[str, ...], section: str) -> None:
    for key in table:
        if key not in known:
            raise UserError(f"unknown key '{key}' in {section} (known: {', '.join(known)})")


def _check_int(value: Any, what: str, low: int, high: int | None, optional: bool = False) -> Any:
    if value is None and optional:
        return None
    if not isinstance(value, int) or isinstance(value, bool) or value < low:
        raise UserError(f"{what} must be an integer >= {low}, got {value!r}")
    if high is not None and value > high:
        raise UserError(f"{what} must be at most {high}, got {value!r}")
    return value


def _check_grid(grid: dict[str, Any]) -> dict[str, list[Any]]:
    if not grid:
        raise UserError("[grid] is empty: give at least one axis, e.g. n = [1, 2, 3]")
    for key, values in grid.items():
        if not isinstance(values, list) or not values:
            raise UserError(f"[grid] {key} must be a non-empty list of numbers, got {values!r}")
        _value_kind(values, f"[grid] {key}")
    return grid


def _value_kind(values: list[Any], what: str) -> str:
    """``"bool"``, ``"int"`` or ``"float"``: the narrowest kind that holds all values."""
    for value in values:
        if not isinstance(value, (bool, int, float)):
            raise UserError(f"{what} must hold numbers (int, float or bool), got {value!r}")
    n_bools = sum(isinstance(value, bool) for value in values)
    if 0 < n_bools < len(values):
        raise UserError(f"{what} mixes booleans and numbers: {values!r}")
    if n_bools:
        return "bool"
    return "int" if all(isinstance(value, int) for value in values) else "float"


def _import_trial(trial_path: str) -> Callable[..., Any]:
    module_name, _, attributes = trial_path.partition(":")
    try:
        target: Any = importlib.import_module(module_name)
    except ImportError as err:
        raise UserError(f"[sweep] trial: cannot import module '{module_name}': {err}") from None
    for attribute in attributes.split("."):
        try:
            target = getattr(target, attribute)
        except AttributeError:
            raise UserError(f"[sweep] trial: module '{module_name}' has no function '{attributes}'") from None
    if not callable(target):
        raise UserError(f"[sweep] trial: {trial_path} is not a function")
    return target


def _trial_signature(
    trial: Callable[..., Any], trial_path: str
) -> tuple[type, dict[str, inspect.Parameter], bool]:
    """The params NamedTuple, the keyword-only parameters, and whether ``**kwargs`` is taken."""
    contract = "a trial is f(params: ParamsNamedTuple, key, *, static=...) -> NamedTuple of scalars"
    try:
        signature = inspect.signature(trial)
    except (TypeError, ValueError):
        raise UserError(f"the trial {trial_path} has no signature to check ({contract})") from None
    kinds = inspect.Parameter
    positional = [
        p for p in signature.parameters.values() if p.kind in (kinds.POSITIONAL_ONLY, kinds.POSITIONAL_OR_KEYWORD)
    ]
    if len(positional) < 2 or any(p.default is kinds.empty for p in positional[2:]):
        raise UserError(f"the trial {trial_path} must take two positional arguments, params and key ({contract})")
    try:
        hints = typing.get_type_hints(trial)
    except Exception as err:  # noqa: BLE001 - any failure to resolve is the user's to fix
        raise UserError(f"cannot resolve the annotations of the trial {trial_path}: {err}") from None
    params_type = hints.get(positional[0].name)
    if not _is_namedtuple_class(params_type):
        raise UserError(
            f"the first parameter '{positional[0].name}' of the trial {trial_path} must be annotated "
            f"with a NamedTuple class, got {params_type!r} ({contract})"
        )
    keyword_only = {p.name: p for p in signature.parameters.values() if p.kind is kinds.KEYWORD_ONLY}
    takes_any_keyword = any(p.kind is kinds.VAR_KEYWORD for p in signature.parameters.values())
    return params_type, keyword_only, takes_any_keyword


def _is_namedtuple_class(candidate: Any) -> bool:
    return isinstance(candidate, type) and issubclass(candidate, tuple) and hasattr(candidate, "_fields")


def _declared_kinds(params_type: type) -> dict[str, str | None]:
    """Each field's kind by its annotation: ``bool``, ``int``, ``float``, or None for others."""
    try:
        hints = typing.get_type_hints(params_type)
    except Exception as err:  # noqa: BLE001 - any failure to resolve is the user's to fix
        raise UserError(f"cannot resolve the annotations of {params_type.__name__}: {err}") from None
    by_type = {bool: "bool", int: "int", float: "float"}
    return {field: by_type.get(hints.get(field)) for field in params_type._fields}


def _field_kind(declared: str | None, values: list[Any], section: str, field: str, params_type: type) -> str:
    """The kind the trial receives ``values`` of ``field`` as: the annotation's, else the values'."""
    what = f"{section} {field}"
    shown = values if section == "[grid]" else values[0]
    kind = _value_kind(values, what)
    if declared is not None and declared != kind and (declared, kind) != ("float", "int"):
        raise UserError(
            f"{what} must hold {declared} values ({params_type.__name__}.{field} is declared {declared}), got {shown!r}"
        )
    kind = declared or kind
    if kind == "int" and not all(_INT32_MIN <= value <= _INT32_MAX for value in values):
        raise UserError(f"{what} must hold int32 values, got {shown!r}")
    return kind


def _split_fixed(
    fixed: Mapping[str, Any],
    grid: Mapping[str, Any],
    params_type: type,
    field_kinds: Mapping[str, str | None],
    keyword_only: Mapping[str, inspect.Parameter],
    takes_any_keyword: bool,
    trial_path: str,
) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """``[fixed]`` as traced params fields and static keyword arguments."""
    traced, static = {}, {}
    for key, value in fixed.items():
        if key in grid:
            raise UserError(f"'{key}' is in both [grid] and [fixed]")
        if key in params_type._fields and key in keyword_only:
            raise UserError(
                f"[fixed] '{key}' is ambiguous: both a field of {params_type.__name__} "
                f"and a keyword-only parameter of {trial_path}"
            )
        if key in params_type._fields:
            kind = _field_kind(field_kinds[key], [value], "[fixed]", key, params_type)
            traced[key] = np.asarray(value, dtype=_KIND_DTYPES[kind])
        elif key in keyword_only or takes_any_keyword:
            static[key] = value
        else:
            raise UserError(
                f"[fixed] '{key}' is neither a field of {params_type.__name__} "
                f"(fields: {', '.join(params_type._fields) or 'none'}) nor a keyword-only parameter "
                f"of {trial_path} (keyword-only: {', '.join(keyword_only) or 'none'})"
            )
    return traced, static


def _with_defaults(
    traced: dict[str, np.ndarray],
    grid: Mapping[str, Any],
    params_type: type,
    field_kinds: Mapping[str, str | None],
) -> dict[str, np.ndarray]:
    defaults = params_type._field_defaults
    for field in params_type._fields:
        if field in grid or field in traced:
            continue
        if field not in defaults:
            raise UserError(f"{params_type.__name__}.{field} has no default: set it in [grid] or [fixed]")
        default = defaults[field]
        kind = field_kinds[field]
        if kind is None and isinstance(default, (bool, int, float)):
            kind = _value_kind([default], f"the default of {params_type.__name__}.{field}")
        traced[field] = np.asarray(default, dtype=_KIND_DTYPES[kind] if kind else None)
    return traced


# ------------------------------------------------------------------------ trials


class _Column(NamedTuple):
    name: str
    dtype: str


def _key_columns(spec: SweepSpec) -> list[_Column]:
    return [_Column("trial", "int64"), _Column("seed", "int64")] + [
        _Column(axis.name, _AXIS_TABLE_DTYPES[axis.kind]) for axis in spec.axes
    ]


def _as_result_dict(result: Any, trial_path: str) -> dict[str, Any]:
    if isinstance(result, tuple) and hasattr(result, "_asdict"):
        return dict(result._asdict())
    if isinstance(result, Mapping):
        return dict(result)
    raise UserError(
        f"the trial {trial_path} must return a NamedTuple or a dict of scalars, got {type(result).__name__}"
    )


def _bound_trial(spec: SweepSpec, static_values: Mapping[str, Any]) -> Callable[[Any, jax.Array], Any]:
    static = {**spec.static, **static_values}
    return functools.partial(spec.trial, **static) if static else spec.trial


def _static_values(spec: SweepSpec, trial: int) -> dict[str, Any]:
    """The static axes' values of trial ``trial`` (empty without static axes)."""
    coords = np.unravel_index(trial // spec.seeds, spec.grid_shape)
    return {axis.name: axis.values[int(c)] for axis, c in zip(spec.axes, coords) if axis.static}


def _example_params(spec: SweepSpec) -> Any:
    values = dict(spec.traced)
    for axis in spec.axes:
        if not axis.static:
            values[axis.name] = axis.array()[0]
    return spec.params_type(**values)


def _result_columns(spec: SweepSpec) -> list[_Column]:
    """The result columns, found by tracing one trial (nothing is compiled)."""
    trial = _bound_trial(spec, _static_values(spec, 0))
    names: list[Any] = []

    def probe(params: Any, key: jax.Array) -> dict[str, Any]:
        result = _as_result_dict(trial(params, key), spec.trial_path)
        names.extend(result)  # dicts come back with sorted keys; keep the trial's order
        return result

    try:
        shapes = jax.eval_shape(probe, _example_params(spec), jax.random.key(0))
    except (ValueError, TypeError) as err:
        # A trial that validates its own arguments (a bad [fixed] choice, say) says why here.
        message = str(err).splitlines()[0] if str(err) else type(err).__name__
        raise UserError(f"the trial {spec.trial_path} rejects the sweep's values: {message}") from None
    taken = {column.name for column in _key_columns(spec)}
    columns = []
    for name in names:
        if not isinstance(name, str) or name in taken:
            raise UserError(
                f"the trial {spec.trial_path} returns a result named {name!r}, which is not a free column name"
            )
        shape = shapes[name]
        if not isinstance(shape, jax.ShapeDtypeStruct) or shape.shape != ():
            raise UserError(
                f"result '{name}' of the trial {spec.trial_path} must be a scalar, got "
                f"{getattr(shape, 'shape', type(shape).__name__)}"
            )
        columns.append(_Column(name, _table_dtype(shape.dtype, name, spec.trial_path)))
        taken.add(name)
    if not columns:
        raise UserError(f"the trial {spec.trial_path} returns no results")
    return columns


def _table_dtype(dtype: np.dtype, name: str, trial_path: str) -> str:
    if dtype == np.bool_ or jnp.issubdtype(dtype, jnp.integer):
        return np.dtype(dtype).name
    if jnp.issubdtype(dtype, jnp.floating):
        return "float64" if dtype == np.float64 else "float32"
    raise UserError(
        f"result '{name}' of the trial {trial_path} must be a bool, an integer or a real float, got {dtype}"
    )


def _compile(
    spec: SweepSpec, results: list[_Column], size: int, static_values: Mapping[str, Any], devices: list[Any]
) -> Callable[..., tuple[jax.Array, ...]]:
    """The trial, vmapped over ``size`` trials and compiled once for these static values.

    With several ``devices`` each takes an equal share of the chunk
    (``jax.shard_map`` over the trial axis; ``size`` is a multiple of their
    number). Each trial is computed alone either way, but XLA compiles the
    split program apart, and a chaotic trial can come out a rounding
    different: the RoboBee learning flights changed in 16 of 144 rows between
    one and two CPU devices (the toy trials of the tests do not). So a table
    is only resumed on as many devices as it was started on (`run_sweep`).
    """
    trial = _bound_trial(spec, static_values)
    on_grid = {axis.name for axis in spec.axes if not axis.static}
    params_axes = spec.params_type(**{field: 0 if field in on_grid else None for field in spec.params_type._fields})

    def one(params: Any, seed: jax.Array) -> tuple[jax.Array, ...]:
        result = _as_result_dict(trial(params, trial_key(spec.base_seed, seed)), spec.trial_path)
        return tuple(jnp.asarray(result[column.name]).astype(column.dtype) for column in results)

    batched = jax.vmap(one, in_axes=(params_axes, 0))
    if len(devices) > 1:
        mesh = jax.sharding.Mesh(np.array(devices), ("trials",))
        split, whole = jax.sharding.PartitionSpec("trials"), jax.sharding.PartitionSpec()
        params_specs = spec.params_type(*(whole if axis is None else split for axis in params_axes))
        batched = jax.shard_map(batched, mesh=mesh, in_specs=(params_specs, split), out_specs=split, check_vma=False)
    return jax.jit(batched).lower(*_chunk_inputs(spec, 0, 1, size)).compile()


def _chunk_inputs(spec: SweepSpec, start: int, end: int, size: int) -> tuple[Any, np.ndarray]:
    """Params and seeds of the trials ``start .. end-1``, padded to ``size`` with the last."""
    index = np.minimum(np.arange(start, start + size), end - 1)
    point, seed = np.divmod(index, spec.seeds)
    coords = np.unravel_index(point, spec.grid_shape)
    values = dict(spec.traced)
    for axis, coord in zip(spec.axes, coords):
        if not axis.static:
            values[axis.name] = axis.array()[coord]
    return spec.params_type(**values), seed.astype(np.int32)


# ------------------------------------------------------------------------- table


def _header(columns: list[_Column]) -> str:
    buffer = io.StringIO()
    csv.writer(buffer, lineterminator="\n").writerow(column.name for column in columns)
    return buffer.getvalue()


def _format_value(value: bool | int | float, kind: str) -> str:
    if kind == "bool":
        return "true" if value else "false"
    return str(int(value)) if kind == "int" else repr(float(value))


def _format_array(values: np.ndarray) -> list[str]:
    if values.dtype == np.bool_:
        return np.where(values, "true", "false").tolist()
    if values.dtype == np.float32:
        return [str(value) for value in values]  # numpy's shortest float32 round trip
    return [repr(value) for value in values.tolist()]


def _format_rows(spec: SweepSpec, start: int, end: int, results: list[np.ndarray]) -> str:
    index = np.arange(start, end)
    point, seed = np.divmod(index, spec.seeds)
    cells: list[list[str]] = [[str(i) for i in index.tolist()], [str(s) for s in seed.tolist()]]
    for axis, coord in zip(spec.axes, np.unravel_index(point, spec.grid_shape)):
        texts = [_format_value(value, axis.kind) for value in axis.values]
        cells.append([texts[i] for i in coord.tolist()])
    cells.extend(_format_array(values) for values in results)
    return "".join(",".join(row) + "\n" for row in zip(*cells))


# ------------------------------------------------------------------------- files

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


def _chunks(missing: list[tuple[int, int]], size: int, block: int | None = None) -> Iterator[tuple[int, int]]:
    """Chunks of at most ``size`` trials covering ``missing``, none crossing a multiple of ``block``."""
    for start, end in missing:
        chunk_start = start
        while chunk_start < end:
            chunk_end = min(chunk_start + size, end)
            if block is not None:
                chunk_end = min(chunk_end, (chunk_start // block + 1) * block)
            yield chunk_start, chunk_end
            chunk_start = chunk_end


def _static_block(spec: SweepSpec) -> int | None:
    """Trials that share the static axes' values come in runs of this length (None: no static axis)."""
    static = [i for i, axis in enumerate(spec.axes) if axis.static]
    if not static:
        return None
    return spec.seeds * math.prod(spec.grid_shape[static[-1] + 1 :])


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
    trials = []
    with open(results, "rb") as file:
        next(file)
        for line in file:
            if b"nan" in line:
                cells = line.rstrip(b"\n").split(b",")
                if b"nan" in cells[first_result:]:
                    trials.append(int(cells[0]))
    return trials


# ---------------------------------------------------------------------- metadata


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


def _new_metadata(spec: SweepSpec, columns: list[_Column]) -> dict[str, Any]:
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


# ------------------------------------------------------------------------ running


class _Table:
    """The parts on disk, and the table and metadata published from them."""

    def __init__(self, out: Path, header: str, parts: list[_Part], metadata: dict[str, Any]):
        self.out = out
        self.header = header
        self.parts = parts
        self.metadata = metadata
        self._publish_cost = 0.0
        self._last_published = -math.inf

    @property
    def done(self) -> int:
        return sum(part.end - part.start for part in self.parts)

    def add(self, start: int, end: int, rows: str) -> None:
        self.parts.append(_write_part(self.out / _PARTS, start, end, rows))
        # Rebuilding the table costs O(rows so far): do it only as often as costs a tenth of the time.
        if time.perf_counter() - self._last_published >= self._publish_cost / _PUBLISH_SHARE:
            self.publish()

    def publish(self) -> None:
        began = time.perf_counter()
        if self.parts and (
            not (self.out / _RESULTS).exists()
            or (self.out / _RESULTS).stat().st_size != _table_size(self.header, self.parts)
        ):
            _write_table(self.out, self.header, self.parts)
        self.metadata["done_trials"] = self.done
        _write_metadata(self.out, self.metadata)
        self._last_published = time.perf_counter()
        self._publish_cost = self._last_published - began


def _progress_bar(spec: SweepSpec, done: int, enabled: bool) -> tqdm:
    interactive = sys.stderr.isatty() and os.environ.get("CI", "").lower() not in ("1", "true")
    return tqdm(
        total=spec.n_trials,
        initial=done,
        desc=spec.name,
        unit=" trials",
        file=sys.stderr,
        disable=not enabled,
        dynamic_ncols=interactive,
        mininterval=0.5 if interactive else 30.0,
        smoothing=0.05,
    )


def run_sweep(spec: SweepSpec, out_dir: str | os.PathLike[str], progress: bool = True) -> Path:
    """Run the trials of ``spec`` that ``out_dir`` does not hold yet.

    The trials run in chunks of ``spec.chunk_size`` consecutive rows through one
    compiled ``jax.jit(jax.vmap(trial))``, split evenly over ``jax.devices()``
    (the accelerators, or the CPU's cores when ``--cpu-devices`` presents them
    as devices); each chunk is written to disk as soon
    as it is done. Run it again after an interruption and it goes on where it
    stopped; on a finished sweep it computes nothing. See the module's docstring
    for the files in ``out_dir`` and how they are kept whole.

    Args:
        spec: the sweep, from :func:`load_sweep`.
        out_dir: the output directory; created if missing.
        progress: show a progress bar (trials/s, ETA) on stderr.

    Returns:
        The path of ``results.csv``.

    Raises:
        UserError: ``out_dir`` holds another sweep or other files, another run is
            going on in it, or the trial does not return a NamedTuple or dict of
            scalars. All are found before anything is compiled.
    """
    out = Path(out_dir)
    metadata = _read_metadata(out)
    if metadata is not None:
        _check_same_sweep(out, spec, metadata)
    missing = _missing_ranges(_scan_parts(out / _PARTS, spec.n_trials), spec.n_trials)
    if metadata is not None and missing:
        _check_same_devices(out, metadata)
    if metadata is not None and not missing:
        columns = [_Column(*column) for column in metadata["columns"]]
    else:
        columns = _key_columns(spec) + _result_columns(spec)
        if metadata is not None and [list(column) for column in columns] != metadata["columns"]:
            raise UserError(
                f"{out} holds results with other columns than the trial now returns: "
                f"choose another --out directory, or delete {out} to start over"
            )
    (out / _PARTS).mkdir(parents=True, exist_ok=True)
    with _locked(out):
        _remove_temporaries(out, out / _PARTS)
        parts = _scan_parts(out / _PARTS, spec.n_trials)
        metadata = metadata or _new_metadata(spec, columns)
        environment = _environment()
        metadata.update(environment)
        run = {"started": _now(), "finished": None, "chunk_size": spec.chunk_size, "computed_trials": 0}
        run.update(environment)
        metadata["runs"].append(run)
        table = _Table(out, _header(columns), parts, metadata)
        table.publish()
        try:
            _run_missing(spec, table, columns[len(_key_columns(spec)) :], run, progress)
        finally:
            table.publish()
        if table.done == spec.n_trials:
            _finish(spec, table, first_result=len(_key_columns(spec)))
    return out / _RESULTS


def _check_same_devices(out: Path, metadata: Mapping[str, Any]) -> None:
    """A table is finished on as many devices as it was started on (see `_compile`)."""
    used = {run.get("devices", 1) for run in metadata["runs"] if run.get("computed_trials")}
    have = jax.device_count()
    if used and used != {have}:
        raise UserError(
            f"{out} was computed on {', '.join(map(str, sorted(used)))} device(s) and JAX presents {have}: "
            f"resume it where JAX presents {min(used)} (on a CPU: --cpu-devices {min(used)}), as a split program "
            "can differ in the last bits"
        )


def _run_missing(
    spec: SweepSpec, table: _Table, results: list[_Column], run: dict[str, Any], progress: bool
) -> None:
    missing = _missing_ranges(table.parts, spec.n_trials)
    if not missing:
        return
    block = _static_block(spec)
    chunks = list(_chunks(missing, spec.chunk_size, block))
    devices = jax.devices()
    # Every device takes an equal share; a chunk is padded with its last trial to fill them.
    size = -(-max(end - start for start, end in chunks) // len(devices)) * len(devices)
    run["devices"] = len(devices)
    programs: dict[tuple[Any, ...], Callable[..., tuple[jax.Array, ...]]] = {}
    run["compile_seconds"] = 0.0

    def program(start: int) -> Callable[..., tuple[jax.Array, ...]]:
        static_values = _static_values(spec, start)
        signature = tuple(static_values.items())
        if signature not in programs:
            if progress:
                shown = "".join(f", {name} = {value}" for name, value in signature)
                print(f"{spec.name}: compiling for chunks of {size} trials{shown}", file=sys.stderr, flush=True)
            began = time.perf_counter()
            programs[signature] = _compile(spec, results, size, static_values, devices)
            run["compile_seconds"] = round(run["compile_seconds"] + time.perf_counter() - began, 3)
        return programs[signature]

    with _progress_bar(spec, table.done, progress) as bar:
        # One chunk in flight while the previous one is written: dispatch is asynchronous.
        pending = None
        for start, end in chunks:
            outputs = program(start)(*_chunk_inputs(spec, start, end, size))
            if pending is not None:
                _store(spec, table, bar, run, *pending)
            pending = (start, end, outputs)
        if pending is not None:
            _store(spec, table, bar, run, *pending)


def _store(
    spec: SweepSpec,
    table: _Table,
    bar: tqdm,
    run: dict[str, Any],
    start: int,
    end: int,
    outputs: tuple[jax.Array, ...],
) -> None:
    results = [np.asarray(values)[: end - start] for values in outputs]
    table.add(start, end, _format_rows(spec, start, end, results))
    run["computed_trials"] += end - start
    bar.update(end - start)


def _finish(spec: SweepSpec, table: _Table, first_result: int) -> None:
    nan_trials = _nan_trials(table.out / _RESULTS, first_result)
    table.metadata["nan_trials"] = nan_trials
    table.metadata["runs"][-1]["finished"] = _now()
    table.metadata["finished"] = table.metadata["finished"] or _now()
    table.publish()
    if nan_trials:
        listed = ", ".join(str(trial) for trial in nan_trials[:_NAN_TRIALS_LISTED])
        more = f", ... ({len(nan_trials) - _NAN_TRIALS_LISTED} more)" if len(nan_trials) > _NAN_TRIALS_LISTED else ""
        print(
            f"warning: sweep '{spec.name}': NaN results in {len(nan_trials)} of {spec.n_trials} trials: "
            f"{listed}{more} (all in {table.out / _METADATA}, nan_trials)",
            file=sys.stderr,
        )


# ------------------------------------------------------------------------ reading


def read_results(out_dir: str | os.PathLike[str]) -> dict[str, np.ndarray]:
    """The table of a sweep's output directory, one array per column.

    Args:
        out_dir: the directory given to :func:`run_sweep` (``--out``).

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
    columns = [_Column(*column) for column in metadata["columns"]]
    with open(out / _RESULTS, newline="", encoding="utf-8") as file:
        reader = csv.reader(file)
        header = next(reader)
        rows = list(reader)
    if header != [column.name for column in columns]:
        raise UserError(f"{out / _RESULTS} does not have the columns of {out / _METADATA}")
    cells = list(zip(*rows)) if rows else [() for _ in columns]
    return {column.name: _parse_column(texts, column.dtype) for column, texts in zip(columns, cells)}


def _parse_column(texts: tuple[str, ...], dtype: str) -> np.ndarray:
    if dtype == "bool":
        return np.asarray([text == "true" for text in texts], dtype=np.bool_)
    return np.asarray(texts, dtype=str).astype(dtype) if texts else np.zeros(0, dtype)


# ---------------------------------------------------------------------------- CLI


def main(args: argparse.Namespace) -> int:
    """``spikejax sweep FILE --out DIR [--chunk-size N] [--seeds N] [--cpu-devices N] [--no-progress]``.

    With ``cpu_devices``, the CPU is presented as that many devices before
    anything runs on JAX, and each chunk is split over them (about 1.6x faster
    on two cores for the RoboBee flights); by default JAX's devices are used as
    they are (one on a CPU, every accelerator otherwise).

    Args:
        args: the parsed command line (``file``, ``out``, ``chunk_size``, ``seeds``,
            ``cpu_devices``, ``no_progress``).

    Returns:
        The exit code, 0.

    Raises:
        UserError: a bad sweep file, flag or output directory.
    """
    if getattr(args, "cpu_devices", None):
        cpu_devices_for_run(args.cpu_devices)
    spec = load_sweep(args.file, seeds=args.seeds, chunk_size=args.chunk_size)
    results = run_sweep(spec, args.out, progress=not args.no_progress)
    print(results)
    return 0
