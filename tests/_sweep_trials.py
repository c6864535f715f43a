"""Toy trial functions for the sweep engine's tests: closed forms plus one uniform draw."""

from __future__ import annotations

import os
import time
from typing import NamedTuple

import jax
import jax.numpy as jnp

from spikejax.ranges import POSITIVE, Range, ranged


class ToyParams(NamedTuple):
    a: float = 1.0
    n: int = 2
    flag: bool = False
    offset: float = 0.0


class ToyResult(NamedTuple):
    value: jax.Array
    count: jax.Array
    draw: jax.Array
    positive: jax.Array


def toy_value(a, n, flag, offset, draw, scale=1.0):
    """The closed form of ``toy_trial``'s ``value``, in the trial's float32."""
    base = jnp.float32(scale) * (jnp.float32(a) * jnp.float32(n) + jnp.float32(offset))
    return jnp.where(flag, -base, base) + jnp.sin(jnp.float32(draw))


def toy_trial(params: ToyParams, key: jax.Array, *, scale: float = 1.0) -> ToyResult:
    draw = jax.random.uniform(key)
    value = toy_value(params.a, params.n, params.flag, params.offset, draw, scale)
    return ToyResult(value=value, count=params.n * 10 + 1, draw=draw, positive=value > 0)


def dict_trial(params: ToyParams, key: jax.Array) -> dict[str, jax.Array]:
    return {"zeta": params.a * 2, "alpha": jax.random.normal(key)}


def nan_trial(params: ToyParams, key: jax.Array) -> ToyResult:
    """``value`` is NaN where ``a < 0``."""
    result = toy_trial(params, key)
    return result._replace(value=jnp.sqrt(params.a) + result.draw)


def _maybe_sleep(_):
    seconds = float(os.environ.get("SWEEP_TEST_SLEEP", "0"))
    if seconds:
        time.sleep(seconds)


def slow_trial(params: ToyParams, key: jax.Array) -> ToyResult:
    """``toy_trial``, sleeping ``$SWEEP_TEST_SLEEP`` seconds per trial on the host."""
    jax.debug.callback(_maybe_sleep, params.a)
    return toy_trial(params, key)


def guarded_trial(params: ToyParams, key: jax.Array) -> ToyResult:
    """``toy_trial``, but failing when traced while ``$SWEEP_TEST_FORBID`` is set."""
    if os.environ.get("SWEEP_TEST_FORBID"):
        raise RuntimeError("the trial was traced although every trial was done")
    return toy_trial(params, key)


class RequiredParams(NamedTuple):
    a: float
    b: float


def required_trial(params: RequiredParams, key: jax.Array) -> ToyResult:
    return toy_trial(ToyParams(a=params.a, offset=params.b), key)


def needs_static_trial(params: ToyParams, key: jax.Array, *, size: int) -> ToyResult:
    return toy_trial(params, key)


def unannotated_trial(params, key):
    return toy_trial(params, key)


def vector_trial(params: ToyParams, key: jax.Array) -> dict[str, jax.Array]:
    return {"v": jnp.ones(3) * params.a}


def list_trial(params: ToyParams, key: jax.Array) -> list[jax.Array]:
    return [params.a]


TRACES = []


def counting_trial(params: ToyParams, key: jax.Array) -> ToyResult:
    """``toy_trial``, counting its traces in ``TRACES``."""
    TRACES.append(params)
    return toy_trial(params, key)


def shaped_trial(params: ToyParams, key: jax.Array, *, size: int = 1, scale: float = 1.0) -> ToyResult:
    """``toy_trial`` whose draw is the mean of ``size`` uniforms: ``size`` shapes the program."""
    TRACES.append(size)
    draw = jnp.mean(jax.random.uniform(key, (size,)))
    value = toy_value(params.a, params.n, params.flag, params.offset, draw, scale)
    return ToyResult(value=value, count=params.n * 10 + size, draw=draw, positive=value > 0)


def inf_trial(params: ToyParams, key: jax.Array) -> ToyResult:
    """``value`` is +inf where ``a > 2``, -inf where ``a < -2``, NaN where ``a == 0``."""
    result = toy_trial(params, key)
    value = jnp.where(params.a > 2, jnp.inf, jnp.where(params.a < -2, -jnp.inf, result.value))
    return result._replace(value=jnp.where(params.a == 0, jnp.nan, value))


class FlagResult(NamedTuple):
    count: jax.Array
    ok: jax.Array
    nonfinite: jax.Array


def flag_trial(params: ToyParams, key: jax.Array) -> FlagResult:
    """Int and bool results only; the state ``1 / a`` is infinite where ``a == 0``."""
    from spikejax.sweep import nonfinite

    state = {"inverse": 1.0 / params.a, "count": params.n}
    return FlagResult(count=params.n * 10, ok=params.a > 0, nonfinite=nonfinite(state))


def int_flag_trial(params: ToyParams, key: jax.Array) -> dict[str, jax.Array]:
    return {"nonfinite": params.n}


def raising_trial(params: ToyParams, key: jax.Array) -> ToyResult:
    """Raises while traced, on the line below."""
    raise ZeroDivisionError("the user's own mistake")  # RAISING_LINE


def shape_error_trial(params: ToyParams, key: jax.Array) -> ToyResult:
    result = toy_trial(params, key)
    return result._replace(value=jnp.ones(3) + jnp.ones(4))  # SHAPE_LINE


@ranged(a=POSITIVE, n=Range(1, 3, integer=True))
class RangedParams(NamedTuple):
    a: float = 1.0
    n: int = 2


@ranged(steps=Range(1, integer=True))
def ranged_trial(params: RangedParams, key: jax.Array, *, steps: int = 3, gain: float = 1.0) -> ToyResult:
    """``toy_trial`` with declared ranges: ``a > 0``, ``n`` in [1, 3], ``steps >= 1``."""
    return toy_trial(ToyParams(a=params.a, n=params.n), key, scale=gain)


def picky_trial(params: ToyParams, key: jax.Array, *, size: int = 1) -> ToyResult:
    """``toy_trial``, refusing a ``size`` above 2 while traced."""
    if size > 2:
        raise ValueError(f"size {size} is too large for this toy")  # PICKY_LINE
    return toy_trial(params, key)
