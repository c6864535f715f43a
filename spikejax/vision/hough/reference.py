"""Alg. 1 of the snake pipe-tracking paper event by event in NumPy: an oracle for tests and benchmarks.

`async_run_numpy` is the plain way to run the asynchronous mode: a Python loop
over the events of one stream, each updating the cells it votes for, in
float64 and without JAX. Tests check `spikejax.vision.hough.async_run` against
it; the Hough benchmark times it as the per-event peer.
"""

from __future__ import annotations

import itertools

import numpy as np

from spikejax.vision.events import Events
from spikejax.vision.hough.grids import Grid, LineGrid, check_grid, line_table, ring_offsets
from spikejax.vision.hough.neuron import HoughParams, HoughState

__all__ = ["async_run_numpy"]


def _cells_of(grid: Grid):
    """``cells(x, y)``: the flat cells (on the grid only) an event at pixel ``(x, y)`` votes for."""
    if isinstance(grid, LineGrid):
        table = line_table(grid)

        def cells(x, y):
            row = table[y * grid.width + x]
            return row[row < grid.size]

        return cells
    offsets = ring_offsets(grid)

    def cells(x, y):
        k, b, a = offsets[:, 0], y + offsets[:, 1], x + offsets[:, 2]
        inside = (a >= 0) & (a < grid.width) & (b >= 0) & (b < grid.height)
        return ((k * grid.height + b) * grid.width + a)[inside]

    return cells


def async_run_numpy(
    params: HoughParams, grid: Grid, events: Events, state: HoughState | None = None
) -> tuple[HoughState, np.ndarray]:
    """`spikejax.vision.hough.async_run` for one stream, as a per-event loop in NumPy (float64).

    For each valid event ``(x, y, t, p)`` of each slot, in order, every cell it
    votes for decays since its own last update,
    ``v <- sign(v) max(|v| - decay (t - t_last), 0)``, adds ``p`` and takes the
    time ``t``; the cells with ``|v| >= v_th`` fire with the sign of ``v``, and
    then the 3 x 3 (x 3) neighbourhoods of the fired cells, the fired cells
    included, are reset to ``v = 0``. Events off the sensor vote for nothing.

    Args:
        params: neuron parameters (scalars).
        grid: a `LineGrid` or a `CircleGrid`.
        events: `Events` with leaves ``(n_slots, capacity)``, each row in time order.
        state: the starting state (default: at rest at time 0).

    Returns:
        ``(state, spikes)``: the state as float64 NumPy arrays of ``grid.shape``,
        spikes ``(n_slots, *grid.shape)`` int8, the sign of the last spike of each
        neuron in each slot. The spikes are those of `async_run`; the potentials
        agree to float32 rounding.
    """
    check_grid(grid)
    v_th, decay = float(params.v_th), float(params.decay)
    x, y, t, p, valid = (np.asarray(a) for a in events)
    if state is None:
        v, last = np.zeros(grid.size), np.zeros(grid.size)
    else:
        v = np.asarray(state.v, np.float64).reshape(-1).copy()
        last = np.asarray(state.t, np.float64).reshape(-1).copy()
    cells_of = _cells_of(grid)
    steps = np.array(list(itertools.product((-1, 0, 1), repeat=len(grid.shape))))  # (3 ** ndim, ndim)
    shape = np.array(grid.shape)
    strides = np.cumprod((1,) + grid.shape[:0:-1])[::-1]  # flat index = grid index @ strides
    spikes = np.zeros((x.shape[0], grid.size), np.int8)
    for s in range(x.shape[0]):
        keep = valid[s] & (x[s] >= 0) & (x[s] < grid.width) & (y[s] >= 0) & (y[s] < grid.height)
        for xi, yi, ti, pi in zip(*(a[s][keep].tolist() for a in (x, y, t, p))):
            cells = cells_of(xi, yi)
            vv = v[cells]
            vv = np.sign(vv) * np.maximum(np.abs(vv) - decay * (ti - last[cells]), 0.0) + pi
            v[cells] = vv
            last[cells] = ti
            fired = np.abs(vv) >= v_th
            if fired.any():
                spikes[s, cells[fired]] = np.sign(vv[fired])
                index = cells[fired, None] // strides % shape  # (n_fired, ndim): the cells' grid indices
                near = index[:, None, :] + steps  # (n_fired, 3 ** ndim, ndim)
                inside = np.all((near >= 0) & (near < shape), axis=2)
                v[(near @ strides)[inside]] = 0.0
    state = HoughState(v.reshape(grid.shape), last.reshape(grid.shape))
    return state, spikes.reshape((x.shape[0],) + grid.shape)
