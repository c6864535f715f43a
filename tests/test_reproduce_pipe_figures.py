"""The counterparts of Figs. 5-7 of the snake pipe-tracking paper (`robots.snake.reproduce_pipe_figures`)."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from robots.snake import reproduce_pipe_figures as pf
from robots.snake.calibration import SWING, Run
from spikejax.vision import pipe as pp


def test_fundamental_keeps_the_component_at_omega_only():
    """Over whole periods the FFT coefficient at omega of a sum of harmonics is that harmonic, exactly."""
    omega = 2 * math.pi / 2.5
    t = np.arange(0, 4 * 2.5, 0.02)  # 4 whole periods, 125 samples each
    first = 3.0 * np.sin(omega * t + 0.4)
    y = first + 0.5 * np.sin(3 * omega * t) + 0.2 * np.cos(2 * omega * t)
    np.testing.assert_allclose(pf.fundamental(t, y, omega), first, atol=1e-10)


def test_offset_stats_by_hand():
    t = np.linspace(0, 2 * math.pi, 1000, endpoint=False)
    true = 0.08 * np.sin(t)
    s = pf.offset_stats(true, true + 0.01)
    assert s["rmse"] == pytest.approx(0.01)
    assert s["amplitude"] == pytest.approx(0.08)  # sqrt(2) times the RMS of a sine
    assert s["rmse_share"] == pytest.approx(0.125)
    assert s["correlation"] == pytest.approx(1.0)
    assert pf.offset_stats(true, -true)["correlation"] == pytest.approx(-1.0)


def test_camera_offset_figure_on_a_pure_swing(tmp_path):
    """A camera swinging as a pure sine across a straight path: its offset is that sine (right of the path
    positive), its fundamental the same, and Eqs. (4)-(6) are what `calibration.estimate` makes of the encoder."""
    per = 125  # steps of 20 ms in a 2.5 s period, as the gait's
    dt = 2.5 / per
    t = dt * np.arange(1, 8 * per + 1)
    omega = SWING.omega
    swing = 0.09 * np.sin(omega * t)
    head = np.stack([0.1 * t, -swing], axis=1)  # moving along +x: right is -y
    angle = 0.7 * np.sin(omega * t + 1.0)
    run = Run(t, angle, 0.7 * omega * np.cos(omega * t + 1.0), head, head.copy(), per)
    stats = pf.camera_offset_figure(tmp_path / "offset.png", run)
    assert (tmp_path / "offset.png").stat().st_size > 0
    assert stats["fft"]["rmse"] < 1e-9 and stats["fft"]["correlation"] == pytest.approx(1.0)
    assert stats["fft"]["amplitude"] == pytest.approx(0.09, rel=1e-9)
    used = slice(per, per + 6 * per)  # whole periods after the first, the last half period left out
    from robots.snake.calibration import estimate

    expected = pf.offset_stats(swing[used], estimate(SWING, angle, run.velocity)[used])
    assert stats["eq_4_6"] == pytest.approx(expected)


def test_pick_slots_spreads_the_panels_over_the_approach():
    depth = np.array([3.1, 2.9, 2.4, 2.0, 1.6, 1.2, 0.9, 0.6, 0.5])
    candidates = np.array([0, 2, 3, 5, 6, 8])  # depths 3.1, 2.4, 2.0, 1.2, 0.9, 0.5
    # Targets 3.1, 2.233, 1.367, 0.5: nearest 3.1, 2.4 (0.167 against 2.0's 0.233), 1.2, 0.5.
    assert pf.pick_slots(depth, candidates) == [0, 2, 5, 8]
    assert pf.pick_slots(depth, candidates[:2]) == [0, 2]
    assert pf.pick_slots(depth, np.array([4])) == [4]
    assert pf.pick_slots(depth, np.array([], int)) == []


def _pipes(valid):
    n = len(valid)
    z = np.zeros(n, np.float32)
    return pp.Pipe(z, z, np.arange(n, dtype=np.float32) + 10, z, z, z, z, np.asarray(valid), z)


def test_lane_cuts_at_the_end_and_detections_are_of_the_targets_kind():
    rec = {
        "done": np.array([[0, 0, 1, 1], [0, 0, 0, 0]], np.float32),
        "depth": np.array([[3.0, 2.0, 1.0, 0.5]] * 2),
        "body_distance": np.array([[3.1, 2.2, 0.9, 0.4]] * 2),
        "entry_distance": np.array([[9.0, 9.0, 1.2, 9.0]] * 2),
        "body": jax.tree.map(lambda *a: np.stack(a), _pipes([1, 0, 1, 1]), _pipes([1, 0, 1, 1])),
        "entry": jax.tree.map(lambda *a: np.stack(a), _pipes([0, 0, 1, 0]), _pipes([0, 0, 1, 0])),
    }
    first = pf.lane(rec, 0)
    assert first["depth"].tolist() == [3.0, 2.0, 1.0]  # up to and including the slot that ended it
    assert pf.lane(rec, 1)["depth"].shape == (4,)
    idx, width, distance = pf.target_detections(first, lying=False)
    assert idx.tolist() == [0, 2] and width.tolist() == [10.0, 12.0] and distance.tolist() == [3.1, 0.9]
    idx, width, distance = pf.target_detections(first, lying=True)
    assert idx.tolist() == [2] and distance.tolist() == [1.2]


def _recorded_and_rolled_out(env, kind, side, controller, slots: int):
    """Two lanes of ``env`` recorded by `record` and run by `pipe_env.rollout` on the same keys and scenes:
    ``(record, the rollout's per-slot depth, Alg. 3 distance)`` (the rollout's record at each slot's last step)."""
    from robots.snake import pipe_controller as pc
    from robots.snake import pipe_env, pipes

    keys = jax.random.split(jax.random.key(5), 2)
    scenes = jax.vmap(lambda k: pipes.sample(k, kind, side))(keys)
    params = pc.SwitchParams(controller, jnp.zeros(2, jnp.int32))
    params = jax.tree.map(lambda a: jnp.broadcast_to(jnp.asarray(a), (2,)), params)
    rec = pf.record(env, keys, scenes, params, slots)
    ref, _ = jax.jit(jax.vmap(lambda k, s, p: pipe_env.rollout(env, pc.switch, p, k, slots, s)))(keys, scenes, params)
    ends = np.arange(slots) * env.slot_steps + env.slot_steps - 1
    return rec, np.asarray(ref["metrics"]["depth"])[:, ends], np.asarray(ref["metrics"]["d_est"])[:, ends]


@pytest.mark.slow  # about 45 s: the recording and the rollout compiled
def test_recorded_episode_is_the_rollouts_trial():
    """The figures' episodes are the run's: `record` gives, slot by slot, the true depth and Alg. 3's distance of
    `pipe_env.rollout` on the same key and scene (its record at each slot's last step)."""
    from robots.snake import pipe_controller as pc
    from robots.snake import pipe_env, pipes

    slots = 12
    env = pipe_env.PipeEnv(max_steps=slots * 5, random_phase=True)
    rec, depth, distance = _recorded_and_rolled_out(env, pipes.STANDING, pipes.RIGHT, pc.ControllerParams(), slots)
    np.testing.assert_array_equal(rec["depth"], depth)
    found = rec["body"].valid
    assert found.sum() > 0
    np.testing.assert_array_equal(rec["body_distance"][found], distance[found])
    assert rec["image"].shape == (2, slots, 128, 128) and np.abs(rec["image"]).sum() > 0


@pytest.mark.slow  # about 60 s
def test_recorded_lying_episode_follows_the_circle_schedule_as_the_rollout():
    """With the circle grid every 4 slots on the last 2 slots' events, `record` is `pipe_env.rollout`'s trial."""
    from robots.snake import pipe_controller as pc
    from robots.snake import pipe_env, pipes

    slots = 16
    tracker = pipe_env.default_tracker(circle=True, line=False, circle_bin=2, near=True)
    env = pipe_env.PipeEnv(
        situation="lying-right",
        tracker=tracker,
        max_steps=slots * 5,
        random_phase=True,
        entry_memory=0.3,
        circle_every=4,
        circle_window=2,
    )
    controller = pc.machine_params(True, near=True)
    rec, depth, distance = _recorded_and_rolled_out(env, pipes.LYING, pipes.RIGHT, controller, slots)
    np.testing.assert_array_equal(rec["depth"], depth)
    found = rec["entry"].valid
    assert found.any() and not found[:, np.arange(slots) % 4 != 3].any()  # entries, only at the updates
    np.testing.assert_array_equal(rec["entry_distance"][found], distance[found])
