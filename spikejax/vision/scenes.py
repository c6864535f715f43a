"""Synthetic scenes with known ground truth, for tests, benchmarks and notebooks.

Each scene renders a sequence of ``(height, width)`` intensity frames in
``[0, 1]`` (anti-aliased edges, optional Gaussian pixel noise drawn from an
explicit key) and returns the geometry that produced them:

* `standing_pipe`: a bright vertical (or tilted) pipe on a dark
  background while the camera sweeps sideways. Its two edges are parallel
  lines whose events have opposite polarity (the pipe body of Section 2.3 of
  the snake pipe-tracking paper).
* `lying_pipe`: the open end of a pipe seen head on, a dark disc (the
  hole) on a bright background, drifting sideways and growing as the camera
  approaches (the pipe entry: a circle).
* `moving_ball`: a bright disc moving along a straight line.

Line truth uses the convention of `spikejax.vision.hough.LineGrid` with
its default origin ``(width / 2, height / 2)``:
``rho = (x - width / 2) sin(theta) + (y - height / 2) cos(theta)``, with
``theta`` in ``[0, pi)``. Circle truth is ``(a, b, r)``: centre column, centre
row, radius, in pixels.

Feed the frames to `spikejax.vision.dvs.difference_events` or
`spikejax.vision.dvs.emulate` for events; the events between frames
``k - 1`` and ``k`` belong to the truth of frame ``k``.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from spikejax.errors import UserError

__all__ = ["PipeTruth", "CircleTruth", "SyntheticScene", "standing_pipe", "lying_pipe", "moving_ball"]


class PipeTruth(NamedTuple):
    """The two edges of a standing pipe in each frame (arrays of shape ``(n,)``).

    Attributes:
        theta: angle of both edges, radians in ``[0, pi)`` (``pi / 2``: vertical).
        rho_left, rho_right: the edges' rho, pixels (``rho_left < rho_right``).
        polarity_left, polarity_right: polarity of the events each edge makes
            (+1 brighter, -1 darker); opposite to one another.
        width: distance between the edges, pixels (``rho_right - rho_left``).
        pos: the pipe's centre column at the middle row, pixels from the left.
    """

    theta: np.ndarray
    rho_left: np.ndarray
    rho_right: np.ndarray
    polarity_left: np.ndarray
    polarity_right: np.ndarray
    width: np.ndarray
    pos: np.ndarray


class CircleTruth(NamedTuple):
    """A circle in each frame (arrays of shape ``(n,)``): centre column ``a``, row ``b``, radius ``r``."""

    a: np.ndarray
    b: np.ndarray
    r: np.ndarray


class SyntheticScene(NamedTuple):
    """Frames, their times and the ground truth (not a `spikejax.vision.render.Scene`, which holds primitives).

    Attributes:
        frames: ``(n, height, width)`` float32 intensities in ``[0, 1]``.
        times: ``(n,)`` float32 frame times, seconds.
        truth: `PipeTruth` or `CircleTruth`.
    """

    frames: jax.Array
    times: jax.Array
    truth: PipeTruth | CircleTruth


def _check(n_frames, height, width, noise, fps):
    if n_frames < 2:
        raise UserError(f"a scene needs at least 2 frames, not {n_frames}")
    if height < 4 or width < 4:
        raise UserError(f"sensor too small: {width} x {height} pixels")
    if noise < 0:
        raise UserError(f"noise must be >= 0, not {noise}")
    if not fps > 0:
        raise UserError(f"fps must be > 0, not {fps}")


def _grid(height, width):
    y, x = jnp.meshgrid(jnp.arange(height, dtype=jnp.float32), jnp.arange(width, dtype=jnp.float32), indexing="ij")
    return x, y


def _finish(frames, key, noise):
    if noise > 0:
        if key is None:
            raise UserError("a noisy scene needs a PRNG key")
        frames = frames + noise * jax.random.normal(key, frames.shape)
    return jnp.clip(frames, 0.0, 1.0).astype(jnp.float32)


def standing_pipe(
    *,
    n_frames: int = 8,
    height: int = 128,
    width: int = 128,
    pipe_width: float = 24.0,
    start: float = 40.0,
    speed: float = 4.0,
    tilt: float = 0.0,
    background: float = 0.2,
    foreground: float = 0.8,
    noise: float = 0.0,
    fps: float = 100.0,
    key: jax.Array | None = None,
) -> SyntheticScene:
    """A bright pipe on a dark background moving sideways across the image.

    The camera sweeps left, so the pipe moves right by ``speed`` pixels a frame:
    its right (leading) edge makes ON events, its left (trailing) edge OFF
    events. ``tilt`` turns the pipe by that angle (radians) from the vertical,
    clockwise in the image.

    Args:
        n_frames, height, width: sequence length and sensor size.
        pipe_width: distance between the edges, pixels.
        start: centre column of the pipe at the middle row in frame 0.
        speed: sideways motion, pixels per frame (negative: to the left).
        tilt: angle from the vertical, radians.
        background, foreground: intensities of the scene and of the pipe.
        noise: standard deviation of Gaussian pixel noise.
        fps: frames per second (sets ``times``).
        key: PRNG key for the pixel noise (needed when ``noise > 0``).
    """
    _check(n_frames, height, width, noise, fps)
    x, y = _grid(height, width)
    # Edge normal n = (sin theta, cos theta) in (x, y); theta = pi/2 - tilt for a
    # pipe turned by `tilt` from the vertical.
    theta = (np.pi / 2 - tilt) % np.pi
    s, c = np.sin(theta), np.cos(theta)
    ox, oy = width / 2, height / 2
    centres = start + speed * np.arange(n_frames)
    # The centre line passes through (centre, oy): its rho.
    rho_c = (centres - ox) * s
    frames = []
    for rc in rho_c:
        d = (x - ox) * s + (y - oy) * c - rc
        inside = jnp.clip(pipe_width / 2 + 0.5 - jnp.abs(d), 0.0, 1.0)
        frames.append(background + (foreground - background) * inside)
    frames = _finish(jnp.stack(frames), key, noise)
    half = pipe_width / 2
    lead = 1 if speed * s >= 0 else -1  # the edge on the side of motion gets brighter
    truth = PipeTruth(
        theta=np.full(n_frames, theta),
        rho_left=rho_c - half,
        rho_right=rho_c + half,
        polarity_left=np.full(n_frames, -lead),
        polarity_right=np.full(n_frames, lead),
        width=np.full(n_frames, pipe_width),
        pos=centres,
    )
    return SyntheticScene(frames, jnp.arange(n_frames, dtype=jnp.float32) / fps, truth)


def _disc_frames(x, y, a, b, r, inside_value, outside_value):
    d = jnp.sqrt((x - a) ** 2 + (y - b) ** 2)
    cover = jnp.clip(r + 0.5 - d, 0.0, 1.0)
    return outside_value + (inside_value - outside_value) * cover


def lying_pipe(
    *,
    n_frames: int = 8,
    height: int = 128,
    width: int = 128,
    centre: tuple[float, float] = (56.0, 64.0),
    radius: float = 20.0,
    speed: float = 3.0,
    growth: float = 1.0,
    background: float = 0.8,
    hole: float = 0.15,
    noise: float = 0.0,
    fps: float = 100.0,
    key: jax.Array | None = None,
) -> SyntheticScene:
    """The dark opening of a pipe seen head on, drifting sideways and growing.

    Args:
        centre: ``(a, b)`` in frame 0, pixels.
        radius: radius in frame 0, pixels.
        speed: sideways motion, pixels per frame.
        growth: radius increase per frame, pixels (the camera approaches).
        background, hole: intensities of the wall and of the opening.
        key: PRNG key for the pixel noise (needed when ``noise > 0``); the other
            arguments as in `standing_pipe`.
    """
    _check(n_frames, height, width, noise, fps)
    x, y = _grid(height, width)
    k = np.arange(n_frames)
    a = centre[0] + speed * k
    b = np.full(n_frames, float(centre[1]))
    r = radius + growth * k
    frames = jnp.stack([_disc_frames(x, y, a[i], b[i], r[i], hole, background) for i in range(n_frames)])
    frames = _finish(frames, key, noise)
    return SyntheticScene(frames, jnp.arange(n_frames, dtype=jnp.float32) / fps, CircleTruth(a, b, r))


def moving_ball(
    *,
    n_frames: int = 8,
    height: int = 128,
    width: int = 128,
    start: tuple[float, float] = (40.0, 50.0),
    velocity: tuple[float, float] = (4.0, 2.0),
    radius: float = 12.0,
    background: float = 0.2,
    ball: float = 0.9,
    noise: float = 0.0,
    fps: float = 100.0,
    key: jax.Array | None = None,
) -> SyntheticScene:
    """A bright ball moving at constant velocity (pixels per frame) on a dark background.

    ``key`` draws the pixel noise (needed when ``noise > 0``); the other
    arguments as in `standing_pipe`.
    """
    _check(n_frames, height, width, noise, fps)
    x, y = _grid(height, width)
    k = np.arange(n_frames)
    a = start[0] + velocity[0] * k
    b = start[1] + velocity[1] * k
    r = np.full(n_frames, float(radius))
    frames = jnp.stack([_disc_frames(x, y, a[i], b[i], radius, ball, background) for i in range(n_frames)])
    frames = _finish(frames, key, noise)
    return SyntheticScene(frames, jnp.arange(n_frames, dtype=jnp.float32) / fps, CircleTruth(a, b, r))
