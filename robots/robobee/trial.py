"""The RoboBee flight trial that sweep files name: one SNN flight, summarised as scalars."""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from robots.robobee.controller import ControllerConfig, controller_params
from robots.robobee.flight import FlightPlan, Recording, flight_plan, fly
from robots.robobee.lqr import altitude_params, lateral_gain
from robots.robobee.params import randomize, robobee_params
from spikejax.ranges import NON_NEGATIVE, POSITIVE, Range, ranged
from spikejax.sweep import nonfinite

# A waypoint counts as reached within this distance (x, z) at the end of its segment.
REACHED_M = 5e-3


@ranged(
    landing=Range(0, 1, integer=True),
    mu=NON_NEGATIVE,
    tau_reward=POSITIVE,
    spread=Range(0, 1, high_open=True),
    use_snn=Range(0, 1, integer=True),
)
class FlightTrialParams(NamedTuple):
    """Traced parameters of a flight trial.

    Attributes:
        landing: 0 for flight 1 (q0 -> q1 -> q2), 1 for flight 2 (the landing).
        mu: learning rate of Eq. (10) of the RoboBee paper, both weight layers.
        tau_reward: reward time constant of Eq. (9) of the RoboBee paper, s.
        spread: robot randomisation: mass, drag and inertia each scaled by
            ``U(1 - spread, 1 + spread)``; the controllers keep the nominal model.
        use_snn: 1 for the SNN steering (learning online), 0 for the LQR teacher.

    Valid ranges (checked by the sweep engine before anything compiles):
    ``landing`` and ``use_snn`` 0 or 1, ``mu`` >= 0, ``tau_reward`` > 0,
    ``spread`` in [0, 1) (a scale ``1 - spread`` stays positive); all finite.
    """

    landing: int = 0
    mu: float = 1e-3
    tau_reward: float = 5e-3
    spread: float = 0.0
    use_snn: int = 1


class FlightTrialResult(NamedTuple):
    """One row of a flight table.

    Attributes:
        rms_error: RMS of the SNN's minus the LQR's lateral control after the
            hold, units of the torque limit (1 uN m).
        error_1, error_2: distance (x, z) to waypoint 1 and 2 at the end of their segments, m.
        settle_1, settle_2: time after each waypoint is given until the distance
            stays below 5 mm, s (the segment's length if it never does).
        max_theta: largest |theta| of the flight, rad.
        upright: |theta| stayed below pi/2.
        reached: both waypoints reached (within 5 mm) and upright throughout.
        touchdown_speed: |z_dot| when z first comes within 0.5 mm of the floor (the
            landing), m/s; 0 if never.
        nonfinite: a value of the recording (state, targets, controls, weights)
            went NaN or infinite (`spikejax.sweep.nonfinite`).
    """

    rms_error: jax.Array
    error_1: jax.Array
    error_2: jax.Array
    settle_1: jax.Array
    settle_2: jax.Array
    max_theta: jax.Array
    upright: jax.Array
    reached: jax.Array
    touchdown_speed: jax.Array
    nonfinite: jax.Array


@functools.cache
def nominal_gain() -> np.ndarray:
    """The LQR gain of the nominal robot, computed once on the host, shape (4,)."""
    with jax.ensure_compile_time_eval():
        return np.asarray(lateral_gain(robobee_params()), np.float32).reshape(4)


def _plan(landing: jax.Array) -> FlightPlan:
    a, b = flight_plan("waypoints"), flight_plan("landing")
    return jax.tree.map(lambda x, y: jnp.where(landing > 0, y, x), a, b)


def summarize(rec: Recording, plan: FlightPlan, hold_steps: int, segment_steps: int, record_every: int):
    """The scalars of `FlightTrialResult` from a recording (see there)."""
    t = rec.t
    dt_rec = t[1] - t[0]
    hold_t = hold_steps / record_every * dt_rec
    seg_t = segment_steps / record_every * dt_rec
    after_hold = t > hold_t + 0.5 * dt_rec
    diff = (rec.y_hat - rec.y_lqr) * after_hold
    rms = jnp.sqrt(jnp.sum(diff**2) / jnp.sum(after_hold))
    dist = jnp.hypot(rec.q[:, 2] - rec.target[:, 2], rec.q[:, 3] - rec.target[:, 3])
    errors, settles = [], []
    n_hold, n_seg = hold_steps // record_every, segment_steps // record_every
    for k in range(2):
        seg = slice(n_hold + k * n_seg, n_hold + (k + 1) * n_seg)
        d = dist[seg]
        errors.append(d[-1])
        bad = d >= REACHED_M
        last_bad = jnp.max(jnp.where(bad, jnp.arange(n_seg), -1))
        settles.append(jnp.where(bad[-1], seg_t, (last_bad + 1) * dt_rec))
    max_theta = jnp.max(jnp.abs(rec.q[:, 0]))
    upright = max_theta < jnp.pi / 2
    on_ground = rec.q[:, 3] <= 5e-4  # within half a millimetre of the floor
    first = jnp.argmax(on_ground)
    touchdown = jnp.where(jnp.any(on_ground), jnp.abs(rec.q[jnp.maximum(first - 1, 0), 5]), 0.0)
    reached = upright & (errors[0] < REACHED_M) & (errors[1] < REACHED_M)
    return FlightTrialResult(
        rms, errors[0], errors[1], settles[0], settles[1], max_theta, upright, reached, touchdown, nonfinite(rec)
    )


@ranged(
    hold_steps=Range(1, integer=True),
    segment_steps=Range(1, integer=True),
    record_every=Range(1, integer=True),
    n_per_input=Range(1, integer=True),
    n_hidden=Range(1, integer=True),
    n_output=Range(1, integer=True),
)
def flight_trial(
    params: FlightTrialParams,
    key: jax.Array,
    *,
    hold_steps: int = 5000,
    segment_steps: int = 10000,
    record_every: int = 10,
    n_per_input: int = 50,
    n_hidden: int = 100,
    n_output: int = 50,
) -> FlightTrialResult:
    """Fly one RoboBee (flight 1 or the landing) with a fresh SNN learning online from the LQR."""
    key_net, key_robot = jax.random.split(key)
    robot = randomize(robobee_params(), params.spread, key=key_robot)
    K = jnp.asarray(nominal_gain())
    cparams = controller_params()._replace(
        mu_hidden=jnp.asarray(params.mu, jnp.float32),
        mu_output=jnp.asarray(params.mu, jnp.float32),
        tau_reward=jnp.asarray(params.tau_reward, jnp.float32),
    )
    config = ControllerConfig(n_per_input=n_per_input, n_hidden=n_hidden, n_output=n_output)
    plan = _plan(jnp.asarray(params.landing))
    rec = fly(
        config,
        cparams,
        robot,
        K,
        altitude_params(),
        plan,
        jnp.asarray(params.use_snn) > 0,
        hold_steps=hold_steps,
        segment_steps=segment_steps,
        record_every=record_every,
        key=key_net,
    )
    return summarize(rec, plan, hold_steps, segment_steps, record_every)
