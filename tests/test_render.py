"""The ray-cast pinhole camera: projections by the closed-form pinhole model, distances by MuJoCo's mj_ray."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from spikejax.errors import UserError
from spikejax.vision import render


def _sphere_only(center, radius=0.3, brightness=0.05):
    # The ground as bright as the sky.
    return render.Scene(render.spheres(center, radius, brightness), render.no_cylinders(), ground_brightness=0.75)


def _yaw(angle):
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _disc(img, level=0.5):
    """Pixel mask of the dark target on the bright sky, its centroid (col, row) and area radius."""
    cover = (0.75 - np.asarray(img)) / (0.75 - 0.05)  # fraction of each pixel covered (flat shading)
    rows, cols = np.mgrid[: img.shape[0], : img.shape[1]]
    area = cover.sum()
    return (cover * (cols + 0.5)).sum() / area, (cover * (rows + 0.5)).sum() / area, math.sqrt(area / math.pi)


@pytest.mark.parametrize("distance", [1.6, 3.0])
def test_sphere_ahead_projects_to_centre_with_pinhole_radius(distance):
    camera = render.Camera(supersample=4)
    scene = _sphere_only([distance, 0.0, 1.0])._replace(ambient=1.0)
    img = render.render(scene, jnp.array([0.0, 0.0, 1.0]), jnp.eye(3), camera)
    col, row, radius = _disc(img)
    expected = camera.focal * 0.3 / math.sqrt(distance**2 - 0.3**2)
    assert abs(col - 64.0) < 0.05 and abs(row - 64.0) < 0.05
    assert radius == pytest.approx(expected, abs=0.15)
    # Symmetric about both image axes (the optical axis is the corner of the four central pixels).
    np.testing.assert_allclose(img, img[::-1, :], atol=1e-6)
    np.testing.assert_allclose(img, img[:, ::-1], atol=1e-6)


def test_off_axis_sphere_lands_where_the_pinhole_model_puts_it():
    camera = render.Camera(supersample=4)
    yaw = math.radians(20.0)
    pos = np.array([1.0, -2.0, 0.5])
    rot = _yaw(yaw)
    # 2.5 m ahead, 0.4 m to the left and 0.3 m below the camera, in the camera frame.
    local = np.array([2.5, 0.4, -0.3])
    center = pos + rot @ local
    img = render.render(_sphere_only(center, radius=0.1)._replace(ambient=1.0), pos, rot, camera)
    col, row, _ = _disc(img)
    f = camera.focal
    assert col == pytest.approx(64.0 - f * 0.4 / 2.5, abs=0.3)  # left of centre
    assert row == pytest.approx(64.0 + f * 0.3 / 2.5, abs=0.3)  # below centre
    np.testing.assert_allclose(render.project(camera, pos, rot, center), [64.0 - f * 0.16, 64.0 + f * 0.12], rtol=1e-5)


def test_an_off_centre_optical_axis_shifts_the_view_by_whole_pixels():
    # cx = 56 on a 128-wide image: column j looks where the centred camera's column j + 8 looks.
    centred, shifted = render.Camera(supersample=2), render.Camera(supersample=2, cx=56.0)
    assert shifted.focal == centred.focal and centred.center_col == 64.0
    pos, rot = np.zeros(3), _yaw(0.0)
    scene = _sphere_only(np.array([2.5, 0.2, -0.1]), radius=0.2)._replace(ambient=1.0)
    a = np.asarray(render.render(scene, pos, rot, centred))
    b = np.asarray(render.render(scene, pos, rot, shifted))
    np.testing.assert_array_equal(b[:, :-8], a[:, 8:])
    assert not np.array_equal(a, b)
    point = np.array([2.5, 0.4, -0.3])
    np.testing.assert_allclose(
        render.project(shifted, pos, rot, point), render.project(centred, pos, rot, point) - np.array([8.0, 0.0])
    )


def test_focal_length_from_field_of_view():
    assert render.Camera(width=128, fov=math.radians(90.0)).focal == pytest.approx(64.0)
    assert render.Camera().focal == pytest.approx(64.0 / math.tan(math.radians(30.0)))


def test_ground_horizon_and_brightness():
    # Level camera 0.5 m above the ground: the top half is sky, the bottom half ground.
    scene = render.Scene(render.no_spheres(), render.no_cylinders(), ambient=1.0)
    img = np.asarray(render.render(scene, jnp.array([0.0, 0.0, 0.5]), jnp.eye(3)))
    np.testing.assert_allclose(img[:64], 0.75)
    np.testing.assert_allclose(img[64:], 0.35)


mujoco = pytest.importorskip("mujoco")

_XML = """
<mujoco>
  <worldbody>
    <geom name="floor" type="plane" size="0 0 1"/>
    <geom name="ball" type="sphere" pos="2 0.5 0.4" size="0.3"/>
    <geom name="post" type="cylinder" pos="3 -1 0.6" size="0.25 0.6"/>
    <geom name="pipe" type="cylinder" pos="4 1.5 0.4" size="0.3 1.0" euler="0 90 30"/>
  </worldbody>
