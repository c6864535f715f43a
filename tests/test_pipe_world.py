"""The snake's pipe world: scene files, random placements, ground truth against the renderer, predicates."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from robots.snake import camera as cam
from robots.snake import pipes
from robots.snake.gait import gait_params, joint_targets
from robots.snake.physics import PIPE_GROUP, forward_kinematics, make_physics, start_at
from spikejax.errors import UserError
from spikejax.vision import render

GOOD = """
[snake]
x = 0.0
y = 0.0
yaw_deg = 0.0        # heading; 0 = along +x

[[pipe]]
kind = "standing"
x = 3.0
y = 0.8
yaw_deg = 180.0
radius = 0.125
wall = 0.01
length = 2.0

[[pipe]]
kind = "lying"
x = 2.5
y = -1.0
yaw_deg = 160.0
radius = 0.26
wall = 0.01
length = 3.0
ring_brightness = 0.7
"""


def test_scene_file_loads_into_fixed_slots(tmp_path):
    path = tmp_path / "scene.toml"
    path.write_text(GOOD)
    scene = pipes.load_scene(path, capacity=3)
    np.testing.assert_array_equal(scene.valid, [True, True, False])
    np.testing.assert_array_equal(scene.kind, [pipes.STANDING, pipes.LYING, pipes.STANDING])
    np.testing.assert_allclose(scene.xy[:2], [[3.0, 0.8], [2.5, -1.0]])
    np.testing.assert_allclose(scene.yaw[1], math.radians(160.0), rtol=1e-6)
    np.testing.assert_allclose(scene.ring_brightness[:2], [pipes.STANDING_BRIGHTNESS[2], 0.7])
    assert scene.start.shape == (3,) and scene.capacity == 3
    # The physical bodies take the file's sizes, slot by slot.
    model = make_physics("mujoco", pipes=pipes.bodies_for(scene), nthread=1).mj_model
    np.testing.assert_allclose(model.geom("pipe0_standing").size[:2], [0.125, 1.0])
    np.testing.assert_allclose(model.geom("pipe1_cap").size[:2], [0.26, 0.005])
    assert model.nmocap == 6
    # Scenes of different contents have one pytree structure and shape: they stack and vmap.
    other = pipes.sample(jax.random.key(0), pipes.LYING, pipes.LEFT, capacity=3)
    assert jax.tree.structure(other) == jax.tree.structure(scene)
    assert [x.shape for x in jax.tree.leaves(other)] == [x.shape for x in jax.tree.leaves(scene)]


def _bad(snake="x = 0.0\ny = 0.0\nyaw_deg = 0.0", **pipe):
    fields = {"kind": '"standing"', "x": "3.0", "y": "0.5", "radius": "0.125", "length": "2.0"}
    fields.update(pipe)
    body = "\n".join(f"{k} = {v}" for k, v in fields.items() if v is not None)
    return f"[snake]\n{snake}\n\n[[pipe]]\n{body}\n"


@pytest.mark.parametrize(
    "text, match",
    [
        (_bad(radius=None), r"pipe 1: missing key 'radius'"),
        (_bad(kind=None), r"pipe 1: missing key 'kind'"),
        (_bad(x='"far"'), r"pipe 1: x must be a number, got str"),
        (_bad(length="true"), r"pipe 1: length must be a number, got bool"),
        (_bad(kind='"sitting"'), r"unknown kind 'sitting'"),
        (_bad(radius="-0.1"), r"radius must be positive"),
        (_bad(kind='"lying"', yaw_deg="180.0", wall="0.3", radius="0.26"), r"wall 0.3 must be .*less than the radius"),
        (_bad(kind='"lying"', yaw_deg="180.0"), r"pipe 1: missing key 'wall'"),
        (_bad(x="-0.5", y="0.0"), r"overlaps the snake at its start"),
        (_bad(kind='"lying"', yaw_deg="0.0", wall="0.01", x="0.5", y="0.0"), r"overlaps the snake"),
        (_bad(colour='"red"'), r"unknown key 'colour'"),
        (
            _bad() + "[[pipe]]\nkind = 'standing'\nx = 3.2\ny = 0.5\nradius = 0.125\nlength = 2.0\n",
            r"pipe 2: .* overlaps pipe 1",
        ),
        (
            _bad(kind='"lying"', yaw_deg="90.0", wall="0.01", radius="0.26", length="3.0")
            + "[[pipe]]\nkind = 'standing'\nx = 3.0\ny = -1.5\nradius = 0.125\nlength = 2.0\n",
            r"pipe 2: the standing pipe at \(3.0, -1.5\) overlaps pipe 1",
        ),
        (_bad(brightness="1.5"), r"brightness must be in \[0, 1\]"),
        (_bad(snake="x = 0.0\ny = 0.0"), r"\[snake\]: missing key 'yaw_deg'"),
        ("[[pipe]]\nkind = 'standing'\n", r"missing table \[snake\]"),
        ("[snake\nx = 1", r"not valid TOML"),
        (_bad() + _bad().split("\n\n", 1)[1] * 4, r"5 pipes, more than the scene's 4 slots"),
    ],
)
def test_bad_scene_files_get_one_line_errors(tmp_path, text, match):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(UserError, match=match) as err:
        pipes.load_scene(path)
    assert "\n" not in str(err.value) and str(path) in str(err.value)


def test_missing_scene_file_is_a_user_error(tmp_path):
    with pytest.raises(UserError, match="cannot read scene file"):
        pipes.load_scene(tmp_path / "none.toml")


def test_sampler_is_pure_and_keeps_to_its_ranges():
    keys = jax.random.split(jax.random.key(7), 512)
    kinds = jnp.tile(jnp.array([pipes.STANDING, pipes.LYING]), 256)
    sides = jnp.tile(jnp.array([pipes.LEFT, pipes.LEFT, pipes.RIGHT, pipes.RIGHT]), 128)
    batch = jax.jit(jax.vmap(pipes.sample))(keys, kinds, sides)
    again = pipes.sample(keys[5], kinds[5], sides[5])
    for a, b in zip(jax.tree.leaves(again), jax.tree.leaves(batch)):
        np.testing.assert_array_equal(a, b[5])  # the same key gives the same scene at any batch
    x, y = np.asarray(batch.xy[:, 0, 0]), np.asarray(batch.xy[:, 0, 1])
    assert x.min() >= 2.0 and x.max() <= 4.0 and x.max() - x.min() > 1.8
    assert np.all(np.abs(y) >= 0.3) and np.all(np.abs(y) <= 1.2)
    np.testing.assert_array_equal(np.sign(y), -np.asarray(sides))  # right of a +x heading is -y
    lying = np.asarray(kinds) == pipes.LYING
    # A lying entry faces the start within 20 degrees; the sizes are the default scene's.
    facing = np.asarray(batch.yaw[:, 0]) - np.arctan2(-y, -x)
    facing = (facing + np.pi) % (2 * np.pi) - np.pi
    assert np.abs(facing[lying]).max() <= math.radians(20.0) + 1e-6 and np.abs(facing[lying]).max() > math.radians(15)
    np.testing.assert_allclose(batch.radius[:, 0], np.where(lying, 0.26, 0.125))
    np.testing.assert_allclose(batch.length[:, 0], np.where(lying, 3.0, 2.0))
    np.testing.assert_allclose(batch.radius[:, 0] - batch.wall[:, 0], np.where(lying, 0.25, 0.0), atol=1e-7)


def _flat(scene, ambient=1.0):
    """The pipes black, floor and sky white, unshaded: ``1 - image`` is the pipes' pixel coverage."""
    flat = render.Pipes(*render_fields(scene))
    cyl, ann = render.pipe_primitives(flat)
    return render.Scene(
        render.no_spheres(), cyl, ground_brightness=1.0, sky_brightness=1.0, ambient=ambient, annuli=ann
    )


