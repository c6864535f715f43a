"""A pinhole camera that ray-casts spheres, open cylinders, flat annuli, boxes and a ground plane in JAX.

Each pixel casts one ray (or ``supersample**2`` rays, averaged) from the camera
centre and takes the brightness of the nearest surface it hits. Intersections
are closed forms (a quadratic per sphere and per cylinder, a division for the
plane), so a 128 x 128 frame of a few primitives is a handful of fused array
operations that ``jit`` and ``vmap`` like any other JAX function (an annulus
or disc is one plane intersection and a radius test, a box the slab test of
Kay and Kajiya in its own yawed frame); the camera
pose is a traced input, so a batch of robots renders a batch of frames in the
same compiled program as their physics.

The renderer knows nothing of robots: it takes a camera position and
orientation and a `Scene` of primitive arrays; its `Camera` (image size and
field of view) is static configuration, a frozen dataclass that ``jit`` never
traces.

Conventions
-----------
* World frame: z is up; the ground is the plane ``z = ground_height``.
* Camera frame (the columns of ``rot``, in world coordinates): x forward along
  the optical axis, y to the left, z up, the usual body frame of a robot.
* Image: ``(height, width)``, row 0 at the top, column 0 on the left. Pixel
  ``(row, col)`` looks through the point ``(col + 0.5, row + 0.5)`` of the image
  plane, so the optical axis meets the image at ``(c_x, height / 2)``, where
  ``c_x`` (`Camera.center_col`) is ``width / 2`` unless set: by default the
  corner shared by the four central pixels.
* Pinhole model: with horizontal field of view ``fov`` the focal length in
  pixels is ``f = (width / 2) / tan(fov / 2)``; a point at camera coordinates
  ``(x, y, z)``, ``x > 0``, is seen at column ``c_x - f y / x`` and row
  ``height / 2 - f z / x``. A ``c_x`` off the centre is a lens mounted off the
  sensor's centre: the same focal length, the view shifted sideways. A sphere of radius ``R`` centred on the axis at
  distance ``d`` covers a disc of radius ``f R / sqrt(d**2 - R**2)`` pixels.
* A pipe with a wall (`Pipes`) is drawn by `pipe_primitives` as its outer
  tube, its bore (a second tube of radius ``radius - wall``), the annular
  entry face and a disc closing the far end.
* A box (`Boxes`) is axis-aligned in its own frame, turned by ``yaw`` about
  the world z axis: a cuboid standing on the floor, as the hexapod's prey are.
* Brightness is in [0, 1]: each primitive has its own, optionally shaded by a
  directional light (``ambient + (1 - ambient) * max(0, n . light)``).
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from spikejax.errors import UserError

__all__ = [
    "Camera",
    "Spheres",
    "Cylinders",
    "Annuli",
    "Pipes",
    "Boxes",
    "Scene",
    "spheres",
    "no_spheres",
    "no_cylinders",
    "no_annuli",
    "boxes",
    "no_boxes",
    "pipe_primitives",
    "standing_cylinder",
    "lying_cylinder",
    "concat_cylinders",
    "ray_directions",
    "project",
    "intersect",
    "render",
    "depth",
]

_FAR = 1e6  # "no hit": farther than anything in a scene


@dataclasses.dataclass(frozen=True)
class Camera:
    """Static intrinsics: image size in pixels, horizontal field of view in radians.

    A frozen dataclass (hashable, not a pytree): the image size sets array
    shapes, so a camera is configuration, closed over or passed as a static
    argument, never traced. ``supersample`` casts ``supersample**2`` rays a pixel.

    The default, 128 x 128 pixels, is the DVS128 sensor both snake papers
    simulate; neither paper states the field of view, so the default is 60
    degrees (1.047 rad), the default ``horizontal_fov`` of a Gazebo camera.
    ``cx``, the column where the optical axis meets the image (``None``:
    ``width / 2``), shifts the view sideways without changing ``fov``'s
    focal length.
    """

    width: int = 128
    height: int = 128
    fov: float = math.radians(60.0)
    supersample: int = 1
    cx: float | None = None

    @property
    def center_col(self) -> float:
        """The optical axis's column, ``cx`` or ``width / 2``."""
        return 0.5 * self.width if self.cx is None else float(self.cx)

    @property
    def focal(self) -> float:
        """Focal length in pixels, ``(width / 2) / tan(fov / 2)``."""
        return 0.5 * self.width / math.tan(0.5 * self.fov)

    def validate(self) -> "Camera":
        if self.width < 1 or self.height < 1:
            raise UserError(f"camera size must be positive, got {self.width} x {self.height}")
        if not 0.0 < self.fov < math.pi:
            raise UserError(f"camera field of view must be in (0, pi) radians, got {self.fov}")
        if self.supersample < 1:
            raise UserError(f"camera supersample must be >= 1, got {self.supersample}")
        if self.cx is not None and not 0.0 <= self.cx <= self.width:
            raise UserError(f"camera cx must be within the image's 0-{self.width} columns, got {self.cx}")
        return self


