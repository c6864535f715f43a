"""The slithering gait: Eq. (1) by hand, the head compensation's closed form, and what the snake does under it."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from robots.snake.gait import JOINT_LIMIT, gait_params, gait_period, head_compensation, joint_targets
from robots.snake.physics import make_physics
from spikejax.vision.pipe import camera_offset


def test_eq1_by_hand():
    p = gait_params()._replace(P_head=0.5, P_tail=1.0, C_e=0.05)
    t, steer = 0.7, 0.2
    alpha = np.asarray(joint_targets(p, t, steer, compensate=False))
    for i in range(1, 17):
        P = 0.5 + 0.5 * (i - 1) / 15
        if i % 2:
            expected = P * p.A_o * math.sin(i * p.Omega_o + t * p.omega_o + p.delta_o) + steer
        else:
            expected = P * p.A_e * math.sin(i * p.Omega_e + t * p.omega_e) + p.C_e
        assert alpha[i - 1] == pytest.approx(expected, abs=1e-6), i


def test_head_compensation_zeroes_the_mean_module_yaw():
    """With the compensated first joint, sum over odd j of (17 - j) alpha_j, 17 x the modules' mean yaw, is 0."""
    p = gait_params()
    j = np.arange(1, 17)
    weights = np.where(j % 2 == 1, 17 - j, 0)
    for t in np.linspace(0.0, 2.5, 7):
        alpha = np.asarray(joint_targets(p, t, 0.05))
        assert np.abs(alpha).max() < JOINT_LIMIT  # no clipping at these values
        assert float(weights @ alpha) == pytest.approx(0.0, abs=1e-5)
    alpha = np.asarray(joint_targets(p, 0.3, compensate=False))
    assert float(head_compensation(jnp.asarray(alpha))) == pytest.approx(-(weights[2:] @ alpha[2:]) / 16, abs=1e-6)


def test_head_offset_adds_to_the_first_joint_and_targets_are_clipped():
    p = gait_params()
    base = joint_targets(p, 1.0, 0.0)
    shifted = joint_targets(p, 1.0, 0.0, 0.3)
    np.testing.assert_allclose(shifted - base, np.eye(16)[0] * 0.3, atol=1e-6)
    assert float(jnp.max(jnp.abs(joint_targets(p, 1.0, 3.0)))) == pytest.approx(JOINT_LIMIT)


def test_compensation_from_targets_whips_with_the_steering_and_from_joints_does_not():
    """A jump of C_o moves the target-compensated joint 1 by -(14 + 12 + ... + 2) / 16 = -3.5 times it at once.

    Read from the measured joints, joint 1 is a function of the body as it is:
    the same joints give the same head target whatever the steering.
    """
    p = gait_params()
    t = 0.9
    jump = float(joint_targets(p, t, 0.125)[0] - joint_targets(p, t, -0.125)[0])
    assert jump == pytest.approx(-3.5 * 0.25, abs=1e-5)
    joints = jnp.asarray(np.random.default_rng(0).uniform(-0.4, 0.4, 16), jnp.float32)
    left, right = (joint_targets(p, t, s, 0.1, joints=joints) for s in (-0.125, 0.125))
    assert float(left[0]) == pytest.approx(float(right[0]), abs=1e-7)
    assert float(left[0]) == pytest.approx(float(head_compensation(joints)) + 0.1, abs=1e-6)
    # the other joints still follow Eq. (1), steered
    np.testing.assert_allclose(right[1:], joint_targets(p, t, 0.125)[1:], atol=1e-7)


def test_camera_offset_eq6_phase_identity():
    """For theta = a sin(wt + phi), Eq. (5)'s theta_tuned is alpha a sin(wt + phi + phi_pos)."""
    a, w, phi, alpha, phi_pos, A = math.radians(35), 2.0, 0.4, 2.571, 0.908, 1.4
    for t in (0.0, 0.3, 1.1):
        theta, theta_dot = a * math.sin(w * t + phi), a * w * math.cos(w * t + phi)
        expected = A * math.sin(alpha * a * math.sin(w * t + phi + phi_pos))
        got = camera_offset(theta, theta_dot, swing_amplitude=A, ratio=alpha, phase=phi_pos, omega=w)
        assert float(got) == pytest.approx(expected, abs=1e-5)


