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

__all__ = ["Events", "empty", "compact"]


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


def _running_count(mask: jax.Array, block: int = 128) -> jax.Array:
    """``cumsum(mask)`` as int32, row by row when rows of ``block`` divide ``mask``.

    On a CPU under ``vmap`` one long ``cumsum`` of a 128 x 128 frame is slower
    than ``cumsum`` along rows plus the rows' offsets (docs/BENCHMARKS.md).
    """
    n = mask.shape[0]
    if n % block or n <= block:
        return jnp.cumsum(mask, dtype=jnp.int32)
    within = jnp.cumsum(mask.reshape(n // block, block), axis=1, dtype=jnp.int32)
    before = jnp.cumsum(within[:, -1]) - within[:, -1]
    return (within + before[:, None]).reshape(n)


def compact(x, y, t, p, mask, capacity: int) -> tuple[Events, jax.Array]:
    """Pack the entries where ``mask`` holds into ``capacity`` slots, in order.

    Works under ``jit``: the inputs are flat arrays of any static length ``n``;
    the first ``capacity`` selected entries (in input order) become the events.
    Returns ``(events, overflow)``, ``overflow`` being the number of selected
    entries that did not fit (0 when all fit).

    Slot ``k`` holds the entry where the running count of selected entries
    reaches ``k + 1``, found by binary search of the running count: gathers
    of ``capacity`` entries rather than scatters of all ``n``, faster under
    ``vmap`` on a CPU (docs/BENCHMARKS.md).
    """
    mask = jnp.asarray(mask, bool).reshape(-1)
    n = mask.shape[0]
    count = _running_count(mask)
    total = count[-1] if n else jnp.zeros((), jnp.int32)
    # Slots beyond the total find index n: the padding entry appended below.
    source = jnp.searchsorted(count, jnp.arange(1, capacity + 1, dtype=jnp.int32), side="left")

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
