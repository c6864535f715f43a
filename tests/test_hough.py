"""Spiking Hough grids: accumulators against brute force and scikit-image, Alg. 1 by hand, the fast path
against the readable reference (`hough.neuron`) and the NumPy oracle (`hough.reference`)."""

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from skimage.draw import circle_perimeter
from skimage.transform import hough_circle, hough_circle_peaks, hough_line

from spikejax.errors import UserError
from spikejax.vision import dvs, hough, scenes
from spikejax.vision.events import Events
from spikejax.vision.hough import neuron, reference


def _events(x, y, t=None, p=None, valid=None):
    n = len(x)
    return Events(
        jnp.asarray(x, jnp.int32),
        jnp.asarray(y, jnp.int32),
        jnp.asarray(np.zeros(n) if t is None else t, jnp.float32),
        jnp.asarray(np.ones(n) if p is None else p, jnp.int32),
        jnp.asarray(np.ones(n, bool) if valid is None else valid),
    )


def _random_events(rng, n, width, height):
    return _events(
        rng.integers(0, width, n),
        rng.integers(0, height, n),
        np.sort(rng.random(n)),
        rng.choice([-1, 1], n),
        rng.random(n) < 0.9,
    )


def _c_round(v):
    """C's round (ties away from zero), without the error of floor(v + 0.5)."""
    a = abs(v)
    n = math.floor(a)
    n += 1 if a - n >= 0.5 else 0
    return n if v >= 0 else -n


def _line_cell(grid, x, y, k):
    phi = math.pi / 2 - k * (math.pi / grid.n_theta)  # the trigonometry of line_table
    rho = (x - grid.origin[0]) * math.cos(phi) + (y - grid.origin[1]) * math.sin(phi)
    j = _c_round(rho / grid.rho_step) + grid.rho_offset
    return j if 0 <= j < grid.n_rho else None


def test_line_votes_equal_brute_force():
    rng = np.random.default_rng(0)
    for grid in (
        hough.LineGrid(width=12, height=10, n_theta=30, n_rho=25),
        hough.LineGrid(width=9, height=14, n_theta=17, n_rho=9, rho_step=2.0, origin=(1.0, 3.5)),
    ):
        ev = _random_events(rng, 60, grid.width, grid.height)
        expected = np.zeros(grid.shape)
        for x, y, p, ok in zip(*(np.asarray(a) for a in (ev.x, ev.y, ev.p, ev.valid))):
            for k in range(grid.n_theta):
                j = _line_cell(grid, x, y, k)
                if ok and j is not None:
                    expected[k, j] += p
        np.testing.assert_array_equal(np.asarray(hough.line_votes(grid, ev)), expected)


def test_merged_pixel_votes_equal_the_event_votes():
    # 1,200 events on 40 pixels (a few off the sensor, a tenth invalid): pixels
    # repeat ~30 times and many cancel, and the merged votes fill one of the
    # three chunks, so the other two are skipped.
    grid = hough.LineGrid(width=12, height=10, n_theta=30, n_rho=25, merge_pixels=True)
    plain = dataclasses.replace(grid, merge_pixels=False)
    rng = np.random.default_rng(7)
    n = 1200
    pix = rng.integers(0, 40, n)
    x, y = pix % 8 + 3, pix // 8 * 2
    x[:5] = -1  # off the sensor: no votes
    ev = _events(x, y, np.sort(rng.random(n)), rng.choice([-1, 1], n), rng.random(n) < 0.9)
    for signed in (True, False):
        expected = np.zeros(grid.shape)
        for xi, yi, p, ok in zip(*(np.asarray(a) for a in (ev.x, ev.y, ev.p, ev.valid))):
            for k in range(grid.n_theta):
                j = _line_cell(grid, xi, yi, k) if 0 <= xi < grid.width else None
                if ok and j is not None:
                    expected[k, j] += p if signed else 1
        merged = np.asarray(hough.line_votes(grid, ev, signed=signed))
        np.testing.assert_array_equal(merged, expected)
        np.testing.assert_array_equal(merged, np.asarray(hough.line_votes(plain, ev, signed=signed)))
    assert np.abs(expected).sum() > 0
    # The whole synchronous detector, two streams of four slots: the same spikes and states.
    params = hough.hough_params(v_th=6.0, decay=3.0)
    slots = jax.tree.map(lambda a: a.reshape(2, 4, 150), ev)
    times = jnp.arange(1.0, 5.0) / 4
    run = lambda g: jax.jit(jax.vmap(lambda e: hough.sync_run(params, g, e, times)))(slots)  # noqa: E731
    ours = run(grid)
    assert np.abs(np.asarray(ours[1])).sum() > 10
    _assert_trees_equal(ours, run(plain))