def render_fields(scene):
    p = pipes.render_pipes(scene)
    zero = jnp.zeros_like(p.brightness)
    return p._replace(brightness=zero, inner_brightness=zero, ring_brightness=zero)


CAMERA = render.Camera(width=96, height=64, supersample=4)
_render = jax.jit(render.render, static_argnames="camera")
_truth = jax.jit(pipes.truth, static_argnames="camera")
_entered = jax.jit(pipes.entered)
_reached = jax.jit(pipes.reached)
_clearance = jax.jit(pipes.clearance)


@pytest.mark.parametrize("yaw_deg, lateral", [(0.0, 0.3), (12.0, -0.5)])
def test_standing_pipe_edges_and_width_match_the_rendered_silhouette(yaw_deg, lateral):
    scene = pipes.sample(jax.random.key(1), pipes.STANDING, pipes.RIGHT)
    scene = scene._replace(xy=jnp.array([[2.2, -lateral]]))
    yaw = math.radians(yaw_deg)
    pos = jnp.array([0.1, 0.05, 0.0305])
    rot = jnp.array([[math.cos(yaw), -math.sin(yaw), 0.0], [math.sin(yaw), math.cos(yaw), 0.0], [0.0, 0.0, 1.0]])
    img = np.asarray(_render(_flat(scene), pos, rot, CAMERA))
    t = _truth(pos, rot, scene, CAMERA)
    # A vertical tube seen by a level camera: both silhouette edges are vertical lines; the rows above
    # the horizon show the pipe against the sky, so each row's coverage is the width, its moments the edges.
    cover = 1.0 - img[5:25]
    cols = np.arange(CAMERA.width) + 0.5
    width = cover.sum(axis=1)
    centre = (cover * cols).sum(axis=1) / width
    # 4 x 4 rays a pixel place a vertical edge to 1/8 px: the width to 1/4 px, the centre to 1/8 px.
    np.testing.assert_allclose(width, float(t.width[0]), atol=0.26)
    np.testing.assert_allclose(centre, float(t.pos[0]), atol=0.13)
    assert np.all(cover[:, : int(t.left_col[0]) - 1] < 1e-6) and np.all(cover[:, int(t.right_col[0]) + 2 :] < 1e-6)
    # Eq. (8)'s relation: w = f l / sqrt(d^2 - (l/2)^2) for a pipe on the axis (SPEC.md section 5), here off axis.
    d = float(jnp.hypot(2.2 - 0.1, -lateral - 0.05))
    half_angle = math.asin(0.125 / d)
    assert float(t.width[0]) == pytest.approx(
        CAMERA.focal * (math.tan(float(t.bearing[0]) + half_angle) - math.tan(float(t.bearing[0]) - half_angle)),
        rel=1e-4,
    )
    assert (float(t.pos[0]) > CAMERA.width / 2) == (float(t.lateral[0]) > 0) == (float(t.bearing[0]) > 0)


