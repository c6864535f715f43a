"""Spiking edge windows: the hexapod paper's visual SNN (Sec. IV), for any sensor and window size.

Four layers of the discrete LIF of Eq. (1)-(2) of the hexapod paper
(``V <- leak(V) + sum_i W_ij S_i``; a spike when ``V > V_th``, then ``V = 0``),
with the leak driven by the events' time stamps as Sec. IV says ("the
timestamps of the events are used to encode voltage leakage"): a neuron last
updated at ``t_last`` and touched again at ``t`` first decays to
``V exp(-(t - t_last) / tau)`` (Eq. (1)'s ``1 / alpha`` per step read as
``exp(-dt / tau)``), lazily and exactly.

1. **Nearest-neighbour filter** (Sec. IV-A, Fig. 6(a)): one neuron per pixel; an
   event at a pixel adds ``centre`` (0.5) to the neuron opposite it, ``edge``
   (0.18) to its four nearest neighbours and ``corner`` (0.06) to the four
   diagonal ones. With ``V_th = 1`` one event never fires a neuron (0.5), the
   centre and three four-neighbours do (1.04), the centre, two four-neighbours
   and two diagonals do not (0.98). Polarity is not used (the paper never
   mentions it).
2. **Layer 2, edges in a window** (Sec. IV-B, Fig. 6(c)): the frame's first
   ``n_rows x n_cols`` windows of ``window x window`` pixels (pixels beyond them,
   the paper's rightmost 80 columns, are ignored); per window one *vertical*
   neuron per column, fed by the window's filter neurons in that column, and one
   *horizontal* neuron per row, each synapse of weight ``column`` (0.06: **17**
   coincident spikes fire it, not the 16 the paper writes, since
   16 x 0.06 = 0.96).
3. **Layer 3, a window's edge confirmed** (Sec. IV-B, Fig. 6(d)): per window and
   branch (vertical, horizontal) one neuron fed by the window's layer-2 neurons
   of that branch at weight ``window`` (0.3: four spikes fire it, three do not).
4. **Readout** (Sec. IV-C, Fig. 6(e)): ``n_out`` neurons fed by the layer-3
   neurons through a weight array ``(n_out, n_rows, n_cols, 2)`` (the hexapod's
   gait-selection neurons: its region map and the 0.4 / 0.7 weights live with the
   robot, ``robots/hexapod/vision.py``). The decision is a rate-coded
   winner-take-all over the readout's spike counts (`winner`).

Within one update a layer's spikes drive the next layer at once (no synaptic
delay), so an event's effect reaches the readout at the event's time.

Two modes, as the Hough grids have (`spikejax.vision.hough`):

* `sync_step`: the events of a time slot as a per-pixel count image
  (`count_image`), then every layer once at the slot's time, dense.
* `async_step`: events one at a time (a ``lax.scan``), each touching the nine
  filter neurons around it and only what they fire.

Both keep each neuron's ``t_last`` and decay lazily, so with one event per slot
they give the same spikes and update times, and potentials equal to float32
rounding: the compiler fuses the leak's product and the sum into one
multiply-add in one mode and not in the other (``tests/test_edges.py``).
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp

from spikejax.errors import UserError
from spikejax.ranges import POSITIVE, ranged
from spikejax.vision.events import Events

__all__ = [
    "EdgeConfig",
    "EdgeParams",
    "EdgeState",
    "Spikes",
    "edge_params",
    "init",
    "count_image",
    "sync_step",
    "async_step",
    "winner",
]


@dataclasses.dataclass(frozen=True)
class EdgeConfig:
    """The layers' sizes (static).

    Attributes:
        height, width: sensor size, pixels (the paper's CeleX-V: 800 x 1280).
        window: window edge, pixels (the paper's 100).
        n_out: readout neurons (the hexapod's three gait-selection neurons).
    """

    height: int = 800
    width: int = 1280
    window: int = 100
    n_out: int = 3

    def __post_init__(self):
        for name in ("height", "width", "window", "n_out"):
            value = getattr(self, name)
            if not isinstance(value, int) or value < 1:
                raise UserError(f"{name} must be a positive integer, got {value!r}")
        if self.window > min(self.height, self.width):
            raise UserError(f"window ({self.window}) must fit in the {self.height} x {self.width} sensor")

    @property
    def n_rows(self) -> int:
        """Window rows (800 // 100 = 8)."""
        return self.height // self.window

    @property
    def n_cols(self) -> int:
        """Window columns (1280 // 100 = 12; the 80 columns beyond are ignored)."""
        return self.width // self.window

    @property
    def used(self) -> tuple[int, int]:
        """The rows and columns the windows cover."""
        return self.n_rows * self.window, self.n_cols * self.window


@ranged(tau_filter=POSITIVE, tau_column=POSITIVE, tau_window=POSITIVE, tau_out=POSITIVE, v_th=POSITIVE)
class EdgeParams(NamedTuple):
    """Weights, time constants and threshold (traced).

    Attributes:
        centre, edge, corner: the filter's 3 x 3 kernel (Sec. IV-B: 0.5, 0.18, 0.06).
        column: filter -> layer-2 weight (0.06).
        window: layer-2 -> layer-3 weight (0.3).
        readout: layer-3 -> readout weights, ``(n_out, n_rows, n_cols, 2)``, the last
            axis (vertical, horizontal).
        tau_filter, tau_column, tau_window, tau_out: leak time constants of the
            four layers, s (unstated in the paper; see `edge_params`).
        v_th: threshold of every layer (Sec. IV-B: 1).
    """

    centre: jax.Array
    edge: jax.Array
    corner: jax.Array
    column: jax.Array
    window: jax.Array
    readout: jax.Array
    tau_filter: jax.Array
    tau_column: jax.Array
    tau_window: jax.Array
    tau_out: jax.Array
    v_th: jax.Array


def edge_params(
    readout,
    *,
    centre=0.5,
    edge=0.18,
    corner=0.06,
    column=0.06,
    window=0.3,
    tau_filter=10e-3,
    tau_column=20e-3,
    tau_window=50e-3,
    tau_out=100e-3,
    v_th=1.0,
) -> EdgeParams:
    """`EdgeParams` as float32 arrays; the weights and threshold are the paper's.

    The time constants are not in the paper: 10 ms makes the filter's window of
    coincidence a few DVS events of one edge; the deeper layers integrate over an
    edge's sweep (20 ms) and a step of the gait (50-100 ms).
    """
    f = lambda v: jnp.asarray(v, jnp.float32)
    return EdgeParams(
        f(centre), f(edge), f(corner), f(column), f(window), f(readout),
        f(tau_filter), f(tau_column), f(tau_window), f(tau_out), f(v_th),
    )  # fmt: skip


class Layer(NamedTuple):
    """Potentials of one layer and the time each neuron was last updated, s."""

    v: jax.Array
    t_last: jax.Array


class EdgeState(NamedTuple):
    """The four layers and the spikes counted since `init` (for rates and energy).

    Attributes:
        filter: ``(height, width)``.
        vertical: layer 2's vertical neurons, ``(n_rows, n_cols * window)``: window
            row, pixel column.
        horizontal: layer 2's horizontal neurons, ``(n_rows * window, n_cols)``.
        windows: layer 3, ``(n_rows, n_cols, 2)`` (vertical, horizontal).
        out: the readout, ``(n_out,)``.
        counts: spikes of each neuron of layer 3 and the readout since `init`,
            ``windows`` ``(n_rows, n_cols, 2)`` and ``out`` ``(n_out,)`` int32, and the
            totals ``events``, ``filter``, ``layer2`` (scalars int32).
    """

    filter: Layer
    vertical: Layer
    horizontal: Layer
    windows: Layer
    out: Layer
    counts: dict


class Spikes(NamedTuple):
    """The spikes of one `sync_step`, every layer (booleans)."""

    filter: jax.Array
    vertical: jax.Array
    horizontal: jax.Array
    windows: jax.Array
    out: jax.Array


def _layer(shape, t0) -> Layer:
    return Layer(jnp.zeros(shape, jnp.float32), jnp.full(shape, t0, jnp.float32))


def init(config: EdgeConfig, t0=0.0) -> EdgeState:
    """Every neuron at rest, last updated at ``t0``, nothing counted."""
    rows, cols = config.used
    t0 = jnp.asarray(t0, jnp.float32)
    zero = jnp.zeros((), jnp.int32)
    return EdgeState(
        filter=_layer((config.height, config.width), t0),
        vertical=_layer((config.n_rows, cols), t0),
        horizontal=_layer((rows, config.n_cols), t0),
        windows=_layer((config.n_rows, config.n_cols, 2), t0),
        out=_layer((config.n_out,), t0),
        counts={
            "windows": jnp.zeros((config.n_rows, config.n_cols, 2), jnp.int32),
            "out": jnp.zeros((config.n_out,), jnp.int32),
            "events": zero,
            "filter": zero,
            "layer2": zero,
        },
    )


def count_image(config: EdgeConfig, events: Events) -> jax.Array:
    """The valid events per pixel, ``(height, width)`` int32, whatever their polarity."""
    image = jnp.zeros((config.height, config.width), jnp.int32)
    return image.at[events.y, events.x].add(events.valid.astype(jnp.int32), mode="drop")


def _leak_and_add(v, t_last, t, tau, drive):
    """``v exp(-(t - t_last) / tau) + drive``: Eq. (1) with the leak of the elapsed time."""
    return v * jnp.exp(-(t - t_last) / tau) + drive


def _update(layer: Layer, touched, drive, t, tau, v_th):
    """Eq. (1)-(2) where ``touched``: decay from ``t_last`` to ``t``, add ``drive``, fire above ``v_th``, reset."""
    v = jnp.where(touched, _leak_and_add(layer.v, layer.t_last, t, tau, drive), layer.v)
    fired = touched & (v > v_th)
    return Layer(jnp.where(fired, 0.0, v), jnp.where(touched, t, layer.t_last)), fired


def _kernel(params: EdgeParams) -> jax.Array:
    c, e, d = params.centre, params.edge, params.corner
    return jnp.stack([jnp.stack([d, e, d]), jnp.stack([e, c, e]), jnp.stack([d, e, d])])


def _filter_drive(params: EdgeParams, image: jax.Array) -> tuple[jax.Array, jax.Array]:
    """``sum_(dy, dx) K[dy, dx] E[y + dy, x + dx]`` and where any event is in the 3 x 3 neighbourhood."""
    h, w = image.shape
    padded = jnp.pad(image, 1)
    k = _kernel(params)
    drive = jnp.zeros((h, w), jnp.float32)
    near = jnp.zeros((h, w), jnp.int32)
    for dy in range(3):
        for dx in range(3):
            window = padded[dy : dy + h, dx : dx + w]
            drive = drive + k[2 - dy, 2 - dx] * window.astype(jnp.float32)
            near = near + window
    return drive, near > 0


def _readout_drive(params: EdgeParams, fired_windows) -> jax.Array:
    return jnp.einsum("oijb,ijb->o", params.readout, fired_windows.astype(jnp.float32))


def sync_step(config: EdgeConfig, params: EdgeParams, state: EdgeState, image, t) -> tuple[EdgeState, Spikes]:
    """One time slot: the per-pixel event counts ``image`` ``(height, width)`` at time ``t``, every layer once.

    A neuron with no input in the slot is left as it was (it only decays, lazily,
    when it is next touched), so this is `async_step` exactly when the slot holds
    one event.
    """
    rows, cols = config.used
    win, n_rows, n_cols = config.window, config.n_rows, config.n_cols
    t = jnp.asarray(t, jnp.float32)
    drive, near = _filter_drive(params, jnp.asarray(image, jnp.int32))
    filt, s_f = _update(state.filter, near, drive, t, params.tau_filter, params.v_th)
    # The window sums as reduce-windows: XLA materialises their operand once, where sums of a reshape let it
    # recompute the filter layer's update inside each of them (docs/BENCHMARKS.md).
    s_int = s_f.astype(jnp.int32)
    by_rows = jax.lax.reduce_window(s_int, 0, jax.lax.add, (win, 1), (win, 1), "VALID")  # (n_rows, width)
    n_col = by_rows[:, :cols]
    n_row = jax.lax.reduce_window(s_int, 0, jax.lax.add, (1, win), (1, win), "VALID")[:rows]  # (height, n_cols)
    n_filter = jnp.sum(by_rows) + jnp.sum(s_int[rows:])
    vert, s_v = _update(state.vertical, n_col > 0, params.column * n_col, t, params.tau_column, params.v_th)
    horz, s_h = _update(state.horizontal, n_row > 0, params.column * n_row, t, params.tau_column, params.v_th)
    n_win = jnp.stack(
        [
            s_v.astype(jnp.int32).reshape(n_rows, n_cols, win).sum(-1),
            s_h.astype(jnp.int32).reshape(n_rows, win, n_cols).sum(1),
        ],
        axis=-1,
    )
    wins, s_w = _update(state.windows, n_win > 0, params.window * n_win, t, params.tau_window, params.v_th)
    out_drive = _readout_drive(params, s_w)
    out, s_o = _update(state.out, jnp.any(s_w), out_drive, t, params.tau_out, params.v_th)
    counts = _count(state.counts, jnp.sum(image), n_filter, s_v, s_h, s_w, s_o)
    return EdgeState(filt, vert, horz, wins, out, counts), Spikes(s_f, s_v, s_h, s_w, s_o)


def _count(counts, n_events, n_filter, s_v, s_h, s_w, s_o) -> dict:
    """``counts`` plus one step's: ``n_filter`` the filter layer's spikes, the other layers' as booleans."""
    i32 = lambda a: jnp.sum(a, dtype=jnp.int32)
    return {
        "windows": counts["windows"] + s_w.astype(jnp.int32),
        "out": counts["out"] + s_o.astype(jnp.int32),
        "events": counts["events"] + jnp.asarray(n_events, jnp.int32),
        "filter": counts["filter"] + jnp.asarray(n_filter, jnp.int32),
        "layer2": counts["layer2"] + i32(s_v) + i32(s_h),
    }


_NINE = tuple((dy, dx) for dy in (-1, 0, 1) for dx in (-1, 0, 1))


def _sparse_update(layer: Layer, idx, valid, n, weight, t, tau, v_th):
    """`_update` on the neurons at ``idx`` (a tuple of index arrays, one row per candidate), ``n`` inputs each.

    Candidates may repeat a neuron: each copy carries that neuron's total count
    and computes the same new value, and only the first copy fires, so a neuron
    is updated and counted once.
    """
    same = jnp.all(jnp.stack([a[:, None] == a[None, :] for a in idx]), axis=0) & valid[:, None] & valid[None, :]
    total = jnp.sum(same * n[None, :], axis=1)
    first = valid & ~jnp.any(jnp.tril(same, -1), axis=1)
    touched = valid & (total > 0)
    v_old, t_old = layer.v[idx], layer.t_last[idx]
    v = _leak_and_add(v_old, t_old, t, tau, weight * total)
    fired = touched & first & (v > v_th)
    fired_any = touched & (v > v_th)
    drop = tuple(jnp.where(touched, a, jnp.iinfo(jnp.int32).max) for a in idx)
    layer = Layer(
        layer.v.at[drop].set(jnp.where(fired_any, 0.0, v), mode="drop"),
        layer.t_last.at[drop].set(t, mode="drop"),
    )
    return layer, fired


def _one_event(config: EdgeConfig, params: EdgeParams, state: EdgeState, x, y, t, valid) -> EdgeState:
    rows, cols = config.used
    win = config.window
    ys = y + jnp.array([d[0] for d in _NINE], jnp.int32)
    xs = x + jnp.array([d[1] for d in _NINE], jnp.int32)
    inside = valid & (ys >= 0) & (ys < config.height) & (xs >= 0) & (xs < config.width)
    k = _kernel(params)
    weights = jnp.stack([k[1 + dy, 1 + dx] for dy, dx in _NINE])
    ones = jnp.ones(9, jnp.int32)
    # The filter's nine neurons get weight * 1 (one event); `_sparse_update` multiplies weight by a count.
    filt, s_f = _sparse_update(state.filter, (ys, xs), inside, ones, weights, t, params.tau_filter, params.v_th)
    in_windows = s_f & (ys < rows) & (xs < cols)
    vert, s_v = _sparse_update(
        state.vertical, (ys // win, xs), in_windows, ones, params.column, t, params.tau_column, params.v_th
    )
    horz, s_h = _sparse_update(
        state.horizontal, (ys, xs // win), in_windows, ones, params.column, t, params.tau_column, params.v_th
    )
    wr = jnp.concatenate([ys // win, ys // win])
    wc = jnp.concatenate([xs // win, xs // win])
    branch = jnp.concatenate([jnp.zeros(9, jnp.int32), jnp.ones(9, jnp.int32)])
    s_2 = jnp.concatenate([s_v, s_h])
    wins, s_w = _sparse_update(
        state.windows, (wr, wc, branch), s_2, jnp.ones(18, jnp.int32), params.window, t, params.tau_window, params.v_th
    )
    fired_windows = jnp.zeros(state.windows.v.shape, bool).at[wr, wc, branch].max(s_w, mode="drop")
    out, s_o = _update(state.out, jnp.any(s_w), _readout_drive(params, fired_windows), t, params.tau_out, params.v_th)
    counts = _count(state.counts, valid, jnp.sum(s_f, dtype=jnp.int32), s_v, s_h, fired_windows, s_o)
    return EdgeState(filt, vert, horz, wins, out, counts)


def async_step(config: EdgeConfig, params: EdgeParams, state: EdgeState, events: Events) -> EdgeState:
    """The events one at a time, in their order, each at its own time stamp; invalid slots change nothing.

    The spikes of the step are the growth of ``state.counts``.
    """

    def body(state, e):
        return _one_event(config, params, state, *e), None

    state, _ = jax.lax.scan(body, state, (events.x, events.y, events.t, events.valid))
    return state


def winner(counts, previous) -> jax.Array:
    """The rate-coded winner-take-all of Sec. IV-C: the readout neuron with the most spikes.

    The paper leaves ties and silence unstated: both keep ``previous`` (a robot
    that sees nothing new keeps its gait); a tie between others goes to the
    lowest index.

    Args:
        counts: spikes per readout neuron over the decision window, ``(n_out,)``.
        previous: the last decision, an int32 index.
    """
    counts = jnp.asarray(counts)
    best = jnp.max(counts)
    tied = counts == best
    keep = (best == 0) | tied[previous]
    return jnp.where(keep, previous, jnp.argmax(counts)).astype(jnp.int32)
