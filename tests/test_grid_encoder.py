"""The DVS grid encoder of the snake R-STDP paper (Eq. 2): dense counts against the events, by hand, and rates."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from spikejax.coding import event_grid_counts, grid_counts, grid_rates
from spikejax.errors import UserError
from spikejax.vision.dvs import frame_difference

ROI = (17, 113, 3, 131)  # rows 17..112 (96 = 2 x 48), columns 3..130 (128, not a multiple of 5)
SHAPE = (128, 140)


def _frames(seed, shape=SHAPE):
    rng = np.random.default_rng(seed)
    prev = rng.uniform(0.0, 1.0, shape).astype(np.float32)
    # Most pixels change a little, some a lot, so that each threshold selects a different subset.
    step = rng.normal(0.0, 0.15, shape) * (rng.uniform(size=shape) < 0.6)
    frame = np.clip(prev + step, 0.0, 1.0).astype(np.float32)
    return jnp.asarray(prev), jnp.asarray(frame)


def _reference(prev, frame, threshold, roi, rows, cols, log=False, eps=1e-3):
    """Per pixel, in numpy with Python ints, from the dense float32 difference frame_difference takes."""
    prev, frame = np.asarray(prev, np.float32), np.asarray(frame, np.float32)
    d = np.log(frame + np.float32(eps)) - np.log(prev + np.float32(eps)) if log else frame - prev
    row0, row1, col0, col1 = roi
    counts = np.zeros(rows * cols, np.int64)
    for y, x in zip(*np.nonzero(np.abs(d) >= np.float32(threshold))):
        if row0 <= y < row1 and col0 <= x < col1:
            r = rows * (y - row0) // (row1 - row0)
            c = cols * (x - col0) // (col1 - col0)
            counts[r * cols + c] += 1
    return counts


@functools.partial(jax.jit, static_argnames=("roi", "rows", "cols", "log", "capacity"))
def _both(prev, frame, threshold, *, roi, rows, cols, log, capacity):
    dense = grid_counts(prev, frame, threshold=threshold, roi=roi, rows=rows, cols=cols, log=log)
    events, overflow = frame_difference(prev, frame, 0.0, threshold=threshold, capacity=capacity, log=log)
    return dense, event_grid_counts(events, roi=roi, rows=rows, cols=cols), events, overflow


@pytest.mark.parametrize("log", [False, True])
def test_dense_counts_equal_event_counts_without_overflow(log):
    n_pixels = SHAPE[0] * SHAPE[1]
    compiled = None
    for seed, threshold in enumerate([0.02, 0.1, 0.3] if not log else [0.05, 0.4, 1.5]):
        prev, frame = _frames(seed)
        # threshold is a traced argument of _both: one compilation serves all thresholds.
        dense, from_events, events, overflow = _both(
            prev, frame, jnp.float32(threshold), roi=ROI, rows=2, cols=5, log=log, capacity=n_pixels
        )
        assert int(overflow) == 0
        assert dense.dtype == jnp.int32 and dense.shape == (10,)
        np.testing.assert_array_equal(dense, from_events)
        np.testing.assert_array_equal(dense, _reference(prev, frame, threshold, ROI, 2, 5, log=log))
        assert 0 < int(dense.sum()) < int(events.count())  # the ROI drops some events, and keeps some
        compiled = compiled or _both._cache_size()
        assert _both._cache_size() == compiled


def test_vmap_over_traced_thresholds_matches_one_by_one():
    prev, frame = _frames(7)
    thresholds = jnp.array([0.01, 0.05, 0.2, 0.6], jnp.float32)
    f = jax.jit(jax.vmap(lambda t: grid_counts(prev, frame, threshold=t, roi=ROI, rows=3, cols=4)))
    batched = f(thresholds)
    for t, row in zip(thresholds.tolist(), batched):
        np.testing.assert_array_equal(row, _reference(prev, frame, t, ROI, 3, 4))
    assert np.all(np.diff(np.asarray(batched).sum(axis=1)) < 0)  # a higher threshold, fewer events


@pytest.mark.parametrize("capacity", [1, 200, 3000])
def test_overflow_loses_exactly_the_dropped_events(capacity):
    prev, frame = _frames(11)
    threshold = jnp.float32(0.05)
    dense, from_events, _, overflow = _both(
        prev, frame, threshold, roi=ROI, rows=2, cols=5, log=False, capacity=capacity
    )
    assert int(overflow) > 0
    assert np.all(np.asarray(from_events) <= np.asarray(dense))
    # The dropped events are the ones after the first `capacity` in row-major order.
    everything, _ = frame_difference(prev, frame, 0.0, threshold=threshold, capacity=SHAPE[0] * SHAPE[1])
    dropped = everything._replace(valid=everything.valid & (jnp.arange(everything.capacity) >= capacity))
    assert int(dropped.count()) == int(overflow)
    np.testing.assert_array_equal(np.asarray(dense) - np.asarray(from_events), event_grid_counts(dropped, roi=ROI))
    # Over the whole frame in one cell, the shortfall is the overflow.
    whole = (0, SHAPE[0], 0, SHAPE[1])
    full, partial, _, overflow = _both(prev, frame, threshold, roi=whole, rows=1, cols=1, log=False, capacity=capacity)
    assert int(full[0]) - int(partial[0]) == int(overflow)


# (y, x) of a single changed pixel in a 10 x 140 frame with roi (2, 8, 5, 133): 6 rows, 128 columns.
# Rows: floor(2 (y - 2) / 6) is 0 for y = 2, 3, 4 and 1 for y = 5, 6, 7. Columns: floor(5 (x - 5) / 128)
# steps up where 5 (x - 5) reaches 128, 256, 384, 512, i.e. at x - 5 = 26, 52, 77, 103 (widths 26, 26, 25, 26, 25).
EDGE_ROI = (2, 8, 5, 133)
EDGE_CASES = [
    ((2, 5), 0),  # the ROI's first row and column are inside
    ((4, 30), 0),
    ((4, 31), 1),
    ((5, 31), 6),
    ((3, 56), 1),
    ((3, 57), 2),
    ((3, 81), 2),
    ((3, 82), 3),
    ((7, 107), 8),
    ((7, 108), 9),
    ((7, 132), 9),  # last row and column inside
    ((8, 60), None),  # row1 is outside
    ((5, 133), None),  # col1 is outside
    ((1, 60), None),
    ((5, 4), None),
]


@pytest.mark.parametrize("pixel, cell", EDGE_CASES)
@pytest.mark.parametrize("brighter", [True, False])
def test_roi_edges_by_hand(pixel, cell, brighter):
    prev = jnp.full((10, 140), 0.5, jnp.float32)
    frame = prev.at[pixel].set(1.0 if brighter else 0.0)  # |d| = 0.5: on the threshold, which counts
    expected = np.zeros(10, np.int32)
    if cell is not None:
        expected[cell] = 1
    dense, from_events, _, overflow = _both(prev, frame, 0.5, roi=EDGE_ROI, rows=2, cols=5, log=False, capacity=4)
    assert int(overflow) == 0
    np.testing.assert_array_equal(dense, expected)
    np.testing.assert_array_equal(from_events, expected)


def test_cell_widths_of_128_columns_in_5():
    frame = jnp.ones((1, 128), jnp.float32)
    counts = grid_counts(jnp.zeros_like(frame), frame, threshold=0.5, roi=(0, 1, 0, 128), rows=1, cols=5)
    assert counts.tolist() == [26, 26, 25, 26, 25]


def test_below_threshold_and_unchanged_pixels_do_not_count():
    prev = jnp.full((4, 10), 0.5, jnp.float32)
    frame = prev.at[0, 0].set(0.74).at[3, 9].set(0.75)
    counts = grid_counts(prev, frame, threshold=0.25, roi=(0, 4, 0, 10))
    assert counts.tolist() == [0] * 9 + [1]


@pytest.mark.parametrize(
    "kwargs",
    [
        dict(roi=(0, 129, 0, 10)),
        dict(roi=(0, 10, 0, 141)),
        dict(roi=(5, 5, 0, 10)),
        dict(roi=(0, 10, 7, 3)),
        dict(roi=(-1, 10, 0, 10)),
        dict(roi=(0, 10, 0)),
        dict(roi=(0, 10.0, 0, 10)),
        dict(roi=(0, 10, 0, 10), rows=0),
        dict(roi=(0, 10, 0, 10), cols=2.5),
        dict(roi=(0, 10, 0, 10), cols=True),
    ],
)
def test_bad_grids_are_user_errors(kwargs):
    frame = jnp.zeros(SHAPE)
    with pytest.raises(UserError):
        grid_counts(frame, frame, threshold=0.1, **kwargs)
    # event_grid_counts knows no frame: only the ROIs that are bad whatever the frame fail there too.
    if "roi" in kwargs and max(kwargs["roi"][1::2] or (0,)) <= 128:
        events, _ = frame_difference(frame, frame, 0.0, threshold=0.1, capacity=4)
        with pytest.raises(UserError):
            event_grid_counts(events, **kwargs)


def test_mismatched_frames_are_user_errors():
    with pytest.raises(UserError):
        grid_counts(jnp.zeros((4, 5)), jnp.zeros((5, 4)), threshold=0.1, roi=(0, 4, 0, 4))
    with pytest.raises(UserError):
        grid_counts(jnp.zeros(5), jnp.zeros(5), threshold=0.1, roi=(0, 1, 0, 1))


def test_grid_rates_eq2_and_cap():
    counts = jnp.array([0, 1, 4, 10, 40], jnp.int32)
    np.testing.assert_allclose(grid_rates(counts, 0.02), [0.0, 50.0, 200.0, 500.0, 2000.0], rtol=1e-6)
    np.testing.assert_allclose(grid_rates(counts, 0.02, 300.0), [0.0, 50.0, 200.0, 300.0, 300.0], rtol=1e-6)
    capped = jax.jit(lambda c, m: grid_rates(c, 0.02, m))
    np.testing.assert_allclose(capped(counts, 100.0), [0.0, 50.0, 100.0, 100.0, 100.0], rtol=1e-6)
    np.testing.assert_allclose(capped(counts, 1e9), grid_rates(counts, 0.02), rtol=0)
    # The expected spike count over the window is the event count.
    np.testing.assert_allclose(grid_rates(counts, 0.02) * 0.02, counts, rtol=1e-6)
    with pytest.raises(UserError):
        grid_rates(counts, 0.0)


def test_grid_rates_follow_the_dtype():
    with jax.enable_x64(True):
        f = grid_rates(jnp.array([3], jnp.int32), jnp.float64(0.02))
        assert f.dtype == jnp.float64 and float(f[0]) == 3 / 0.02
    assert grid_rates(jnp.array([3]), 0.02).dtype == jnp.float32


@pytest.mark.parametrize("roi, rows, cols", [((16, 80, 4, 124), 2, 5), ((0, 128, 0, 140), 4, 7), (ROI, 3, 5)])
def test_equal_cells_and_unequal_cells_both_match_the_reference_under_vmap(roi, rows, cols):
    """ROIs that split into equal cells take a reshape-and-sum path, the others one-hot products: both are exact."""
    frames = [_frames(seed) for seed in range(3)]
    prev = jnp.stack([p for p, _ in frames])
    frame = jnp.stack([f for _, f in frames])
    counts = jax.jit(jax.vmap(lambda p, f: grid_counts(p, f, threshold=0.1, roi=roi, rows=rows, cols=cols)))(
        prev, frame
    )
    assert counts.dtype == jnp.int32
    for i, (p, f) in enumerate(frames):
        np.testing.assert_array_equal(counts[i], _reference(p, f, 0.1, roi, rows, cols))
