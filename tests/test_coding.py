"""Encoders: Poisson generators against their exact statistics; shift-and-scale; antagonist halves."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

from spikejax.coding import antagonist_currents, poisson_spikes, poisson_train, shift_scale
from spikejax.errors import UserError

# Deviations larger than this many standard errors fail a statistical test.
N_SE = 4.0

train_jit = jax.jit(poisson_train, static_argnames="n_steps")


@pytest.mark.parametrize(
    "rate, dt",
    [(5.0, 1e-3), (50.0, 1e-3), (200.0, 1e-4), (2000.0, 1e-3)],
)
def test_poisson_mean_count_matches_exact_expectation(rate, dt):
    n, n_steps = 500, 2000
    spikes = train_jit(jnp.full(n, rate), dt, n_steps, key=jax.random.key(0))
    assert spikes.shape == (n_steps, n) and spikes.dtype == jnp.bool_
    p = -math.expm1(-rate * dt)
    total = int(spikes.sum())
    se = math.sqrt(n * n_steps * p * (1.0 - p))
    assert abs(total - n * n_steps * p) < N_SE * se
    if rate * dt <= 0.05:
        # For rate dt << 1 that is rate * T, to O((rate dt)^2).
        bias = n * n_steps * (rate * dt) ** 2 / 2
        assert abs(total - n * rate * n_steps * dt) < N_SE * se + bias
    else:
        # Here rate dt = 2: a clipped rate dt would spike every step, which is not a Poisson count.
        assert total < n * n_steps - 100 * se


def test_poisson_isis_are_geometric():
    # Spikes of a Bernoulli process with p per step have P(ISI = m) = (1 - p)^(m - 1) p.
    rate, dt, n, n_steps = 100.0, 1e-3, 200, 3000
    spikes = np.asarray(train_jit(jnp.full(n, rate), dt, n_steps, key=jax.random.key(1)))
    isis = np.concatenate([np.diff(np.flatnonzero(spikes[:, j])) for j in range(n)])
    p = -math.expm1(-rate * dt)
    edges = np.array([1, 2, 3, 5, 8, 12, 17, 25, 35, 50, np.inf])
    bins = list(zip(edges[:-1], edges[1:]))
    observed = np.array([np.sum((isis >= a) & (isis < b)) for a, b in bins])
    survival = (1.0 - p) ** (edges - 1)  # P(ISI >= m); 0 at m = inf
    _, p_value = stats.chisquare(observed, -np.diff(survival) * len(isis))
    assert p_value > 1e-3
    assert abs(isis.mean() - 1.0 / p) < N_SE * isis.std() / math.sqrt(len(isis))


def test_poisson_zero_and_negative_rates_never_spike():
    spikes = train_jit(jnp.array([0.0, -50.0, 0.0]), 1e-3, 5000, key=jax.random.key(2))
    assert not spikes.any()


def test_poisson_same_key_same_train():
    rates = jnp.linspace(0.0, 300.0, 16)
    a = train_jit(rates, 1e-3, 400, key=jax.random.key(3))
    b = train_jit(rates, 1e-3, 400, key=jax.random.key(3))
    c = train_jit(rates, 1e-3, 400, key=jax.random.key(4))
    np.testing.assert_array_equal(a, b)
    assert np.asarray(a != c).any()


def test_poisson_train_step_k_is_poisson_spikes_with_key_k():
    rates = jnp.array([10.0, 100.0, 500.0])
    key = jax.random.key(5)
    train = poisson_train(rates, 1e-3, 50, key=key)
    keys = jax.random.split(key, 50)
    for k in (0, 17, 49):
        np.testing.assert_array_equal(train[k], poisson_spikes(rates, 1e-3, key=keys[k]))


def test_poisson_train_jit_equals_eager_and_uses_key_once():
    rates = jnp.array([20.0, 80.0])
    with jax.debug_key_reuse(True):
        eager = poisson_train(rates, 1e-3, 300, key=jax.random.key(6))
        jitted = train_jit(rates, 1e-3, 300, key=jax.random.key(6))
    np.testing.assert_array_equal(eager, jitted)


def test_poisson_train_with_a_rate_per_step():
    n_steps, n = 2000, 300
    rates = np.zeros((n_steps, n), np.float32)
    rates[1000:] = 100.0
    spikes = np.asarray(train_jit(jnp.asarray(rates), 1e-3, n_steps, key=jax.random.key(7)))
    assert not spikes[:1000].any()
    p = -math.expm1(-100.0 * 1e-3)
    total, expected = spikes[1000:].sum(), 1000 * n * p
    assert abs(total - expected) < N_SE * math.sqrt(expected * (1 - p))


def test_poisson_train_rejects_mismatched_rate_steps():
    with pytest.raises(UserError, match="n_steps"):
        poisson_train(jnp.ones((10, 3)), 1e-3, 20, key=jax.random.key(0))


def test_poisson_vmap_equals_loop():
    rates = jnp.array([[5.0, 50.0], [100.0, 0.0], [300.0, 30.0]])
    keys = jax.random.split(jax.random.key(8), 3)
    run = lambda k, r: poisson_train(r, 1e-3, 200, key=k)  # noqa: E731
    batch = jax.vmap(run)(keys, rates)
    for b in range(3):
        np.testing.assert_array_equal(batch[b], run(keys[b], rates[b]))


def test_shift_scale_hand_values_and_broadcasting():
    q = jnp.array([[-1.0, 0.0, 2.0], [0.5, -0.5, 1.0]])
    a = jnp.array([2.0, 1.0, 0.5])
    b = jnp.array([1.0, 3.0, 0.0])
    np.testing.assert_allclose(shift_scale(q, a, b), [[0.0, 3.0, 1.0], [3.0, 2.5, 0.5]])
    assert float(shift_scale(jnp.float32(-0.5), 2.0, 1.0)) == 1.0


def test_antagonist_currents_by_hand():
    """Two groups of 5 (halves of 2 and 3) and one of 1 (all antagonist), gain 0.5, after `shift_scale`."""
    q_hat = shift_scale(jnp.array([0.1, -0.3]), jnp.array([2.0, 1.0]), jnp.array([0.4, 0.1]))  # [1.0, -0.2]
    got = np.asarray(antagonist_currents(q_hat, 5, jnp.float32(0.5)))
    # group 0: q_hat 1.0 -> 0.5 twice, then 0.5 * (1 - 1.0) = 0 three times; group 1: q_hat -0.2 -> -0.1, 0.6.
    np.testing.assert_allclose(got, [0.5, 0.5, 0.0, 0.0, 0.0, -0.1, -0.1, 0.6, 0.6, 0.6], atol=1e-7)
    np.testing.assert_allclose(np.asarray(antagonist_currents(jnp.array([0.25, 0.75]), 1, 2.0)), [1.5, 0.5])


@pytest.mark.parametrize("n", [0, -1, 2.0, True])
def test_antagonist_currents_rejects_bad_group_sizes(n):
    with pytest.raises(UserError, match="n_per_group"):
        antagonist_currents(jnp.zeros(2), n, 1.0)
