"""The snake env: Brax's shapes and wrappers, jit and vmap, Eq. (12) at the start, the head camera and its events."""

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from brax.envs.base import Env, State

from robots.snake import camera as cam
from robots.snake import tracks
from robots.snake.env import TURN_THRESHOLD, SnakeEnv, steering_offset
from robots.snake.gait import gait_params
from spikejax.errors import UserError
from spikejax.vision import dvs, render


@pytest.fixture(scope="module")
def env():
    return SnakeEnv("ladder", backend="mujoco", event_capacity=1024)


@pytest.fixture(scope="module")
def steps(env):
    """Three snakes stepped 30 times with different constant actions, batched and one by one."""
    actions = jnp.array([[0.0, 0.0], [1.0, 0.0], [-0.5, 0.8]])

    def run(action):
        def body(state, _):
            state = env.step(state, action)
            return state, (state.obs, state.reward, state.metrics["events"])

        return jax.lax.scan(body, env.reset(jax.random.PRNGKey(0)), None, length=30)

    batched = jax.jit(jax.vmap(run))(actions)
    single = jax.jit(run)(actions[2])
    return batched, single


def test_brax_env_interface(env):
    assert isinstance(env, Env)
    state = env.reset(jax.random.PRNGKey(0))
    assert isinstance(state, State)
    assert state.obs.shape == (env.observation_size,) == (18,)
    assert env.action_size == 2 and env.backend == "mujoco"
    after = jax.jit(env.step)(state, jnp.zeros(env.action_size))
    assert after.reward.shape == () and after.done.shape == ()
    assert set(after.metrics) == set(state.metrics)  # Brax's wrappers need the same keys before and after
    assert jax.tree.structure(after.info) == jax.tree.structure(state.info)
    assert after.info["events"].capacity == 1024
    assert float(after.pipeline_state.time) == pytest.approx(env.dt)


def test_target_starts_straight_ahead(env):
    state = env.reset(jax.random.PRNGKey(0))
    head = np.asarray(state.pipeline_state.head_pos)
    target = np.asarray(state.info["target_xy"])
    assert np.linalg.norm(target - head[:2]) == pytest.approx(tracks.SPAWN_DISTANCE, abs=1e-5)
    np.testing.assert_allclose(state.obs[:2], 0.0, atol=1e-5)  # a_head = a_body = 0 (Eq. 12)
    # ... and the camera sees it in the middle column of its first frame.
    col, row = render.project(
        cam.HEAD_CAMERA, head, state.pipeline_state.head_mat, jnp.array([*target, tracks.TARGET_RADIUS])
    )
    assert col == pytest.approx(64.0, abs=0.5) and row < 64.0  # centre above the camera's height
    dark = np.asarray(state.info["frame"]) < 0.2
    cols = np.nonzero(dark.any(axis=0))[0]
    assert abs(0.5 * (cols.min() + cols.max() + 1) - 64.0) <= 1.0


def test_vmap_equals_single_runs_and_actions_matter(steps):
    (final_b, (obs_b, reward_b, events_b)), (final_s, (obs_s, reward_s, events_s)) = steps
    np.testing.assert_allclose(obs_b[2], obs_s, atol=1e-5)
    np.testing.assert_allclose(events_b[2], events_s)
    # Steering bends the lateral joints: different actions, different joint angles.
    assert np.abs(obs_b[1, -1, 2:] - obs_b[0, -1, 2:]).max() > 0.05
    assert np.all(np.asarray(reward_b) <= 0.0)
    assert np.all(np.asarray(events_b)[:, 1:] > 0)  # the slithering head sees the scene move


def test_moving_sphere_makes_events_on_its_edges_and_a_still_scene_none():
    pos, rot = jnp.array([0.0, 0.0, 0.3]), jnp.eye(3)
    before = render.render(cam.scene(jnp.array([1.6, 0.0])), pos, rot, cam.HEAD_CAMERA)
    still = render.render(cam.scene(jnp.array([1.6, 0.0])), pos, rot, cam.HEAD_CAMERA)
    moved = render.render(cam.scene(jnp.array([1.6, -0.03])), pos, rot, cam.HEAD_CAMERA)  # 3 cm to the right
    kw = dict(threshold=0.05, capacity=4096)
    none, overflow = dvs.frame_difference(before, still, 0.02, **kw)
    assert int(none.count()) == 0 and int(overflow) == 0
    events, overflow = dvs.frame_difference(before, moved, 0.02, **kw)
    n = int(events.count())
    assert n > 20 and int(overflow) == 0
    x, y, p = (np.asarray(a)[:n] for a in (events.x, events.y, events.p))
    # Every event lies within a pixel or two of the sphere's outline in one frame or the other.
    f = cam.HEAD_CAMERA.focal
    shift = f * 0.03 / 1.6
    centre_col, centre_row = 64.0, 64.0 - f * 0.0 / 1.6
    col, row = x + 0.5, y + 0.5
    radius = f * 0.3 / math.sqrt(1.6**2 - 0.3**2)
    r_before = np.hypot(col - centre_col, row - centre_row)
    r_after = np.hypot(col - centre_col - shift, row - centre_row)
    assert np.all(np.minimum(np.abs(r_before - radius), np.abs(r_after - radius)) < 2.0)
    # The dark sphere moved right: its leading (right) edge darkens, its trailing (left) edge brightens.
    assert np.all(p[col > centre_col + shift / 2] == -1) and np.all(p[col < centre_col - shift / 2] == 1)
    # Both edges fire, the top and bottom (moving along themselves) hardly.
    assert (col > centre_col).sum() > 5 and (col < centre_col).sum() > 5


