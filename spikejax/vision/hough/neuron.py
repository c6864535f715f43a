"""Alg. 1 of the snake pipe-tracking paper, written to be read: the reference of `spikejax.vision.hough`.

Every output neuron of a Hough grid is the extended bipolar LIF neuron of
Alg. 1 (Section 2.2): for each input spike ``s_i`` of polarity ``p_i`` at
``t_i``,

1. decay: ``v <- sign(v) max(|v| - lambda (t_i - t_last), 0)`` (line 2),
2. integrate: ``v <- v + p_i`` (line 3),
3. fire: if ``|v| >= v_th``, emit a spike of sign ``sign(v)`` (line 4),
4. inhibit: reset the fired neuron and its neighbours to ``v = 0`` (lines 5-7),
   a 3 x 3 window in (theta, rho) for lines, 3 x 3 x 3 in (r, b, a) for circles
   (Section 2.2.3).

An event at pixel ``(x, y)`` is an input spike to every cell it votes for
(`event_cells`, the wiring of Eq. (2) or Eq. (3)). Two ways to run the neurons,
each for one stream and written in the plainest form, without batching rules or
caches in mind:

* `async_step` / `async_run`: events one at a time (a ``lax.scan`` over the
  events), each updating the cells it votes for at its own time stamp. Every
  cell keeps the time of its last update, so the decay is exact and lazy.
* `sync_step` / `sync_run`: the votes of all events of a time slot are summed
  (`votes`), then every neuron makes one Alg. 1 update at the slot's time.

`spikejax.vision.hough` runs the same steps with batched, cache-friendly
kernels (`spikejax.vision.hough._fast`); a test pins them to these, spike for
spike and bit for bit.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from spikejax.ranges import NON_NEGATIVE, POSITIVE, ranged
from spikejax.vision.events import Events
from spikejax.vision.hough.grids import Grid, LineGrid, check_grid, line_table, ring_offsets

__all__ = [
    "HoughParams",
    "HoughState",
    "hough_params",
    "init",
    "decay",
    "neighbourhood",
    "event_cells",
    "votes",
    "sync_step",
    "sync_run",
    "async_event",
    "async_step",
    "async_run",
]


@ranged(v_th=POSITIVE, decay=NON_NEGATIVE)
class HoughParams(NamedTuple):
    """Parameters of the extended bipolar LIF neurons of Alg. 1.

    Attributes:
        v_th: firing threshold, in votes, > 0 (above 1, one vote alone never fires).
        decay: the decay rate lambda of Alg. 1, votes per second, >= 0 (0: no leak).
    """

    v_th: jax.Array
    decay: jax.Array


def hough_params(v_th=8.0, decay=50.0) -> HoughParams:
    """`HoughParams` as float32 arrays (the paper gives no values)."""
    return HoughParams(jnp.asarray(v_th, jnp.float32), jnp.asarray(decay, jnp.float32))


class HoughState(NamedTuple):
    """Membrane potentials of a grid and the time each was last updated.

    Attributes:
        v: potentials, ``grid.shape``.
        t: time of each neuron's last update, seconds, ``grid.shape``.
    """

    v: jax.Array
    t: jax.Array


def init(grid: Grid, t0=0.0) -> HoughState:
    """A grid at rest (``v = 0``) at time ``t0``."""
    return HoughState(jnp.zeros(grid.shape, jnp.float32), jnp.full(grid.shape, t0, jnp.float32))


def decay(v, amount):
    """Alg. 1, line 2: ``sign(v) * max(|v| - amount, 0)``, a linear decay toward 0."""
    return jnp.sign(v) * jnp.maximum(jnp.abs(v) - amount, 0.0)


def neighbourhood(fired: jax.Array) -> jax.Array:
    """The cells within one step of a fired cell, the fired ones included (Section 2.2.3).

    A 3 x 3 window for a line grid, 3 x 3 x 3 for a circle grid; the grid does
    not wrap around.
    """
    window = (3,) * fired.ndim
    near = jax.lax.reduce_window(fired.astype(jnp.int32), 0, jax.lax.max, window, (1,) * fired.ndim, "SAME")
    return near > 0


def event_cells(grid: Grid, x, y) -> tuple[jax.Array, jax.Array]:
    """The flat cells an event at pixel ``(x, y)`` votes for, and which of them are on the grid.

    A line grid: one cell per angle, the rho bin of Eq. (2) (`line_table`), so
    ``(n_theta,)``. A circle grid: every ``(a, b, r_k)`` whose ring of Eq. (3)
    passes through the pixel (`ring_offsets`), ``(m,)``. Cells that are off the
    grid, or all of them for a pixel off the sensor, are ``grid.size``.
    """
    on_sensor = (x >= 0) & (x < grid.width) & (y >= 0) & (y < grid.height)
    if isinstance(grid, LineGrid):
        table = jnp.asarray(line_table(grid))
        cells = table[jnp.where(on_sensor, y * grid.width + x, 0)]
        ok = on_sensor & (cells < grid.size)
    else:
        offsets = jnp.asarray(ring_offsets(grid))
        k, b, a = offsets[:, 0], y + offsets[:, 1], x + offsets[:, 2]
        ok = on_sensor & (a >= 0) & (a < grid.width) & (b >= 0) & (b < grid.height)
        cells = (k * grid.height + b) * grid.width + a
    return jnp.where(ok, cells, grid.size), ok


def votes(grid: Grid, events: Events, *, signed: bool = True) -> jax.Array:
    """The accumulator of a set of events: each valid event adds its polarity (or 1) to its cells.

    Returns ``grid.shape`` float32 (whole numbers: sums of +-1).
    """
    check_grid(grid)
    cells, ok = jax.vmap(lambda x, y: event_cells(grid, x, y))(events.x, events.y)
    weight = events.p.astype(jnp.float32) if signed else jnp.ones(events.p.shape, jnp.float32)
    weight = jnp.where(ok & events.valid[:, None], weight[:, None], 0.0)
    acc = jnp.zeros((grid.size,), jnp.float32).at[cells.reshape(-1)].add(weight.reshape(-1), mode="drop")
    return acc.reshape(grid.shape)


def sync_step(params: HoughParams, grid: Grid, state: HoughState, events: Events, t) -> tuple[HoughState, jax.Array]:
    """One synchronous update of the whole grid at time ``t`` (the paper's GPU mode, Section 2.5).

    Every neuron makes one Alg. 1 update with its summed votes as the input:
    decay by ``decay * (t - t_last)``, add the votes, fire with the sign of ``v``
    where ``|v| >= v_th``, reset the neighbourhoods of the fired neurons.

    Returns:
        ``(state, spikes)``: spikes of shape ``grid.shape``, int8 in ``{-1, 0, +1}``.
    """
    t = jnp.asarray(t, jnp.float32)
    v = decay(state.v, params.decay * (t - state.t)) + votes(grid, events)
    fired = jnp.abs(v) >= params.v_th
    spikes = jnp.where(fired, jnp.sign(v), 0.0).astype(jnp.int8)
    v = jnp.where(neighbourhood(fired), 0.0, v)
    return HoughState(v, jnp.full_like(state.t, t)), spikes


def sync_run(
    params: HoughParams, grid: Grid, events: Events, times, state: HoughState | None = None
) -> tuple[HoughState, jax.Array]:
    """`sync_step` over time slots: events ``(n_slots, capacity)``, ``times`` ``(n_slots,)``.

    Returns ``(state, spikes)``, spikes ``(n_slots, *grid.shape)`` int8; the
    default start is `init` at ``times[0]``.
    """
    times = jnp.asarray(times, jnp.float32)
    if state is None:
        state = init(grid, times[0])
    return jax.lax.scan(lambda s, slot: sync_step(params, grid, s, *slot), state, (events, times))


def async_event(
    params: HoughParams, grid: Grid, state: HoughState, spikes: jax.Array, event
) -> tuple[HoughState, jax.Array]:
    """One input event ``(x, y, t, p, valid)`` through Alg. 1, in the cells it votes for.

    The event reaches all its cells at the same instant ``t``: each decays
    since its own last update and adds ``p``; those with ``|v| >= v_th`` fire
    together and write their sign into ``spikes``; then the neighbourhoods of the
    fired cells are reset (their ``v``; a reset cell's time stays, as a potential
    of 0 does not decay). State and spikes are flat, ``(grid.size,)``.
    """
    x, y, t, p, valid = event
    cells, ok = event_cells(grid, x, y)
    cells = jnp.where(ok & valid, cells, grid.size)  # grid.size: no cell, dropped below
    v_old = state.v.at[cells].get(mode="fill", fill_value=0.0)
    t_old = state.t.at[cells].get(mode="fill", fill_value=0.0)
    v_new = decay(v_old, params.decay * (t - t_old)) + p.astype(jnp.float32)
    # The cells take v_new and t, written as adding the change to what they held
    # (as `_fast` does, to update the state in place). In float32 ``v_old +
    # (v_new - v_old)`` can differ from ``v_new`` in the last bit; written so, the
    # two paths agree bit for bit. `reference.async_run_numpy` sets them in float64.
    v = state.v.at[cells].add(v_new - v_old, mode="drop")
    times = state.t.at[cells].add(t - t_old, mode="drop")
    fired_cells = jnp.where(jnp.abs(v_new) >= params.v_th, cells, grid.size)
    spikes = spikes.at[fired_cells].set(jnp.sign(v_new).astype(jnp.int8), mode="drop")
    fired = jnp.zeros((grid.size,), bool).at[fired_cells].set(True, mode="drop")
    v = jnp.where(neighbourhood(fired.reshape(grid.shape)).reshape(-1), 0.0, v)
    return HoughState(v, times), spikes


def async_step(params: HoughParams, grid: Grid, state: HoughState, events: Events) -> tuple[HoughState, jax.Array]:
    """One slot's events, one at a time in the order given (time order), through `async_event`.

    Returns:
        ``(state, spikes)``: spikes of shape ``grid.shape``, int8, the sign of the
        last spike of each neuron during the slot (0 if it did not fire).
    """
    check_grid(grid)
    flat = HoughState(state.v.reshape(-1), state.t.reshape(-1))
    spikes = jnp.zeros((grid.size,), jnp.int8)

    def one(carry, event):
        return async_event(params, grid, *carry, event), None

    (flat, spikes), _ = jax.lax.scan(one, (flat, spikes), tuple(events))
    return HoughState(flat.v.reshape(grid.shape), flat.t.reshape(grid.shape)), spikes.reshape(grid.shape)


def async_run(
    params: HoughParams, grid: Grid, events: Events, state: HoughState | None = None
) -> tuple[HoughState, jax.Array]:
    """`async_step` over time slots: events ``(n_slots, capacity)``, each row in time order.

    Returns ``(state, spikes)``, spikes ``(n_slots, *grid.shape)`` int8; the
    default start is `init` at time 0.
    """
    if state is None:
        state = init(grid)
    return jax.lax.scan(lambda s, ev: async_step(params, grid, s, ev), state, events)
