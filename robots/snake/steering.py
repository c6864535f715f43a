"""A scripted, non-spiking steering controller that follows the target: the baseline the SNNs must beat.

It reads the angle of the target to the body (Eq. (12) of the snake R-STDP
paper, observation 1 of `robots.snake.env.SnakeEnv`), optionally
smooths it with a first-order low-pass filter of time constant ``tau``, and
steers in proportion to it: ``action[0] = clip(gain * angle, -1, 1)``, a
positive action turning right towards a target on the right. It also turns
the head towards the target, ``action[1] = clip(head_gain * angle, -1, 1)``,
the role of the paper's head controller (section III-B), on top of the gait's
head compensation: the slithering swings the head from side to side, and
pointing it at the target is what keeps the target in view.

Like the SNN controllers to come it is an ``(init, step)`` pair of pure
functions of explicit state (`robots.snake.steering.init`,
`robots.snake.steering.step`), so it runs inside the same ``lax.scan`` as the
env and ``vmap`` batches it.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

__all__ = ["SteeringParams", "SteeringState", "init", "step"]


class SteeringParams(NamedTuple):
    """Gains (per radian of target angle, in units of the action range) and the filter's time constant (s).

    The defaults (gain 1, head gain 2, no filter) were the best of a small
    grid (gain 0.5, 1, 1.5; head gain 1.5, 2.5, 4; ``tau`` 0, 0.2 s, and an
    earlier one with ``tau`` up to a gait period and no head control) on the 8
    and the mirrored zigzag with the default env: the settings that kept the
    target on both for 180 s with the lowest mean ``|a_head|`` (about 6
    degrees). Without head control, or with a slow filter, the swinging head
    loses the target within about a minute; a higher body gain turns the snake
    on the spot (a large ``C_o`` stalls the slithering gait) and loses it at
    once. ``tau = 0`` means no filtering.
    """

    gain: float | jax.Array = 1.0
    head_gain: float | jax.Array = 2.0
    tau: float | jax.Array = 0.0


class SteeringState(NamedTuple):
    angle: jax.Array  # the low-pass filtered target angle, rad


def init() -> SteeringState:
    return SteeringState(angle=jnp.zeros((), jnp.float32))


def step(params: SteeringParams, state: SteeringState, obs: jax.Array, dt) -> tuple[SteeringState, jax.Array]:
    """One control step: filter the body-to-target angle ``obs[1]`` and steer towards it.

    Returns the new state and the action ``(2,)``: steering and head offset, each in [-1, 1].
    """
    decay = jnp.where(params.tau > 0, jnp.exp(-dt / jnp.maximum(params.tau, 1e-9)), 0.0)
    angle = decay * state.angle + (1.0 - decay) * obs[1]
    action = jnp.clip(jnp.stack([params.gain * angle, params.head_gain * angle]), -1.0, 1.0)
    return SteeringState(angle), action
