"""The sweep file: its schema, its validation, and the trial contract it is checked against.

`load_sweep` reads a sweep file (the format is in `spikejax.sweep`), checks
every section, key and value, imports the trial function and checks its
signature and its params NamedTuple against ``[fixed]`` and ``[grid]``; it
compiles nothing. The result is a `SweepSpec`: the grid as `Axis` values, the
traced values off the grid as the arrays the trial receives, the static
keyword arguments, and the fingerprint that tells one sweep from another.

The rules are those of the sweep file and the trial contract in
`spikejax.sweep`. Besides: a value's kind is ``"bool"``, ``"int"`` or
``"float"``, the narrowest that holds all the values of an axis; a field
annotated ``bool``, ``int`` or ``float`` takes values of that kind alone (an int
may fill a float field); int values must fit int32.
"""

from __future__ import annotations

import dataclasses
import hashlib
import importlib
import inspect
import json
import math
import os
import re
import tomllib
import typing
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from spikejax.errors import UserError

__all__ = ["Axis", "SweepSpec", "load_sweep"]

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
_TRIAL_PATH = re.compile(r"[A-Za-z_]\w*(\.[A-Za-z_]\w*)*:[A-Za-z_]\w*(\.[A-Za-z_]\w*)*")


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
    """A validated sweep: what `load_sweep` returns and `spikejax.sweep.run_sweep` runs.

    Attributes:
        path: the sweep file.
        text: the sweep file's text.
        document: the sweep file as parsed.
        name: ``[sweep] name``.
        trial_path: ``[sweep] trial``, ``"module:function"``.
        seeds: seeds per grid point (the file's, or the override).
        base_seed: the root of every trial's key (see `spikejax.sweep.trial_key`).
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

        A params field's values are written as the trial receives them (``2`` of a
        float field as ``2.0``), so that equivalent sweep files are one sweep. The
        form is the one JSON gives back, so that it compares equal to the copy in
        ``metadata.json``.
        """
        fixed = {
            key: _normalised(value, _ARRAY_KINDS.get(self.traced[key].dtype) if key in self.traced else None)
            for key, value in self.document.get("fixed", {}).items()
        }
        grid = [
            [axis.name, [_normalised(v, None if axis.static else axis.kind) for v in axis.values]] for axis in self.axes
        ]
        return json.loads(_canonical_json(self._canonical(fixed, grid)))

    @property
    def fingerprint(self) -> str:
        """SHA-256 of `canonical`: equal fingerprints, equal trials."""
        return hashlib.sha256(_canonical_json(self.canonical).encode()).hexdigest()

    @property
    def legacy_fingerprint(self) -> str:
        """The fingerprint as earlier versions computed it, of the values as the file writes them.

        An output directory that records it is this sweep too (it differs from
        `fingerprint` only where an int is given for a float field).
        """
        fixed = dict(self.document.get("fixed", {}))
        grid = [[axis.name, list(axis.values)] for axis in self.axes]
        return hashlib.sha256(_canonical_json(self._canonical(fixed, grid)).encode()).hexdigest()

    def _canonical(self, fixed: dict[str, Any], grid: list[Any]) -> dict[str, Any]:
        sweep = {"name": self.name, "trial": self.trial_path, "seeds": self.seeds, "base_seed": self.base_seed}
        return json.loads(_canonical_json({"sweep": sweep, "fixed": fixed, "grid": grid}))


_ARRAY_KINDS = {
    dtype: kind
    for kind, dtype in {"bool": np.dtype(np.bool_), "int": np.dtype(np.int32), "float": np.dtype(np.float32)}.items()
}


def _normalised(value: Any, kind: str | None) -> Any:
    """``value`` as the Python value of ``kind`` (None: as it is)."""
    if kind == "float" and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    return value


def _canonical_json(value: Any) -> str:
    return json.dumps(value, sort_keys=True, separators=(",", ":"), default=str)


