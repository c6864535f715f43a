"""The RoboBee SNN controller: drawn network, batching, and open-loop learning of a teacher."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from robots.robobee.controller import ControllerConfig, controller_init, controller_params, controller_step
from spikejax.errors import UserError

CONFIG = ControllerConfig()
DT = 1e-4
# Teacher y = -K q in units of the torque limit (1 uN m) per rad, rad/s, m, m/s.
K = jnp.array([1.5, 0.15, 10.0, 2.0], jnp.float32)
# Deviations of a Bernoulli fraction larger than this many standard errors fail.
N_SE = 4.0


def lateral_trajectory(t: jax.Array) -> jax.Array:
    """A slowly varying lateral state [theta, theta_dot, x, x_dot] at times ``t`` (s)."""
    w_theta, w_x = 2 * jnp.pi * 0.7, 2 * jnp.pi * 0.4
    theta = 0.3 * jnp.sin(w_theta * t)
    x = 0.03 * jnp.sin(w_x * t + 1.0)
    return jnp.stack(
        [theta, 0.3 * w_theta * jnp.cos(w_theta * t), x, 0.03 * w_x * jnp.cos(w_x * t + 1.0)],
        axis=-1,
    )


@functools.partial(jax.jit, static_argnames="config")
def simulate(config, params, key, q, y, learn):
    """Runs `controller_step` over ``q`` ``(n, 4)``, ``y`` ``(n,)``, ``learn`` ``(n,)``.

    Returns the decoded ``y_hat`` after every step and the final state.
    """
    state = controller_init(config, params, key=key)

    def body(s, xs):
        return controller_step(config, params, s, *xs)

    state, y_hat = jax.lax.scan(body, state, (q, y, learn))
    return y_hat, state


def test_connectivity_is_thirty_percent_and_seeded():
    p = controller_params()
    s = controller_init(CONFIG, p, key=jax.random.key(0))
    for mask in (s.mask_ih, s.mask_ho):
        n = mask.size
        se = np.sqrt(0.3 * 0.7 / n)
        assert abs(float(mask.mean()) - 0.3) < N_SE * se
    assert s.mask_ih.shape == (200, 100) and s.mask_ho.shape == (100, 50)
    same = controller_init(CONFIG, p, key=jax.random.key(0))
    other = controller_init(CONFIG, p, key=jax.random.key(1))
    np.testing.assert_array_equal(s.mask_ih, same.mask_ih)
    np.testing.assert_array_equal(s.w_ho, same.w_ho)
    assert np.asarray(s.mask_ih != other.mask_ih).any()


def test_initial_weights_and_thresholds():
    p = controller_params()
    s = controller_init(CONFIG, p, key=jax.random.key(2))
    for w, mask in ((s.w_ih, s.mask_ih), (s.w_ho, s.mask_ho)):
        w, on = np.asarray(w), np.asarray(mask) == 1
        assert np.all((w[on] >= 0.0) & (w[on] < 1.0))  # U(0, 1) on existing synapses
        np.testing.assert_array_equal(w[~on], 0.0)
        assert abs(w[on].mean() - 0.5) < N_SE * np.sqrt(1 / 12 / on.sum())
    for v_th in (s.v_th_input, s.v_th_hidden, s.v_th_output):
        v_th = np.asarray(v_th)
        assert np.all((v_th >= 0.7) & (v_th <= 1.7))
        assert v_th.max() - v_th.min() > 0.5
    assert s.v_th_input.shape == (200,) and s.v_th_output.shape == (50,)


@pytest.mark.parametrize(
    "config",
    [
        ControllerConfig(connectivity=0.0),
        ControllerConfig(connectivity=1.5),
        ControllerConfig(n_hidden=0),
    ],
)
def test_bad_config_raises(config):
    with pytest.raises(UserError, match="ControllerConfig"):
        controller_init(config, controller_params(), key=jax.random.key(0))


def test_vmap_over_seeds_equals_loop_over_seeds():
    n_steps = 400
    p = controller_params()
    q = lateral_trajectory(jnp.arange(n_steps) * DT + 0.3)
    y = -(q @ K)
    learn = jnp.ones(n_steps, bool)
    keys = jax.random.split(jax.random.key(3), 3)
    batched, b_state = jax.vmap(simulate, in_axes=(None, None, 0, None, None, None))(CONFIG, p, keys, q, y, learn)
    for i in range(len(keys)):
        looped, l_state = simulate(CONFIG, p, keys[i], q, y, learn)
        np.testing.assert_allclose(batched[i], looped, rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(b_state.w_ho[i], l_state.w_ho, rtol=1e-5, atol=1e-6)
    # The rule ran: weights moved on existing synapses only.
    assert np.abs(np.asarray(l_state.w_ho - controller_init(CONFIG, p, key=keys[-1]).w_ho)).max() > 0


def test_learns_to_track_a_teacher_open_loop():
    # Section V: the state is held for 500 ms while the decoder settles (learning off),
    # then the rule runs online for 1 s; the error is taken over the last 0.5 s.
    n_hold, n_learn = 5000, 10000
    n_steps = n_hold + n_learn
    k = jnp.arange(n_steps)
    q = lateral_trajectory(jnp.maximum(k - n_hold, 0) * DT)
    y = -(q @ K)
    # Open loop, the decoder can afford a 50 ms window and a slower rule (smoother);
    # the defaults are tuned for the closed loop's bandwidth instead.
    p = controller_params(dt=DT, alpha=0.008, beta=20.0, mu_hidden=1e-4, mu_output=1e-4)
    keys = jax.random.split(jax.random.key(4), 8)
    run = jax.vmap(simulate, in_axes=(None, None, 0, None, None, None))
    trained, _ = run(CONFIG, p, keys, q, y, k >= n_hold)
    untrained, _ = run(CONFIG, p, keys, q, y, jnp.zeros(n_steps, bool))

    tail = slice(n_hold + n_learn // 2, n_steps)
    y_tail = np.asarray(y[tail])
    teacher_rms = np.sqrt(np.mean(y_tail**2))
    assert 0.4 < teacher_rms < 1.0  # the teacher spans a good part of [-1, 1]
    err = np.sqrt(np.mean((np.asarray(trained[:, tail]) - y_tail) ** 2, axis=1))
    err0 = np.sqrt(np.mean((np.asarray(untrained[:, tail]) - y_tail) ** 2, axis=1))
    # Measured: trained 4-5 % of the teacher's RMS, untrained above 100 %.
    assert np.all(err < 0.2 * teacher_rms), err / teacher_rms
    assert np.all(err < 0.2 * err0), (err, err0)
