"""Spiking Hough grids: line and circle detectors built of bipolar LIF neurons.

The snake pipe-tracking paper (Jiang et al. 2019, Section 2.2) detects lines and
circles in a DVS event stream with a two-layer spiking network: every input
pixel is wired to the output neurons of the Hough parameter space that a shape
through that pixel would excite, and each output neuron is the extended bipolar
LIF neuron of the paper's Alg. 1 with 3 x 3 (3 x 3 x 3 for circles) lateral
inhibition (Section 2.2.3). Equation and algorithm numbers below are the
paper's.

Grids (`spikejax.vision.hough.grids`; static, hashable configurations, a change
recompiles):

* `LineGrid`: Eq. (2), ``rho = (x - ox) sin(theta) + (y - oy) cos(theta)``
  with ``theta_k = k * 180 / n_theta`` degrees, ``k = 0 .. n_theta - 1``, and rho
  bins of ``rho_step`` pixels. Shape ``(n_theta, n_rho)``, 180 x 180 for a
  128 x 128 sensor as in the paper. ``theta = 90`` degrees is a vertical line
  ``x = ox + rho``; ``theta = 0`` a horizontal line ``y = oy + rho``.
* `CircleGrid`: Eq. (3), ``(x - a)^2 + (y - b)^2 = r^2`` with the centre
  ``(a, b)`` on the sensor's pixels and radii ``r_k = r_min + k * r_step``. Shape
  ``(n_r, height, width)`` -- radius, centre row ``b``, centre column ``a`` --
  the layout of `skimage.transform.hough_circle`; 64 x 128 x 128 for the
  paper's 128 x 128 x 64 grid.

Neurons (Alg. 1; `spikejax.vision.hough.neuron` writes it out as the paper
does): a neuron's potential decays linearly toward 0 at ``decay`` units per
second, ``v <- sign(v) max(|v| - decay (t - t_last), 0)``; an input spike adds
its polarity; when ``|v| >= v_th`` the neuron emits a spike of sign ``sign(v)``
and it and its 3 x 3 (x 3) neighbourhood are reset to 0. Two modes, both written
for one stream (``jax.vmap`` adds streams):

* `async_step` / `async_run`: events one at a time in time order, each
  updating only the cells it votes for (Alg. 1 and the inner loops of Alg. 2
  exactly, see `async_step`). The decay is lazy: every cell keeps the time of
  its last update, so the decay is exact and costs only the cells touched.
* `sync_step` / `sync_run`: all events of a time slot are voted at once
  (`votes`), then every neuron makes one Alg. 1 update at the slot's time with
  the summed votes as its input -- the paper's GPU mode (Section 2.5).

Both return, per time slot, the grid of output spikes with values in
``{-1, 0, +1}``: the sign of the last spike each neuron emitted in the slot.

The two modes differ only when events are dense in time: synchronously, votes
of one slot are summed before any neuron is tested, so a neuron can overshoot
the threshold (``|v| >= v_th`` by more than one vote), opposite votes within a
slot cancel before they can fire, the decay within a slot is ignored, and the
inhibition of a spike acts at the end of the slot rather than on the later
events of the slot. With at most one event per slot they agree exactly.

How it is computed: the functions here are jitted (the grid static) and run
the kernels of `spikejax.vision.hough._fast` (per-stream batching rules on a
CPU, cache-sized chunks of line votes, FFT circle votes, one event loop over a
flat batch of streams), which give the spikes and states of
`spikejax.vision.hough.neuron` bit for bit (tested). Why those kernels, and
their timings: docs/BENCHMARKS.md, "Spiking Hough detectors".
"""

from __future__ import annotations

import functools

import jax

from spikejax.vision.events import Events
from spikejax.vision.hough import _fast
from spikejax.vision.hough.grids import CircleGrid, Grid, LineGrid, check_grid, line_table, ring_offsets
from spikejax.vision.hough.neuron import HoughParams, HoughState, hough_params, init

__all__ = [
    "LineGrid",
    "CircleGrid",
    "Grid",
    "HoughParams",
    "HoughState",
    "hough_params",
    "init",
    "line_table",
    "ring_offsets",
    "line_votes",
    "circle_image_votes",
    "circle_votes",
    "event_image",
    "votes",
    "sync_step",
    "sync_run",
    "sync_update",
    "async_step",
    "async_run",
]


@functools.partial(jax.jit, static_argnames=("grid", "signed"))
def line_votes(grid: LineGrid, events: Events, *, signed: bool = True) -> jax.Array:
    """The line accumulator of a set of events: ``grid.shape`` float32.

    Each valid event adds its polarity (``signed``) or 1 to the cell of its rho
    at every angle (the wiring of Section 2.2.1). With ``signed=False``,
    ``origin=(0, 0)`` and the bins of `LineGrid.skimage_thetas`, the
    accumulator of the events at the nonzero pixels of a binary image is
    ``skimage.transform.hough_line(image, grid.skimage_thetas())[0].T``.
    """
    return _fast.line_votes(grid, events, signed=signed)


@functools.partial(jax.jit, static_argnames=("grid", "signed", "method"))
def circle_votes(grid: CircleGrid, events: Events, *, signed: bool = True, method: str = "fft") -> jax.Array:
    """The circle accumulator of a set of events: ``grid.shape`` float32.

    Each valid event adds its polarity (``signed``) or 1 to every cell
    ``(k, b, a)`` whose ring passes through it (Section 2.2.2). ``method`` picks the
    formulation; both give the same integers:

    * ``"fft"``: the event image convolved with each ring (one real FFT of the
      image, one product and one inverse FFT per radius); cost independent of
      the number of events.
    * ``"scatter"``: every event adds to its ring cells one by one
      (`ring_offsets`); cost proportional to events times ring cells.
    """
    return _fast.circle_votes(grid, events, signed=signed, method=method)


