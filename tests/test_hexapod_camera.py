"""The hexapod's head camera and its open-loop prey decisions (robots/hexapod/camera.py, decisions.py)."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from robots.hexapod import camera as cam
from robots.hexapod import decisions, physics, prey
from robots.hexapod.vision import FORWARD, LEFT, PAPER_SENSOR, RIGHT
from spikejax.errors import UserError
from spikejax.vision import render


def test_camera_sits_on_the_mjcf_site_above_the_standing_torso():
    model = physics.load_model()
    qpos = physics.standing_state(model)[1 : 1 + model.nq]
    assert cam.site_offset() == pytest.approx((0.1, 0.0, 0.04))
    assert cam.camera_height() == pytest.approx(qpos[2] + 0.04, abs=1e-3)
    # d_near = h / tan(tilt + atan(20 / f)), f = 128 / tan(HFoV / 2): SPEC 4.4 at our sensor.
    f = 128 / math.tan(math.radians(cam.HFOV_DEG / 2))
    expected = cam.camera_height() / math.tan(math.radians(cam.TILT_DEG) + math.atan(20 / f))
    assert cam.D_NEAR == pytest.approx(expected, rel=1e-9)
    assert (cam.HFOV_DEG, cam.TILT_DEG) == (90.0, 0.0) and cam.D_NEAR == pytest.approx(0.109 * 128 / 20, rel=1e-3)
    narrow = render.Camera(width=256, height=160, fov=math.radians(60))
    assert cam.d_near(0.0, narrow) == pytest.approx(1.21, abs=0.01)  # SPEC 4.4's level 60 deg example at h = 0.109 m
    assert cam.d_near(10.0, narrow) == pytest.approx(0.40, abs=0.01)  # the first camera, 60 deg tilted 10 deg down


def test_pose_follows_the_torso_yaw_and_the_tilt():
    torso = jnp.array([1.0, 2.0, 0.07, 0.0, 0.0, math.pi / 2])
    pos, rot = cam.pose(torso)
    t = math.radians(cam.TILT_DEG)
    np.testing.assert_allclose(pos, [1.0, 2.1, 0.11], atol=1e-6)  # the site 0.1 m ahead, i.e. along +y
    np.testing.assert_allclose(rot[:, 0], [0.0, math.cos(t), -math.sin(t)], atol=1e-6)  # forward, pitched down
    np.testing.assert_allclose(rot[:, 1], [-1.0, 0.0, 0.0], atol=1e-6)  # left
    np.testing.assert_allclose(rot.T @ rot, np.eye(3), atol=1e-6)


def _scene(*prey_xy_alive):
    xy = np.full((prey.MAX_PREY, 2), 50.0, np.float32)
    alive = np.zeros(prey.MAX_PREY, bool)
    for i, (x, y, a) in enumerate(prey_xy_alive):
        xy[i], alive[i] = (x, y), a
    size = jnp.full((prey.MAX_PREY,), prey.PREY_SIZE)
    return prey.PreyScene(jnp.zeros(3), jnp.asarray(xy), size, jnp.asarray(alive))


def test_a_prey_at_d_near_puts_its_base_on_the_near_far_boundary_row():
    torso = jnp.array([0.0, 0.0, cam.camera_height() - 0.04, 0.0, 0.0, 0.0])
    cam_x = float(cam.pose(torso)[0][0])
    # The front face D_NEAR ahead of the camera: its bottom edge at row 100 of 160 (5/8 from the top).
    world = cam.prey_scene(_scene((cam_x + cam.D_NEAR + prey.PREY_SIZE / 2, 0.0, True)))
    frame = jax.jit(cam.frame)
    img = np.asarray(frame(torso, world))
    column = img[:, int(cam.CAMERA.center_col)]  # the optical axis
    dark = np.nonzero(column < 0.3)[0]
    assert dark.max() + 1 == pytest.approx(100, abs=1)
    # A dead slot is not drawn: the frame is the bare floor.
    hidden = np.asarray(frame(torso, cam.prey_scene(_scene((cam_x + cam.D_NEAR + prey.PREY_SIZE / 2, 0.0, False)))))
    np.testing.assert_allclose(hidden, cam.FLOOR_BRIGHTNESS, atol=1e-6)
    assert isinstance(world.boxes, render.Boxes)


@pytest.fixture(scope="module")
def fixed_decisions():
    track = jnp.asarray(decisions.g1_step_tracks([(0.8, 1.0, 1.0)])[0])
    cam_x = float(cam.ground_pose(track[0])[0])

    def at(d, bearing_deg):
        b = math.radians(bearing_deg)
        return (cam_x + d * math.cos(b), d * math.sin(b), True)

    scenes = [
        _scene(at(1.5, 0.0)),  # far, ahead
        _scene(at(0.34, 26.0), at(2.0, -5.0)),  # near on the left, a far one beside
        _scene(at(0.30, -10.0)),  # near on the right
        _scene(),  # an empty arena: keep walking
    ]
    batch = jax.tree.map(lambda *a: jnp.stack(a), *scenes)
    key = jax.random.key(3)
    batched = jax.jit(jax.vmap(decisions.decide, in_axes=(None, 0, None)))(track, batch, key)
    single = jax.jit(decisions.decide)
    return batched, [single(track, s, key) for s in scenes[:2]]


def test_fixed_scenes_get_the_truths_gait(fixed_decisions):
    # Scenes where the wiring wins; over random near scenes it does far less often (docs/BENCHMARKS.md).
    d, _ = fixed_decisions
    np.testing.assert_array_equal(d.truth, [FORWARD, LEFT, RIGHT, FORWARD])
    np.testing.assert_array_equal(d.gait, [FORWARD, LEFT, RIGHT, FORWARD])
    out = np.asarray(d.out_counts)
    assert out[3].sum() == 0  # the empty arena's shot noise never reaches the gait neurons
    assert out[0, 0] > 0 and out[0, 1:].sum() == 0  # a far prey fires G1 alone
    assert out[1, LEFT] > out[1, FORWARD] and out[1, RIGHT] == 0  # the turn away from the prey stays silent
    assert out[2, RIGHT] > out[2, FORWARD] and out[2, LEFT] == 0
    assert int(d.events[:3].min()) > 0 and int(d.filter_spikes[:3].min()) > 0
    # The filter drops most events (the shot noise), layer 2 most filter spikes.
    assert np.all(d.filter_spikes < d.events) and np.all(d.layer2_spikes[:3] < d.filter_spikes[:3])
    # Nothing is lost to the capacity; the crossings beyond MAX_PER_PIXEL are counted apart (none without prey).
    assert int(d.overflow.max()) == 0 and int(d.clipped[1]) > 0 and int(d.clipped[3]) == 0


def test_vmap_over_scenes_equals_single_runs(fixed_decisions):
    batched, singles = fixed_decisions
    for i, s in enumerate(singles):
        for a, b in zip(jax.tree.leaves(s), jax.tree.leaves(batched)):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b)[i])


def test_a_batch_decided_in_chunks_is_decided_as_a_whole(monkeypatch):
    """Six members on a CPU: chunks of four and the remaining two (`decisions.DECIDE_CHUNK`), or all six at once."""
    track = jnp.asarray(decisions.g1_step_tracks([(0.8, 1.0, 1.0)])[0])
    scene = _scene((float(cam.ground_pose(track[0])[0]) + 0.5, 0.1, True))
    keys = jax.random.split(jax.random.key(4), 6)
    runs = {}
    for chunk in (4, 10**9):
        monkeypatch.setattr(decisions, "DECIDE_CHUNK", chunk)
        runs[chunk] = jax.jit(jax.vmap(decisions.decide, in_axes=(None, None, 0)))(track, scene, keys)
    assert int(np.asarray(runs[4].events).min()) > 0
    assert len(set(np.asarray(runs[4].events).tolist())) > 1  # the members' noise differs
    for a, b in zip(jax.tree.leaves(runs[4]), jax.tree.leaves(runs[10**9])):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_capacity_scales_with_the_pixels():
    assert decisions.capacity(cam.EDGE_CONFIG) == decisions.CAPACITY
    assert decisions.capacity(PAPER_SENSOR) == 25 * decisions.CAPACITY
    # The lens centred on the windows (columns 0-1199 of 1280, 0-239 of 256), or on the sensor as in the paper.
    assert cam.sensor_camera(PAPER_SENSOR) == render.Camera(width=1280, height=800, fov=cam.CAMERA.fov, cx=600.0)
    assert cam.sensor_camera(PAPER_SENSOR, "paper") == render.Camera(width=1280, height=800, fov=cam.CAMERA.fov)
    assert cam.sensor_camera(cam.EDGE_CONFIG) == cam.CAMERA and cam.CAMERA.center_col == 120.0
    with pytest.raises(UserError, match="lens"):
        cam.sensor_camera(cam.EDGE_CONFIG, "fisheye")


def test_ordered_readout_is_eq1_2_input_by_input():
    # By hand: three inputs of 0.4 fire once (1.2 > 1), two of 0.7 once; from 0.5 one of 0.7 fires at once.
    fires, v = decisions.ordered_readout(
        jnp.array([0.0, 0.0, 0.5, 0.0]), jnp.array([3, 5, 4, 2]), jnp.array([0.4, 0.4, 0.7, 0.7])
    )
    np.testing.assert_array_equal(fires, [1, 1, 2, 1])
    np.testing.assert_allclose(v, [0.0, 0.8, 0.7, 0.0], atol=1e-6)
    # Against a plain loop over the inputs, one at a time: v += w; fire and reset when v > 1.
    rng = np.random.default_rng(0)
    v0, n, w = rng.uniform(0, 1, 200), rng.integers(0, 40, 200), rng.choice([0.0, 0.3, 0.4, 0.7, 0.95], 200)
    expected = []
    for a, k, b in zip(v0, n, w):
        f = 0
        for _ in range(k):
            a += b
            if a > 1.0:
                f, a = f + 1, 0.0
        expected.append((f, a))
    fires, v = decisions.ordered_readout(jnp.asarray(v0, jnp.float32), jnp.asarray(n), jnp.asarray(w, jnp.float32))
    np.testing.assert_array_equal(fires, [e[0] for e in expected])
    np.testing.assert_allclose(v, [e[1] for e in expected], atol=1e-5)


@pytest.mark.slow
def test_the_paper_sensor_decides_as_the_scaled_one_on_fixed_scenes():
    # ACCEPTANCE A11 on two scenes: 800 x 1280 pixels, 100-px windows and the paper's own weights (0.06, 0.3)
    # against 160 x 256 and 20-px windows; the reproduction's --full-check measures the agreement rate.
    track = jnp.asarray(decisions.g1_step_tracks([(0.8, 1.0, 1.0)])[0])
    cam_x = float(cam.ground_pose(track[0])[0])
    b = math.radians(-10.0)
    scenes = [_scene((cam_x + 1.5, 0.0, True)), _scene((cam_x + 0.3 * math.cos(b), 0.3 * math.sin(b), True))]
    batch = jax.tree.map(lambda *a: jnp.stack(a), *scenes)
    key = jax.random.key(3)
    run = lambda config: jax.jit(jax.vmap(lambda s: decisions.decide(track, s, key, config=config)))(batch)
    full, scaled = run(PAPER_SENSOR), run(cam.EDGE_CONFIG)
    np.testing.assert_array_equal(full.truth, [FORWARD, RIGHT])
    np.testing.assert_array_equal(full.gait, scaled.gait)
    np.testing.assert_array_equal(full.gait, full.truth)
    assert int(full.overflow.max()) == 0
