"""The results table: its columns, their dtypes, and each value written as a cell's text and read back.

Columns: ``trial``, ``seed``, the grid axes in file order, then the result
fields in the order the trial returns them. ``trial`` and ``seed`` are int64;
a grid axis is int64, float64 or bool, as the sweep file gives its values
(the table keeps Python's precision); a result keeps the dtype the trial
returns it in (any integer, bool, float32 or float64; other floats as
float32).

Cells: integers are written in decimal, booleans as ``true``/``false``,
floats as the shortest decimal that reads back to the same value of the
column's dtype (``nan``, ``inf`` included). How the cells are laid out in files
is `spikejax.sweep.store`'s.
"""

from __future__ import annotations

import re
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

from spikejax.errors import UserError
from spikejax.sweep.spec import SweepSpec

__all__ = ["Column", "NAN", "NONFINITE", "bad_cell", "cells", "key_columns", "parse_column", "result_dtype"]

# Grid values are written as the file gives them, so the table keeps Python's precision.
_AXIS_TABLE_DTYPES = {"bool": "bool", "int": "int64", "float": "float64"}
# The text of a NaN cell, float32 (numpy's str) and float64 (repr) alike.
NAN = "nan"
# The documented name of a bool result that says the trial's state went non-finite
# (`spikejax.sweep.nonfinite`); the engine reports the trials where it is true.
NONFINITE = "nonfinite"
# The texts the engine writes, and nothing else, read back: decimal integers; Python's
# repr of a float and numpy's str of a float32 (digits with a point and/or an exponent,
# nan, inf, -inf).
_INT_CELL = re.compile(r"-?(0|[1-9][0-9]*)")
_FLOAT_CELL = re.compile(r"-?([0-9]+\.[0-9]+(e[+-][0-9]+)?|[0-9]+e[+-][0-9]+|inf)|nan")
_BOOL_CELLS = ("true", "false")


class Column(NamedTuple):
    """One column of the table: its name and the numpy dtype name of its values."""

    name: str
    dtype: str


def key_columns(spec: SweepSpec) -> list[Column]:
    """The columns that say which trial a row is: ``trial``, ``seed``, the grid axes."""
    return [Column("trial", "int64"), Column("seed", "int64")] + [
        Column(axis.name, _AXIS_TABLE_DTYPES[axis.kind]) for axis in spec.axes
    ]


def result_dtype(dtype: np.dtype, name: str, trial_path: str) -> str:
    """The column dtype of a result the trial returns as ``dtype``."""
    if dtype == np.bool_ or jnp.issubdtype(dtype, jnp.integer):
        return np.dtype(dtype).name
    if jnp.issubdtype(dtype, jnp.floating):
        return "float64" if dtype == np.float64 else "float32"
    raise UserError(
        f"result '{name}' of the trial {trial_path} must be a bool, an integer or a real float, got {dtype}"
    )


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


def cells(spec: SweepSpec, start: int, end: int, results: list[np.ndarray]) -> list[list[str]]:
    """The cells of the rows ``start .. end-1``, column by column.

    Args:
        spec: the sweep.
        start: the first trial.
        end: one past the last trial.
        results: one array of ``end - start`` values per result column.
    """
    index = np.arange(start, end)
    point, seed = np.divmod(index, spec.seeds)
    columns: list[list[str]] = [[str(i) for i in index.tolist()], [str(s) for s in seed.tolist()]]
    for axis, coord in zip(spec.axes, np.unravel_index(point, spec.grid_shape)):
        texts = [_format_value(value, axis.kind) for value in axis.values]
        columns.append([texts[i] for i in coord.tolist()])
    columns.extend(_format_array(values) for values in results)
    return columns


def bad_cell(text: str, dtype: str) -> str | None:
    """Why ``text`` is not a cell the engine writes for a column of ``dtype`` (None: it is one)."""
    if dtype == "bool":
        return None if text in _BOOL_CELLS else "not true or false"
    if np.issubdtype(np.dtype(dtype), np.integer):
        if not _INT_CELL.fullmatch(text):
            return "not an integer"
        info = np.iinfo(np.dtype(dtype))
        return None if info.min <= int(text) <= info.max else f"out of the range of {dtype}"
    return None if _FLOAT_CELL.fullmatch(text) else "not a number"


def parse_column(texts: tuple[str, ...], dtype: str) -> np.ndarray:
    """The values of a column's cells, as an array of ``dtype``.

    Only the texts the engine writes are read (see the module docstring); check
    them with `bad_cell` first, which says where a table is damaged.

    Raises:
        UserError: a cell is not one the engine writes for ``dtype``.
    """
    for text in set(texts):
        reason = bad_cell(text, dtype)
        if reason is not None:
            raise UserError(f"cell {text!r} is {reason} ({dtype} column)")
    if dtype == "bool":
        return np.asarray([text == "true" for text in texts], dtype=np.bool_)
    return np.asarray(texts, dtype=str).astype(dtype) if texts else np.zeros(0, dtype)
