"""The hexapod's closed predator-prey loop: the env, its controllers and the reproduction's arithmetic."""

import math
from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from robots.hexapod import camera as cam
from robots.hexapod import controllers
from robots.hexapod import prey as prey_mod
from robots.hexapod import reproduce_prey as rp
from robots.hexapod.cpg import CPGWeights, cpg_init
from robots.hexapod.env import STEP_S, HexapodEnv, cpg_cycle
from robots.hexapod.gaits import PATTERNS
from spikejax.errors import UserError
from spikejax.neurons import DiscreteLIFParams


@pytest.fixture(scope="module")
def blind_env():
    return HexapodEnv(n_robots=2, seconds=4 * STEP_S, see=False, nthread=1)


def _scene(xy):
    xy = np.asarray(xy, np.float32).reshape(-1, 2)
    full = np.zeros((prey_mod.MAX_PREY, 2), np.float32)
    full[: len(xy)] = xy
    alive = np.arange(prey_mod.MAX_PREY) < len(xy)
    return prey_mod.PreyScene(jnp.zeros(3), jnp.asarray(full), jnp.full((prey_mod.MAX_PREY,), 0.1), jnp.asarray(alive))


@pytest.mark.slow
def test_mjx_backend_walks_the_loop_as_the_c_engine():
    """Three robots of the pool, six decisions of mixed gaits: the torso on MJX within 3 mm and 0.5 deg of MuJoCo C.

    Slow (~30 s, MJX compiles on a CPU): the suite keeps `test_hexapod_walk`'s MJX-against-C walk.

    Both start every decision from the same float32 state; contacts amplify
    the engines' rounding (0.3 mm measured at the sixth decision).
    """
    scenes = jax.tree.map(lambda *a: jnp.stack(a), *[_scene([[2.0, 0.1]])] * 3)
    keys = jax.random.split(jax.random.key(1), 3)
    gaits = [jnp.asarray(a, jnp.int32) for a in ([0, 1, 2],) * 3 + ([2, 0, 1],) * 3]
    torsos = {}
    for backend in ("mujoco", "mjx"):
        env = HexapodEnv(backend, n_robots=3, seconds=8 * STEP_S, see=False, nthread=1)
        assert env.backend == backend
        step, state = jax.jit(jax.vmap(env.step)), jax.jit(jax.vmap(env.reset))(keys, scenes)
        robots = np.asarray(state.info["robot"])
        rows = []
        for g in gaits:
            state = step(state, g)
            rows.append(np.asarray(state.info["torso"]))
        torsos[backend] = np.stack(rows)
    assert len(set(robots.tolist())) > 1  # different robots of the pool in one batch
    c, ours = torsos["mujoco"], torsos["mjx"]
    assert np.abs(ours[..., :3] - c[..., :3]).max() < 3e-3
    assert np.degrees(np.abs(ours[..., 3:] - c[..., 3:]).max()) < 0.5
    # The walk moved: G1 forward, G2 left, G3 right over the first three cycles.
    assert c[2, 0, 0] - c[0, 0, 0] > 0.1 and c[2, 1, 5] > c[0, 1, 5] and c[2, 2, 5] < c[0, 2, 5]


def test_an_unknown_backend_is_a_one_line_error():
    with pytest.raises(UserError, match="unknown hexapod physics backend 'brax'"):
        HexapodEnv("brax")


@pytest.mark.slow
def test_reset_and_step_shapes_and_a_batch_of_two_is_each_alone(blind_env):
    env = blind_env
    assert env.observation_size == 6 and env.action_size == 1 and env.backend == "mujoco"
    keys = jax.random.split(jax.random.key(3), 2)
    scenes = jax.tree.map(lambda *a: jnp.stack(a), _scene([[2.5, 0.1]]), _scene([[2.5, -0.3], [3.0, 0.4]]))
    step, reset = jax.jit(jax.vmap(env.step)), jax.jit(jax.vmap(env.reset))
    batch = reset(keys, scenes)
    assert batch.obs.shape == (2, 6)
    np.testing.assert_array_equal(batch.obs[:, :3], 0)  # no counts yet, G1 in force
    np.testing.assert_array_equal(batch.obs[:, 3:], [[1, 0, 0], [1, 0, 0]])
    actions = jnp.asarray([0, 2], jnp.int32)
    batch = step(step(batch, actions), actions)
    assert batch.info["torso"].shape == (2, 6) and batch.info["cpg_spikes"].shape == (2, 2, 6)
    for i in range(2):
        one = reset(keys[i : i + 1], jax.tree.map(lambda a: a[i : i + 1], scenes))
        one = step(step(one, actions[i : i + 1]), actions[i : i + 1])
        for field in ("phys", "torso", "cpg_spikes", "distance"):
            # A batch of 2 and a lone run differ by float32 rounding (about 1e-6 here), as the snake's do.
            np.testing.assert_allclose(
                np.asarray(one.info[field][0]), np.asarray(batch.info[field][i]), rtol=1e-5, atol=1e-5, err_msg=field
            )
    # Two G1 cycles walk forward (about 0.09 m a cycle); two G3 cycles turn right.
    x0 = float(env.torso0[int(batch.info["robot"][0])][0])
    assert 0.1 < float(batch.info["torso"][0, 0]) - x0 < 0.3
    assert float(batch.info["torso"][1, 5]) < math.radians(-10)


