"""Pipe detection on event recordings: the pipeline behind ``spikejax detect pipe FILE``.

The recording is cut into time slots (Alg. 2 of the snake pipe-tracking
paper: "for each time slot"), each slot into ``sub_slots`` equal parts. The
line and circle grids of `spikejax.vision.hough` run over the parts,
synchronously (one update per part, the paper's GPU mode) or asynchronously
(event by event, Alg. 1 exactly), their states carried from part to part and
slot to slot. A grid reports at most one spike per neuron per part, so a
neuron's firing frequency in a slot (the third condition of Section 2.3) is
the number of parts in which it fired, and a pair's the number of parts in
which both fired; ties, frequent when every neuron over threshold fires at
once, are broken by the slot's vote accumulator. `spikejax.vision.pipe.find_body`
and `spikejax.vision.pipe.find_entry` turn the counts into pipes, and
Alg. 3 (`spikejax.vision.pipe.track`) into distances and offsets.

Everything per slot is one jitted ``lax.scan``; slots are processed in chunks
of fixed size (the last one padded with empty slots), so a recording of any
length compiles once and the result does not depend on the chunk size.

The command itself (argument checks, the printed table, the CSV file and the
overlay figure) is `spikejax.commands.detect_pipe`.
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from spikejax.errors import UserError
from spikejax.ranges import POSITIVE, Range, check, ranged
from spikejax.vision import hough, io
from spikejax.vision import pipe as pp
from spikejax.vision.events import Events

__all__ = [
    "BODY",
    "ENTRY",
    "NEAR_ENTRY",
    "Detections",
    "Detector",
    "DetectorParams",
    "DetectorState",
    "Evidence",
    "binned_image",
    "circle_events",
    "circle_image",
    "detect",
    "detector_params",
    "event_images",
    "find_pipes",
    "run",
    "slot_step",
]

MODES = ("sync", "async")


@dataclasses.dataclass(frozen=True)
class Detector:
    """Static configuration: the grids (``None`` skips one), the mode and the slot split.

    Attributes:
        line: the line grid (pipe bodies), or ``None``.
        circle: the circle grid (pipe entries), or ``None``.
        mode: ``"sync"`` or ``"async"``.
        sub_slots: parts per slot; a neuron fires at most once per part.
        k: candidate spikes per polarity for `spikejax.vision.pipe.find_body`.
        circle_bin: sensor pixels a side per circle-grid pixel. With 2, the
            circle grid sees the events summed over 2 x 2 bins (its centres
            and radii in those pixels: a 64 x 64 grid on a 128 x 128 sensor)
            and its entries are reported in sensor pixels; its convolutions
            and its update cost about a quarter. The sensor (`sensor`) is the
            line grid's, else the circle grid's times ``circle_bin``.
        circle_top: circle-grid rows above the sensor (in the grid's pixels):
            its first ``circle_top`` rows of centres lie above the image, for
            rings whose lower arc alone is in view (a lying pipe's entry seen
            from close by and from below its axis). The grid's ``height`` counts
            them; entries are reported in sensor rows (negative above the image).
    """

    line: hough.LineGrid | None = hough.LineGrid()
    circle: hough.CircleGrid | None = hough.CircleGrid()
    mode: str = "sync"
    sub_slots: int = 5
    k: int = 32
    circle_bin: int = 1
    circle_top: int = 0

    def __post_init__(self):
        if self.mode not in MODES:
            raise UserError(f"mode must be one of {', '.join(MODES)}, not {self.mode!r}")
        if self.line is None and self.circle is None:
            raise UserError("the detector needs a line grid, a circle grid or both")
        if not (isinstance(self.sub_slots, int) and self.sub_slots >= 1):
            raise UserError(f"sub_slots must be a positive integer, not {self.sub_slots!r}")
        if not (isinstance(self.circle_bin, int) and self.circle_bin >= 1):
            raise UserError(f"circle_bin must be a positive integer, not {self.circle_bin!r}")
        if not (isinstance(self.circle_top, int) and self.circle_top >= 0):
            raise UserError(f"circle_top must be a non-negative integer, not {self.circle_top!r}")
        if self.circle is not None and self.circle_top >= self.circle.height:
            raise UserError(
                f"circle_top ({self.circle_top}) leaves none of the circle grid's {self.circle.height} rows on the sensor"
            )
        if self.circle_bin > 1 and self.circle is not None and self.line is not None:
            covers = self.circle_covers
            if covers != (self.line.height, self.line.width):
                raise UserError(
                    f"a circle grid of {self.circle.height} x {self.circle.width} in bins of {self.circle_bin} "
                    f"covers {covers[0]} x {covers[1]} pixels, not the line grid's {self.line.height} x {self.line.width}"
                )

    @property
    def circle_covers(self) -> tuple[int, int] | None:
        """``(height, width)`` in sensor pixels that the circle grid covers (``None`` without one)."""
        if self.circle is None:
            return None
        return (self.circle.height - self.circle_top) * self.circle_bin, self.circle.width * self.circle_bin

    @property
    def sensor(self) -> tuple[int, int]:
        """``(height, width)`` of the sensor, pixels: the line grid's, else what the circle grid covers."""
        if self.line is not None:
            return self.line.height, self.line.width
        return self.circle_covers


class DetectorParams(NamedTuple):
    """Traced parameters: the two grids' neurons, Alg. 2's conditions for bodies and entries."""

    line: hough.HoughParams
    circle: hough.HoughParams
    body: pp.BodyParams
    entry: pp.EntryParams


# The detector's judgment beyond Section 2.3's three conditions (measured in
# docs/BENCHMARKS.md, "Pipe detection: false positives"): a body's edges within
# 30 degrees of the vertical and drawn along a quarter of their length by the
# slot's events; an entry's ring half in view and half drawn.
BODY = pp.BodyParams(max_tilt=math.radians(30.0), min_support=0.25)
ENTRY = pp.EntryParams(min_count=1.0, min_coverage=0.5, min_in_view=0.5)
# With centres above the image (`Detector.circle_top`) the grid looks for rings whose lower arc alone is
# in view: on the snake's 2 x 2 bins a lying entry's ring 0.36 m away (radius 40 bins, its centre on the
# image's top row, the image's columns cutting its sides) has 0.30 of it in view.
NEAR_ENTRY = ENTRY._replace(min_in_view=0.3)


def detector_params(
    *,
    v_th: float = 8.0,
    decay: float = 50.0,
    circle_v_th: float | None = None,
    circle_decay: float | None = None,
    body: pp.BodyParams | None = None,
    entry: pp.EntryParams | None = None,
    entry_min_count: float | None = None,
) -> DetectorParams:
    """`DetectorParams` as float32 arrays.

    The circle grid defaults to the line grid's neurons; ``body`` and
    ``entry`` to `BODY` and `ENTRY`; ``entry_min_count`` replaces the
    entry's ``min_count``.
    """
    body = BODY if body is None else body
    entry = ENTRY if entry is None else entry
    if entry_min_count is not None:
        entry = entry._replace(min_count=entry_min_count)
    return DetectorParams(
        line=hough.hough_params(v_th, decay),
        circle=hough.hough_params(
            v_th if circle_v_th is None else circle_v_th, decay if circle_decay is None else circle_decay
        ),
        body=pp.BodyParams(*(jnp.asarray(v, jnp.float32) for v in body)),
        entry=pp.EntryParams(*(jnp.asarray(v, jnp.float32) for v in entry)),
    )


class DetectorState(NamedTuple):
    """The grids' states (``None`` for a grid the `Detector` skips)."""

    line: hough.HoughState | None
    circle: hough.HoughState | None


def _init(det: Detector, t0=0.0) -> DetectorState:
    return DetectorState(
        None if det.line is None else hough.init(det.line, t0),
        None if det.circle is None else hough.init(det.circle, t0),
    )


def _grid_spikes(det, grid, params, state, events, times):
    if det.mode == "sync":
        return hough.sync_run(params, grid, events, times, state)
    return hough.async_run(params, grid, events, state)


def _empty_pipe(kind):
    z = jnp.zeros((), jnp.float32)
    return pp.Pipe(z, z, z, z, z, jnp.asarray(kind, jnp.int32), z, jnp.zeros((), bool), z)


def _flat(events: Events) -> Events:
    return jax.tree.map(lambda v: v.reshape(-1), events)


def circle_events(det: Detector, events: Events) -> Events:
    """The events in the circle grid's pixels: each at its ``circle_bin`` x ``circle_bin`` bin, ``circle_top`` rows down."""
    b, top = det.circle_bin, det.circle_top
    if b == 1 and top == 0:
        return events
    return events._replace(x=events.x // b, y=events.y // b + top)


def binned_image(det: Detector, image: jax.Array) -> jax.Array:
    """A sensor image ``(height, width)`` summed over the circle grid's bins (the sensor's part of the grid)."""
    b = det.circle_bin
    if b == 1:
        return image
    h, w = image.shape
    return image.reshape(h // b, b, w // b, b).sum(axis=(1, 3))


def circle_image(det: Detector, image: jax.Array) -> jax.Array:
    """A sensor image ``(height, width)`` in the circle grid's pixels: binned, ``circle_top`` empty rows above."""
    binned = binned_image(det, image)
    return jnp.pad(binned, ((det.circle_top, 0), (0, 0))) if det.circle_top else binned


def _entry_in_sensor_pixels(det: Detector, entry: pp.Pipe) -> pp.Pipe:
    """An entry found on the binned circle grid, its centre and width in sensor pixels (a bin's centre)."""
    b = det.circle_bin
    if b == 1:
        return entry
    return entry._replace(pos=b * entry.pos + 0.5 * (b - 1), row=b * entry.row + 0.5 * (b - 1), width=b * entry.width)


class Evidence(NamedTuple):
    """What one slot leaves for Alg. 2 (``None`` for a grid the `Detector` skips).

    Attributes:
        line_spikes: the line grid's output spikes of every update of the
            slot, ``(n_updates, n_theta, n_rho)`` int8.
        line_votes: the slot's signed line votes, ``(n_theta, n_rho)`` (ties).
        circle_counts: circle-grid spikes per neuron over the slot (both
            signs), ``(n_r, height, width)``.
        circle_votes: the slot's unsigned circle votes (ties).
        image: ``(positive, negative)`` events per pixel of the slot, each
            ``(height, width)``: the support tests of `spikejax.vision.pipe`.
    """

    line_spikes: jax.Array | None
    line_votes: jax.Array | None
    circle_counts: jax.Array | None
    circle_votes: jax.Array | None
    image: tuple[jax.Array, jax.Array]


def event_images(det: Detector, events: Events) -> tuple[jax.Array, jax.Array]:
    """``(positive, negative)`` events per sensor pixel, each ``det.sensor`` float32 (events of any shape)."""
    height, width = det.sensor
    grid = det.line if det.line is not None else dataclasses.replace(det.circle, height=height, width=width)
    events = _flat(events)
    signed = hough.event_image(grid, events, signed=True)
    count = hough.event_image(grid, events, signed=False)
    return 0.5 * (count + signed), 0.5 * (count - signed)


def find_pipes(det: Detector, params: DetectorParams, evidence: Evidence, t) -> tuple[pp.Pipe, pp.Pipe]:
    """Alg. 2 at the end of a slot: the body and the entry, judged by the slot's events and classified.

    `spikejax.vision.pipe.find_body` on the line spikes (the parallel,
    opposite, most frequent pair, upright and drawn by the events),
    `spikejax.vision.pipe.find_entry` on the circle counts (the most active
    neuron whose ring the events draw), then
    `spikejax.vision.pipe.classify` (one kind per object). ``evidence.image``
    is in sensor pixels; the entry is judged on it binned as the circle grid
    (`circle_image`) and reported in sensor pixels.

    Returns:
        ``(body, entry)``, `spikejax.vision.pipe.Pipe` scalars (``valid``
        False for a grid the `Detector` skips).
    """
    body, entry = _empty_pipe(pp.BODY), _empty_pipe(pp.ENTRY)
    if det.line is not None:
        votes = evidence.line_votes
        body = pp.find_body(
            params.body,
            evidence.line_spikes,
            jnp.asarray(det.line.thetas(), jnp.float32),
            jnp.asarray(det.line.rhos(), jnp.float32),
            t,
            strength=(jnp.maximum(votes, 0.0), jnp.maximum(-votes, 0.0)),
            image=evidence.image,
            origin=det.line.origin,
            row=0.5 * det.line.height,
            k=det.k,
        )
    if det.circle is not None:
        entry = pp.find_entry(
            evidence.circle_counts,
            jnp.asarray(det.circle.radii(), jnp.float32),
            t,
            params.entry,
            strength=evidence.circle_votes,
            image=binned_image(det, evidence.image[0] + evidence.image[1]),
            top=det.circle_top,
        )
        entry = _entry_in_sensor_pixels(det, entry)
    if det.line is not None and det.circle is not None:
        body, entry = pp.classify(body, entry)
    return body, entry


def slot_step(det: Detector, params: DetectorParams, state: DetectorState, events: Events, times, t):
    """One slot: the grids over its ``sub_slots`` parts, then Alg. 2 (`find_pipes`).

    Args:
        det: static configuration.
        params: traced parameters.
        state: the grids' states.
        events: `spikejax.vision.events.Events` with leaves ``(sub_slots, capacity)``.
        times: ``(sub_slots,)`` end of each part, s (the synchronous update times).
        t: the slot's time stamp for the detections, s.

    Returns:
        ``(state, (body, entry, line_counts, circle_counts))``; the counts are
        the ``(positive, negative)`` spike counts per neuron, or ``None``.

    Notes:
        The tie-breaking votes are voted again over the whole slot: the
        grids' `spikejax.vision.hough.sync_step` computes each part's votes
        but does not return them. By linearity they are the sum of the parts'
        votes (whole numbers, exact in float32), which is how
        `spikejax.vision.stream` gathers them step by step.
    """
    line_state, circle_state = state
    line_spikes = line_votes = line_counts = circle_counts = circle_votes = None
    if det.line is not None:
        line_state, line_spikes = _grid_spikes(det, det.line, params.line, line_state, events, times)
        line_counts = pp.spike_counts(line_spikes, 2)
        line_votes = hough.line_votes(det.line, _flat(events))
    if det.circle is not None:
        binned = circle_events(det, events)
        circle_state, spikes = _grid_spikes(det, det.circle, params.circle, circle_state, binned, times)
        circle_counts = pp.spike_counts(spikes, 3)
        circle_votes = hough.circle_votes(det.circle, _flat(binned), signed=False)
    total = None if circle_counts is None else circle_counts[0] + circle_counts[1]
    evidence = Evidence(line_spikes, line_votes, total, circle_votes, event_images(det, events))
    body, entry = find_pipes(det, params, evidence, t)
    return DetectorState(line_state, circle_state), (body, entry, line_counts, circle_counts)


def run(
    det: Detector,
    params: DetectorParams,
    events: Events,
    times,
    state: DetectorState | None = None,
    *,
    keep_counts: bool = False,
):
    """`slot_step` over slots, as a ``lax.scan`` (one stream; ``vmap`` adds streams).

    Args:
        det: static configuration.
        params: traced parameters.
        events: `spikejax.vision.events.Events` with leaves ``(n_slots, sub_slots, capacity)``.
        times: ``(n_slots, sub_slots)`` end of each part, s; a slot's detections
            are stamped with the end of its last part.
        state: the grids' states (default: at rest at time 0).
        keep_counts: also return the spike counts of every slot (memory:
            ``n_slots`` grids of each kind).

    Returns:
        ``(state, bodies, entries)`` with `spikejax.vision.pipe.Pipe`
        fields of shape ``(n_slots,)``, plus ``(line_counts, circle_counts)``
        when ``keep_counts``.
    """
    times = jnp.asarray(times, jnp.float32)
    state = _init(det) if state is None else state

    def body(state, slot):
        ev, ts = slot
        state, (b, e, lc, cc) = slot_step(det, params, state, ev, ts, ts[-1])
        return state, (b, e, lc, cc) if keep_counts else (b, e)

    state, out = jax.lax.scan(body, state, (events, times))
    return (state, *out)


_run_jit = jax.jit(run, static_argnums=0)


class Detections(NamedTuple):
    """What `detect` found in a recording (host arrays, one row per slot).

    Attributes:
        bodies, entries: `spikejax.vision.pipe.Pipe` of numpy arrays ``(n_slots,)``.
        body_estimates, entry_estimates: Alg. 3 for each kind, `spikejax.vision.pipe.Estimate`.
        overflow: ``(n_slots,)`` events that did not fit the parts' capacity.
        t0: absolute time (us) of ``t = 0``.
    """

    bodies: pp.Pipe
    entries: pp.Pipe
    body_estimates: pp.Estimate
    entry_estimates: pp.Estimate
    overflow: np.ndarray
    t0: int

    def table(self) -> list[dict]:
        """The valid detections in time order: t, kind, theta (deg), width, pos, distance, offset, control."""
        rows = []
        for pipes, est, kind in (
            (self.bodies, self.body_estimates, "body"),
            (self.entries, self.entry_estimates, "entry"),
        ):
            for i in np.flatnonzero(pipes.valid):
                rows.append(
                    dict(
                        t=float(pipes.t[i]),
                        kind=kind,
                        theta_deg=math.degrees(float(pipes.theta[i])),
                        width_px=float(pipes.width[i]),
                        pos_px=float(pipes.pos[i]),
                        row_px=float(pipes.row[i]),
                        distance_m=float(est.distance[i]),
                        offset_m=float(est.offset[i]),
                        control=int(est.control[i]),
                        score=float(pipes.score[i]),
                        support=float(pipes.support[i]),
                    )
                )
        return sorted(rows, key=lambda r: (r["t"], r["kind"]))


# Host bytes a slot's results take (two `Pipe`s, two `Estimate`s, the overflow), for the memory check.
_SLOT_RESULT_BYTES = 2 * 9 * 4 + 2 * 6 * 4 + 8


@ranged(slot=POSITIVE, sub_slots=Range(1, integer=True), capacity=Range(1, integer=True), chunk=Range(1, integer=True))
def detect(
    events: np.ndarray,
    sensor_size: tuple[int, int] = (128, 128),
    *,
    mode: str = "sync",
    slot: float = 0.02,
    sub_slots: int = 5,
    capacity: int = 4096,
    lines: bool = True,
    circles: bool = True,
    params: DetectorParams | None = None,
    track: pp.TrackParams | None = None,
    chunk: int = 64,
    progress: bool = False,
) -> Detections:
    """Detect pipes in a recording: Alg. 2 slot by slot, then Alg. 3.

    The recording is cut into slots a chunk at a time, so the memory does not
    grow with its length; a chunk without events, reached while every neuron is
    at rest, is not computed (its slots detect nothing, and the grids stay at
    rest). Fields of a slot without a detection (``valid`` False) carry no meaning.

    Args:
        events: canonical structured array (`spikejax.vision.io.read`).
        sensor_size: ``(width, height)``; the grids are the paper's for this size.
        mode: ``"sync"`` or ``"async"`` (see `spikejax.vision.hough`).
        slot: slot length, s (> 0).
        sub_slots: parts per slot.
        capacity: events per part; the rest are counted in ``overflow``.
        lines, circles: which grids to run.
        params: neuron and detection parameters (default `detector_params`
            with ``v_th`` half the sensor height: an edge fires a neuron once
            it has covered about half the image within a part).
        track: Alg. 3 parameters (default: 60 degree field of view, unknown size, no speed).
        chunk: slots per compiled call.
        progress: show a progress bar.

    Returns:
        `Detections`.

    Raises:
        UserError: a parameter out of its range, or a recording (its span in
            slots) or sensor (its grids) that would not fit in memory, with the size.
    """
    check(detect, {"slot": slot, "sub_slots": sub_slots, "capacity": capacity, "chunk": chunk})
    width, height = sensor_size
    det = Detector(
        line=hough.LineGrid(width, height) if lines else None,
        circle=hough.CircleGrid(width, height, n_r=min(64, max(1, min(width, height) // 2))) if circles else None,
        mode=mode,
        sub_slots=sub_slots,
    )
    cells = sum(g.size for g in (det.line, det.circle) if g is not None)
    # Per cell: potential and time (float32), a slot's spikes (int8 per part), its counts and votes;
    # the line grid's table of the cell of every pixel at every angle, built in float64 (`hough.line_table`).
    table = 0 if det.line is None else width * height * det.line.n_theta
    io.check_fits(cells * (24 + sub_slots) + table * 32, f"the Hough grids of a {width}x{height} sensor")
    params = detector_params(v_th=0.5 * height) if params is None else params
    track = pp.track_params(width=width) if track is None else track
    part = slot / det.sub_slots
    t0 = int(events["t"][0]) if len(events) else 0
    index = io.slot_index(events, part, t0)
    n_parts = int(index[-1]) + 1 if len(events) else 0
    n_slots = max(1, -(-n_parts // det.sub_slots))
    io.check_fits(
        n_slots * _SLOT_RESULT_BYTES,
        f"the results of {n_slots} slots of {slot * 1e3:g} ms ({(n_slots * slot):.0f} s of recording)",
    )
    chunk = max(1, min(chunk, n_slots))
    state = _init(det)
    bodies, entries, overflow = [], [], []
    bar = _progress(n_slots, progress)
    start = 0
    while start < n_slots:
        stop = min(start + chunk, n_slots)
        first, parts = start * det.sub_slots, chunk * det.sub_slots
        lo, hi = np.searchsorted(index, [first, first + parts])
        if lo == hi and _can_skip(det, state):
            # Up to the chunk of the next event, nothing is computed (see `_can_skip`).
            later = n_slots if lo == len(index) else int(index[lo]) // det.sub_slots // chunk * chunk
            stop = min(max(later, stop), n_slots)
            slot_ends = (np.arange(start, stop) * det.sub_slots + det.sub_slots) * part
            state = _rested(det, state, slot_ends[-1])
            bodies.append(_nothing(pp.BODY, slot_ends))
            entries.append(_nothing(pp.ENTRY, slot_ends))
            overflow.append(np.zeros(stop - start, np.int64))
            bar.update(stop - start)
            start = stop
            continue
        ends = (np.arange(first, first + parts) + 1) * part
        ev, over = io.slot_grid(events[lo:hi], index[lo:hi], capacity, parts, t0=t0, first=first)
        ev = jax.tree.map(lambda v: v.reshape(chunk, det.sub_slots, -1), ev)
        ts = ends.reshape(chunk, det.sub_slots)
        if stop - start < chunk:
            ts = _pad(ts[: stop - start], chunk, edge=True)
        # Padded slots are empty and come last: the state after them is never used.
        state, b, e = _run_jit(det, params, ev, ts, state)
        bodies.append(jax.tree.map(lambda v: np.asarray(v)[: stop - start], b))
        entries.append(jax.tree.map(lambda v: np.asarray(v)[: stop - start], e))
        overflow.append(over.reshape(chunk, det.sub_slots).sum(axis=1)[: stop - start])
        bar.update(stop - start)
        start = stop
    bar.close()
    cat = lambda parts_: jax.tree.map(lambda *v: np.concatenate(v), *parts_)
    bodies, entries = cat(bodies), cat(entries)
    est_body = jax.tree.map(np.asarray, pp.track(track, jax.tree.map(jnp.asarray, bodies)))
    est_entry = jax.tree.map(np.asarray, pp.track(track, jax.tree.map(jnp.asarray, entries)))
    return Detections(bodies, entries, est_body, est_entry, np.concatenate(overflow), t0)


def _can_skip(det: Detector, state: DetectorState) -> bool:
    """Whether slots without events can be left uncomputed: they detect nothing, and the state after them is known.

    Asynchronously an empty slot updates no neuron; synchronously every neuron
    decays, which changes nothing once every potential is 0.
    """
    return det.mode == "async" or all(bool(jnp.all(s.v == 0)) for s in state if s is not None)


def _rested(det: Detector, state: DetectorState, end: float) -> DetectorState:
    """The state after empty slots from rest: async leaves it as it is, sync stamps every neuron with the end."""
    if det.mode == "async":
        return state
    t = jnp.float32(end)
    return DetectorState(*(None if s is None else hough.HoughState(s.v, jnp.full_like(s.t, t)) for s in state))


def _nothing(kind: int, slot_ends: np.ndarray) -> pp.Pipe:
    """What slots without a detection hold: their time stamps (the end of each), the kind, ``valid`` False."""
    n = len(slot_ends)
    zeros = np.zeros(n, np.float32)
    return pp.Pipe(
        slot_ends.astype(np.float32),
        zeros,
        zeros,
        zeros,
        zeros,
        np.full(n, kind, np.int32),
        zeros,
        np.zeros(n, bool),
        zeros,
    )


def _pad(v: np.ndarray, n: int, edge: bool = False) -> np.ndarray:
    if v.shape[0] == n:
        return v
    widths = [(0, n - v.shape[0])] + [(0, 0)] * (v.ndim - 1)
    return np.pad(v, widths, mode="edge" if edge else "constant")


def _progress(total: int, enabled: bool):
    from tqdm import tqdm

    return tqdm(total=total, unit="slot", desc="detect pipe", disable=not enabled)
