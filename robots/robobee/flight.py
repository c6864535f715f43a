"""Closed-loop RoboBee flights: the SNN controller learning online from the LQR while it flies.

One flight (Sec. V of the RoboBee paper) is one ``lax.scan`` over neural steps
of ``dt = 0.1 ms``; the physics takes one MJX step per neural step (the same
``dt``, ``robots/robobee/physics.py``), so SNN, plasticity and physics form one
compiled program that ``jax.vmap`` batches over network seeds and robots.

Per step, at time ``t``:

1. The target is ``q0`` during the initial hold, then the waypoints in turn.
2. The teacher is the LQR torque on the lateral error,
   ``y = -K (q_lat - q*_lat)``, in units of ``TORQUE_UNIT``.
3. The SNN receives that same lateral error ``e = q_lat - q*_lat`` (shifted and
   scaled), so that it sees what the teacher sees; it steps once, decodes its
   output ``y_hat`` (Eq. (8)) and learns on ``y - y_hat`` (Eq. (9)-(10)).
4. The robot gets the altitude controller's lift and, as the lateral torque,
   ``y_hat`` (SNN flight) or ``y`` (LQR flight); during the hold the state is
   held at ``q0`` (the paper's first 500 ms, which lets the decoder's trace
   build up): the hold is a scan of its own that does not step the physics.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp

from robots.robobee.controller import TORQUE_UNIT, ControllerConfig, ControllerParams, controller_init, controller_step
from robots.robobee.dynamics import LATERAL
from robots.robobee.lqr import AltitudeParams, altitude_control, lateral_lqr
from robots.robobee.params import RoboBeeParams
from robots.robobee.physics import data_at, load_model, physics_step, state_of
from spikejax.errors import UserError

# Sec. V of the RoboBee paper: initial state and the two waypoints of flight 1.
Q0 = (-0.6, 0.0, 0.0, 0.02, 0.0, 0.0)
Q1 = (0.0, 0.0, 0.05, 0.08, 0.0, 0.0)
Q2 = (0.0, 0.0, 0.01, 0.05, 0.0, 0.0)
# Flight 2, the landing: to 1 cm above the ground, then down onto it.
LANDING_Q0 = (0.2, 0.0, 0.0, 0.04, 0.0, 0.0)
LANDING_Q1 = (0.0, 0.0, 0.02, 0.01, 0.0, 0.0)
LANDING_Q2 = (0.0, 0.0, 0.02, 0.0, 0.0, 0.0)


class FlightPlan(NamedTuple):
    """Where a flight starts and where it goes (traced).

    Attributes:
        q0: initial state, held during the hold, shape (6,).
        waypoints: the targets in turn, shape (n_waypoints, 6).
    """

    q0: jax.Array
    waypoints: jax.Array


# The weights' means are taken at every WEIGHTS_EVERY-th sample of a Recording.
WEIGHTS_EVERY = 10


class Recording(NamedTuple):
    """A flight sampled every ``record_every`` steps.

    Attributes:
        t: time of each sample, s, shape (n,).
        q: robot state, shape (n, 6).
        target: target state, shape (n, 6).
        y_hat: decoded SNN output, units of ``TORQUE_UNIT``, shape (n,).
        y_lqr: the teacher, same units, shape (n,).
        w_ih_mean: mean input->hidden weight over existing synapses, shape (n,),
            taken every `WEIGHTS_EVERY` samples and held in between (reading all
            the weights costs as much as several steps of the event-driven network).
        w_ho_mean: mean hidden->output weight over existing synapses, shape (n,), as ``w_ih_mean``.
    """

    t: jax.Array
    q: jax.Array
    target: jax.Array
    y_hat: jax.Array
    y_lqr: jax.Array
    w_ih_mean: jax.Array
    w_ho_mean: jax.Array


def flight_plan(name: str) -> FlightPlan:
    """``"waypoints"`` (flight 1: q0 -> q1 -> q2) or ``"landing"`` (flight 2)."""
    plans = {"waypoints": (Q0, (Q1, Q2)), "landing": (LANDING_Q0, (LANDING_Q1, LANDING_Q2))}
    if name not in plans:
        raise UserError(f"flight must be one of {sorted(plans)}, got {name!r}")
    q0, waypoints = plans[name]
    return FlightPlan(jnp.asarray(q0, jnp.float32), jnp.asarray(waypoints, jnp.float32))


def fly(
    config: ControllerConfig,
    cparams: ControllerParams,
    robot: RoboBeeParams,
    K: jax.Array,
    altitude: AltitudeParams,
    plan: FlightPlan,
    use_snn: jax.Array,
    *,
    hold_steps: int = 5000,
    segment_steps: int = 10000,
    record_every: int = 10,
    key: jax.Array,
) -> Recording:
    """Fly ``plan`` with the SNN (``use_snn`` true) or the LQR on the lateral axis.

    The SNN learns online in both cases (in the LQR flight it learns without
    acting), so the two flights of one seed differ only in who steers.

    Args:
        config: network sizes (static).
        cparams: the controller's traced parameters.
        robot: the flown robot (mass, inertia, drag...).
        K: LQR gain, N m per unit of the lateral state, shape (4,) or (1, 4).
        altitude: gains of the altitude controller.
        plan: initial state and waypoints.
        use_snn: bool scalar: who applies the lateral torque.
        hold_steps: steps of the initial hold (static; 5000 = 500 ms).
        segment_steps: steps spent on each waypoint (static).
        record_every: sampling of the recording (static); ``hold_steps`` and ``segment_steps`` are multiples of it.
        key: the network's PRNG key (connectivity, weights, thresholds).

    Returns:
        The flight, sampled every ``record_every`` steps.
    """

    def step(ctrl, error, y_lqr):
        return controller_step(config, cparams, ctrl, error, y_lqr, jnp.float32(1.0))

    def weight_means(ctrl):
        return jnp.stack([jnp.sum(ctrl.w_ih) / jnp.sum(ctrl.mask_ih), jnp.sum(ctrl.w_ho) / jnp.sum(ctrl.mask_ho)])

    ctrl = controller_init(config, cparams, key=key)
    return _flight(
        step, ctrl, weight_means, robot, K, altitude, plan, use_snn, cparams.dt, hold_steps, segment_steps, record_every
    )


def fly_controller(
    step: Callable,
    state,
    robot: RoboBeeParams,
    K: jax.Array,
    altitude: AltitudeParams,
    plan: FlightPlan,
    *,
    dt: float,
    hold_steps: int = 5000,
    segment_steps: int = 10000,
    record_every: int = 10,
) -> Recording:
    """Fly ``plan`` with a frozen lateral controller: any ``step(state, error) -> (state, y_hat)``.

    The flight of `fly` with the SNN steering, for a controller that does not
    learn: a trained spikejax network, or a network imported from a NIR graph
    (`robots.robobee.nir.graph_controller_step`). ``error`` is the lateral
    error ``q_lat - q*_lat`` the SNN sees in `fly`; ``y_hat`` is in units of
    `TORQUE_UNIT` and clipped to the actuator's range, as in `fly`. The LQR
    teacher is still recorded (``y_lqr``) for comparison; the weight means are
    NaN (the controller's weights are not known here).

    Args:
        step: the controller's step (closed over its static structure).
        state: its state at the start of the hold.
        robot, K, altitude, plan: as `fly`.
        dt: the controller's step, s; the physics takes one step per controller step.
        hold_steps, segment_steps, record_every: as `fly`.
    """
    nan = jnp.full((2,), jnp.nan, jnp.float32)
    return _flight(
        lambda s, error, _: step(s, error),
        state,
        lambda _: nan,
        robot,
        K,
        altitude,
        plan,
        jnp.bool_(True),
        dt,
        hold_steps,
        segment_steps,
        record_every,
    )


def _flight(
    controller, ctrl, weight_means, robot, K, altitude, plan, use_snn, dt, hold_steps, segment_steps, record_every
) -> Recording:
    """The flight's scans, for any ``controller(state, error, y_lqr) -> (state, y_hat)``."""
    model = load_model()
    n_waypoints = plan.waypoints.shape[0]
    n_steps = hold_steps + n_waypoints * segment_steps
    if hold_steps % record_every or segment_steps % record_every:
        raise UserError(
            f"hold_steps ({hold_steps}) and segment_steps ({segment_steps}) must be multiples of "
            f"record_every ({record_every})"
        )
    lat = jnp.asarray(LATERAL)
    targets = jnp.concatenate([plan.q0[None], plan.waypoints])

    def step(carry, i, moving):
        data, ctrl = carry
        q = state_of(data)
        segment = jnp.where(i < hold_steps, 0, 1 + (i - hold_steps) // segment_steps)
        target = targets[segment]
        # The teacher within the actuator's range: the SNN cannot be asked for more torque than exists.
        y_lqr = jnp.clip(lateral_lqr(K, q, target) / TORQUE_UNIT, -1.0, 1.0)
        ctrl, y_hat = controller(ctrl, q[lat] - target[lat], y_lqr)
        if moving:
            torque = jnp.where(use_snn, jnp.clip(y_hat, -1.0, 1.0), y_lqr) * TORQUE_UNIT
            lift = altitude_control(altitude, q, target, robot)
            data = physics_step(model, data, robot, lift, torque)
        return (data, ctrl), (q, target, y_hat, y_lqr)

    def record(carry, block, moving):
        carry, means = carry[:2], carry[2]
        carry, (q, target, y_hat, y_lqr) = jax.lax.scan(lambda c, i: step(c, i, moving), carry, block)
        # The block index is the same for every flight of a batch, so this stays a branch under vmap.
        sample = (block[0] // record_every) % WEIGHTS_EVERY == 0
        means = jax.lax.cond(sample, weight_means, lambda _: means, carry[1])
        return (*carry, means), (q[-1], target[-1], y_hat[-1], y_lqr[-1], means[0], means[1])

    carry = (data_at(model, plan.q0), ctrl, weight_means(ctrl))
    blocks = jnp.arange(n_steps).reshape(-1, record_every)
    n_hold = hold_steps // record_every
    # The hold and the flight as two scans: during the hold the physics is not stepped at all.
    carry, held = jax.lax.scan(lambda c, b: record(c, b, False), carry, blocks[:n_hold])
    _, flown = jax.lax.scan(lambda c, b: record(c, b, True), carry, blocks[n_hold:])
    q, target, y_hat, y_lqr, w_ih, w_ho = jax.tree.map(lambda a, b: jnp.concatenate([a, b]), held, flown)
    t = (blocks[:, -1] + 1) * dt
    return Recording(t=t, q=q, target=target, y_hat=y_hat, y_lqr=y_lqr, w_ih_mean=w_ih, w_ho_mean=w_ho)