def test_cpg_cycle_resets_to_rest_at_a_gait_change_by_hand():
    # N1 driven at 0.6 by G1 and by G2, alpha 2, threshold 1: V = 0.6, 0.9 from rest; carried on, 0.45 + 0.6 = 1.05 fires.
    w_in = np.zeros((3, 6), np.float32)
    w_in[0, 0] = w_in[1, 0] = 0.6
    weights = CPGWeights(jnp.asarray(w_in), jnp.zeros((6, 6)))
    neuron = DiscreteLIFParams(alpha=jnp.float32(2.0), v_th=jnp.float32(1.0))
    cycle = jax.jit(cpg_cycle)
    state, rows = cycle(neuron, weights, cpg_init(), jnp.int32(0), jnp.int32(0))
    assert np.asarray(rows).sum() == 0 and float(state.neurons.v[0]) == pytest.approx(0.9)
    state, rows = cycle(neuron, weights, state, jnp.int32(0), jnp.int32(1))  # G1 -> G2: from rest
    assert np.asarray(rows).sum() == 0 and float(state.neurons.v[0]) == pytest.approx(0.9)
    state, rows = cycle(neuron, weights, state, jnp.int32(1), jnp.int32(1))  # G2 kept: carried, fires at once
    np.testing.assert_array_equal(np.asarray(rows)[:, 0], [1, 0])
    assert float(state.neurons.v[0]) == pytest.approx(0.6)


@pytest.mark.slow
def test_a_gait_change_resets_the_cpg_to_rest_and_a_kept_gait_does_not(blind_env):
    env = blind_env
    state = env.reset(jax.random.key(0), _scene([[2.0, 0.0]]))
    step = jax.jit(env.step)
    state = step(state, jnp.int32(0))
    np.testing.assert_array_equal(state.info["cpg_spikes"], PATTERNS[0])  # G1 from rest: {N2,N4,N6} -> {N1,N3,N5}
    state = step(state, jnp.int32(1))  # to G2: reset, so G2's pattern from rest at once
    np.testing.assert_array_equal(state.info["cpg_spikes"], PATTERNS[1])  # {N4,N6} -> {N5}
    state = step(state, jnp.int32(1))  # kept: the state carries on, and the pattern repeats
    np.testing.assert_array_equal(state.info["cpg_spikes"], PATTERNS[1])
    assert np.asarray(state.info["raster"])[:6].sum() == 6 + 3 + 3


def test_controllers_are_pure_pairs():
    state = SimpleNamespace(info={"wta": jnp.int32(2), "wta_ordered": jnp.int32(0), "truth_gait": jnp.int32(1)})
    key = jax.random.key(0)
    for (init, act), want in ((controllers.snn, 2), (controllers.snn_ordered, 0), (controllers.oracle, 1)):
        assert int(act(init(key), state)[1]) == want
    init, act = controllers.random
    c = init(key)
    draws = []
    for _ in range(60):
        c, a = act(c, state)
        draws.append(int(a))
    assert set(draws) == {0, 1, 2}
    again = act(init(key), state)[1]
    assert int(again) == draws[0]  # keyed: the same key gives the same gaits


