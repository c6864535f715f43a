"""The head's residual swing on the slithering gait, and the phase-locked head offset that cancels it.

Sec. II-A of the snake R-STDP paper applies "a compensation C_compensation to
the first joint so that the DVS can always sense the environment in front".
`robots.snake.gait.head_compensation` writes it as kinematics (the head along
the modules' mean heading as the joint targets place them). Measured on the
straight lead-in of the ladder with no steering, the head still swings about
the target ahead by 15.0 degrees (the fundamental of ``a_head`` at the gait's
frequency; the servos lag their targets, and a body holding one wave does not
travel along its mean heading at every instant). A network without a head
controller (the paper's basic one) then sees the target sweep 30 degrees
across its view every gait period.

The residual is cancelled by `robots.snake.gait.swing_correction`,
``amplitude sin(omega_o t + phase)`` added to the head joint's target
(`robots.snake.env.SnakeEnv`'s ``head_swing``). `fit` finds the pair: the
fundamental ``z`` of ``a_head`` (a complex amplitude) responds linearly to the
correction's complex amplitude ``c = amplitude e^{i phase}``, ``z = z0 + g c``,
so one run without and one with a probe correction give ``z0`` and ``g``, and
``c = -z0 / g``; a second such step refines it (the response is only nearly
linear). `HEAD_SWING` is the result for the default gait and physics; it
leaves 0.14 degrees of the 15 (``tests/test_head_swing.py``).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from robots.snake.env import SnakeEnv, rollout
from robots.snake.gait import gait_period

__all__ = ["HEAD_SWING", "HEAD_SWING_JOINTS", "fundamental", "swing", "fit"]

# (amplitude, phase), rad: `fit()` for the default gait on the C backend (2 steps from a 10-degree probe).
HEAD_SWING = (math.radians(14.27), math.radians(259.7))
# The same for the compensation read from the measured joints (``SnakeEnv(compensate_from="joints")``):
# fit(env=SnakeEnv("ladder", drawn=True, camera=False, compensate_from="joints")).
HEAD_SWING_JOINTS = (math.radians(14.943), math.radians(51.13))

SKIP_PERIODS = 2  # the start-up transient left out of every measurement
PERIODS = 12  # measured after it: the ladder's lead-in and first run stay straight for 14 periods


def fundamental(x: np.ndarray, t: np.ndarray, omega: float) -> complex:
    """The complex amplitude ``z`` of ``x``'s component at ``omega``: ``x ~ Im(z e^{i omega t})`` + a constant.

    A least-squares fit of ``a sin(omega t) + b cos(omega t) + c``, ``z = a + i b``:
    ``|z|`` is the amplitude, and a correction ``|c| sin(omega t + arg c)`` is
    ``Im(c e^{i omega t})`` in the same form, so a linear response multiplies it
    by one complex gain.
    """
    design = np.stack([np.sin(omega * t), np.cos(omega * t), np.ones_like(t)], axis=1)
    (a, b, _), *_ = np.linalg.lstsq(design, np.asarray(x, float), rcond=None)
    return complex(a, b)


def swing(corrections, *, env: SnakeEnv | None = None) -> np.ndarray:
    """The fundamental of ``a_head`` (complex, rad) with each ``(amplitude, phase)`` correction, no steering.

    ``env`` defaults to the ladder without a camera; every correction runs as
    one member of a ``vmap`` with the env's traced ``head_swing`` parameters.
    """
    env = SnakeEnv("ladder", drawn=True, camera=False) if env is None else env
    per = int(round(float(gait_period(env.gait)) / env.dt))
    steps = (SKIP_PERIODS + PERIODS) * per
    corr = jnp.asarray(np.asarray(corrections, np.float32).reshape(-1, 2))

    def one(c):
        params = env.params._replace(head_swing_amplitude=c[0], head_swing_phase=c[1])
        record, _ = rollout(env, lambda p, obs, state: (p, jnp.zeros(2)), (), steps, params=params)
        return record.metrics["a_head"], record.pipeline_state.time

    a_head, t = jax.device_get(jax.jit(jax.vmap(one))(corr))
    keep = slice(SKIP_PERIODS * per, None)
    omega = float(abs(env.gait.omega_o))
    return np.array([fundamental(a[keep], tt[keep], omega) for a, tt in zip(a_head, t)])


def fit(*, probe_deg: float = 10.0, steps: int = 2, env: SnakeEnv | None = None) -> tuple[float, float, float]:
    """``(amplitude, phase, residual)``, rad: the correction cancelling the head's swing, and what is left of it."""
    c = 0j
    for _ in range(steps):
        probe = c + math.radians(probe_deg)
        z0, z1 = swing([(abs(c), np.angle(c)), (abs(probe), np.angle(probe))], env=env)
        c = c - z0 * (probe - c) / (z1 - z0)
    (z,) = swing([(abs(c), np.angle(c))], env=env)
    return abs(c), float(np.angle(c)) % (2 * math.pi), abs(z)
