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

from robots.snake.env import COMPENSATE_FROM
from spikejax.errors import UserError

__all__ = ["SteeringParams", "SteeringState", "for_max_steer", "init", "step"]


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

    The gains are per unit of the action range, so they depend on the env's
    ``max_steer``: these were tuned at `robots.snake.env.SnakeEnv`'s 0.25 rad;
    `for_max_steer` keeps their ``C_o`` per radian of target angle for
    another range.
    """

    gain: float | jax.Array = 1.0
    head_gain: float | jax.Array = 2.0
    tau: float | jax.Array = 0.0


def for_max_steer(max_steer: float, compensate_from: str = "targets") -> SteeringParams:
    """The default gains rescaled to a steering range of ``max_steer`` rad (the same ``C_o`` per radian).

    With the head compensated from the joint targets (the snake env's
    default), at `robots.snake.training.MAX_STEER` (0.125 rad) this doubles
    the body gain to 2. Kept at 1 there, the controller lost the target
    0.8-0.9 times a minute, at every first turn of the test tracks: this
    snake does not turn at all for ``|C_o|`` below
    `robots.snake.env.TURN_THRESHOLD` (0.08 rad, 64 % of that range), so it
    only turned once the body's angle to the target passed about 37 degrees,
    and the body-angle rule (35 degrees) fired first. Measured over full
    test passes of the ladder, the zigzag and their mirrors in
    `robots.snake.training.env_for`'s env (then compensated from the
    targets), a grid of body gains 1-3 and head gains 1-3: body 2 / head 2
    was one of the few cells that never lost the target on any of the four,
    and had the lowest running-mean head angle (0.10-0.14 degrees in the
    paper's 625-step window, 3.0-3.1 degrees instantaneous); body 1 and 1.5
    failed on all four.

    ``compensate_from``: what the env's head compensation reads
    (`robots.snake.env.SnakeEnv`'s ``compensate_from``). From the measured
    joints the head loop has a path back through the body: turning the head
    bends the neck joints, which the compensation reads. There head gain 2
    oscillates (the head 19 degrees off the target on average, three
    failures a minute) and 1.5 does with body gains from 2.5 (8-11 degrees).
    The gains for it are body 2 at 0.25 rad (4 at 0.125) and head 1.25,
    measured in `robots.snake.training.env_for`'s env (now compensated from
    the joints), full passes as above, over body gains 1.5-8 and head gains
    1-1.5: no cell lost the target, and of those with a head gain of 1.25
    or less (a margin to the oscillation) this one had about the lowest
    running-mean head angle, 0.70-1.08 degrees in the paper's window,
    2.5-2.7 instantaneous (body 5: 0.72-1.05; 5 / 1.4: 0.51-0.80; 2 / 1:
    2.0-3.6).

    From the lagged targets (``"lagged"``, `robots.snake.training.env_for`'s
    env) head gain 2 oscillates as well (13-17 degrees instantaneous): the
    compensation leaves the head turned with the neck for about ``lag_tau``
    after a change of ``C_o``, so the body gain moves the camera, and from
    1.75 the head loop oscillates at any body gain. The gains for it are body
    2 at 0.25 rad (4 at 0.125) and head 1.5, measured as above over body
    gains 1-6 and head gains 1-2 (at 0.125 rad): no failure, 0.6-1.0
    degrees in the paper's window, 0.9-1.1 instantaneous; body 0.5 at 0.25
    rad lost the target on the ladder, and body 3 swung the head by 1.9-2.3
    degrees.
    """
    if compensate_from not in COMPENSATE_FROM:
        raise UserError(f"compensate_from must be one of {', '.join(COMPENSATE_FROM)}, got {compensate_from!r}")
    defaults = {
        "targets": SteeringParams(),
        "joints": SteeringParams(gain=2.0, head_gain=1.25),
        "lagged": SteeringParams(gain=2.0, head_gain=1.5),
    }[compensate_from]
    return defaults._replace(gain=defaults.gain * 0.25 / max_steer)


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
