"""Address-event streams as a fixed-capacity pytree.

A DVS camera emits events ``(x, y, t, p)``: pixel column, pixel row, time
stamp and polarity (+1 brighter, -1 darker). Their number varies from frame to
frame, but arrays under ``jit`` and ``vmap`` must have a static shape, so an
`Events` holds ``capacity`` slots and a boolean ``valid`` mask
(DESIGN rule 4). Whoever fills a fixed capacity counts what did not fit and
returns that count beside the events: an overflow is reported, never silently
dropped.

Conventions, used by every module of `spikejax.vision`:

* ``x`` (column) and ``y`` (row) are ``int32`` pixel indices, ``0 <= x < width``,
  ``0 <= y < height``; the image's row 0 is its top row.
* ``t`` is ``float32`` seconds.
* ``p`` is ``int32`` in ``{-1, +1}`` for a valid event.
* Slots past the last valid event hold zeros and ``valid=False``; a function
  that consumes events must ignore invalid slots (give them zero weight).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

__all__ = ["Events", "empty", "compact", "set_indices"]


class Events(NamedTuple):
    """``capacity`` event slots; only those with ``valid`` set are events."""

    x: jax.Array  # (capacity,) int32, column
    y: jax.Array  # (capacity,) int32, row
    t: jax.Array  # (capacity,) float32, seconds
    p: jax.Array  # (capacity,) int32, -1 or +1
    valid: jax.Array  # (capacity,) bool

    @property
    def capacity(self) -> int:
        return self.x.shape[-1]

    def count(self) -> jax.Array:
        """Number of valid events (per stream, if batched)."""
        return jnp.sum(self.valid, axis=-1)


def empty(capacity: int) -> Events:
    """An event buffer with ``capacity`` slots and no events."""
    zeros = jnp.zeros((capacity,), jnp.int32)
    return Events(zeros, zeros, jnp.zeros((capacity,), jnp.float32), zeros, jnp.zeros((capacity,), bool))


_WORD = 32  # mask bits packed per word


def set_indices(mask: jax.Array, capacity: int) -> tuple[jax.Array, jax.Array]:
    """The index of the ``k``-th set entry of the flat ``mask`` for each slot ``k < capacity``, and the total.

    Works under ``jit`` (``mask`` of static length). Slots past the total get ``mask.size`` (the padding entry `compact` appends). The mask is packed into 32-bit
    words; each word's first slot is scattered (its running count of set bits), a running maximum over the slots
    gives each slot its word, and five halvings by `lax.population_count` the bit within it. Work of order
    ``n / 32 + capacity``: a running count of every entry (`jnp.cumsum`, a ``reduce_window`` on XLA's CPU
    backend) and a binary search per slot cost three times as much under ``vmap`` (docs/BENCHMARKS.md).
    """
    n = mask.shape[0]
    pad = -n % _WORD
    if pad:
        mask = jnp.concatenate([mask, jnp.zeros((pad,), bool)])
    shifts = jnp.arange(_WORD, dtype=jnp.uint32)
    words = jnp.sum(mask.reshape(-1, _WORD).astype(jnp.uint32) << shifts, axis=1, dtype=jnp.uint32)
    counts = jax.lax.population_count(words).astype(jnp.int32)
    before = jnp.cumsum(counts) - counts  # set entries in the words before each
    total = before[-1] + counts[-1]
    slot = jnp.arange(capacity, dtype=jnp.int32)
    # A word's first slot holds its index; words with no set bit share the next word's slot and lose to it.
    first = jnp.zeros((capacity,), jnp.int32).at[before].max(jnp.arange(words.shape[0], dtype=jnp.int32), mode="drop")
    word = jax.lax.associative_scan(jnp.maximum, first)
    rank, bits, bit = slot - before[word], words[word], jnp.zeros((capacity,), jnp.int32)
    for width in (16, 8, 4, 2, 1):  # the rank-th set bit of each slot's word
        low = jax.lax.population_count(bits & jnp.uint32((1 << width) - 1)).astype(jnp.int32)
        above = rank >= low
        rank = jnp.where(above, rank - low, rank)
        bits = jnp.where(above, bits >> width, bits)
        bit = bit + jnp.where(above, width, 0)
    return jnp.where(slot < total, word * _WORD + bit, n), total


def compact(x, y, t, p, mask, capacity: int) -> tuple[Events, jax.Array]:
    """Pack the entries where ``mask`` holds into ``capacity`` slots, in order.

    Works under ``jit``: the inputs are flat arrays of any static length ``n``;
    the first ``capacity`` selected entries (in input order) become the events.
    Returns ``(events, overflow)``, ``overflow`` being the number of selected
    entries that did not fit (0 when all fit).

    Slot ``k`` gathers the ``k``-th selected entry (`set_indices`): gathers of
    ``capacity`` entries rather than scatters of all ``n``, faster under
    ``vmap`` on a CPU (docs/BENCHMARKS.md).
    """
    mask = jnp.asarray(mask, bool).reshape(-1)
    n = mask.shape[0]
    if n:
        source, total = set_indices(mask, capacity)
    else:
        source, total = jnp.zeros((capacity,), jnp.int32), jnp.zeros((), jnp.int32)

    def take(values, dtype):
        values = jnp.broadcast_to(jnp.asarray(values, dtype).reshape(-1), (n,))
        return jnp.concatenate([values, jnp.zeros((1,), dtype)])[source]

    events = Events(
        x=take(x, jnp.int32),
        y=take(y, jnp.int32),
        t=take(t, jnp.float32),
        p=take(p, jnp.int32),
        valid=jnp.arange(capacity) < jnp.minimum(total, capacity),
    )
    overflow = jnp.maximum(total - capacity, 0)
    return events, overflow
