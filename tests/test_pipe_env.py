"""The closed pipe loop (`robots.snake.pipe_env`, `robots.snake.pipe_controller`): the spiking detector steers.

One compiled program runs a small batch: standing pipes 1.3 m ahead and
0.6 m to either side (going straight passes them more than 0.3 m away:
0.6 - 0.125 m of radius, less the head's swing of about 0.09 m), each driven
by the paper's bang-bang law on the spiking detector's output and by going
straight, for 16 s. The detector is the paper's (128 x 128 camera, 180 x 180
line grid, sync, slots of 5 steps), nothing reduced.
"""

from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from robots.snake import pipe_controller as pc
from robots.snake import pipe_env, pipes
from robots.snake.gait import gait_params, gait_period, joint_targets
from spikejax.errors import UserError

SLOTS = 160  # 800 control steps, 16 s
PLACEMENTS = ((1.3, 0.6), (1.3, -0.6))  # (ahead, right of the snake), m; at 0.7 m the loop reaches neither in 16 s


def _scene(ahead, right):
    scene = pipes.sample(jax.random.key(0), pipes.STANDING, pipes.RIGHT)
    return scene._replace(xy=jnp.array([[ahead, -right]], jnp.float32))


@pytest.fixture(scope="module")
def env():
    return pipe_env.PipeEnv()


@pytest.fixture(scope="module")
def batch(env):
    """Bang-bang and go-straight on the same placements, and the first episode again at the end, in one
    program."""
    n = len(PLACEMENTS)
    scenes = jax.tree.map(lambda *a: jnp.stack(a), *[_scene(*p) for p in PLACEMENTS] * 2, _scene(*PLACEMENTS[0]))
    which = jnp.array([pc.CONTROLLERS["bang-bang"]] * n + [pc.CONTROLLERS["straight"]] * n + [0])
    keys = jnp.stack([jax.random.key(7)] * (2 * n + 1))
    machine = pc.ControllerParams()

    def episode(key, scene, w):
        return pipe_env.rollout(env, pc.switch, pc.SwitchParams(machine, w), key, SLOTS, scene)

    return jax.jit(jax.vmap(episode))(keys, scenes, which)


def test_spiking_bang_bang_reaches_pipes_that_going_straight_misses(batch):
    record, final = batch
    n = len(PLACEMENTS)
    success = np.asarray(final.metrics["success"])[: 2 * n] > 0
    spiking, straight = success[:n], success[n:]
    assert straight.sum() == 0  # the placements are out of reach without steering
    assert spiking.all()  # measured: at steps 735 and 681 of 800
    # The detector saw the pipe, and a success is the head within 0.3 m of the pipe's surface, never a collision.
    assert np.all(np.asarray(record["metrics"]["detected"][:n]).sum(axis=1) >= 20)
    assert np.all(np.asarray(final.metrics["collided"]) == 0)
    step = np.asarray(final.info["success_step"])
    head = np.asarray(record["head"])
    for i in np.flatnonzero(success):
        ahead, right = PLACEMENTS[i % n]
        gap = np.hypot(head[i, step[i] - 1, 0] - ahead, head[i, step[i] - 1, 1] + right) - 0.125
        assert gap <= 0.3 + 1e-5
        assert np.asarray(record["done"][i, step[i] - 1]) == 1.0


def test_steering_follows_the_side_of_the_pipe(batch):
    record, _ = batch
    action = np.asarray(record["action"])
    n = len(PLACEMENTS)
    for i, (_, right) in enumerate(PLACEMENTS):
        first = action[i][action[i] != 0][:25]  # the first detections' C
        assert np.mean(np.sign(first) == np.sign(right)) >= 0.8
    assert np.all(action[n : 2 * n] == 0)  # going straight never steers


def test_the_same_episode_anywhere_in_a_batch_is_the_same_trial(batch):
    record, final = batch
    same = lambda a: np.testing.assert_array_equal(np.asarray(a[0]), np.asarray(a[-1]))  # noqa: E731
    jax.tree.map(same, record)
    jax.tree.map(same, final.metrics)


