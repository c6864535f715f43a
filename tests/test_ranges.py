"""Declared ranges: each kind of bound, NaN and infinity refused, the user's own name and value in the message."""

import math
from typing import NamedTuple

import pytest

from spikejax.errors import UserError
from spikejax.ranges import NON_NEGATIVE, POSITIVE, Range, check, ranged, ranges_of


@ranged(
    tau=POSITIVE,
    rate=NON_NEGATIVE,
    fov=Range(0, math.pi, low_open=True, high_open=True),
    n_gaits=Range(1, 3, integer=True),
)
class _Params(NamedTuple):
    tau: float = 0.02
    rate: float = 0.0
    fov: float = 1.0
    n_gaits: int = 3
    free: float = 0.0


@pytest.mark.parametrize(
    ("values", "message"),
    [
        ({"tau": 0.0}, "tau must be > 0, got 0"),
        ({"tau": -50}, "tau must be > 0, got -50"),
        ({"rate": -1e-9}, "rate must be >= 0, got -1e-09"),
        ({"fov": math.pi}, "fov must be in (0, 3.14159), got 3.14159"),
        ({"n_gaits": [1, 2, 7]}, "n_gaits must be a whole number in [1, 3], got 7"),
        ({"n_gaits": 2.5}, "n_gaits must be a whole number in [1, 3], got 2.5"),
        ({"tau": float("nan")}, "tau must be a finite number, got nan"),
        ({"rate": float("inf")}, "rate must be a finite number, got inf"),
    ],
)
def test_out_of_range_values_are_one_line_errors(values, message):
    with pytest.raises(UserError) as err:
        check(_Params, values)
    assert str(err.value) == message


def test_values_in_range_and_undeclared_fields_pass():
    check(_Params, {"tau": 1e-6, "rate": 0.0, "fov": 3.14, "n_gaits": [1, 2, 3], "free": float("nan"), "other": -1})


def test_the_users_name_and_value_are_shown():
    with pytest.raises(UserError) as err:
        check(_Params, {"fov": math.radians(500)}, names={"fov": "--fov"}, scales={"fov": 180 / math.pi})
    assert str(err.value) == "--fov must be in (0, 180), got 500"


def test_declaring_a_range_for_a_missing_field_is_refused():
    with pytest.raises(TypeError, match="no field nope"):
        ranged(nope=POSITIVE)(_Params)
    assert set(ranges_of(_Params)) == {"tau", "rate", "fov", "n_gaits"}
    assert ranges_of(int) == {}
