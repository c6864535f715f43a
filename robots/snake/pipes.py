"""A world with pipes for the snake: scene files, random placements, the camera's view, physics and truth.

The pipe-tracking paper's scenes (section 3.1; Fig. 4) hold one pipe: a
standing one, seen as two parallel edges, or a lying one, whose entry is seen
as a ring. Neither sizes nor placements are given; those here are the reading
notes' (``specs/snake-pipe``: SPEC.md section 5, ACCEPTANCE.md "Default
scene"): a standing pipe of diameter 0.25 m and height 2 m, a lying pipe of
inner diameter 0.5 m (wall 0.01 m) and length 3 m, 2-4 m ahead of the snake,
0.3-1.2 m to one side, a lying pipe's axis within 20 degrees of the line of
sight.

A scene is data (`PipeScene`): the snake's start and a fixed number of pipe
slots, each with a ``valid`` flag, all traced arrays, so that scenes of
different contents batch under ``vmap`` in one compiled program. It comes
from a TOML file (`load_scene`, the form of issue 15)::

    [snake]
    x = 0.0
    y = 0.0
    yaw_deg = 0.0        # heading; 0 = along +x

    [[pipe]]
    kind = "standing"    # or "lying"
    x = 3.0              # centre of the base (standing) or of the entry (lying), m
    y = 0.8
    yaw_deg = 180.0      # lying: direction the entry faces
    radius = 0.125       # outer radius, m
    wall = 0.01          # m
    length = 2.0         # height (standing) or length (lying), m

with the optional keys ``brightness`` (outer wall), ``inner_brightness``
(bore and far cap) and ``ring_brightness`` (entry face) in [0, 1]; or from
`sample` (one random placement per key, for the reproduction's four
situations).

What each part gives the pipe env built on top of it:

* the head camera's view: `render_pipes` (for `spikejax.vision.render`) and
  `robots.snake.camera.pipe_scene` (ground and sky, no target sphere);
* physical pipes: `bodies_for` sizes the model's mocap bodies
  (`robots.snake.physics.PipeBodies`) and `place_pipes` puts a scene's pipes
  into a physics state, per episode, without recompiling;
  `robots.snake.physics.start_at` puts the snake at the scene's start;
* ground truth per step (`truth`, `reached`, `entered`, `clearance`), pure
  functions of the physics state and the scene, for metrics only: a
  controller must never read them.

Conventions: world frame z up; angles in radians inside (degrees only in the
files); "lateral" and "bearing" are positive when the pipe is on the
camera's **right** (the sign of the steering that turns towards it, ``C =
+1`` of Alg. 3 and ``action[0] > 0`` of the snake env); image columns as in
`spikejax.vision.render` (0 on the left, the optical axis at ``width / 2``).
"""

from __future__ import annotations

import dataclasses
import math
import pathlib
import tomllib
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from robots.snake import physics
from spikejax.errors import UserError
from spikejax.vision import render

__all__ = [
    "KINDS",
    "LEFT",
    "LYING",
    "MAX_PIPES",
    "RIGHT",
    "SITUATIONS",
    "STANDING",
    "Placement",
    "PipeScene",
    "PipeTruth",
    "bodies_for",
    "clearance",
    "collided",
    "default_bodies",
    "entered",
    "line_offset",
    "load_scene",
    "parse_scene",
    "place_pipes",
    "reached",
    "render_pipes",
    "sample",
    "truth",
]

STANDING, LYING = 0, 1
KINDS = {"standing": STANDING, "lying": LYING}
LEFT, RIGHT = -1, 1
# The reproduction's four situations (section 3.2): (kind, side).
SITUATIONS = {
    "standing-left": (STANDING, LEFT),
    "standing-right": (STANDING, RIGHT),
    "lying-left": (LYING, LEFT),
    "lying-right": (LYING, RIGHT),
}
MAX_PIPES = 4  # default number of pipe slots of a loaded scene

