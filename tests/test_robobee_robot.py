"""The RoboBee robot: MJX model against Eq. (4)-(5), open-loop instability, LQR teacher."""

import time

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
import scipy.linalg
from scipy.integrate import solve_ivp

from robots.robobee import dynamics, lqr, physics
from robots.robobee.params import max_lift, randomize, robobee_params

DT = 1e-4
# Paper, Sec. V.
Q0 = np.array([-0.6, 0.0, 0.0, 0.02, 0.0, 0.0])
Q1 = np.array([0.0, 0.0, 0.05, 0.08, 0.0, 0.0])
Q2 = np.array([0.0, 0.0, 0.01, 0.05, 0.0, 0.0])
# Open-loop runs: 0.6 s at DT, one compiled program for every open-loop test.
N_OPEN = 6000
# Closed-loop flight: 1 s toward q1, then 1 s toward q2.
N_LEG = 10000

_rollout = jax.jit(physics.rollout)


def _with_timestep(dt):
    # Every open-loop test passes a model built this way, so `_rollout` compiles once.
    model = physics.load_model()
    return model.replace(opt=model.opt.replace(timestep=jnp.asarray(dt, jnp.float32)))


def _numpy_params(p):
    return jax.tree.map(np.float64, p)


@jax.jit
def _fly(params, K, gains, q0, targets):
    """The LQR teacher and the altitude controller fly the robot through ``targets``."""
    model = physics.load_model()

    def step(data, q_target):
        q = physics.state_of(data)
        tau_c = lqr.lateral_lqr(K, q, q_target)
        f_lift = lqr.altitude_control(gains, q, q_target, params)
        data = physics.physics_step(model, data, params, f_lift, tau_c)
        return data, physics.state_of(data)

    _, qs = jax.lax.scan(step, physics.data_at(model, q0), targets)
    return qs


def _waypoints():
    legs = np.concatenate([np.tile(Q1, (N_LEG, 1)), np.tile(Q2, (N_LEG, 1))])
    return jnp.asarray(legs, jnp.float32)


@pytest.fixture(scope="module")
def teacher():
    p = robobee_params()
    return lqr.lateral_gain(p), lqr.altitude_params()


@pytest.fixture(scope="module")
def nominal_flight(teacher):
    K, gains = teacher
    K = jnp.asarray(K, jnp.float32)
    qs = _fly(robobee_params(), K, gains, jnp.asarray(Q0, jnp.float32), _waypoints())
    return np.asarray(qs, np.float64)


def test_model_matches_params_and_fig3_convention():
    mj = physics.load_mj_model()
    p = robobee_params()
    assert (mj.nq, mj.nv, mj.nbody) == (3, 3, 2)
    assert [mj.joint(i).name for i in range(3)] == ["x", "z", "theta"]
    assert mj.opt.timestep == DT and mj.opt.integrator == mujoco.mjtIntegrator.mjINT_EULER
    assert mj.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_CONTACT
    np.testing.assert_allclose(mj.body_mass[1], p.mass, rtol=1e-6)
    np.testing.assert_allclose(mj.body_inertia[1, 1], p.inertia_y, rtol=1e-6)

    model = physics.load_model()
    q = jnp.array([0.3, -2.0, 0.01, 0.04, 0.2, -0.1])
    data = physics.data_at(model, q)
    np.testing.assert_array_equal(physics.state_of(data), q)
    # Fig. 3: a positive theta tilts the body axis z' (the lift) toward +x.
    z_axis = np.asarray(data.xmat[1][:, 2])
    np.testing.assert_allclose(z_axis, [np.sin(0.3), 0.0, np.cos(0.3)], atol=1e-6)
    np.testing.assert_allclose(data.xpos[1], [0.01, 0.0, 0.04], atol=1e-7)

    heavy = p._replace(mass=p.mass * 1.2, inertia_y=p.inertia_y * 0.8, g=p.g * 0.5)
    m2 = physics.set_params(model, heavy)
    np.testing.assert_allclose(m2.body_mass[1], heavy.mass, rtol=1e-6)
    np.testing.assert_allclose(m2.body_inertia[1, 1], heavy.inertia_y, rtol=1e-6)
    np.testing.assert_allclose(m2.opt.gravity, [0.0, 0.0, -heavy.g], rtol=1e-6)