</mujoco>
"""


def test_ray_distances_match_mujoco_mj_ray():
    model = mujoco.MjModel.from_xml_string(_XML)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    pipe_axis = data.geom_xmat[3].reshape(3, 3)[:, 2]
    scene = render.Scene(
        render.spheres([2.0, 0.5, 0.4], 0.3, 0.1),
        render.concat_cylinders(
            render.standing_cylinder(3.0, -1.0, 0.25, 1.2),
            render.Cylinders(
                jnp.array([[4.0, 1.5, 0.4]]),
                jnp.asarray(pipe_axis[None], jnp.float32),
                jnp.array([0.3]),
                jnp.array([1.0]),
                jnp.array([0.1]),
                jnp.array([0.05]),
            ),
        ),
    )
    origin = np.array([0.0, 0.0, 0.45])
    rng = np.random.default_rng(0)
    # Rays aimed at random points on the three bodies and the ground (mj_ray caps cylinders; aim at their walls).
    targets = np.concatenate(
        [
            [2.0, 0.5, 0.4] + rng.uniform(-0.2, 0.2, (20, 3)),
            [3.0, -1.0, 0.6] + rng.uniform(-0.2, 0.2, (20, 3)) * [1, 1, 2.5],
            [4.0, 1.5, 0.4] + np.outer(rng.uniform(-0.6, 0.6, 20), pipe_axis) + rng.uniform(-0.1, 0.1, (20, 3)),
            rng.uniform([1, -3, -0.5], [8, 3, 0.0], (20, 3)),
        ]
    )
    dirs = targets - origin
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    t, _ = render.intersect(scene, jnp.asarray(origin, jnp.float32), jnp.asarray(dirs, jnp.float32))
    expected, caps = [], []
    for d in dirs:
        geomid = np.zeros(1, np.int32)
        dist = mujoco.mj_ray(model, data, origin, d, None, 1, -1, geomid)
        expected.append(dist)
        # MuJoCo's cylinders have end caps, the renderer's pipes are open: leave out rays that hit a cap.
        g = int(geomid[0])
        axial = (origin + dist * d - data.geom_xpos[g]) @ data.geom_xmat[g].reshape(3, 3)[:, 2]
        caps.append(model.geom_type[g] == mujoco.mjtGeom.mjGEOM_CYLINDER and abs(axial) > model.geom_size[g, 1] - 1e-6)
    expected, caps = np.array(expected), np.array(caps)
    hit = (expected >= 0) & ~caps
    assert hit.sum() >= 70
    np.testing.assert_allclose(np.asarray(t)[hit], expected[hit], rtol=1e-4, atol=1e-4)


def test_open_pipe_shows_its_inner_wall_end_on():
    # Looking down the axis of a lying pipe: a ring of inner wall around the dark far opening.
    pipe = render.lying_cylinder([3.0, 0.0, 0.0], 0.0, 0.3, 2.0, 0.2, 0.05)
    scene = render.Scene(render.no_spheres(), pipe, ground_height=-100.0, ground_brightness=0.75, ambient=1.0)
    img = np.asarray(render.render(scene, jnp.array([0.0, 0.0, 0.0]), jnp.eye(3)))
    f = render.Camera().focal
    assert img[64, 64] == pytest.approx(0.75)  # sky through the far end
    near, far = f * 0.3 / 2.0, f * 0.3 / 4.0  # radii of the near and far rims
    ring_col = int(64 + 0.5 * (near + far))
    assert img[64, ring_col] == pytest.approx(0.05)  # inner wall between the rims
    assert img[64, int(64 + near) + 2] == pytest.approx(0.75)  # sky outside the pipe


def test_render_vmaps_over_camera_poses():
    scene = _sphere_only([2.0, 0.0, 0.0])
    poses = jnp.stack([jnp.zeros(3), jnp.array([0.0, 0.3, 0.0])])
    batch = jax.jit(jax.vmap(lambda p: render.render(scene, p, jnp.eye(3))))(poses)
    np.testing.assert_allclose(batch[1], render.render(scene, poses[1], jnp.eye(3)), atol=1e-6)
    # Moving the camera left moves the sphere right in the image.
    assert _disc(batch[1])[0] > _disc(batch[0])[0] + 5


@pytest.mark.parametrize("supersample", [1, 2])
def test_a_band_of_rows_is_those_rows_of_the_whole_frame_exactly(supersample):
    camera = render.Camera(width=64, height=48, supersample=supersample)
    scene = render.Scene(
        render.spheres(jnp.array([2.0, 0.1, 0.2]), 0.3, 0.05), render.no_cylinders(), ground_height=-0.4
    )
    rot = jnp.asarray(_yaw(0.2), jnp.float32)
    whole = jax.jit(lambda: render.render(scene, jnp.zeros(3), rot, camera))()
    band = jax.jit(lambda: render.render(scene, jnp.zeros(3), rot, camera, rows=(10, 30)))()
    assert band.shape == (20, 64)
    np.testing.assert_array_equal(band, whole[10:30])
    assert np.ptp(np.asarray(band)) > 0.3  # the band holds sphere, sky and ground
    with pytest.raises(UserError, match="rows must be"):
        render.render(scene, jnp.zeros(3), rot, camera, rows=(30, 10))


def test_bad_camera_is_a_user_error():
    with pytest.raises(UserError, match="field of view"):
        render.Camera(fov=4.0).validate()
    with pytest.raises(UserError, match="cx"):
        render.Camera(cx=-1.0).validate()


def test_camera_is_static_configuration():
    # A frozen dataclass: hashable, not a pytree, so jit takes it as a static argument.
    camera = render.Camera(width=16, height=8)
    assert jax.tree.leaves(camera) == [camera] and hash(camera) == hash(render.Camera(width=16, height=8))
    scene = _sphere_only([2.0, 0.0, 1.0])
    pos = jnp.array([0.0, 0.0, 1.0])
    img = jax.jit(render.render, static_argnames="camera")(scene, pos, jnp.eye(3), camera=camera)
    assert img.shape == (8, 16)
    np.testing.assert_allclose(img, render.render(scene, pos, jnp.eye(3), camera), atol=1e-6)


def _tube_mesh_xml(radius, wall, length, pos, yaw, n=256):
    """MJCF of a lying pipe as a mesh of ``n`` facets a surface: outer wall, bore, entry face, far plug.

    The entry face is at the mesh origin, the bore runs along +x to the plug's inner face at
    ``length - wall``; the plug's outer face closes the tube at ``length``. mj_ray casts against a
    mesh's triangles, so this is the renderer's pipe up to the facets (a chord error of
    radius * (1 - cos(pi / n)), 2e-5 m).
    """
    ang = 2 * np.pi * np.arange(n) / n
    c, s = np.cos(ang), np.sin(ang)

    def ring(r, x):
        return np.stack([np.full(n, x), r * c, r * s], 1)

    inner, end = radius - wall, length - wall
    verts = np.concatenate(
        [ring(radius, 0), ring(radius, length), ring(inner, 0), ring(inner, end), [[end, 0, 0], [length, 0, 0]]]
    )
    oe, of, ie, fi, fc, bc = 0, n, 2 * n, 3 * n, 4 * n, 4 * n + 1
    faces = []
    for k in range(n):
        j = (k + 1) % n
        faces += [[oe + k, of + k, of + j], [oe + k, of + j, oe + j]]  # outer wall
        faces += [[ie + k, ie + j, fi + j], [ie + k, fi + j, fi + k]]  # bore
        faces += [[oe + k, oe + j, ie + j], [oe + k, ie + j, ie + k]]  # entry face
        faces += [[fi + k, fi + j, fc], [of + k, bc, of + j]]  # the plug's inner and outer faces
    vert = " ".join(f"{v:.9g}" for v in verts.ravel())
    face = " ".join(map(str, np.ravel(faces)))
    return f"""<mujoco><compiler angle="radian"/>
      <asset><mesh name="tube" vertex="{vert}" face="{face}" inertia="shell"/></asset>
      <worldbody><geom name="tube" type="mesh" mesh="tube" pos="{pos[0]} {pos[1]} {pos[2]}" euler="0 0 {yaw}"/></worldbody>
    </mujoco>"""


def _pipes(entry, axis, radius, wall, length, valid=True):
    one = jnp.ones(1)
    return render.Pipes(
        jnp.asarray([entry], jnp.float32),
        jnp.asarray([axis], jnp.float32),
        jnp.array([radius]),
        jnp.array([wall]),
        jnp.array([length]),
        0.1 * one,
        0.05 * one,
        0.9 * one,
        jnp.array([valid]),
    )


def test_pipe_with_wall_matches_mj_ray_on_a_tube_mesh_outside_inside_and_end_on():
    radius, wall, length, yaw = 0.3, 0.03, 2.0, 0.3
    pos = np.array([1.0, 0.2, 0.4])
    model = mujoco.MjModel.from_xml_string(_tube_mesh_xml(radius, wall, length, pos, yaw))
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    axis = np.array([math.cos(yaw), math.sin(yaw), 0.0])
    cylinders, annuli = render.pipe_primitives(_pipes(pos, axis, radius, wall, length))
    scene = render.Scene(render.no_spheres(), cylinders, ground_height=-100.0, annuli=annuli)
    rng = np.random.default_rng(1)
    # In front of the entry (rays into the bore, onto the entry face, the outer wall), inside the bore, beside it.
    for origin in [pos - 1.5 * axis + [0.05, 0.1, 0.02], pos + 0.8 * axis + [0.0, 0.05, -0.05], pos + [0.5, -2.0, 0.3]]:
        targets = pos + np.outer(rng.uniform(-0.1, length + 0.1, 200), axis) + rng.uniform(-radius, radius, (200, 3))
        dirs = targets - origin
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        t, _ = render.intersect(scene, jnp.asarray(origin, jnp.float32), jnp.asarray(dirs, jnp.float32))
        t = np.where(np.asarray(t) > 50.0, -1.0, np.asarray(t))  # the far ground is not in the mesh model
        expected = np.array([mujoco.mj_ray(model, data, origin, d, None, 1, -1, np.zeros(1, np.int32)) for d in dirs])
        assert (expected > 0).sum() > 150
        np.testing.assert_allclose(t, expected, atol=1e-3)


def test_solid_pipe_is_a_capped_cylinder_like_mujocos():
    model = mujoco.MjModel.from_xml_string(
        '<mujoco><worldbody><geom type="cylinder" pos="3 -1 0.6" size="0.25 0.6"/></worldbody></mujoco>'
    )
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    # A standing pipe: entry face (a disc, the wall being the radius) on top, axis down.
    cylinders, annuli = render.pipe_primitives(_pipes([3.0, -1.0, 1.2], [0.0, 0.0, -1.0], 0.25, 0.25, 1.2))
    scene = render.Scene(render.no_spheres(), cylinders, ground_height=-100.0, annuli=annuli)
    origin = np.array([0.0, 0.0, 2.0])  # above the top: the cap is in view
    rng = np.random.default_rng(0)
    targets = np.concatenate(
        [
            [3.0, -1.0, 0.6] + rng.uniform(-0.3, 0.3, (80, 3)) * [1, 1, 2.5],
            [3.0, -1.0, 1.2] + rng.uniform(-0.17, 0.17, (20, 3)) * [1, 1, 0],  # on the top cap
        ]
    )
    dirs = targets - origin
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    t, _ = render.intersect(scene, jnp.asarray(origin, jnp.float32), jnp.asarray(dirs, jnp.float32))
    expected = np.array([mujoco.mj_ray(model, data, origin, d, None, 1, -1, np.zeros(1, np.int32)) for d in dirs])
    on_cap = (expected > 0) & (np.abs(origin[2] + expected * dirs[:, 2] - 1.2) < 1e-6)
    assert (expected > 0).sum() > 70 and on_cap.sum() > 10
    t = np.where(np.asarray(t) > 50.0, -1.0, np.asarray(t))  # the far ground is not in the MJCF
    np.testing.assert_allclose(t, expected, rtol=1e-4, atol=1e-4)
    # A hidden slot is never hit.
    cylinders, annuli = render.pipe_primitives(_pipes([3.0, -1.0, 1.2], [0.0, 0.0, -1.0], 0.25, 0.25, 1.2, False))
    t, _ = render.intersect(scene._replace(cylinders=cylinders, annuli=annuli), jnp.asarray(origin), jnp.asarray(dirs))
    assert np.all(np.asarray(t) > 50.0)


def test_entry_face_shows_the_ring_and_a_closed_far_end():
    # End-on from 2 m: the entry face is a bright annulus between f (R - wall) / 2 and f R / 2 px,
    # the bore and the far cap inside are dark (no background through the pipe).
    radius, wall = 0.3, 0.06
    cylinders, annuli = render.pipe_primitives(_pipes([2.0, 0.0, 0.0], [1.0, 0.0, 0.0], radius, wall, 3.0))
    scene = render.Scene(
        render.no_spheres(), cylinders, ground_height=-100.0, ground_brightness=0.75, ambient=1.0, annuli=annuli
    )
    img = np.asarray(render.render(scene, jnp.zeros(3), jnp.eye(3)))
    f = render.Camera().focal
    inner, outer = f * (radius - wall) / 2.0, f * radius / 2.0
    row = img[64, 64:]
    cols = np.arange(64) + 0.5
    np.testing.assert_allclose(row[cols < inner - 0.5], 0.05)  # bore wall, then the far cap: both dark
    np.testing.assert_allclose(row[(cols > inner + 0.5) & (cols < outer - 0.5)], 0.9)  # the entry face
    np.testing.assert_allclose(row[cols > outer + 0.5], 0.75)  # sky around the pipe


_BOX_XML = """
<mujoco>
  <compiler angle="degree"/>
  <worldbody>
    <geom name="floor" type="plane" size="0 0 1"/>
    <geom name="cube" type="box" pos="1.5 0.3 0.05" size="0.05 0.05 0.05" euler="0 0 0"/>
    <geom name="slab" type="box" pos="2.5 -0.6 0.2" size="0.3 0.1 0.2" euler="0 0 35"/>
    <geom name="post" type="box" pos="3.5 0.8 0.4" size="0.08 0.15 0.4" euler="0 0 -70"/>
  </worldbody>
