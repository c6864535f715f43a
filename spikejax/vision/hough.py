"""Spiking Hough grids: line and circle detectors built of bipolar LIF neurons.

The snake pipe-tracking paper (Jiang et al. 2019, Section 2.2) detects lines and
circles in a DVS event stream with a two-layer spiking network: every input
pixel is wired to the output neurons of the Hough parameter space that a shape
through that pixel would excite, and each output neuron is the extended bipolar
LIF neuron of Alg. 1 with 3 x 3 (3 x 3 x 3 for circles) lateral inhibition
(Section 2.2.3). This module holds the grids, their vote accumulators and the
two ways of running the neurons.

Grids (static, hashable configurations; a change recompiles):

* :class:`LineGrid`: Eq. (2), ``rho = (x - ox) sin(theta) + (y - oy) cos(theta)``
  with ``theta_k = k * 180 / n_theta`` degrees, ``k = 0 .. n_theta - 1``, and rho
  bins of ``rho_step`` pixels. Shape ``(n_theta, n_rho)``, 180 x 180 for a
  128 x 128 sensor as in the paper. ``theta = 90`` degrees is a vertical line
  ``x = ox + rho``; ``theta = 0`` a horizontal line ``y = oy + rho``.
* :class:`CircleGrid`: Eq. (3), ``(x - a)^2 + (y - b)^2 = r^2`` with the centre
  ``(a, b)`` on the sensor's pixels and radii ``r_k = r_min + k * r_step``. Shape
  ``(n_r, height, width)`` -- radius, centre row ``b``, centre column ``a`` --
  the layout of :func:`skimage.transform.hough_circle`; 64 x 128 x 128 for the
  paper's 128 x 128 x 64 grid.

Neurons (Alg. 1): a neuron's potential decays linearly toward 0 at ``decay``
units per second, ``v <- sign(v) max(|v| - decay (t - t_last), 0)``; an input
spike adds its polarity; when ``|v| >= v_th`` the neuron emits a spike of sign
``sign(v)`` and it and its 3 x 3 (x 3) neighbourhood are reset to 0. Two modes,
both written for one stream (``jax.vmap`` adds streams):

* :func:`async_step` / :func:`async_run`: events one at a time in time order, each
  updating only the cells it votes for (Alg. 1 and the inner loops of Alg. 2
  exactly, see :func:`async_step`). The decay is lazy: every cell keeps the time
  of its last update, so the decay is exact and costs only the cells touched.
* :func:`sync_step` / :func:`sync_run`: all events of a time slot are voted at
  once (:func:`votes`), then every neuron makes one Alg. 1 update at the slot's
  time with the summed votes as its input -- the paper's GPU mode (Section 2.5).

Both return, per time slot, the grid of output spikes with values in
``{-1, 0, +1}``: the sign of the last spike each neuron emitted in the slot.

The two modes differ only when events are dense in time: synchronously, votes
of one slot are summed before any neuron is tested, so a neuron can overshoot
the threshold (``|v| >= v_th`` by more than one vote), opposite votes within a
slot cancel before they can fire, the decay within a slot is ignored, and the
inhibition of a spike acts at the end of the slot rather than on the later
events of the slot. With at most one event per slot they agree exactly.

How it is computed (each choice measured against the alternatives on a 2-core
CPU, see :mod:`spikejax.vision.bench_hough` and ``docs/ARCHITECTURE.md``): line
votes are scatter-adds of each event's ``n_theta`` cells, read from a static
(pixel, angle) -> cell table (:func:`line_table`, gathered as uint16) into an
int32 accumulator, a few hundred events at a time so that the gathered cells
stay in the L2 cache; under ``vmap`` on a CPU the streams are voted one after
another, each into its own cache-resident accumulator (a custom batching
rule). Circle votes are the event image convolved with the ring kernels by
FFT. The asynchronous loop steps over event positions with every stream of the
batch at once: one gather of the ``(v, t_last)`` of the cells the events touch
and one scatter-add of the change, with inhibition (the fired cells packed to
the front) only on steps where some stream fired.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from spikejax import bits
from spikejax.errors import UserError
from spikejax.vision.events import Events

__all__ = [
    "LineGrid",
    "CircleGrid",
    "HoughParams",
    "HoughState",
    "hough_params",
    "init",
    "line_table",
    "ring_offsets",
    "line_votes",
    "circle_votes",
    "votes",
    "sync_step",
    "sync_run",
    "async_step",
    "async_run",
]


def _round_half_away(v: np.ndarray) -> np.ndarray:
    """C's ``round``: nearest integer, ties away from zero (what scikit-image uses)."""
    r = np.rint(v)
    tie = np.abs(v - np.trunc(v)) == 0.5
    return np.where(tie, np.trunc(v) + np.sign(v), r)


