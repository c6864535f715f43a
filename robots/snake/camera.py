"""The snake's head camera: its pose from the physics state and the scene it sees.

The camera is the site ``head_camera`` of ``snake.xml``, at the front face of
the head module, looking along the head's +x with +z up; its world pose is in
the physics state (``head_pos``, ``head_mat``), whichever backend produced it,
and its frame axes (forward, left, up) are those `spikejax.vision.render.render`
expects, so the head's rotation matrix is the camera's.

The scene is the papers' world: the target sphere of radius 0.3 m resting on
the ground (section II-A of the snake R-STDP paper), the ground plane and,
optionally, pipes (standing and lying cylinders, section 3.1 of the
pipe-tracking paper). `pipe_scene` is the pipe-tracking paper's world
instead: the pipes of a `robots.snake.pipes.PipeScene` (walls with a
thickness, an entry ring, a closed far end), the ground and the sky, and no
target sphere. Brightness values are grey levels in [0, 1]: a dark
target on a mid-grey floor under a bright sky, so that the target's outline
makes events against either background.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

from robots.snake.tracks import TARGET_RADIUS
from spikejax.vision import render

HEAD_CAMERA = render.Camera(width=128, height=128, fov=math.radians(60.0))  # DVS128; fovy=60 in snake.xml
TARGET_BRIGHTNESS = 0.08
GROUND_BRIGHTNESS = 0.4
SKY_BRIGHTNESS = 0.8


def scene(target_xy, pipes: render.Cylinders | None = None, target_radius: float = TARGET_RADIUS) -> render.Scene:
    """The target sphere resting on the ground at ``target_xy`` (2,), the ground, the sky and ``pipes``."""
    target_xy = jnp.asarray(target_xy, jnp.float32)
    center = jnp.concatenate([target_xy, jnp.full((1,), target_radius, jnp.float32)])
    return render.Scene(
        spheres=render.spheres(center, target_radius, TARGET_BRIGHTNESS),
        cylinders=render.no_cylinders() if pipes is None else pipes,
        ground_height=0.0,
        ground_brightness=GROUND_BRIGHTNESS,
        sky_brightness=SKY_BRIGHTNESS,
    )


def pipe_scene(pipes: render.Pipes) -> render.Scene:
    """The pipe world the head camera sees: ``pipes`` (`robots.snake.pipes.render_pipes`), ground and sky.

    No target sphere: the pipe-tracking paper's scenes hold one pipe and
    nothing else (section 3.1). Traced in every field, so a batch of
    episodes with different placements renders in one program.
    """
    cylinders, annuli = render.pipe_primitives(pipes)
    return render.Scene(
        spheres=render.no_spheres(),
        cylinders=cylinders,
        ground_height=0.0,
        ground_brightness=GROUND_BRIGHTNESS,
        sky_brightness=SKY_BRIGHTNESS,
        annuli=annuli,
    )


def pose(phys) -> tuple[jax.Array, jax.Array]:
    """The camera's position (3,) and rotation (3, 3) (columns: forward, left, up) from a physics state."""
    return phys.head_pos, phys.head_mat


def frame(
    phys, world: render.Scene, camera: render.Camera = HEAD_CAMERA, rows: tuple[int, int] | None = None
) -> jax.Array:
    """The head camera's ``(128, 128)`` grey-level frame of ``world`` for the physics state ``phys``.

    ``rows = (row0, row1)``: only those rows are rendered; the others are 0,
    a band that never changes and so never makes an event.
    """
    pos, rot = pose(phys)
    if rows is None:
        return render.render(world, pos, rot, camera)
    band = render.render(world, pos, rot, camera, rows=rows)
    return jnp.zeros((camera.height, camera.width), band.dtype).at[rows[0] : rows[1]].set(band)