def test_without_vision_the_same_physics_runs_and_nothing_is_detected(batch):
    """``PipeEnv(vision=False)``, the baselines' env, steps the same snakes as the full env, step for step:
    the going-straight episodes of the batch again (the same batch of five), with no camera or detector."""
    blind = pipe_env.PipeEnv(vision=False)
    n = len(PLACEMENTS)
    scenes = jax.tree.map(lambda *a: jnp.stack(a), *[_scene(*p) for p in PLACEMENTS] * 2, _scene(*PLACEMENTS[0]))
    which = jnp.array([pc.CONTROLLERS["bang-bang"]] * n + [pc.CONTROLLERS["straight"]] * n + [0])
    keys = jnp.stack([jax.random.key(7)] * (2 * n + 1))

    def episode(key, scene, w):
        return pipe_env.rollout(blind, pc.switch, pc.SwitchParams(pc.ControllerParams(), w), key, SLOTS, scene)

    record, final = jax.jit(jax.vmap(episode))(keys, scenes, which)
    seen, _ = batch
    straight = slice(n, 2 * n)
    np.testing.assert_array_equal(np.asarray(record["head"][straight]), np.asarray(seen["head"][straight]))
    for name in ("depth", "lateral", "success", "reached"):
        np.testing.assert_array_equal(
            np.asarray(record["metrics"][name][straight]), np.asarray(seen["metrics"][name][straight]), err_msg=name
        )
    assert not np.asarray(record["metrics"]["detected"]).any()
    assert np.all(np.asarray(record["action"]) == 0)  # the spiking controller, blind, never steers
    ends = np.asarray(final.info["control_steps"]) == SLOTS * blind.slot_steps
    assert ends.all()


@pytest.mark.slow  # 14 s: two more compiles (the fast budget is spent above)
def test_an_episode_alone_steers_as_in_a_batch(env):
    """Alone and in a batch of two, the first 4 slots make the same detections and actions; the C physics
    of a lone snake and of a batch member differ by float rounding that the floor contacts amplify
    (measured: 4e-4 m after 20 steps with the same actions), so the heads agree to 1 mm, not bit for bit."""
    scenes = jax.tree.map(lambda *a: jnp.stack(a), _scene(*PLACEMENTS[0]), _scene(*PLACEMENTS[1]))
    keys = jnp.stack([jax.random.key(7)] * 2)
    params = pc.ControllerParams()

    def episode(key, scene):
        return pipe_env.rollout(env, pc.bang_bang, params, key, 4, scene)[0]

    together = jax.jit(jax.vmap(episode))(keys, scenes)
    alone = jax.jit(episode)(keys[0], jax.tree.map(lambda a: a[0], scenes))
    np.testing.assert_allclose(np.asarray(alone["head"]), np.asarray(together["head"][0]), atol=1e-3)
    np.testing.assert_array_equal(np.asarray(alone["action"]), np.asarray(together["action"][0]))
    for name in ("control", "detected"):
        np.testing.assert_array_equal(np.asarray(alone["metrics"][name]), np.asarray(together["metrics"][name][0]))