def test_the_oracle_in_view_turns_by_depth_and_only_while_the_prey_is_in_the_cameras_view():
    init, act = controllers.oracle_in_view
    half = math.radians(0.5 * cam.HFOV_DEG)
    size = 0.03
    boundary = cam.D_NEAR + 0.5 * size  # near: depth along the camera's axis within this

    def state(bearing, distance, sizes=(size, size, size, size), nearest=0):
        scene = SimpleNamespace(size=jnp.asarray(sizes, jnp.float32))
        return SimpleNamespace(
            info={
                "bearing": jnp.float32(bearing),
                "distance": jnp.float32(distance),
                "scene": scene,
                "nearest": jnp.int32(nearest),
            }
        )

    gait = init(jax.random.key(0))
    assert int(gait) == 0  # starts forward, as the SNN does
    b = -0.9 * half  # in view, on the right
    gait, a = act(gait, state(b, 0.99 * boundary / math.cos(b)))  # depth just inside: near, turn right
    assert int(a) == 2
    gait, a = act(gait, state(b, 1.01 * boundary / math.cos(b)))  # depth just beyond (distance 1.4x): forward
    assert int(a) == 0
    gait, a = act(gait, state(0.5 * half, 0.5))  # near on the left
    assert int(a) == 1
    gait, a = act(gait, state(1.1 * half, 5.0))  # out of view: the left turn is held, far or not
    assert int(a) == 1
    # The boundary is the nearest prey's own: a 0.3 m cube in slot 2 is near 0.135 m further out.
    big = (size, size, 0.3, size)
    depth = cam.D_NEAR + 0.1
    assert int(act(0, state(b, depth / math.cos(b), big, nearest=2))[1]) == 2
    assert int(act(0, state(b, depth / math.cos(b), big, nearest=0))[1]) == 0


def test_summary_arithmetic_on_hand_made_episodes():
    # Four episodes of two prey: captured slot 0 at step 3; slot 1 at 2 then slot 0 at 5; none; slot 1 at 4.
    res = {
        "captures": np.array([[3, -1, -1, -1], [5, 2, -1, -1], [-1, -1, -1, -1], [-1, 4, -1, -1]]),
        "order": np.array([[0, -1, -1, -1], [1, 0, -1, -1], [-1, -1, -1, -1], [1, -1, -1, -1]]),
        "first_nearest": np.array([0, 0, 1, 1]),
        "steps": np.array([3, 5, 40, 10]),
        "alive0": np.tile([True, True, False, False], (4, 1)),
        "wall_s": 29.0,
    }
    row = dict(zip(rp.HEADER, rp.summarize("multi-2", "snn", res)))
    assert (row["episodes"], row["captured"], row["all_captured"], row["nearest_first"]) == (4, 3, 1, 2)
    assert row["capture_rate"] == 0.75 and row["nearest_first_rate"] == 0.5
    # Wilson's interval for 3 of 4 by hand: centre (0.75 + 1.92^2/8) / (1 + 1.92^2/4).
    z = 1.959963984540054
    centre = (0.75 + z**2 / 8) / (1 + z**2 / 4)
    half = z * math.sqrt(0.75 * 0.25 / 4 + z**2 / 64) / (1 + z**2 / 4)
    assert row["capture_ci_low"] == pytest.approx(centre - half, abs=1e-4)
    # First captures at steps 3, 2 and 4: a mean of 3 steps of 0.32 s.
    assert row["time_to_capture_s"] == pytest.approx(3 * STEP_S, abs=1e-3)
    assert row["decisions_per_sim_s"] == pytest.approx(1 / STEP_S, abs=1e-4)
    assert row["decisions_per_wall_s"] == pytest.approx(58 / 29.0)


def test_reach_rows_bin_captures_by_the_prey_s_initial_bearing_and_offset():
    """Three hand-placed prey from a start turned 90 deg left: bearings 0, 11.3 and 18.4 deg, offsets 0, 0.2, 0.5 m."""
    start = jnp.asarray([[1.0, 2.0, math.pi / 2]] * 3, jnp.float32)
    # Ahead is +y from this start and its left -x: 1 m ahead, 1 m ahead 0.2 m right, 1.5 m ahead 0.5 m left.
    prey = np.zeros((3, prey_mod.MAX_PREY, 2), np.float32)
    prey[:, 0] = [[1.0, 3.0], [1.2, 3.0], [0.5, 3.5]]
    scenes = prey_mod.PreyScene(start, jnp.asarray(prey), jnp.full((3, 4), 0.03), jnp.arange(4)[None].repeat(3, 0) < 1)
    bearing, lateral = rp.initial_offsets(scenes)
    np.testing.assert_allclose(
        bearing, [0.0, math.degrees(math.atan(0.2)), math.degrees(math.atan(0.5 / 1.5))], atol=1e-4
    )
    np.testing.assert_allclose(lateral, [0.0, 0.2, 0.5], atol=1e-6)
    rows = rp.reach_rows("snn", np.array([True, True, False]), scenes)
    assert all(len(r) == len(rp.REACH_HEADER) for r in rows)
    by = {(r[1], r[2]): r for r in rows}
    assert by[("bearing_deg", 0.0)][4:7] == [1, 1, 1.0]
    assert by[("bearing_deg", 10.0)][4:7] == [1, 1, 1.0]
    assert by[("bearing_deg", 15.0)][4:7] == [1, 0, 0.0]
    assert by[("bearing_deg", 5.0)][4:] == [0, 0, "", "", ""]
    assert by[("lateral_m", 0.2)][4:6] == [1, 1] and by[("lateral_m", 0.45)][4:6] == [1, 0]
    low, high = by[("lateral_m", 0.0)][7:9]
    assert 0.0 < low < 1.0 == high