class Spheres(NamedTuple):
    """``n`` spheres: centres ``(n, 3)``, radii ``(n,)``, brightness ``(n,)``."""

    center: jax.Array
    radius: jax.Array
    brightness: jax.Array


class Cylinders(NamedTuple):
    """``n`` open tubes (pipes, no end caps): a hollow pipe shows its inside.

    ``center (n, 3)`` is the middle of the axis, ``axis (n, 3)`` a unit vector
    along it, ``radius (n,)``, ``half_length (n,)``; the outer wall has
    ``brightness (n,)`` and the inner wall ``inner_brightness (n,)``.
    """

    center: jax.Array
    axis: jax.Array
    radius: jax.Array
    half_length: jax.Array
    brightness: jax.Array
    inner_brightness: jax.Array


class Annuli(NamedTuple):
    """``n`` flat rings: the points ``p`` of the plane through ``center`` normal to ``normal`` with
    ``inner <= |p - center| <= outer``; ``inner = 0`` makes a disc (an end cap).

    ``center (n, 3)``, ``normal (n, 3)`` unit vectors, ``inner (n,)``,
    ``outer (n,)``, ``brightness (n,)``. A ring is seen from both sides (its
    shading uses the normal turned towards the camera); ``outer < 0`` hides it,
    so a fixed number of slots can hold fewer rings.
    """

    center: jax.Array
    normal: jax.Array
    inner: jax.Array
    outer: jax.Array
    brightness: jax.Array


class Pipes(NamedTuple):
    """``n`` pipes with a wall thickness, each drawn as two tubes and two flat rings (`pipe_primitives`).

    A pipe runs from its entry, the open end at ``entry (n, 3)`` (the centre
    of the end face), along the unit ``axis (n, 3)`` pointing into the bore,
    for ``length (n,)``, and has outer ``radius (n,)`` and wall ``wall (n,)``.
    The entry face is an annulus between ``radius - wall`` and ``radius``; the
    far end is closed by a disc, so looking into the bore shows the inner
    wall and the dark end cap, never the background (one ring to detect, not
    two). ``wall = radius`` gives a solid cylinder, closed at both ends (a
    standing pipe's capped top is its "entry" face then). ``valid (n,)``
    (bool) hides the unused slots of a fixed-size scene. Brightness:
    ``brightness`` the outer wall, ``inner_brightness`` the bore and the far
    cap inside, ``ring_brightness`` the entry face.
    """

    entry: jax.Array
    axis: jax.Array
    radius: jax.Array
    wall: jax.Array
    length: jax.Array
    brightness: jax.Array
    inner_brightness: jax.Array
    ring_brightness: jax.Array
    valid: jax.Array