def test_mirror_flips_the_track(env):
    plain = env.reset(jax.random.PRNGKey(0))
    mirrored = env.reset(jax.random.PRNGKey(0), mirror=True)
    s = jnp.float32(20.0)
    a, b = env._target_xy(s, plain.info["mirror"]), env._target_xy(s, mirrored.info["mirror"])
    np.testing.assert_allclose(b - env.origin, (a - env.origin) * jnp.array([1.0, -1.0]), atol=1e-5)


def test_brax_training_wrappers_accept_the_env():
    from brax.envs.wrappers.training import wrap

    env = wrap(SnakeEnv("eight", camera=False), episode_length=4)
    state = jax.jit(env.reset)(jax.random.split(jax.random.PRNGKey(1), 2))
    step = jax.jit(env.step)
    for _ in range(5):
        state = step(state, jnp.zeros((2, 2)))
    assert state.obs.shape == (2, 18)
    # After 4 steps the episode wrapper truncated and the auto-reset put the snakes back at the start.
    assert float(state.info["steps"][0]) == 1.0
    assert int(state.info["control_steps"][0]) == 1  # the task restarted too, not only the physics
    assert float(state.info["target_s"][0]) <= 0.2 * 0.02 + 1e-6


def test_env_params_are_traced_so_a_vmap_over_them_compiles_once():
    traces = []

    def run(env, params):
        traces.append(env)
        state = env.reset(jax.random.PRNGKey(0), params=params)
        for _ in range(5):
            state = env.step(state, jnp.array([1.0, 0.0]))
        return state.obs

    env = SnakeEnv("eight", camera=False)
    steers = jnp.array([0.1, 0.25], jnp.float32)
    swept = jax.vmap(lambda v: env.params._replace(max_steer=v))(steers)
    batched = jax.jit(jax.vmap(functools.partial(run, env)))(swept)
    one = jax.jit(functools.partial(run, env))
    singles = [one(env.params._replace(max_steer=v)) for v in steers]
    assert len(traces) == 2  # once for the vmap, once for both single values
    for v, obs_b, obs_s in zip(steers, batched, singles):
        np.testing.assert_allclose(obs_b, obs_s, atol=1e-5)
        # The same as an env built with that value: the traced parameter takes effect.
        built = SnakeEnv("eight", camera=False, max_steer=float(v))
        np.testing.assert_allclose(obs_s, jax.jit(functools.partial(run, built))(built.params), atol=1e-5)
    assert np.abs(np.asarray(batched[1, 2:] - batched[0, 2:])).max() > 0.05


def test_bad_input_is_a_user_error():
    with pytest.raises(UserError, match="unknown track"):
        SnakeEnv("circle")
    with pytest.raises(UserError, match="event_capacity"):
        SnakeEnv(event_capacity=0)
    with pytest.raises(UserError, match="physics backend"):
        SnakeEnv(backend="bullet")
    with pytest.raises(UserError, match="friction cone"):
        SnakeEnv(friction_cone="square")
    with pytest.raises(UserError, match="steer_threshold"):
        SnakeEnv(max_steer=0.1, steer_threshold=0.1)


def test_steering_offset_by_hand():
    a = np.array([-1.0, -0.5, 0.0, 0.25, 1.0])
    np.testing.assert_allclose(steering_offset(a, 0.125), 0.125 * a)  # no threshold: the linear map
    # With a threshold c: sign(a) (c + |a| (max - c)); 0 stays 0, +-1 is +-max.
    np.testing.assert_allclose(steering_offset(a, 0.125, 0.08), [-0.125, -0.1025, 0.0, 0.09125, 0.125])
    np.testing.assert_allclose(steering_offset(jnp.asarray(a), 0.125, 0.08), steering_offset(a, 0.125, 0.08))
    np.testing.assert_allclose(steering_offset(a, 0.05, 0.08), 0.05 * np.sign(a))  # threshold above the range


