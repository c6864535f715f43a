"""Plastic weight matrices whose rows move together, kept lazily and read by events.

A presynaptic rule such as the RoboBee's reward-modulated Hebbian rule (Eq. (10)
of the RoboBee paper, `spikejax.plasticity.reward_modulated_hebbian`) changes
every synapse leaving neuron ``i`` by the same amount ``d_i`` each step, and the
weights are clipped to ``[w_min, w_max]`` after each step:

    w_ij(t + dt) = clip(w_ij(t) + d_i(t), w_min, w_max).

Clamped shifts compose: ``clip(clip(x + a, l, h) + d, lo, hi)`` equals
``clip(x + a + d, clip(l + d, lo, hi), clip(h + d, lo, hi))``. So every weight of
row ``i`` at any time is ``clip(w0_ij + shift_i, low_i, high_i)`` with three
numbers per row, whatever the history: a step updates ``3 n_pre`` numbers
instead of ``n_pre x n_post`` weights (`add_to_rows`).

A layer's input current ``sum_i s_i w_ij`` then needs only the rows of the
neurons that spiked, a few percent of them in a step (`propagate`); the dense
vector-matrix product reads every weight. The spiking rows are found from
the spikes packed 32 to a word, lowest set bit first (`spikejax.bits`), which
is cheaper than ``lax.top_k`` on a CPU (measured: docs/BENCHMARKS.md, "RoboBee
closed loop").

Absent synapses are NaN in ``w0``, so that one gathered row carries both the
weights and the connectivity; they read as 0.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from spikejax import bits
from spikejax.errors import UserError

__all__ = ["RowWeights", "row_weights", "add_to_rows", "dense", "connected", "propagate"]


class RowWeights(NamedTuple):
    """A weight matrix as ``clip(w0_ij + shift_i, low_i, high_i)``, 0 where no synapse.

    Attributes:
        w0: the initial weights, NaN where no synapse exists, shape ``(n_pre, n_post)``.
        shift: the summed increments of each row, shape ``(n_pre,)``.
        low: each row's lower clamp, shape ``(n_pre,)``; ``-inf`` before the first update.
        high: each row's upper clamp; ``+inf`` before the first update.
    """

    w0: jax.Array
    shift: jax.Array
    low: jax.Array
    high: jax.Array


def row_weights(weights: jax.Array, mask: jax.Array) -> RowWeights:
    """The weights ``weights`` on the synapses where ``mask`` is nonzero, not yet clipped.

    Args:
        weights: ``(n_pre, n_post)`` float.
        mask: ``(n_pre, n_post)``, nonzero where a synapse exists.
    """
    weights = jnp.asarray(weights)
    n_pre = weights.shape[0]
    return RowWeights(
        w0=jnp.where(jnp.asarray(mask) != 0, weights, jnp.nan),
        shift=jnp.zeros((n_pre,), weights.dtype),
        low=jnp.full((n_pre,), -jnp.inf, weights.dtype),
        high=jnp.full((n_pre,), jnp.inf, weights.dtype),
    )


def add_to_rows(rows: RowWeights, increment: jax.Array, w_min: jax.Array, w_max: jax.Array) -> RowWeights:
    """Adds ``increment[i]`` to every synapse of row ``i``, then clips all to ``[w_min, w_max]``.

    Args:
        rows: the weights.
        increment: ``(n_pre,)``.
        w_min: lower clip (scalar), ``w_min <= w_max``.
        w_max: upper clip.
    """
    increment = jnp.asarray(increment, rows.shift.dtype)
    return RowWeights(
        w0=rows.w0,
        shift=rows.shift + increment,
        low=jnp.clip(rows.low + increment, w_min, w_max),
        high=jnp.clip(rows.high + increment, w_min, w_max),
    )


def _rows_of(w0: jax.Array, shift: jax.Array, low: jax.Array, high: jax.Array) -> jax.Array:
    w = jnp.clip(w0 + shift[..., None], low[..., None], high[..., None])
    return jnp.where(jnp.isnan(w0), jnp.zeros((), w.dtype), w)


def dense(rows: RowWeights) -> jax.Array:
    """The weights as a dense ``(n_pre, n_post)`` matrix, 0 where no synapse."""
    return _rows_of(*rows)


def connected(rows: RowWeights) -> jax.Array:
    """Where a synapse exists, bool ``(n_pre, n_post)``."""
    return ~jnp.isnan(rows.w0)


def propagate(rows: RowWeights, spikes: jax.Array, max_rows: int = 24) -> jax.Array:
    """``spikes @ dense(rows)``, reading only the rows of the neurons that spiked.

    The spiking rows are taken ``max_rows`` at a time, lowest index first, until
    none is left: exact for any number of spikes; the cost is one pass while at
    most ``max_rows`` neurons spike, which should be the usual case (set it
    near the 99th percentile of the spikes a step). Under ``vmap`` all the
    batch makes as many passes as its busiest member needs.

    Args:
        rows: the weights, ``(n_pre, n_post)``.
        spikes: ``(n_pre,)`` bool or 0/1.
        max_rows: rows gathered per pass (static, >= 1).

    Returns:
        The summed rows, ``(n_post,)``.
    """
    if int(max_rows) < 1:
        raise UserError(f"max_rows must be >= 1, got {max_rows!r}")
    n_pre = rows.w0.shape[0]
    k = min(int(max_rows), n_pre)
    words = bits.pack(spikes)

    def gathered(words):
        idx, words = bits.take_lowest(words, k, n_pre)
        take = lambda a, fill: a.at[idx].get(mode="fill", fill_value=fill)  # idx n_pre: no spike left
        part = _rows_of(take(rows.w0, jnp.nan), take(rows.shift, 0.0), take(rows.low, 0.0), take(rows.high, 0.0))
        return part.sum(0), words

    def more(carry):
        total, words = carry
        part, words = gathered(words)
        return total + part, words

    total, _ = jax.lax.while_loop(lambda c: jnp.any(c[1] != 0), more, gathered(words))
    return total
