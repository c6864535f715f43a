"""The target's tracks (Fig. 5 of the snake R-STDP paper), its motion rule and the angles of Eq. (12).

The paper's snake starts at (-5, 0) heading along +x, and the target sphere
(radius 0.3 m) is spawned 1.6 m in front of it, at (-3.4, 0). Fig. 5 draws the
tracks without dimensions: (a) an 8-shaped training track, mirrored about the
x axis after each episode so that the target goes alternately
counter-clockwise and clockwise round its first lobe; (b) a ladder and (c) a
zigzag test track, "with a similar curvature as the training path", tested as
drawn and mirrored. Here each track is a curve of piecewise-constant curvature
(straight lines and circular arcs) parametrised by arc length ``s``, so that its
points, headings and curvature are closed forms, and every turn has the same
radius `TURN_RADIUS`:

* ``eight``: a straight lead-in from the spawn point to the origin, then
  forever a counter-clockwise circle above the x axis and a clockwise one
  below it, the two lobes of the 8 meeting at the origin;
* ``ladder``: the lead-in, then steps: a quarter turn left, a straight rung, a
  quarter turn right, a straight run along +x;
* ``zigzag``: the lead-in, then alternating straight legs at +-45 degrees to
  the x axis joined by arcs.

The mirror image of a track is ``(x, y) -> (x, -y)``.

The target moves along its track "a little faster than the snake robot, but
not further away from the snake robot than the initial distance": each control
step it advances by ``speed * dt`` unless that would take it farther than the
initial 1.6 m from the snake's head, in which case it waits (`advance`).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from spikejax.errors import UserError

START = (-5.0, 0.0)  # the snake's head at the start (Fig. 5)
SPAWN_DISTANCE = 1.6  # the target starts this far in front of the head (section II-A)
TARGET_RADIUS = 0.3  # the target sphere (section II-A)
TURN_RADIUS = 2.5  # every arc of every track; Fig. 5 has no scale, chosen within the snake's turning range
LEAD_IN = -START[0] - SPAWN_DISTANCE  # straight from the spawn point (-3.4, 0) to the origin
TRACK_LENGTH = 1000.0  # each track is built at least this long; the target stops at its end

TRACKS = ("eight", "eight-mirror", "ladder", "ladder-mirror", "zigzag", "zigzag-mirror")


class Track(NamedTuple):
    """A curve of piecewise-constant curvature, parametrised by arc length.

    Segment ``k`` starts at arc length ``s0[k]`` at point ``start[k]`` (2,) with
    heading ``heading[k]`` (radians from +x, counter-clockwise) and has
    curvature ``curvature[k]`` (1/m, positive turning left). ``length`` is the
    total arc length. All fields are arrays, so a track can be traced (a batch of
    targets on different tracks of the same number of segments vmaps).
    """

    s0: jax.Array
    start: jax.Array
    heading: jax.Array
    curvature: jax.Array
    length: jax.Array


def from_segments(origin, heading, segments) -> Track:
    """A `Track` from ``(length, curvature)`` segments, integrated in closed form from ``origin``."""
    s0, starts, headings, curvatures = [], [], [], []
    p = np.asarray(origin, float)
    th = float(heading)
    s = 0.0
    for length, kappa in segments:
        s0.append(s)
        starts.append(p.copy())
        headings.append(th)
        curvatures.append(kappa)
        p = p + _chord(th, kappa, length)
        th += kappa * length
        s += length
    f = lambda a: jnp.asarray(np.asarray(a), jnp.float32)  # noqa: E731
    return Track(f(s0), f(starts), f(headings), f(curvatures), f(s))


def _chord(th, kappa, ds):
    """Displacement along an arc of curvature ``kappa`` and length ``ds`` from heading ``th`` (numpy)."""
    if abs(kappa) < 1e-12:
        return ds * np.array([math.cos(th), math.sin(th)])
    return np.array([math.sin(th + kappa * ds) - math.sin(th), math.cos(th) - math.cos(th + kappa * ds)]) / kappa


def _repeat(unit, length):
    n = math.ceil(length / sum(seg[0] for seg in unit))
    return list(unit) * n


def eight(radius: float = TURN_RADIUS) -> Track:
    """Fig. 5(a): lead-in, then a counter-clockwise lobe above the x axis and a clockwise one below, repeated."""
    lobe = 2.0 * math.pi * radius
    return from_segments(
        (-LEAD_IN, 0.0), 0.0, [(LEAD_IN, 0.0)] + _repeat([(lobe, 1.0 / radius), (lobe, -1.0 / radius)], TRACK_LENGTH)
    )


def ladder(radius: float = TURN_RADIUS, rung: float = 2.0, run: float = 3.0) -> Track:
    """Fig. 5(b): lead-in, then steps climbing to the left: quarter turn left, rung, quarter turn right, run."""
    quarter = 0.5 * math.pi * radius
    unit = [(quarter, 1.0 / radius), (rung, 0.0), (quarter, -1.0 / radius), (run, 0.0)]
    return from_segments((-LEAD_IN, 0.0), 0.0, [(LEAD_IN, 0.0)] + _repeat(unit, TRACK_LENGTH))


def zigzag(radius: float = TURN_RADIUS, leg: float = 4.0) -> Track:
    """Fig. 5(c): lead-in, then legs at +45 and -45 degrees to the x axis joined by arcs."""
    eighth = 0.25 * math.pi * radius
    unit = [(eighth, 1.0 / radius), (leg, 0.0), (2 * eighth, -1.0 / radius), (leg, 0.0), (eighth, 1.0 / radius)]
    return from_segments((-LEAD_IN, 0.0), 0.0, [(LEAD_IN, 0.0)] + _repeat(unit, TRACK_LENGTH))


def mirror(track: Track) -> Track:
    """The mirror image about the x axis, ``(x, y) -> (x, -y)``."""
    return track._replace(
        start=track.start * jnp.array([1.0, -1.0]), heading=-track.heading, curvature=-track.curvature
    )


def get(name: str) -> Track:
    """A track by name, one of `TRACKS`."""
    base, _, mirrored = name.partition("-")
    builders = {"eight": eight, "ladder": ladder, "zigzag": zigzag}
    if base not in builders or mirrored not in ("", "mirror"):
        raise UserError(f"unknown track {name!r}; choose one of {', '.join(TRACKS)}")
    track = builders[base]()
    return mirror(track) if mirrored else track


def training_mirror(episode):
    """Whether episode ``episode`` runs the 8 mirrored: odd episodes are (Fig. 5 caption)."""
    return episode % 2 == 1


def training_track(episode: int) -> Track:
    """The 8 of episode ``episode``: as drawn for even episodes, mirrored for odd ones (Fig. 5 caption)."""
    return mirror(eight()) if training_mirror(episode) else eight()


def _segment(track: Track, s):
    s = jnp.clip(s, 0.0, track.length)
    k = jnp.clip(jnp.searchsorted(track.s0, s, side="right") - 1, 0, track.s0.shape[0] - 1)
    return k, s - track.s0[k]


def point(track: Track, s) -> jax.Array:
    """The track's point ``(x, y)`` at arc length ``s`` (clamped to ``[0, length]``)."""
    k, ds = _segment(track, s)
    th, kappa = track.heading[k], track.curvature[k]
    straight = jnp.abs(kappa) < 1e-9
    safe = jnp.where(straight, 1.0, kappa)
    arc = jnp.stack([jnp.sin(th + kappa * ds) - jnp.sin(th), jnp.cos(th) - jnp.cos(th + kappa * ds)]) / safe
    line = ds * jnp.stack([jnp.cos(th), jnp.sin(th)])
    return track.start[k] + jnp.where(straight, line, arc)


