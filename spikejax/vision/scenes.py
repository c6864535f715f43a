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
* `snake_view`: what the snake's head camera sees of one pipe, or of none:
  a sky above a bobbing horizon, a floor below it, and a dark standing pipe
  (two edges from its base up out of the image), a lying pipe's entry (a dark
  bore inside a lighter wall ring) or nothing, swinging sideways with the
  gait, with pixel noise. `random_view` draws one from a key: the scenes of
  the detector's false-positive and detection rates (`detection_rates`).

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

__all__ = [
    "KINDS",
    "PipeTruth",
    "CircleTruth",
    "SyntheticScene",
    "View",
    "detection_rates",
    "in_view",
    "lying_pipe",
    "moving_ball",
    "random_view",
    "snake_view",
    "standing_pipe",
]

KINDS = ("standing", "lying", "empty")


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
        truth: `PipeTruth` or `CircleTruth`; ``None`` for a scene without a pipe.
    """

    frames: jax.Array
    times: jax.Array
    truth: PipeTruth | CircleTruth | None


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


class View(NamedTuple):
    """The placement of a `snake_view` scene (host floats; per-frame values follow from them).

    Attributes:
        kind: ``"standing"``, ``"lying"`` or ``"empty"``.
        centre: the pipe's centre column at rest, pixels.
        swing: amplitude of the sideways swing, pixels.
        period: period of the swing, frames.
        phase: phase of the swing at frame 0, rad.
        size: the standing pipe's width or the entry's outer radius, pixels.
        horizon: the horizon's row at rest, pixels.
        bob: amplitude of the horizon's vertical bob (the gait's pitch), pixels.
        base: the standing pipe's base (or the ring's centre), rows below the horizon.
    """

    kind: str
    centre: float
    swing: float
    period: float
    phase: float
    size: float
    horizon: float
    bob: float
    base: float


SKY, FLOOR, PIPE, WALL, BORE = 0.8, 0.4, 0.1, 0.6, 0.05


def snake_view(
    view: View,
    *,
    n_frames: int = 30,
    height: int = 128,
    width: int = 128,
    noise: float = 0.0,
    fps: float = 50.0,
    key: jax.Array | None = None,
) -> SyntheticScene:
    """The head camera's view of one pipe (or none) while the snake slithers: frames and truth.

    The sky (0.8) lies above a horizon at ``view.horizon + bob sin(4 pi k /
    period)`` (the dorsal wave bobs at twice the gait's frequency), the floor
    (0.4) below it. The pipe swings sideways with the gait, its centre at
    ``centre + swing sin(2 pi k / period + phase)`` in frame ``k``:

    * ``"standing"``: a dark (0.1) upright pipe ``size`` pixels wide, from
      its base ``base`` rows below the horizon up out of the image; its two
      edges make events of opposite polarity while it swings (truth:
      `PipeTruth`).
    * ``"lying"``: a pipe's entry seen end on, a dark bore (0.05) of radius
      ``0.8 size`` inside a lighter wall face (0.6) of outer radius ``size``,
      its centre ``base`` rows below the horizon (truth: `CircleTruth` of
      the outer rim).
    * ``"empty"``: the horizon alone (truth ``None``).

    Args:
        view: the placement.
        n_frames, height, width, noise, fps, key: as in `standing_pipe`
            (50 frames/s: the snake's 20 ms control step).
    """
    if view.kind not in KINDS:
        raise UserError(f"unknown view kind {view.kind!r}; expected one of {', '.join(KINDS)}")
    _check(n_frames, height, width, noise, fps)
    x, y = _grid(height, width)
    k = np.arange(n_frames)
    centre = view.centre + view.swing * np.sin(2 * np.pi * k / view.period + view.phase)
    horizon = view.horizon + view.bob * np.sin(4 * np.pi * k / view.period)
    frames = []
    for i in range(n_frames):
        ground = jnp.clip(y - horizon[i] + 0.5, 0.0, 1.0)
        frame = SKY + (FLOOR - SKY) * ground
        if view.kind == "standing":
            across = jnp.clip(0.5 * view.size + 0.5 - jnp.abs(x - centre[i]), 0.0, 1.0)
            below_base = jnp.clip(y - (view.horizon + view.base) + 0.5, 0.0, 1.0)
            cover = across * (1.0 - below_base)
            frame = frame + (PIPE - frame) * cover
        elif view.kind == "lying":
            b = view.horizon + view.base
            frame = _disc_frames(x, y, centre[i], b, view.size, WALL, 0.0) + frame * (
                1.0 - _disc_frames(x, y, centre[i], b, view.size, 1.0, 0.0)
            )
            bore = _disc_frames(x, y, centre[i], b, 0.8 * view.size, 1.0, 0.0)
            frame = frame + (BORE - frame) * bore
        frames.append(frame)
    frames = _finish(jnp.stack(frames), key, noise)
    times = jnp.arange(n_frames, dtype=jnp.float32) / fps
    if view.kind == "standing":
        half = 0.5 * view.size
        velocity = np.gradient(centre) if n_frames > 1 else np.zeros(n_frames)
        lead = np.where(velocity >= 0, -1, 1)  # a dark pipe moving right darkens on its right edge
        truth = PipeTruth(
            theta=np.full(n_frames, np.pi / 2),
            rho_left=centre - half - width / 2,
            rho_right=centre + half - width / 2,
            polarity_left=-lead,
            polarity_right=lead,
            width=np.full(n_frames, float(view.size)),
            pos=centre,
        )
    elif view.kind == "lying":
        truth = CircleTruth(centre, np.full(n_frames, view.horizon + view.base), np.full(n_frames, float(view.size)))
    else:
        truth = None
    return SyntheticScene(frames, times, truth)


def random_view(key: jax.Array, kind: str, *, height: int = 128, width: int = 128, period: float = 125.0) -> View:
    """A `View` of ``kind`` drawn from ``key``: the placements of the detection rates.

    Sizes scale with the sensor (those below are for 128 pixels): a standing
    pipe 8-40 pixels wide (0.25 m at 0.7-3.5 m with a 60 degree field of
    view), its base 1-6 rows below the horizon; an entry of outer radius 10-28
    pixels, its centre 0-6 rows below the horizon; the centre within the
    middle half of the image, a swing of 10-30 pixels (the head's residual yaw
    of about 15 degrees is 30 pixels)
    over the gait's period (125 frames: 2.5 s at 50 frames/s) from a random
    phase, a horizon at rows 56-72 bobbing by up to 2 pixels.
    """
    if kind not in KINDS:
        raise UserError(f"unknown view kind {kind!r}; expected one of {', '.join(KINDS)}")
    u = np.asarray(jax.random.uniform(key, (7,)), np.float64)
    scale = width / 128.0
    size = (8.0 + 32.0 * u[0]) * scale if kind == "standing" else (10.0 + 18.0 * u[0]) * scale
    base = (1.0 + 5.0 * u[1]) * scale if kind == "standing" else 6.0 * u[1] * scale
    return View(
        kind=kind,
        centre=float(width * (0.25 + 0.5 * u[2])),
        swing=float((10.0 + 20.0 * u[3]) * scale),
        period=float(period),
        phase=float(2 * np.pi * u[4]),
        size=float(size),
        horizon=float(height * (56.0 + 16.0 * u[5]) / 128.0),
        bob=float(2.0 * u[6] * scale),
        base=float(base),
    )


def in_view(scene: SyntheticScene, width: int, height: int | None = None) -> np.ndarray:
    """Whether the whole pipe is inside the image in each frame, ``(n,)`` bool (False without a pipe).

    A body: both edges inside the columns. An entry: the whole ring inside the image.
    """
    truth = scene.truth
    n = scene.frames.shape[0]
    height = scene.frames.shape[1] if height is None else height
    if truth is None:
        return np.zeros(n, bool)
    if isinstance(truth, PipeTruth):
        left, right = truth.pos - 0.5 * truth.width, truth.pos + 0.5 * truth.width
        return (left >= 0) & (right <= width - 1)
    return (
        (truth.a - truth.r >= 0)
        & (truth.a + truth.r <= width - 1)
        & (truth.b - truth.r >= 0)
        & (truth.b + truth.r <= height - 1)
    )


def detection_rates(
    kinds=KINDS,
    n_scenes: int = 16,
    *,
    seed: int = 0,
    size: int = 128,
    n_frames: int = 30,
    steps_per_slot: int = 5,
    noise: float = 0.02,
    threshold: float = 0.1,
    min_travel: float = 1.0,
    params=None,
    det=None,
) -> dict:
    """Per-slot detection and false-positive rates of `spikejax.vision.detect` on `random_view` scenes.

    Each scene's events (frame difference, ``threshold``) are cut into slots
    of ``steps_per_slot`` frames, one grid update per frame, and run through
    `spikejax.vision.detect.run` (default: both grids, 1 degree and 1 pixel
    lines over the sensor's diagonal, circles of radius 1 to ``size / 2``),
    all scenes of a kind at once (``vmap``). Scene ``i`` of a kind is drawn
    from ``fold_in(key(seed), i)`` split by kind, so a rate does not depend on
    ``n_scenes`` beyond the scenes it adds.

    Returns:
        ``{kind: {"slots", "in_view", "body", "entry", "body_in_view",
        "entry_in_view"}}``: the number of slots, the slots with the whole
        pipe in view and moving (by ``min_travel`` pixels or more over the
        slot: a still pipe makes no events), and the fractions of slots (all,
        and those in view) with a body or an entry reported.
    """
    from spikejax.vision import detect, dvs, hough

    if det is None:
        det = detect.Detector(
            line=hough.LineGrid(size, size, n_rho=int(np.ceil(size * np.sqrt(2))) + 2),
            circle=hough.CircleGrid(size, size, n_r=size // 2),
            sub_slots=steps_per_slot,
        )
    params = detect.detector_params(v_th=0.5 * size) if params is None else params
    n_slots = (n_frames - 1) // steps_per_slot
    run = jax.jit(jax.vmap(detect.run, in_axes=(None, None, 0, 0)), static_argnums=0)
    out = {}
    for kind_index, kind in enumerate(kinds):
        events, times, seen = [], [], []
        for i in range(n_scenes):
            key = jax.random.fold_in(jax.random.fold_in(jax.random.key(seed), KINDS.index(kind)), i)
            k_view, k_noise = jax.random.split(key)
            scene = snake_view(
                random_view(k_view, kind, height=size, width=size), n_frames=n_frames, height=size, width=size,
                noise=noise, key=k_noise,
            )  # fmt: skip
            ev, _ = dvs.difference_events(scene.frames, scene.times, threshold=threshold, capacity=size * size)
            used = n_slots * steps_per_slot
            events.append(jax.tree.map(lambda v: v[:used].reshape(n_slots, steps_per_slot, -1), ev))
            times.append(np.asarray(scene.times[1 : used + 1]).reshape(n_slots, steps_per_slot))
            # A slot is in view when the pipe is in all its frames (frame k + 1 makes row k's events).
            frames_in = in_view(scene, size)[1 : used + 1].reshape(n_slots, steps_per_slot)
            centre = (
                np.zeros(n_frames) if scene.truth is None else np.asarray(scene.truth[-1 if kind == "standing" else 0])
            )
            # ... and moving: a still edge makes no events (the swing's turning points).
            travel = np.abs(centre[steps_per_slot : used + 1 : steps_per_slot] - centre[0:used:steps_per_slot])
            seen.append(frames_in.all(axis=1) & (travel >= min_travel))
        batch = jax.tree.map(lambda *v: jnp.stack(v), *events)
        _, bodies, entries = run(det, params, batch, jnp.asarray(np.stack(times)))
        body, entry, seen = np.asarray(bodies.valid), np.asarray(entries.valid), np.stack(seen)
        out[kind] = dict(
            slots=int(body.size),
            in_view=int(seen.sum()),
            body=float(body.mean()),
            entry=float(entry.mean()),
            body_in_view=float(body[seen].mean()) if seen.any() else float("nan"),
            entry_in_view=float(entry[seen].mean()) if seen.any() else float("nan"),
        )
    return out
