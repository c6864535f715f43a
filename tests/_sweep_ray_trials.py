"""Trials for the Ray tests: a closed form, a host callback that can sleep, log its process and raise."""

from __future__ import annotations

import functools
import os
import time
from typing import NamedTuple

import jax
import jax.numpy as jnp


class LoggedParams(NamedTuple):
    a: float = 0.0
    sleep: float = 0.0
    fail_at: float = -1.0


class LoggedResult(NamedTuple):
    value: jax.Array
    draw: jax.Array


def _record(log: str, a, sleep, fail_at) -> None:
    """Sleeps ``sleep`` s, appends ``a`` to ``log/<pid>.txt``, raises where ``a == fail_at``."""
    if float(sleep):
        time.sleep(float(sleep))
    if log:
        with open(os.path.join(log, f"{os.getpid()}.txt"), "a") as file:
            file.write(f"{float(a)!r}\n")
    if float(a) == float(fail_at):
        raise ValueError(f"a = {float(a)} is the value this trial refuses")


def logged_trial(params: LoggedParams, key: jax.Array, *, log: str = "", host: bool = True) -> LoggedResult:
    """``value = 3 a + sin(u)``, ``u`` the seed's uniform draw; with ``host``, one host callback per trial.

    JAX's persistent cache keeps no program with a host callback: ``host = false`` makes one it keeps.
    """
    if host:
        jax.debug.callback(functools.partial(_record, log), params.a, params.sleep, params.fail_at)
    draw = jax.random.uniform(key)
    return LoggedResult(value=3.0 * params.a + jnp.sin(draw), draw=draw)
