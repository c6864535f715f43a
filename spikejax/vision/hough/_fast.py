"""The fast kernels behind `spikejax.vision.hough`: batching rules, cache-sized chunks, a flat-batch event loop.

They compute what `spikejax.vision.hough.neuron` computes (Alg. 1 of the snake
pipe-tracking paper, whose algorithm and equation numbers the comments cite),
spike for spike and bit for bit (tested), arranged for XLA's CPU backend; the
public functions of `spikejax.vision.hough` call them. What each arrangement
was measured against: docs/BENCHMARKS.md, "Spiking Hough detectors".

* Line votes, a stream alone or a few: scatter-adds of each event's
  ``n_theta`` cells, read from the static table `line_table` (gathered as
  uint16) into an int32 accumulator, a few hundred events at a time so that
  the gathered cells stay in the cache; under ``vmap`` on a CPU the streams
  are voted one after another, each into its own cache-resident accumulator
  (a custom batching rule, the one place that asks for the backend).
* Line votes and the synchronous run, from `DENSE_MIN_STREAMS` streams on
  under ``vmap`` on a CPU: groups of about 64 streams (a multiple of 32) laid out ``(cell, stream)``;
  each stream's events summed into its image, and every cell the sum of the
  image rows of the pixels on its line (`_line_dense_sums`): the same
  integers, vectorised across the 64 streams of a row, 2-3x faster than the
  scatter on the bench frames. `sync_run` keeps that layout from the first
  slot to the last (`_line_sync_group`).
* Circle votes: the event image convolved with the ring kernels by FFT, each
  radius at the smallest size (a multiple of 8) its ring needs, two radii to
  a complex inverse FFT (the real and imaginary parts).
* Lateral inhibition (sync): the box dilation as ORs of shifted slices.
* The asynchronous loop steps over event positions with every stream of the
  batch at once: one gather of the ``(v, t_last)`` of the cells the events
  touch and one scatter-add of the change, with inhibition (the fired cells
  taken a few at a time from their mask packed as bits) only on steps where
  some stream fired.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from spikejax import bits
from spikejax.devices import in_chunks_on_cpu
from spikejax.errors import UserError
from spikejax.vision.events import Events
from spikejax.vision.hough.grids import CircleGrid, Grid, LineGrid, check_grid, line_table, ring_offsets
from spikejax.vision.hough.neuron import HoughParams, HoughState, decay, init


def _one_stream_at_a_time(fn):
    """``fn`` (written for one stream), batched under ``vmap`` by ``lax.map`` on a CPU.

    A scatter into a per-stream accumulator stays in the cache, and XLA's CPU
    backend runs it as one tight loop; a batched (or flattened) scatter touches
    every stream's accumulator and is slower there. Other backends ``vmap``
    (`spikejax.devices.in_chunks_on_cpu`).
    """
    return in_chunks_on_cpu(fn)


def _scatter_add(length: int, index, weight):
    """``zeros(length).at[index].add(weight)``, with ``0 <= index < length``."""
    return jnp.zeros((length,), weight.dtype).at[index].add(weight, mode="promise_in_bounds")


@functools.cache
def _histogram(length: int):
    """`_scatter_add` of one stream, batched by `_one_stream_at_a_time`."""
    return _one_stream_at_a_time(lambda index, weight: _scatter_add(length, index, weight))


def _weights(events: Events, signed: bool) -> jax.Array:
    w = events.p.astype(jnp.float32) if signed else jnp.ones(events.p.shape, jnp.float32)
    return jnp.where(events.valid, w, 0.0)


def _pixel(grid, events: Events) -> tuple[jax.Array, jax.Array]:
    """Flat pixel index of each event and whether it lies on the sensor."""
    on = (events.x >= 0) & (events.x < grid.width) & (events.y >= 0) & (events.y < grid.height)
    pixel = jnp.where(on, events.y * grid.width + events.x, 0)
    return pixel, on & events.valid


def line_votes(grid: LineGrid, events: Events, *, signed: bool = True) -> jax.Array:
    """`spikejax.vision.hough.line_votes`, by `_line_accumulator`."""
    return _line_accumulator(grid, signed, merge=grid.merge_pixels)(events)


# Events voted at a time by `_line_accumulator`: their cells stay in the L2 cache.
VOTE_CHUNK = 576


@functools.cache
def _compact_table(grid: LineGrid) -> np.ndarray:
    """`line_table` as uint16 where the cells fit: half the bytes to gather per event."""
    table = line_table(grid)
    return table.astype(np.uint16) if grid.size < 2**16 else table


@functools.cache
def _line_accumulator(grid: LineGrid, signed: bool, chunk: int = VOTE_CHUNK, merge: bool = False):
    """`line_votes` for one stream: scatter-adds of the events' table rows.

    With ``merge``, the events at the same pixel are first summed into one
    vote of their total weight (the accumulator is linear in the events:
    ``sum_e w_e T[pixel_e] = sum_pixels (sum of w_e at the pixel) T[pixel]``, in
    integers, so exactly), pixels whose events cancel are dropped, and the
    remaining votes are packed to the front. A slot then costs votes for its
    active pixels, not for its events or its capacity.

    Either way, chunks past the last valid event (or merged vote) are
    skipped (a ``cond`` per chunk: on a CPU the streams run one at a time,
    so it stays a branch): a buffer of capacity 2,048 holding 400 events
    packed to the front costs one chunk, not four.

    The votes go ``chunk`` at a time (a ``lax.scan``), so that the cell indices
    and weights of a chunk (``chunk * n_theta`` of each) stay in the CPU's L2
    cache between being gathered and being scattered. Counts are summed in
    int32 (exact, as float32 sums of +-1 are); the table is gathered as uint16.
    Streams run one at a time on a CPU (`_one_stream_at_a_time`).
    """
    table = _compact_table(grid)
    n_pixels = grid.height * grid.width

    def accumulate(events):
        pixel, ok = _pixel(grid, events)
        w = jnp.where(ok, events.p if signed else 1, 0).astype(jnp.int32)
        n = pixel.shape[0]
        if merge:
            order = jnp.arange(n, dtype=jnp.int32)
            first = jnp.full((n_pixels,), n, jnp.int32).at[pixel].min(jnp.where(ok, order, n))
            total = jnp.zeros((n_pixels,), jnp.int32).at[pixel].add(w)[pixel]
            keep = ok & (first[pixel] == order) & (total != 0)
            rank = jnp.cumsum(keep.astype(jnp.int32))
            slot = jnp.where(keep, rank - 1, n)
            pixel = jnp.zeros((n + 1,), pixel.dtype).at[slot].set(pixel, mode="promise_in_bounds")[:n]
            w = jnp.zeros((n + 1,), jnp.int32).at[slot].set(total, mode="promise_in_bounds")[:n]
            votes = rank[-1]
        else:
            votes = jnp.max(jnp.where(ok, jnp.arange(1, n + 1, dtype=jnp.int32), 0))
        n_chunks = -(-n // chunk)
        length = -(-n // n_chunks)
        pad = n_chunks * length - n  # padding events have weight 0
        pixel = jnp.pad(pixel, (0, pad)).astype(jnp.uint32).reshape(n_chunks, length)
        w = jnp.pad(w, (0, pad)).reshape(n_chunks, length)

        def add(acc, part):
            pixel, w = part
            cells = jnp.asarray(table).at[pixel].get(mode="promise_in_bounds")
            return acc.at[cells.reshape(-1)].add(jnp.repeat(w, grid.n_theta), mode="promise_in_bounds")

        def maybe_add(acc, part):
            start, pixel, w = part
            return jax.lax.cond(start < votes, add, lambda acc, _: acc, acc, (pixel, w)), None

        starts = jnp.arange(n_chunks, dtype=jnp.int32) * length
        acc, _ = jax.lax.scan(maybe_add, jnp.zeros((grid.size + 1,), jnp.int32), (starts, pixel, w))
        return acc[: grid.size].reshape(grid.shape).astype(jnp.float32)

    batched = jax.custom_batching.custom_vmap(accumulate)

    @batched.def_vmap
    def _rule(axis_size, in_batched, events):
        events = _broadcast_unbatched(axis_size, in_batched[0], events)
        if jax.default_backend() != "cpu":
            out = jax.vmap(accumulate)(events)
        elif axis_size < DENSE_MIN_STREAMS:
            out = jax.lax.map(batched, events)
        else:
            out = _line_votes_by_groups(grid, signed, events, lambda e: jax.lax.map(batched, e))
        return out, True

    return batched


# Streams voted together by `_line_dense_sums` (64 int8 or int16 counts a row: shorter rows vectorise poorly,
# and a group's potentials, 8 MB at 64 streams, stay in the L3 cache), and the fewest for which a batch is.
DENSE_GROUP = 64
DENSE_MIN_STREAMS = 32
# Events a stream at which `_line_dense_sums` (0.13 ms a stream, whatever its events) costs what the event
# scatter costs (0.30 us an event); measured on a 2-core AMD EPYC, docs/BENCHMARKS.md.
DENSE_MIN_EVENTS = 430


@functools.cache
def _line_pixel_lists(grid: LineGrid, blocks: int = 32, unroll: int = 4) -> tuple[list[np.ndarray], np.ndarray]:
    """`line_table` inverted: the pixels on each cell's line, for `_line_dense_sums`.

    Returns ``(lists, order)``: the cells sorted by how many pixels vote for
    them (most first), split into ``blocks`` blocks; ``lists[i]`` is block
    ``i``'s ``(steps, unroll, cells)`` pixel indices, padded with the index
    ``height * width`` (a pixel that is always 0); ``order`` the inverse of
    that sort (``concatenate(blocks)[order]`` is in cell order). Sorting
    keeps the padding at 7 % of the entries (3.17 M for 2.95 M on the paper's
    grid). The indices are int16 below 2^15 pixels: they are the dense sums'
    largest read (12.7 MB a frame as int32), and half of it ran 6 % faster on
    two devices.
    """
    n_pixels = grid.height * grid.width
    table = line_table(grid)
    cells = table.reshape(-1)
    pixels = np.repeat(np.arange(n_pixels, dtype=np.int32), grid.n_theta)
    keep = cells < grid.size
    cells, pixels = cells[keep], pixels[keep]
    by_cell = np.argsort(cells, kind="stable")
    cells, pixels = cells[by_cell], pixels[by_cell]
    counts = np.bincount(cells, minlength=grid.size)
    rank = np.arange(cells.size) - (np.cumsum(counts) - counts)[cells]
    longest = -(-max(int(counts.max()), 1) // unroll) * unroll
    padded = np.full((grid.size, longest), n_pixels, np.int32)
    padded[cells, rank] = pixels
    sort = np.argsort(-counts, kind="stable")
    index = np.int16 if n_pixels < 2**15 else np.int32
    lists = []
    for block in np.array_split(sort, blocks):
        steps = -(-max(int(counts[block].max()), 1) // unroll)
        lists.append(padded[block, : steps * unroll].T.reshape(steps, unroll, block.size).astype(index).copy())
    return lists, np.argsort(sort).astype(np.int32)


def _vote_dtype(events: Events):
    """int16 when a slot's capacity bounds every count below 2^15 (each event adds +-1), else int32."""
    return jnp.int16 if events.x.shape[-1] < 2**15 else jnp.int32