def test_line_votes_equal_skimage_hough_line():
    # Eq. (2) is rho = x sin(theta) + y cos(theta); scikit-image's is
    # rho = x cos(phi) + y sin(phi) from the top-left pixel, so phi = pi/2 - theta,
    # origin (0, 0) and distances -D .. D with D = ceil(hypot(height, width)).
    rng = np.random.default_rng(1)
    image = rng.random((40, 52)) < 0.08
    image[5:35, 20] = True
    d = int(np.ceil(np.hypot(*image.shape)))
    grid = hough.LineGrid(width=52, height=40, n_rho=2 * d + 1, origin=(0, 0), rho_offset=d)
    ys, xs = np.nonzero(image)
    ours = np.asarray(hough.line_votes(grid, _events(xs, ys), signed=False))
    accumulator, angles, distances = hough_line(image, grid.skimage_thetas())
    np.testing.assert_array_equal(ours, accumulator.T)
    np.testing.assert_allclose(grid.rhos(), distances)


def test_line_cell_conversions():
    grid = hough.LineGrid()
    assert grid.cell(np.pi / 2, 10.0) == (90, 100)
    assert grid.cell(np.pi + 0.5 * np.pi / 180, 3.0) == (0, 87)  # (theta + pi, -rho)
    theta, rho = grid.line(90, 100)
    assert theta == pytest.approx(np.pi / 2) and rho == 10.0


def test_standing_pipe_edges_are_the_extreme_cells():
    # One pixel of motion per frame: the events are the two edges, the right
    # (leading) one ON, the left one OFF.
    scene = scenes.standing_pipe(n_frames=3, speed=1.0, tilt=0.3, start=60.0)
    events, overflow = dvs.difference_events(scene.frames, scene.times, threshold=0.3, capacity=2048)
    assert int(overflow.sum()) == 0
    grid = hough.LineGrid()
    acc = np.asarray(hough.line_votes(grid, jax.tree.map(lambda a: a[1], events)))
    truth = scene.truth
    right = grid.cell(truth.theta[2], truth.rho_right[2] - 0.5)  # the band between frames 1 and 2
    left = grid.cell(truth.theta[2], truth.rho_left[2] - 0.5)
    top = np.unravel_index(np.argmax(acc), acc.shape)
    bottom = np.unravel_index(np.argmin(acc), acc.shape)
    assert truth.polarity_right[2] == 1 and truth.polarity_left[2] == -1
    assert abs(top[0] - right[0]) <= 1 and abs(top[1] - right[1]) <= 1
    assert abs(bottom[0] - left[0]) <= 1 and abs(bottom[1] - left[1]) <= 1


def test_circle_votes_fft_and_scatter_equal_brute_force():
    rng = np.random.default_rng(2)
    grid = hough.CircleGrid(width=16, height=12, n_r=5, r_min=2.0)
    ev = _random_events(rng, 25, grid.width, grid.height)
    expected = np.zeros(grid.shape)
    for x, y, p, ok in zip(*(np.asarray(a) for a in (ev.x, ev.y, ev.p, ev.valid))):
        for k in range(grid.n_r):
            for b in range(grid.height):
                for a in range(grid.width):
                    if ok and _c_round(math.hypot(x - a, y - b) - grid.r_min) == k:
                        expected[k, b, a] += p
    for method in ("fft", "scatter"):
        np.testing.assert_array_equal(np.asarray(hough.circle_votes(grid, ev, method=method)), expected)


def test_circle_image_votes_under_vmap_equal_each_streams_scatter():
    # Batched images are convolved one at a time (`_fast._circle_image_streams`); odd size groups pair a
    # radius with nothing (`_fast._ring_spectra`).
    rng = np.random.default_rng(12)
    grid = _small_grid("circle")
    assert any(radii % 2 for _, _, radii, _ in hough._fast._ring_spectra(grid))
    streams = [_random_events(rng, 60, grid.width, grid.height) for _ in range(3)]
    images = jnp.stack([hough.event_image(grid, ev) for ev in streams])
    together = np.asarray(jax.jit(jax.vmap(lambda im: hough.circle_image_votes(grid, im)))(images))
    for ev, votes in zip(streams, together):
        np.testing.assert_array_equal(votes, np.asarray(hough.circle_votes(grid, ev, method="scatter")))
    assert np.abs(together).max() > 0


