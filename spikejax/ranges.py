"""Valid ranges of parameters, declared once beside the parameter and checked on the host.

A parameter whose valid range is documented (a decay rate > 0, a field of view
in (0, pi), a number of gaits in [1, 3]) says so where it is defined, by the
``ranged`` decorator on its params NamedTuple::

    @ranged(tau=Range(low=0, low_open=True), n_gaits=Range(1, 3, integer=True))
    class GaitParams(NamedTuple):
        tau: float = 20e-3
        n_gaits: int = 3

A function's parameters are declared the same way, on the function: a sweep
trial's keyword-only (static) parameters, ``@ranged(max_epochs=Range(1,
integer=True))``, or a factory's arguments that become traced values later,
such as the field of view of `spikejax.vision.pipe.track_params`.

Whoever takes values from a user (a sweep file, a flag) calls ``check`` before
anything compiles: a value out of range, NaN or infinite is one ``UserError``
naming the key or flag the user wrote. Inside ``jit`` nothing is checked (the
values are tracers there); the edge is where they enter.
"""

from __future__ import annotations

import dataclasses
import inspect
import math
from collections.abc import Callable, Mapping
from typing import Any, TypeVar

import numpy as np

from spikejax.errors import UserError

__all__ = ["NON_NEGATIVE", "POSITIVE", "Range", "check", "ranged", "ranges_of"]

T = TypeVar("T")


@dataclasses.dataclass(frozen=True)
class Range:
    """A closed, open or half-open interval of valid values, optionally of integers.

    Attributes:
        low, high: the bounds (None: unbounded on that side).
        low_open, high_open: whether the bound itself is excluded.
        integer: whether the value must be a whole number.
    """

    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    integer: bool = False

    def contains(self, value: float) -> bool:
        """Whether ``value`` (a finite number) lies in the range."""
        if self.integer and value != math.floor(value):
            return False
        if self.low is not None and (value <= self.low if self.low_open else value < self.low):
            return False
        if self.high is not None and (value >= self.high if self.high_open else value > self.high):
            return False
        return True

    def describe(self, scale: float = 1.0) -> str:
        """The range in words, its bounds times ``scale``: ``> 0``, ``in (0, 180)``, ``a whole number in [1, 3]``."""
        kind = "a whole number " if self.integer else ""
        if self.low is not None and self.high is not None:
            left, right = "(" if self.low_open else "[", ")" if self.high_open else "]"
            return f"{kind}in {left}{self.low * scale:g}, {self.high * scale:g}{right}"
        if self.low is not None:
            return f"{kind}{'>' if self.low_open else '>='} {self.low * scale:g}"
        if self.high is not None:
            return f"{kind}{'<' if self.high_open else '<='} {self.high * scale:g}"
        return f"{kind or 'a number '}".strip()


POSITIVE = Range(low=0, low_open=True)
NON_NEGATIVE = Range(low=0)


def ranged(**ranges: Range) -> Callable[[T], T]:
    """Decorator: declare the valid ranges of some fields of a params NamedTuple, or parameters of a function."""

    def declare(cls: T) -> T:
        fields = getattr(cls, "_fields", None)
        if fields is None:
            fields = tuple(inspect.signature(cls).parameters) if callable(cls) else ()
        unknown = sorted(set(ranges) - set(fields))
        if unknown:
            raise TypeError(f"{cls.__name__} has no field {', '.join(unknown)} to declare a range for")
        cls.__ranges__ = {**getattr(cls, "__ranges__", {}), **ranges}
        return cls

    return declare


def ranges_of(cls: type) -> Mapping[str, Range]:
    """The ranges declared for ``cls``'s fields (empty if none)."""
    return dict(getattr(cls, "__ranges__", {}))


def check(
    cls: type,
    values: Mapping[str, Any],
    *,
    names: Mapping[str, str] | None = None,
    scales: Mapping[str, float] | None = None,
) -> None:
    """Raise a one-line ``UserError`` if a value lies outside its field's declared range, or is not finite.

    Args:
        cls: the params NamedTuple (or the function, for its keyword-only
            parameters) whose ranges apply.
        values: field -> a value or a sequence of values (a sweep's grid axis); fields
            without a declared range, and keys that are not fields, are not checked here.
        names: field -> how the user wrote it (``"--fov"``, ``"[grid] n_gaits"``); default
            the field's name.
        scales: field -> the factor from the field's unit to the user's, when the user
            wrote another unit (``180 / pi`` for a field in radians given in degrees): the
            message then shows the bounds and the value in the user's unit.
    """
    names = names or {}
    scales = scales or {}
    for field, declared in ranges_of(cls).items():
        if field not in values:
            continue
        flat = np.asarray(values[field], dtype=np.float64).ravel()
        for i, value in enumerate(flat):
            if math.isfinite(value) and declared.contains(value):
                continue
            scale = scales.get(field, 1.0)
            reason = f"must be {declared.describe(scale)}" if math.isfinite(value) else "must be a finite number"
            raise UserError(f"{names.get(field, field)} {reason}, got {value * scale:g}")