def _line_dense_sums(grid: LineGrid, signed: bool, events: Events) -> jax.Array:
    """The line accumulators of a group of ``G`` streams at once: ``(grid.size, G)`` integers (`_vote_dtype`).

    The votes are linear in the events, so a cell's count is the sum, over the
    pixels on its line, of the events' weights summed per pixel: each stream's
    events are first summed into its image, laid out ``(pixel, stream)``, and
    then every cell adds up the image rows of its line's pixels
    (`_line_pixel_lists`), all ``G`` streams in one contiguous row. That is
    the same integers as the per-event scatter, for ``height * width *
    n_theta`` row additions a group whatever its events: a CPU vectorises
    them across the streams, where a scatter-add of each event's cells runs
    one cell at a time. The image is read as int8 when every pixel's sum fits
    (the rows are then half as long), the rows added four at a time.
    """
    group = events.x.shape[0]
    n_pixels = grid.height * grid.width
    dtype = _vote_dtype(events)
    pixel, ok = jax.vmap(lambda e: _pixel(grid, e))(events)
    w = jnp.where(ok, events.p if signed else 1, 0).astype(dtype)
    slot = jnp.where(ok, pixel, n_pixels) * group + jnp.arange(group, dtype=jnp.int32)[:, None]
    image = jnp.zeros(((n_pixels + 1) * group,), dtype)
    image = image.at[slot.reshape(-1)].add(w.reshape(-1), mode="promise_in_bounds").reshape(n_pixels + 1, group)
    lists, order = _line_pixel_lists(grid)

    def sums(image):
        out = []
        for pixels in lists:
            pixels = jnp.asarray(pixels)

            def add(i, acc, pixels=pixels):
                for row in pixels[i]:
                    acc = acc + image.at[row].get(mode="promise_in_bounds").astype(dtype)
                return acc

            out.append(jax.lax.fori_loop(0, pixels.shape[0], add, jnp.zeros((pixels.shape[2], group), dtype)))
        return jnp.concatenate(out)[jnp.asarray(order)]

    small = jnp.max(jnp.abs(image)) <= 127
    return jax.lax.cond(small, lambda image: sums(image.astype(jnp.int8)), sums, image)


