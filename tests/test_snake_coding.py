"""Encoders and decoders of the snake R-STDP paper: antagonist pairs (Eq. 3), Poisson counts, Eq. 4 and Eq. 5."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from spikejax.coding import antagonist_rates, d_norm, direction_step, poisson_counts

# Deviations larger than this many standard errors fail a statistical test (CLT over many draws).
N_SE = 5.0


def test_antagonist_rates_closed_form():
    alpha = jnp.array([-45.0, -0.5, 0.0, 0.25, 30.0], jnp.float32)
    k = 2.0
    f = antagonist_rates(alpha, k)
    assert f.shape == (10,)
    np.testing.assert_array_equal(f[0::2], np.maximum(0.0, k * np.asarray(alpha)))
    np.testing.assert_array_equal(f[1::2], np.maximum(0.0, -k * np.asarray(alpha)))
    pairs = np.asarray(f).reshape(5, 2)
    assert np.all(pairs >= 0) and np.all(pairs.min(axis=1) == 0)  # at most one neuron of a pair is active
    assert np.all(pairs.max(axis=1)[alpha != 0] > 0)
    # Linear in k (powers of two: exact in floating point).
    np.testing.assert_array_equal(antagonist_rates(alpha, 8.0), 4.0 * f)


def test_paper_fig1_example():
    # Fig. 1: beta = -30 deg (module 3 against module 4) -> f_P = 0, f_N > 0.
    f_p, f_n = antagonist_rates(jnp.array([-30.0]), 3.0).tolist()
    assert f_p == 0.0 and f_n == 90.0


def test_antagonist_rates_jit_and_vmap_over_k():
    alpha = jnp.array([10.0, -20.0, 5.0])
    ks = jnp.array([0.5, 1.0, 2.0])
    f = jax.jit(jax.vmap(antagonist_rates, in_axes=(None, 0)))(alpha, ks)
    assert f.shape == (3, 6)
    np.testing.assert_allclose(f[2], [20.0, 0.0, 0.0, 40.0, 10.0, 0.0])
    np.testing.assert_allclose(f, np.asarray(ks)[:, None] * np.asarray(f[1])[None, :], rtol=1e-6)


@pytest.mark.parametrize("rate, dt", [(50.0, 1e-3), (500.0, 1e-3), (4000.0, 1e-3), (150.0, 0.02)])
def test_poisson_counts_mean_and_variance_are_rate_dt(rate, dt):
    n = 200_000
    counts = np.asarray(poisson_counts(jnp.full(n, rate), dt, key=jax.random.key(3)), np.float64)
    lam = rate * dt
    assert abs(counts.mean() - lam) < N_SE * math.sqrt(lam / n)
    # Var(sample variance) ~ (mu_4 - sigma^4) / n, with mu_4 = lam (1 + 3 lam) for a Poisson count.
    assert abs(counts.var(ddof=1) - lam) < N_SE * math.sqrt((lam + 2 * lam**2) / n)
    p0 = math.exp(-lam)
    assert abs(np.mean(counts == 0) - p0) < N_SE * math.sqrt(p0 * (1 - p0) / n) + 1e-12


def test_poisson_counts_have_multiplicity_at_high_rates():
    lam, n = 4.0, 50_000
    counts = np.asarray(poisson_counts(jnp.full(n, lam / 1e-3), 1e-3, key=jax.random.key(4)))
    assert counts.dtype == np.int32 and counts.max() > 1
    p_many = 1.0 - math.exp(-lam) * (1.0 + lam)  # P(count >= 2)
    assert abs(np.mean(counts >= 2) - p_many) < N_SE * math.sqrt(p_many * (1 - p_many) / n)


def test_poisson_counts_deterministic_given_the_key_and_silent_at_zero():
    rates = jnp.array([0.0, -10.0, 300.0, 3000.0] * 100)
    a = poisson_counts(rates, 1e-3, key=jax.random.key(5))
    b = jax.jit(poisson_counts)(rates, 1e-3, key=jax.random.key(5))
    c = poisson_counts(rates, 1e-3, key=jax.random.key(6))
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    assert a.shape == rates.shape and a.dtype == jnp.int32
    assert not np.asarray(a)[0::4].any() and not np.asarray(a)[1::4].any()


def test_poisson_counts_vmap_over_keys():
    keys = jax.random.split(jax.random.key(7), 3)
    counts = jax.vmap(lambda k: poisson_counts(jnp.full(4, 1000.0), 1e-3, key=k))(keys)
    np.testing.assert_array_equal(counts[1], poisson_counts(jnp.full(4, 1000.0), 1e-3, key=keys[1]))


def test_d_norm_eq4_values_sign_and_zero_case():
    n_r = jnp.array([3, 0, 0, 5, 1], jnp.int32)
    n_l = jnp.array([1, 2, 0, 5, 0], jnp.int32)
    d = d_norm(n_r, n_l)
    assert d.dtype == jnp.float32
    assert d.tolist() == [0.5, -1.0, 0.0, 0.0, 1.0]
    assert float(d_norm(7, 2)) > 0 > float(d_norm(2, 7))  # right wins: positive
    assert float(d_norm(7, 2)) == -float(d_norm(2, 7))
    # No NaN in the value or the gradient at the undefined point.
    assert float(jax.jit(d_norm)(0.0, 0.0)) == 0.0
    g = jax.grad(lambda r: d_norm(r, 0.0))(0.0)
    assert np.isfinite(float(g))
    with jax.enable_x64(True):
        assert d_norm(jnp.float64(1.0), jnp.float64(2.0)).dtype == jnp.float64


def test_direction_step_eq5_clips_and_scales_with_eta():
    assert float(direction_step(0.9, 1.0, 0.2)) == 1.0
    assert float(direction_step(-0.9, -1.0, 0.2)) == -1.0
    assert float(direction_step(0.5, -0.5, 0.5)) == 0.25
    assert float(direction_step(0.3, 1.0, 0.0)) == pytest.approx(0.3)
    # A constant D_norm = 1 takes D from 0 to 1 in 1 / eta steps and then holds it.
    step = jax.jit(direction_step)
    d, path = jnp.float32(0.0), []
    for _ in range(6):
        d = step(d, jnp.float32(1.0), jnp.float32(0.25))
        path.append(float(d))
    assert path == [0.25, 0.5, 0.75, 1.0, 1.0, 1.0]
    # From a clipped state, the opposite intention moves it back at once.
    assert float(step(jnp.float32(1.0), jnp.float32(-1.0), jnp.float32(0.25))) == 0.75


def test_poisson_counts_match_nest_poisson_generator():
    # NEST's poisson_generator sends each target an independent Poisson count per step as one spike of that
    # multiplicity; a parrot_neuron repeats it and the spike_recorder logs one entry per repeated spike.
    nest = pytest.importorskip("nest")
    nest.set_verbosity("M_ERROR")
    nest.ResetKernel()
    rate, dt, n = 4000.0, 1e-3, 2000
    nest.SetKernelStatus({"resolution": dt * 1e3, "rng_seed": 12})
    generator = nest.Create("poisson_generator", params={"rate": rate})
    parrots = nest.Create("parrot_neuron", n)
    recorder = nest.Create("spike_recorder")
    nest.Connect(generator, parrots, syn_spec={"delay": 1.0})
    nest.Connect(parrots, recorder)
    nest.Simulate(51.0)
    events = recorder.get("events")
    senders, times = np.asarray(events["senders"]), np.round(np.asarray(events["times"])).astype(int)
    steps = np.unique(times)
    table = np.zeros((n, steps.size), np.int64)
    np.add.at(table, (senders - senders.min(), np.searchsorted(steps, times)), 1)
    ours = np.asarray(poisson_counts(jnp.full(table.size, rate), dt, key=jax.random.key(8)))
    lam, size = rate * dt, table.size
    for counts in (table.ravel(), ours):
        assert abs(counts.mean() - lam) < N_SE * math.sqrt(lam / size)
        assert abs(counts.var(ddof=1) - lam) < N_SE * math.sqrt((lam + 2 * lam**2) / size)
        for p, observed in ((math.exp(-lam), np.mean(counts == 0)), (math.exp(-lam) * lam, np.mean(counts == 1))):
            assert abs(observed - p) < N_SE * math.sqrt(p * (1 - p) / size)
    assert table.max() > 1  # multiplicity, not a Bernoulli spike


@pytest.mark.parametrize("lam", [0.01, 0.3, 1.8, 4.0])
def test_poisson_count_train_has_the_poisson_pmf(lam):
    from spikejax.coding import poisson_count_train

    steps, n = 20_000, 8
    counts = np.asarray(poisson_count_train(jnp.full(n, lam / 1e-4), 1e-4, steps, key=jax.random.key(7)))
    assert counts.shape == (steps, n) and counts.dtype == np.int32
    total = steps * n
    for k in range(6):
        p = math.exp(-lam) * lam**k / math.factorial(k)
        assert abs(np.mean(counts == k) - p) < N_SE * math.sqrt(p * (1 - p) / total) + 1e-6
    assert abs(counts.mean() - lam) < N_SE * math.sqrt(lam / total)


def test_poisson_cdf_draws_the_rows_of_the_train_one_step_at_a_time():
    from spikejax.coding import poisson_cdf, poisson_cdf_counts, poisson_count_train

    rates, key = jnp.array([[0.0, 300.0, 5e3], [2e4, 1.0, 250.0]]), jax.random.key(3)
    train = np.asarray(poisson_count_train(rates, 1e-4, 50, key=key))
    gen = poisson_cdf(rates, 1e-4, key=key)
    step = jax.jit(poisson_cdf_counts)
    rows = np.stack([np.asarray(step(gen, i)) for i in range(50)])
    np.testing.assert_array_equal(rows, train)
    assert train[:, 1, 0].sum() > 0 and (train[:, 0, 0] == 0).all()


def test_poisson_count_train_clips_at_max_count_and_is_silent_at_zero():
    from spikejax.coding import poisson_count_train

    lam, steps = 3.0, 40_000
    counts = np.asarray(
        poisson_count_train(jnp.array([0.0, lam / 1e-3]), 1e-3, steps, key=jax.random.key(8), max_count=2)
    )
    assert (counts[:, 0] == 0).all() and counts[:, 1].max() == 2
    p_clipped = 1.0 - math.exp(-lam) * (1.0 + lam)  # P(N >= 2) lands on 2
    assert abs(np.mean(counts[:, 1] == 2) - p_clipped) < N_SE * math.sqrt(p_clipped * (1 - p_clipped) / steps)
