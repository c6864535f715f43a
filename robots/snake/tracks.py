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

Each track comes in two lengths: endless (built to at least `TRACK_LENGTH`,
the target never runs out of track) and as drawn (``drawn=True``: one 8, the
ladder's `LADDER_STEPS` steps, the zigzag's `ZIGZAG_PERIODS` periods), which has
an end, so that an episode can be completed: the R-STDP training's episode is
one traversal of the drawn 8 (section III of the paper), and a test is one pass
of a drawn test track. Fig. 5 has no scale; the drawn lengths are this
project's choice (`drawn_length` gives them).

Any other track can be given as waypoints (`from_waypoints`, `load_waypoints`):
a polyline placed so that the snake starts `SPAWN_DISTANCE` behind its first
waypoint, facing along its first segment.

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
TRACK_LENGTH = 1000.0  # each endless track is built at least this long; the target stops at its end
LADDER_STEPS = 2  # steps of the drawn ladder (Fig. 5b has no scale: this project's choice)
ZIGZAG_PERIODS = 1  # periods (one leg up, one leg down) of the drawn zigzag (Fig. 5c, likewise)

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


def _repeat(unit, units):
    """``unit`` repeated ``units`` times, or (``units=None``) until at least `TRACK_LENGTH` long."""
    if units is None:
        units = math.ceil(TRACK_LENGTH / sum(seg[0] for seg in unit))
    return list(unit) * units


def _with_lead_in(segments) -> Track:
    return from_segments((-LEAD_IN, 0.0), 0.0, [(LEAD_IN, 0.0)] + segments)


def eight(radius: float = TURN_RADIUS, units: int | None = None) -> Track:
    """Fig. 5(a): lead-in, then a counter-clockwise lobe above the x axis and a clockwise one below.

    ``units`` 8s follow the lead-in (``None``: endless, `TRACK_LENGTH`); the drawn 8 is ``units=1``.
    """
    lobe = 2.0 * math.pi * radius
    return _with_lead_in(_repeat([(lobe, 1.0 / radius), (lobe, -1.0 / radius)], units))


def ladder(radius: float = TURN_RADIUS, rung: float = 2.0, run: float = 3.0, units: int | None = None) -> Track:
    """Fig. 5(b): lead-in, then ``units`` steps climbing to the left: quarter turn left, rung, quarter turn right, run."""
    quarter = 0.5 * math.pi * radius
    return _with_lead_in(_repeat([(quarter, 1.0 / radius), (rung, 0.0), (quarter, -1.0 / radius), (run, 0.0)], units))


def zigzag(radius: float = TURN_RADIUS, leg: float = 4.0, units: int | None = None) -> Track:
    """Fig. 5(c): lead-in, then ``units`` periods of legs at +45 and -45 degrees to the x axis joined by arcs."""
    eighth = 0.25 * math.pi * radius
    unit = [(eighth, 1.0 / radius), (leg, 0.0), (2 * eighth, -1.0 / radius), (leg, 0.0), (eighth, 1.0 / radius)]
    return _with_lead_in(_repeat(unit, units))


DRAWN_UNITS = {"eight": 1, "ladder": LADDER_STEPS, "zigzag": ZIGZAG_PERIODS}