@pytest.mark.parametrize("centre, radius", [((40, 30), 17), ((25, 38), 9)])
def test_circle_detection_matches_skimage(centre, radius):
    rng = np.random.default_rng(3)
    image = rng.random((64, 64)) < 0.01
    rr, cc = circle_perimeter(centre[1], centre[0], radius, shape=image.shape)
    image[rr, cc] = True
    radii = np.arange(4, 24)
    _, cx, cy, rad = hough_circle_peaks(hough_circle(image, radii), radii, total_num_peaks=1)
    grid = hough.CircleGrid(width=64, height=64, n_r=20, r_min=4.0)
    ys, xs = np.nonzero(image)
    acc = np.asarray(hough.circle_votes(grid, _events(xs, ys), signed=False))
    k, b, a = np.unravel_index(np.argmax(acc), acc.shape)
    assert (a, b) == (cx[0], cy[0]) == centre
    assert grid.radii()[k] == rad[0] == radius


def test_alg1_by_hand():
    # One angle (theta = 0): cell j is row y; neighbours are rows y +- 1.
    grid = hough.LineGrid(width=1, height=5, n_theta=1, n_rho=5, origin=(0, 0), rho_offset=0)
    params = hough.hough_params(v_th=2.5, decay=2.0)
    rows = [
        # (t, y, p)
        [(0.0, 2, 1), (0.25, 2, 1), (0.5, 3, -1), (0.5, 2, 1)],
        [(0.5, 2, 1), (0.75, 4, -1), (0.75, 4, -1), (0.75, 4, -1), (1.0, 0, -1), (2.0, 0, 1)],
    ]
    cap = 6
    ev = Events(*(jnp.asarray(np.zeros((2, cap)), d) for d in (jnp.int32, jnp.int32, jnp.float32, jnp.int32, bool)))
    ev = Events(
        x=ev.x,
        y=jnp.asarray([[e[1] for e in r] + [0] * (cap - len(r)) for r in rows], jnp.int32),
        t=jnp.asarray([[e[0] for e in r] + [0.0] * (cap - len(r)) for r in rows], jnp.float32),
        p=jnp.asarray([[e[2] for e in r] + [0] * (cap - len(r)) for r in rows], jnp.int32),
        valid=jnp.asarray([[True] * len(r) + [False] * (cap - len(r)) for r in rows]),
    )
    # Row 2: 1; decays 0.5 by t = 0.25 -> 1.5; decays 0.5 by t = 0.5 -> 2.0 (no
    # spike: without the decay it would be 3). Slot 2: 3.0 >= 2.5, spike +1,
    # rows 1-3 reset (row 3 held -1). Row 4: -3 at t = 0.75, spike -1, rows 3-4
    # reset. Row 0: -1 at t = 1, decays to 0 by t = 2, then +1.
    for run in (hough.async_run, neuron.async_run, reference.async_run_numpy):
        state, spikes = run(params, grid, ev)
        np.testing.assert_array_equal(np.asarray(spikes)[:, 0, :], [[0, 0, 0, 0, 0], [0, 0, 1, 0, -1]])
        np.testing.assert_allclose(np.asarray(state.v)[0], [1.0, 0, 0, 0, 0])
        assert float(state.t[0, 0]) == 2.0


def test_sync_sums_a_slot_before_firing():
    grid = hough.LineGrid(width=1, height=3, n_theta=1, n_rho=3, origin=(0, 0), rho_offset=0)
    params = hough.hough_params(v_th=2.5, decay=0.0)
    ev = _events([0, 0, 0, 0], [1, 1, 1, 1], [0.1, 0.2, 0.3, 0.4], [1, 1, 1, -1])
    batch = jax.tree.map(lambda a: a[None], ev)
    _, sync = hough.sync_run(params, grid, batch, jnp.asarray([0.4]))
    _, asyn = hough.async_run(params, grid, batch)
    assert np.asarray(sync)[0, 0].tolist() == [0, 0, 0]  # 1 + 1 + 1 - 1 = 2 < 2.5
    assert np.asarray(asyn)[0, 0].tolist() == [0, 1, 0]  # the third event reaches 3