def pipe_primitives(pipes: Pipes) -> tuple[Cylinders, Annuli]:
    """The tubes and rings that draw ``pipes``: per pipe, ``(outer tube, bore)`` and ``(entry face, far cap)``.

    Returns ``Cylinders`` of ``2 n`` tubes (outer walls, then bores) and
    ``Annuli`` of ``2 n`` rings (entry faces, then far caps). A hidden pipe
    gets a negative half length and outer radius (never hit); a solid pipe
    (``wall >= radius``) has no bore, and its entry face is a disc. The far
    cap is a ``wall`` thick plug: its disc is drawn at the bore's end,
    ``length - wall`` from the entry, the face seen from inside.
    """
    n = pipes.radius.shape[0]
    valid = jnp.asarray(pipes.valid, bool)
    half = 0.5 * pipes.length
    center = pipes.entry + half[:, None] * pipes.axis
    bore = jnp.maximum(pipes.radius - pipes.wall, 0.0)
    hidden = -jnp.ones((n,), jnp.float32)
    outer_half = jnp.where(valid, half, hidden)
    bore_half = jnp.where(valid & (bore > 0), half, hidden)
    cyl = Cylinders(
        jnp.concatenate([center, center]),
        jnp.concatenate([pipes.axis, pipes.axis]),
        jnp.concatenate([pipes.radius, jnp.where(bore > 0, bore, 1.0)]),
        jnp.concatenate([outer_half, bore_half]),
        jnp.concatenate([pipes.brightness, pipes.inner_brightness]),
        jnp.concatenate([pipes.brightness, pipes.inner_brightness]),
    )
    far = pipes.entry + (pipes.length - jnp.minimum(pipes.wall, pipes.length))[:, None] * pipes.axis
    outer = jnp.where(valid, pipes.radius, hidden)
    ann = Annuli(
        jnp.concatenate([pipes.entry, far]),
        jnp.concatenate([pipes.axis, pipes.axis]),
        jnp.concatenate([bore, jnp.zeros((n,), jnp.float32)]),
        jnp.concatenate([outer, outer]),
        jnp.concatenate([pipes.ring_brightness, pipes.inner_brightness]),
    )
    return cyl, ann


def no_annuli() -> Annuli:
    z = jnp.zeros((0,), jnp.float32)
    return Annuli(jnp.zeros((0, 3)), jnp.zeros((0, 3)), z, z, z)


class Boxes(NamedTuple):
    """``n`` solid cuboids, each axis-aligned in its own frame turned by ``yaw`` about the world z axis.

    ``center (n, 3)``, ``half (n, 3)`` half edges along the box's own x, y, z
    (the box's x axis is at angle ``yaw (n,)`` from the world x axis),
    ``brightness (n,)``. ``valid (n,)`` (bool) hides the unused slots of a
    fixed-size scene (a removed prey).
    """

    center: jax.Array
    half: jax.Array
    yaw: jax.Array
    brightness: jax.Array
    valid: jax.Array


def boxes(center, half, yaw=0.0, brightness=0.1, valid=True) -> Boxes:
    """Boxes from array-likes; one box may be given unbatched (``center`` of shape (3,)); scalars broadcast."""
    center = jnp.asarray(center, jnp.float32).reshape(-1, 3)
    n = center.shape[0]
    return Boxes(
        center,
        jnp.broadcast_to(jnp.asarray(half, jnp.float32), (n, 3)),
        jnp.broadcast_to(jnp.asarray(yaw, jnp.float32), (n,)),
        jnp.broadcast_to(jnp.asarray(brightness, jnp.float32), (n,)),
        jnp.broadcast_to(jnp.asarray(valid, bool), (n,)),
    )


def no_boxes() -> Boxes:
    return boxes(jnp.zeros((0, 3)), 1.0)