def test_generalized_forces_hand_computed():
    p = robobee_params()
    # Upright, moving at 0.1 m/s along +x: drag -b_w * 0.1 along x' = x, acting r_w above the CoM.
    q = jnp.array([0.0, 0.0, 0.0, 0.05, 0.1, 0.0])
    qfrc = physics.generalized_forces(q, p, p.mass * p.g, 0.5e-6)
    f_d = -2.0e-4 * 0.1
    np.testing.assert_allclose(qfrc, [f_d, 80e-6 * 9.81, 0.5e-6 + 9e-3 * f_d], rtol=1e-5)
    # Tilted and pitching, no translation: the wing point moves at r_w theta_dot along x'.
    q = jnp.array([0.4, 3.0, 0.0, 0.05, 0.0, 0.0])
    qfrc = physics.generalized_forces(q, p, 1e-4, 0.0)
    f_d = -2.0e-4 * 9e-3 * 3.0
    expected = [
        1e-4 * np.sin(0.4) + f_d * np.cos(0.4),
        1e-4 * np.cos(0.4) - f_d * np.sin(0.4),
        9e-3 * f_d,
    ]
    np.testing.assert_allclose(qfrc, expected, rtol=1e-5)


def test_clip_controls_are_the_papers_limits():
    p = robobee_params()
    weight = float(p.mass * p.g)
    f, tau = dynamics.clip_controls(p, jnp.asarray(3.0 * weight), jnp.asarray(-5e-6))
    np.testing.assert_allclose([f, tau], [1.5 * weight, -1e-6], rtol=1e-6)
    f, tau = dynamics.clip_controls(p, jnp.asarray(-1.0), jnp.asarray(0.3e-6))
    np.testing.assert_allclose([f, tau], [0.0, 0.3e-6], rtol=1e-6)
    np.testing.assert_allclose(max_lift(p), 1.5 * weight, rtol=1e-6)


def test_rhs_numpy_equals_jax_and_hover_is_equilibrium():
    p = robobee_params()
    pn = _numpy_params(p)
    q = np.array([0.3, -2.0, 0.01, 0.04, 0.2, -0.1])
    a = dynamics.rhs(q, pn, 1e-3, 0.4e-6)
    b = dynamics.rhs(jnp.asarray(q, jnp.float32), p, 1e-3, 0.4e-6)
    assert isinstance(a, np.ndarray) and a.dtype == np.float64
    np.testing.assert_allclose(b, a, rtol=2e-5, atol=1e-6)
    np.testing.assert_allclose(dynamics.rhs(np.zeros(6), pn, pn.mass * pn.g, 0.0), 0.0, atol=1e-12)


@pytest.mark.parametrize("lift_factor", [1.03, 0.97])
def test_mjx_matches_solve_ivp(lift_factor):
    """MJX under open-loop inputs against Eq. (4)-(5) integrated by solve_ivp (rtol 1e-8).

    MuJoCo's semi-implicit Euler has a global error ``C dt``, so the check is
    twofold: at ``dt = 0.1 ms`` the error is below 1 % of each quantity's range
    over the flight (measured 0.07-0.34 %; a 5 % error in ``r_w`` gives 3-15 %),
    and doubling ``dt`` doubles it (ratio 1.7-2.3), which shows it is the
    integrator's truncation error and not a modelling difference (that would
    not shrink with ``dt``). float32 rounding is far below either.
    """
    p = robobee_params()
    pn = _numpy_params(p)
    t_end = 0.3
    q0 = np.array([0.05, 0.0, 0.0, 0.05, 0.0, 0.0])
    f_lift = lift_factor * float(pn.mass * pn.g)
    amp, omega = 1e-7, 2 * np.pi * 5.0

    def torque(t):
        return amp * np.sin(omega * t)

    ref = solve_ivp(
        lambda t, q: dynamics.rhs(q, pn, f_lift, torque(t)),
        (0.0, t_end),
        q0,
        method="DOP853",
        rtol=1e-8,
        atol=1e-12,
        dense_output=True,
    )
    assert ref.success
    scale = np.ptp(ref.sol(np.linspace(0.0, t_end, 301)), axis=1)
    scale[3] = max(scale[3], 1e-3)  # z barely moves at 0.97-1.03 m g: compare with 1 mm
    errors = {}
    for dt in (DT, 2 * DT):
        model = _with_timestep(dt)
        t_steps = np.arange(N_OPEN) * dt
        qs = _rollout(
            model,
            p,
            jnp.asarray(q0, jnp.float32),
            jnp.full((N_OPEN,), f_lift, jnp.float32),
            jnp.asarray(torque(t_steps), jnp.float32),
        )
        n = int(round(t_end / dt))
        expected = ref.sol(np.arange(n + 1) * dt).T
        errors[dt] = np.abs(np.asarray(qs[: n + 1], np.float64) - expected).max(axis=0)
    relative = errors[DT] / scale
    assert np.all(relative < 1e-2), relative
    ratio = errors[2 * DT] / errors[DT]
    assert np.all((ratio > 1.7) & (ratio < 2.3)), ratio


