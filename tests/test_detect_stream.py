"""The streaming pipe detector (`spikejax.vision.stream`): one control step at a time, as a closed loop needs it.

Fed step by step, it must give what `spikejax.vision.detect.run` gives for
the same slots (bit for bit), Alg. 3's estimates of `spikejax.vision.pipe.track`,
and the same result per stream whether streams run alone or vmapped.
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from spikejax.errors import UserError
from spikejax.vision import detect, dvs, hough, scenes, stream
from spikejax.vision import pipe as pp

SIZE, SLOTS, K = 32, 4, 5
RUN = jax.jit(stream.run, static_argnums=0)
UPDATE = jax.jit(stream.update, static_argnums=0)
TRACK = jax.jit(pp.track)


def _events(kind, index, size=SIZE):
    """A pipe swinging across the middle at its fastest (the gait's swing through the centre), with noise."""
    h = size / 64
    view = scenes.View(
        kind, 32.0 * h, 12.0 * h, 125.0, 0.0 if index == 0 else math.pi, (10.0 if kind == "standing" else 8.0) * h,
        30.0 * h, 0.5 * h, 2.0 * h,
    )  # fmt: skip
    k_noise = jax.random.fold_in(jax.random.key(3), index)
    scene = scenes.snake_view(view, n_frames=SLOTS * K + 1, height=size, width=size, noise=0.02, key=k_noise)
    ev, _ = dvs.difference_events(scene.frames, scene.times, threshold=0.1, capacity=1024)
    return jax.tree.map(lambda v: v.reshape(SLOTS, K, -1), ev), np.asarray(scene.times[1:]).reshape(SLOTS, K)


def _same(a, b):
    for name, x, y in zip(a._fields, a, b):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y), err_msg=name)


