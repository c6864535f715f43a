"""Leaky-integrator decoder, Eq. (8) of the RoboBee paper, against closed forms."""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from spikejax.coding import DecoderParams, decoder_init, decoder_step, poisson_train

# Float32 trace of up to a few hundred spikes against a float64 sum.
RTOL = 1e-5
# Deviations larger than this many standard errors fail a statistical test.
N_SE = 4.0


def decoder_params(alpha=0.05, beta=20.0, gamma=1.5):
    return DecoderParams(alpha=jnp.float32(alpha), beta=jnp.float32(beta), gamma=jnp.float32(gamma))


@jax.jit
def decode(params, spikes, dt):
    """``y_hat`` after each step of a spike raster ``(n_steps, n)``."""

    def body(s, sp):
        return decoder_step(params, s, sp, dt)

    return jax.lax.scan(body, decoder_init(), spikes)[1]


def test_eq8_against_direct_sum_over_spike_times():
    alpha, beta, gamma, dt, n_steps = 0.05, 20.0, 1.5, 1e-4, 3000
    spikes = poisson_train(jnp.full(7, 80.0), dt, n_steps, key=jax.random.key(0))
    y_hat = np.asarray(decode(decoder_params(alpha, beta, gamma), spikes, dt))

    steps, _ = np.nonzero(np.asarray(spikes))
    t_f = steps * dt  # spikes are stamped at the start of their step
    for k in (0, 1, 10, 500, 1234, n_steps - 1):
        t = (k + 1) * dt  # decoder_step's output is y_hat at the end of step k
        past = t_f[t_f < t - dt / 2]
        expected = alpha * np.sum(np.exp(beta * (past - t))) - gamma
        np.testing.assert_allclose(y_hat[k], expected, rtol=RTOL, atol=RTOL * gamma)


def test_silent_population_gives_minus_gamma_and_a_spike_counts_strictly_after():
    alpha, beta, gamma, dt = 0.5, 10.0, 0.25, 1e-3
    spikes = jnp.zeros((5, 3), bool).at[2, 1].set(True)
    y_hat = np.asarray(decode(decoder_params(alpha, beta, gamma), spikes, dt))
    np.testing.assert_allclose(y_hat[:2], -gamma)
    # The spike at t_2 enters y_hat(t_3) with exp(-beta dt), then decays.
    for k in (2, 3, 4):
        expected = alpha * math.exp(-beta * (k + 1 - 2) * dt) - gamma
        np.testing.assert_allclose(y_hat[k], expected, rtol=RTOL)


def steady_state(alpha, beta, gamma, dt, n, p):
    """Mean steady output for ``n`` neurons spiking with probability ``p`` per step.

    The trace is a geometric sum over past steps: ``sum_{m >= 1} n p exp(-beta m dt)
    = n p exp(-beta dt) / (1 - exp(-beta dt))``.
    """
    decay = math.exp(-beta * dt)
    return alpha * n * p * decay / (1.0 - decay) - gamma


def test_regular_population_reaches_the_closed_form_steady_state():
    # 50 neurons, each firing every 100 steps (100 Hz) with staggered phases, so the
    # population spikes once every 2 steps.
    alpha, beta, gamma, dt, n, period = 0.01, 20.0, 1.0, 1e-4, 50, 100
    k = np.arange(6000)[:, None]
    phase = (np.arange(n) * period) // n
    spikes = jnp.asarray((k % period) == phase)
    y_hat = np.asarray(decode(decoder_params(alpha, beta, gamma), spikes, dt))
    p = 1.0 / period
    exact = steady_state(alpha, beta, gamma, dt, n, p)
    # After many time constants the output oscillates around the mean with the population's
    # two-step period; average one full neuron period.
    np.testing.assert_allclose(y_hat[-period:].mean(), exact, rtol=1e-4)
    # For beta dt << 1 that is alpha N rate / beta - gamma, to O(beta dt).
    rate = p / dt
    approx = alpha * n * rate / beta - gamma
    assert abs(exact - approx) < beta * dt * alpha * n * rate / beta


def test_poisson_population_mean_matches_the_steady_state():
    alpha, beta, gamma, dt, n, rate, n_steps = 0.01, 20.0, 1.0, 1e-4, 50, 80.0, 40000
    spikes = poisson_train(jnp.full(n, rate), dt, n_steps, key=jax.random.key(1))
    y_hat = np.asarray(decode(decoder_params(alpha, beta, gamma), spikes, dt))
    settled = y_hat[10000:]  # 20 decay times after the start
    p = -math.expm1(-rate * dt)
    expected = steady_state(alpha, beta, gamma, dt, n, p)
    # Samples are correlated over 1 / beta = 500 steps: about one independent sample per
    # 2 / (beta dt) = 1000 steps for the mean of an exponentially filtered process.
    n_eff = len(settled) / (2.0 / (beta * dt))
    assert abs(settled.mean() - expected) < N_SE * settled.std() / math.sqrt(n_eff)


def test_vmap_over_decoder_params_equals_loop():
    dt = 1e-4
    spikes = poisson_train(jnp.full(10, 120.0), dt, 500, key=jax.random.key(2))
    betas = jnp.array([5.0, 20.0, 80.0])
    batched = jax.vmap(
        functools.partial(decode, spikes=spikes, dt=dt),
    )(DecoderParams(alpha=jnp.full(3, 0.1), beta=betas, gamma=jnp.full(3, 0.2)))
    for i, b in enumerate(betas):
        looped = decode(decoder_params(0.1, float(b), 0.2), spikes, dt)
        np.testing.assert_allclose(batched[i], looped, rtol=RTOL)