class Scene(NamedTuple):
    """What the camera sees: spheres, cylinders, flat rings, boxes, the ground and the sky.

    The numbers of spheres, cylinders, rings and boxes are static (array
    shapes); any may be zero (``annuli=None`` or ``boxes=None`` is none). All
    fields may be traced (a moving target is a traced centre).
    """

    spheres: Spheres
    cylinders: Cylinders
    ground_height: jax.Array | float = 0.0
    ground_brightness: jax.Array | float = 0.35
    sky_brightness: jax.Array | float = 0.75
    light: jax.Array | tuple = (0.3, -0.2, 0.93)  # direction towards the light, world frame
    ambient: jax.Array | float = 0.6
    annuli: Annuli | None = None
    boxes: Boxes | None = None


def spheres(center, radius, brightness) -> Spheres:
    """Spheres from array-likes; a single sphere may be given unbatched (``center`` of shape (3,))."""
    center = jnp.asarray(center, jnp.float32).reshape(-1, 3)
    n = center.shape[0]
    return Spheres(
        center,
        jnp.broadcast_to(jnp.asarray(radius, jnp.float32), (n,)),
        jnp.broadcast_to(jnp.asarray(brightness, jnp.float32), (n,)),
    )


def no_spheres() -> Spheres:
    return spheres(jnp.zeros((0, 3)), 1.0, 0.0)


def no_cylinders() -> Cylinders:
    z = jnp.zeros((0,), jnp.float32)
    return Cylinders(jnp.zeros((0, 3)), jnp.zeros((0, 3)), z, z, z, z)


def standing_cylinder(x, y, radius, height, brightness=0.1, inner_brightness=0.05, base=0.0) -> Cylinders:
    """One vertical pipe standing on the ground at ``(x, y)``, ``height`` tall."""
    return Cylinders(
        jnp.asarray([[x, y, base + 0.5 * height]], jnp.float32),
        jnp.asarray([[0.0, 0.0, 1.0]]),
        jnp.asarray([radius], jnp.float32),
        jnp.asarray([0.5 * height], jnp.float32),
        jnp.asarray([brightness], jnp.float32),
        jnp.asarray([inner_brightness], jnp.float32),
    )


def lying_cylinder(center, yaw, radius, length, brightness=0.1, inner_brightness=0.05) -> Cylinders:
    """One horizontal pipe centred at ``center`` (3,), its axis at angle ``yaw`` from the world x axis."""
    axis = jnp.stack([jnp.cos(yaw), jnp.sin(yaw), 0.0 * yaw])[None].astype(jnp.float32)
    return Cylinders(
        jnp.asarray(center, jnp.float32).reshape(1, 3),
        axis,
        jnp.asarray([radius], jnp.float32),
        jnp.asarray([0.5 * length], jnp.float32),
        jnp.asarray([brightness], jnp.float32),
        jnp.asarray([inner_brightness], jnp.float32),
    )


def concat_cylinders(*cyls: Cylinders) -> Cylinders:
    """Several `Cylinders` as one."""
    return Cylinders(*(jnp.concatenate(parts, axis=0) for parts in zip(*cyls)))


def _local_directions(camera: Camera) -> np.ndarray:
    s = camera.supersample
    f = camera.focal
    cols = (np.arange(camera.width * s) + 0.5) / s - camera.center_col
    rows = (np.arange(camera.height * s) + 0.5) / s - 0.5 * camera.height
    col, row = np.meshgrid(cols, rows)
    d = np.stack([np.full_like(col, f), -col, -row], axis=-1)
    return (d / np.linalg.norm(d, axis=-1, keepdims=True)).astype(np.float32)


def ray_directions(camera: Camera) -> jax.Array:
    """Unit ray directions in the camera frame, ``(height * s, width * s, 3)`` for supersample ``s``."""
    return jnp.asarray(_local_directions(camera))


def project(camera: Camera, cam_pos, rot, point) -> jax.Array:
    """Image coordinates ``(col, row)`` (continuous, pixel corners at integers) of a world point.

    The pinhole model of the module docstring; valid for points in front of the camera.
    """
    p = jnp.asarray(rot).T @ (jnp.asarray(point) - jnp.asarray(cam_pos))
    f = camera.focal
    return jnp.stack([camera.center_col - f * p[1] / p[0], 0.5 * camera.height - f * p[2] / p[0]])