def test_camera_offset_on_the_snakes_head_joint():
    """Eq. (4)-(6) of the pipe-tracking paper fed with this gait's head joint (Eq. (1), uncompensated, and its rate).

    The head joint of `gait_params` is Eq. (4) with ``a = A_o``, ``omega = omega_o``,
    ``phi = Omega_o + delta_o``; the camera offset from its angle and rate is the phase-shifted swing.
    """
    p = gait_params()
    A, alpha, phi_pos = 1.4, math.radians(90) / p.A_o, 0.908
    for t in (0.0, 0.4, 1.3, 2.2):
        theta, theta_dot = jax.jvp(lambda s: joint_targets(p, s, compensate=False)[0], (t,), (1.0,))
        got = camera_offset(theta, theta_dot, swing_amplitude=A, ratio=alpha, phase=phi_pos, omega=p.omega_o)
        expected = A * math.sin(alpha * p.A_o * math.sin(p.omega_o * t + p.Omega_o + p.delta_o + phi_pos))
        assert float(got) == pytest.approx(expected, abs=1e-5), t


# ----------------------------------------------------------------- on the robot

PERIOD = float(gait_period(gait_params()))
SECONDS = 4 * PERIOD
CONTROL_DT = 0.02
# (steer, compensate) of each simulated snake, all in one batch.
CASES = [(0.0, True), (0.1, True), (-0.1, True), (0.0, False)]


@pytest.fixture(scope="module")
def runs():
    """Four snakes for four gait periods (10 s), batched: head pose and centre of mass every control step."""
    phys = make_physics("mujoco")
    gait = gait_params()
    n = int(round(SECONDS / CONTROL_DT))

    def run(steer, compensate):
        def body(state, _):
            state = phys.step(state, joint_targets(gait, state.time, steer, 0.0, compensate))
            return state, (state.time, state.head_mat, state.com_pos)

        return jax.lax.scan(body, phys.init(), None, length=n)[1]

    steers = jnp.array([c[0] for c in CASES])
    compensate = jnp.array([c[1] for c in CASES])
    time, head_mat, com = jax.jit(jax.vmap(run))(steers, compensate)
    yaw = np.unwrap(np.arctan2(head_mat[..., 1, 0], head_mat[..., 0, 0]), axis=1)
    return np.asarray(time[0]), yaw, np.asarray(com)


def _per_period(x, per):
    return x[:, : (x.shape[1] // per) * per].reshape(x.shape[0], -1, per, *x.shape[2:])


def test_straight_gait_moves_forward_steadily(runs):
    time, yaw, com = runs
    per = int(round(PERIOD / CONTROL_DT))
    ends = _per_period(com, per)[0, :, -1, :2]  # the straight snake's position at the end of each period
    advance = np.diff(ends[:, 0])  # along +x, where the head looked at rest
    speed = advance / PERIOD
    assert np.all(speed > 0.05), speed  # forward, m/s
    assert np.ptp(speed) < 0.2 * speed.mean(), speed  # steady from period to period
    assert abs(ends[-1, 1] - ends[0, 1]) < 0.2 * (ends[-1, 0] - ends[0, 0])  # and straight


def test_sign_of_C_o_sets_the_sign_of_the_turn(runs):
    time, yaw, com = runs
    per = int(round(PERIOD / CONTROL_DT))
    mean_yaw = _per_period(yaw, per).mean(axis=2)
    turn = (mean_yaw[:, -1] - mean_yaw[:, 1]) / (2 * PERIOD)  # rad/s, after the first period
    straight, right, left = turn[0], turn[1], turn[2]
    assert right < -0.03 and left > 0.03  # C_o > 0 turns clockwise, C_o < 0 counter-clockwise
    assert abs(straight) < 0.25 * min(-right, left)


def test_head_compensation_reduces_head_yaw_oscillation(runs):
    time, yaw, com = runs
    per = int(round(PERIOD / CONTROL_DT))
    steady = slice(per, None)

    def oscillation(y):
        # Head yaw about its trend (a slow drift of the heading is not oscillation).
        t = time[steady]
        return np.std(y[steady] - np.polyval(np.polyfit(t, y[steady], 1), t))

    with_comp, without = oscillation(yaw[0]), oscillation(yaw[3])
    assert with_comp < 0.7 * without, (with_comp, without)