def test_uncontrolled_hover_oscillates_with_growing_amplitude():
    """Sec. II-B: hovering with f_L = m g, tau_c = 0 is unstable, a growing oscillation."""
    p = robobee_params()
    A, B = lqr.linearize(p)
    m, i_y, b_w, r_w, g = 80e-6, 1.4e-9, 2.0e-4, 9e-3, 9.81
    expected_a = [
        [0, 1, 0, 0],
        [0, -b_w * r_w**2 / i_y, 0, -b_w * r_w / i_y],
        [0, 0, 0, 1],
        [g, -b_w * r_w / m, 0, -b_w / m],
    ]
    np.testing.assert_allclose(A, expected_a, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(B, [[0], [1 / i_y], [0], [0]], rtol=1e-5)
    eig = np.linalg.eigvals(np.asarray(A, np.float64))
    unstable = eig[eig.real > 0]
    assert len(unstable) == 2 and np.all(np.abs(unstable.imag) > 0)
    growth, omega = unstable[0].real, abs(unstable[0].imag)  # about 7.5 1/s, 19.5 rad/s

    theta0 = 1e-3
    q0 = jnp.array([theta0, 0.0, 0.0, 0.05, 0.0, 0.0])
    qs = _rollout(
        _with_timestep(DT),
        p,
        q0,
        jnp.full((N_OPEN,), p.mass * p.g),
        jnp.zeros((N_OPEN,)),
    )
    theta = np.abs(np.asarray(qs[:, 0], np.float64))
    peaks = np.flatnonzero((theta[1:-1] > theta[:-2]) & (theta[1:-1] >= theta[2:])) + 1
    assert len(peaks) >= 3
    # Each swing is larger than the last, and the envelope grows as exp(Re(lambda) t).
    assert np.all(np.diff(theta[peaks]) > 0)
    assert theta[peaks[-1]] > 20 * theta0
    t_peaks = peaks * DT
    fitted_growth = np.polyfit(t_peaks, np.log(theta[peaks]), 1)[0]
    np.testing.assert_allclose(fitted_growth, growth, rtol=0.1)
    np.testing.assert_allclose(np.diff(t_peaks).mean(), np.pi / omega, rtol=0.05)


def test_floor_stops_a_falling_robot():
    """Without lift the robot falls from 2 cm, lands at z = 0 and stays there."""
    p = robobee_params()
    q0 = jnp.array([0.0, 0.0, 0.0, 0.02, 0.0, 0.0])
    qs = np.asarray(_rollout(_with_timestep(DT), p, q0, jnp.zeros((N_OPEN,)), jnp.zeros((N_OPEN,))))
    assert qs[:, 3].min() == 0.0 and qs[-1, 3] == 0.0 and qs[-1, 5] == 0.0
    # Free fall until the floor (at sqrt(2 z0 / g) = 64 ms), by semi-implicit Euler:
    # z_k = z0 - g dt^2 k (k + 1) / 2, i.e. z0 - g t^2 / 2 to O(dt).
    k = np.arange(600)
    np.testing.assert_allclose(qs[:600, 3], 0.02 - 0.5 * 9.81 * DT**2 * k * (k + 1), atol=1e-6)


def test_lqr_gain_is_optimal_and_stabilizes():
    p = robobee_params()
    K = lqr.lateral_gain(p)
    A, B = (np.asarray(a, np.float64) for a in lqr.linearize(p))
    Q, R = lqr.bryson_weights(lqr.LATERAL_SCALES, 1e-6)
    assert K.shape == (1, 4) and np.all(K > 0)
    closed = A - B @ K
    assert np.all(np.linalg.eigvals(closed).real < 0)
    # Optimality: with P the cost-to-go of u = -K e, (A-BK)^T P + P (A-BK) + Q + K^T R K = 0,
    # the gain must satisfy K = R^-1 B^T P (the stationarity condition of the Riccati equation).
    cost_to_go = scipy.linalg.solve_continuous_lyapunov(closed.T, -(Q + K.T @ R @ K))
    np.testing.assert_allclose(np.linalg.solve(R, B.T @ cost_to_go), K, rtol=1e-6)
    np.testing.assert_allclose(K, [[2.82e-6, 7.93e-8, 2.00e-5, 2.18e-6]], rtol=5e-3)


def test_lateral_lqr_sign_and_altitude_control_hand_computed():
    p = robobee_params()
    K = jnp.asarray([[1.0, 2.0, 3.0, 4.0]])
    q = jnp.array([0.1, 0.2, 0.3, 0.05, 0.4, 0.0])
    target = jnp.array([0.0, 0.0, 0.5, 0.08, 0.0, 0.0])
    expected = -(1.0 * 0.1 + 2.0 * 0.2 + 3.0 * (0.3 - 0.5) + 4.0 * 0.4)
    np.testing.assert_allclose(lqr.lateral_lqr(K, q, target), expected, rtol=1e-6)

    gains = lqr.altitude_params(kp=100.0, kd=20.0, cos_min=0.5)
    weight = float(p.mass * p.g)
    at_target = jnp.array([0.0, 0.0, 0.0, 0.08, 0.0, 0.0])
    lift = lqr.altitude_control(gains, at_target, at_target, p)
    np.testing.assert_allclose(lift, weight, rtol=1e-6)
    tilted = at_target.at[0].set(0.5).at[5].set(-0.01)
    expected = 80e-6 * (9.81 + 20.0 * 0.01) / np.cos(0.5)
    lift = lqr.altitude_control(gains, tilted, at_target, p)
    np.testing.assert_allclose(lift, expected, rtol=1e-5)
    low = at_target.at[3].set(0.0)
    lift = lqr.altitude_control(gains, low, at_target, p)
    np.testing.assert_allclose(lift, 1.5 * weight, rtol=1e-6)
    high = at_target.at[3].set(0.3)
    assert float(lqr.altitude_control(gains, high, at_target, p)) == 0.0


def test_lqr_teacher_flies_q0_q1_q2(nominal_flight):
    """Sec. V: from q0 to q1 (1 s), then to q2 (1 s), with the actuators' limits."""
    qs = nominal_flight
    assert np.all(np.isfinite(qs))
    assert np.abs(qs[:, 0]).max() < np.pi / 2
    assert qs[:, 3].min() > 0.01
    # Sec. V: the initial tilt first carries the robot toward -x.
    assert qs[:, 2].min() < -0.005
    for end, target in ((N_LEG - 1, Q1), (2 * N_LEG - 1, Q2)):
        position_error = np.hypot(*(qs[end, 2:4] - target[2:4]))
        assert position_error < 1e-3, position_error
        assert abs(qs[end, 0]) < 0.01
        assert np.abs(qs[end, 4:6]).max() < 0.02


def test_vmap_over_randomized_robots_equals_single_runs(teacher):
    K, gains = teacher
    K = jnp.asarray(K, jnp.float32)
    keys = jax.random.split(jax.random.key(7), 8)
    robots = jax.vmap(lambda k: randomize(robobee_params(), key=k))(keys)
    nominal = robobee_params()
    for name in ("mass", "b_w", "inertia_y"):
        factor = np.asarray(getattr(robots, name)) / float(getattr(nominal, name))
        assert np.all((factor >= 0.8) & (factor <= 1.2)) and np.ptp(factor) > 0.05
    np.testing.assert_array_equal(robots.r_w, np.full(8, nominal.r_w))

    q0, targets = jnp.asarray(Q0, jnp.float32), _waypoints()
    fly_batch = jax.vmap(_fly, in_axes=(0, None, None, None, None))
    batched = np.asarray(fly_batch(robots, K, gains, q0, targets))
    for i in range(8):
        robot = jax.tree.map(lambda x: x[i], robots)
        single = np.asarray(_fly(robot, K, gains, q0, targets))
        # Batched and single programs round differently in float32 (measured: below
        # 3e-7 of each quantity's range over the flight); a real difference would be O(1).
        difference = np.abs(batched[i] - single).max(axis=0)
        assert np.all(difference <= 1e-5 * np.ptp(single, axis=0) + 1e-9), difference
    # The teacher designed for the nominal robot also flies every randomized one.
    final_error = np.hypot(batched[:, -1, 2] - Q2[2], batched[:, -1, 3] - Q2[3])
    assert np.all(final_error < 2e-3), final_error


def test_physics_step_compiles_within_seconds():
    model, p = physics.load_model(), robobee_params()
    data = physics.data_at(model, jnp.asarray(Q1, jnp.float32))
    start = time.perf_counter()
    step = jax.jit(physics.physics_step).lower(model, data, p, p.mass * p.g, 0.0).compile()
    compile_s = time.perf_counter() - start
    data = step(model, data, p, p.mass * p.g, 0.0)
    assert compile_s < 15.0, compile_s
    np.testing.assert_allclose(physics.state_of(data), Q1, atol=1e-6)