def _one_per_slot(ev):
    return jax.tree.map(lambda a: a[:, None], ev)


@pytest.mark.parametrize(
    "grid",
    [hough.LineGrid(width=10, height=8, n_theta=24, n_rho=16), hough.CircleGrid(width=10, height=8, n_r=4, r_min=2.0)],
)
def test_sync_and_async_agree_when_events_are_sparse_in_time(grid):
    # Events concentrated on few pixels, so that many cells fire.
    rng = np.random.default_rng(4)
    n = 120
    pix = rng.integers(0, 6, n)
    ev = _events(pix % 3 + 3, pix // 3 + 2, np.cumsum(rng.random(n) * 0.05), rng.choice([-1, 1, 1, 1], n))
    params = hough.hough_params(v_th=3.5, decay=4.0)
    slots = _one_per_slot(ev)
    s_sync, sp_sync = jax.jit(lambda e, t: hough.sync_run(params, grid, e, t))(slots, ev.t)
    s_async, sp_async = jax.jit(lambda e: hough.async_run(params, grid, e, hough.init(grid, ev.t[0])))(slots)
    assert np.abs(np.asarray(sp_sync)).sum() > 5
    np.testing.assert_array_equal(np.asarray(sp_sync), np.asarray(sp_async))
    # Untouched neurons have decayed in sync mode only on paper: compare at the end.
    end = float(ev.t[-1])
    decayed = lambda s: neuron.decay(s.v, params.decay * (end - s.t))
    np.testing.assert_allclose(np.asarray(decayed(s_sync)), np.asarray(decayed(s_async)), atol=1e-5)


def test_modes_vmap_over_streams_like_single_streams():
    grid = hough.LineGrid(width=10, height=8, n_theta=12, n_rho=16)
    params = hough.hough_params(v_th=2.5, decay=1.0)
    rng = np.random.default_rng(5)
    streams = [_random_events(rng, 40, grid.width, grid.height) for _ in range(3)]
    batch = jax.tree.map(lambda *a: jnp.stack(a).reshape(3, 4, 10), *streams)
    times = jnp.arange(1.0, 5.0) / 4
    together = jax.vmap(lambda e: hough.async_run(params, grid, e)[1])(batch)
    together_sync = jax.vmap(lambda e: hough.sync_run(params, grid, e, times)[1])(batch)
    assert np.abs(np.asarray(together)).sum() > 0 and np.abs(np.asarray(together_sync)).sum() > 0
    for i in range(3):
        one = jax.tree.map(lambda a: a[i], batch)
        np.testing.assert_array_equal(np.asarray(together[i]), np.asarray(hough.async_run(params, grid, one)[1]))
        np.testing.assert_array_equal(
            np.asarray(together_sync[i]), np.asarray(hough.sync_run(params, grid, one, times)[1])
        )


def test_async_nested_vmap_and_batched_params_like_single_streams():
    # Nested vmaps fold into one batch of streams; v_th differs per stream.
    grid = hough.LineGrid(width=10, height=8, n_theta=12, n_rho=16)
    rng = np.random.default_rng(6)
    streams = [_random_events(rng, 40, 10, 8) for _ in range(6)]
    batch = jax.tree.map(lambda *a: jnp.stack(a).reshape(2, 3, 4, 10), *streams)
    v_th = jnp.asarray([[2.5, 3.5, 1.5], [2.5, 2.0, 3.0]], jnp.float32)
    run = lambda e, v: hough.async_run(hough.hough_params(v, 1.0), grid, e)
    together = jax.jit(jax.vmap(jax.vmap(run)))(batch, v_th)
    assert np.abs(np.asarray(together[1])).sum() > 0
    for i in range(2):
        for j in range(3):
            one = run(jax.tree.map(lambda a: a[i, j], batch), v_th[i, j])
            for a, b in zip(jax.tree.leaves(together), jax.tree.leaves(one)):
                np.testing.assert_array_equal(np.asarray(a)[i, j], np.asarray(b))


def test_bad_grids_are_refused():
    with pytest.raises(UserError, match="n_theta"):
        hough.LineGrid(n_theta=0)
    with pytest.raises(UserError, match="merge_pixels"):
        hough.LineGrid(merge_pixels="yes")
    with pytest.raises(UserError, match="r_min"):
        hough.CircleGrid(r_min=0.0)
    with pytest.raises(UserError, match="method"):
        hough.circle_votes(hough.CircleGrid(width=8, height=8, n_r=2), _events([1], [1]), method="dense")


def test_lying_pipe_circle_is_the_peak():
    scene = scenes.lying_pipe(n_frames=2, height=64, width=64, centre=(30.0, 32.0), radius=12.0, speed=1.0, growth=1.0)
    events, overflow = dvs.difference_events(scene.frames, scene.times, threshold=0.2, capacity=1024)
    assert int(overflow[0]) == 0 and int(events.count()[0]) > 50
    grid = hough.CircleGrid(width=64, height=64, n_r=24, r_min=4.0)
    acc = np.asarray(hough.circle_votes(grid, jax.tree.map(lambda a: a[0], events), signed=False))
    k, b, a = np.unravel_index(np.argmax(acc), acc.shape)
    truth = scene.truth
    assert abs(a - truth.a[1]) <= 1 and abs(b - truth.b[1]) <= 1 and abs(grid.radii()[k] - truth.r[1]) <= 1


# --- the fast path against the readable reference and the NumPy oracle ---------

SMALL = 32  # a 32 x 32 sensor keeps the per-event reference loops short


def _scene_events(kind, variant=0):
    """Event frames ``(5, 256)`` and the frame times of a small synthetic scene."""
    if kind == "line":
        scene = scenes.standing_pipe(
            n_frames=6,
            height=SMALL,
            width=SMALL,
            pipe_width=8.0,
            start=10.0 + 2 * variant,
            speed=2.0,
            tilt=0.2 - 0.1 * variant,
        )
    else:
        scene = scenes.lying_pipe(
            n_frames=6, height=SMALL, width=SMALL, centre=(14.0 + variant, 16.0), radius=6.0, speed=1.0, growth=1.0
        )
    events, overflow = dvs.difference_events(scene.frames, scene.times, threshold=0.1, capacity=256)
    assert int(overflow.sum()) == 0 and int(events.count().min()) > 50
    return events, scene.times[1:]


def _small_grid(kind):
    if kind == "line":
        return hough.LineGrid(width=SMALL, height=SMALL, n_theta=45, n_rho=48)
    return hough.CircleGrid(width=SMALL, height=SMALL, n_r=10, r_min=2.0)


def _assert_trees_equal(a, b):
    assert jax.tree.structure(a) == jax.tree.structure(b)
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b)):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


