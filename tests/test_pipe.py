"""Pipe detection (Alg. 2) and relative position (Alg. 3, Eqs. 4-9) of the snake pipe-tracking paper."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from spikejax.vision import pipe as pp

THETA = jnp.deg2rad(jnp.arange(180.0))  # the paper's line grid: 1 degree
RHO = jnp.arange(-90.0, 180.0)  # signed rho, 1 pixel
find_body = jax.jit(pp.find_body, static_argnames=("origin", "k"))
find_entry = jax.jit(pp.find_entry, static_argnames=("k",))


def _spikes(*lines, n_updates=10):
    """Output spikes ``(n_updates, 180, n_rho)``: (polarity, theta_deg, rho, updates) fires in
    the given updates (a list) or in the first ``updates`` ones (an int)."""
    spikes = np.zeros((n_updates, 180, RHO.shape[0]), np.int8)
    for polarity, theta, rho, updates in lines:
        updates = range(updates) if isinstance(updates, int) else updates
        spikes[list(updates), theta, int(rho) + 90] = polarity
    return jnp.asarray(spikes)


def test_body_is_the_most_frequent_parallel_opposite_pair():
    spikes = _spikes(
        (+1, 90, 40, 5),  # left edge x = 40
        (-1, 91, 60, 4),  # right edge, 1 degree off: parallel within 5 degrees
        (-1, 30, 50, 9),  # strongest negative, not parallel: rejected
        (+1, 90, 41, 8),  # a stronger left edge a pixel over (its spikes outnumber x = 40's)
        (-1, 90, 42, 2),  # parallel to both positives but too close to x = 41, and rarer
        (+1, 10, 5, 1),  # pair only with nothing
    )
    found = find_body(pp.BodyParams(), spikes, THETA, RHO, t=0.25)
    assert bool(found.valid) and int(found.kind) == pp.BODY
    # x = 41 (8 spikes) and rho = 60 (4) fire together in 4 updates, as do x = 40 and rho = 60,
    # but the first pair has more spikes in all.
    assert float(found.score) == 4.0
    np.testing.assert_allclose(float(found.width), 19.0)
    # Columns at the middle row (y = 64): 41 and (60 - 64 cos 91 deg) / sin 91 deg.
    x_right = (60 - 64 * math.cos(math.radians(91))) / math.sin(math.radians(91))
    np.testing.assert_allclose(float(found.pos), 0.5 * (41 + x_right), atol=1e-4)
    np.testing.assert_allclose(float(found.theta), math.radians(90.5), atol=1e-6)
    np.testing.assert_allclose(float(found.t), 0.25)


def test_body_pairs_across_the_theta_wrap():
    # theta = 0: the row y = rho; theta = 179 deg is nearly the same direction with rho ~ -y.
    found = find_body(pp.BodyParams(), _spikes((+1, 0, 30, 3), (-1, 179, -50, 3)), THETA, RHO, t=0.0)
    assert bool(found.valid)
    np.testing.assert_allclose(float(found.width), 20.0, atol=1e-4)
    assert float(found.theta) < math.radians(1.0) or float(found.theta) > math.radians(179.0)


@pytest.mark.parametrize(
    "lines, params",
    [
        ([(+1, 90, 40, 5), (-1, 100, 60, 5)], pp.BodyParams()),  # 10 degrees apart
        ([(+1, 90, 40, 5), (-1, 90, 41, 5)], pp.BodyParams()),  # one edge's two polarities
        ([(+1, 90, 40, 5), (-1, 90, 60, 5)], pp.BodyParams(max_width=10.0)),
        ([(+1, 90, 40, 2), (-1, 90, 60, 5)], pp.BodyParams(min_count=3.0)),
        ([(+1, 90, 40, 5), (+1, 90, 60, 5)], pp.BodyParams()),  # same polarity
    ],
)
def test_body_conditions_reject(lines, params):
    assert not bool(find_body(params, _spikes(*lines), THETA, RHO, t=0.0).valid)


def test_body_edges_must_fire_together():
    # A sweeping camera: the right edge is at x = 70 in updates 2-3, at x = 60 in update 0.
    spikes = _spikes((+1, 90, 40, [0, 1]), (-1, 90, 70, [2, 3]), (-1, 90, 60, [0]))
    found = find_body(pp.BodyParams(), spikes, THETA, RHO, t=0.0)
    assert bool(found.valid) and float(found.score) == 1.0
    np.testing.assert_allclose(float(found.width), 20.0)


def test_strength_breaks_ties_without_outranking_spikes():
    spikes = _spikes((+1, 88, 40, 2), (-1, 88, 60, 2), (+1, 90, 40, 2), (-1, 90, 64, 2), n_updates=2)
    strength = np.zeros((2, 180, RHO.shape[0]), np.float32)
    strength[:, 90] = 100.0  # the 90-degree lines carry the votes
    found = find_body(pp.BodyParams(), spikes, THETA, RHO, 0.0, strength=tuple(jnp.asarray(strength)))
    np.testing.assert_allclose(float(found.width), 24.0)
    more = _spikes((+1, 88, 40, 2), (-1, 88, 60, 2), (+1, 90, 40, 1), (-1, 90, 64, 1), n_updates=2)
    found = find_body(pp.BodyParams(), more, THETA, RHO, 0.0, strength=tuple(jnp.asarray(strength)))
    np.testing.assert_allclose(float(found.width), 20.0)


def test_spike_counts_and_entry():
    spikes = jnp.zeros((3, 4, 5, 6), jnp.int32)  # (updates, r, b, a)
    spikes = spikes.at[0, 1, 2, 3].set(1).at[1, 1, 2, 3].set(-1).at[2, 1, 2, 3].set(1).at[0, 0, 0, 0].set(1)
    positive, negative = pp.spike_counts(spikes, n_grid_axes=3)
    assert float(positive[1, 2, 3]) == 2 and float(negative[1, 2, 3]) == 1
    entry = pp.find_entry(positive + negative, jnp.arange(4) + 10.0, t=1.0)
    assert bool(entry.valid) and int(entry.kind) == pp.ENTRY
    assert float(entry.pos) == 3.0 and float(entry.row) == 2.0
    assert float(entry.width) == 22.0 and float(entry.score) == 3.0
    assert not bool(pp.find_entry(jnp.zeros((4, 5, 6)), jnp.arange(4.0), t=0.0).valid)


def test_find_body_vmaps_like_a_loop():
    spikes = jnp.stack([_spikes((+1, 90, 20 + i, 3), (-1, 90, 40 + 2 * i, 3), n_updates=3) for i in range(4)])
    batched = jax.jit(jax.vmap(pp.find_body, in_axes=(None, 0, None, None, None)))(
        pp.BodyParams(), spikes, THETA, RHO, 0.0
    )
    for i in range(4):
        one = find_body(pp.BodyParams(), spikes[i], THETA, RHO, 0.0)
        np.testing.assert_allclose(batched.width[i], one.width)
        np.testing.assert_allclose(batched.pos[i], one.pos)
    np.testing.assert_allclose(batched.width, [20, 21, 22, 23])


# --- Alg. 3 ------------------------------------------------------------------

FOCAL = 0.5 * 128 / math.tan(math.radians(30.0))  # 60 degree field of view


@pytest.mark.parametrize("values", ["distinct", "ties", "zeros"])
@pytest.mark.parametrize("n", [pp.TOP_K_BLOCK * 64, 32 * 128 * 128, 32 * 128 * 128 + 77])
def test_top_k_by_blocks_is_lax_top_k_ties_included(values, n):
    rng = np.random.default_rng(n)
    x = {
        "distinct": rng.random(n),
        "ties": rng.integers(0, 2, n) + rng.integers(0, 3, n) / 8,  # circle counts with tie fractions
        "zeros": np.zeros(n),
    }[values].astype(np.float32)
    x[[5, n - 1]] = x.max()  # the largest value at both ends, across blocks
    got, want = jax.jit(pp.top_k, static_argnums=1)(jnp.asarray(x), 16), jax.lax.top_k(jnp.asarray(x), 16)
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_array_equal(got[1], want[1])


def test_eq8_distance_from_known_size():
    assert float(pp.distance_from_size(20.0, FOCAL, 0.2)) == pytest.approx(FOCAL * 0.2 / 20.0)


def test_eq9_distance_from_expansion_is_exact_for_a_pinhole():
    f_l, v = FOCAL * 0.2, 0.05  # pipe 0.2 m wide, approached at 5 cm/s
    d1, dt = 3.0, 4.0
    d2 = d1 - v * dt
    estimate = pp.distance_from_expansion(f_l / d1, f_l / d2, dt, v)
    assert float(estimate) == pytest.approx(d2, rel=1e-6)
    assert float(pp.distance_from_expansion(10.0, 10.0, dt, v)) == 0.0  # no growth: unknown


def _approach(n, v=0.05, d0=3.0, dt=0.5, l=0.2):
    t = jnp.arange(n) * dt
    d = d0 - v * t
    width = FOCAL * l / d
    return t, d, width


def test_track_with_unknown_size_uses_the_detection_ten_valid_ones_earlier():
    t, d, width = _approach(30)
    valid = jnp.ones(30, bool).at[jnp.array([3, 12, 13])].set(False)
    pipes = pp.Pipe(
        t,
        jnp.full(30, math.pi / 2),
        width,
        jnp.full(30, 64.0),
        jnp.full(30, 64.0),
        jnp.zeros(30, jnp.int32),
        jnp.ones(30),
        valid,
        jnp.ones(30),
    )
    params = pp.track_params(fov=math.radians(60.0), speed=0.05)
    est = jax.jit(pp.track)(params, pipes)
    rank = np.cumsum(np.asarray(valid)) - 1  # index among valid detections
    expect = np.where(np.asarray(valid) & (rank >= 10), np.asarray(d), 0.0)
    np.testing.assert_allclose(est.distance, expect, rtol=1e-4)
    assert int(np.sum(expect > 0)) == 17  # 27 valid detections, the first 10 unknown


def test_track_with_known_size_and_pipe_offset_from_projection():
    # A pipe centred X = 0.3 m to the right at depth d: pinhole column 64 + f X / d.
    t, d, _ = _approach(5)
    width = FOCAL * 0.2 / d
    pos = 64.0 + FOCAL * 0.3 / d
    pipes = pp.Pipe(
        t,
        jnp.full(5, math.pi / 2),
        width,
        pos,
        jnp.full(5, 64.0),
        jnp.zeros(5, jnp.int32),
        jnp.ones(5),
        jnp.ones(5, bool),
        jnp.ones(5),
    )
    est = pp.track(pp.track_params(size=0.2), pipes)
    np.testing.assert_allclose(est.distance, d, rtol=1e-5)
    np.testing.assert_allclose(est.pipe_offset, 0.3, rtol=1e-5)
    np.testing.assert_array_equal(est.control, 1)  # right of the central line: turn right
    left = pp.track(pp.track_params(size=0.2), pipes._replace(pos=128.0 - pos))
    np.testing.assert_array_equal(left.control, -1)


def test_eq4_to_6_camera_offset_is_the_phase_shifted_swing():
    a, omega, phi = 0.6, 2.0 * math.pi * 0.5, 0.3
    amplitude, alpha, phi_pos = 1.4, 2.571, 0.908  # the paper's NRP tuple
    t = jnp.linspace(0.0, 4.0, 50)
    angle = pp.head_joint_angle(t, a, omega, phi)
    velocity = jax.vmap(jax.grad(pp.head_joint_angle), in_axes=(0, None, None, None))(t, a, omega, phi)
    got = pp.camera_offset(angle, velocity, amplitude, alpha, phi_pos, omega)
    expect = amplitude * jnp.sin(alpha * a * jnp.sin(omega * t + phi + phi_pos))
    np.testing.assert_allclose(got, expect, atol=1e-5)


def test_camera_offset_decides_the_sign_when_the_pipe_is_ahead():
    params = pp.track_params(size=0.2, swing_amplitude=0.1, swing_ratio=1.0, swing_phase=0.0)
    pipe = pp.Pipe(
        *(jnp.float32(v) for v in (0.0, math.pi / 2, 20.0, 64.0, 64.0)),
        jnp.int32(0),
        jnp.float32(1),
        jnp.bool_(True),
        jnp.float32(1),
    )
    # Camera swung to the left of the central line (negative offset): the pipe straight
    # ahead of the camera is left of the central line too.
    _, est = pp.track_step(params, pp.track_init(), pipe, -0.5, 0.0)
    assert float(est.pipe_offset) == 0.0
    np.testing.assert_allclose(float(est.camera_offset), 0.1 * math.sin(-0.5), rtol=1e-6)
    assert int(est.control) == -1


def _pipe(t, width, pos, valid=True):
    f = jnp.float32
    return pp.Pipe(f(t), f(math.pi / 2), f(width), f(pos), f(64.0), jnp.int32(0), f(1), jnp.bool_(valid), f(1))


def test_off_axis_correction_recovers_the_depth_of_a_cylinder_seen_aside():
    # A cylinder of radius R at depth Z and lateral X: its edges are the tangents from the camera,
    # at bearings b +- asin(R / D), projected at f tan(.). Eq. (8) reads D cos^2 b; divided by cos b
    # (the bearing from the edges' midpoint) it reads the depth to within the R^2/D^2 terms.
    params = pp.track_params(size=0.25)
    fixed = params._replace(off_axis=jnp.float32(1.0))
    f, R = float(params.focal), 0.125
    for Z, X in ((2.0, 0.7), (1.0, -0.4), (3.0, 1.2)):
        D, b = math.hypot(Z, X), math.atan2(X, Z)
        a = math.asin(R / D)
        left, right = f * math.tan(b - a), f * math.tan(b + a)
        pipe = _pipe(0.0, right - left, 64.0 + 0.5 * (left + right))
        plain = float(pp.track_step(params, pp.track_init(), pipe, 0.0, 0.0)[1].distance)
        corrected = float(pp.track_step(fixed, pp.track_init(), pipe, 0.0, 0.0)[1].distance)
        assert plain == pytest.approx(D * math.cos(b) ** 2, rel=0.02)
        assert corrected == pytest.approx(Z, rel=0.01) and abs(corrected - Z) < abs(plain - Z)


def test_smoothing_takes_the_median_of_recent_distances_brought_forward():
    f = float(pp.track_params().focal)
    params = pp.track_params(size=0.25, speed=0.1, smooth=3.0)
    state = pp.track_init(4)
    # Eq. (8) distances 2.0, 2.6 (an outlier), 1.9 and 1.8 at t = 0, 1, 2, 3.5 s, widths f l / d.
    distances = (2.0, 2.6, 1.9, 1.8)
    out = []
    for t, d in zip((0.0, 1.0, 2.0, 3.5), distances):
        state, est = pp.track_step(params, state, _pipe(t, f * 0.25 / d, 64.0), 0.0, 0.0)
        out.append(float(est.distance))
    # Brought forward to each detection's time: at t = 1: median(2.0 - 0.1, 2.6) = 2.25; at t = 2:
    # median(1.8, 2.5, 1.9) = 1.9; at t = 3.5 the first is 3.5 s old (out of the 3 s): median(2.35, 1.75, 1.8).
    np.testing.assert_allclose(out, [2.0, 2.25, 1.9, 1.8], rtol=1e-5)
    # An invalid detection changes nothing and gives no distance.
    state2, est = pp.track_step(params, state, _pipe(4.0, 10.0, 64.0, valid=False), 0.0, 0.0)
    assert float(est.distance) == 0.0
    np.testing.assert_array_equal(np.asarray(state2.distance), np.asarray(state.distance))


def test_the_pooled_distances_are_the_last_pool_detections_whatever_eq9s_interval():
    """``pool`` sizes the distances' ring apart from Eq. (9)'s ``interval``: the same median with an interval of 2."""
    f = float(pp.track_params().focal)
    params = pp.track_params(size=0.25, speed=0.0, smooth=10.0)
    distances, times = (2.0, 2.6, 1.9, 1.8, 3.0), (0.0, 1.0, 2.0, 3.0, 4.0)
    for interval, pool, expected in ((2, 3, [2.0, 2.3, 2.0, 1.9, 1.9]), (10, 3, [2.0, 2.3, 2.0, 1.9, 1.9]),
                                     (2, 5, [2.0, 2.3, 2.0, 1.95, 2.0])):  # fmt: skip
        state, out = pp.track_init(interval, pool), []
        for t, d in zip(times, distances):
            state, est = pp.track_step(params, state, _pipe(t, f * 0.25 / d, 64.0), 0.0, 0.0)
            out.append(float(est.distance))
        # The medians by hand: (2.6, 1.9, 1.8) -> 1.9, (1.9, 1.8, 3.0) -> 1.9; all five: 2.0.
        np.testing.assert_allclose(out, expected, rtol=1e-5)
        assert state.t.shape == (interval,) and state.distance.shape == (pool,)


def test_track_vmaps_over_streams():
    t, _, width = _approach(12)
    ones = jnp.ones(12)
    pipes = pp.Pipe(t, ones, width, 64.0 * ones, 64.0 * ones, jnp.zeros(12, jnp.int32), ones, jnp.ones(12, bool), ones)
    batch = jax.tree.map(lambda x: jnp.stack([x, x]), pipes)
    speeds = jnp.array([0.05, 0.10])
    params = jax.vmap(lambda v: pp.track_params(speed=0.0)._replace(speed=v))(speeds)
    est = jax.vmap(pp.track)(params, batch)
    np.testing.assert_allclose(est.distance[1, 10:], 2.0 * est.distance[0, 10:], rtol=1e-5)


# --- beyond Section 2.3: upright edges, image support, one kind per object ----


def test_support_of_lines_and_rings_by_hand():
    image = np.zeros((32, 32), np.float32)
    image[:, 10] = 1.0  # a full column of events at x = 10
    image[:16, 25] = 1.0  # half a column at x = 25
    origin = (16.0, 16.0)
    support = jax.jit(pp.line_support, static_argnums=3)(
        jnp.asarray(image), jnp.full(3, math.pi / 2), jnp.array([-6.0, 9.0, 4.0]), origin
    )
    # Near an event: columns 9-11 (all rows) and 24-26 (rows 0-16): chance q = (96 + 51) / 1024.
    q = (3 * 32 + 3 * 17) / 1024
    np.testing.assert_allclose(support, [1.0, (17 / 32 - q) / (1 - q), 0.0], atol=1e-6)
    ring = np.zeros((32, 32), np.float32)
    phi = np.linspace(0, 2 * np.pi, 400)
    ring[np.round(16 + 8 * np.sin(phi)).astype(int), np.round(16 + 8 * np.cos(phi)).astype(int)] = 1.0
    coverage, in_view = jax.jit(pp.ring_support)(
        jnp.asarray(ring), jnp.array([16.0, 16.0, 0.0]), 16.0, jnp.array([8.0, 4.0, 8.0])
    )
    np.testing.assert_allclose(coverage[0], 1.0) and np.testing.assert_allclose(in_view[:2], 1.0)
    assert float(coverage[1]) < 0.05  # radius 4 inside the ring: no events within a pixel
    assert 0.5 <= float(in_view[2]) <= 0.56  # centred on the left edge: the right half (and the x = 0 column) in view


def test_body_needs_upright_edges_drawn_by_the_events():
    spikes = _spikes((+1, 90, 20, 3), (-1, 90, 40, 3))  # x = 20 (positive) and x = 40 (negative), origin (0, 0)
    image = np.zeros((2, 128, 128), np.float32)
    image[0, :, 20] = 1.0
    image[1, :, 40] = 1.0
    params = pp.BodyParams(max_tilt=math.radians(30.0), min_support=0.25)
    found = find_body(params, spikes, THETA, RHO, 0.0, image=tuple(jnp.asarray(image)))
    assert bool(found.valid) and float(found.support) == pytest.approx(1.0)
    image[1, 10:, 40] = 0.0  # the negative edge drawn over 10 rows (and near 11) only: a curve's tangent, not an edge
    assert not bool(find_body(params, spikes, THETA, RHO, 0.0, image=tuple(jnp.asarray(image))).valid)
    horizontal = _spikes((+1, 0, 30, 3), (-1, 179, -50, 3))  # the theta-wrap pair above: horizon-like lines
    assert not bool(find_body(params, horizontal, THETA, RHO, t=0.0).valid)


def test_classify_keeps_the_better_supported_kind_where_they_overlap():
    classify = jax.jit(pp.classify)
    body = pp.Pipe(*(jnp.float32(v) for v in (0.0, math.pi / 2, 20.0, 30.0, 64.0)), jnp.int32(0), jnp.float32(2),
                   jnp.bool_(True), jnp.float32(0.6))  # fmt: skip
    entry = body._replace(kind=jnp.int32(1), width=jnp.float32(16.0), pos=jnp.float32(35.0), support=jnp.float32(0.8))
    b, e = classify(body, entry)
    assert not bool(b.valid) and bool(e.valid)
    b, e = classify(body, entry._replace(support=jnp.float32(0.4)))
    assert bool(b.valid) and not bool(e.valid)
    b, e = classify(body, entry._replace(pos=jnp.float32(100.0)))  # two objects apart: both stay
    assert bool(b.valid) and bool(e.valid)


def test_entry_is_the_first_candidate_whose_ring_the_events_draw():
    counts = np.zeros((2, 32, 32), np.float32)
    counts[1, 16, 16] = 5.0  # the most active neuron: radius 9 at (16, 16), but no ring in the events
    counts[0, 10, 12] = 3.0  # radius 8 at (12, 10): its ring is drawn
    image = np.zeros((32, 32), np.float32)
    phi = np.linspace(0, 2 * np.pi, 400)
    image[np.round(10 + 8 * np.sin(phi)).astype(int).clip(0, 31), np.round(12 + 8 * np.cos(phi)).astype(int)] = 1.0
    params = pp.EntryParams(min_count=1.0, min_coverage=0.5, min_in_view=0.5)
    found = find_entry(jnp.asarray(counts), jnp.array([8.0, 9.0]), 0.0, params, image=jnp.asarray(image))
    assert bool(found.valid) and (float(found.pos), float(found.row), float(found.width)) == (12.0, 10.0, 16.0)
    assert not bool(
        find_entry(jnp.asarray(counts), jnp.array([8.0, 9.0]), 0.0, params, image=jnp.zeros((32, 32))).valid
    )
    # Without an image, the paper's rule: the most active neuron.
    assert float(find_entry(jnp.asarray(counts), jnp.array([8.0, 9.0]), 0.0).width) == 18.0
