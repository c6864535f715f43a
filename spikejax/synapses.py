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

A connection's transmission delay of a whole number of steps is a `DelayLine`, a
ring buffer with NEST's timing (`delay_step`).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from spikejax import bits
from spikejax.errors import UserError

__all__ = [
    "RowWeights",
    "row_weights",
    "add_to_rows",
    "dense",
    "connected",
    "propagate",
    "DelayLine",
    "delay_steps_of",
    "delay_init",
    "delay_read",
    "delay_step",
]


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


class DelayLine(NamedTuple):
    """A transmission delay of a whole number ``D`` of steps, as a ring buffer.

    Attributes:
        buffer: the values of the last ``D`` steps, shape ``(D, n)``; slot
            ``head`` holds the oldest, the one due now.
        head: index of the oldest slot, int32 scalar.
    """

    buffer: jax.Array
    head: jax.Array


def delay_steps_of(delay_ms, dt) -> int:
    """A delay in ms as whole steps, rounded to nearest as NEST rounds it; at least 1.

    Args:
        delay_ms: the connection delay, ms (static).
        dt: the step, ms (static).

    Raises:
        UserError: if the delay is shorter than half a step (NEST requires
            delays of at least one step).
    """
    steps = int(round(float(delay_ms) / float(dt)))
    if steps < 1:
        raise UserError(f"delay must be at least one step ({dt} ms), got {delay_ms!r} ms")
    return steps


def delay_init(n: int, delay_steps: int, dtype=jnp.float32) -> DelayLine:
    """An empty delay line of ``delay_steps`` steps for ``n`` values.

    Args:
        n: values per step (static), e.g. the neurons of the presynaptic population.
        delay_steps: ``D``, the delay in steps (static), >= 1; see `delay_steps_of`.
        dtype: dtype of the values (spike counts may be integers).

    Raises:
        UserError: if ``n < 0`` or ``delay_steps < 1``.
    """
    if int(delay_steps) != delay_steps or int(delay_steps) < 1:
        raise UserError(f"delay_steps must be an integer >= 1, got {delay_steps!r}")
    if int(n) < 0:
        raise UserError(f"n must be >= 0, got {n!r}")
    return DelayLine(buffer=jnp.zeros((int(delay_steps), int(n)), dtype), head=jnp.zeros((), jnp.int32))


def delay_read(line: DelayLine) -> jax.Array:
    """The values due this step, pushed ``D`` steps ago: what `delay_step` will pop next."""
    return line.buffer[line.head]


def delay_step(line: DelayLine, x: jax.Array) -> tuple[DelayLine, jax.Array]:
    """Pushes this step's ``x``, pops those pushed ``D`` steps (calls) ago.

    Called once per step, ``out_k = x_{k-D}``, and 0 for ``k < D``. The output
    does not depend on ``x``, so a step can read it first (`delay_read`) and
    push afterwards. That is NEST's timing for a neuron model such as
    `spikejax.neurons.iaf_psc_alpha_step`: the spikes emitted in step ``k``
    (stamped ``(k + 1) dt``) over a connection of ``D`` steps are the input of
    the target's step ``k + D``. One step of a network is::

        arriving = delay_read(line)                    # spikes of step k - D
        state, spikes = iaf_psc_alpha_step(p, state, arriving @ w_ex, arriving @ w_in, dt)
        line, _ = delay_step(line, spikes)             # push step k's spikes

    Args:
        line: the delay line.
        x: this step's values, ``(n,)``.

    Returns:
        The line advanced by one step and the values pushed ``D`` steps ago, ``(n,)``.
    """
    out = line.buffer[line.head]
    buffer = line.buffer.at[line.head].set(jnp.asarray(x, line.buffer.dtype))
    head = (line.head + 1) % line.buffer.shape[0]
    return DelayLine(buffer=buffer, head=head.astype(jnp.int32)), out