def test_lying_entry_ring_centre_and_radius_match_the_rendered_entry():
    # Entry 2 m ahead facing the camera, end-on: the projected entry disc is a circle of radius f R / d.
    scene = pipes.sample(jax.random.key(2), pipes.LYING, pipes.LEFT)
    scene = scene._replace(xy=jnp.array([[2.0, 0.0]]), yaw=jnp.array([math.pi]))
    pos, rot = jnp.array([0.0, 0.0, 0.26]), jnp.eye(3)
    t = _truth(pos, rot, scene, CAMERA)
    scene_img = _flat(scene)._replace(ground_height=-100.0)
    cover = 1.0 - np.asarray(_render(scene_img, pos, rot, CAMERA))
    rows, cols = np.mgrid[: CAMERA.height, : CAMERA.width] + 0.5
    area = cover.sum()
    assert math.sqrt(area / math.pi) == pytest.approx(float(t.ring_radius[0]), rel=0.01)
    assert (cover * cols).sum() / area == pytest.approx(float(t.ring_col[0]), abs=0.05)
    assert (cover * rows).sum() / area == pytest.approx(float(t.ring_row[0]), abs=0.05)
    assert float(t.ring_radius[0]) == pytest.approx(CAMERA.focal * 0.26 / 2.0, rel=1e-5)
    # Off axis, from the snake's camera height: the dark entry disc's top and bottom are the ring's vertical
    # semi-axis about the projected centre (its depth is the entry centre's within R sin(20 deg)).
    pos = jnp.array([0.3, 0.4, 0.0305])
    scene = scene._replace(yaw=jnp.array([math.pi - math.radians(20.0)]))
    # The outer wall white like the background: the dark region is the entry face and what the bore shows.
    p = render_fields(scene)
    p = p._replace(brightness=jnp.ones_like(p.brightness))
    cyl, ann = render.pipe_primitives(p)
    img = _render(
        render.Scene(
            render.no_spheres(),
            cyl,
            ground_height=-100.0,
            ground_brightness=1.0,
            sky_brightness=1.0,
            ambient=1.0,
            annuli=ann,
        ),
        pos,
        rot,
        CAMERA,
    )
    cover = 1.0 - np.asarray(img)
    t = _truth(pos, rot, scene, CAMERA)
    col = int(t.ring_col[0])
    column = cover[:, col]
    top, bottom = np.nonzero(column > 0.5)[0][[0, -1]]
    assert 0.5 * (bottom + 1 - top) == pytest.approx(float(t.ring_radius[0]), abs=1.0)
    assert 0.5 * (top + bottom + 1) == pytest.approx(float(t.ring_row[0]), abs=1.0)