def _runs(mode, grid, times):
    """``(fast, readable)``: ``run(params, events)`` of `hough` and of `hough.neuron`."""
    if mode == "sync":
        return (lambda p, e: hough.sync_run(p, grid, e, times)), (lambda p, e: neuron.sync_run(p, grid, e, times))
    return (lambda p, e: hough.async_run(p, grid, e)), (lambda p, e: neuron.async_run(p, grid, e))


@pytest.mark.parametrize("mode", ["sync", "async"])
@pytest.mark.parametrize("kind", ["line", "circle"])
def test_fast_path_equals_the_readable_reference(kind, mode):
    grid = _small_grid(kind)
    events, times = _scene_events(kind)
    fast, readable = _runs(mode, grid, times)
    for v_th in (3.0, 5.0):
        params = hough.hough_params(v_th=v_th, decay=37.0)
        ours = jax.jit(fast)(params, events)
        assert np.abs(np.asarray(ours[1])).sum() > 100
        _assert_trees_equal(ours, jax.jit(readable)(params, events))


@pytest.mark.parametrize("mode", ["sync", "async"])
@pytest.mark.parametrize("kind", ["line", "circle"])
def test_fast_path_equals_the_readable_reference_vmapped(kind, mode):
    # Three streams (three scenes), each with its own threshold; also nested (2 x 3).
    grid = _small_grid(kind)
    streams = [_scene_events(kind, variant) for variant in range(3)]
    events = jax.tree.map(lambda *a: jnp.stack(a), *(e for e, _ in streams))
    fast, readable = _runs(mode, grid, streams[0][1])
    run = lambda f: jax.jit(jax.vmap(lambda e, v: f(hough.hough_params(v_th=v, decay=37.0), e)))
    v_th = jnp.asarray([3.0, 4.0, 5.0])
    ours = run(fast)(events, v_th)
    assert np.abs(np.asarray(ours[1])).reshape(3, -1).sum(axis=1).min() > 100
    _assert_trees_equal(ours, run(readable)(events, v_th))
    nested = lambda f: jax.jit(jax.vmap(jax.vmap(lambda e, v: f(hough.hough_params(v_th=v, decay=37.0), e))))
    pairs = jax.tree.map(lambda a: jnp.stack([a, a[::-1]]), events)
    _assert_trees_equal(nested(fast)(pairs, jnp.stack([v_th, v_th])), nested(readable)(pairs, jnp.stack([v_th, v_th])))