def test_bad_arguments_are_one_line_errors():
    with pytest.raises(UserError, match="situation"):
        pipe_env.PipeEnv(situation="floating")
    with pytest.raises(UserError, match="max_steps"):
        pipe_env.PipeEnv(max_steps=0)
    with pytest.raises(UserError, match="event_threshold"):
        pipe_env.PipeEnv(event_threshold=2.0)
    with pytest.raises(UserError, match="line grid, the circle grid"):
        pipe_env.default_tracker(circle=False, line=False)
    entry_only = pipe_env.default_tracker(circle=True, line=False)  # the lying pipes' detector: the entry steers
    assert entry_only.detector.line is None and entry_only.target == "entry"
    from robots.snake import reproduce_pipe as rp

    with pytest.raises(UserError, match="--lead"):
        rp.run(None, 1, 1.0, lead=-0.5)
    with pytest.raises(UserError, match="entry_memory"):
        pipe_env.PipeEnv(entry_memory=1.5)
    with pytest.raises(UserError, match="--entry-memory"):
        rp.run(None, 1, 1.0, entry_memory=-0.1)
    with pytest.raises(UserError, match="circle_every > 1 needs"):
        pipe_env.PipeEnv(circle_every=2)  # the standing pipes' line grid
    with pytest.raises(UserError, match="circle_every must be"):
        pipe_env.PipeEnv(circle_every=0)
    every = pipe_env.PipeEnv(situation="lying-right", tracker=entry_only, circle_every=2)
    with pytest.raises(UserError, match="whole groups of circle_every = 2 slots, not 3"):
        pipe_env.rollout(every, pc.bang_bang, pc.ControllerParams(), jax.random.key(0), 3)
    with pytest.raises(UserError, match="--circle-every"):
        rp.run(None, 1, 1.0, circle_every=3)
    with pytest.raises(UserError, match="circle_window must be"):
        pipe_env.PipeEnv(situation="lying-right", tracker=entry_only, circle_every=2, circle_window=3)
    with pytest.raises(UserError, match="--circle-window"):
        rp.run(None, 1, 1.0, circle_every=4, circle_window=0)
    # A group of four slots whose update sees the last two: the first two slots' events are dropped.
    window = pipe_env.PipeEnv(situation="lying-right", tracker=entry_only, circle_every=4, circle_window=2)
    assert window.circle_schedule() == ((False, False), (False, False), (False, True), (True, True))
    assert every.circle_schedule() == ((False, True), (True, True))  # the window defaults to all the group


def test_failure_labels_take_the_first_cause_that_applies():
    from robots.snake.reproduce_pipe import LABELS, label_failures

    # Episodes: a success; never detected; a lying pipe approached but not entered; steering mostly
    # against the pipe's side; passed the pipe; lost for long; still approaching.
    success = np.array([1, 0, 0, 0, 0, 0, 0], bool)
    approached = np.array([1, 0, 1, 0, 0, 0, 0], bool)
    lying = np.array([0, 0, 1, 0, 0, 0, 0], bool)
    detected = np.array([9, 0, 9, 9, 9, 9, 9])
    sign_right = np.array([1.0, 0.0, 1.0, 0.2, 0.9, 0.9, 0.9])
    depth_end = np.array([0.2, -1.0, 0.1, -1.0, -0.5, 0.8, 0.8])
    last_seen = np.array([0, 10**9, 0, 0, 20, 20, 1])
    labels = label_failures(success, approached, lying, detected, sign_right, depth_end, last_seen, 8)
    names = [None if i < 0 else LABELS[i] for i in labels]
    assert names == [None, "never_detected", "missed_bore", "wrong_side", "overshoot", "lost", "timeout"]


def test_a_straight_lane_has_passed_its_target_once_it_is_a_margin_behind_along_the_course():
    from robots.snake.reproduce_pipe import passed

    start = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 1.6], [1.0, 1.0, 0.0]])
    head = np.array([[3.0, 0.0], [2.0, 0.0], [0.5, 0.0], [0.0, 3.0], [1.0, 1.0]])
    target = np.array([[1.5, 0.5], [1.5, 0.5], [-1.0, 0.0], [0.3, 1.9], [0.0, 0.0]])
    # Along the course: 1.5 m behind; 0.5 m behind; moved only 0.5 m; 1.1 m behind (course along +y); not moved.
    np.testing.assert_array_equal(passed(head, start, target, 1.0), [True, False, False, True, False])
    np.testing.assert_array_equal(passed(head, start, target, 0.4), [True, True, True, True, False])


def test_detection_rate_counts_slots_in_view_and_the_rest_apart():
    from robots.snake.reproduce_pipe import HEADER, summarize

    # One episode of 4 slots (5 steps each) ending at step 18: slot ends 4, 9, 14 count, 19 does not.
    # In view at 4 and 9; detections at 4, 14 (out of view) and 19 (after the end).
    z = np.zeros((1, 20), np.float32)
    detected, in_view = z.copy(), z.copy()
    detected[0, [4, 14, 19]] = 1.0
    in_view[0, [4, 9]] = 1.0
    res = dict(
        success=np.array([True]), reached=np.array([True]), end_step=np.array([18]), detected=detected,
        in_view=in_view, d_est=z + 1.0, depth=z + 1.5, offset_est=z + 0.2, offset_true=z + 0.3,
        action=z + 1.0,
    )  # fmt: skip
    row = dict(zip(HEADER, summarize("s", "bang-bang", res, False, 0.02, 5, 100)))
    assert row["detection_rate"] == 0.5  # 1 of the 2 slots in view
    assert row["out_of_view_share"] == 0.5  # 1 of the 2 detections that count
    assert row["mean_distance_error_m"] == 0.5 and row["mean_time_to_success_s"] == 18 * 0.02


