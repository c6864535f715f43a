"""The counter-based uniform generator: uniform, serially uncorrelated, keyed."""

import jax
import jax.numpy as jnp
import numpy as np

from spikejax.random import hash_seed, hash_uniform

N = 1 << 20


def _draws(seed: int) -> np.ndarray:
    return np.asarray(hash_uniform(hash_seed(key=jax.random.key(seed)), jnp.arange(N, dtype=jnp.uint32)))


def test_uniform_moments_and_histogram():
    u = _draws(0)
    assert u.min() >= 0.0 and u.max() < 1.0
    # Standard errors: 1/sqrt(12 N) for the mean, about 0.3/sqrt(N) for the variance.
    assert abs(u.mean() - 0.5) < 4 / np.sqrt(12 * N)
    assert abs(u.var() - 1 / 12) < 4 * 0.075 / np.sqrt(N)
    counts = np.histogram(u, bins=64, range=(0, 1))[0]
    expected = N / 64
    chi2 = ((counts - expected) ** 2 / expected).sum()
    assert chi2 < 63 + 5 * np.sqrt(2 * 63)  # chi-square with 63 dof, mean 63, sd 11.2


def test_no_serial_correlation():
    u = _draws(1) - 0.5
    for lag in (1, 2, 6, 12, 48):
        r = np.dot(u[:-lag], u[lag:]) / np.dot(u, u)
        assert abs(r) < 4 / np.sqrt(N), lag
    # Pairs of consecutive draws fill the unit square evenly (8 x 8 cells).
    pairs = np.histogram2d(u[0::2], u[1::2], bins=8, range=((-0.5, 0.5), (-0.5, 0.5)))[0]
    expected = N / 2 / 64
    assert ((pairs - expected) ** 2 / expected).sum() < 63 + 5 * np.sqrt(2 * 63)


def test_keys_give_independent_streams():
    a, b = _draws(2), _draws(3)
    np.testing.assert_array_equal(a, _draws(2))
    assert abs(np.corrcoef(a, b)[0, 1]) < 4 / np.sqrt(N)
    # Neighbouring keys of a fold_in sequence (how trials are keyed) are unrelated as well.
    c = np.asarray(
        hash_uniform(hash_seed(key=jax.random.fold_in(jax.random.key(0), 1)), jnp.arange(N, dtype=jnp.uint32))
    )
    d = np.asarray(
        hash_uniform(hash_seed(key=jax.random.fold_in(jax.random.key(0), 2)), jnp.arange(N, dtype=jnp.uint32))
    )
    assert abs(np.corrcoef(c, d)[0, 1]) < 4 / np.sqrt(N)