@pytest.fixture(scope="module")
def both():
    """Two streams (a standing pipe, an entry), both grids, synchronous: the detector's and the stream's results."""
    det = detect.Detector(
        line=hough.LineGrid(SIZE, SIZE, n_rho=48), circle=hough.CircleGrid(SIZE, SIZE, n_r=SIZE // 2), sub_slots=K
    )
    tracker = stream.Tracker(det)
    params = stream.tracker_params(tracker, track=pp.track_params(width=SIZE, speed=0.1, swing_amplitude=0.05))
    (ev_a, ts_a), (ev_b, ts_b) = _events("standing", 0), _events("lying", 0)
    ev = jax.tree.map(lambda a, b: jnp.stack([a, b]), ev_a, ev_b)
    ts = np.stack([ts_a, ts_b])
    angle = 0.3 * np.sin(2 * np.pi * ts / 2.5)
    velocity = 0.3 * 2 * np.pi / 2.5 * np.cos(2 * np.pi * ts / 2.5)
    _, bodies, entries = jax.jit(jax.vmap(detect.run, in_axes=(None, None, 0, 0)), static_argnums=0)(
        det, params.detector, ev, ts
    )
    _, out = jax.jit(jax.vmap(stream.run, in_axes=(None, None, 0, 0, 0, 0)), static_argnums=0)(
        tracker, params, ev, ts, angle, velocity
    )
    return tracker, params, ev, ts, angle, velocity, bodies, entries, out


def test_stream_gives_the_detections_of_detect_run_and_vmaps_like_a_loop(both):
    *_, bodies, entries, out = both
    _same(bodies, out.body)
    _same(entries, out.entry)
    # A vmapped stream equals the stream alone, fed one `update` (a step, then the slot's end when due) per step.
    tracker, params, ev, ts, angle, velocity = both[:6]
    update = UPDATE
    state, ends = stream.init(tracker), []
    for i in range(SLOTS):
        for j in range(K):
            step_ev = jax.tree.map(lambda v: v[1, i, j], ev)
            state, o, ended = update(tracker, params, state, step_ev, ts[1, i, j], angle[1, i, j], velocity[1, i, j])
            assert bool(ended) == (j == K - 1)
        ends.append(o)
    _same(jax.tree.map(lambda v: v[1], out), jax.tree.map(lambda *v: jnp.stack(v), *ends))
    # Not vacuous: the standing pipe is a body, the entry an entry, and neither the other.
    assert out.body.valid[0].sum() >= 3 and out.entry.valid[1].sum() >= 3
    assert not out.entry.valid[0].any() and not out.body.valid[1].any()


def test_stream_estimates_are_alg3_over_its_detections(both):
    _, params, _, _, angle, velocity, bodies, entries, out = both
    for s in range(2):
        for pipes, est in ((bodies, out.body_estimate), (entries, out.entry_estimate)):
            one = jax.tree.map(lambda v: v[s], pipes)
            # Window 1: Eq. (5) reads the encoders at the slot's last step.
            expect = TRACK(params.track, one, angle[s, :, -1], velocity[s, :, -1])
            _same(expect, jax.tree.map(lambda v: v[s], est))
    # The control follows the steering detection (the entry first) and is held for one missed slot.
    control = np.where(out.entry.valid, out.entry_estimate.control, out.body_estimate.control)
    seen = np.asarray(out.body.valid | out.entry.valid)
    np.testing.assert_array_equal(np.asarray(out.control)[seen], control[seen])


@pytest.mark.slow
def test_async_one_update_per_step_is_the_nested_scan_and_detect_run():
    """`update` step by step equals `run` and `detect.run`, asynchronously (lines; three compiles, ~25 s)."""
    size = SIZE
    det = detect.Detector(line=hough.LineGrid(size, size, n_rho=48), circle=None, mode="async", sub_slots=K)
    tracker = stream.Tracker(det, window=3)
    params = stream.tracker_params(tracker)
    ev, ts = _events("standing", 0, size)
    angle = 0.2 * np.cos(ts)
    _, out = RUN(tracker, params, ev, ts, angle, -angle)
    _, bodies, _ = jax.jit(detect.run, static_argnums=0)(det, params.detector, ev, ts)
    _same(bodies, out.body)
    assert out.body.valid.sum() >= 2
    update = jax.jit(stream.update, static_argnums=0)
    state = stream.init(tracker)
    ends = []
    for i in range(SLOTS):
        for j in range(K):
            step_ev = jax.tree.map(lambda v: v[i, j], ev)
            state, o, ended = update(tracker, params, state, step_ev, ts[i, j], angle[i, j], -angle[i, j])
            assert bool(ended) == (j == K - 1)
        ends.append(o)
    stack = lambda xs: jax.tree.map(lambda *v: jnp.stack(v), *xs)  # noqa: E731
    _same(out.body, stack([o.body for o in ends]))
    _same(out.body_estimate, stack([o.body_estimate for o in ends]))
    # The mean filter: the head signal Eq. (5) saw at each slot's end is the mean of its last 3 steps.
    np.testing.assert_allclose(out.head_angle, pp.causal_mean(angle.reshape(-1), 3)[K - 1 :: K], rtol=1e-5)


def _pipe(pos, valid=True, t=0.0, width=10.0):
    f = jnp.float32
    return pp.Pipe(f(t), f(math.pi / 2), f(width), f(pos), f(32.0), jnp.int32(0), f(3.0), jnp.bool_(valid), f(1.0))


def test_unknown_distance_policy():
    """With d = 0 the paper's Alg. 3 steers by the camera's swing; an assumed distance keeps the pipe's side."""
    swing = dict(swing_amplitude=0.1, swing_ratio=1.0, swing_phase=0.0, omega=1.0, speed=0.1)
    pipe = _pipe(pos=100.0)  # well right of the centre column 64
    track_step = jax.jit(pp.track_step)
    paper = pp.track_params(**swing)
    _, est = track_step(paper, pp.track_init(), pipe, -0.5, 0.0)  # camera swung left
    assert float(est.distance) == 0.0 and float(est.pipe_offset) == 0.0 and int(est.control) == -1
    ours = pp.track_params(**swing, assumed_distance=3.0)
    _, est = track_step(ours, pp.track_init(), pipe, -0.5, 0.0)
    np.testing.assert_allclose(float(est.pipe_offset), 3.0 * 36.0 / ours.focal, rtol=1e-6)
    assert float(est.distance) == 0.0 and int(est.control) == 1


def test_control_is_held_for_hold_slots_then_straight(both):
    tracker, params, ev = both[:3]
    params = params._replace(hold=jnp.int32(2))  # traced: no recompile
    state = stream.init(tracker)._replace(control=jnp.int32(1))
    nothing = jax.tree.map(lambda v: jnp.zeros_like(v[0, 0, 0]), ev)  # a step without events
    controls = []
    for i in range(4):  # slots without events: no detections
        for j in range(K):
            state, out, ended = UPDATE(
                tracker, params, state, nothing, np.float64(0.1 * i + 0.02 * j), np.float64(0), np.float64(0)
            )
        controls.append(int(out.control))
        assert bool(ended) and int(state.steps) == 0 and not bool(out.body.valid | out.entry.valid)
    assert controls == [1, 1, 0, 0]


def test_bad_configurations_are_one_line_errors():
    with pytest.raises(UserError, match="target must be one of any, body, entry"):
        stream.Tracker(target="pipe")
    with pytest.raises(UserError, match="Tracker.window must be a positive integer"):
        stream.Tracker(window=0)
    tracker = stream.Tracker(detect.Detector(line=hough.LineGrid(16, 16), circle=None, sub_slots=3))
    with pytest.raises(UserError, match=r"slot_steps must be within 1\.\.3"):
        stream.tracker_params(tracker, slot_steps=4)


def test_circle_per_slot_is_one_sync_update_on_the_slots_events(both):
    """``circle_per_slot``: the circle grid after each slot is `hough.sync_step` on all the slot's events at its end."""
    tracker, params, ev, ts, angle, velocity = both[:6]
    per_slot = stream.Tracker(tracker.detector, circle_per_slot=True)
    state, _ = jax.jit(stream.run, static_argnums=0)(
        per_slot, params, jax.tree.map(lambda a: a[1], ev), ts[1], angle[1], velocity[1]
    )
    grid, p = tracker.detector.circle, params.detector.circle
    ref = stream.init(per_slot).grids.circle
    fired_any = False
    for s in range(SLOTS):
        slot_events = jax.tree.map(lambda a: a[1, s].reshape(-1), ev)
        ref, spikes = hough.sync_step(p, grid, ref, slot_events, ts[1][s, -1])
        fired_any |= bool(np.any(np.asarray(spikes)))
    np.testing.assert_array_equal(np.asarray(state.grids.circle.v), np.asarray(ref.v))
    assert fired_any
    with pytest.raises(UserError, match="circle_per_slot needs the synchronous mode"):
        stream.Tracker(detect.Detector(mode="async"), circle_per_slot=True)


def test_a_skipped_circle_update_carries_the_slots_events_to_the_next(both):
    """``slot_end(circle_update=False)``: no update and no entry; the next update takes both slots' events."""
    tracker, _, ev, ts = both[:4]
    det = detect.Detector(circle=tracker.detector.circle, line=None, sub_slots=2 * K)
    alone = stream.Tracker(det, circle_per_slot=True)
    params = stream.tracker_params(alone, track=pp.track_params(width=SIZE, speed=0.1))
    step, end = jax.jit(stream.step, static_argnums=0), jax.jit(stream.slot_end, static_argnums=(0, 4))
    state, ref = stream.init(alone), stream.init(alone).grids.circle
    for s in range(SLOTS):
        for j in range(K):
            state = step(alone, params, state, jax.tree.map(lambda a: a[1, s, j], ev), ts[1][s, j])
        state, out = end(alone, params, state, ts[1][s, -1], s % 2 == 1)
        if s % 2 == 0:
            assert not bool(out.entry.valid) and int(state.steps) == 0
            np.testing.assert_array_equal(np.asarray(state.grids.circle.v), np.asarray(ref.v))
        else:
            pair = jax.tree.map(lambda a: a[1, s - 1 : s + 1].reshape(-1), ev)
            ref, _ = hough.sync_step(params.detector.circle, det.circle, ref, pair, ts[1][s, -1])
            np.testing.assert_array_equal(np.asarray(state.grids.circle.v), np.asarray(ref.v))
    assert np.any(np.asarray(ref.v) != 0)
    with pytest.raises(UserError, match="needs circle_per_slot and no line grid"):
        stream.slot_end(tracker, both[1], stream.init(tracker), 0.0, False)


def test_a_skipped_slot_whose_events_are_dropped_leaves_the_next_update_its_own(both):
    """``slot_end(circle_update=False, keep_events=False)``: the next update sees only the slots after it."""
    tracker, _, ev, ts = both[:4]
    det = detect.Detector(circle=tracker.detector.circle, line=None, sub_slots=2 * K)
    alone = stream.Tracker(det, circle_per_slot=True)
    params = stream.tracker_params(alone, track=pp.track_params(width=SIZE, speed=0.1))
    step, end = jax.jit(stream.step, static_argnums=0), jax.jit(stream.slot_end, static_argnums=(0, 4, 5))
    state, ref = stream.init(alone), stream.init(alone).grids.circle
    for s in range(SLOTS):
        for j in range(K):
            state = step(alone, params, state, jax.tree.map(lambda a: a[1, s, j], ev), ts[1][s, j])
        state, out = end(alone, params, state, ts[1][s, -1], s % 2 == 1, False)
        if s % 2 == 1:
            own = jax.tree.map(lambda a: a[1, s].reshape(-1), ev)
            ref, _ = hough.sync_step(params.detector.circle, det.circle, ref, own, ts[1][s, -1])
        np.testing.assert_array_equal(np.asarray(state.grids.circle.v), np.asarray(ref.v))
    assert np.any(np.asarray(ref.v) != 0)