</mujoco>
"""


def _box_scene(valid=(True, True, True)):
    return render.Scene(
        render.no_spheres(),
        render.no_cylinders(),
        boxes=render.boxes(
            [[1.5, 0.3, 0.05], [2.5, -0.6, 0.2], [3.5, 0.8, 0.4]],
            [[0.05, 0.05, 0.05], [0.3, 0.1, 0.2], [0.08, 0.15, 0.4]],
            np.radians([0.0, 35.0, -70.0]),
            0.1,
            jnp.asarray(valid),
        ),
    )


def test_box_ray_distances_match_mujoco_mj_ray():
    model = mujoco.MjModel.from_xml_string(_BOX_XML)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    rng = np.random.default_rng(1)
    origin = np.array([0.0, 0.05, 0.12])
    # Rays aimed at random points in each box (faces seen edge-on to face-on, top faces from above) and the floor.
    targets = np.concatenate(
        [data.geom_xpos[g] + rng.uniform(-1, 1, (25, 3)) * model.geom_size[g] * 1.3 for g in (1, 2, 3)]
        + [rng.uniform([0.5, -2, -0.2], [5, 2, 0.0], (15, 3))]
    )
    dirs = targets - origin
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    t, _ = render.intersect(_box_scene(), jnp.asarray(origin, jnp.float32), jnp.asarray(dirs, jnp.float32))
    expected = np.array([mujoco.mj_ray(model, data, origin, d, None, 1, -1, np.zeros(1, np.int32)) for d in dirs])
    hit = expected >= 0
    assert hit.sum() >= 70
    np.testing.assert_allclose(np.asarray(t)[hit], expected[hit], rtol=1e-4, atol=1e-4)
    # A hidden slot is never hit: the rays that met the cube now go on to what is behind it.
    t_hidden, _ = render.intersect(
        _box_scene((False, True, True)), jnp.asarray(origin, jnp.float32), jnp.asarray(dirs[:25], jnp.float32)
    )
    model.geom_rgba[1, 3] = 0.0  # mj_ray skips transparent geoms
    cube_gone = np.array([mujoco.mj_ray(model, data, origin, d, None, 1, -1, np.zeros(1, np.int32)) for d in dirs[:25]])
    np.testing.assert_allclose(np.asarray(t_hidden), np.where(cube_gone >= 0, cube_gone, 1e6), rtol=1e-4, atol=1e-4)


def test_box_faces_are_shaded_by_their_normals_and_project_as_pinhole():
    # A cube ahead seen face-on under a light along -x of the camera: its front face gets the full light.
    camera = render.Camera(width=96, height=96, supersample=1)
    scene = render.Scene(
        render.no_spheres(),
        render.no_cylinders(),
        ground_height=-100.0,
        light=(-1.0, 0.0, 0.0),
        ambient=0.2,
        boxes=render.boxes([2.0, 0.0, 1.0], 0.25, 0.0, 0.5),
    )
    img = np.asarray(render.render(scene, jnp.array([0.0, 0.0, 1.0]), jnp.eye(3), camera))
    dark = np.asarray(render.depth(scene, jnp.array([0.0, 0.0, 1.0]), jnp.eye(3), camera)) < 10.0
    # Front face at x = 1.75: half width 0.25 m spans f * 0.25 / 1.75 pixels either side of the centre.
    half_px = camera.focal * 0.25 / 1.75
    cols = np.nonzero(dark.any(axis=0))[0]
    assert cols.min() == pytest.approx(48 - half_px, abs=1.0) and cols.max() + 1 == pytest.approx(48 + half_px, abs=1.0)
    np.testing.assert_allclose(img[48, 48], 0.5)  # lambert 1 on the face turned towards the light
    # Turned by 45 deg about z, the two visible faces get cos 45 deg each: 0.5 (0.2 + 0.8 cos 45).
    turned = scene._replace(boxes=render.boxes([2.0, 0.0, 1.0], 0.25, math.radians(45.0), 0.5))
    img = np.asarray(render.render(turned, jnp.array([0.0, 0.0, 1.0]), jnp.eye(3), camera))
    np.testing.assert_allclose(img[48, 44], 0.5 * (0.2 + 0.8 * math.cos(math.radians(45.0))), rtol=1e-5)
    np.testing.assert_allclose(img[48, 52], 0.5 * (0.2 + 0.8 * math.cos(math.radians(45.0))), rtol=1e-5)


def test_boxes_render_batched_under_vmap_with_traced_positions():
    camera = render.Camera(width=32, height=24)
    base = render.Scene(render.no_spheres(), render.no_cylinders(), boxes=render.boxes([2.0, 0.0, 0.1], 0.1))
    xs = jnp.array([1.5, 2.0, 3.0])

    def one(x):
        scene = base._replace(boxes=base.boxes._replace(center=jnp.stack([x, 0.0, 0.1])[None]))
        return render.render(scene, jnp.array([0.0, 0.0, 0.15]), jnp.eye(3), camera)

    batch = jax.jit(jax.vmap(one))(xs)
    for i, x in enumerate(np.asarray(xs)):
        np.testing.assert_allclose(batch[i], one(x), atol=1e-6)
    assert not np.allclose(batch[0], batch[2])


def test_a_flat_scene_renders_the_shading_formula_exactly_without_the_normals():
    # ambient the number 1 takes the shortcut; the same scene with ambient traced runs the formula.
    camera = render.Camera(width=64, height=48)
    scene = render.Scene(
        render.spheres([[2.5, 0.6, 0.3]], [0.3], [0.2]),
        render.standing_cylinder(3.0, -0.8, 0.2, 0.8, brightness=0.3),
        ground_brightness=0.6,
        sky_brightness=0.9,
        ambient=1.0,
        annuli=render.Annuli(
            jnp.array([[4.0, 0.0, 0.5]]), jnp.array([[-1.0, 0.0, 0.0]]), jnp.array([0.1]), jnp.array([0.3]),
            jnp.array([0.45]),
        ),
        boxes=render.boxes([2.0, 0.1, 0.1], 0.1, 0.4, 0.1),
    )  # fmt: skip
    pos, rot = jnp.array([0.0, 0.0, 0.4]), jnp.asarray(_yaw(0.1))
    flat = np.asarray(jax.jit(lambda p: render.render(scene, p, rot, camera))(pos))
    traced = np.asarray(jax.jit(lambda p, a: render.render(scene._replace(ambient=a), p, rot, camera))(pos, 1.0))
    np.testing.assert_array_equal(flat, traced)
    assert set(np.unique(flat)) == {np.float32(v) for v in (0.2, 0.3, 0.45, 0.1, 0.6, 0.9)}
