"""DVS emulators: event counts and times a contrast step predicts, refractory, mismatch and noise; scenes."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from spikejax.errors import UserError
from spikejax.vision import dvs, scenes


def _frames(*values, shape=(4, 5)):
    return jnp.stack([jnp.full(shape, v, jnp.float32) for v in values])


def test_frame_difference_by_hand():
    prev = jnp.asarray([[0.2, 0.2, 0.2], [0.5, 0.5, 0.5]])
    frame = jnp.asarray([[0.2, 0.35, 0.0], [0.5, 0.61, 0.45]])
    events, overflow = dvs.frame_difference(prev, frame, 0.25, threshold=0.1, capacity=4)
    ok = np.asarray(events.valid)
    assert ok.tolist() == [True, True, True, False] and int(overflow) == 0
    assert np.asarray(events.x)[ok].tolist() == [1, 2, 1]
    assert np.asarray(events.y)[ok].tolist() == [0, 0, 1]
    assert np.asarray(events.p)[ok].tolist() == [1, -1, 1]
    assert np.all(np.asarray(events.t)[ok] == 0.25)
    small, overflow = dvs.frame_difference(prev, frame, 0.25, threshold=0.1, capacity=2)
    assert int(small.count()) == 2 and int(overflow) == 1
    # In log mode the threshold is a contrast: 0.5 -> 0.61 is log(1.22) ~ 0.2.
    logged, _ = dvs.frame_difference(prev, frame, 0.0, threshold=0.25, capacity=4, log=True)
    assert np.asarray(logged.x)[np.asarray(logged.valid)].tolist() == [1, 2]


@pytest.mark.parametrize("low, high, c", [(0.2, 0.8, 0.2), (0.9, 0.1, 0.3)])
def test_contrast_step_makes_the_predicted_events(low, high, c):
    params = dvs.dvs_params(pos_threshold=c, neg_threshold=c, eps=1e-3)
    frames = _frames(low, high)
    events, overflow = dvs.emulate(
        params, frames, jnp.asarray([0.0, 0.1]), capacity=512, max_per_pixel=8, key=jax.random.key(0)
    )
    contrast = np.log(high + 1e-3) - np.log(low + 1e-3)
    n = int(np.floor(abs(contrast) / c))
    assert int(events.count()[0]) == 20 * n and int(overflow[0]) == 0
    ok = np.asarray(events.valid[0])
    assert set(np.asarray(events.p[0])[ok].tolist()) == {int(np.sign(contrast))}
    # The k-th crossing happens when the linearly moving log intensity has gone k c.
    times = np.unique(np.round(np.asarray(events.t[0])[ok], 6))
    np.testing.assert_allclose(times, 0.1 * np.arange(1, n + 1) * c / abs(contrast), atol=1e-6)
    assert np.all(np.diff(np.asarray(events.t[0])[ok]) >= 0)


def test_no_change_no_events():
    params = dvs.dvs_params(threshold_sigma=0.1)
    frames = _frames(0.4, 0.4)
    events, overflow = dvs.emulate(
        params, frames, jnp.asarray([0.0, 0.1]), capacity=512, max_per_pixel=8, key=jax.random.key(1)
    )
    assert int(events.count()[0]) == 0 and int(overflow[0]) == 0
    fd, _ = dvs.difference_events(frames, jnp.asarray([0.0, 0.1]), threshold=0.01, capacity=64)
    assert int(fd.count()[0]) == 0


def test_refractory_keeps_one_event_per_period():
    params = dvs.dvs_params(pos_threshold=0.2, neg_threshold=0.2, refractory=0.02)
    frames = _frames(0.2, 0.8)  # 6 crossings spread over 0.1 s: 0.0144 s apart
    events, _ = dvs.emulate(
        params, frames, jnp.asarray([0.0, 0.1]), capacity=512, max_per_pixel=8, key=jax.random.key(0)
    )
    # Crossings at 1..6 x 0.01443 s: kept 1, 3, 5 (each >= 0.02 s after the last kept).
    assert int(events.count()[0]) == 20 * 3
    long, _ = dvs.emulate(
        params._replace(refractory=jnp.float32(1.0)),
        frames,
        jnp.asarray([0.0, 0.1]),
        capacity=512,
        max_per_pixel=8,
        key=jax.random.key(0),
    )
    assert int(long.count()[0]) == 20


def test_too_many_crossings_are_counted():
    params = dvs.dvs_params(pos_threshold=0.2, neg_threshold=0.2)
    events, overflow = dvs.emulate(
        params, _frames(0.2, 0.8), jnp.asarray([0.0, 0.1]), capacity=50, max_per_pixel=4, key=jax.random.key(0)
    )
    # 6 crossings per pixel, 4 made (2 counted), 80 made of which 50 fit.
    assert int(events.count()[0]) == 50 and int(overflow[0]) == 20 * 2 + 30


def test_crossings_split_the_overflow_into_clipped_and_beyond_capacity():
    params = dvs.dvs_params(pos_threshold=0.2, neg_threshold=0.2)
    frames = _frames(0.2, 0.8)
    # log(0.801 / 0.201) / 0.2 = 6.9: six crossings a pixel, as the test above counts.
    n = dvs.crossings(params, dvs.init(params, frames[0], key=jax.random.key(0)), frames[1])
    assert n.shape == (4, 5) and (np.asarray(n) == 6).all()
    events, overflow = dvs.emulate(
        params, frames, jnp.asarray([0.0, 0.1]), capacity=50, max_per_pixel=4, key=jax.random.key(0)
    )
    clipped = int(jnp.maximum(n - 4, 0).sum())
    assert clipped == 40 and int(overflow[0]) - clipped == 80 - int(events.count()[0]) == 30


@pytest.mark.parametrize("refractory", [2e-3, 0.0])
@pytest.mark.parametrize("params_traced", [True, False])
def test_step_counts_are_the_event_list_counted_per_pixel(refractory, params_traced):
    # A moving bright bar with mismatch, heavy shot noise and a refractory period or none (which `step_counts`
    # computes apart: traced, through `lax.cond`; as a constant, chosen when tracing); the list holds every event.
    params = dvs.dvs_params(threshold_sigma=0.05, noise_rate=20.0, refractory=refractory)
    x = jnp.arange(24)
    frames = [jnp.where((x[None, :] >= k) & (x[None, :] < k + 4), 0.9, 0.15) * jnp.ones((10, 1)) for k in range(6)]
    key = jax.random.key(4)
    state = dvs.init(params, frames[0], 0.0, key=key)
    dense_state, total = state, 0
    listed = jax.jit(functools.partial(dvs.step, capacity=2048, max_per_pixel=3))
    counted = jax.jit(functools.partial(dvs.step_counts, max_per_pixel=3))
    if not params_traced:
        counted = jax.jit(lambda _, *a, **k: dvs.step_counts(params, *a, max_per_pixel=3, **k))
    for k, frame in enumerate(frames[1:], start=1):
        kk = jax.random.fold_in(key, k)
        state, events, overflow = listed(params, state, frame, 0.01 * k, key=kk)
        dense_state, counts, clipped = counted(params, dense_state, frame, 0.01 * k, key=kk)
        image = jnp.zeros((10, 24), jnp.int32).at[events.y, events.x].add(events.valid.astype(jnp.int32))
        np.testing.assert_array_equal(np.asarray(counts), np.asarray(image))
        assert int(clipped) == int(overflow) and int(events.count()) < 2048
        for a, b in zip(jax.tree.leaves(state), jax.tree.leaves(dense_state)):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
        total += int(counts.sum())
    noise_only = int(np.asarray(counts)[:, 12:].sum())  # the bar never reached these columns
    assert total > 200 and noise_only > 0


def test_mismatch_and_noise_come_from_the_key():
    params = dvs.dvs_params(threshold_sigma=0.2, noise_rate=5.0)
    frames = jnp.stack([jnp.full((32, 32), v) for v in (0.3, 0.5, 0.5)])
    times = jnp.asarray([0.0, 0.1, 0.2])
    run = jax.jit(lambda k: dvs.emulate(params, frames, times, capacity=4096, key=k))
    a, _ = run(jax.random.key(7))
    b, _ = run(jax.random.key(7))
    c, _ = run(jax.random.key(8))
    for leaf_a, leaf_b in zip(a, b):
        np.testing.assert_array_equal(np.asarray(leaf_a), np.asarray(leaf_b))
    assert not np.array_equal(np.asarray(a.x), np.asarray(c.x))
    # Mismatched thresholds: a uniform step gives different counts per pixel.
    ok = np.asarray(a.valid[0])
    per_pixel = np.bincount(np.asarray(a.y[0] * 32 + a.x[0])[ok], minlength=1024)
    assert per_pixel.min() < per_pixel.max()
    # Noise only in the second interval: about 1024 (1 - exp(-0.5)) = 403 events.
    n = int(a.count()[1])
    expected = 1024 * (1 - np.exp(-5.0 * 0.1))
    assert abs(n - expected) < 5 * np.sqrt(expected)


def test_emulator_vmaps_over_cameras():
    params = dvs.dvs_params(noise_rate=2.0)
    frames = jnp.stack([_frames(0.2, 0.5), _frames(0.6, 0.1)])
    keys = jax.random.split(jax.random.key(0), 2)
    times = jnp.asarray([0.0, 0.05])
    batch, _ = jax.vmap(lambda k, f: dvs.emulate(params, f, times, capacity=512, max_per_pixel=8, key=k))(keys, frames)
    for i in range(2):
        alone, _ = dvs.emulate(params, frames[i], times, capacity=512, max_per_pixel=8, key=keys[i])
        np.testing.assert_array_equal(np.asarray(batch.t[i]), np.asarray(alone.t))


def test_scenes_give_their_truth_and_check_input():
    ball = scenes.moving_ball(n_frames=3, start=(30.0, 40.0), velocity=(5.0, 0.0), radius=8.0)
    assert isinstance(ball, scenes.SyntheticScene)
    frame = np.asarray(ball.frames[2])
    assert frame[40, 40] > 0.8 and frame[40, 30] < 0.3  # moved from (30, 40) to (40, 40)
    assert ball.truth.a.tolist() == [30.0, 35.0, 40.0]
    pipe = scenes.lying_pipe(n_frames=2, centre=(50.0, 60.0), radius=10.0, growth=2.0)
    assert float(pipe.frames[1][60, 50]) < 0.2 and pipe.truth.r.tolist() == [10.0, 12.0]
    noisy = scenes.standing_pipe(key=jax.random.key(0), n_frames=2, noise=0.05)
    assert 0.0 <= float(noisy.frames.min()) and float(noisy.frames.max()) <= 1.0
    with pytest.raises(UserError, match="key"):
        scenes.standing_pipe(n_frames=2, noise=0.05)
    with pytest.raises(UserError, match="2 frames"):
        scenes.moving_ball(n_frames=1)