@functools.partial(jax.jit, static_argnames=("grid",))
def circle_image_votes(grid: CircleGrid, image: jax.Array) -> jax.Array:
    """The circle accumulator of an event image (events per pixel, ``(height, width)``, integer-valued).

    ``circle_votes(grid, events, signed=s)`` is
    ``circle_image_votes(grid, event_image(grid, events, signed=s))``: the
    accumulator is linear in the events, so the votes of a slot's steps sum
    to the votes of the slot's image, one convolution instead of one a step.
    """
    return _fast.circle_image_votes(grid, image)


def event_image(grid: Grid, events: Events, *, signed: bool = True) -> jax.Array:
    """Sum of the events' polarities (or counts) per pixel of the grid's sensor: ``(height, width)`` float32."""
    return _fast.event_image(grid, events, signed=signed)


def votes(grid: Grid, events: Events, *, signed: bool = True) -> jax.Array:
    """The accumulator of ``grid`` for a set of events (`line_votes` or `circle_votes`)."""
    check_grid(grid)
    if isinstance(grid, LineGrid):
        return line_votes(grid, events, signed=signed)
    return circle_votes(grid, events, signed=signed)


@functools.partial(jax.jit, static_argnames=("grid",))
def sync_step(params: HoughParams, grid: Grid, state: HoughState, events: Events, t) -> tuple[HoughState, jax.Array]:
    """One synchronous update of the whole grid at time ``t`` (the paper's GPU mode).

    All events of the slot are voted at once (`votes`, signed by polarity);
    then every neuron makes one Alg. 1 update: decay by ``decay * (t - t_last)``,
    add its summed votes, fire with the sign of ``v`` where ``|v| >= v_th``; the
    3 x 3 (x 3) neighbourhoods of the fired neurons are reset to 0.

    Returns:
        ``(state, spikes)``: spikes of shape ``grid.shape``, int8 in ``{-1, 0, +1}``.
    """
    return _fast.sync_step(params, grid, state, events, t)


@jax.jit
def sync_update(params: HoughParams, state: HoughState, votes: jax.Array, t) -> tuple[HoughState, jax.Array]:
    """`sync_step` from the slot's accumulator ``votes`` instead of its events.

    ``sync_step(params, grid, state, events, t)`` is
    ``sync_update(params, state, votes(grid, events), t)``: for callers that
    also keep the votes, one vote pass instead of two.
    """
    return _fast.sync_update(params, state, votes, t)


@functools.partial(jax.jit, static_argnames=("grid",))
def sync_run(
    params: HoughParams, grid: Grid, events: Events, times, state: HoughState | None = None
) -> tuple[HoughState, jax.Array]:
    """`sync_step` over time slots.

    Args:
        params: neuron parameters.
        grid: the grid (static).
        events: `Events` with leaves ``(n_slots, capacity)``, one row per slot.
        times: ``(n_slots,)`` the time of each slot's update, seconds (its end).
        state: the starting state (default: `init` at ``times[0]``).

    Returns:
        ``(state, spikes)``, spikes ``(n_slots, *grid.shape)`` int8.
    """
    return _fast.sync_run(params, grid, events, times, state)


def async_step(params: HoughParams, grid: Grid, state: HoughState, events: Events) -> tuple[HoughState, jax.Array]:
    """Feed one slot's events one at a time, in the order given (time order), through Alg. 1.

    Each event updates only the cells it votes for, at its own time stamp: the
    lazy decay makes the potentials exactly those of Alg. 1 (a linear decay
    toward 0 composes: decaying by ``a`` then ``b`` is decaying by ``a + b``).
    An event's spikes reach all its cells (one per angle, or its rings) at the
    same instant ``t_i``: they are all updated, those with ``|v| >= v_th`` fire
    together, and then the 3 x 3 (x 3) neighbourhoods of the fired cells are
    reset, the fired cells included. (A loop over the angles that resets
    between angles, as a literal reading of Alg. 2 would, differs only when two
    neighbouring cells of the same event cross the threshold on the same event:
    then it lets only the first of them fire.) So with one event per slot,
    `sync_step` at the event's time gives the same spikes and potentials.

    Returns:
        ``(state, spikes)``: spikes of shape ``grid.shape``, int8, the sign of the
        last spike of each neuron during the slot (0 if it did not fire).
    """
    state, spikes = async_run(params, grid, jax.tree.map(lambda a: a[None], events), state)
    return state, spikes[0]


@functools.partial(jax.jit, static_argnames=("grid",))
def async_run(
    params: HoughParams, grid: Grid, events: Events, state: HoughState | None = None
) -> tuple[HoughState, jax.Array]:
    """`async_step` over time slots.

    Args:
        params: neuron parameters.
        grid: the grid (static).
        events: `Events` with leaves ``(n_slots, capacity)``, each row in
            time order, rows consecutive in time.
        state: the starting state (default: `init` at time 0).

    Returns:
        ``(state, spikes)``, spikes ``(n_slots, *grid.shape)`` int8.
    """
    return _fast.async_run(params, grid, events, state)
