"""Row weights: lazily clipped rows equal the step-by-step clipped matrix; event reads equal the product."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from spikejax import synapses
from spikejax.errors import UserError


def _network(rng, n_pre=30, n_post=12, p=0.3):
    mask = rng.random((n_pre, n_post)) < p
    w = np.where(mask, rng.random((n_pre, n_post)), 0.0)
    return w, mask


def test_rows_equal_step_by_step_clipping():
    """Increments large enough to pin rows at both bounds and release them again."""
    rng = np.random.default_rng(0)
    w, mask = _network(rng)
    w_min, w_max = -0.5, 1.2
    rows = synapses.row_weights(jnp.asarray(w, jnp.float32), jnp.asarray(mask))
    ref = w.copy()
    for step in range(300):
        d = rng.normal(0.0, 0.15, w.shape[0]) * (1 + 3 * (step % 50 < 10))
        ref = np.clip(ref + d[:, None], w_min, w_max) * mask
        rows = synapses.add_to_rows(rows, jnp.asarray(d, jnp.float32), w_min, w_max)
    np.testing.assert_allclose(synapses.dense(rows), ref, atol=2e-5)
    assert np.any(ref == w_min) and np.any(ref == w_max) and np.any((ref > w_min) & (ref < w_max) & mask)
    np.testing.assert_array_equal(synapses.connected(rows), mask)


def test_no_update_keeps_the_weights():
    rng = np.random.default_rng(1)
    w, mask = _network(rng)
    rows = synapses.row_weights(jnp.asarray(w, jnp.float32), jnp.asarray(mask))
    np.testing.assert_array_equal(synapses.dense(rows), w.astype(np.float32))


@pytest.mark.parametrize("n_spikes", [0, 1, 5, 6, 7, 13, 30])
def test_propagate_equals_the_dense_product(n_spikes):
    """Fewer, exactly as many and more spikes than rows a pass (5): more passes, same sum."""
    rng = np.random.default_rng(n_spikes)
    w, mask = _network(rng)
    rows = synapses.row_weights(jnp.asarray(w, jnp.float32), jnp.asarray(mask))
    rows = synapses.add_to_rows(rows, jnp.asarray(rng.normal(0, 0.4, 30), jnp.float32), 0.0, 1.0)
    spikes = np.zeros(30, bool)
    spikes[rng.choice(30, n_spikes, replace=False)] = True
    got = synapses.propagate(rows, jnp.asarray(spikes), max_rows=5)
    np.testing.assert_allclose(got, spikes.astype(np.float32) @ np.asarray(synapses.dense(rows)), atol=1e-5)


@pytest.mark.parametrize("spiking", [[0, 31, 32, 63, 64, 95, 96, 99], [99], [31, 32], list(range(100))])
def test_propagate_finds_spikes_across_32_bit_words(spiking):
    """Spikes are packed 32 to a word: the first and last bit of each word, and a last partial word."""
    rng = np.random.default_rng(3)
    w, mask = _network(rng, n_pre=100)
    rows = synapses.row_weights(jnp.asarray(w, jnp.float32), jnp.asarray(mask))
    spikes = np.zeros(100, bool)
    spikes[spiking] = True
    for max_rows in (1, 3, 8, 100):
        got = synapses.propagate(rows, jnp.asarray(spikes), max_rows)
        np.testing.assert_allclose(got, spikes.astype(np.float32) @ w.astype(np.float32), atol=1e-4)


def test_propagate_under_vmap_with_different_counts():
    rng = np.random.default_rng(2)
    w, mask = _network(rng)
    rows = synapses.row_weights(jnp.asarray(w, jnp.float32), jnp.asarray(mask))
    spikes = rng.random((8, 30)) < np.linspace(0.0, 0.9, 8)[:, None]
    got = jax.jit(jax.vmap(lambda s: synapses.propagate(rows, s, 4)))(jnp.asarray(spikes))
    np.testing.assert_allclose(got, spikes.astype(np.float32) @ w.astype(np.float32), atol=1e-5)


def test_propagate_rejects_a_bad_pass_size():
    rows = synapses.row_weights(jnp.ones((3, 2)), jnp.ones((3, 2)))
    with pytest.raises(UserError, match="max_rows"):
        synapses.propagate(rows, jnp.ones(3, bool), 0)