STANDING_BRIGHTNESS = (0.1, 0.05, 0.1)  # outer wall, bore, top cap: dark against floor 0.4 and sky 0.8
LYING_BRIGHTNESS = (0.1, 0.05, 0.9)  # outer wall, bore and far cap, the bright entry face
SNAKE_LENGTH = 1.70  # m, from the head camera back to the tail's end (snake.xml)
SNAKE_HALF_WIDTH = 0.035  # m, the head's radius (the modules' is 0.03)
REACH_DISTANCE = 0.3  # m, ACCEPTANCE.md #1 and #2 ("approach")
ENTRY_MARGIN = 0.05  # m, ACCEPTANCE.md #2: radial offset <= bore radius - margin
ENTRY_HEADING = math.radians(30.0)  # ACCEPTANCE.md #2
CONTACT_TOLERANCE = 0.005  # m, clearance at or below which a module touches a pipe
MODULE_RADIUS = np.array([0.035] + [0.03] * 16)  # module 0 (head) .. 16, snake.xml

_REQUIRED = ("kind", "x", "y", "radius", "length")
_OPTIONAL = ("yaw_deg", "wall", "brightness", "inner_brightness", "ring_brightness")
_SNAKE_KEYS = ("x", "y", "yaw_deg")


class PipeScene(NamedTuple):
    """The snake's start and ``n`` pipe slots, all traced arrays (float32 unless said).

    Attributes:
        start: ``(3,)``: the head camera's ``x``, ``y`` (m) and heading (rad) at the start.
        kind: ``(n,)`` int32, `STANDING` or `LYING`.
        xy: ``(n, 2)``, m: the centre of a standing pipe's base, of a lying pipe's entry face.
        yaw: ``(n,)``, rad: the direction a lying pipe's entry faces (its axis
            points the other way, into the bore); ignored for standing pipes.
        radius: ``(n,)`` outer radius, m.
        wall: ``(n,)`` wall thickness, m (``< radius``); a standing pipe is drawn solid and capped.
        length: ``(n,)`` height (standing) or length (lying), m.
        brightness, inner_brightness, ring_brightness: ``(n,)`` grey levels
            of the outer wall, of the bore and far cap, of the entry face
            (a standing pipe's top cap).
        valid: ``(n,)`` bool: the slot holds a pipe.
    """

    start: jax.Array
    kind: jax.Array
    xy: jax.Array
    yaw: jax.Array
    radius: jax.Array
    wall: jax.Array
    length: jax.Array
    brightness: jax.Array
    inner_brightness: jax.Array
    ring_brightness: jax.Array
    valid: jax.Array

    @property
    def capacity(self) -> int:
        return self.kind.shape[-1]


# ----------------------------------------------------------------- scene files


def _fail(source: str, where: str, problem: str):
    raise UserError(f"{source}: {where}{problem}")


def _number(source, where, table, key, *, required=True, default=None):
    if key not in table:
        if required:
            _fail(source, where, f"missing key {key!r}")
        return default
    value = table[key]
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        _fail(source, where, f"{key} must be a number, got {type(value).__name__} {value!r}")
    if not math.isfinite(value):
        _fail(source, where, f"{key} must be finite, got {value}")
    return float(value)


def _footprint_gap(px, py, kind, xy, yaw, radius, length) -> float:
    """Smallest horizontal distance from the points ``(px, py)`` to a pipe's footprint, m (-1 if one is inside)."""
    px, py = np.asarray(px, float), np.asarray(py, float)
    if kind == STANDING:
        return float(np.min(np.hypot(px - xy[0], py - xy[1]) - radius))
    # Lying: the rectangle from the entry back along the axis, 2 radius wide.
    ax, ay = -math.cos(yaw), -math.sin(yaw)
    u = (px - xy[0]) * ax + (py - xy[1]) * ay
    v = -(px - xy[0]) * ay + (py - xy[1]) * ax
    du = np.maximum(np.maximum(-u, u - length), 0.0)
    dv = np.maximum(np.abs(v) - radius, 0.0)
    inside = (du == 0) & (dv == 0)
    return float(np.min(np.where(inside, -1.0, np.hypot(du, dv))))