def test_distance_table_bins_the_errors_by_true_depth_and_kind():
    from robots.snake.reproduce_pipe import DISTANCE_BINS, distance_rows

    # Two episodes of 6 steps; the second ends after 4. Detections (d_est > 0) at known depths.
    res = {
        "detected": np.array([[1, 1, 0, 1, 1, 1], [1, 1, 1, 0, 1, 1]], float),
        "entry_detected": np.array([[0, 0, 0, 1, 1, 0], [0, 0, 0, 0, 1, 1]], float),
        "depth": np.array([[0.7, 1.2, 9.0, 2.2, 0.8, 3.5], [0.6, 2.9, 1.1, 9.0, 9.0, 9.0]]),
        "d_est": np.array([[0.8, 1.0, 0.0, 2.0, 0.9, 3.0], [0.6, 2.6, 0.0, 0.0, 5.0, 5.0]]),
        "end_step": np.array([6, 4]),
    }
    rows = {(r[2], r[3], r[4]): r for r in distance_rows("s", "bang-bang", res)}
    # Body: errors 0.1 at 0.7 and 0.0 at 0.6 (bin 0.5-1), 0.2 at 1.2 (1-1.5), 0.3 at 2.9 (2.5-3), 0.5 at 3.5;
    # d_est 0 at 1.1 is no estimate, and the second episode's steps 5-6 come after its end.
    assert rows[("body", 0.5, 1.0)][5:8] == [2, pytest.approx(0.05), pytest.approx(0.05)]
    assert rows[("body", 1.0, 1.5)][5:7] == [1, pytest.approx(0.2)]
    assert rows[("body", 2.5, 3.0)][5:7] == [1, pytest.approx(0.3)]
    assert rows[("body", 3.0, 4.0)][5:7] == [1, pytest.approx(0.5)]
    assert rows[("body", 0.5, 1.0)][8] == pytest.approx((0.1 / 0.7 + 0.0) / 2)
    assert DISTANCE_BINS[-1] == (0.5, 3.0) and rows[("body", 0.5, 3.0)][5:7] == [4, pytest.approx(0.6 / 4)]
    # Entry: 0.2 at 2.2 and 0.1 at 0.8.
    assert rows[("entry", 0.5, 1.0)][5:7] == [1, pytest.approx(0.1)] and rows[("entry", 2.0, 2.5)][5:7] == [
        1,
        pytest.approx(0.2),
    ]
    assert rows[("entry", 1.5, 2.0)][5] == 0


