"""A scripted, non-spiking steering controller that follows the target: the baseline the SNNs must beat.

It reads the angle of the target to the body (Eq. (12) of the snake R-STDP
paper, observation 1 of :class:`robots.snake.env.SnakeEnv`), smooths it over
about a gait period with a first-order low-pass filter (the slithering head
swings the measured angle from side to side at the gait's frequency), and
steers in proportion to it: ``action[0] = clip(gain * filtered angle, -1, 1)``,
a positive action turning right towards a target on the right. With
``head_gain > 0`` it also turns the head towards the target
(``action[1] = clip(head_gain * filtered angle, -1, 1)``), the role of the
paper's head controller; by default the head is left to the gait's
compensation.

Like the SNN controllers to come it is an ``(init, act)`` pair of pure
functions of explicit state, so it runs inside the same ``lax.scan`` as the
env and ``vmap`` batches it.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp


class SteeringParams(NamedTuple):
    """Gains (per radian of target angle, in units of the action range) and the filter's time constant (s)."""

    gain: float | jax.Array = 3.0
    head_gain: float | jax.Array = 0.0
    tau: float | jax.Array = 1.0


class SteeringState(NamedTuple):
    angle: jax.Array  # the low-pass filtered target angle, rad


def init() -> SteeringState:
    return SteeringState(angle=jnp.zeros((), jnp.float32))


def act(params: SteeringParams, state: SteeringState, obs: jax.Array, dt) -> tuple[SteeringState, jax.Array]:
    """One control step: filter the body-to-target angle ``obs[1]`` and steer towards it.

    Returns the new state and the action ``(2,)``: steering and head offset, each in [-1, 1].
    """
    decay = jnp.exp(-dt / params.tau)
    angle = decay * state.angle + (1.0 - decay) * obs[1]
    action = jnp.clip(jnp.stack([params.gain * angle, params.head_gain * angle]), -1.0, 1.0)
    return SteeringState(angle), action
