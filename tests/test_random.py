"""The counter-based uniform generator: uniform, serially uncorrelated, keyed; and JAX's own, drawn in one pass."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from spikejax.random import hash_seed, hash_uniform, threefry_uniform

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


@pytest.mark.parametrize("shape", [(1,), (7,), (3, 5, 2), (160, 256)])
@pytest.mark.parametrize("make_key", [jax.random.key, jax.random.PRNGKey], ids=["typed", "raw"])
def test_threefry_uniform_is_jax_random_uniform_bit_for_bit(shape, make_key):
    for seed in (0, 5, 2**31 + 3):
        key = jax.random.fold_in(make_key(seed), 11)
        for low, high in ((0.0, 1.0), (1e-6, 1.0), (-2.0, 3.5)):
            ours = jax.jit(lambda k, lo=low, hi=high: threefry_uniform(k, shape, lo, hi))(key)
            theirs = jax.jit(lambda k, lo=low, hi=high: jax.random.uniform(k, shape, jnp.float32, lo, hi))(key)
            assert ours.dtype == jnp.float32 and ours.shape == shape
            np.testing.assert_array_equal(np.asarray(ours), np.asarray(theirs))


def test_threefry_uniform_passes_other_generators_to_jax():
    key = jax.random.key(3, impl="rbg")
    np.testing.assert_array_equal(
        np.asarray(threefry_uniform(key, (4, 3))), np.asarray(jax.random.uniform(key, (4, 3), jnp.float32))
    )