def _outline(kind, xy, yaw, radius, length, n=64):
    """Points along a pipe's footprint outline (and its centre), for the overlap test."""
    if kind == STANDING:
        a = 2 * np.pi * np.arange(n) / n
        return np.r_[xy[0], xy[0] + radius * np.cos(a)], np.r_[xy[1], xy[1] + radius * np.sin(a)]
    ax, ay = -math.cos(yaw), -math.sin(yaw)
    s = np.linspace(0.0, 1.0, n // 4)
    u = np.concatenate([s * length, s * length, np.zeros_like(s), np.full_like(s, length)])
    v = np.concatenate([np.full_like(s, radius), np.full_like(s, -radius), (2 * s - 1) * radius, (2 * s - 1) * radius])
    return xy[0] + u * ax - v * ay, xy[1] + u * ay + v * ax


def _segment_footprint_distance(start, kind, xy, yaw, radius, length) -> float:
    """Smallest horizontal distance from the snake's body at the start to a pipe's footprint, m."""
    x0, y0, heading = start
    s = np.linspace(0.0, SNAKE_LENGTH, 35)
    return _footprint_gap(x0 - s * math.cos(heading), y0 - s * math.sin(heading), kind, xy, yaw, radius, length)


def parse_scene(data: dict, source: str = "scene", capacity: int = MAX_PIPES) -> PipeScene:
    """A `PipeScene` of ``capacity`` slots from a scene file's parsed TOML ``data`` (see the module docstring).

    Every problem raises a one-line `UserError` that starts with ``source``
    and names the table and the key: a missing or unknown key, a wrong type,
    an unknown kind, a non-positive radius or length, a wall not thinner than
    the radius, a grey level outside [0, 1], more pipes than slots, a pipe on
    the snake's body at the start or on another pipe (their footprints on the
    floor overlap).
    """
    if isinstance(capacity, bool) or not isinstance(capacity, int) or capacity < 1:
        raise UserError(f"a scene needs at least one pipe slot, got capacity {capacity!r}")
    if not isinstance(data, dict):
        _fail(source, "", "a scene must be a TOML table")
    unknown = sorted(set(data) - {"snake", "pipe"})
    if unknown:
        _fail(source, "", f"unknown table {unknown[0]!r}; expected [snake] and [[pipe]]")
    snake = data.get("snake")
    if snake is None:
        _fail(source, "", "missing table [snake]")
    if not isinstance(snake, dict):
        _fail(source, "", "[snake] must be a table")
    for key in snake:
        if key not in _SNAKE_KEYS:
            _fail(source, "[snake]: ", f"unknown key {key!r}; expected {', '.join(_SNAKE_KEYS)}")
    start = (
        _number(source, "[snake]: ", snake, "x"),
        _number(source, "[snake]: ", snake, "y"),
        math.radians(_number(source, "[snake]: ", snake, "yaw_deg")),
    )
    pipes = data.get("pipe", [])
    if not isinstance(pipes, list) or not all(isinstance(p, dict) for p in pipes):
        _fail(source, "", "pipes must be an array of tables, [[pipe]]")
    if len(pipes) > capacity:
        _fail(source, "", f"{len(pipes)} pipes, more than the scene's {capacity} slots")
    rows = []
    for k, pipe in enumerate(pipes):
        where = f"pipe {k + 1}: "
        for key in pipe:
            if key not in _REQUIRED + _OPTIONAL:
                _fail(source, where, f"unknown key {key!r}; expected {', '.join(_REQUIRED + _OPTIONAL)}")
        if "kind" not in pipe:
            _fail(source, where, "missing key 'kind'")
        kind = pipe["kind"]
        if not isinstance(kind, str):
            _fail(source, where, f"kind must be a string, got {type(kind).__name__} {kind!r}")
        if kind not in KINDS:
            _fail(source, where, f"unknown kind {kind!r}; expected 'standing' or 'lying'")
        lying = kind == "lying"
        x = _number(source, where, pipe, "x")
        y = _number(source, where, pipe, "y")
        radius = _number(source, where, pipe, "radius")
        length = _number(source, where, pipe, "length")
        yaw_deg = _number(source, where, pipe, "yaw_deg", required=lying, default=0.0)
        wall = _number(source, where, pipe, "wall", required=lying, default=radius)
        if not radius > 0:
            _fail(source, where, f"radius must be positive, got {radius}")
        if not length > 0:
            _fail(source, where, f"length must be positive, got {length}")
        if "wall" in pipe and not 0 < wall < radius:
            _fail(source, where, f"wall {wall} must be positive and less than the radius {radius}")
        default_grey = LYING_BRIGHTNESS if lying else STANDING_BRIGHTNESS
        greys = []
        for key, default in zip(("brightness", "inner_brightness", "ring_brightness"), default_grey):
            g = _number(source, where, pipe, key, required=False, default=default)
            if not 0.0 <= g <= 1.0:
                _fail(source, where, f"{key} must be in [0, 1], got {g}")
            greys.append(g)
        yaw = math.radians(yaw_deg)
        gap = _segment_footprint_distance(start, KINDS[kind], (x, y), yaw, radius, length)
        if gap < SNAKE_HALF_WIDTH:
            _fail(source, where, f"the {kind} pipe at ({x}, {y}) overlaps the snake at its start")
        for j, other in enumerate(rows):
            footprint = (other[0], other[1:3], other[3], other[4], other[6])
            mine = (KINDS[kind], (x, y), yaw, radius, length)
            if min(_footprint_gap(*_outline(*mine), *footprint), _footprint_gap(*_outline(*footprint), *mine)) <= 0:
                _fail(source, where, f"the {kind} pipe at ({x}, {y}) overlaps pipe {j + 1}")
        rows.append((KINDS[kind], x, y, yaw, radius, wall, length, *greys))
    return _scene(start, rows, capacity)


def _scene(start, rows, capacity) -> PipeScene:
    n = len(rows)
    pad = [(STANDING, 0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0)] * (capacity - n)
    cols = list(zip(*(list(rows) + pad))) if capacity else [()] * 10
    f32 = lambda c: jnp.asarray(np.asarray(c, np.float32).reshape(capacity))  # noqa: E731
    return PipeScene(
        jnp.asarray(start, jnp.float32),
        jnp.asarray(np.asarray(cols[0], np.int32).reshape(capacity)),
        jnp.asarray(np.stack([np.asarray(cols[1]), np.asarray(cols[2])], -1).reshape(capacity, 2), jnp.float32),
        *(f32(cols[i]) for i in range(3, 10)),
        jnp.asarray(np.arange(capacity) < n),
    )


def load_scene(path, capacity: int = MAX_PIPES) -> PipeScene:
    """The `PipeScene` of the TOML scene file at ``path`` (`parse_scene` checks it)."""
    path = pathlib.Path(path)
    try:
        text = path.read_text()
    except OSError as err:
        raise UserError(f"cannot read scene file {path}: {err.strerror or err}") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise UserError(f"{path}: not valid TOML: {err}") from None
    return parse_scene(data, str(path), capacity)


# ----------------------------------------------------------------- random placements


class Placement(NamedTuple):
    """Ranges and sizes of the reproduction's random scenes (ACCEPTANCE.md "Default scene"), traced floats.

    Distances in m, angles in rad. The pipe is ``distance`` ahead of the
    snake's start along its heading and ``offset`` to the side; a lying pipe's
    entry faces the start, turned by up to ``max_axis_yaw`` either way.
    """

    min_distance: float = 2.0
    max_distance: float = 4.0
    min_offset: float = 0.3
    max_offset: float = 1.2
    max_axis_yaw: float = math.radians(20.0)
    standing_radius: float = 0.125
    standing_height: float = 2.0
    lying_radius: float = 0.26
    lying_wall: float = 0.01
    lying_length: float = 3.0


def sample(key: jax.Array, kind, side, placement: Placement = Placement(), capacity: int = 1) -> PipeScene:
    """One random scene for a situation: a pipe of ``kind`` on ``side`` (`LEFT` or `RIGHT`) of the snake.

    Pure in ``key``; ``kind`` and ``side`` may be traced (one program for all
    four `SITUATIONS`). The snake starts at the origin looking along ``+x``;
    the pipe takes slot 0, the other ``capacity - 1`` slots are empty.
    ``distance ~ U[min, max]``, ``|offset| ~ U[min, max]``, the lying axis
    yaw ``~ U[-max, max]`` about the line of sight.
    """
    k_dist, k_off, k_yaw = jax.random.split(key, 3)
    p = placement
    distance = jax.random.uniform(k_dist, (), jnp.float32, p.min_distance, p.max_distance)
    offset = jax.random.uniform(k_off, (), jnp.float32, p.min_offset, p.max_offset)
    turn = jax.random.uniform(k_yaw, (), jnp.float32, -p.max_axis_yaw, p.max_axis_yaw)
    kind = jnp.asarray(kind, jnp.int32)
    side = jnp.asarray(side, jnp.float32)
    xy = jnp.stack([distance, -side * offset])  # right of a +x heading is -y
    lying = kind == LYING
    yaw = jnp.where(lying, jnp.arctan2(-xy[1], -xy[0]) + turn, 0.0)
    radius = jnp.where(lying, p.lying_radius, p.standing_radius)
    wall = jnp.where(lying, p.lying_wall, p.standing_radius)
    length = jnp.where(lying, p.lying_length, p.standing_height)
    greys = [jnp.where(lying, a, b) for a, b in zip(LYING_BRIGHTNESS, STANDING_BRIGHTNESS)]

    def slots(first, fill):
        first = jnp.asarray(first)
        rest = jnp.broadcast_to(jnp.asarray(fill, first.dtype), (capacity - 1,) + first.shape)
        return jnp.concatenate([first[None], rest])

    return PipeScene(
        jnp.zeros(3, jnp.float32),
        slots(kind, STANDING),
        slots(xy, 0.0),
        slots(yaw, 0.0),
        slots(radius, 1.0),
        slots(wall, 1.0),
        slots(length, 1.0),
        *(slots(g, 0.0) for g in greys),
        slots(jnp.asarray(True), False),
    )


# ----------------------------------------------------------------- geometry


def _axis_frame(scene: PipeScene):
    """Per slot: the entry face's centre (3,), the unit axis into the bore (3,), the bore radius."""
    lying = scene.kind == LYING
    facing = jnp.stack([jnp.cos(scene.yaw), jnp.sin(scene.yaw), jnp.zeros_like(scene.yaw)], -1)
    down = jnp.broadcast_to(jnp.array([0.0, 0.0, -1.0]), facing.shape)
    axis = jnp.where(lying[:, None], -facing, down)
    z = jnp.where(lying, scene.radius, scene.length)  # a lying pipe rests on the floor; a standing one's top
    entry = jnp.concatenate([scene.xy, z[:, None]], -1)
    bore = jnp.where(lying, scene.radius - scene.wall, 0.0)
    return entry, axis, bore


def render_pipes(scene: PipeScene) -> render.Pipes:
    """The scene's pipes for `spikejax.vision.render` (a standing pipe solid and capped, a lying one a tube).

    A lying pipe rests on the floor (its axis ``radius`` above it), its far
    end closed; a standing pipe's entry face is its top cap, a disc.
    """
    entry, axis, bore = _axis_frame(scene)
    return render.Pipes(
        entry,
        axis,
        scene.radius,
        scene.radius - bore,
        scene.length,
        scene.brightness,
        scene.inner_brightness,
        scene.ring_brightness,
        scene.valid,
    )


def default_bodies(capacity: int = 1, placement: Placement = Placement()) -> physics.PipeBodies:
    """Physical pipe bodies of `sample`'s sizes for ``capacity`` slots."""
    p = placement
    slot = physics.PipeSlot(p.standing_radius, p.standing_height, p.lying_radius, p.lying_wall, p.lying_length)
    return physics.PipeBodies((slot,) * capacity)


def bodies_for(scene: PipeScene) -> physics.PipeBodies:
    """Physical pipe bodies sized as a concrete (host) scene's pipes, slot by slot.

    Geom sizes are model constants, so a scene with other sizes is another
    model (one compile each); the positions are free (`place_pipes`). Each
    slot's unused kind keeps `PipeSlot`'s default size.
    """
    kind, radius, wall, length, valid = (
        np.asarray(a) for a in (scene.kind, scene.radius, scene.wall, scene.length, scene.valid)
    )
    slots = []
    for k in range(kind.shape[0]):
        slot = physics.PipeSlot()
        if valid[k] and kind[k] == STANDING:
            slot = dataclasses.replace(slot, standing_radius=float(radius[k]), standing_height=float(length[k]))
        elif valid[k]:
            slot = dataclasses.replace(
                slot, lying_radius=float(radius[k]), lying_wall=float(wall[k]), lying_length=float(length[k])
            )
        slots.append(slot)
    return physics.PipeBodies(tuple(slots))


def place_pipes(state: physics.PhysState, scene: PipeScene) -> physics.PhysState:
    """``state`` with the model's pipe bodies where ``scene`` puts its pipes (pure; vmaps over scenes).

    Slot ``i``'s standing body (mocap ``2 i``) goes to a valid standing pipe's
    base, its lying body (``2 i + 1``) to a valid lying pipe's entry, turned
    to its yaw; the other bodies stay parked below the floor. The model must
    have been built with at least the scene's number of slots
    (`bodies_for`, `default_bodies`).
    """
    n = scene.capacity
    if state.mocap_pos.shape[-2] < 2 * n:
        raise UserError(f"the physics has {state.mocap_pos.shape[-2] // 2} pipe slots, the scene {n}")
    park = jnp.asarray(state.mocap_pos[: 2 * n])
    standing = scene.valid & (scene.kind == STANDING)
    lying = scene.valid & (scene.kind == LYING)
    base = jnp.concatenate([scene.xy, jnp.zeros((n, 1))], -1)
    entry = jnp.concatenate([scene.xy, scene.radius[:, None]], -1)
    pos = jnp.stack([jnp.where(standing[:, None], base, park[0::2]), jnp.where(lying[:, None], entry, park[1::2])], 1)
    half = 0.5 * jnp.where(lying, scene.yaw, 0.0)
    yaw_quat = jnp.stack([jnp.cos(half), jnp.zeros(n), jnp.zeros(n), jnp.sin(half)], -1)
    quat = jnp.stack([jnp.broadcast_to(jnp.array([1.0, 0.0, 0.0, 0.0]), (n, 4)), yaw_quat], 1)
    mocap_pos = state.mocap_pos.at[: 2 * n].set(pos.reshape(2 * n, 3))
    mocap_quat = state.mocap_quat.at[: 2 * n].set(quat.reshape(2 * n, 4))
    return state._replace(mocap_pos=mocap_pos, mocap_quat=mocap_quat)


# ----------------------------------------------------------------- ground truth


class PipeTruth(NamedTuple):
    """What the head camera should see of each pipe slot, ``(n,)`` each (never fed to a controller).

    Attributes:
        depth: the pipe's depth along the optical axis, m: of the axis at the
            camera's height (standing), of the entry face's centre (lying);
            the ``d`` that Eq. (8) of the pipe-tracking paper estimates.
        distance: the horizontal Euclidean distance to the same point, m.
        lateral: its offset across the optical axis, m, positive on the right.
        bearing: ``atan2(lateral, depth)``, rad, positive on the right.
        left_col, right_col: image columns of a standing pipe's two silhouette
            edges at the camera's height (the tangents from the camera to the
            pipe's circle, projected by the pinhole model).
        width: ``right_col - left_col``, px (Eq. (8)'s ``w``).
        pos: the pipe's centre column ``(left_col + right_col) / 2``, px from
            the left edge of the image (Alg. 2's ``pos``).
        ring_col, ring_row: where the entry face's centre projects.
        ring_radius: ``f R / depth``, px: the projected radius of the entry's
            outer rim (exact when seen end-on; the rim's vertical semi-axis
            otherwise).
        in_view: the point is ahead of the camera and inside the image's columns.
    """

    depth: jax.Array
    distance: jax.Array
    lateral: jax.Array
    bearing: jax.Array
    left_col: jax.Array
    right_col: jax.Array
    width: jax.Array
    pos: jax.Array
    ring_col: jax.Array
    ring_row: jax.Array
    ring_radius: jax.Array
    in_view: jax.Array


def truth(cam_pos, cam_rot, scene: PipeScene, camera: render.Camera = render.Camera()) -> PipeTruth:
    """Ground truth of every pipe slot seen from the camera at ``cam_pos`` (3,) with ``cam_rot`` (3, 3).

    ``cam_rot``'s columns are the camera's forward, left and up axes (as the
    snake's ``PhysState.head_pos`` / ``head_mat`` give them). Pure; a slot's
    numbers are meaningless where ``scene.valid`` is false, the edge columns
    where the kind is lying, the ring where it is standing.
    """
    cam_pos = jnp.asarray(cam_pos, jnp.float32)
    cam_rot = jnp.asarray(cam_rot, jnp.float32)
    entry, _, _ = _axis_frame(scene)
    lying = scene.kind == LYING
    n = scene.capacity
    point = jnp.where(lying[:, None], entry, jnp.concatenate([scene.xy, jnp.full((n, 1), cam_pos[2])], -1))
    local = (point - cam_pos) @ cam_rot  # (n, 3): forward, left, up
    depth, lateral = local[:, 0], -local[:, 1]
    distance = jnp.hypot(point[:, 0] - cam_pos[0], point[:, 1] - cam_pos[1])
    bearing = jnp.arctan2(lateral, depth)
    f = camera.focal
    proj = jax.vmap(lambda p: render.project(camera, cam_pos, cam_rot, p))
    # Standing: the two tangent points from the camera to the circle, at the camera's height.
    to = scene.xy - cam_pos[:2]
    d = jnp.linalg.norm(to, axis=-1)
    beta = jnp.arcsin(jnp.clip(scene.radius / jnp.maximum(d, 1e-6), 0.0, 1.0))
    reach = jnp.sqrt(jnp.maximum(d * d - scene.radius**2, 0.0))
    u = to / jnp.maximum(d, 1e-6)[:, None]

    def tangent(sign):
        c, s = jnp.cos(sign * beta), jnp.sin(sign * beta)
        dirs = jnp.stack([c * u[:, 0] - s * u[:, 1], s * u[:, 0] + c * u[:, 1]], -1)
        pts = cam_pos[:2] + reach[:, None] * dirs
        return proj(jnp.concatenate([pts, jnp.full((n, 1), cam_pos[2])], -1))[:, 0]

    a, b = tangent(1.0), tangent(-1.0)  # +beta is to the left (counter-clockwise) of the line of sight
    left_col, right_col = jnp.minimum(a, b), jnp.maximum(a, b)
    ring = proj(entry)
    half_width = 0.5 * camera.width
    in_view = (depth > 0) & (jnp.abs(lateral) * f < half_width * depth)
    return PipeTruth(
        depth,
        distance,
        lateral,
        bearing,
        left_col,
        right_col,
        right_col - left_col,
        0.5 * (left_col + right_col),
        ring[:, 0],
        ring[:, 1],
        f * scene.radius / jnp.maximum(depth, 1e-6),
        in_view,
    )


def line_offset(scene: PipeScene, point_xy, heading) -> jax.Array:
    """Each pipe's signed distance from a line on the floor, m, positive on its right, ``(n,)``.

    The line passes through ``point_xy`` (2,) along ``heading`` (rad); the
    pipe's point is a standing pipe's axis, a lying pipe's entry centre. With
    the snake's centre of mass and its heading averaged over a gait period
    (ACCEPTANCE.md's "central line", kept by the caller), this is the true
    lateral offset that Alg. 3's ``offset`` estimates; with the head's
    position and the optical axis it is `truth`'s ``lateral`` on the floor.
    """
    d = scene.xy - jnp.asarray(point_xy, jnp.float32)
    return d[:, 0] * jnp.sin(heading) - d[:, 1] * jnp.cos(heading)


def _axial_radial(point, scene: PipeScene):
    """Per slot: the point's distance along the axis from the entry face, and from the axis, m."""
    entry, axis, bore = _axis_frame(scene)
    w = jnp.asarray(point, jnp.float32) - entry
    a = jnp.sum(w * axis, -1)
    radial = jnp.linalg.norm(w - a[:, None] * axis, axis=-1)
    return a, radial, bore


def reached(head_pos, scene: PipeScene, within: float = REACH_DISTANCE) -> jax.Array:
    """Per slot: the head is within ``within`` of the pipe: a standing pipe's surface, a lying one's entry centre.

    ACCEPTANCE.md #1 (standing: the head comes within 0.3 m of the pipe
    surface, measured horizontally) and #2 ("approach": within 0.3 m of the
    entry centre). ``(n,)`` bool, false for empty slots.
    """
    head_pos = jnp.asarray(head_pos, jnp.float32)
    entry, _, _ = _axis_frame(scene)
    surface = jnp.hypot(head_pos[0] - scene.xy[:, 0], head_pos[1] - scene.xy[:, 1]) - scene.radius
    to_entry = jnp.linalg.norm(head_pos - entry, axis=-1)
    near = jnp.where(scene.kind == LYING, to_entry, surface) <= within
    return near & scene.valid


def entered(head_pos, head_mat, scene: PipeScene, margin: float = ENTRY_MARGIN, heading: float = ENTRY_HEADING):
    """Per slot: the head is inside a lying pipe's bore (ACCEPTANCE.md #2, "enter").

    Past the entry plane (and not beyond the far end), inside the bore's
    cross-section, its offset across the axis at most ``bore radius -
    margin``, and its heading (the optical axis, horizontal part) within
    ``heading`` of the pipe's axis. The offset is measured horizontally, across
    the vertical plane through the axis: a snake in a lying pipe crawls on the
    bore's floor, about ``bore - 0.035`` m below the axis, so the distance
    from the axis itself could never pass the test; centring is sideways.
    ``(n,)`` bool, false for standing pipes and empty slots.
    """
    a, radial, bore = _axial_radial(head_pos, scene)
    entry, axis, _ = _axis_frame(scene)
    w = jnp.asarray(head_pos, jnp.float32)[:2] - entry[:, :2]
    across = jnp.abs(w[:, 0] * axis[:, 1] - w[:, 1] * axis[:, 0])  # the horizontal axis is a unit vector
    fwd = jnp.asarray(head_mat, jnp.float32)[:2, 0]
    fwd = fwd / jnp.maximum(jnp.linalg.norm(fwd), 1e-6)
    cos_angle = axis[:, 0] * fwd[0] + axis[:, 1] * fwd[1]
    inside = (a > 0) & (a < scene.length) & (radial <= bore) & (across <= bore - margin)
    return inside & (cos_angle >= jnp.cos(heading)) & scene.valid & (scene.kind == LYING)


def clearance(points, radii, scene: PipeScene) -> jax.Array:
    """Gap between each sphere ``(points (m, 3), radii (m,))`` and each pipe's solid, ``(m, n)`` m (< 0: overlap).

    The solids are those drawn: a standing pipe a solid cylinder; a lying pipe
    its wall (radii ``bore`` to ``radius`` along the whole length) and the far
    cap (a disc ``wall`` thick). Both are rectangles in the (radial, axial)
    half-plane of the pipe, so the distance is a rectangle's, exact for a
    solid of revolution. Empty slots are infinitely far.
    """
    points = jnp.asarray(points, jnp.float32)
    a, r, bore = jax.vmap(lambda p: _axial_radial(p, scene))(points)  # (m, n) each

    def box(r_lo, r_hi, a_lo, a_hi):
        dr = jnp.maximum(jnp.maximum(r_lo - r, r - r_hi), 0.0)
        da = jnp.maximum(jnp.maximum(a_lo - a, a - a_hi), 0.0)
        outside = jnp.hypot(dr, da)
        depth_in = jnp.minimum(jnp.minimum(r - r_lo, r_hi - r), jnp.minimum(a - a_lo, a_hi - a))
        return jnp.where((dr == 0) & (da == 0), -depth_in, outside)

    wall = box(bore, scene.radius, 0.0, scene.length)
    cap = box(0.0, scene.radius, scene.length - scene.wall, scene.length)
    gap = jnp.minimum(wall, cap) - jnp.asarray(radii, jnp.float32)[:, None]
    return jnp.where(scene.valid, gap, jnp.inf)


def collided(qpos, scene: PipeScene, tolerance: float = CONTACT_TOLERANCE) -> jax.Array:
    """Per slot: some module of the snake at ``qpos`` touches the pipe (clearance <= ``tolerance``), ``(n,)`` bool.

    Each module is taken as a sphere of its radius about its body's centre
    (`robots.snake.physics.forward_kinematics`), a conservative stand-in for
    the capsules (each 0.04 m long between its end spheres).
    """
    xpos = physics.forward_kinematics(jnp.asarray(qpos, jnp.float32))[0]
    modules = jnp.asarray(_module_bodies())
    gap = clearance(xpos[modules], MODULE_RADIUS, scene)
    return jnp.any(gap <= tolerance, axis=0)


def _module_bodies() -> np.ndarray:
    model = physics.load_mj_model()
    return np.array([model.body(f"module{k}").id for k in range(17)])
