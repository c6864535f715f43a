"""Boolean vectors packed 32 to a word, and their set positions taken a few at a time.

Event-driven steps need "the indices of the first ``k`` true entries" of a
short boolean vector (the neurons that spiked, the Hough cells that fired),
with a fixed ``k`` so that the step jits, and the rest left for a further pass.
On XLA's CPU backend the obvious tools are slow for this: ``lax.top_k`` runs a
partial sort, ``jnp.nonzero(size=k)`` and a cumulative-sum rank a scatter or a
``k x n`` comparison. Packing the vector into ``ceil(n / 32)`` uint32 words and
peeling off the lowest set bit ``k`` times (``w & -w``, count leading zeros)
works on a handful of words instead (measured against ``top_k``:
docs/BENCHMARKS.md, "RoboBee closed loop").

Both functions are written for one vector; ``vmap`` batches them.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

__all__ = ["pack", "take_lowest"]


def pack(flags: jax.Array) -> jax.Array:
    """``flags`` as bits: entry ``i`` at bit ``i % 32`` of word ``i // 32``.

    Args:
        flags: ``(n,)``, bool or numbers (nonzero is set).

    Returns:
        uint32 ``(ceil(n / 32),)``.
    """
    flags = (jnp.asarray(flags) != 0).astype(jnp.uint32)
    n = flags.shape[0]
    n_words = -(-n // 32)
    padded = jnp.zeros(n_words * 32, jnp.uint32).at[:n].set(flags).reshape(n_words, 32)
    return jnp.sum(padded << jnp.arange(32, dtype=jnp.uint32), axis=1, dtype=jnp.uint32)


def take_lowest(words: jax.Array, k: int, fill: int) -> tuple[jax.Array, jax.Array]:
    """The positions of the ``k`` lowest set bits of ``words``, and the words without them.

    Args:
        words: uint32 ``(n_words,)``, as `pack` makes them.
        k: positions to take (static, >= 1).
        fill: the position given when fewer than ``k`` bits are set (e.g. ``n``).

    Returns:
        ``(positions, rest)``: int32 ``(k,)`` in increasing order, ``fill`` past the
        last set bit; ``rest`` the words with those bits cleared (all zero once
        every set bit was taken).
    """
    lanes = jnp.arange(words.shape[0])
    positions = []
    for _ in range(int(k)):
        first = jnp.argmax(words != 0)
        this = lanes == first
        word = jnp.sum(jnp.where(this, words, 0), dtype=jnp.uint32)
        lowest = word & (~word + jnp.uint32(1))  # word & -word
        bit = 31 - jax.lax.clz(lowest).astype(jnp.int32)
        positions.append(jnp.where(word != 0, first.astype(jnp.int32) * 32 + bit, fill))
        words = jnp.where(this, word & (word - jnp.uint32(1)), words)
    return jnp.stack(positions), words