@pytest.mark.slow  # 40-60 s, mostly compiling a second loop and the figures' recording
def test_reproduce_with_a_scene_file_writes_one_row_per_pipe(tmp_path):
    import csv

    from robots.snake.reproduce_pipe import DISTANCE_HEADER, HEADER, LABELS, reproduce_command_run
    from spikejax.stats import wilson_interval

    scene = tmp_path / "scene.toml"
    scene.write_text(
        '[snake]\nx = 0.0\ny = 0.0\nyaw_deg = 0.0\n\n[[pipe]]\nkind = "standing"\nx = 1.3\ny = -0.6\n'
        "radius = 0.125\nlength = 2.0\n"
    )
    out = tmp_path / "out"
    assert reproduce_command_run(out=out, episodes=2, seconds=2.0, scene=str(scene), no_progress=True) == 0
    with open(out / "snake_pipe.csv") as f:
        rows = list(csv.reader(f))
    assert rows[0] == HEADER and len(rows) == 4  # the spiking controller, then the two baselines on the same episodes
    assert [r[1] for r in rows[1:]] == ["bang-bang", "straight", "privileged"]
    row = dict(zip(HEADER, rows[1]))
    assert row["situation"] == "pipe 1 (standing)" and int(row["episodes"]) == 2
    k = int(row["successes"])
    low, high = wilson_interval(k, 2)
    assert float(row["wilson_low"]) == pytest.approx(float(low)) and float(row["wilson_high"]) == pytest.approx(
        float(high)
    )
    # 2 s from 1.3 m: not reached by either start phase; every failure has one label, the same for both.
    assert k == 0
    fails = [int(row[f"fail_{label}"]) for label in LABELS]
    assert sum(fails) == 2 and max(fails) == 2
    assert (out / "snake_pipe_trajectories.png").stat().st_size > 0
    with open(out / "snake_pipe_distance.csv") as f:
        assert next(csv.reader(f)) == DISTANCE_HEADER
    # The Fig. 5-7 counterparts; Eqs. (4)-(6) follow the camera's swing (RMSE within a quarter of it).
    for name in ("snake_pipe_camera_offset.png", "snake_pipe_detections.png", "snake_pipe_width_distance.png"):
        assert (out / name).stat().st_size > 0
    with open(out / "snake_pipe_camera_offset.csv") as f:
        offset = {r["curve"]: r for r in csv.DictReader(f)}
    assert float(offset["eq_4_6"]["rmse_share"]) <= 0.25 and float(offset["eq_4_6"]["correlation"]) >= 0.9
    with open(out / "snake_pipe_width_distance.csv") as f:
        approach = list(csv.DictReader(f))
    assert [r["name"] for r in approach] == ["pipe 1 (standing)"]


@pytest.mark.slow  # about 40 s: two batch shapes compiled
def test_refilled_lanes_give_each_episode_the_trial_it_gets_alone(monkeypatch):
    """`reproduce_pipe._episodes` restarts a finished lane with the next episode, and runs a lone episode beside its
    copy: nothing about an episode changes."""
    from robots.snake import reproduce_pipe as rp

    monkeypatch.setattr(rp, "SEGMENT", 4)  # slots a batch runs between refills
    slots = 12
    env = pipe_env.PipeEnv(max_steps=slots * 5)
    # Episode 0 starts 0.35 m from a pipe (the head is already within 0.3 m of its surface: done in the
    # first segment), the others at the test placements: its lane takes episode 2 after one segment.
    scenes = [_scene(0.35, 0.0), _scene(*PLACEMENTS[0]), _scene(*PLACEMENTS[1])]
    scenes = jax.tree.map(lambda *a: jnp.stack(a), *scenes)
    keys = jax.random.split(jax.random.key(3), 3)
    params = rp._switch_params(pc.ControllerParams(), "bang-bang", 3)
    refilled = rp._episodes(env, scenes, keys, slots, params, False, "", size=2)
    alone = rp._episodes(env, scenes, keys, slots, params, False, "", size=3)
    first = jax.tree.map(lambda a: a[1:2], (scenes, keys, params))  # alone in the run: beside its copy
    lone = rp._episodes(env, first[0], first[1], slots, first[2], False, "", size=1)
    assert refilled["end_step"][0] <= 4 * 5 and refilled["success"][0]
    assert list(refilled["end_step"][1:]) == [slots * 5] * 2  # the others run to the end
    for name in alone:
        np.testing.assert_array_equal(refilled[name], alone[name], err_msg=name)
        np.testing.assert_array_equal(lone[name], alone[name][1:2], err_msg=name)


def test_action_1_narrows_the_gaits_lateral_amplitude_only():
    """``action[1] = 1`` scales ``A_o`` of Eq. (1) by ``narrow``, halfway by half of it; 0 and negative leave the
    gait alone. Compared uncompensated, where the lateral joints are Eq. (1) itself."""
    gait = gait_params()
    params = pipe_env.PipeEnvParams(jnp.float32(0.1), jnp.float32(0.05), jnp.float32(0.4))
    t = 1.3
    full = np.asarray(joint_targets(gait, t, 0.1, 0.0, compensate=False))
    odd = np.arange(16) % 2 == 0  # joints 1, 3, ... (lateral) at even indices
    for a1, factor in ((1.0, 0.4), (0.5, 0.7), (0.0, 1.0), (-1.0, 1.0)):
        got = np.asarray(pipe_env.gait_targets(gait, params, t, jnp.array([1.0, a1]), compensate=False))
        np.testing.assert_allclose(got[odd], (full[odd] - 0.1) * factor + 0.1, atol=1e-6)
        np.testing.assert_allclose(got[~odd], full[~odd], atol=1e-6)
    with pytest.raises(UserError, match="narrow"):
        pipe_env.PipeEnv(narrow=0.0)


