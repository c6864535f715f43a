"""The predator-prey task of the hexapod SCPG paper (Sec. V): prey scenes, their truth, and what "captured" means.

The paper hunts cuboid prey in a lab (Sec. V-A one prey, V-B several, the
nearest first) and gives no distances, sizes or success criterion. Ours:

* **Scenes** are data: a TOML file (`load_scene`) with the robot's start and
  the prey, or a random scene per seed (`sample_scene`: one to four prey at
  0.8-2.5 m and bearings within +-20 deg of the start heading, at least 0.3 m
  apart). A scene holds ``MAX_PREY`` prey slots and an ``alive`` mask, so scenes
  with different numbers of prey batch under ``vmap`` and a captured prey is
  removed by clearing its slot (the paper removes it by hand). Zero prey is an
  empty arena (the truth: keep walking, G1).
* **Prey size**: cubes of `PREY_SIZE` = 0.03 m by default, about a quarter of
  the camera's height (0.109 m). The visual SNN reads distance from the image
  row of a prey's edges, which is the row of its base only for a prey well
  below the camera: a prey of height ``s`` at ground distance ``d`` spans the
  depression angles ``atan((h - s) / d)`` (its top) to ``atan(h / d)`` (its
  base), so a prey as tall as the camera keeps its top on the horizon at every
  distance and lights the far window rows however near it is. On the
  open-loop decisions (ACCEPTANCE A6, docs/ARCHITECTURE.md) 0.10 m cubes were
  right in 82 % of 256 scenes and 0.03 m cubes in 93 %. The paper gives no
  size; this is our choice.
* **Near and far**: the visual SNN turns toward a prey once its base shows in
  the lower 3 of the 8 window rows (`robots.hexapod.vision`). For a pinhole
  camera at height ``h`` pitched down by ``tilt`` the base of a prey at ground
  distance ``d`` shows ``f tan(atan(h / d) - tilt)`` pixels below the image
  centre, so it crosses that boundary at `near_distance`
  ``d_near = h / tan(tilt + atan(dy / f))``, ``dy`` the boundary's offset below the
  centre (100 px of the paper's 800 rows) and ``f`` the focal length in pixels.
* **The rule the SNN approximates** (`truth_gait`): forward while the nearest
  prey is beyond ``d_near``, else turn toward its side (left for a positive
  bearing).
* **Captured** (`captured`): the nearest prey within ``d_near + margin`` and
  within 15 deg of straight ahead: the paper's end state, "aligned" in front of it.
"""

from __future__ import annotations

import math
import tomllib
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from robots.hexapod.vision import FORWARD, LEFT, RIGHT
from spikejax.errors import UserError

__all__ = [
    "MAX_PREY",
    "PREY_SIZE",
    "PreyScene",
    "load_scene",
    "sample_scene",
    "near_distance",
    "relative",
    "nearest",
    "truth_gait",
    "captured",
]

MAX_PREY = 4
PREY_SIZE = 0.03  # m, the cubes' edge: about a quarter of the head camera's 0.109 m (module docstring)
_ROBOT_KEYS = {"x", "y", "yaw_deg"}
_PREY_KEYS = {"x", "y", "size"}


class PreyScene(NamedTuple):
    """A robot's start and its prey (traced).

    Attributes:
        start: ``(x, y, yaw)``, m, m, rad; yaw 0 looks along +x, positive to the left.
        prey: prey centres on the floor, ``(MAX_PREY, 2)``, m.
        size: cube edges, ``(MAX_PREY,)``, m.
        alive: which slots hold a prey, ``(MAX_PREY,)`` bool.
    """

    start: jax.Array
    prey: jax.Array
    size: jax.Array
    alive: jax.Array


def _number(table: dict, key: str, where: str, path) -> float:
    value = table.get(key)
    if value is None:
        raise UserError(f"{path}: {where} has no '{key}'")
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise UserError(f"{path}: {where}.{key} must be a finite number, got {value!r}")
    return float(value)


def load_scene(path) -> PreyScene:
    """A scene file: ``[robot]`` with ``x``, ``y``, ``yaw_deg``; one to `MAX_PREY` ``[[prey]]`` with ``x``, ``y``, ``size``.

    Raises:
        UserError: in one line naming the problem: an unreadable file, bad TOML, a
            missing or unknown key, a value that is not a finite number, a size not
            in (0, 1] m, no prey or too many, a prey under the robot's start.
    """
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as err:
        raise UserError(f"cannot read the scene file {path}: {err.strerror or err}") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as err:
        raise UserError(f"{path}: not a TOML file ({str(err).splitlines()[0]})") from None
    unknown = set(data) - {"robot", "prey"}
    if unknown:
        raise UserError(f"{path}: unknown section(s) {sorted(unknown)}; a scene has [robot] and [[prey]]")
    robot = data.get("robot")
    if not isinstance(robot, dict):
        raise UserError(f"{path}: no [robot] section")
    if set(robot) - _ROBOT_KEYS:
        raise UserError(f"{path}: unknown key(s) {sorted(set(robot) - _ROBOT_KEYS)} in [robot]")
    start = [_number(robot, k, "[robot]", path) for k in ("x", "y", "yaw_deg")]
    prey = data.get("prey")
    if not isinstance(prey, list) or not prey:
        raise UserError(f"{path}: no [[prey]]; a scene needs 1 to {MAX_PREY}")
    if len(prey) > MAX_PREY:
        raise UserError(f"{path}: {len(prey)} prey; a scene holds at most {MAX_PREY}")
    xy, size = np.zeros((MAX_PREY, 2)), np.full(MAX_PREY, PREY_SIZE)
    for i, p in enumerate(prey):
        where = f"prey {i + 1}"
        if not isinstance(p, dict) or set(p) - _PREY_KEYS:
            raise UserError(f"{path}: {where} takes only the keys {sorted(_PREY_KEYS)}")
        xy[i] = [_number(p, "x", where, path), _number(p, "y", where, path)]
        size[i] = _number(p, "size", where, path)
        if not 0 < size[i] <= 1:
            raise UserError(f"{path}: {where}.size must be in (0, 1] m, got {size[i]:g}")
        if math.hypot(xy[i, 0] - start[0], xy[i, 1] - start[1]) < size[i] / 2 + 0.15:
            raise UserError(f"{path}: {where} stands on the robot's start")
    alive = np.arange(MAX_PREY) < len(prey)
    return PreyScene(
        jnp.asarray([start[0], start[1], math.radians(start[2])], jnp.float32),
        jnp.asarray(xy, jnp.float32),
        jnp.asarray(size, jnp.float32),
        jnp.asarray(alive),
    )


