"""Closed-loop flights through `robots.robobee.flight.fly` (the LQR steering; the SNN learning beside it)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from robots.robobee.controller import TORQUE_UNIT, ControllerConfig, controller_params
from robots.robobee.flight import flight_plan, fly, fly_controller
from robots.robobee.lqr import altitude_params, lateral_gain
from robots.robobee.params import robobee_params

LQR_STEPS = dict(hold_steps=2000, segment_steps=10000)


@pytest.fixture(scope="module")
def lqr_flight():
    robot = robobee_params()
    K = jnp.asarray(lateral_gain(robot), jnp.float32).reshape(4)
    plan = flight_plan("waypoints")
    rec = jax.jit(
        lambda key: fly(
            ControllerConfig(), controller_params(), robot, K, altitude_params(), plan, False, key=key, **LQR_STEPS
        )
    )(jax.random.key(0))
    return robot, K, plan, rec


def test_lqr_flight_reaches_both_waypoints_and_holds_q0(lqr_flight):
    robot, K, plan, rec = lqr_flight
    t, q = np.asarray(rec.t), np.asarray(rec.q)
    # The hold keeps the state at q0 exactly (Sec. V: the first 500 ms in the paper).
    np.testing.assert_allclose(q[t <= 0.2], np.broadcast_to(np.asarray(plan.q0), q[t <= 0.2].shape), atol=1e-7)
    for end, target in ((1.2, plan.waypoints[0]), (2.2, plan.waypoints[1])):
        i = np.searchsorted(t, end - 1e-6)
        assert np.hypot(q[i, 2] - target[2], q[i, 3] - target[3]) < 2e-3
        assert abs(q[i, 0]) < 0.05
    assert np.abs(q[:, 0]).max() < np.pi / 2
    # The teacher is clipped to the actuator's range.
    assert np.abs(np.asarray(rec.y_lqr)).max() <= 1.0


def test_snn_flight_learning_online_reaches_both_waypoints():
    # The paper's Fig. 8: the SNN, learning from the LQR while it steers, flies q0 -> q1 -> q2.
    robot = robobee_params()
    K = jnp.asarray(lateral_gain(robot), jnp.float32).reshape(4)
    plan = flight_plan("waypoints")
    run = jax.jit(
        jax.vmap(
            lambda key: fly(
                ControllerConfig(),
                controller_params(),
                robot,
                K,
                altitude_params(),
                plan,
                True,
                hold_steps=5000,
                segment_steps=10000,
                key=key,
            )
        )
    )
    rec = run(jax.vmap(jax.random.key)(jnp.arange(3)))
    t, q = np.asarray(rec.t[0]), np.asarray(rec.q)
    for end, target in ((1.5, plan.waypoints[0]), (2.5, plan.waypoints[1])):
        i = np.searchsorted(t, end - 1e-6)
        assert np.all(np.hypot(q[:, i, 2] - target[2], q[:, i, 3] - target[3]) < 5e-3)
    assert np.all(np.abs(q[:, :, 0]).max(axis=1) < np.pi / 2)
    # The SNN's torque follows the teacher's after the hold (RMS in units of the torque limit).
    after = t > 0.5
    rms = np.sqrt(np.mean((np.asarray(rec.y_hat) - np.asarray(rec.y_lqr))[:, after] ** 2, axis=1))
    assert np.all(rms < 0.5)


def test_a_frozen_controller_that_computes_the_lqr_flies_the_lqr_flight(lqr_flight):
    """`fly_controller` with the teacher's own law as the controller is `fly`'s LQR flight, state for state."""
    robot, K, plan, teacher = lqr_flight

    def lqr(state, error):
        return state + 1, jnp.clip(-jnp.dot(K, error) / TORQUE_UNIT, -1.0, 1.0)

    dt = float(controller_params().dt)
    frozen = jax.jit(lambda: fly_controller(lqr, jnp.int32(0), robot, K, altitude_params(), plan, dt=dt, **LQR_STEPS))()
    np.testing.assert_allclose(np.asarray(frozen.q), np.asarray(teacher.q), rtol=0, atol=1e-6)
    np.testing.assert_allclose(np.asarray(frozen.y_hat), np.asarray(teacher.y_lqr), rtol=0, atol=1e-6)
    np.testing.assert_array_equal(np.asarray(frozen.t), np.asarray(teacher.t))
    assert np.all(np.isnan(np.asarray(frozen.w_ih_mean)))