@pytest.mark.parametrize("kind", ["line", "circle"])
def test_async_equals_the_numpy_oracle(kind):
    grid = _small_grid(kind)
    events, _ = _scene_events(kind)
    params = hough.hough_params(v_th=3.0, decay=37.0)
    state, spikes = hough.async_run(params, grid, events)
    oracle_state, oracle_spikes = reference.async_run_numpy(params, grid, events)
    assert np.abs(oracle_spikes).sum() > 100
    np.testing.assert_array_equal(np.asarray(spikes), oracle_spikes)
    np.testing.assert_array_equal(np.asarray(state.t), oracle_state.t)  # frame times: exact in float32
    # The oracle runs in float64: the potentials agree to float32 rounding.
    np.testing.assert_allclose(np.asarray(state.v), oracle_state.v, rtol=0, atol=1e-5)


def test_reference_votes_equal_the_fast_votes():
    for kind in ("line", "circle"):
        grid = _small_grid(kind)
        events, _ = _scene_events(kind)
        one = jax.tree.map(lambda a: a[2], events)
        for signed in (True, False):
            np.testing.assert_array_equal(
                np.asarray(hough.votes(grid, one, signed=signed)), np.asarray(neuron.votes(grid, one, signed=signed))
            )


# --- many streams: the dense line votes (`_fast._line_dense_sums`) --------------


def _many_streams(rng, capacity=1024, n_slots=None):
    """150 streams on the small line grid, in three groups of 50 padded to 64 (`_fast._groups`): the first two voted
    densely (events up to the end of the buffer), the third by the event scatter (events only in its first
    300 places); stream 7 has 200 events at one pixel, so its group sums its image in int16, not int8."""
    shape = (150,) if n_slots is None else (150, n_slots)
    x = rng.integers(-2, SMALL + 2, shape + (capacity,))  # a few off the sensor: no votes
    y = rng.integers(0, SMALL, shape + (capacity,))
    p = rng.choice([-1, 1], shape + (capacity,))
    valid = rng.random(shape + (capacity,)) < 0.8
    valid[100:, ..., 300:] = False
    x[7, ..., :200], y[7, ..., :200], p[7, ..., :200], valid[7, ..., :200] = 3, 4, 1, True
    t = np.sort(rng.random(shape + (capacity,)), axis=-1)
    return _events(x, y, t, p, valid)


def test_many_streams_vote_as_each_alone():
    grid = _small_grid("line")
    events = _many_streams(np.random.default_rng(21))
    assert events.x.shape[0] >= 3 * 50 and hough._fast.DENSE_MIN_STREAMS <= 50
    for signed in (True, False):
        together = np.asarray(jax.jit(jax.vmap(lambda e: hough.line_votes(grid, e, signed=signed)))(events))
        for i in (0, 7, 49, 50, 99, 100, 149):
            one = jax.tree.map(lambda a: a[i], events)
            np.testing.assert_array_equal(together[i], np.asarray(neuron.votes(grid, one, signed=signed)))
        assert np.abs(together[7]).max() >= 200 and np.abs(together[100:]).sum() > 0


def test_many_streams_count_in_int32_past_int16():
    grid = _small_grid("line")
    capacity = 2**15  # a slot's counts could then pass 2^15 - 1
    rng = np.random.default_rng(22)
    x, y = rng.integers(0, SMALL, (32, capacity)), rng.integers(0, SMALL, (32, capacity))
    x[0], y[0] = 5, 6  # every event of stream 0 at one pixel: 32,768 votes in each of its cells
    events = _events(x, y, p=np.ones((32, capacity)), valid=np.ones((32, capacity), bool))
    together = np.asarray(jax.jit(jax.vmap(lambda e: hough.line_votes(grid, e)))(events))
    assert together[0].max() == capacity
    for i in (0, 31):
        one = jax.tree.map(lambda a: a[i], events)
        np.testing.assert_array_equal(together[i], np.asarray(neuron.votes(grid, one)))


