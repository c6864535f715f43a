"""The fixed-capacity event buffer: packing in order and counting overflow."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from spikejax.vision import compact


def test_compact_keeps_selected_in_order_and_counts_overflow():
    x = jnp.arange(10)
    mask = jnp.array([0, 1, 1, 0, 1, 1, 1, 0, 1, 0], bool)
    events, overflow = jax.jit(compact, static_argnums=5)(x, x + 100, x * 0.5, jnp.where(x % 2 == 0, 1, -1), mask, 4)
    np.testing.assert_array_equal(events.x, [1, 2, 4, 5])
    np.testing.assert_array_equal(events.y, [101, 102, 104, 105])
    np.testing.assert_allclose(events.t, [0.5, 1.0, 2.0, 2.5])
    np.testing.assert_array_equal(events.p, [-1, 1, 1, -1])
    assert bool(events.valid.all())
    assert int(overflow) == 2


def test_compact_pads_with_invalid_slots():
    mask = jnp.array([1, 0, 1], bool)
    events, overflow = compact(jnp.array([3, 4, 5]), 0, 0.0, 1, mask, 5)
    np.testing.assert_array_equal(events.valid, [True, True, False, False, False])
    np.testing.assert_array_equal(events.x, [3, 5, 0, 0, 0])
    assert int(overflow) == 0 and int(events.count()) == 2


@pytest.mark.parametrize(
    "n, capacity, density",
    [(16384, 2048, 0.05), (16384, 100, 0.05), (16384, 2048, 0.3), (16384, 64, 0.0), (1000, 64, 0.05), (37, 40, 0.9)],
)
def test_compact_matches_numpy_selection_on_frames(n, capacity, density):
    # 1000 and 37 are no whole number of 32-bit words (the mask is padded); 0.3 of 16384 overflows 2048 slots;
    # 0.9 of 37 sets most bits of a word (the bit search's every halving).
    rng = np.random.default_rng(n + capacity)
    mask = rng.random(n) < density
    x = np.arange(n)
    events, overflow = compact(x, x // 7, 0.25, np.where(x % 3, 1, -1), mask, capacity)
    chosen = np.flatnonzero(mask)[:capacity]
    k = len(chosen)
    np.testing.assert_array_equal(np.asarray(events.x)[:k], chosen)
    np.testing.assert_array_equal(np.asarray(events.y)[:k], chosen // 7)
    np.testing.assert_array_equal(np.asarray(events.p)[:k], np.where(chosen % 3, 1, -1))
    assert np.asarray(events.valid).sum() == k and not np.asarray(events.valid)[k:].any()
    assert int(overflow) == max(int(mask.sum()) - capacity, 0)