def test_energy_rows_charge_1_7_nj_a_spike_and_restate_the_paper():
    totals = {"dvs": 1000, "filter": 100, "layer2": 20, "layer3": 4, "gait": 6, "drive": 20, "cpg": 60}
    rows = {(r[0], r[1]): r for r in rp.energy_rows(totals, steps=10, captures=2)}
    assert rows[("ours", "filter")][2] == 10.0 and rows[("ours", "filter")][3] == pytest.approx(10 * 1.7e-9)
    assert rows[("ours", "total_spikes")][2] == 21.0  # (100 + 20 + 4 + 6 + 20 + 60) / 10, no DVS events
    assert rows[("ours", "total_with_dvs_events")][4] == pytest.approx(1210 / 2)
    assert rows[("ours", "cpg")][5] == pytest.approx(30 * 1.7e-9)
    assert rows[("paper", "filter")][3] == pytest.approx(2.55e-3)  # 1.5e6 x 1.7 nJ
    assert rows[("paper", "cpg")][3] == pytest.approx(11.9e-9)  # 7 x 1.7 nJ
    assert rows[("paper", "total")][3] > 1e-3  # "sub-mJ" it is not


def test_gait_strings_and_edit_distance():
    gaits = np.array([0, 0, 0, 2, 2, 0, 0, 2, 1, 1])
    assert rp.gait_string(gaits, 10, [5, 8, -1, -1]) == "FFFRR|FFR|LL"
    assert rp.fig8_gaits(gaits, 10, [5, 8, -1, -1]) == "FFFRR|FFR"
    assert rp.edit_distance(rp.fig8_gaits(gaits, 10, [5, 8, -1, -1]), rp.PAPER_FIG8) == 0
    assert rp.edit_distance("FFFFRR|FFRR", rp.PAPER_FIG8) == 2
    assert rp.edit_distance("", "abc") == 3 and rp.edit_distance("kitten", "sitting") == 3


def test_the_fig8_layout_puts_object_1_nearest_and_object_2_beyond_it_on_the_right():
    pose = jnp.asarray([0.1, 0.0, 0.0])  # the camera of the robot at the origin
    dist, bearing = prey_mod.relative(rp.FIG8_SCENE, pose)
    assert int(np.argmin(np.asarray(dist))) == 0
    assert -25 < math.degrees(float(bearing[0])) < -10 and -32 < math.degrees(float(bearing[1])) < -24
    assert np.all(np.asarray(dist) > cam.D_NEAR + prey_mod.PREY_SIZE) and np.all(
        rp.FIG8_SCENE.size == prey_mod.PREY_SIZE
    )


def test_a_bad_scene_file_is_one_line_before_any_work(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[robot]\nx = 0.0\ny = 0.0\nyaw_deg = 0.0\n[[prey]]\nx = 1.0\n")
    with pytest.raises(UserError) as err:
        rp.run(out=tmp_path / "out", episodes=1, scene=str(bad))
    assert "no 'y'" in str(err.value) and "\n" not in str(err.value)
    assert not (tmp_path / "out").exists()
    with pytest.raises(UserError, match="cannot read"):
        rp.run(out=tmp_path / "out", episodes=1, scene=str(tmp_path / "missing.toml"))
    args = rp.command.parser("spikejax reproduce hexapod-prey").parse_args(
        ["--out", "D", "--scene", str(bad), "--episodes", "3", "--seconds", "3.2", "--backend", "mjx"]
    )
    assert (args.scene, args.episodes, args.seconds, args.backend) == (str(bad), 3, 3.2, "mjx")


def test_the_visual_snn_captures_more_often_than_random_gaits_on_the_same_scenes():
    # Prey 1.0-1.3 m ahead within 5 deg: the SNN walks on (G1 wins on far prey) and takes them; random gaits wander.
    env = HexapodEnv(n_robots=4, seconds=10 * STEP_S)
    keys = rp.episode_keys(7, 6)
    scenes = jax.vmap(lambda k: prey_mod.sample_scene(k, 1, distance=(1.0, 1.3), bearing_deg=5.0))(keys)
    caught = {}
    for name in ("snn", "random"):
        e = env if name == "snn" else HexapodEnv(n_robots=4, seconds=10 * STEP_S, see=False)
        res = rp.run_episodes(e, controllers.CONTROLLERS[name], scenes, keys, batch=6, progress=False)
        caught[name] = int((res["captures"] >= 0).any(axis=1).sum())
    assert caught["snn"] > caught["random"], caught