def _light(scene: Scene) -> tuple[jax.Array, jax.Array, jax.Array]:
    light = jnp.asarray(scene.light, jnp.float32)
    light = light / jnp.linalg.norm(light)
    return light[0], light[1], light[2]


def _flat(scene: Scene) -> bool:
    """Whether the scene's light is known, when tracing, to shade nothing (``ambient`` the number 1)."""
    return isinstance(scene.ambient, (int, float)) and scene.ambient == 1


def _shade(scene: Scene, base, nx, ny, nz):
    """Brightness ``base`` lit by the scene's light on a surface of unit normal ``(nx, ny, nz)``.

    In a `_flat` scene it is ``base`` itself, the formula's exact value for
    any finite normal (``base * (1 + 0 * lambert)``), and the normals'
    arithmetic drops out of the program: a fifth of the hexapod's render,
    whose scene is flat (docs/BENCHMARKS.md).
    """
    if _flat(scene):
        return jnp.asarray(base, jnp.float32)
    lx, ly, lz = _light(scene)
    lambert = jnp.maximum(nx * lx + ny * ly + nz * lz, 0.0)
    return base * (scene.ambient + (1.0 - scene.ambient) * lambert)


def intersect(scene: Scene, origin, dirs) -> tuple[jax.Array, jax.Array]:
    """Distance to the nearest surface along each ray and its shaded brightness.

    ``origin`` (3,), ``dirs`` (..., 3) unit vectors, all in the world frame.
    Returns ``(t, brightness)`` of shape ``dirs.shape[:-1]``; rays that hit
    nothing have ``t = 1e6`` and the sky's brightness.

    Every primitive is one elementwise pass over the rays' three components;
    the nearest hit so far is kept with ``where`` (the first of equal
    distances wins). Written without small matrix products or gathers: under
    ``vmap`` on a CPU, XLA runs those far slower than the elementwise form.
    """
    dx, dy, dz = (dirs[..., k] for k in range(3))
    ox, oy, oz = (origin[k] for k in range(3))
    eps = 1e-4
    # Ground plane z = h, seen from above: normal +z.
    t_best = (scene.ground_height - oz) / jnp.where(dz < 0, dz, -1.0)
    t_best = jnp.where((dz < 0) & (oz > scene.ground_height) & (t_best > eps), t_best, _FAR)
    b_best = jnp.broadcast_to(_shade(scene, scene.ground_brightness, 0.0, 0.0, 1.0), t_best.shape)

    def keep_nearest(t, b):
        closer = t < t_best
        return jnp.where(closer, t, t_best), jnp.where(closer, b, b_best)

    sph = scene.spheres
    for i in range(sph.center.shape[0]):
        # |o + t d - c|^2 = R^2 with |d| = 1: t^2 + 2 b t + c = 0.
        cx, cy, cz = sph.center[i, 0], sph.center[i, 1], sph.center[i, 2]
        r = sph.radius[i]
        wx, wy, wz = ox - cx, oy - cy, oz - cz
        b = dx * wx + dy * wy + dz * wz
        c = wx * wx + wy * wy + wz * wz - r * r
        disc = b * b - c
        root = jnp.sqrt(jnp.maximum(disc, 0.0))
        t0, t1 = -b - root, -b + root
        t = jnp.where(t0 > eps, t0, t1)
        t = jnp.where((disc >= 0) & (t > eps), t, _FAR)
        shade = _shade(scene, sph.brightness[i], (wx + t * dx) / r, (wy + t * dy) / r, (wz + t * dz) / r)
        t_best, b_best = keep_nearest(t, shade)

    cyl = scene.cylinders
    for i in range(cyl.center.shape[0]):
        # Perpendicular parts to the axis: |w_p + t d_p|^2 = R^2, then |(w + t d) . a| <= half_length.
        ax, ay, az = cyl.axis[i, 0], cyl.axis[i, 1], cyl.axis[i, 2]
        r = cyl.radius[i]
        wx, wy, wz = ox - cyl.center[i, 0], oy - cyl.center[i, 1], oz - cyl.center[i, 2]
        da = dx * ax + dy * ay + dz * az
        wa = wx * ax + wy * ay + wz * az
        dpx, dpy, dpz = dx - da * ax, dy - da * ay, dz - da * az
        wpx, wpy, wpz = wx - wa * ax, wy - wa * ay, wz - wa * az
        qa = dpx * dpx + dpy * dpy + dpz * dpz
        qb = dpx * wpx + dpy * wpy + dpz * wpz
        qc = wpx * wpx + wpy * wpy + wpz * wpz - r * r
        disc = qb * qb - qa * qc
        root = jnp.sqrt(jnp.maximum(disc, 0.0))
        safe_a = jnp.where(qa > 1e-12, qa, 1.0)
        t0, t1 = (-qb - root) / safe_a, (-qb + root) / safe_a

        def on_tube(t):
            return (disc >= 0) & (qa > 1e-12) & (t > eps) & (jnp.abs(wa + t * da) <= cyl.half_length[i])

        first = on_tube(t0)
        t = jnp.where(first, t0, jnp.where(on_tube(t1), t1, _FAR))
        # The far root seen first means the ray looks at the inside wall: the normal points inwards.
        sign = jnp.where(first, 1.0, -1.0) / r
        base = jnp.where(first, cyl.brightness[i], cyl.inner_brightness[i])
        shade = _shade(scene, base, sign * (wpx + t * dpx), sign * (wpy + t * dpy), sign * (wpz + t * dpz))
        t_best, b_best = keep_nearest(t, shade)

    ann = scene.annuli
    for i in range(0 if ann is None else ann.center.shape[0]):
        # Plane (p - c) . n = 0 at t = (c - o) . n / (d . n), then inner <= |p - c| <= outer.
        nx, ny, nz = ann.normal[i, 0], ann.normal[i, 1], ann.normal[i, 2]
        wx, wy, wz = ann.center[i, 0] - ox, ann.center[i, 1] - oy, ann.center[i, 2] - oz
        dn = dx * nx + dy * ny + dz * nz
        wn = wx * nx + wy * ny + wz * nz
        t = wn / jnp.where(jnp.abs(dn) > 1e-12, dn, 1.0)
        px, py, pz = t * dx - wx, t * dy - wy, t * dz - wz
        r2 = px * px + py * py + pz * pz
        inner, outer = ann.inner[i], ann.outer[i]
        hit = (jnp.abs(dn) > 1e-12) & (t > eps) & (outer > 0) & (r2 <= outer * outer) & (r2 >= inner * inner)
        t = jnp.where(hit, t, _FAR)
        # The face turned towards the camera: its normal points against the ray.
        facing = jnp.where(dn < 0, 1.0, -1.0)
        shade = _shade(scene, ann.brightness[i], facing * nx, facing * ny, facing * nz)
        t_best, b_best = keep_nearest(t, shade)

    box = scene.boxes
    for i in range(0 if box is None else box.center.shape[0]):
        # Slab test in the box's frame (world turned by -yaw about z): per axis the ray is between the
        # two faces for t in [min(t1, t2), max(t1, t2)], t1,2 = (+-half - w) / d; it hits the box when the
        # latest entry comes before the earliest exit. The entry's axis names the face hit.
        c, s = jnp.cos(box.yaw[i]), jnp.sin(box.yaw[i])
        wx, wy, wz = ox - box.center[i, 0], oy - box.center[i, 1], oz - box.center[i, 2]
        local_w = (c * wx + s * wy, -s * wx + c * wy, wz)
        local_d = (c * dx + s * dy, -s * dx + c * dy, dz)
        near, far, axis, sign = None, None, None, None
        for k in range(3):
            h = box.half[i, k]
            dk = local_d[k]
            inv = 1.0 / jnp.where(jnp.abs(dk) > 1e-12, dk, 1e-12)
            ta, tb = (-h - local_w[k]) * inv, (h - local_w[k]) * inv
            lo, hi = jnp.minimum(ta, tb), jnp.maximum(ta, tb)
            face = jnp.where(dk > 0, -1.0, 1.0)  # the face entered has its normal against the ray
            if k == 0:
                near, far, axis, sign = lo, hi, jnp.zeros(lo.shape, jnp.int32), face
            else:
                later = lo > near
                near = jnp.where(later, lo, near)
                axis = jnp.where(later, k, axis)
                sign = jnp.where(later, face, sign)
                far = jnp.minimum(far, hi)
        hit = box.valid[i] & (near <= far) & (far > eps)
        # From inside (near <= eps) the ray meets the far wall; a solid box is never seen that way from outside.
        t = jnp.where(hit, jnp.where(near > eps, near, far), _FAR)
        lx = jnp.where(axis == 0, sign, 0.0)
        ly = jnp.where(axis == 1, sign, 0.0)
        lz = jnp.where(axis == 2, sign, 0.0)
        shade = _shade(scene, box.brightness[i], c * lx - s * ly, s * lx + c * ly, lz)
        t_best, b_best = keep_nearest(t, shade)

    bright = jnp.where(t_best < _FAR, b_best, scene.sky_brightness)
    return t_best, jnp.clip(bright, 0.0, 1.0)