def heading(track: Track, s) -> jax.Array:
    """The track's direction (radians from +x, counter-clockwise) at arc length ``s``."""
    k, ds = _segment(track, s)
    return track.heading[k] + track.curvature[k] * ds


def advance(track: Track, s, head_xy, speed, dt, max_distance=SPAWN_DISTANCE):
    """The target's next arc length: ``s + speed * dt``, unless that point is farther than ``max_distance`` from the head.

    Section II-A: the target "moves a little bit faster than the snake robot,
    but not further away from the snake robot than the initial distance".
    """
    ahead = s + speed * dt
    ok = jnp.linalg.norm(point(track, ahead) - head_xy) <= max_distance
    return jnp.where(ok, jnp.minimum(ahead, track.length), s)


def wrap(angle):
    """An angle in ``[-pi, pi)``."""
    return (angle + jnp.pi) % (2 * jnp.pi) - jnp.pi


def target_angles(head_xy, head_forward_xy, target_xy, d_head):
    """The angles of the target to the head and to the body, Eq. (12) of the snake R-STDP paper.

    ``a_head`` is the angle between the head's forward direction (projected on
    the ground) and the direction from the head to the target, positive when
    the target is to the right, so that a positive angle rewards the right
    output neuron as in Eq. (9). ``d_head`` is the head's yaw
    deflection commanded by the head controller, positive to the left
    (counter-clockwise seen from above); ``a_body = a_head - d_head`` (Eq. 12)
    is then the angle between the body's direction and the target.
    Returns ``(a_head, a_body)`` in radians.
    """
    to_target = target_xy - head_xy
    bearing = jnp.arctan2(to_target[1], to_target[0])
    facing = jnp.arctan2(head_forward_xy[1], head_forward_xy[0])
    a_head = wrap(facing - bearing)
    return a_head, a_head - d_head