def sample_scene(
    key: jax.Array,
    n_prey: jax.Array,
    *,
    distance=(0.8, 2.5),
    bearing_deg=20.0,
    min_gap=0.3,
    size=PREY_SIZE,
    tries: int = 16,
) -> PreyScene:
    """A random scene: the robot at the origin facing +x and ``n_prey`` (traced, 0..4) prey, cubes of edge ``size``.

    Each prey's distance is uniform in ``distance`` (m) and its bearing in
    ``+-bearing_deg``; each is drawn up to ``tries`` times until it stands
    ``min_gap`` (m) from the prey before it (the last draw is kept otherwise,
    which the defaults make vanishingly rare). Pure in ``key``.
    """
    k_d, k_b = jax.random.split(key)
    d = jax.random.uniform(k_d, (MAX_PREY, tries), minval=distance[0], maxval=distance[1])
    b = jax.random.uniform(k_b, (MAX_PREY, tries), minval=-1.0, maxval=1.0) * math.radians(bearing_deg)
    candidates = jnp.stack([d * jnp.cos(b), d * jnp.sin(b)], axis=-1)  # (MAX_PREY, tries, 2)

    def place(placed, i):
        gaps = jnp.linalg.norm(candidates[i][:, None, :] - placed[None, :, :], axis=-1)
        earlier = jnp.arange(MAX_PREY) < i
        ok = jnp.all((gaps >= min_gap) | ~earlier[None, :], axis=1)
        choice = jnp.where(jnp.any(ok), jnp.argmax(ok), tries - 1)
        return placed.at[i].set(candidates[i, choice]), None

    placed, _ = jax.lax.scan(place, jnp.full((MAX_PREY, 2), 1e3, jnp.float32), jnp.arange(MAX_PREY))
    return PreyScene(
        jnp.zeros(3, jnp.float32),
        placed,
        jnp.full((MAX_PREY,), size, jnp.float32),
        jnp.arange(MAX_PREY) < n_prey,
    )


def near_distance(height: float, tilt_deg: float, hfov_deg: float, width_px: int, boundary_px: float) -> float:
    """``d_near`` (m): where a prey's base crosses ``boundary_px`` below the image centre (module docstring).

    Args:
        height: the camera above the floor, m.
        tilt_deg: the camera pitched down, deg.
        hfov_deg: horizontal field of view, deg (square pixels).
        width_px: image width, pixels.
        boundary_px: the near/far boundary's offset below the centre row, pixels.
    """
    f = (width_px / 2) / math.tan(math.radians(hfov_deg) / 2)
    angle = math.radians(tilt_deg) + math.atan(boundary_px / f)
    if angle <= 0:
        raise UserError("the near/far boundary lies at or above the horizon: tilt the camera down")
    return height / math.tan(angle)


def relative(scene: PreyScene, pose: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Distance (m) and bearing (rad, positive to the left) of every prey slot from ``pose = (x, y, yaw)``."""
    d = scene.prey - pose[:2]
    bearing = jnp.arctan2(d[:, 1], d[:, 0]) - pose[2]
    return jnp.linalg.norm(d, axis=-1), jnp.arctan2(jnp.sin(bearing), jnp.cos(bearing))


def nearest(scene: PreyScene, pose: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """The nearest living prey: its slot, distance and bearing (slot -1 and infinite distance if none lives)."""
    dist, bearing = relative(scene, pose)
    dist = jnp.where(scene.alive, dist, jnp.inf)
    i = jnp.argmin(dist)
    return jnp.where(jnp.any(scene.alive), i, -1), dist[i], bearing[i]


def truth_gait(scene: PreyScene, pose: jax.Array, d_near: float) -> jax.Array:
    """The ground-truth rule: `FORWARD` while the nearest prey is beyond ``d_near`` (or none lives), else the turn toward it."""
    _, dist, bearing = nearest(scene, pose)
    return jnp.where(dist > d_near, FORWARD, jnp.where(bearing > 0, LEFT, RIGHT)).astype(jnp.int32)


def captured(scene: PreyScene, pose: jax.Array, d_near: float, margin: float = 0.2, max_bearing_deg: float = 15.0):
    """Whether the nearest living prey is within ``d_near + margin`` and ``max_bearing_deg`` of straight ahead."""
    _, dist, bearing = nearest(scene, pose)
    return (dist <= d_near + margin) & (jnp.abs(bearing) <= math.radians(max_bearing_deg))