def _world_directions(camera: Camera, rot, rows: tuple[int, int] | None = None) -> jax.Array:
    """The camera's ray directions (`ray_directions`) rotated into the world frame, ``(h, w, 3)``.

    ``rows``: only the rays of those image rows (supersampled rows included).
    """
    local = _local_directions(camera)
    if rows is not None:
        s = camera.supersample
        local = local[rows[0] * s : rows[1] * s]
    rot = jnp.asarray(rot, jnp.float32)
    return jnp.stack(
        [local[..., 0] * rot[k, 0] + local[..., 1] * rot[k, 1] + local[..., 2] * rot[k, 2] for k in range(3)], axis=-1
    )


def render(scene: Scene, cam_pos, rot, camera: Camera = Camera(), *, rows: tuple[int, int] | None = None) -> jax.Array:
    """The frame the camera at ``cam_pos`` (3,) with orientation ``rot`` (3, 3) sees.

    ``rot``'s columns are the camera's forward, left and up axes in the world
    frame (see the module docstring). Returns ``(height, width)`` float32
    brightness in [0, 1]; with ``camera.supersample = s`` each pixel is the mean
    of an ``s x s`` grid of rays, which antialiases the edges.

    ``rows = (row0, row1)`` renders only the image rows ``row0 .. row1 - 1``
    and returns them, ``(row1 - row0, width)``: the same pixels as the whole
    frame's, at the cost of those rows (a reader of a band of the image, such
    as a region of interest, pays for that band only).

    Raises:
        UserError: if ``rows`` is not a non-empty range within the image.
    """
    height = camera.height
    if rows is not None:
        row0, row1 = (int(r) for r in rows)
        if not 0 <= row0 < row1 <= camera.height:
            raise UserError(f"rows must be (row0, row1) with 0 <= row0 < row1 <= {camera.height}, got {tuple(rows)}")
        rows, height = (row0, row1), row1 - row0
    cam_pos = jnp.asarray(cam_pos, jnp.float32)
    _, bright = intersect(scene, cam_pos, _world_directions(camera, rot, rows))
    s = camera.supersample
    if s > 1:
        bright = bright.reshape(height, s, camera.width, s).mean(axis=(1, 3))
    return bright


def depth(scene: Scene, cam_pos, rot, camera: Camera = Camera()) -> jax.Array:
    """Distance along each pixel's central ray to the nearest surface (1e6 for the sky), ``(height, width)``."""
    dirs = _world_directions(dataclasses.replace(camera, supersample=1), rot)
    t, _ = intersect(scene, jnp.asarray(cam_pos, jnp.float32), dirs)
    return t