def from_waypoints(xy) -> Track:
    """A polyline through waypoints ``xy`` (k, 2), in metres, placed where the snake starts.

    The polyline is moved rigidly so that its first waypoint is the target's
    spawn point, `SPAWN_DISTANCE` in front of the snake's start `START`, and
    its first segment points along +x, the snake's initial heading: the snake
    starts 1.6 m behind the first waypoint, facing along the first segment.
    Each segment is straight; the target turns at the waypoints.

    Raises:
        UserError: for fewer than two waypoints, non-finite values, or two
            consecutive waypoints closer than 1 mm.
    """
    xy = np.asarray(xy, float)
    if xy.ndim != 2 or xy.shape[1] != 2 or xy.shape[0] < 2:
        raise UserError(f"a track needs at least two (x, y) waypoints, got an array of shape {xy.shape}")
    if not np.all(np.isfinite(xy)):
        raise UserError("track waypoints must be finite numbers")
    d = np.diff(xy, axis=0)
    lengths = np.hypot(d[:, 0], d[:, 1])
    if np.any(lengths < 1e-3):
        k = int(np.argmax(lengths < 1e-3))
        raise UserError(f"track waypoints {k + 1} and {k + 2} coincide (closer than 1 mm)")
    angles = np.arctan2(d[:, 1], d[:, 0])
    turns = np.concatenate([[0.0], np.angle(np.exp(1j * np.diff(angles)))])
    headings = np.cumsum(turns)  # first segment along +x
    spawn = np.array([START[0] + SPAWN_DISTANCE, START[1]])
    p = spawn.copy()
    starts = []
    for length, th in zip(lengths, headings):
        starts.append(p.copy())
        p = p + length * np.array([math.cos(th), math.sin(th)])
    s0 = np.concatenate([[0.0], np.cumsum(lengths)[:-1]])
    f = lambda a: jnp.asarray(np.asarray(a), jnp.float32)  # noqa: E731
    return Track(f(s0), f(starts), f(headings), f(np.zeros_like(lengths)), f(lengths.sum()))


def load_waypoints(path) -> Track:
    """`from_waypoints` of a CSV file of ``x, y`` rows in metres (an optional header line ``x,y``).

    Raises:
        UserError: naming the file (and the line) when it cannot be read as waypoints.
    """
    import csv

    rows = []
    try:
        with open(path, newline="") as f:
            for line, row in enumerate(csv.reader(f), start=1):
                cells = [c.strip() for c in row]
                if not cells or all(c == "" for c in cells) or cells[0].startswith("#"):
                    continue
                if line == 1 and [c.lower() for c in cells] == ["x", "y"]:
                    continue
                if len(cells) != 2:
                    raise UserError(f"{path}: line {line}: expected two columns x, y, got {len(cells)}")
                try:
                    rows.append((float(cells[0]), float(cells[1])))
                except ValueError:
                    raise UserError(f"{path}: line {line}: {','.join(cells)!r} is not two numbers x, y") from None
    except OSError as e:
        raise UserError(f"cannot read track file {path}: {e.strerror or e}") from None
    try:
        return from_waypoints(np.asarray(rows, float).reshape(-1, 2))
    except UserError as e:
        raise UserError(f"{path}: {e}") from None


def from_argument(text: str) -> tuple[str | Track, str]:
    """A ``--track`` argument: one of `TRACKS` (kept as its name) or a waypoints CSV (`load_waypoints`), and its label."""
    if text in TRACKS:
        return text, text
    import pathlib

    return load_waypoints(text), pathlib.Path(text).name


def mirror(track: Track) -> Track:
    """The mirror image about the x axis, ``(x, y) -> (x, -y)``."""
    return track._replace(
        start=track.start * jnp.array([1.0, -1.0]), heading=-track.heading, curvature=-track.curvature
    )


def get(name: str, drawn: bool = False) -> Track:
    """A track by name, one of `TRACKS`: endless, or as drawn (``drawn=True``, with an end)."""
    base, _, mirrored = name.partition("-")
    builders = {"eight": eight, "ladder": ladder, "zigzag": zigzag}
    if base not in builders or mirrored not in ("", "mirror"):
        raise UserError(f"unknown track {name!r}; choose one of {', '.join(TRACKS)}")
    track = builders[base](units=DRAWN_UNITS[base] if drawn else None)
    return mirror(track) if mirrored else track


def drawn_length(name: str) -> float:
    """Arc length of the drawn track ``name``, m."""
    return float(get(name, drawn=True).length)


def training_mirror(episode):
    """Whether episode ``episode`` runs the 8 mirrored: odd episodes are (Fig. 5 caption)."""
    return episode % 2 == 1


def training_track(episode: int, drawn: bool = False) -> Track:
    """The 8 of episode ``episode``: as drawn for even episodes, mirrored for odd ones (Fig. 5 caption)."""
    track = eight(units=1 if drawn else None)
    return mirror(track) if training_mirror(episode) else track


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