def load_sweep(
    path: str | os.PathLike[str],
    seeds: int | None = None,
    chunk_size: int | None = None,
) -> SweepSpec:
    """Read and validate a sweep file; compile nothing.

    Args:
        path: the sweep file (TOML, see `spikejax.sweep`).
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
        raise UserError(f'[sweep] trial must be a string "module:function", got {trial_path!r}')
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
    _check_ranges(trial, trial_path, params_type, axes, fixed, static)
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


def _check_ranges(
    trial: Callable[..., Any],
    trial_path: str,
    params_type: type,
    axes: tuple[Axis, ...],
    fixed: Mapping[str, Any],
    static: Mapping[str, Any],
) -> None:
    """The values of ``[fixed]`` and ``[grid]`` against the declared ranges and the keywords' annotations.

    Ranges are declared with `spikejax.ranges.ranged` on the params NamedTuple (traced
    fields) and on the trial function (its keyword-only parameters).
    """
    from spikejax import ranges

    traced_values = {axis.name: list(axis.values) for axis in axes if not axis.static}
    traced_values.update({key: value for key, value in fixed.items() if key in params_type._fields})
    names = {
        key: f"[grid] {key}" if key in traced_values and any(a.name == key for a in axes) else f"[fixed] {key}"
        for key in traced_values
    }
    ranges.check(params_type, traced_values, names=names)
    static_values = {axis.name: list(axis.values) for axis in axes if axis.static}
    static_values.update({key: [value] for key, value in static.items()})
    names = {key: f"[grid] {key}" if any(a.name == key for a in axes) else f"[fixed] {key}" for key in static_values}
    try:
        hints = typing.get_type_hints(trial)
    except Exception:  # noqa: BLE001 - checked by _trial_signature already
        hints = {}
    wanted = {bool: "a boolean", int: "an integer", float: "a number", str: "a string"}
    for key, values in static_values.items():
        kind = hints.get(key)
        if kind not in wanted:
            continue
        for value in values:
            fits = isinstance(value, kind) and (kind is bool or not isinstance(value, bool))
            if kind is float and isinstance(value, int) and not isinstance(value, bool):
                fits = True
            if not fits:
                raise UserError(
                    f"{names[key]} must be {wanted[kind]} (the trial's keyword '{key}: {kind.__name__}'), got {value!r}"
                )
    numeric = {
        key: values
        for key, values in static_values.items()
        if all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values)
    }
    ranges.check(trial, numeric, names=names)


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
    except SyntaxError as err:
        where = f"{err.filename}:{err.lineno}" if err.filename else f"line {err.lineno}"
        raise UserError(f"[sweep] trial: module '{module_name}' has a syntax error at {where}: {err.msg}") from None
    except ModuleNotFoundError as err:
        if err.name is not None and (module_name == err.name or module_name.startswith(err.name + ".")):
            raise UserError(f"[sweep] trial: cannot import module '{module_name}': {err}") from None
        raise UserError(f"[sweep] trial: importing module '{module_name}' failed at {user_frame(err)}: {err}") from None
    except Exception as err:  # noqa: BLE001 - whatever the user's module raises is theirs to fix
        raise UserError(
            f"[sweep] trial: importing module '{module_name}' failed at {user_frame(err)}: "
            f"{type(err).__name__}: {first_line(err)}"
        ) from None
    for attribute in attributes.split("."):
        try:
            target = getattr(target, attribute)
        except AttributeError:
            raise UserError(f"[sweep] trial: module '{module_name}' has no function '{attributes}'") from None
    if not callable(target):
        raise UserError(f"[sweep] trial: {trial_path} is not a function")
    return target


def first_line(err: BaseException) -> str:
    """The first line of an exception's message (its type's name if it has none)."""
    text = str(err).strip()
    return text.splitlines()[0] if text else type(err).__name__


def user_frame(err: BaseException) -> str:
    """``file:line`` of the innermost frame of ``err``'s traceback that is the user's code.

    The user's code is any file outside JAX, jaxlib, numpy, spikejax and Python's
    own library; ``"an unknown place"`` if no frame is.
    """
    import sysconfig
    import traceback

    import jax as jax_module

    skipped = [str(Path(jax_module.__file__).parent), str(Path(np.__file__).parent), str(Path(__file__).parent.parent)]
    for name in ("jaxlib",):
        module = __import__("sys").modules.get(name)
        if module is not None and getattr(module, "__file__", None):
            skipped.append(str(Path(module.__file__).parent))
    skipped.append(sysconfig.get_paths()["stdlib"])
    frames = traceback.extract_tb(err.__traceback__)
    for frame in reversed(frames):
        name = frame.filename
        installed = "site-packages" in Path(name).parts or "dist-packages" in Path(name).parts
        if name.startswith("<") or any(
            name.startswith(prefix + os.sep) and (installed is False or prefix != skipped[-1]) for prefix in skipped
        ):
            continue
        return f"{name}:{frame.lineno}"
    return "an unknown place"


def _trial_signature(trial: Callable[..., Any], trial_path: str) -> tuple[type, dict[str, inspect.Parameter], bool]:
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