def _line_group_sums(grid: LineGrid, signed: bool, events: Events, sparse) -> jax.Array:
    """`_line_dense_sums` of a group, or, below `DENSE_MIN_EVENTS` events a stream, ``sparse`` transposed.

    ``sparse`` maps the group's events to its ``(G, *grid.shape)`` float32
    accumulators one stream at a time; both give the same integers.
    """
    group, capacity = events.x.shape
    dtype = _vote_dtype(events)

    def by_stream(events):
        return sparse(events).reshape(group, grid.size).T.astype(dtype)

    # The events the scatter would vote: each stream's up to its last valid one, in whole chunks.
    n_chunks = -(-capacity // VOTE_CHUNK)
    length = -(-capacity // n_chunks)
    last = jnp.max(jnp.where(events.valid, jnp.arange(1, capacity + 1, dtype=jnp.int32), 0), axis=1)
    busy = jnp.sum(-(-last // length) * length) >= DENSE_MIN_EVENTS * group
    return jax.lax.cond(busy, lambda e: _line_dense_sums(grid, signed, e), by_stream, events)


def _groups(batch: int) -> tuple[int, int]:
    """``(n_groups, group)``: a batch split into groups of at most about `DENSE_GROUP`, a multiple of 32.

    Rows of 32 streams vectorise worse than rows of 64 (the votes 1.2-1.3x
    the time a stream), but better than 32 streams padded to 64 (measured,
    one core: the votes of 32 streams 6.8 ms a step in a row of 32, 9.4
    padded to 64; a whole `sync_run` 0.29 ms a stream-slot either way).
    """
    n_groups = -(-batch // DENSE_GROUP)
    group = -(-batch // n_groups)
    return n_groups, -(-group // 32) * 32


def _grouped(tree, n_groups: int, group: int):
    """Leading axis padded to ``n_groups * group`` (with zeros: invalid events) and split ``(n_groups, group)``."""

    def split(a):
        a = jnp.pad(a, [(0, n_groups * group - a.shape[0])] + [(0, 0)] * (a.ndim - 1))
        return a.reshape((n_groups, group) + a.shape[1:])

    return jax.tree.map(split, tree)


def _ungrouped(tree, batch: int):
    return jax.tree.map(lambda a: a.reshape((-1,) + a.shape[2:])[:batch], tree)


def _line_votes_by_groups(grid: LineGrid, signed: bool, events: Events, sparse) -> jax.Array:
    """`line_votes` of a batch of streams, a group at a time (`_line_group_sums`)."""
    batch = events.x.shape[0]
    n_groups, group = _groups(batch)

    def one_group(events):
        acc = _line_group_sums(grid, signed, events, sparse)
        return acc.T.reshape((group,) + grid.shape).astype(jnp.float32)

    return _ungrouped(jax.lax.map(one_group, _grouped(events, n_groups, group)), batch)


def event_image(grid, events: Events, *, signed: bool = True) -> jax.Array:
    """Sum of the events' polarities (or counts) per pixel: ``(height, width)`` float32."""
    pixel, ok = _pixel(grid, events)
    w = jnp.where(ok, _weights(events, signed), 0.0)
    image = jnp.zeros((grid.height * grid.width,), jnp.float32).at[pixel].add(w)
    return image.reshape(grid.height, grid.width)


def _fft_size(n: int, reach: int) -> int:
    """Smallest multiple of 8 >= n + reach: a circular convolution of that size has no wrap-around.

    (Measured against 2^i 3^j 5^k sizes and multiples of 4 and 16: multiples
    of 8 were fastest for the 128 x 128 circle grid, docs/BENCHMARKS.md.)
    """
    return -(-(n + reach) // 8) * 8


@functools.cache
def _ring_spectra(grid: CircleGrid) -> tuple[tuple[int, int, int, np.ndarray], ...]:
    """The ring kernels' FFTs, two radii to a spectrum, complex64, computed once on the host (constants).

    The radii are grouped by the FFT size their rings need (`_fft_size` of the
    largest offset; a small ring convolved at the size of the largest would
    cost up to 2x more): ``(ny, nx, radii, spectra (pairs, ny, nx))`` per
    group, in radius order. In a group of ``n`` radii, radius ``i`` is paired
    with radius ``i + ceil(n / 2)`` and the pair's spectrum is ``F(k_a) + i
    F(k_b)``: the image and the kernels are real, so one complex inverse FFT of
    the image's spectrum times it gives both convolutions, the group's first
    half as its real part and its second half as its imaginary part. (XLA's
    CPU ``irfft2`` ran 3x slower than a complex ``ifft2`` of the same size
    carrying two radii, measured.)
    """
    offsets = ring_offsets(grid)
    groups = []
    for k in range(grid.n_r):
        ring = offsets[offsets[:, 0] == k]
        reach = int(np.abs(ring[:, 1:]).max()) if len(ring) else 0
        size = (_fft_size(grid.height, reach), _fft_size(grid.width, reach))
        if groups and groups[-1][0] == size:
            groups[-1][1].append(k)
        else:
            groups.append((size, [k]))
    out = []
    for (ny, nx), radii in groups:
        kernels = np.zeros((2 * (-(-len(radii) // 2)), ny, nx))
        for i, k in enumerate(radii):
            ring = offsets[offsets[:, 0] == k]
            # An event at (x, y) votes for the centre (x + da, y + db): the kernel is the
            # ring itself, placed at (db mod ny, da mod nx).
            kernels[i, ring[:, 1] % ny, ring[:, 2] % nx] = 1.0
        spectra = np.fft.fft2(kernels)
        half = spectra.shape[0] // 2
        out.append((ny, nx, len(radii), (spectra[:half] + 1j * spectra[half:]).astype(np.complex64)))
    return tuple(out)


def circle_image_votes(grid: CircleGrid, image: jax.Array) -> jax.Array:
    """`spikejax.vision.hough.circle_image_votes`: the image convolved with each ring by FFT, two radii a transform.

    Under ``vmap`` on a CPU the images are convolved one at a time: a batch's
    spectra (16 snakes of the pipe loop: 82 MB) leave the caches, and the
    pipe loop's two convolutions a slot then cost 3.6 ms a snake each.
    """
    return _circle_image_streams(grid)(image)


@functools.cache
def _circle_image_streams(grid: CircleGrid):
    return _one_stream_at_a_time(lambda image: _circle_image_votes(grid, image))


def _circle_image_votes(grid: CircleGrid, image: jax.Array) -> jax.Array:
    parts = []
    h, w = grid.height, grid.width
    for ny, nx, radii, spectra in _ring_spectra(grid):
        both = jnp.fft.ifft2(spectra * jnp.fft.fft2(image, s=(ny, nx))[None])[:, :h, :w]
        parts += [both.real, both.imag[: radii - both.shape[0]]]
    return jnp.round(jnp.concatenate(parts))


def circle_votes(grid: CircleGrid, events: Events, *, signed: bool = True, method: str = "fft") -> jax.Array:
    """`spikejax.vision.hough.circle_votes`: by FFT (`_ring_kernels`) or by a scatter of the ring cells."""
    if method == "fft":
        return circle_image_votes(grid, event_image(grid, events, signed=signed))
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
    """`line_votes` or `circle_votes`, by the type of ``grid``."""
    check_grid(grid)
    if isinstance(grid, LineGrid):
        return line_votes(grid, events, signed=signed)
    return circle_votes(grid, events, signed=signed)


# --- neurons -------------------------------------------------------------------


def _neighbourhood(fired: jax.Array, axes=None) -> jax.Array:
    """`spikejax.vision.hough.neuron.neighbourhood`, as a box dilation one axis at a time (``axes``: all).

    The OR of three shifted slices of the padded mask per axis: XLA's CPU
    ``reduce_window`` is a generic loop, slower.
    """
    for axis in range(fired.ndim) if axes is None else axes:
        n = fired.shape[axis]
        padded = jnp.pad(fired, [(1, 1) if a == axis else (0, 0) for a in range(fired.ndim)])
        shifted = [jax.lax.slice_in_dim(padded, i, i + n, axis=axis) for i in range(3)]
        fired = shifted[0] | shifted[1] | shifted[2]
    return fired


def _neighbourhood_by_words(fired: jax.Array) -> jax.Array:
    """`_neighbourhood` of a mask whose last axis is a multiple of 32 long, that axis packed 32 cells a word.

    Along the last axis a cell's neighbours are the bits beside it (shifts,
    with the carries between words); along the others, ORs of shifted slices
    of 32 times fewer words. On the 64 x 128 x 128 circle grid 1.7x faster
    than dilating the unpacked mask.
    """
    lead, n = fired.shape[:-1], fired.shape[-1]
    bit = jnp.arange(32, dtype=jnp.uint32)
    words = jnp.sum(fired.reshape(lead + (n // 32, 32)).astype(jnp.uint32) << bit, axis=-1, dtype=jnp.uint32)
    pad = [(0, 0)] * len(lead)
    before = jnp.pad(words, pad + [(1, 0)])[..., :-1]  # the word of the 32 cells before
    after = jnp.pad(words, pad + [(0, 1)])[..., 1:]
    words = words | (words << 1) | (before >> 31) | (words >> 1) | (after << 31)
    words = _neighbourhood(words, axes=range(len(lead)))
    return ((words[..., None] >> bit) & 1).reshape(fired.shape) != 0


def sync_step(params: HoughParams, grid: Grid, state: HoughState, events: Events, t) -> tuple[HoughState, jax.Array]:
    """`spikejax.vision.hough.neuron.sync_step` with the fast `votes` and `_neighbourhood`.

    On a circle grid, streams under ``vmap`` run one after another
    (`_circle_streams`).
    """
    if isinstance(grid, CircleGrid):
        return _circle_streams(grid, "step")(params, state, events, jnp.asarray(t, jnp.float32))
    return sync_update(params, state, votes(grid, events), t)


@functools.cache
def _circle_streams(grid: CircleGrid, what: str):
    """`sync_step` (``what="step"``) or `_sync_scan` (``"run"``; ``"fresh"`` from `init`) of a circle grid,
    one stream at a time under ``vmap``.

    A stream's grid is 4 MB of potentials and its FFTs work on 64 spectra of
    up to 192 x 97: batched, several streams' leave the caches, and on the
    bench frames a batch of 4 ran at two thirds of the rate of one stream.
    """
    if what == "step":
        return _one_stream_at_a_time(lambda p, s, e, t: sync_update(p, s, votes(grid, e), t))
    if what == "fresh":
        return _one_stream_at_a_time(lambda p, e, t: _sync_scan(p, grid, init(grid, t[0]), e, t))
    return _one_stream_at_a_time(lambda p, s, e, t: _sync_scan(p, grid, s, e, t))


def sync_update(params: HoughParams, state: HoughState, slot_votes: jax.Array, t) -> tuple[HoughState, jax.Array]:
    """`sync_step` given the slot's accumulator ``slot_votes`` (the grid's shape) instead of its events."""
    t = jnp.asarray(t, jnp.float32)
    v = decay(state.v, params.decay * (t - state.t)) + slot_votes
    fired = jnp.abs(v) >= params.v_th
    spikes = jnp.where(fired, jnp.sign(v), 0.0).astype(jnp.int8)
    near = _neighbourhood_by_words(fired) if fired.shape[-1] % 32 == 0 else _neighbourhood(fired)
    v = jnp.where(near, 0.0, v)
    return HoughState(v, jnp.full_like(state.t, t)), spikes


def sync_run(
    params: HoughParams, grid: Grid, events: Events, times, state: HoughState | None = None
) -> tuple[HoughState, jax.Array]:
    """`sync_step` over time slots (a ``lax.scan``); under ``vmap``, `_line_sync_streams` or `_circle_streams`."""
    times = jnp.asarray(times, jnp.float32)
    if state is None and isinstance(grid, CircleGrid):  # each stream's grid made in its turn, not all at once
        return _circle_streams(grid, "fresh")(params, events, times)
    if state is None:
        state = init(grid, times[0])
    if isinstance(grid, LineGrid):
        return _line_sync_streams(grid)(params, state, events, times)
    return _circle_streams(grid, "run")(params, state, events, times)


def _sync_scan(params: HoughParams, grid: Grid, state: HoughState, events: Events, times):
    def body(state, slot):
        ev, t = slot
        return sync_step(params, grid, state, ev, t)

    return jax.lax.scan(body, state, (events, times))


@functools.cache
def _line_sync_streams(grid: LineGrid):
    """`sync_run` on a line grid for one stream; under ``vmap`` on a CPU, `_line_sync_batch`.

    From `DENSE_MIN_STREAMS` streams on, the batch runs in groups laid out
    ``(cell, stream)`` from the first slot to the last (`_line_sync_group`);
    fewer streams run the plain scan batched. Nested ``vmap``s fold into one
    batch of streams.
    """

    def plain(params, state, events, times):
        return _sync_scan(params, grid, state, events, times)

    streams = _folding_nested_vmaps(lambda *args: _line_sync_batch(args[0], grid, *args[1:]))

    one = jax.custom_batching.custom_vmap(plain)

    @one.def_vmap
    def _batch(axis_size, in_batched, *args):
        args = _broadcast_unbatched(axis_size, tuple(in_batched), args)
        if jax.default_backend() == "cpu" and axis_size >= DENSE_MIN_STREAMS:
            out = streams(*args)
        else:
            out = jax.vmap(plain)(*args)
        return out, jax.tree.map(lambda _: True, out)

    return one


def _line_sync_batch(params: HoughParams, grid: LineGrid, state: HoughState, events: Events, times):
    """`sync_run` of ``B`` streams (a leading axis on every leaf), `_line_sync_group` a group at a time."""
    batch = state.v.shape[0]
    if times.shape[1] == 0:
        return jax.vmap(lambda *a: _sync_scan(a[0], grid, *a[1:]))(params, state, events, times)
    n_groups, group = _groups(batch)
    args = _grouped((params, state, events, times), n_groups, group)
    return _ungrouped(jax.lax.map(lambda a: _line_sync_group(grid, *a), args), batch)


def _line_sync_group(grid: LineGrid, params: HoughParams, state: HoughState, events: Events, times):
    """`sync_run` of a group of ``G`` streams with the state laid out ``(theta, rho, stream)`` throughout.

    Each slot's votes come from `_line_group_sums` in that layout, so nothing
    is transposed between slots; the update is `sync_update`'s arithmetic
    with the per-stream parameters and times as rows, the 3 x 3 inhibition
    over the first two axes. The same floats as the plain scan, bit for bit.
    """
    group = state.v.shape[0]

    def cells_first(a):
        return jnp.moveaxis(a.reshape(group, grid.size), 0, -1).reshape(grid.shape + (group,))

    sparse = _line_accumulator(grid, True, merge=grid.merge_pixels)
    v_th, rate = params.v_th, params.decay  # (G,)
    # The decay rate as a (1, rho, stream) array, not a broadcast row: XLA then computes each cell's
    # ``rate * (t - t_last)`` within its update, as the one-stream scan does, its rounding included (a CPU
    # may fuse the product into the subtraction, and does so there), rather than once a row: the same
    # potentials bit for bit. (A (1, 1, stream) array is folded back into a row.)
    rate_cells = jax.lax.optimization_barrier(jnp.broadcast_to(rate, (1, grid.n_rho, group)))

    def step(v, t_last, events, t):  # events (G, capacity), t (G,)
        votes = _line_group_sums(grid, True, events, lambda e: jax.lax.map(sparse, e)).reshape(grid.shape + (group,))
        v = decay(v, rate_cells * (t - t_last)) + votes.astype(jnp.float32)
        fired = jnp.abs(v) >= v_th
        spikes = jnp.where(fired, jnp.sign(v), 0.0).astype(jnp.int8)
        return jnp.where(_neighbourhood(fired, axes=(0, 1)), 0.0, v), spikes

    # Every cell is first decayed from its own last update to the first slot's
    # time; the scan then carries the last update's time as one row (the first
    # slot's decay by 0 leaves each potential as it is, bit for bit).
    events = jax.tree.map(lambda a: jnp.moveaxis(a, 1, 0), events)
    times = jnp.moveaxis(times, 1, 0)
    v = decay(cells_first(state.v), rate * (times[0] - cells_first(state.t)))

    def body(carry, slot):
        v, t_last = carry
        v, spikes = step(v, t_last, *slot)
        return (v, slot[1]), spikes

    (v, t_last), spikes = jax.lax.scan(body, (v, times[0]), (events, times))

    def streams_first(a):
        return jnp.moveaxis(a, -1, 0)

    state = HoughState(streams_first(v), jnp.broadcast_to(t_last[:, None, None], (group,) + grid.shape))
    return state, jnp.moveaxis(spikes, -1, 0)


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
    """`_line_wiring` for a circle grid: an event's ring cells, 3 x 3 x 3 neighbourhoods."""
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


def _async_batch(params: HoughParams, grid: Grid, state: HoughState, events: Events, chunk: int = 4):
    """`async_run` for a batch of ``B`` streams (leading axis of every leaf), written out.

    The loop runs over event positions, not streams: step ``i`` feeds event ``i``
    of every stream at once, so that each step is one gather and one scatter-add
    of ``B x m`` cells (``m`` the cells an event votes for) on a flat state of
    ``B`` grids, each with a dummy cell ``grid.size`` that masked votes go to.
    A cell's ``(v, t_last)`` is one complex64 ``v + i t_last``: one 8-byte element
    to gather and scatter instead of a pair of float32 (the gather and
    scatter alone 1.4-2x faster, the whole loop 1.0-1.2x). A ``vmap`` of
    the one-stream loop does the same work, but XLA's CPU backend copies the
    whole batched state on every event there.

    Inhibition (Alg. 1, line 5) runs only on steps where some stream fired: the
    fired cells of each stream are taken ``chunk`` at a time, lowest first, from
    their mask packed as bits (`spikejax.bits`; faster than packing them to the
    front with a cumulative sum and a scatter), and their neighbourhoods set to
    ``v = 0``, each keeping its ``t_last``. Four at a time: on the line
    bench's frames (about four cells fire per event) 1.3x faster than twelve
    on one core and on two (1.08 -> 1.39 M events/s, 64 streams); 2, 3 and 8
    were 1-10 % slower than 4, and the circle grid runs alike at 4 and 12.
    """
    size, n = grid.size, grid.size + 1
    batch = state.v.shape[0]
    base = jnp.arange(batch, dtype=jnp.int32) * n
    v_th = jnp.broadcast_to(params.v_th, (batch,))
    rate = jnp.broadcast_to(params.decay, (batch,))
    cells_of, neighbours_of = _line_wiring(grid) if isinstance(grid, LineGrid) else _circle_wiring(grid)
    z = jax.lax.complex(state.v.reshape(batch, size), state.t.reshape(batch, size))
    z = jnp.concatenate([z, jnp.zeros((batch, 1), jnp.complex64)], axis=1).reshape(batch * n)

    def step(carry, event):
        z, out = carry
        x, y, t, p, valid = event  # each (B,)
        cells, ok = cells_of(x, y, valid)  # (B, m)
        flat = cells + base[:, None]
        old = z.at[flat].get(mode="promise_in_bounds")
        v_old, t_old = jnp.real(old), jnp.imag(old)
        # Alg. 1, lines 2-3, with the decay since each cell's own last update.
        new = decay(v_old, rate[:, None] * (t[:, None] - t_old)) + p[:, None].astype(jnp.float32)
        # Written as the change from the gathered values: XLA updates the state in
        # place for a scatter-add after a gather, where a scatter-set makes it copy.
        # Masked votes add nothing, so the dummy cell stays at 0.
        change = jnp.where(ok, jax.lax.complex(new - v_old, t[:, None] - t_old), 0)
        z = z.at[flat].add(change, mode="promise_in_bounds")
        fired = ok & (jnp.abs(new) >= v_th[:, None])

        def inhibit(z, out):
            signs = jnp.sign(new).astype(jnp.int8)
            m = fired.shape[1]

            def body(carry):
                words, z, out = carry
                which, words = jax.vmap(lambda w: bits.take_lowest(w, chunk, m))(words)
                live = which < m
                which = jnp.where(live, which, 0)
                idx = jnp.where(live[..., None], neighbours_of(cells, which, x, y), size) + base[:, None, None]
                idx = idx.reshape(-1)
                near = z.at[idx].get(mode="promise_in_bounds")
                zero = jax.lax.complex(jnp.zeros(near.shape, jnp.float32), jnp.imag(near))
                z = z.at[idx].set(zero, mode="promise_in_bounds")
                spiked = jnp.where(live, jnp.take_along_axis(cells, which, axis=1), size) + base[:, None]
                out = out.at[spiked.reshape(-1)].set(
                    jnp.take_along_axis(signs, which, axis=1).reshape(-1), mode="promise_in_bounds"
                )
                return words, z, out

            words = jax.vmap(bits.pack)(fired)
            _, z, out = jax.lax.while_loop(lambda c: jnp.any(c[0] != 0), body, (words, z, out))
            return z, out

        return jax.lax.cond(jnp.any(fired), inhibit, lambda z, out: (z, out), z, out), None

    def slot(z, events):
        out = jnp.zeros((batch * n,), jnp.int8)
        (z, out), _ = jax.lax.scan(step, (z, out), events)
        return z, out.reshape(batch, n)[:, :size].reshape((batch,) + grid.shape)

    # (B, n_slots, capacity) -> (n_slots, capacity, B): one scan step per event position.
    events = jax.tree.map(lambda a: jnp.moveaxis(a, 0, -1), tuple(events))
    z, spikes = jax.lax.scan(slot, z, events)
    z = z.reshape(batch, n)[:, :size]
    state = HoughState(jnp.real(z).reshape(state.v.shape), jnp.imag(z).reshape(state.t.shape))
    return state, jnp.moveaxis(spikes, 0, 1)


def async_run(
    params: HoughParams, grid: Grid, events: Events, state: HoughState | None = None
) -> tuple[HoughState, jax.Array]:
    """`spikejax.vision.hough.neuron.async_run` by `_async_batch`; batches of streams fold into one."""
    check_grid(grid)
    if state is None:
        state = init(grid)
    return _async_streams(grid)(params, state, events)


def _folding_nested_vmaps(fn):
    """``fn`` (every leaf of every argument with a leading stream axis) with a ``vmap`` over it folded into that axis.

    Under ``vmap`` the batch and stream axes merge into one batch of streams,
    so nested ``vmap``s reach ``fn`` as a single flat batch.
    """
    streams = jax.custom_batching.custom_vmap(fn)

    @streams.def_vmap
    def _fold(axis_size, in_batched, *args):
        args = _broadcast_unbatched(axis_size, tuple(in_batched), args)
        out = streams(*jax.tree.map(lambda a: a.reshape((-1,) + a.shape[2:]), args))
        out = jax.tree.map(lambda a: a.reshape((axis_size, -1) + a.shape[1:]), out)
        return out, jax.tree.map(lambda _: True, out)

    return streams


def _broadcast_unbatched(axis_size, in_batched, args):
    return jax.tree.map(lambda a, b: a if b else jnp.broadcast_to(a, (axis_size,) + jnp.shape(a)), args, in_batched)


@functools.cache
def _async_streams(grid: Grid):
    """`async_run` for one stream; under ``vmap``, `_async_batch` over the streams.

    Nested ``vmap``s fold into one batch of streams.
    """

    streams = _folding_nested_vmaps(lambda params, state, events: _async_batch(params, grid, state, events))

    @jax.custom_batching.custom_vmap
    def one(params, state, events):
        out = streams(*jax.tree.map(lambda a: jnp.asarray(a)[None], (params, state, events)))
        return jax.tree.map(lambda a: a[0], out)

    @one.def_vmap
    def _batch(axis_size, in_batched, params, state, events):
        out = streams(*_broadcast_unbatched(axis_size, tuple(in_batched), (params, state, events)))
        return out, jax.tree.map(lambda _: True, out)

    return one
