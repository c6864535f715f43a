"""The head's residual swing and its phase-locked correction (`robots.snake.head_swing`, `gait.swing_correction`)."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from robots.snake import head_swing
from robots.snake.env import SnakeEnv
from robots.snake.gait import gait_params, gait_period, swing_correction
from spikejax.errors import UserError


def test_fundamental_recovers_a_sine_and_composes_with_a_correction():
    omega = 2 * math.pi / 2.5
    t = np.arange(0, 25, 0.02)
    x = 0.3 * np.sin(omega * t + 0.7) + 0.05
    z = head_swing.fundamental(x, t, omega)
    assert abs(z) == pytest.approx(0.3, rel=1e-9)
    assert np.angle(z) == pytest.approx(0.7, abs=1e-9)
    # a correction c in the same form cancels it exactly when c = -z
    corrected = x + abs(-z) * np.sin(omega * t + np.angle(-z))
    assert abs(head_swing.fundamental(corrected, t, omega)) < 1e-9


def test_swing_correction_fades_in_over_one_period():
    gait = gait_params()
    period = float(gait_period(gait))
    amp, phase = 0.2, 1.1
    assert float(swing_correction(gait, 0.0, amp, phase)) == 0.0
    t = 0.5 * period
    assert float(swing_correction(gait, t, amp, phase)) == pytest.approx(
        0.5 * amp * math.sin(float(gait.omega_o) * t + phase), rel=1e-5
    )
    t = 2.3 * period
    assert float(swing_correction(gait, t, amp, phase)) == pytest.approx(
        amp * math.sin(float(gait.omega_o) * t + phase), rel=1e-5
    )
    assert float(swing_correction(gait, t, 0.0, phase)) == 0.0


def test_head_swing_cancels_the_residual_swing():
    """Without the correction the head swings 15 degrees about the target ahead; `HEAD_SWING` leaves under 1."""
    z = head_swing.swing([(0.0, 0.0), head_swing.HEAD_SWING])
    before, after = np.degrees(np.abs(z))
    assert 13.0 < before < 17.0
    assert after < 1.0


def test_head_swing_joints_cancels_the_swing_of_the_compensation_from_the_joints():
    """Compensated from the measured joints the head swings 16 degrees; `HEAD_SWING_JOINTS` leaves under 1."""
    env = SnakeEnv("ladder", drawn=True, camera=False, compensate_from="joints")
    z = head_swing.swing([(0.0, 0.0), head_swing.HEAD_SWING_JOINTS], env=env)
    before, after = np.degrees(np.abs(z))
    assert 14.0 < before < 18.0
    assert after < 1.0


def test_bad_compensate_from_is_one_line_error():
    with pytest.raises(UserError, match="compensate_from"):
        SnakeEnv("ladder", camera=False, compensate_from="servos")


def test_bad_head_swing_is_one_line_error():
    with pytest.raises(UserError, match="head_swing"):
        SnakeEnv("ladder", camera=False, head_swing=(0.1,))


def test_default_env_has_no_correction():
    env = SnakeEnv("ladder", camera=False)
    assert float(env.params.head_swing_amplitude) == 0.0
    assert jnp.asarray(env.params.head_swing_phase).dtype == jnp.float32


def test_lagged_compensation_low_passes_the_steering_and_without_steering_is_the_targets():
    """``compensate_from="lagged"``: ``C_o`` low-passed, ``s (1 - exp(-n dt / tau))`` after n steps of a step ``s``.

    With no steering the lagged compensation is the targets' exactly (the
    same joint targets, so the same physics, bit for bit).
    """
    lagged = SnakeEnv("ladder", drawn=True, camera=False, compensate_from="lagged", lag_tau=0.4)
    plain = SnakeEnv("ladder", drawn=True, camera=False)

    def run(env, steer):
        def body(state, _):
            state = env.step(state, jnp.array([steer, 0.0]))
            return state, state.pipeline_state.head_pos

        return jax.lax.scan(body, env.reset(jax.random.PRNGKey(0)), None, length=30)

    state, heads = jax.jit(lambda: run(lagged, 1.0))()
    expected = float(lagged.params.max_steer) * (1.0 - np.exp(-30 * lagged.dt / 0.4))
    assert float(state.info["steer_lag"]) == pytest.approx(expected, rel=1e-5)
    _, straight = jax.jit(lambda: run(lagged, 0.0))()
    _, reference = jax.jit(lambda: run(plain, 0.0))()
    np.testing.assert_array_equal(straight, reference)
    assert np.abs(np.asarray(heads) - np.asarray(reference)).max() > 1e-4  # the steering does reach the body


def test_bad_lag_tau_is_one_line_error():
    with pytest.raises(UserError, match="lag_tau"):
        SnakeEnv("ladder", camera=False, compensate_from="lagged", lag_tau=0.0)