def test_half_a_period_later_the_gait_steered_the_other_way_is_the_mirror_image():
    """Why ``random_phase`` makes a scene and its mirror the same task: at ``t + T/2`` with ``-C_o`` every lateral
    target (and the head's compensation) changes sign and every dorsal one is unchanged."""
    gait = gait_params()
    params = pipe_env.PipeEnvParams(jnp.float32(0.1), jnp.float32(0.05), jnp.float32(0.5))
    half = 0.5 * float(gait_period(gait))
    lateral = np.arange(16) % 2 == 0  # joints 1, 3, ... at even indices
    for t, c in ((0.0, 1.0), (0.37, -1.0), (1.9, 0.5)):
        now = np.asarray(pipe_env.gait_targets(gait, params, t, jnp.array([c, 0.0])))
        later = np.asarray(pipe_env.gait_targets(gait, params, t + half, jnp.array([-c, 0.0])))
        np.testing.assert_allclose(later[lateral], -now[lateral], atol=2e-5)
        np.testing.assert_allclose(later[~lateral], now[~lateral], atol=2e-5)


def test_random_phase_draws_each_episodes_start_phase_from_its_key():
    """Over one period, different for different keys, the same for the same key; 0 without ``random_phase``. The
    physics follows: 0.5 s of straight slithering ends elsewhere from another phase."""
    kw = dict(situation="lying-left", vision=False, max_steps=50)
    on, off = pipe_env.PipeEnv(random_phase=True, **kw), pipe_env.PipeEnv(**kw)
    keys = jax.random.split(jax.random.key(5), 8)

    def head_after(env, keys):
        def one(s, _):
            return env.step(s, jnp.zeros(2), slot_end=False), None

        def trial(key):
            first = env.reset(key)
            last = jax.lax.scan(one, first, None, length=25)[0]
            return first.info["gait_t0"], last.pipeline_state.head_pos[:2]

        return jax.vmap(trial)(keys)

    run = jax.jit(head_after, static_argnums=0)
    t0, heads = map(np.asarray, run(on, jnp.concatenate([keys, keys[:1]])))  # the first key again, last
    period = float(gait_period(on.gait))
    assert t0[-1] == t0[0] and np.all(heads[-1] == heads[0])
    t0 = t0[:-1]
    assert np.all((t0 >= 0) & (t0 < period)) and np.unique(t0).size == 8 and np.ptp(t0) > 0.5 * period
    assert np.linalg.norm(heads[0] - heads[1]) > 1e-3
    t0_off, heads_off = map(np.asarray, run(off, keys[:2]))
    assert np.all(t0_off == 0.0)
    np.testing.assert_array_equal(heads_off[0], heads_off[1])


def _slot_state(seen: bool, control: float, d_est: float, offset: float | None = None, side: float = 0.0):
    """What `pc.bang_bang` reads of the env's state after a slot's end: a body detection (or none), Alg. 3's estimates
    (``side``: its ``pipeOffset``, across the camera's axis)."""
    valid = jnp.asarray(seen)
    slot = SimpleNamespace(
        body=SimpleNamespace(valid=valid), entry=SimpleNamespace(valid=jnp.asarray(False)), control=jnp.float32(control)
    )
    offset = 0.1 * control if offset is None else offset
    info = {
        "slot": slot,
        "ended": jnp.asarray(True),
        "d_est": jnp.float32(d_est),
        "offset_est": jnp.float32(offset),
        "side_est": jnp.float32(side),
        "mem_ok": jnp.asarray(False),
        "mem_side": jnp.float32(0.0),
    }
    return SimpleNamespace(info=info)