def test_many_streams_run_sync_as_the_readable_reference():
    # Per-stream thresholds, decay rates and slot times, a starting state with a time per cell; also nested.
    grid = _small_grid("line")
    rng = np.random.default_rng(23)
    events = _many_streams(rng, capacity=640, n_slots=3)
    times = jnp.asarray(1.0 + np.cumsum(rng.random((150, 3)), axis=1), jnp.float32)
    v_th = jnp.asarray(rng.uniform(3.0, 9.0, 150), jnp.float32)
    rate = jnp.asarray(rng.uniform(0.0, 4.0, 150), jnp.float32)
    state = hough.HoughState(
        jnp.asarray(rng.normal(0, 3, (150,) + grid.shape), jnp.float32),
        jnp.asarray(rng.uniform(0, 1, (150,) + grid.shape), jnp.float32),
    )

    def runs(f):
        return jax.jit(jax.vmap(lambda e, t, v, d, s: f(hough.hough_params(v, d), grid, e, t, s)))

    ours = runs(hough.sync_run)(events, times, v_th, rate, state)
    assert np.abs(np.asarray(ours[1])).reshape(150, -1).sum(axis=1).min() > 0
    _assert_trees_equal(ours, runs(neuron.sync_run)(events, times, v_th, rate, state))
    first = jax.tree.map(lambda a: a[:32], (events, times, v_th, rate, state))  # one group of 32, not padded to 64
    assert hough._fast._groups(32) == (1, 32)
    _assert_trees_equal(runs(hough.sync_run)(*first), runs(neuron.sync_run)(*first))
    pairs = jax.tree.map(lambda a: a[:80].reshape((2, 40) + a.shape[1:]), (events, times, v_th, rate, state))

    def nested(f):
        return jax.jit(jax.vmap(jax.vmap(lambda e, t, v, d, s: f(hough.hough_params(v, d), grid, e, t, s))))

    _assert_trees_equal(nested(hough.sync_run)(*pairs), nested(neuron.sync_run)(*pairs))


def test_neighbourhood_by_words_is_the_box_dilation():
    rng = np.random.default_rng(24)
    for shape in [(3, 64), (4, 5, 96), (2, 32)]:
        fired = rng.random(shape) < 0.05
        fired[..., 31] = fired[..., 32 % shape[-1]] = True  # across a word boundary
        fired[..., -1] = True  # at the last cell: nothing wraps around
        np.testing.assert_array_equal(
            np.asarray(hough._fast._neighbourhood_by_words(jnp.asarray(fired))),
            np.asarray(neuron.neighbourhood(jnp.asarray(fired))),
        )


def test_circle_streams_under_vmap_step_and_run_as_the_readable_reference():
    # Circle grids run their streams one after another under vmap (`_fast._circle_streams`): from a given
    # state, by steps and by runs, per-stream thresholds.
    grid = _small_grid("circle")
    streams = [_scene_events("circle", variant) for variant in range(3)]
    events = jax.tree.map(lambda *a: jnp.stack(a), *(e for e, _ in streams))
    times = streams[0][1]
    rng = np.random.default_rng(25)
    state = hough.HoughState(
        jnp.asarray(rng.normal(0, 2, (3,) + grid.shape), jnp.float32),
        jnp.asarray(rng.uniform(0, times[0], (3,) + grid.shape), jnp.float32),
    )
    v_th = jnp.asarray([3.0, 4.0, 5.0])
    run = lambda f: jax.jit(jax.vmap(lambda e, v, s: f(hough.hough_params(v, 37.0), grid, e, times, s)))
    ours = run(hough.sync_run)(events, v_th, state)
    assert np.abs(np.asarray(ours[1])).reshape(3, -1).sum(axis=1).min() > 100
    _assert_trees_equal(ours, run(neuron.sync_run)(events, v_th, state))
    first = jax.tree.map(lambda a: a[:, 0], events)
    step = lambda f: jax.jit(jax.vmap(lambda e, v, s: f(hough.hough_params(v, 37.0), grid, s, e, times[0])))
    _assert_trees_equal(step(hough.sync_step)(first, v_th, state), step(neuron.sync_step)(first, v_th, state))
