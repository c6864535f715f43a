"""Packed flags: the lowest set positions equal NumPy's ``flatnonzero``, taken in passes."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from spikejax import bits


@pytest.mark.parametrize("n", [1, 31, 32, 33, 200])
def test_pack_puts_entry_i_at_bit_i_mod_32_of_word_i_div_32(n):
    flags = np.random.default_rng(n).random(n) < 0.4
    words = np.asarray(bits.pack(jnp.asarray(flags)))
    assert words.dtype == np.uint32 and words.shape == (-(-n // 32),)
    unpacked = (words[:, None] >> np.arange(32, dtype=np.uint32)) & 1
    np.testing.assert_array_equal(unpacked.reshape(-1)[:n], flags)
    assert not unpacked.reshape(-1)[n:].any()


@pytest.mark.parametrize("p", [0.0, 0.05, 0.5, 1.0])
def test_passes_of_k_give_every_set_position_in_order(p):
    n, k = 200, 7
    rng = np.random.default_rng(int(p * 100))
    flags = rng.random(n) < p
    flags[[31, 32, 199]] = p > 0  # first and last bits of words, and the last partial word
    words, taken = bits.pack(jnp.asarray(flags)), []
    for _ in range(-(-n // k) + 1):
        positions, words = bits.take_lowest(words, k, n)
        taken += [int(i) for i in positions if i != n]
        assert np.all(np.diff(np.asarray(positions)) >= 0)
    np.testing.assert_array_equal(taken, np.flatnonzero(flags))
    assert not np.any(np.asarray(words))


def test_fill_marks_missing_positions_under_vmap():
    flags = jnp.asarray([[True, False, True, False], [False] * 4, [False, False, False, True]])
    positions, rest = jax.jit(jax.vmap(lambda f: bits.take_lowest(bits.pack(f), 3, -1)))(flags)
    np.testing.assert_array_equal(positions, [[0, 2, -1], [-1, -1, -1], [3, -1, -1]])
    assert not np.any(np.asarray(rest))
