"""From CPG spikes to servo targets: the hexapod's spike-triggered step primitive.

The hexapod SCPG paper says only that "the leg corresponding to a neuron moves
when that neuron fires" (Fig. 1(c), Sec. III-A); no servo, angle or timing is
given. Ours, after the reading notes' recommendation and the RaspClaws kit's
own step cycle (a hip swing servo and a lift servo per leg), is this: when CPG
neuron ``N_j`` fires at CPG step ``k`` (time ``k dt_cpg``), leg ``j``

1. **swings** during ``[k, k + 1) dt_cpg``: its foot lifts and comes down again,
   ``lift = L sin(pi u)``, while its hip swings forward from where it was
   (``-A`` after a stance, 0 from rest) to ``+A``;
2. is in **stance** during ``[k + 1, k + 2) dt_cpg``: foot down, hip from ``+A``
   back to ``-A``, which pushes the body forward;
3. **holds** at ``-A``, foot down, until its next spike.

Hip moves follow a raised cosine, ``s(u) = (1 - cos(pi u)) / 2``, ``u`` the
fraction of the CPG step elapsed. A spike that comes while the leg is still
moving starts a new swing from the hip's angle at that moment. A leg that never
fires stays planted at 0. With the tripod G1 each tripod swings while the other
pushes (duty factor 0.5) and the robot walks forward; in G2 only the right legs
step, so the robot pivots on its planted left legs (a left turn), and G3 is its
mirror image (`robots.hexapod.gaits`).

Signs (``robots/hexapod/hexapod.xml``): a positive hip angle swings the foot
forward and a positive lift raises it, on either side. Actuator order: per leg
``(yaw, lift)``, legs in the CPG's order L1, L2, L3, R1, R2, R3.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from robots.hexapod.gaits import N_LEGS
from spikejax.ranges import NON_NEGATIVE, POSITIVE, ranged

__all__ = ["StepParams", "step_params", "swing_starts", "servo_targets"]


@ranged(amplitude=NON_NEGATIVE, lift=NON_NEGATIVE, dt_cpg=POSITIVE)
class StepParams(NamedTuple):
    """The step primitive's constants (traced).

    Attributes:
        amplitude: ``A``, the hip's swing either side of neutral, rad.
        lift: ``L``, the lift servo's peak during a swing, rad.
        dt_cpg: one CPG step, s (a gait cycle is two).
    """

    amplitude: jax.Array
    lift: jax.Array
    dt_cpg: jax.Array


def step_params(amplitude=0.26, lift=0.6, dt_cpg=0.16) -> StepParams:
    """Defaults: a hip swing of +-15 deg and a lift of 34 deg, about the RaspClaws kit's (its code's 35
    and 90 servo ticks), and 0.16 s a CPG step (its 80 ms per position, two positions a step)."""
    return StepParams(*(jnp.asarray(v, jnp.float32) for v in (amplitude, lift, dt_cpg)))


def _s(u):
    return 0.5 * (1.0 - jnp.cos(jnp.pi * u))


def _hip(params: StepParams, tau, start):
    """The hip angle ``tau`` seconds after a spike whose swing started from ``start``."""
    a, dt = params.amplitude, params.dt_cpg
    swing = start + (a - start) * _s(jnp.clip(tau / dt, 0.0, 1.0))
    stance = a - 2.0 * a * _s(jnp.clip(tau / dt - 1.0, 0.0, 1.0))
    return jnp.where(tau < dt, swing, stance)


def swing_starts(params: StepParams, raster: jax.Array) -> jax.Array:
    """The hip angle each spike's swing starts from, ``(n_steps, 6)`` (0 where there is no spike).

    Raster row ``k`` holds the spikes at time ``k dt_cpg``.
    """

    def step(carry, inputs):
        last, start = carry
        k, fired = inputs
        tau = (k - last).astype(jnp.float32) * params.dt_cpg
        now = jnp.where(last >= 0, _hip(params, tau, start), 0.0)
        fired = fired > 0
        last = jnp.where(fired, k, last)
        start = jnp.where(fired, now, start)
        return (last, start), jnp.where(fired, now, 0.0)

    init = (jnp.full((N_LEGS,), -1, jnp.int32), jnp.zeros((N_LEGS,), jnp.float32))
    _, starts = jax.lax.scan(step, init, (jnp.arange(raster.shape[0], dtype=jnp.int32), raster))
    return starts


def servo_targets(params: StepParams, raster: jax.Array, t: jax.Array) -> jax.Array:
    """The 12 servo targets at times ``t`` (s), ``(len(t), 12)``: per leg (hip, lift), legs in the CPG's order.

    Args:
        params: the step primitive.
        raster: CPG spikes, ``(n_steps, 6)``; row ``k`` at time ``k dt_cpg``.
        t: times, s, ``>= 0``; past the raster's last step the legs finish their moves and hold.
    """
    n_steps = raster.shape[0]
    starts = swing_starts(params, raster)
    steps = jnp.arange(n_steps, dtype=jnp.int32)
    # last[k, j]: the latest step <= k at which leg j fired, -1 if none.
    last = jax.lax.cummax(jnp.where(raster > 0, steps[:, None], -1), axis=0)
    k = jnp.clip(jnp.floor(t / params.dt_cpg).astype(jnp.int32), 0, n_steps - 1)
    spike = last[k]  # (n_t, 6)
    tau = t[:, None] - spike.astype(jnp.float32) * params.dt_cpg
    start = starts[jnp.maximum(spike, 0), jnp.arange(N_LEGS)]
    fired = spike >= 0
    hip = jnp.where(fired, _hip(params, tau, start), 0.0)
    lift = jnp.where(
        fired & (tau < params.dt_cpg), params.lift * jnp.sin(jnp.pi * jnp.clip(tau / params.dt_cpg, 0, 1)), 0.0
    )
    return jnp.stack([hip, lift], axis=-1).reshape(t.shape[0], 2 * N_LEGS)
