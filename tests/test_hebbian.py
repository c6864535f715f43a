"""Reward-modulated Hebbian rule, Eq. (9)-(10) of the RoboBee paper, against hand computation."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from spikejax.plasticity import RewardHebbianParams, reward_modulated_hebbian

RULE = reward_modulated_hebbian()
# Float32 against float64 over a few dozen multiply-adds of order-one numbers.
RTOL = 1e-5


def params(mu=0.01, tau=5e-3, dt=1e-4):
    f = lambda x: jnp.float32(x)  # noqa: E731
    return RewardHebbianParams(mu=f(mu), tau=f(tau), dt=f(dt))


def run(p, w, mask, pres, errors):
    """Applies ``update`` step by step; returns the ``dw`` and ``r`` of every step."""
    state = RULE.init(w)
    dws, rs = [], []
    post = jnp.zeros(w.shape[1])
    for pre, e in zip(pres, errors):
        dw, state = RULE.update(p, state, w, jnp.asarray(pre), post, jnp.float32(e), mask)
        dws.append(np.asarray(dw))
        rs.append(np.asarray(state.r))
    return np.array(dws), np.array(rs)


def test_eq9_eq10_hand_computed():
    # Neuron 0 spikes at steps 2 and 6, neuron 1 never; the error stays positive.
    mu, tau, dt = 0.01, 5e-3, 1e-4
    n_steps, spike_steps = 10, (2, 6)
    pres = np.zeros((n_steps, 2), bool)
    pres[list(spike_steps), 0] = True
    w = jnp.zeros((2, 3))
    mask = jnp.ones((2, 3))
    dws, rs = run(params(mu, tau, dt), w, mask, pres, [0.3] * n_steps)

    r, t_i = 0.0, None
    for k in range(n_steps):
        t = k * dt
        if k in spike_steps:
            t_i = t
        # Eq. (9); before the first spike exp((t_i - t) / tau) = 0.
        r = 0.0 if t_i is None else (1.0 + r) * math.exp((t_i - t) / tau)
        np.testing.assert_allclose(rs[k, 0], r, rtol=RTOL)
        np.testing.assert_allclose(dws[k, 0], mu * r, rtol=RTOL)  # Eq. (10), every j
    assert rs[2, 0] == pytest.approx(1.0)  # factor 1 in the spiking step
    assert rs[6, 0] > rs[5, 0]  # a new spike restarts the factor at 1
    np.testing.assert_array_equal(rs[:, 1], 0.0)
    np.testing.assert_array_equal(dws[:, 1], 0.0)


def test_zero_error_only_decays_the_trace():
    tau, dt = 5e-3, 1e-4
    pres = np.zeros((4, 1), bool)
    pres[0, 0] = True
    _, rs = run(params(tau=tau, dt=dt), jnp.zeros((1, 1)), jnp.ones((1, 1)), pres, [1, 0, 0, 0])
    expected = [1.0]
    for k in (1, 2, 3):
        expected.append(expected[-1] * math.exp(-k * dt / tau))
    np.testing.assert_allclose(rs[:, 0], expected, rtol=RTOL)


@pytest.mark.parametrize("error", [0.7, -0.2, 1e-6, -50.0])
def test_dw_follows_the_sign_of_y_minus_y_hat(error):
    key = jax.random.key(0)
    pres = np.array(jax.random.bernoulli(key, 0.3, (40, 8)))
    pres[0] = True  # every neuron has a trace
    dws, _ = run(params(), jnp.zeros((8, 5)), jnp.ones((8, 5)), pres, [error] * 40)
    assert np.all(np.sign(dws) == np.sign(error))
    # Only the sign of the error enters Eq. (9).
    dws_unit, _ = run(params(), jnp.zeros((8, 5)), jnp.ones((8, 5)), pres, [np.sign(error)] * 40)
    np.testing.assert_array_equal(dws, dws_unit)


def test_masked_synapses_never_change():
    k_mask, k_pre, k_err = jax.random.split(jax.random.key(1), 3)
    mask = jax.random.bernoulli(k_mask, 0.3, (20, 10)).astype(jnp.float32)
    pres = np.asarray(jax.random.bernoulli(k_pre, 0.2, (60, 20)))
    errors = np.asarray(jax.random.normal(k_err, (60,)))
    dws, _ = run(params(), jnp.zeros((20, 10)), mask, pres, errors)
    off = np.asarray(mask) == 0
    assert off.any() and (~off).any()
    np.testing.assert_array_equal(dws[:, off], 0.0)
    assert np.abs(dws[:, ~off]).max() > 0


def test_jit_equals_eager():
    p = params()
    w = jnp.zeros((6, 4))
    mask = jnp.ones((6, 4))
    pre = jnp.array([1, 0, 1, 0, 0, 1], bool)
    state = RULE.init(w)
    state = state._replace(r=jnp.linspace(-1.0, 2.0, 6), since=jnp.full((6,), 3e-4))
    args = (p, state, w, pre, jnp.zeros(4), jnp.float32(-0.4), mask)
    dw_e, s_e = RULE.update(*args)
    dw_j, s_j = jax.jit(RULE.update)(*args)
    np.testing.assert_allclose(dw_j, dw_e, rtol=RTOL)
    np.testing.assert_allclose(s_j.r, s_e.r, rtol=RTOL)
    np.testing.assert_array_equal(s_j.since, s_e.since)