def test_predicates_on_hand_placed_heads():
    scene = pipes.parse_scene(
        {
            "snake": {"x": -2.0, "y": 0.0, "yaw_deg": 0.0},
            "pipe": [
                {"kind": "standing", "x": 3.0, "y": 2.0, "radius": 0.125, "length": 2.0},
                {"kind": "lying", "x": 0.0, "y": 0.0, "yaw_deg": 180.0, "radius": 0.26, "wall": 0.01, "length": 3.0},
            ],
        },
        capacity=3,
    )
    eye = jnp.eye(3)
    # Standing: 0.3 m from the surface is reached (horizontal distance to the axis 0.425), 0.31 m is not.
    for gap, want in [(0.29, True), (0.31, False)]:
        head = jnp.array([3.0 - 0.125 - gap, 2.0, 0.03])
        np.testing.assert_array_equal(_reached(head, scene), [want, False, False])
    # Lying: the entry plane is x = 0 facing -x, the bore (radius 0.25, margin 0.05) runs along +x at z = 0.26.
    looking_out = jnp.array([[-1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0]])
    cases = [
        ((0.1, 0.0, 0.26), eye, True),  # inside on the axis
        ((-0.1, 0.0, 0.26), eye, False),  # before the entry plane
        ((0.1, 0.19, 0.26), eye, True),  # sideways 0.19 <= 0.20
        ((0.1, 0.21, 0.26), eye, False),  # sideways 0.21 > 0.20
        ((0.1, 0.19, 0.05), eye, False),  # sideways 0.19, but outside the bore (0.28 from the axis)
        ((0.1, 0.1, 0.05), eye, True),  # on the bore's floor, 0.1 to the side
        ((0.1, 0.0, 0.26), looking_out, False),  # facing out
        ((3.1, 0.0, 0.26), eye, False),  # past the far end
    ]
    for degrees, want in [(29.0, True), (-29.0, True), (31.0, False)]:
        c, s = math.cos(math.radians(degrees)), math.sin(math.radians(degrees))
        cases.append(((0.5, 0.0, 0.05), jnp.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]), want))
    for head, mat, want in cases:
        inside = _entered(jnp.array(head), mat, scene)
        assert bool(inside[1]) == want and not bool(inside[0]) and not bool(inside[2]), (head, want)
    assert bool(_reached(jnp.array([-0.29, 0.0, 0.26]), scene)[1])
    # Offsets from a central line, positive on its right: along +y from the origin, x > 0 is right.
    np.testing.assert_allclose(pipes.line_offset(scene, [0.0, 0.0], math.pi / 2)[:2], [3.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(pipes.line_offset(scene, [1.0, 1.0], 0.0)[:2], [-1.0, 1.0], atol=1e-6)
    # Clearance: hand-computed gaps to the standing solid and the lying wall (radius 0.26, bore 0.25).
    points = jnp.array([[3.5, 2.0, 1.0], [3.0, 2.0, 2.5], [1.0, 0.0, 0.26 + 0.4], [1.0, 0.0, 0.26 + 0.1]])
    gap = np.asarray(_clearance(points, jnp.full(4, 0.03), scene))
    np.testing.assert_allclose(gap[:2, 0], [0.5 - 0.125 - 0.03, 0.5 - 0.03], atol=1e-6)  # beside, above the top
    np.testing.assert_allclose(gap[2:, 1], [0.4 - 0.26 - 0.03, 0.25 - 0.1 - 0.03], atol=1e-6)  # outside, in the bore
    assert np.all(np.isinf(gap[:, 2]))


@pytest.fixture(scope="module")
def pipe_physics():
    return make_physics("mujoco", pipes=pipes.default_bodies(1), nthread=1)


def _crawl(phys, state, n_steps, scene=None):
    """``n_steps`` of the straight gait; per step the head, its frame and, given ``scene``, the truth."""
    gait = gait_params()

    def body(s, _):
        s = phys.step(s, joint_targets(gait, s.time, 0.0, 0.0, True))
        out = (s.head_pos, s.head_mat, s.qpos)
        if scene is not None:
            gap = pipes.clearance(forward_kinematics(s.qpos)[0][1:], jnp.zeros(17), scene)
            out += (
                pipes.collided(s.qpos, scene),
                pipes.collided(s.qpos, scene, -0.01),
                jnp.min(gap, axis=0),
                pipes.entered(s.head_pos, s.head_mat, scene),
            )
        return s, out

    return jax.lax.scan(body, state, None, length=n_steps)[1]


@pytest.fixture(scope="module")
def crawls(pipe_physics):
    """Three episodes in one program (the scenes differ only in traced data): a standing pipe 0.55 m
    ahead of the head, a lying pipe's entry 0.35 m ahead facing the snake, no pipe; and the snake
    alone (the model without pipes) on the same batch."""
    standing = pipes.sample(jax.random.key(0), pipes.STANDING, pipes.LEFT)._replace(xy=jnp.array([[0.55, 0.0]]))
    lying = pipes.sample(jax.random.key(0), pipes.LYING, pipes.LEFT)
    lying = lying._replace(xy=jnp.array([[0.35, 0.0]]), yaw=jnp.array([math.pi]))
    empty = standing._replace(valid=jnp.array([False]))
    scenes = jax.tree.map(lambda *a: jnp.stack(a), standing, lying, empty)

    def episode(scene):
        start = start_at(pipe_physics.init(), 0.0 * scene.xy[0, 0], 0.0, 0.0)  # batched like the scene
        return _crawl(pipe_physics, pipes.place_pipes(start, scene), 450, scene)

    alone = make_physics("mujoco", nthread=1)
    assert alone.init().mocap_pos.shape == (0, 3)

    def episode_alone(scene):
        return _crawl(alone, start_at(alone.init(), 0.0 * scene.xy[0, 0], 0.0, 0.0), 60)

    return jax.jit(jax.vmap(episode))(scenes), jax.jit(jax.vmap(episode_alone))(scenes)


def test_parked_pipes_leave_the_snake_as_it_was(crawls):
    (_, _, qpos, *_), (_, _, qpos_alone) = crawls
    np.testing.assert_array_equal(qpos[2, :60], qpos_alone[2])


def test_snake_collides_with_a_standing_pipe_and_crawls_into_a_lying_one(crawls):
    (head, _, _, touch, deep, gap, inside), _ = crawls
    # Standing pipe on the path: the head is stopped and deflected, never inside the solid.
    surface = np.hypot(head[0, :, 0] - 0.55, head[0, :, 1]) - 0.125
    assert surface.min() > -0.01 and surface.min() < 0.05
    assert bool(jnp.any(touch[0, :, 0])) and not bool(jnp.any(touch[2]))
    assert float(jnp.min(gap[0, :, 0])) > -0.03  # no module centre deeper than its radius
    # Lying pipe: the head passes the entry plane and is inside the bore, by `entered`, touching no wall
    # deeper than 1 cm.
    assert bool(inside[1, -1, 0]) and float(head[1, -1, 0]) > 0.35 + 0.2 and not bool(jnp.any(inside[0]))
    assert not bool(jnp.any(deep[1]))


def test_pipe_scene_has_no_target_sphere_and_shows_the_pipe():
    scene = pipes.sample(jax.random.key(3), pipes.STANDING, pipes.RIGHT)
    world = cam.pipe_scene(pipes.render_pipes(scene))
    assert world.spheres.center.shape == (0, 3)
    camera = render.Camera(width=64, height=32)
    img = np.asarray(_render(world, jnp.array([0.0, 0.0, 0.0305]), jnp.eye(3), camera))
    t = _truth(jnp.array([0.0, 0.0, 0.0305]), jnp.eye(3), scene, camera)
    col = int(t.pos[0])
    assert img[5, col] < 0.1 < cam.SKY_BRIGHTNESS - 0.1 < img[5, (col + 32) % 64]


@pytest.mark.slow
def test_mjx_backend_takes_the_pipes_and_stops_at_a_standing_one():
    """The MJX model of the same pipe world (compile about 80 s on 2 cores, hence slow).

    The standing pipe 0.55 m ahead of the head: in both backends the head comes
    to the surface and stays out of the solid; over the first 0.4 s (no pipe
    contact yet) the heads agree within 1 cm, the tolerance of
    ``tests/test_snake_physics.py`` for MJX against C.
    """
    scene = pipes.sample(jax.random.key(0), pipes.STANDING, pipes.LEFT)._replace(xy=jnp.array([[0.55, 0.0]]))
    heads = {}
    for backend in ("mjx", "mujoco"):
        phys = make_physics(backend, pipes=pipes.default_bodies(1), nthread=1)
        state = pipes.place_pipes(start_at(phys.init(), 0.0, 0.0, 0.0), scene)
        heads[backend] = np.asarray(jax.jit(lambda s, phys=phys: _crawl(phys, s, 300))(state)[0])
    np.testing.assert_allclose(heads["mjx"][:20], heads["mujoco"][:20], atol=1e-2)
    for head in heads.values():
        surface = np.hypot(head[:, 0] - 0.55, head[:, 1]) - 0.125
        assert -0.01 < surface.min() < 0.05


def test_start_at_moves_the_snake_rigidly():
    phys = make_physics("mujoco", nthread=1)
    rest = phys.init()
    moved = jax.jit(start_at)(rest, 1.0, -2.0, 0.5)
    np.testing.assert_allclose(moved.head_pos[:2], [1.0, -2.0], atol=1e-6)
    assert math.atan2(float(moved.head_mat[1, 0]), float(moved.head_mat[0, 0])) == pytest.approx(0.5, abs=1e-6)
    fk = jax.jit(forward_kinematics)
    a, b = fk(rest.qpos)[0][1:], fk(moved.qpos)[0][1:]
    pair = lambda x: np.linalg.norm(x[:, None] - x[None], axis=-1)  # noqa: E731
    np.testing.assert_allclose(pair(np.asarray(b)), pair(np.asarray(a)), atol=1e-5)
    np.testing.assert_array_equal(moved.qpos[7:], rest.qpos[7:])


def test_physical_pipes_stand_where_the_camera_draws_them(pipe_physics):
    """mj_ray on the placed MuJoCo bodies against the renderer's pipes.

    The standing pipe is the same cylinder; the lying one's 16 staves are an
    inscribed polygon of the drawn wall, whose corners stand out by
    ``0.26 / cos(pi / 16) - 0.26``, 5.1 mm, beyond the drawn surface: every
    point where a ray meets a physical pipe is within 6 mm of the drawn solid.
    """
    import mujoco

    model = pipe_physics.mj_model
    data = mujoco.MjData(model)
    for kind, xy, yaw in [(pipes.STANDING, (2.0, 0.5), 0.0), (pipes.LYING, (2.5, -0.4), math.radians(160.0))]:
        scene = pipes.sample(jax.random.key(0), kind, pipes.LEFT)._replace(xy=jnp.array([xy]), yaw=jnp.array([yaw]))
        state = pipes.place_pipes(pipe_physics.init(), scene)
        data.mocap_pos[:], data.mocap_quat[:] = np.asarray(state.mocap_pos), np.asarray(state.mocap_quat)
        mujoco.mj_forward(model, data)
        world = cam.pipe_scene(pipes.render_pipes(scene))._replace(ground_height=-100.0)
        origin = np.array([0.0, 0.0, 0.2])
        rng = np.random.default_rng(int(kind))
        target = np.array([*xy, 0.25]) + rng.uniform(-0.25, 0.25, (200, 3)) * [1, 1, 0.8]
        if kind == pipes.LYING:  # rays into the bore as well as onto the wall and the entry face
            target = target + np.outer(rng.uniform(0, 2.0, 200), [math.cos(yaw + math.pi), math.sin(yaw + math.pi), 0])
        dirs = target - origin
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        t, _ = jax.jit(render.intersect)(world, jnp.asarray(origin, jnp.float32), jnp.asarray(dirs, jnp.float32))
        t = np.where(np.asarray(t) > 50.0, -1.0, np.asarray(t))
        geom = np.zeros(1, np.int32)
        groups = np.zeros(6, np.uint8)
        groups[PIPE_GROUP] = 1  # the pipes only: not the floor, not the snake
        exp = np.array([mujoco.mj_ray(model, data, origin, d, groups, 1, -1, geom) for d in dirs])
        both = (exp > 0) & (t > 0)
        assert both.sum() > 80 and np.mean((exp > 0) == (t > 0)) > 0.95
        hit = origin + exp[exp > 0, None] * dirs[exp > 0]
        gap = np.asarray(_clearance(jnp.asarray(hit, jnp.float32), jnp.zeros(len(hit)), scene))[:, 0]
        assert np.abs(gap).max() < (1e-4 if kind == pipes.STANDING else 0.006)
        if kind == pipes.STANDING:
            np.testing.assert_allclose(t[both], exp[both], atol=1e-4)
