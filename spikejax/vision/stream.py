"""The pipe detector for a closed loop: Alg. 2 and 3 of the snake pipe-tracking paper, one control step at a time.

`spikejax.vision.detect` cuts a whole recording into slots on the host. A
robot in a closed loop has only the events of the control step it just made,
so here the slot is assembled step by step inside the jitted loop:

* `step` (every control step): the grids' Alg. 1 update on the step's events
  (synchronously at the step's end, or event by event), the step's line
  spikes written to the slot's buffer, its votes and events added to the
  slot's tallies, the head joint's angle and velocity pushed into the mean
  filter's ring.
* `slot_end` (every ``slot_steps`` steps): Alg. 2 on the slot
  (`spikejax.vision.detect.find_pipes`: the body's parallel, opposite, most
  frequent pair, upright and drawn by the events; the entry's ring; one kind
  per object), Alg. 3 for each (`spikejax.vision.pipe.track_step`: Eq. (8)
  with a known size or Eq. (9) from the expansion over ``interval``
  detections; Eqs. (4)-(7) for the offsets, with the head signals
  mean-filtered over ``window`` steps), and the control ``C = sign(offset)``
  held between detections.
* `run`: the recommended loop structure, an outer ``lax.scan`` over slots and
  an inner one over their steps, so that the slot's end is the same for every
  stream and `slot_end` runs once per slot, not under a batched ``cond``.
  `update` (`step`, then `slot_end` when `due`) serves a loop that
  steps one control step at a time; under ``vmap`` its ``cond`` becomes a
  select, which pays for `slot_end` at every step.

Everything is pure and written for one stream (``vmap`` adds streams), with
fixed-size state: the grids (`Tracker.detector`), the buffer size (its
``sub_slots``, the most steps a slot may have), Alg. 3's interval, the filter
window and the steering target are static; the neurons' thresholds and decay,
Alg. 2's conditions, Alg. 3's parameters, the slot length in steps (up to the
buffer) and the hold are traced (`TrackerParams`).

Fed the same events, `run` gives the detections of
`spikejax.vision.detect.run` bit for bit (tested): the slot's votes are the
sum of its steps' votes (whole numbers, exact in float32).

The first detections when the size is unknown
---------------------------------------------
With ``track.size = 0`` the distance is Eq. (9), which needs ``interval``
earlier detections; before that Alg. 3 gives ``d = 0``, hence ``pipeOffset =
0`` and ``offset = cameraOffset``: the control follows the camera's own swing
whatever side the pipe is on. `tracker_params` therefore sets
``track.assumed_distance`` (default 3 m, the middle of the loop's 2-4 m
starts): while ``d = 0`` the pipe's offset is computed at that distance, so
the pipe's side in the image counts from the first detection, weighed against
the camera's offset as if the pipe were that far. The reported distance stays
0 (unknown). ``assumed_distance = 0`` restores the paper's behaviour.

Without a detection in a slot the last control is held for ``hold`` slots,
then ``C = 0`` (straight) until the pipe is seen again.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp

from spikejax.errors import UserError
from spikejax.vision import detect, hough
from spikejax.vision import pipe as pp
from spikejax.vision.events import Events

__all__ = [
    "TARGETS",
    "SlotOutput",
    "Tracker",
    "TrackerParams",
    "TrackerState",
    "due",
    "init",
    "run",
    "slot_end",
    "step",
    "tracker_params",
    "update",
    "no_slot",
]

TARGETS = ("any", "body", "entry")


@dataclasses.dataclass(frozen=True)
class Tracker:
    """Static configuration of the streaming detector.

    Attributes:
        detector: the grids (``None`` skips one), ``"sync"`` or ``"async"``,
            and ``sub_slots``: the most control steps a slot may have (the
            size of the slot's spike buffer).
        interval: Alg. 3's Eq. (9) interval, detections (10 in the paper).
        pool: how many of the last detections' distances Alg. 3 pools
            (`spikejax.vision.pipe.TrackParams.smooth`).
        window: the mean filter's window on the head joint's angle and
            velocity, control steps (1: no filter).
        target: which detection steers: ``"body"``, ``"entry"`` or ``"any"``
            (the entry when there is one, else the body).
        circle_per_slot: update the circle grid once per slot, at its end, on
            the slot's events (a synchronous slot of ``slot_steps`` steps),
            instead of once per step: the same Alg. 1 update with a longer
            time slot, one convolution of the slot's signed event image
            instead of one a step (the circle grid's votes cost far more
            than the line grid's). Synchronous mode only.
    """

    detector: detect.Detector = detect.Detector()
    interval: int = 10
    pool: int = 10
    window: int = 1
    target: str = "any"
    circle_per_slot: bool = False

    def __post_init__(self):
        if self.target not in TARGETS:
            raise UserError(f"target must be one of {', '.join(TARGETS)}, not {self.target!r}")
        if self.circle_per_slot and self.detector.mode != "sync":
            raise UserError("circle_per_slot needs the synchronous mode (the asynchronous grid updates per event)")
        if self.circle_per_slot and (self.detector.circle is None or not _image_is_circle_sensor(self.detector)):
            raise UserError("circle_per_slot needs a circle grid on the same sensor as the slot's event images")
        for name in ("interval", "pool", "window"):
            value = getattr(self, name)
            if not (isinstance(value, int) and value >= 1):
                raise UserError(f"Tracker.{name} must be a positive integer, not {value!r}")


class TrackerParams(NamedTuple):
    """Traced parameters (build them with `tracker_params`).

    Attributes:
        detector: the neurons and Alg. 2's conditions.
        track: Alg. 3 (`spikejax.vision.pipe.TrackParams`).
        slot_steps: control steps per slot (int32), 1 to the buffer's size;
            read by `due` (`run` takes the slot length from its input's shape).
        hold: slots the last control is held without a detection (int32).
    """

    detector: detect.DetectorParams
    track: pp.TrackParams
    slot_steps: jax.Array
    hold: jax.Array


def tracker_params(
    tracker: Tracker,
    *,
    detector: detect.DetectorParams | None = None,
    track: pp.TrackParams | None = None,
    slot_steps: int | None = None,
    hold: int = 1,
    assumed_distance: float = 3.0,
) -> TrackerParams:
    """`TrackerParams`: the detector's defaults (threshold half the sensor height) and Alg. 3's.

    Args:
        tracker: the static configuration (for the sensor and buffer sizes).
        detector: default `spikejax.vision.detect.detector_params` with
            ``v_th`` half the sensor height (and `spikejax.vision.detect.NEAR_ENTRY`'s
            ``min_in_view`` for a circle grid with centres above the image).
        track: default `spikejax.vision.pipe.track_params` for the sensor's
            width, with ``assumed_distance``.
        slot_steps: default the buffer's size.
        hold: slots a control is held without a detection.
        assumed_distance: m, see the module's notes (used when ``track`` is
            not given).
    """
    det = tracker.detector
    height, width = det.sensor
    if slot_steps is None:
        slot_steps = det.sub_slots
    if not 1 <= slot_steps <= det.sub_slots:
        raise UserError(f"slot_steps must be within 1..{det.sub_slots} (the detector's sub_slots), not {slot_steps}")
    if hold < 0:
        raise UserError(f"hold must be >= 0 slots, not {hold}")
    if detector is None:
        entry = detect.NEAR_ENTRY if det.circle_top else detect.ENTRY
        detector = detect.detector_params(v_th=0.5 * height, entry=entry)
    track = pp.track_params(width=width, assumed_distance=assumed_distance) if track is None else track
    return TrackerParams(detector, track, jnp.asarray(slot_steps, jnp.int32), jnp.asarray(hold, jnp.int32))


class TrackerState(NamedTuple):
    """Everything the streaming detector carries from step to step (``None`` for a skipped grid).

    Attributes:
        grids: the Hough grids' neurons (`spikejax.vision.detect.DetectorState`).
        line_spikes: the slot's line spikes, one row per step,
            ``(sub_slots, n_theta, n_rho)`` int8 (rows past ``steps`` are 0).
        line_votes: the slot's signed line votes.
        circle_counts: the slot's circle-grid spikes per neuron (both signs).
        circle_votes: the slot's unsigned circle votes (zeros when the event images give them at the
            slot's end, see `slot_end`).
        image: ``(positive, negative)`` events per pixel of the slot.
        steps: control steps in the slot so far (int32).
        angles, velocities: ``(window,)`` rings of the head joint's last
            angles (rad) and velocities (rad/s); ``samples`` written so far.
        body_track, entry_track: Alg. 3's histories for Eq. (9).
        control: the control in force, int32 in ``{-1, 0, +1}``.
        misses: slots since the last detection that steered (int32).
    """

    grids: detect.DetectorState
    line_spikes: jax.Array | None
    line_votes: jax.Array | None
    circle_counts: jax.Array | None
    circle_votes: jax.Array | None
    image: tuple[jax.Array, jax.Array]
    steps: jax.Array
    angles: jax.Array
    velocities: jax.Array
    samples: jax.Array
    body_track: pp.TrackState
    entry_track: pp.TrackState
    control: jax.Array
    misses: jax.Array


class SlotOutput(NamedTuple):
    """What a slot's end gives: Alg. 2's detections, Alg. 3's estimates, the control in force.

    Attributes:
        body, entry: `spikejax.vision.pipe.Pipe` (``valid`` False if none).
        body_estimate, entry_estimate: `spikejax.vision.pipe.Estimate` of each.
        control: ``C`` for the next slot, int32 in ``{-1, 0, +1}`` (held, see `Tracker`).
        head_angle, head_velocity: the filtered head signals Eq. (5) used.
    """

    body: pp.Pipe
    entry: pp.Pipe
    body_estimate: pp.Estimate
    entry_estimate: pp.Estimate
    control: jax.Array
    head_angle: jax.Array
    head_velocity: jax.Array


def _slot_tallies(det: detect.Detector):
    """Empty slot buffers: line spikes, line votes, circle counts, circle votes, event images."""
    z = lambda shape, dtype=jnp.float32: jnp.zeros(shape, dtype)  # noqa: E731
    return (
        None if det.line is None else z((det.sub_slots, *det.line.shape), jnp.int8),
        None if det.line is None else z(det.line.shape),
        None if det.circle is None else z(det.circle.shape),
        None if det.circle is None else z(det.circle.shape),
        (z(det.sensor), z(det.sensor)),
    )


def init(tracker: Tracker, t0=0.0) -> TrackerState:
    """The streaming detector at rest at time ``t0``: grids at 0, an empty slot, no history."""
    det = tracker.detector
    grids = detect.DetectorState(
        None if det.line is None else hough.init(det.line, t0),
        None if det.circle is None else hough.init(det.circle, t0),
    )
    zi = jnp.zeros((), jnp.int32)
    ring = jnp.zeros((tracker.window,), jnp.float32)
    return TrackerState(
        grids, *_slot_tallies(det), zi, ring, ring, zi, pp.track_init(tracker.interval, tracker.pool),
        pp.track_init(tracker.interval, tracker.pool), zi, zi,
    )  # fmt: skip


def _image_is_circle_sensor(det: detect.Detector) -> bool:
    """Whether the slot's event images cover the circle grid's sensor, so its unsigned votes come from them.

    By linearity the slot's unsigned circle votes are those of the slot's
    event count image (binned as the grid, `spikejax.vision.detect.circle_image`):
    one convolution at the slot's end, not one a step.
    """
    return det.circle is not None and det.sensor == det.circle_covers


def _grid_step(det, grid, params, state, events, t):
    if det.mode == "sync":
        return hough.sync_step(params, grid, state, events, t)
    return hough.async_step(params, grid, state, events)


def step(
    tracker: Tracker, params: TrackerParams, state: TrackerState, events: Events, t, head_angle=0.0, head_velocity=0.0
) -> TrackerState:
    """One control step: the grids on the step's events, the slot's tallies, the head signals.

    Args:
        tracker: static configuration.
        params: traced parameters.
        state: from `init`, `step` or `slot_end`.
        events: the step's `spikejax.vision.events.Events` (leaves ``(capacity,)``),
            in time order for the asynchronous mode.
        t: the step's end, s: the synchronous update's time.
        head_angle, head_velocity: the head joint's encoder readings at ``t``
            (rad, rad/s), for Eq. (5).

    Returns:
        The new state. A step past the buffer's ``sub_slots`` without a
        `slot_end` still updates the grids and tallies, but its spikes are
        not kept for Alg. 2's joint-firing count.
    """
    det = tracker.detector
    t = jnp.asarray(t, jnp.float32)
    line, circle = state.grids
    line_spikes, line_votes, circle_counts, circle_votes = (
        state.line_spikes,
        state.line_votes,
        state.circle_counts,
        state.circle_votes,
    )
    if det.line is not None:
        votes = hough.line_votes(det.line, events)
        if det.mode == "sync":
            line, spikes = hough.sync_update(params.detector.line, line, votes, t)
        else:
            line, spikes = hough.async_step(params.detector.line, det.line, line, events)
        line_spikes = line_spikes.at[state.steps].set(spikes, mode="drop")
        line_votes = line_votes + votes
    if det.circle is not None and not tracker.circle_per_slot:
        binned = detect.circle_events(det, events)
        circle, spikes = _grid_step(det, det.circle, params.detector.circle, circle, binned, t)
        circle_counts = circle_counts + (spikes != 0).astype(jnp.float32)
        if not _image_is_circle_sensor(det):
            circle_votes = circle_votes + hough.circle_votes(det.circle, binned, signed=False)
    positive, negative = detect.event_images(det, events)
    ring = state.samples % tracker.window
    return state._replace(
        grids=detect.DetectorState(line, circle),
        line_spikes=line_spikes,
        line_votes=line_votes,
        circle_counts=circle_counts,
        circle_votes=circle_votes,
        image=(state.image[0] + positive, state.image[1] + negative),
        steps=state.steps + 1,
        angles=state.angles.at[ring].set(jnp.asarray(head_angle, jnp.float32)),
        velocities=state.velocities.at[ring].set(jnp.asarray(head_velocity, jnp.float32)),
        samples=state.samples + 1,
    )


def due(params: TrackerParams, state: TrackerState) -> jax.Array:
    """Whether the slot is complete (``slot_steps`` steps since the last `slot_end`)."""
    return state.steps >= params.slot_steps


def slot_end(
    tracker: Tracker,
    params: TrackerParams,
    state: TrackerState,
    t,
    circle_update: bool = True,
    keep_events: bool = True,
) -> tuple[TrackerState, SlotOutput]:
    """The slot's end: Alg. 2 on its tallies, Alg. 3 on the detections, the control; a new slot begins.

    Args:
        tracker: static configuration.
        params: traced parameters.
        state: after the slot's steps.
        t: the slot's time stamp for the detections, s (its last step's end).
        circle_update: static; ``False`` skips the circle grid at this slot's
            end (a tracker with ``circle_per_slot`` and no line grid): no
            update, no entry (Alg. 3 sees no detection), and the slot's event
            image carries over, so the next update takes both slots' events.
        keep_events: static; with ``circle_update=False``, ``False`` drops the
            slot's event image (and any carried into it) instead: the next
            update sees only the slots after this one.

    Returns:
        ``(state, output)``: the state with empty slot tallies (the grids and
        Alg. 3's histories carried on), and the `SlotOutput`.
    """
    det = tracker.detector
    skip = not circle_update
    if skip and not (tracker.circle_per_slot and det.line is None):
        raise UserError("skipping the circle grid at a slot's end needs circle_per_slot and no line grid")
    circle, circle_counts, circle_votes = state.grids.circle, state.circle_counts, state.circle_votes
    if det.circle is not None and _image_is_circle_sensor(det) and not skip:
        circle_votes = hough.circle_image_votes(det.circle, detect.circle_image(det, state.image[0] + state.image[1]))
    if tracker.circle_per_slot and not skip:
        signed = hough.circle_image_votes(det.circle, detect.circle_image(det, state.image[0] - state.image[1]))
        circle, spikes = hough.sync_update(params.detector.circle, circle, signed, t)
        circle_counts = (spikes != 0).astype(jnp.float32)
    evidence = detect.Evidence(state.line_spikes, state.line_votes, circle_counts, circle_votes, state.image)
    if skip:
        stamp = jnp.asarray(t, jnp.float32)
        body, entry = (pp.Pipe(stamp, *detect._empty_pipe(kind)[1:]) for kind in (pp.BODY, pp.ENTRY))
    else:
        body, entry = detect.find_pipes(det, params.detector, evidence, t)
    angle = pp.mean_filter(state.angles, state.samples)
    velocity = pp.mean_filter(state.velocities, state.samples)
    body_track, body_est = pp.track_step(params.track, state.body_track, body, angle, velocity)
    entry_track, entry_est = pp.track_step(params.track, state.entry_track, entry, angle, velocity)
    if tracker.target == "body":
        seen, control = body.valid, body_est.control
    elif tracker.target == "entry":
        seen, control = entry.valid, entry_est.control
    else:
        seen = entry.valid | body.valid
        control = jnp.where(entry.valid, entry_est.control, body_est.control)
    misses = jnp.where(seen, 0, state.misses + 1)
    control = jnp.where(seen, control, jnp.where(misses <= params.hold, state.control, 0)).astype(jnp.int32)
    line_spikes, line_votes, circle_counts, circle_votes, image = _slot_tallies(det)
    image = state.image if (skip and keep_events) else image
    new = state._replace(
        grids=detect.DetectorState(state.grids.line, circle),
        line_spikes=line_spikes,
        line_votes=line_votes,
        circle_counts=circle_counts,
        circle_votes=circle_votes,
        image=image,
        steps=jnp.zeros((), jnp.int32),
        body_track=body_track,
        entry_track=entry_track,
        control=control,
        misses=misses,
    )
    return new, SlotOutput(body, entry, body_est, entry_est, control, angle, velocity)


def no_slot(tracker: Tracker, state: TrackerState, t) -> SlotOutput:
    """The `SlotOutput` of a step that ends no slot: no detections, the control in force."""
    z = jnp.zeros((), jnp.float32)
    no = jnp.zeros((), bool)
    empty = lambda kind: pp.Pipe(jnp.asarray(t, jnp.float32), z, z, z, z, jnp.asarray(kind, jnp.int32), z, no, z)  # noqa: E731
    est = pp.Estimate(z, z, z, z, jnp.zeros((), jnp.int32), jnp.zeros((), bool))
    return SlotOutput(empty(pp.BODY), empty(pp.ENTRY), est, est, state.control, z, z)


def update(
    tracker: Tracker, params: TrackerParams, state: TrackerState, events: Events, t, head_angle=0.0, head_velocity=0.0
) -> tuple[TrackerState, SlotOutput, jax.Array]:
    """`step`, then `slot_end` if the slot is `due`: one call per control step.

    Returns:
        ``(state, output, ended)``: ``output`` is the slot's when ``ended``,
        else no detections and the control in force.
    """
    state = step(tracker, params, state, events, t, head_angle, head_velocity)
    ended = due(params, state)
    state, out = jax.lax.cond(
        ended,
        lambda s: slot_end(tracker, params, s, t),
        lambda s: (s, no_slot(tracker, s, t)),
        state,
    )
    return state, out, ended


def run(
    tracker: Tracker,
    params: TrackerParams,
    events: Events,
    times,
    head_angle=None,
    head_velocity=None,
    state: TrackerState | None = None,
) -> tuple[TrackerState, SlotOutput]:
    """The streaming detector over slots of ``K`` steps: a ``lax.scan`` of slots, each a ``lax.scan`` of steps.

    Args:
        tracker: static configuration (``K <= tracker.detector.sub_slots``).
        params: traced parameters (``slot_steps`` is not read: a slot is ``K`` steps).
        events: `spikejax.vision.events.Events` with leaves ``(n_slots, K, capacity)``.
        times: ``(n_slots, K)`` each step's end, s; a slot's detections are
            stamped with its last step's.
        head_angle, head_velocity: ``(n_slots, K)`` encoder readings (default 0).
        state: default `init` at time 0.

    Returns:
        ``(state, outputs)``: `SlotOutput` with leaves ``(n_slots, ...)``.
    """
    times = jnp.asarray(times, jnp.float32)
    if times.shape[1] > tracker.detector.sub_slots:
        raise UserError(f"slots of {times.shape[1]} steps do not fit the buffer of {tracker.detector.sub_slots}")
    zeros = jnp.zeros(times.shape, jnp.float32)
    head_angle = zeros if head_angle is None else jnp.asarray(head_angle, jnp.float32)
    head_velocity = zeros if head_velocity is None else jnp.asarray(head_velocity, jnp.float32)
    state = init(tracker) if state is None else state

    def one_step(s, x):
        ev, t, a, v = x
        return step(tracker, params, s, ev, t, a, v), None

    def one_slot(s, x):
        s, _ = jax.lax.scan(one_step, s, x)
        return slot_end(tracker, params, s, x[1][-1])

    return jax.lax.scan(one_slot, state, (events, times, head_angle, head_velocity))