@dataclasses.dataclass(frozen=True)
class LineGrid:
    """The (theta, rho) parameter space of Eq. (2).

    Attributes:
        width, height: sensor size, pixels.
        n_theta: angles ``theta_k = k * 180 / n_theta`` degrees (180: 1 degree).
        n_rho: rho bins.
        rho_step: bin width, pixels. Bin ``j`` holds the rho that round to
            ``(j - rho_offset) * rho_step`` (ties away from zero).
        origin: ``(ox, oy)``, the pixel the distances are measured from. Default
            ``(width / 2, height / 2)``: then ``|rho| <= 90`` on a 128 x 128
            sensor and the paper's 180 bins of 1 pixel hold every line.
        rho_offset: bin of ``rho = 0``; default ``n_rho // 2``.

    Votes that fall outside the bins are dropped (with the defaults on a
    128 x 128 sensor only the corner pixel ``(0, 0)`` at 44-46 degrees, where
    ``rho = -90.5``).
    """

    width: int = 128
    height: int = 128
    n_theta: int = 180
    n_rho: int = 180
    rho_step: float = 1.0
    origin: tuple[float, float] | None = None
    rho_offset: int | None = None

    def __post_init__(self):
        for name in ("width", "height", "n_theta", "n_rho"):
            value = getattr(self, name)
            if not (isinstance(value, (int, np.integer)) and value > 0):
                raise UserError(f"LineGrid.{name} must be a positive integer, not {value!r}")
        if not self.rho_step > 0:
            raise UserError(f"LineGrid.rho_step must be > 0 pixels, not {self.rho_step!r}")
        if self.origin is None:
            object.__setattr__(self, "origin", (self.width / 2, self.height / 2))
        else:
            object.__setattr__(self, "origin", tuple(float(o) for o in self.origin))
        if self.rho_offset is None:
            object.__setattr__(self, "rho_offset", self.n_rho // 2)

    @property
    def shape(self) -> tuple[int, int]:
        return (self.n_theta, self.n_rho)

    @property
    def size(self) -> int:
        return self.n_theta * self.n_rho

    def thetas(self) -> np.ndarray:
        """Angles of the rows, radians, ``(n_theta,)``."""
        return np.arange(self.n_theta) * (np.pi / self.n_theta)

    def rhos(self) -> np.ndarray:
        """Centre of each rho bin, pixels, ``(n_rho,)``."""
        return (np.arange(self.n_rho) - self.rho_offset) * self.rho_step

    def skimage_thetas(self) -> np.ndarray:
        """The angles to give :func:`skimage.transform.hough_line` for the same lines.

        scikit-image writes ``rho = x cos(phi) + y sin(phi)`` from the top-left
        pixel, Eq. (2) writes ``rho = x sin(theta) + y cos(theta)``: the same line
        has ``phi = pi / 2 - theta``. With ``origin=(0, 0)``, ``rho_step=1`` and
        ``rho_offset = ceil(hypot(height, width))`` (``n_rho = 2 rho_offset + 1``),
        row ``k`` of our accumulator is column ``k`` of scikit-image's, bin for bin.
        """
        return np.pi / 2 - self.thetas()

    def cell(self, theta: float, rho: float) -> tuple[int, int]:
        """``(theta_index, rho_index)`` of the cell nearest to a line (radians, pixels).

        ``theta`` is taken modulo pi (``(theta + pi, -rho)`` is the same line).
        """
        theta = float(theta) % (2 * np.pi)
        if theta >= np.pi:
            theta, rho = theta - np.pi, -rho
        k = int(round(theta / (np.pi / self.n_theta)))
        if k == self.n_theta:
            k, rho = 0, -rho
        j = int(_round_half_away(np.asarray(rho / self.rho_step))) + self.rho_offset
        return k, j

    def line(self, theta_index, rho_index) -> tuple[np.ndarray, np.ndarray]:
        """``(theta, rho)`` (radians, pixels) of cells given by their indices."""
        theta_index = np.asarray(theta_index)
        rho_index = np.asarray(rho_index)
        return theta_index * (np.pi / self.n_theta), (rho_index - self.rho_offset) * self.rho_step


@dataclasses.dataclass(frozen=True)
class CircleGrid:
    """The (a, b, r) parameter space of Eq. (3).

    Attributes:
        width, height: sensor size, pixels; the centres ``(a, b)`` are its pixels.
        n_r: radii ``r_k = r_min + k * r_step``.
        r_min: smallest radius, pixels.
        r_step: radius step, pixels.

    An event at ``(x, y)`` votes for ``(a, b, r_k)`` when its distance to the
    centre rounds to ``r_k`` in steps of ``r_step``:
    ``round((hypot(x - a, y - b) - r_min) / r_step) == k`` (ties away from zero).
    """

    width: int = 128
    height: int = 128
    n_r: int = 64
    r_min: float = 1.0
    r_step: float = 1.0

    def __post_init__(self):
        for name in ("width", "height", "n_r"):
            value = getattr(self, name)
            if not (isinstance(value, (int, np.integer)) and value > 0):
                raise UserError(f"CircleGrid.{name} must be a positive integer, not {value!r}")
        if not self.r_min > 0:
            raise UserError(f"CircleGrid.r_min must be > 0 pixels, not {self.r_min!r}")
        if not self.r_step > 0:
            raise UserError(f"CircleGrid.r_step must be > 0 pixels, not {self.r_step!r}")

    @property
    def shape(self) -> tuple[int, int, int]:
        return (self.n_r, self.height, self.width)

    @property
    def size(self) -> int:
        return self.n_r * self.height * self.width

    def radii(self) -> np.ndarray:
        """Radius of each plane, pixels, ``(n_r,)``."""
        return self.r_min + np.arange(self.n_r) * self.r_step

    def r_max(self) -> float:
        """Largest distance that still votes, pixels."""
        return self.r_min + (self.n_r - 0.5) * self.r_step


Grid = LineGrid | CircleGrid


class HoughParams(NamedTuple):
    """Parameters of the extended bipolar LIF neurons of Alg. 1.

    Attributes:
        v_th: firing threshold, in votes (> 1: one vote alone never fires).
        decay: the decay rate lambda of Alg. 1, votes per second.
    """

    v_th: jax.Array
    decay: jax.Array


def hough_params(v_th=8.0, decay=50.0) -> HoughParams:
    """:class:`HoughParams` as float32 arrays (the paper gives no values)."""
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


# --- static wiring -------------------------------------------------------------


@functools.cache
def line_table(grid: LineGrid) -> np.ndarray:
    """Which cell each pixel votes for at each angle: ``(height * width, n_theta)`` int32.

    Entry ``[y * width + x, k]`` is the flat cell index ``k * n_rho + j`` of the rho
    bin ``j`` of pixel ``(x, y)`` at ``theta_k``, or ``grid.size`` when the bin is
    outside the grid. Computed once per grid in float64, with the trigonometric
    values of :meth:`LineGrid.skimage_thetas`, so that it agrees with
    scikit-image bin for bin.
    """
    phi = grid.skimage_thetas()
    sin_t, cos_t = np.cos(phi), np.sin(phi)  # sin(theta), cos(theta)
    y, x = np.divmod(np.arange(grid.height * grid.width), grid.width)
    ox, oy = grid.origin
    rho = (x[:, None] - ox) * sin_t[None, :] + (y[:, None] - oy) * cos_t[None, :]
    if grid.rho_step != 1.0:
        rho = rho / grid.rho_step
    j = _round_half_away(rho).astype(np.int64) + grid.rho_offset
    inside = (j >= 0) & (j < grid.n_rho)
    flat = np.arange(grid.n_theta)[None, :] * grid.n_rho + j
    return np.where(inside, flat, grid.size).astype(np.int32)


@functools.cache
def ring_offsets(grid: CircleGrid) -> np.ndarray:
    """The cells one event votes for, as offsets: ``(m, 3)`` int32 rows ``(k, db, da)``.

    An event at ``(x, y)`` votes for centre ``(x + da, y + db)`` at radius index
    ``k`` (the rings of :class:`CircleGrid`); ordered by ``k``, then ``db``, ``da``.
    """
    reach = int(math.floor(grid.r_max()))
    d = np.arange(-reach, reach + 1)
    db, da = np.meshgrid(d, d, indexing="ij")
    k = _round_half_away((np.hypot(da, db) - grid.r_min) / grid.r_step)
    rows = []
    for i in range(grid.n_r):
        sel = k == i
        rows.append(np.stack([np.full(sel.sum(), i), db[sel], da[sel]], axis=1))
    return np.concatenate(rows).astype(np.int32)


# --- votes ---------------------------------------------------------------------


def _one_stream_at_a_time(fn):
    """``fn`` (written for one stream), batched under ``vmap`` by ``lax.map`` on a CPU.

    A scatter into a per-stream accumulator stays in the cache, and XLA's CPU
    backend runs it as one tight loop; a batched (or flattened) scatter touches
    every stream's accumulator and is 2-3 times slower there. Other backends
    ``vmap``. Arguments are positional arrays (``jax.custom_batching``).
    """
    batched = jax.custom_batching.custom_vmap(fn)

    @batched.def_vmap
    def _rule(axis_size, in_batched, *args):
        args = jax.tree.map(
            lambda a, b: a if b else jnp.broadcast_to(a, (axis_size,) + jnp.shape(a)), args, tuple(in_batched)
        )
        if jax.default_backend() == "cpu":
            out = jax.lax.map(lambda a: batched(*a), args)
        else:
            out = jax.vmap(fn)(*args)
        return out, jax.tree.map(lambda _: True, out)

    return batched


def _scatter_add(length: int, index, weight):
    """``zeros(length).at[index].add(weight)``, with ``0 <= index < length``."""
    return jnp.zeros((length,), weight.dtype).at[index].add(weight, mode="promise_in_bounds")


@functools.cache
def _histogram(length: int):
    """:func:`_scatter_add` of one stream, batched by :func:`_one_stream_at_a_time`."""
    return _one_stream_at_a_time(lambda index, weight: _scatter_add(length, index, weight))


def _weights(events: Events, signed: bool) -> jax.Array:
    w = events.p.astype(jnp.float32) if signed else jnp.ones(events.p.shape, jnp.float32)
    return jnp.where(events.valid, w, 0.0)


def _pixel(grid, events: Events) -> tuple[jax.Array, jax.Array]:
    """Flat pixel index of each event and whether it lies on the sensor."""
    on = (events.x >= 0) & (events.x < grid.width) & (events.y >= 0) & (events.y < grid.height)
    pixel = jnp.where(on, events.y * grid.width + events.x, 0)
    return pixel, on & events.valid


@functools.partial(jax.jit, static_argnames=("grid", "signed"))
def line_votes(grid: LineGrid, events: Events, *, signed: bool = True) -> jax.Array:
    """The line accumulator of a set of events: ``grid.shape`` float32.

    Each valid event adds its polarity (``signed``) or 1 to the cell of its rho
    at every angle (the wiring of Section 2.2.1). With ``signed=False``,
    ``origin=(0, 0)`` and the bins of :meth:`LineGrid.skimage_thetas`, the
    accumulator of the events at the nonzero pixels of a binary image is
    ``skimage.transform.hough_line(image, grid.skimage_thetas())[0].T``.
    """
    return _line_accumulator(grid, signed)(events)


@functools.cache
def _compact_table(grid: LineGrid) -> np.ndarray:
    """:func:`line_table` as uint16 where the cells fit: half the bytes to gather per event."""
    table = line_table(grid)
    return table.astype(np.uint16) if grid.size < 2**16 else table


@functools.cache
def _line_accumulator(grid: LineGrid, signed: bool, chunk: int = 576):
    """:func:`line_votes` for one stream: scatter-adds of the events' table rows.

    The events go ``chunk`` at a time (a ``lax.scan``), so that the cell indices
    and weights of a chunk (``chunk * n_theta`` of each) stay in the CPU's L2
    cache between being gathered and being scattered. Counts are summed in
    int32 (exact, as float32 sums of +-1 are); the table is gathered as uint16.
    Streams run one at a time on a CPU (:func:`_one_stream_at_a_time`).
    """
    table = _compact_table(grid)

    def accumulate(events):
        pixel, ok = _pixel(grid, events)
        w = jnp.where(ok, events.p if signed else 1, 0).astype(jnp.int32)
        n_chunks = -(-pixel.shape[0] // chunk)
        length = -(-pixel.shape[0] // n_chunks)
        pad = n_chunks * length - pixel.shape[0]  # padding events have weight 0
        pixel = jnp.pad(pixel, (0, pad)).astype(jnp.uint32).reshape(n_chunks, length)
        w = jnp.pad(w, (0, pad)).reshape(n_chunks, length)

        def add(acc, part):
            pixel, w = part
            cells = jnp.asarray(table).at[pixel].get(mode="promise_in_bounds")
            return acc.at[cells.reshape(-1)].add(jnp.repeat(w, grid.n_theta), mode="promise_in_bounds"), None

        acc, _ = jax.lax.scan(add, jnp.zeros((grid.size + 1,), jnp.int32), (pixel, w))
        return acc[: grid.size].reshape(grid.shape).astype(jnp.float32)

    return _one_stream_at_a_time(accumulate)


def event_image(grid, events: Events, *, signed: bool = True) -> jax.Array:
    """Sum of the events' polarities (or counts) per pixel: ``(height, width)`` float32."""
    pixel, ok = _pixel(grid, events)
    w = jnp.where(ok, _weights(events, signed), 0.0)
    image = jnp.zeros((grid.height * grid.width,), jnp.float32).at[pixel].add(w)
    return image.reshape(grid.height, grid.width)


def _fft_size(n: int, reach: int) -> int:
    """Smallest 2^i 3^j 5^k >= n + reach: a circular convolution of that size has no wrap-around."""
    need = n + reach
    best = None
    for i in range(12):
        for j in range(8):
            for k in range(6):
                v = 2**i * 3**j * 5**k
                if v >= need and (best is None or v < best):
                    best = v
    return best


@functools.cache
def _ring_kernels(grid: CircleGrid) -> tuple[np.ndarray, int, int]:
    """Ring kernels laid out for a circular convolution: ``(n_r, ny, nx)`` float32."""
    reach = int(math.floor(grid.r_max()))
    ny, nx = _fft_size(grid.height, reach), _fft_size(grid.width, reach)
    offsets = ring_offsets(grid)
    kernels = np.zeros((grid.n_r, ny, nx), np.float32)
    # An event at (x, y) votes for the centre (x + da, y + db): the kernel is the
    # ring itself, placed at (db mod ny, da mod nx).
    kernels[offsets[:, 0], offsets[:, 1] % ny, offsets[:, 2] % nx] = 1.0
    return kernels, ny, nx


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
      (:func:`ring_offsets`); cost proportional to events times ring cells.
    """
    if method == "fft":
        kernels, ny, nx = _ring_kernels(grid)
        image = event_image(grid, events, signed=signed)
        spectrum = jnp.fft.rfft2(image, s=(ny, nx))
        rings = jnp.fft.rfft2(jnp.asarray(kernels))
        out = jnp.fft.irfft2(rings * spectrum[None], s=(ny, nx))
        return jnp.round(out[:, : grid.height, : grid.width])
    if method == "scatter":
        offsets = jnp.asarray(ring_offsets(grid))
        pixel, ok = _pixel(grid, events)
        w = jnp.where(ok, _weights(events, signed), 0.0)
        flat, inside = _ring_cells(grid, offsets, events.x[:, None], events.y[:, None])
        flat = jnp.where(inside, flat, grid.size)
        acc = _histogram(grid.size + 1)(flat.reshape(-1), jnp.broadcast_to(w[:, None], flat.shape).reshape(-1))
        return acc[: grid.size].reshape(grid.shape)
    raise UserError(f"unknown circle vote method {method!r}; choose 'fft' or 'scatter'")


def _ring_cells(grid: CircleGrid, offsets: jax.Array, x, y):
    """Flat cell indices of the rings around pixels ``(x, y)`` and whether they are on the grid."""
    a = x + offsets[:, 2]
    b = y + offsets[:, 1]
    inside = (a >= 0) & (a < grid.width) & (b >= 0) & (b < grid.height)
    flat = (offsets[:, 0] * grid.height + b) * grid.width + a
    return flat, inside


def votes(grid: Grid, events: Events, *, signed: bool = True) -> jax.Array:
    """The accumulator of ``grid`` for a set of events (:func:`line_votes` or :func:`circle_votes`)."""
    if isinstance(grid, LineGrid):
        return line_votes(grid, events, signed=signed)
    if isinstance(grid, CircleGrid):
        return circle_votes(grid, events, signed=signed)
    raise UserError(f"not a Hough grid: {type(grid).__name__}")


# --- neurons -------------------------------------------------------------------


def _decay(v, amount):
    """Alg. 1, line 2: ``sign(v) * max(|v| - amount, 0)``."""
    return jnp.sign(v) * jnp.maximum(jnp.abs(v) - amount, 0.0)


def _neighbourhood(fired: jax.Array) -> jax.Array:
    """Cells within one step (3 x 3, or 3 x 3 x 3) of a fired cell; the grid does not wrap.

    A box dilation, one axis at a time, as the OR of three shifted slices of the
    padded mask (XLA's CPU ``reduce_window`` is a generic loop, twice as slow).
    """
    for axis in range(fired.ndim):
        n = fired.shape[axis]
        padded = jnp.pad(fired, [(1, 1) if a == axis else (0, 0) for a in range(fired.ndim)])
        shifted = [jax.lax.slice_in_dim(padded, i, i + n, axis=axis) for i in range(3)]
        fired = shifted[0] | shifted[1] | shifted[2]
    return fired


def sync_step(
    params: HoughParams, grid: Grid, state: HoughState, events: Events, t
) -> tuple[HoughState, jax.Array]:
    """One synchronous update of the whole grid at time ``t`` (the paper's GPU mode).

    All events of the slot are voted at once (:func:`votes`, signed by polarity);
    then every neuron makes one Alg. 1 update: decay by ``decay * (t - t_last)``,
    add its summed votes, fire with the sign of ``v`` where ``|v| >= v_th``; the
    3 x 3 (x 3) neighbourhoods of the fired neurons are reset to 0.

    Returns:
        ``(state, spikes)``: spikes of shape ``grid.shape``, int8 in ``{-1, 0, +1}``.
    """
    t = jnp.asarray(t, jnp.float32)
    v = _decay(state.v, params.decay * (t - state.t)) + votes(grid, events)
    fired = jnp.abs(v) >= params.v_th
    spikes = jnp.where(fired, jnp.sign(v), 0.0).astype(jnp.int8)
    v = jnp.where(_neighbourhood(fired), 0.0, v)
    return HoughState(v, jnp.full_like(state.t, t)), spikes


@functools.partial(jax.jit, static_argnames=("grid",))
def sync_run(
    params: HoughParams, grid: Grid, events: Events, times, state: HoughState | None = None
) -> tuple[HoughState, jax.Array]:
    """:func:`sync_step` over time slots.

    Args:
        params: neuron parameters.
        grid: the grid (static).
        events: :class:`Events` with leaves ``(n_slots, capacity)``, one row per slot.
        times: ``(n_slots,)`` the time of each slot's update, seconds (its end).
        state: the starting state (default: :func:`init` at ``times[0]``).

    Returns:
        ``(state, spikes)``, spikes ``(n_slots, *grid.shape)`` int8.
    """
    times = jnp.asarray(times, jnp.float32)
    if state is None:
        state = init(grid, times[0])

    def body(state, slot):
        ev, t = slot
        return sync_step(params, grid, state, ev, t)

    return jax.lax.scan(body, state, (events, times))


def _line_wiring(grid: LineGrid):
    """The cells an event votes for, and the neighbourhoods of those cells, on a line grid.

    Returns ``(cells, neighbours)``: ``cells(x, y, valid)`` gives, for events of
    shape ``(B,)``, the ``(B, n_theta)`` cells (one per angle, ``grid.size`` where
    masked) and whether each is on the grid; ``neighbours(cells, which, x, y)``
    gives the ``(B, K, 9)`` 3 x 3 neighbourhoods (``grid.size`` outside the grid)
    of the cells at positions ``which`` ``(B, K)`` of ``cells``.
    """
    table = jnp.asarray(_compact_table(grid))
    dk, dj = (a.reshape(-1) for a in np.meshgrid(np.arange(-1, 2), np.arange(-1, 2), indexing="ij"))

    def cells(x, y, valid):
        on = valid & (x >= 0) & (x < grid.width) & (y >= 0) & (y < grid.height)
        pixel = jnp.where(on, y * grid.width + x, 0).astype(jnp.uint32)
        flat = table.at[pixel].get(mode="promise_in_bounds").astype(jnp.int32)
        ok = on[:, None] & (flat < grid.size)
        return jnp.where(ok, flat, grid.size), ok

    def neighbours(flat, which, x, y):
        rho = jnp.take_along_axis(flat, which, axis=1) - which * grid.n_rho
        nk, nj = which[..., None] + dk, rho[..., None] + dj
        inside = (nk >= 0) & (nk < grid.n_theta) & (nj >= 0) & (nj < grid.n_rho)
        return jnp.where(inside, nk * grid.n_rho + nj, grid.size)

    return cells, neighbours


def _circle_wiring(grid: CircleGrid):
    """:func:`_line_wiring` for a circle grid: an event's ring cells, 3 x 3 x 3 neighbourhoods."""
    offsets = jnp.asarray(ring_offsets(grid))
    d = np.stack([a.reshape(-1) for a in np.meshgrid(*(np.arange(-1, 2),) * 3, indexing="ij")], axis=1)

    def cells(x, y, valid):
        flat, inside = _ring_cells(grid, offsets, x[:, None], y[:, None])
        ok = valid[:, None] & inside
        return jnp.where(ok, flat, grid.size), ok

    def neighbours(flat, which, x, y):
        o = offsets[which]  # (B, K, 3)
        kr = o[..., 0, None] + d[:, 0]
        b = y[:, None, None] + o[..., 1, None] + d[:, 1]
        a = x[:, None, None] + o[..., 2, None] + d[:, 2]
        inside = (kr >= 0) & (kr < grid.n_r) & (b >= 0) & (b < grid.height) & (a >= 0) & (a < grid.width)
        return jnp.where(inside, (kr * grid.height + b) * grid.width + a, grid.size)

    return cells, neighbours


def _async_batch(params: HoughParams, grid: Grid, state: HoughState, events: Events, chunk: int = 12):
    """:func:`async_run` for a batch of ``B`` streams (leading axis of every leaf), written out.

    The loop runs over event positions, not streams: step ``i`` feeds event ``i``
    of every stream at once, so that each step is one gather and one scatter-add
    of ``B x m`` cells (``m`` the cells an event votes for) on a flat state of
    ``B`` grids, each with a dummy cell ``grid.size`` that masked votes go to.
    A ``vmap`` of the one-stream loop does the same work, but XLA's CPU backend
    copies the whole batched state on every event there.

    Inhibition (Alg. 1, line 5) runs only on steps where some stream fired: the
    fired cells of each stream are taken ``chunk`` at a time, lowest first, from
    their mask packed as bits (`spikejax.bits`; 1.3-1.7x faster than packing
    them to the front with a cumulative sum and a scatter), and their
    neighbourhoods reset.
    """
    size, n = grid.size, grid.size + 1
    batch = state.v.shape[0]
    base = jnp.arange(batch, dtype=jnp.int32) * n
    v_th = jnp.broadcast_to(params.v_th, (batch,))
    decay = jnp.broadcast_to(params.decay, (batch,))
    cells_of, neighbours_of = _line_wiring(grid) if isinstance(grid, LineGrid) else _circle_wiring(grid)
    packed = jnp.stack([state.v.reshape(batch, size), state.t.reshape(batch, size)], axis=-1)
    packed = jnp.concatenate([packed, jnp.zeros((batch, 1, 2), jnp.float32)], axis=1).reshape(batch * n, 2)

    def step(carry, event):
        packed, out = carry
        x, y, t, p, valid = event  # each (B,)
        cells, ok = cells_of(x, y, valid)  # (B, m)
        flat = cells + base[:, None]
        old = packed[flat]
        # Alg. 1, lines 2-3, with the decay since each cell's own last update.
        new = _decay(old[..., 0], decay[:, None] * (t[:, None] - old[..., 1])) + p[:, None].astype(jnp.float32)
        # Written as the change from the gathered values: XLA updates the state in
        # place for a scatter-add after a gather, where a scatter-set makes it copy.
        # Masked votes add nothing, so the dummy cell stays at (0, 0).
        update = jnp.stack([new, jnp.broadcast_to(t[:, None], new.shape)], axis=-1) - old
        packed = packed.at[flat].add(jnp.where(ok[..., None], update, 0.0), mode="promise_in_bounds")
        fired = ok & (jnp.abs(new) >= v_th[:, None])

        def inhibit(packed, out):
            signs = jnp.sign(new).astype(jnp.int8)
            m = fired.shape[1]

            def body(carry):
                words, packed, out = carry
                which, words = jax.vmap(lambda w: bits.take_lowest(w, chunk, m))(words)
                live = which < m
                which = jnp.where(live, which, 0)
                idx = jnp.where(live[..., None], neighbours_of(cells, which, x, y), size) + base[:, None, None]
                packed = packed.at[idx.reshape(-1), 0].set(0.0, mode="promise_in_bounds")
                spiked = jnp.where(live, jnp.take_along_axis(cells, which, axis=1), size) + base[:, None]
                out = out.at[spiked.reshape(-1)].set(
                    jnp.take_along_axis(signs, which, axis=1).reshape(-1), mode="promise_in_bounds"
                )
                return words, packed, out

            words = jax.vmap(bits.pack)(fired)
            _, packed, out = jax.lax.while_loop(lambda c: jnp.any(c[0] != 0), body, (words, packed, out))
            return packed, out

        return jax.lax.cond(jnp.any(fired), inhibit, lambda packed, out: (packed, out), packed, out), None

    def slot(packed, events):
        out = jnp.zeros((batch * n,), jnp.int8)
        (packed, out), _ = jax.lax.scan(step, (packed, out), events)
        return packed, out.reshape(batch, n)[:, :size].reshape((batch,) + grid.shape)

    # (B, n_slots, capacity) -> (n_slots, capacity, B): one scan step per event position.
    events = jax.tree.map(lambda a: jnp.moveaxis(a, 0, -1), tuple(events))
    packed, spikes = jax.lax.scan(slot, packed, events)
    packed = packed.reshape(batch, n, 2)[:, :size]
    state = HoughState(packed[..., 0].reshape(state.v.shape), packed[..., 1].reshape(state.t.shape))
    return state, jnp.moveaxis(spikes, 0, 1)


def async_step(
    params: HoughParams, grid: Grid, state: HoughState, events: Events
) -> tuple[HoughState, jax.Array]:
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
    :func:`sync_step` at the event's time gives the same spikes and potentials.

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
    """:func:`async_step` over time slots.

    Args:
        params: neuron parameters.
        grid: the grid (static).
        events: :class:`Events` with leaves ``(n_slots, capacity)``, each row in
            time order, rows consecutive in time.
        state: the starting state (default: :func:`init` at time 0).

    Returns:
        ``(state, spikes)``, spikes ``(n_slots, *grid.shape)`` int8.
    """
    if not isinstance(grid, (LineGrid, CircleGrid)):
        raise UserError(f"not a Hough grid: {type(grid).__name__}")
    if state is None:
        state = init(grid)
    return _async_streams(grid)(params, state, events)


def _broadcast_unbatched(axis_size, in_batched, args):
    return jax.tree.map(lambda a, b: a if b else jnp.broadcast_to(a, (axis_size,) + jnp.shape(a)), args, in_batched)


@functools.cache
def _async_streams(grid: Grid):
    """:func:`async_run` for one stream; under ``vmap``, :func:`_async_batch` over the streams.

    Nested ``vmap``s fold into one batch of streams.
    """

    @jax.custom_batching.custom_vmap
    def streams(params, state, events):  # a leading stream axis on every leaf
        return _async_batch(params, grid, state, events)

    @streams.def_vmap
    def _fold(axis_size, in_batched, params, state, events):
        args = _broadcast_unbatched(axis_size, tuple(in_batched), (params, state, events))
        out = streams(*jax.tree.map(lambda a: a.reshape((-1,) + a.shape[2:]), args))
        out = jax.tree.map(lambda a: a.reshape((axis_size, -1) + a.shape[1:]), out)
        return out, jax.tree.map(lambda _: True, out)

    @jax.custom_batching.custom_vmap
    def one(params, state, events):
        out = streams(*jax.tree.map(lambda a: jnp.asarray(a)[None], (params, state, events)))
        return jax.tree.map(lambda a: a[0], out)

    @one.def_vmap
    def _batch(axis_size, in_batched, params, state, events):
        out = streams(*_broadcast_unbatched(axis_size, tuple(in_batched), (params, state, events)))
        return out, jax.tree.map(lambda _: True, out)

    return one