def _turned_deg(env, steer, steps, skip=4):
    """Heading change of the gait-averaged head path under a constant steering action, after ``skip`` gait periods."""
    period = env.window

    def run(a):
        def body(state, _):
            state = env.step(state, jnp.stack([a, 0.0]))
            return state, state.pipeline_state.head_pos[:2]

        return jax.lax.scan(body, env.reset(jax.random.PRNGKey(0)), None, length=steps)[1]

    xy = np.asarray(jax.jit(jax.vmap(run))(jnp.asarray(steer, jnp.float32)))
    kernel = np.ones(period) / period
    out = []
    for path in xy:
        mean = np.stack([np.convolve(path[:, i], kernel, "valid") for i in range(2)], 1)[skip * period :: period // 5]
        heading = np.unwrap(np.arctan2(*np.diff(mean, axis=0).T[::-1]))
        out.append(np.degrees(heading[-1] - heading[0]))
    return np.array(out)


def test_the_gait_does_not_turn_below_the_turning_threshold():
    # max_steer 1: the action is C_o in rad. Below TURN_THRESHOLD the snake keeps its heading for
    # 30 s; a little above it, and at the steering range's end, it turns (to the right for C_o > 0).
    env = SnakeEnv("eight", camera=False, max_steer=1.0)
    c_o = np.array([0.5, -0.9, 1.07, -1.07, 1.56]) * TURN_THRESHOLD
    turned = _turned_deg(env, c_o, 2000)
    assert np.all(np.abs(turned[:2]) < 8.0), turned  # measured 1-4 deg
    assert turned[2] < -50.0 and turned[3] > 50.0, turned  # 80-95 deg
    assert turned[4] < -180.0, turned  # 240 deg


def test_on_the_elliptic_friction_cone_the_turning_rate_is_proportional_to_the_lateral_offset():
    # Isotropic friction: the snake turns for every offset, to the right for C_o > 0, mirror-symmetrically,
    # by an angle that grows with C_o; the threshold above is the pyramidal cone's. A_o 45 deg keeps the
    # gait near its pyramidal speed (0.09 m/s; 0.05 at 30 deg).
    gait = gait_params()._replace(A_o=math.radians(45.0))
    env = SnakeEnv("eight", camera=False, max_steer=1.0, gait=gait, friction_cone="elliptic")
    c_o = np.array([0.0, 0.03, 0.0625, 0.125])
    turned = _turned_deg(env, np.concatenate([c_o, -c_o[1:]]), 3000, skip=12)  # the last 30 s of 60
    assert abs(turned[0]) < 20.0, turned  # measured -10 deg: the straight gait's heading wanders
    right = (turned[1:4] - turned[4:]) / 2  # a mirror pair's mean cancels the wander
    assert right[0] < -15.0 and right[2] < right[1] < right[0], turned  # -31, -71, -169 deg
    np.testing.assert_allclose(right / c_o[1:], right[2] / c_o[3], rtol=0.5)  # -1,027, -1,140, -1,355 deg/rad


def test_steering_controller_by_hand():
    from robots.snake import steering

    obs = jnp.zeros(18).at[1].set(0.2)  # target 0.2 rad to the right of the body
    state, action = steering.step(steering.SteeringParams(gain=1.0, head_gain=2.0, tau=0.0), steering.init(), obs, 0.02)
    np.testing.assert_allclose(action, [0.2, 0.4], rtol=1e-6)  # unfiltered: proportional, both turn right
    params = steering.SteeringParams(gain=10.0, head_gain=0.0, tau=1.0)
    state, action = steering.step(params, steering.init(), obs, 0.02)
    smoothed = (1 - math.exp(-0.02)) * 0.2
    assert float(state.angle) == pytest.approx(smoothed, rel=1e-5)
    np.testing.assert_allclose(action, [10 * smoothed, 0.0], rtol=1e-5)
    for _ in range(300):
        state, action = steering.step(params, state, obs, 0.02)
    np.testing.assert_allclose(action, [1.0, 0.0])  # clipped to the action range


@pytest.mark.slow
def test_mjx_backend_gives_the_same_observations_and_events():
    def run(env):
        def one(key):
            def body(state, action):
                state = env.step(state, action)
                return state, (state.obs, state.metrics["events"])

            return jax.lax.scan(body, env.reset(key), jnp.tile(jnp.array([[0.5, -0.3]]), (20, 1)))[1]

        return jax.device_get(jax.jit(jax.vmap(one))(jax.random.split(jax.random.PRNGKey(0), 2)))

    obs_c, events_c = run(SnakeEnv("eight", backend="mujoco"))
    obs_x, events_x = run(SnakeEnv("eight", backend="mjx"))
    # The two engines' CG solvers stop at different residuals: joint angles part by about 0.02 rad in
    # 20 control steps (tests/test_snake_physics.py bounds the trajectories over 5 s).
    np.testing.assert_allclose(obs_x, obs_c, atol=0.04)
    # Event counts follow the head's pose closely: per snake the same total within 10 %, step by step alike.
    np.testing.assert_allclose(events_x.sum(axis=1), events_c.sum(axis=1), rtol=0.1)
    for x, c in zip(events_x, events_c):
        assert np.corrcoef(x, c)[0, 1] > 0.9
    assert events_c[:, 1:].min() > 50  # the camera sees the target move in every step
