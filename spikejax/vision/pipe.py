"""Pipe detection and relative position from spiking Hough output (snake pipe-tracking paper).

Jiang, Bing, Huang and Knoll (2019), "Retina-based pipe-like object tracking
implemented through spiking neural network on a snake robot", Sections 2.3-2.4:

* **Alg. 2** (pipe detection): a standing pipe's body is two parallel edges of
  opposite polarity (one edge brightens while the other darkens as the camera
  sweeps across it). In each time slot, among the line grid's output spikes,
  the pair of neurons with opposite spike polarity, parallel within a
  tolerance, that fired together most often is the pipe ``P(t, theta, w, pos)``
  (`find_body`). A lying pipe seen end-on is a ring: the circle grid's
  most active neuron is the pipe entry (`find_entry`).
* **Alg. 3** (relative position): the distance from a known pipe size, Eq. (8),
  or from the expansion of the pipe over 10 detections, Eq. (9); the pipe's
  lateral offset in the camera from its image position and the field of view;
  the camera's own lateral offset from the head joint angle and velocity,
  Eqs. (4)-(6); and the bang-bang control ``C = sign(offset)``
  (`track_step`, `track`).

Everything is written for one stream and jits and vmaps; the number of
candidate spikes ``k`` and the Eq. (9) interval are static.

Conventions
-----------
* Lines follow the paper's Eq. (2) measured from an origin ``(ox, oy)``:
  ``rho = (x - ox) sin(theta) + (y - oy) cos(theta)``, ``x`` the column, ``y``
  the row (row 0 at the top), ``theta`` in ``[0, pi)``; the paper's origin is
  the top-left pixel, `spikejax.vision.hough.LineGrid`'s default the
  image centre. A vertical line ``x = ox + r`` has ``theta = pi/2``,
  ``rho = r``. `find_body` takes the grid's ``theta`` and ``rho`` values
  per index, so any such grid (any resolution, signed ``rho``) fits.
* ``pos`` is the column (pixels from the left edge of the image) where the
  pipe's centre line crosses the image's middle row; ``w`` is the
  perpendicular distance between the two edges, pixels. For an entry, ``pos``
  and ``row`` are the ring centre's column and row, ``w`` its diameter and
  ``theta`` 0.
* Lateral offsets are metres, positive to the right of the camera's optical
  axis (``pos`` right of the image centre) and of the robot's central line.
  ``C = +1`` means turn right, ``-1`` turn left, ``0`` go straight.
* A distance of 0 means "unknown" (the paper's Alg. 3, line 8): fewer than
  ``interval`` earlier detections, or a pipe that did not grow.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp

from spikejax.ranges import NON_NEGATIVE, POSITIVE, Range, ranged

__all__ = [
    "BODY",
    "ENTRY",
    "BodyParams",
    "Estimate",
    "Pipe",
    "TrackParams",
    "TrackState",
    "camera_offset",
    "distance_from_expansion",
    "distance_from_size",
    "find_body",
    "find_entry",
    "head_joint_angle",
    "pipe_offset",
    "spike_counts",
    "track",
    "track_init",
    "track_params",
    "track_step",
]

BODY = 0
ENTRY = 1


class Pipe(NamedTuple):
    """A detection ``P(t, theta, w, pos)`` of Alg. 2 (scalars, or ``(n,)`` for a sequence).

    Attributes:
        t: time of the slot, s.
        theta: angle of the edges in Eq. (2)'s convention, rad (``pi/2`` upright).
        width: ``w``, pixels.
        pos: column of the pipe's centre at ``row``, pixels from the left.
        row: the middle row for a body, the ring centre's row for an entry.
        kind: `BODY` (two parallel edges) or `ENTRY` (a ring).
        score: output spikes behind the detection (the pair's smaller count
            for a body, the neuron's count for an entry).
        valid: whether a pipe was found in the slot.
    """

    t: jax.Array
    theta: jax.Array
    width: jax.Array
    pos: jax.Array
    row: jax.Array
    kind: jax.Array
    score: jax.Array
    valid: jax.Array


class BodyParams(NamedTuple):
    """The judgment conditions of Alg. 2 (Section 2.3), all traced.

    Attributes:
        angle_tol: largest angle between the two edges, rad ("parallel or the
            difference of the angle is tiny").
        min_width: smallest distance between the edges, pixels: two spikes of
            one edge (its two polarities a pixel apart) are not a pipe.
        max_width: largest distance between the edges, pixels.
        min_count: fewest updates of the slot in which both edges fired.
    """

    angle_tol: jax.Array | float = math.radians(5.0)
    min_width: jax.Array | float = 3.0
    max_width: jax.Array | float = 1e9
    min_count: jax.Array | float = 1.0


def spike_counts(spikes: jax.Array, n_grid_axes: int = 2) -> tuple[jax.Array, jax.Array]:
    """Positive and negative output spikes per neuron, summed over leading time axes.

    Args:
        spikes: output spikes with values in ``{-1, 0, +1}``, shape
            ``(..., *grid)``: the bipolar LIF's ``delta = sign(v)`` of Alg. 1
            for every update in a slot (one update per slot in the synchronous
            mode, one per event in the asynchronous mode).
        n_grid_axes: number of trailing grid axes (2 for lines, 3 for circles).

    Returns:
        ``(positive, negative)`` counts, each of the grid's shape, float32.
    """
    spikes = jnp.asarray(spikes)
    axes = tuple(range(spikes.ndim - n_grid_axes))
    positive = jnp.sum(spikes > 0, axis=axes, dtype=jnp.float32)
    negative = jnp.sum(spikes < 0, axis=axes, dtype=jnp.float32)
    return positive, negative


def _fractions(strength, shape):
    """Tie-breakers scaled into ``[0, 0.5]``, so that they never outweigh one spike."""
    if strength is None:
        zero = jnp.zeros(shape, jnp.float32)
        return zero, zero
    top = jnp.maximum(jnp.maximum(jnp.max(strength[0]), jnp.max(strength[1])), 1e-12)
    return 0.5 * strength[0] / top, 0.5 * strength[1] / top


def _column_at_row(theta, rho, origin, row):
    """Column where the line ``rho = (x - ox) sin(theta) + (y - oy) cos(theta)`` crosses ``row``."""
    s = jnp.sin(theta)
    s = jnp.where(jnp.abs(s) < 1e-6, 1e-6, s)
    return origin[0] + (rho - (row - origin[1]) * jnp.cos(theta)) / s


def find_body(
    params: BodyParams,
    spikes: jax.Array,
    theta: jax.Array,
    rho: jax.Array,
    t: jax.Array | float,
    *,
    strength: tuple[jax.Array, jax.Array] | None = None,
    origin: tuple[float, float] = (0.0, 0.0),
    row: float = 64.0,
    k: int = 32,
) -> Pipe:
    """Alg. 2, line 11: the pipe body among a slot's line-grid output spikes.

    The ``k`` neurons that fired most positive spikes in the slot and the
    ``k`` that fired most negative ones are paired, every positive with every
    negative one. A pair qualifies when (Section 2.3) the polarities are
    opposite, the two lines are parallel within ``angle_tol`` (angles compared
    modulo ``pi``) and ``min_width <= w <= max_width``. "The pair of parallel
    lines appears at the maximum frequency": the qualifying pair that fired
    together (in the same update) most often is the pipe; ties go to the
    pair with more spikes in all, then to the larger ``strength``. Counting
    joint firing rather than each line's own spikes keeps two edges seen at
    different moments of a sweeping camera from pairing into a wrong width.

    When the grid reports at most one spike per neuron per update (the
    synchronous mode fires every neuron over threshold at once), many
    neighbouring neurons tie; ``strength`` breaks the ties, in the choice of
    candidates and of the pair, without ever outranking a spike.
    `spikejax.vision.detect` passes the slot's votes split by sign.

    Args:
        params: the judgment conditions.
        spikes: output spikes in ``{-1, 0, +1}``, shape ``(n_updates, n_theta,
            n_rho)``: one grid per update of the slot.
        theta: ``(n_theta,)`` angle of each grid row, rad, Eq. (2).
        rho: ``(n_rho,)`` distance of each grid column, pixels, Eq. (2).
        t: time stamp of the slot, s.
        strength: optional ``(positive, negative)`` tie-breakers of the
            grid's shape, >= 0 (e.g. the votes of each sign in the slot).
        origin: ``(ox, oy)``, the pixel the grid measures ``rho`` from.
        row: the row at which ``pos`` is read (the image's middle row).
        k: candidates per polarity (static).

    Returns:
        A `Pipe` of kind `BODY`, ``score`` the number of updates
        in which the pair fired together; ``valid`` is False when no pair
        qualifies.
    """
    n_updates, n_theta, n_rho = spikes.shape
    flat = spikes.reshape(n_updates, -1)
    fired_pos, fired_neg = flat > 0, flat < 0
    positive = jnp.sum(fired_pos, axis=0, dtype=jnp.float32)
    negative = jnp.sum(fired_neg, axis=0, dtype=jnp.float32)
    k = min(k, n_theta * n_rho)
    f_pos, f_neg = _fractions(strength, positive.shape)
    _, i_pos = jax.lax.top_k(positive + f_pos.reshape(-1), k)
    _, i_neg = jax.lax.top_k(negative + f_neg.reshape(-1), k)
    c_pos, c_neg = positive[i_pos], negative[i_neg]
    f_pos, f_neg = f_pos.reshape(-1)[i_pos], f_neg.reshape(-1)[i_neg]
    # Updates in which positive candidate i and negative candidate j both fired.
    together = fired_pos[:, i_pos].astype(jnp.float32).T @ fired_neg[:, i_neg].astype(jnp.float32)
    th_pos, r_pos = theta[i_pos // n_rho], rho[i_pos % n_rho]
    th_neg, r_neg = theta[i_neg // n_rho], rho[i_neg % n_rho]
    # Pair matrix (positive i, negative j). A line at theta - pi is the same
    # line with rho negated: bring each negative edge within pi/2 of the positive.
    d = th_neg[None, :] - th_pos[:, None]
    wrap = jnp.round(d / jnp.pi)
    th_neg_aligned = th_neg[None, :] - wrap * jnp.pi
    r_neg_aligned = jnp.where(jnp.mod(wrap, 2) == 1, -r_neg[None, :], r_neg[None, :])
    angle = jnp.abs(th_neg_aligned - th_pos[:, None])
    width = jnp.abs(r_neg_aligned - r_pos[:, None])
    ok = (
        (together >= jnp.maximum(params.min_count, 1e-6))
        & (angle <= params.angle_tol)
        & (width >= params.min_width)
        & (width <= params.max_width)
    )
    # Lexicographic: firing together, then the total count, then the strength (< 1).
    total = c_pos[:, None] + c_neg[None, :]
    tie = 0.5 * (f_pos[:, None] + f_neg[None, :])
    top = 2.0 * n_updates + 2.0
    key = jnp.where(ok, (together * top + total) * 2.0 + tie, -1.0)
    best = jnp.argmax(key.reshape(-1))
    i, j = best // k, best % k
    theta_mean = 0.5 * (th_pos[i] + th_neg_aligned[i, j])
    pos = 0.5 * (
        _column_at_row(th_pos[i], r_pos[i], origin, row)
        + _column_at_row(th_neg_aligned[i, j], r_neg_aligned[i, j], origin, row)
    )
    return Pipe(
        t=jnp.asarray(t, jnp.float32),
        theta=jnp.mod(theta_mean, jnp.pi),
        width=width[i, j],
        pos=pos,
        row=jnp.asarray(row, jnp.float32),
        kind=jnp.asarray(BODY, jnp.int32),
        score=together[i, j],
        valid=ok[i, j],
    )


def find_entry(
    counts: jax.Array,
    radii: jax.Array,
    t: jax.Array | float,
    min_count: jax.Array | float = 1.0,
    *,
    strength: jax.Array | None = None,
) -> Pipe:
    """The pipe entry: the circle-grid neuron that fired most in the slot (Section 2.3).

    Ties (see `find_body`) are broken by ``strength`` when given.

    Args:
        counts: output spikes per neuron (both polarities), shape
            ``(n_r, height, width)``: radius, centre row ``b``, centre column
            ``a`` (the layout of `spikejax.vision.hough.CircleGrid`).
        radii: ``(n_r,)`` radius of each plane, pixels.
        t: time stamp of the slot, s.
        min_count: fewest spikes for a detection.
        strength: optional tie-breaker of the grid's shape, >= 0.

    Returns:
        A `Pipe` of kind `ENTRY`: ``pos = a``, ``row = b``,
        ``width = 2 r``, ``theta = 0``.
    """
    height, width = counts.shape[1], counts.shape[2]
    tie = _fractions(None if strength is None else (strength, strength), counts.shape)[0]
    best = jnp.argmax((counts + tie).reshape(-1))
    ir, ib, ia = best // (height * width), (best // width) % height, best % width
    score = counts.reshape(-1)[best].astype(jnp.float32)
    return Pipe(
        t=jnp.asarray(t, jnp.float32),
        theta=jnp.zeros((), jnp.float32),
        width=2.0 * jnp.asarray(radii, jnp.float32)[ir],
        pos=ia.astype(jnp.float32),
        row=ib.astype(jnp.float32),
        kind=jnp.asarray(ENTRY, jnp.int32),
        score=score,
        valid=score >= jnp.maximum(min_count, 1e-6),
    )


# --- Alg. 3 ------------------------------------------------------------------


def distance_from_size(width, focal, size):
    """Eq. (8): ``d = f l / w``, the distance of a pipe of known diameter ``l``.

    Args:
        width: ``w``, the pipe's width in the image, pixels.
        focal: ``f``, focal length, pixels.
        size: ``l``, the pipe's diameter, metres.

    Returns:
        ``d``, metres (a pinhole camera; exact for a flat target, and for a
        cylinder of radius ``R`` at distance ``d`` up to ``sqrt(1 - (R/d)^2)``).
    """
    return focal * size / width


def distance_from_expansion(width_before, width_now, elapsed, speed):
    """Eq. (9): ``d2 = w1 v dt / (w2 - w1)``, the distance from the pipe's growth.

    With ``d = f l / w`` at both times and the robot closing ``v dt``
    (Eq. 7), ``f l (1/w1 - 1/w2) = v dt`` gives ``f l`` and hence ``d2``
    without knowing ``l``.

    Args:
        width_before, width_now: ``w1`` and ``w2``, pixels.
        elapsed: ``dt = t2 - t1``, s.
        speed: ``v``, the robot's forward speed, m/s.

    Returns:
        ``d2``, metres; 0 ("unknown") when the pipe did not grow (``w2 <= w1``).
    """
    grew = width_now > width_before
    return jnp.where(grew, width_before * speed * elapsed / jnp.where(grew, width_now - width_before, 1.0), 0.0)


def head_joint_angle(t, amplitude, omega, phase):
    """Eq. (4): ``theta = a sin(omega t + phi)``, the head joint under the slithering gait."""
    return amplitude * jnp.sin(omega * t + phase)


def camera_offset(angle, velocity, swing_amplitude, ratio, phase, omega):
    """Eqs. (5)-(6): the camera's lateral offset from the head joint angle and velocity.

    ``theta_tuned = alpha (theta cos(phi_pos) + theta'/omega sin(phi_pos))``
    (Eq. 5) is ``alpha a sin(omega t + phi + phi_pos)``, the joint signal
    shifted by ``phi_pos``, obtained from its present value and derivative;
    ``Position = A sin(theta_tuned)`` (Eq. 6).

    Args:
        angle: ``theta``, head joint angle, rad.
        velocity: ``theta'``, head joint velocity, rad/s.
        swing_amplitude: ``A``, metres (its sign sets the direction; the paper: -0.124 for V-REP, 1.400 for NRP).
        ratio: ``alpha``, "the ratio of the 90 degrees to ``a``" (1.000 and 2.571).
        phase: ``phi_pos``, rad (0.000 and 0.908).
        omega: the gait's angular frequency, rad/s.

    Returns:
        The camera's lateral offset, metres.

    Notes:
        The paper prints Eq. (5) as ``theta cos(phi_pos) + theta' sin(phi_pos)``;
        that equals the phase-shifted sinusoid only when ``theta'`` is measured
        per radian of gait phase, i.e. divided by ``omega``, which this
        function does. Pass ``omega=1`` for the printed form.
    """
    tuned = ratio * (angle * jnp.cos(phase) + velocity / omega * jnp.sin(phase))
    return swing_amplitude * jnp.sin(tuned)


def pipe_offset(distance, pos, center, focal):
    """Alg. 3, line 11: the pipe's lateral offset from the optical axis, metres.

    ``pipeOffset = d (pos - c) tan(phi/2) / c`` with ``c`` the image centre
    column (64 on a DVS128) and ``phi`` the field of view; with the focal
    length ``f = c / tan(phi/2)`` this is ``d (pos - c) / f``.

    Notes:
        The paper prints ``|pos - 64|``; the sign is kept here, since the
        control ``C = sign(offset)`` needs to know on which side the pipe is.
    """
    return distance * (pos - center) / focal


@ranged(focal=POSITIVE, size=NON_NEGATIVE, speed=NON_NEGATIVE)
class TrackParams(NamedTuple):
    """Parameters of Alg. 3 (traced; build them with `track_params`).

    Attributes:
        focal: ``f``, focal length, pixels.
        center: ``c``, the image centre column, pixels.
        size: ``l``, the pipe's diameter, metres, >= 0; 0 if unknown (then Eq. 9).
        speed: ``v``, forward speed of the robot, m/s, >= 0.
        swing_amplitude, swing_ratio, swing_phase: ``(A, alpha, phi_pos)`` of Eq. (6).
        omega: the gait's angular frequency, rad/s.
    """

    focal: jax.Array
    center: jax.Array
    size: jax.Array
    speed: jax.Array
    swing_amplitude: jax.Array
    swing_ratio: jax.Array
    swing_phase: jax.Array
    omega: jax.Array


@ranged(fov=Range(0, math.pi, low_open=True, high_open=True), width=Range(1, integer=True))
def track_params(
    *,
    fov: float = math.radians(60.0),
    width: int = 128,
    size: float = 0.0,
    speed: float = 0.0,
    swing_amplitude: float = 0.0,
    swing_ratio: float = 1.0,
    swing_phase: float = 0.0,
    omega: float = 1.0,
) -> TrackParams:
    """`TrackParams` from the camera's field of view (rad, in ``(0, pi)``) and width (pixels).

    The paper's swing tuples ``(A, alpha, phi_pos)`` are ``(-0.124, 1.000,
    0.000)`` in V-REP and ``(1.400, 2.571, 0.908)`` in the NRP.
    """
    f = jnp.float32
    return TrackParams(
        focal=f(0.5 * width / math.tan(0.5 * fov)),
        center=f(0.5 * width),
        size=f(size),
        speed=f(speed),
        swing_amplitude=f(swing_amplitude),
        swing_ratio=f(swing_ratio),
        swing_phase=f(swing_phase),
        omega=f(omega),
    )


class TrackState(NamedTuple):
    """The last ``interval`` detections' times and widths (a ring), and how many there were."""

    t: jax.Array  # (interval,) s
    width: jax.Array  # (interval,) pixels
    count: jax.Array  # () int32, valid detections so far


class Estimate(NamedTuple):
    """Output of Alg. 3 for one detection (metres; ``control`` in {-1, 0, +1})."""

    distance: jax.Array
    pipe_offset: jax.Array
    camera_offset: jax.Array
    offset: jax.Array
    control: jax.Array
    valid: jax.Array


def track_init(interval: int = 10) -> TrackState:
    """An empty history for Eq. (9) over ``interval`` detections (10 in the paper)."""
    return TrackState(
        jnp.zeros((interval,), jnp.float32), jnp.zeros((interval,), jnp.float32), jnp.zeros((), jnp.int32)
    )


def track_step(
    params: TrackParams, state: TrackState, pipe: Pipe, head_angle, head_velocity
) -> tuple[TrackState, Estimate]:
    """Alg. 3 for one detection ``P_i(t_i, theta_i, w_i, pos_i)``.

    The distance is Eq. (8) when ``params.size > 0``; otherwise Eq. (9)
    against the detection ``interval`` valid detections earlier (Alg. 3,
    line 6), or 0 before there were that many. Then ``pipeOffset``,
    ``cameraOffset`` (Eq. 6), ``offset = pipeOffset + cameraOffset`` and
    ``C = sign(offset)``. An invalid ``pipe`` leaves the history unchanged and
    gives zeros.

    Args:
        params: see `TrackParams`.
        state: history from `track_init` or the previous step.
        pipe: one detection (scalar fields).
        head_angle, head_velocity: ``theta`` (rad) and ``theta'`` (rad/s) of
            the head joint at ``t_i``.

    Returns:
        ``(state, estimate)``.
    """
    interval = state.t.shape[0]
    slot = state.count % interval
    known = params.size > 0
    d_known = distance_from_size(pipe.width, params.focal, jnp.where(known, params.size, 0.0))
    d_grown = distance_from_expansion(state.width[slot], pipe.width, pipe.t - state.t[slot], params.speed)
    d_grown = jnp.where(state.count >= interval, d_grown, 0.0)
    distance = jnp.where(pipe.valid, jnp.where(known, d_known, d_grown), 0.0)
    p_off = pipe_offset(distance, pipe.pos, params.center, params.focal)
    c_off = camera_offset(
        head_angle, head_velocity, params.swing_amplitude, params.swing_ratio, params.swing_phase, params.omega
    )
    offset = jnp.where(pipe.valid, p_off + c_off, 0.0)
    estimate = Estimate(
        distance=distance,
        pipe_offset=jnp.where(pipe.valid, p_off, 0.0),
        camera_offset=jnp.where(pipe.valid, c_off, 0.0),
        offset=offset,
        control=jnp.sign(offset).astype(jnp.int32),
        valid=pipe.valid,
    )
    new = TrackState(
        t=jnp.where(pipe.valid, state.t.at[slot].set(pipe.t), state.t),
        width=jnp.where(pipe.valid, state.width.at[slot].set(pipe.width), state.width),
        count=state.count + pipe.valid.astype(jnp.int32),
    )
    return new, estimate


def track(params: TrackParams, pipes: Pipe, head_angle=None, head_velocity=None, interval: int = 10) -> Estimate:
    """Alg. 3 over a sequence of detections (fields of shape ``(n,)``), as a ``lax.scan``.

    ``head_angle`` and ``head_velocity`` are ``(n,)`` (default: zeros, a camera
    on the central line).
    """
    n = pipes.t.shape[0]
    zeros = jnp.zeros((n,), jnp.float32)
    head_angle = zeros if head_angle is None else jnp.asarray(head_angle, jnp.float32)
    head_velocity = zeros if head_velocity is None else jnp.asarray(head_velocity, jnp.float32)

    def step(state, inputs):
        pipe, angle, velocity = inputs
        return track_step(params, state, pipe, angle, velocity)

    _, estimates = jax.lax.scan(step, track_init(interval), (pipes, head_angle, head_velocity))
    return estimates