@pytest.mark.slow  # about 35 s: two trackers' rollouts (the ring above the image: test_detect.py, in the suite)
def test_the_near_circle_grid_keeps_a_lying_entry_in_sight_to_0_3_m(tmp_path):
    """``default_tracker(near=True)``: snaking at a lying entry 1 m ahead, the ring is found in most slots between
    0.3 and 0.6 m of true depth, where the grid of radii up to 66 px (its centres on the image) loses it."""
    scene = tmp_path / "lying.toml"
    scene.write_text(
        '[snake]\nx = 0.0\ny = 0.0\nyaw_deg = 0.0\n\n[[pipe]]\nkind = "lying"\nx = 1.0\ny = 0.0\n'
        "yaw_deg = 180.0\nradius = 0.26\nwall = 0.01\nlength = 3.0\n"
    )
    scene = pipes.load_scene(scene)
    found = {}
    for near in (True, False):
        tracker = pipe_env.default_tracker(circle=True, line=False, circle_bin=2, near=near)
        env = pipe_env.PipeEnv(scene=scene, tracker=tracker)
        machine = pc.machine_params(True, near=near)
        record, _ = jax.jit(lambda k: pipe_env.rollout(env, pc.bang_bang, machine, k, 100))(jax.random.key(0))
        m = jax.device_get(record["metrics"])
        ends = np.arange(len(m["depth"])) % env.slot_steps == env.slot_steps - 1
        depth, seen = m["depth"][ends], m["entry_detected"][ends]
        near_ones = (depth >= 0.3) & (depth < 0.6)
        assert near_ones.sum() >= 10
        found[near] = seen[near_ones].mean()
    assert found[True] >= 0.8 and found[False] <= 0.5, found


def test_the_lead_aims_past_the_centre_on_the_side_first_seen():
    """``C = sign(offset + lead * side)`` with ``side`` the sign of the first detection's offset, kept after it;
    ``lead = 0`` follows the detector's C."""
    init, act = pc.bang_bang
    params = pc.ControllerParams(lead=0.25)
    cs = init()
    for offset, c in ((-0.6, -1.0), (0.1, -1.0), (0.2, -1.0), (0.3, 1.0), (-0.2, -1.0)):
        cs, action = act(params, cs, _slot_state(True, np.sign(offset), 3.0, offset))
        assert float(action[0]) == c and float(cs.side) == -1.0
    cs, action = act(pc.ControllerParams(), init(), _slot_state(True, 1.0, 3.0, -0.5))
    assert float(action[0]) == 1.0  # the detector's C, whatever the offset says


def test_the_camera_frame_steers_by_the_side_across_the_optical_axis():
    """``camera_frame = 1``: ``C = sign(pipeOffset)`` (``info["side_est"]``), whatever ``cameraOffset`` adds;
    with a lead, past the centre on the side first seen in that frame."""
    init, act = pc.bang_bang
    cs, action = act(pc.ControllerParams(camera_frame=1.0), init(), _slot_state(True, 1.0, 3.0, 0.3, side=-0.05))
    assert float(action[0]) == -1.0 and float(cs.side) == -1.0
    params = pc.ControllerParams(camera_frame=1.0, lead=0.1)
    cs = init()
    for side, c in ((0.2, 1.0), (-0.05, 1.0), (-0.15, -1.0)):
        cs, action = act(params, cs, _slot_state(True, -1.0, 3.0, -0.4, side=side))
        assert float(action[0]) == c and float(cs.side) == 1.0


def test_the_remembered_entry_is_placed_by_the_cameras_pose_and_seen_from_the_next():
    """`pipe_env.remember_entry` and `entry_in_view` by hand: a camera facing +y sees the entry 2 m ahead and 0.5 m
    to its right, at (1.5, 4); from (1.5, 3) facing +x it is 1 m to the left, straight abeam."""
    along_y = jnp.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # columns: forward, left, up
    along_x = jnp.eye(3)
    pos = jnp.array([1.0, 2.0, 0.05])
    empty = jnp.zeros(3)
    mem, ok = pipe_env.remember_entry(empty, jnp.asarray(False), jnp.asarray(True), pos, along_y, 2.0, 0.5, 0.3)
    np.testing.assert_allclose(mem, [1.5, 4.0, 0.05], atol=1e-6)  # the first detection taken whole
    assert bool(ok)
    np.testing.assert_allclose(pipe_env.entry_in_view(mem, pos, along_y), (2.0, 0.5), atol=1e-6)
    np.testing.assert_allclose(
        pipe_env.entry_in_view(mem, jnp.array([1.5, 3.0, 0.05]), along_x), (0.0, -1.0), atol=1e-6
    )
    # A second detection 0.2 m further right moves it by the weight; none leaves it.
    moved, _ = pipe_env.remember_entry(mem, ok, jnp.asarray(True), pos, along_y, 2.0, 0.7, 0.3)
    np.testing.assert_allclose(moved, [1.56, 4.0, 0.05], atol=1e-6)
    kept, ok2 = pipe_env.remember_entry(mem, ok, jnp.asarray(False), pos, along_y, 2.0, 0.7, 0.3)
    np.testing.assert_array_equal(kept, mem)
    assert bool(ok2)
    _, none = pipe_env.remember_entry(empty, jnp.asarray(False), jnp.asarray(False), pos, along_y, 2.0, 0.7, 0.3)
    assert not bool(none)


def test_with_memory_every_slot_end_steers_by_the_remembered_side():
    """``memory = 1``: at a slot's end ``C = sign(info["mem_side"])`` once the env remembers an entry, with or without
    a detection this slot; between slot ends, before there is a memory, or with ``memory = 0``: as before."""
    init, act = pc.bang_bang
    params = pc.ControllerParams(camera_frame=1.0, memory=1.0)
    cs, action = act(params, init(), _slot_state(True, 1.0, 3.0, side=0.3))
    assert float(action[0]) == 1.0  # no memory yet: the detection's side

    def with_memory(state, side, ended=True):
        state.info.update(mem_ok=jnp.asarray(True), mem_side=jnp.float32(side), ended=jnp.asarray(ended))
        return state

    cs, action = act(params, cs, with_memory(_slot_state(True, 1.0, 3.0, side=0.3), -0.2))
    assert float(action[0]) == -1.0  # the memory, against this slot's detection
    cs, action = act(params, cs, with_memory(_slot_state(False, 0.0, 3.0), 0.1))
    assert float(action[0]) == 1.0  # nothing seen this slot: still the memory
    cs, action = act(params, cs, with_memory(_slot_state(False, 0.0, 3.0), -0.1, ended=False))
    assert float(action[0]) == 1.0  # between slot ends the C in force is held
    plain = pc.ControllerParams(camera_frame=1.0)
    cs, action = act(plain, init(), with_memory(_slot_state(True, 1.0, 3.0, side=0.3), -0.2))
    assert float(action[0]) == 1.0


def test_the_blind_stretch_goes_straight_narrowed_for_its_dead_reckoned_time():
    """APPROACH follows the detection's C at full width; a detection nearer than ``final_distance`` starts FINAL:
    C = 0, ``action[1] = narrow``, for ``final_distance / speed + margin`` s of 20 ms steps, then INSIDE, still
    narrowed; later detections change nothing."""
    params = pc.ControllerParams(final_distance=0.5, speed=0.1, margin=0.04, narrow=0.75)
    init, act = pc.bang_bang
    cs, action = act(params, init(), _slot_state(True, -1.0, 1.2))
    assert int(cs.mode) == pc.APPROACH and action.tolist() == [-1.0, 0.0]
    cs, action = act(params, cs, _slot_state(True, 1.0, 0.45))
    assert int(cs.mode) == pc.FINAL and action.tolist() == [0.0, 0.75]
    blind = 1
    while int(cs.mode) == pc.FINAL:
        cs, action = act(params, cs, _slot_state(True, 1.0, 0.3))
        assert action.tolist() == [0.0, 0.75]
        blind += int(cs.mode) == pc.FINAL
    assert int(cs.mode) == pc.INSIDE
    assert abs(blind - (0.5 / 0.1 + 0.04) / pc.DT) <= 1  # steps in FINAL: 252, give or take float32's countdown
