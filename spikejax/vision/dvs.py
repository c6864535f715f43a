"""DVS emulators: events from a sequence of intensity frames.

Two models, both written for one camera (``jax.vmap`` adds cameras) and
returning fixed-capacity `spikejax.vision.events.Events` with the count
of events that did not fit (DESIGN rule 4):

* `frame_difference`: the simple model of the DVS camera plugins of the
  robot simulators the snake papers used (NRP, V-REP): the simulator renders
  frames, and a pixel whose intensity changed by at least ``threshold`` since
  the previous frame emits one event, polarity the sign of the change, all
  events of a frame stamped with the frame's time. The difference is taken on
  intensities in ``[0, 1]`` by default, as those plugins compare rendered grey
  levels; ``log=True`` takes it on ``log(I + eps)`` instead, which makes the
  threshold a contrast, as in a real DVS pixel. The paper does not say which.
* `init` / `step` / `emulate`: a contrast-threshold emulator in
  the manner of ESIM and v2e. Each pixel keeps a reference log intensity; while
  the log intensity moves (linearly in time between two frames) away from the
  reference by a positive threshold ``C+`` (or a negative one ``C-``), the pixel
  emits an event at the time of the crossing and moves its reference by that
  threshold. Thresholds differ from pixel to pixel (mismatch, drawn once from a
  key), a refractory period drops crossings too soon after the pixel's last
  event, and noise events (shot noise of a given rate per pixel) come from an
  explicit key. `step_counts` is `step` counted per pixel, for consumers of
  count images: the same events without the list (no compaction, sort or
  scatter; about 6x faster under ``vmap`` on a CPU, docs/BENCHMARKS.md).

Frames are ``(height, width)`` float arrays in ``[0, 1]``, row 0 at the top.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from spikejax.random import threefry_uniform
from spikejax.vision.events import Events, compact

__all__ = [
    "frame_difference",
    "difference_events",
    "DVSParams",
    "DVSState",
    "dvs_params",
    "init",
    "crossings",
    "step",
    "step_counts",
    "emulate",
]


def _pixels(shape):
    height, width = shape
    y, x = jnp.divmod(jnp.arange(height * width, dtype=jnp.int32), width)
    return x, y


def frame_difference(
    prev_frame: jax.Array,
    frame: jax.Array,
    t,
    *,
    threshold: float,
    capacity: int,
    log: bool = False,
    eps: float = 1e-3,
) -> tuple[Events, jax.Array]:
    """Events between two frames, all stamped ``t`` (the snake papers' simulator mode).

    A pixel emits one event if ``|d| >= threshold``, with polarity ``sign(d)``,
    where ``d = frame - prev_frame`` (or ``log(frame + eps) - log(prev_frame + eps)``
    with ``log=True``). Events come in row-major pixel order.

    Args:
        prev_frame, frame: ``(height, width)`` intensities in ``[0, 1]``.
        t: time stamp of the events, seconds.
        threshold: smallest change that makes an event (> 0; may be traced).
        capacity: event slots (static).
        log: take the difference of log intensities.
        eps: offset inside the logarithm.

    Returns:
        ``(events, overflow)``; ``overflow`` counts the events that did not fit.
    """
    prev_frame = jnp.asarray(prev_frame, jnp.float32)
    frame = jnp.asarray(frame, jnp.float32)
    if log:
        d = jnp.log(frame + eps) - jnp.log(prev_frame + eps)
    else:
        d = frame - prev_frame
    d = d.reshape(-1)
    x, y = _pixels(frame.shape)
    mask = jnp.abs(d) >= threshold
    p = jnp.where(d > 0, 1, -1).astype(jnp.int32)
    return compact(x, y, jnp.asarray(t, jnp.float32), p, mask, capacity)


@functools.partial(jax.jit, static_argnames=("capacity", "log"))
def difference_events(
    frames: jax.Array, times: jax.Array, *, threshold: float, capacity: int, log: bool = False, eps: float = 1e-3
) -> tuple[Events, jax.Array]:
    """`frame_difference` of each frame with the one before it.

    Args:
        frames: ``(n, height, width)`` intensities in ``[0, 1]``.
        times: ``(n,)`` frame times, seconds.

    Returns:
        ``(events, overflow)``: events with leaves ``(n - 1, capacity)`` (row ``k``
        holds the events of frame ``k + 1``, stamped ``times[k + 1]``), overflow
        ``(n - 1,)``.
    """
    fd = functools.partial(frame_difference, threshold=threshold, capacity=capacity, log=log, eps=eps)
    return jax.vmap(fd)(frames[:-1], frames[1:], jnp.asarray(times)[1:])


class DVSParams(NamedTuple):
    """Parameters of the contrast-threshold emulator.

    Attributes:
        pos_threshold: mean contrast threshold ``C+`` for ON events (log units).
        neg_threshold: mean contrast threshold ``C-`` for OFF events (log units, > 0).
        threshold_sigma: relative per-pixel spread of the thresholds: each pixel
            gets ``C * (1 + sigma * N(0, 1))``, clipped at ``0.01``.
        refractory: refractory period, seconds (0: none).
        noise_rate: rate of noise events per pixel, Hz (0: none); half ON, half OFF.
        eps: offset inside the logarithm, ``log(I + eps)``.
    """

    pos_threshold: jax.Array
    neg_threshold: jax.Array
    threshold_sigma: jax.Array
    refractory: jax.Array
    noise_rate: jax.Array
    eps: jax.Array


def dvs_params(
    pos_threshold=0.2, neg_threshold=0.2, threshold_sigma=0.0, refractory=0.0, noise_rate=0.0, eps=1e-3
) -> DVSParams:
    """`DVSParams` as float32 arrays (defaults: v2e's nominal 0.2 thresholds, no noise)."""
    f = lambda v: jnp.asarray(v, jnp.float32)
    return DVSParams(f(pos_threshold), f(neg_threshold), f(threshold_sigma), f(refractory), f(noise_rate), f(eps))


class DVSState(NamedTuple):
    """One camera's pixels.

    Attributes:
        reference: reference log intensity of each pixel, ``(height, width)``.
        log_frame: log intensity of the last frame, ``(height, width)``.
        pos_threshold, neg_threshold: each pixel's thresholds, ``(height, width)``.
        last_event: time of each pixel's last event, seconds (``-inf``: none yet).
        t: time of the last frame, seconds.
    """

    reference: jax.Array
    log_frame: jax.Array
    pos_threshold: jax.Array
    neg_threshold: jax.Array
    last_event: jax.Array
    t: jax.Array


def init(params: DVSParams, frame: jax.Array, t0=0.0, *, key: jax.Array) -> DVSState:
    """Pixels that have just seen ``frame`` at ``t0``; the thresholds' mismatch is drawn from ``key``."""
    frame = jnp.asarray(frame, jnp.float32)
    log_frame = jnp.log(frame + params.eps)
    k_pos, k_neg = jax.random.split(key)
    spread = lambda k: 1.0 + params.threshold_sigma * jax.random.normal(k, frame.shape)
    return DVSState(
        reference=log_frame,
        log_frame=log_frame,
        pos_threshold=jnp.maximum(params.pos_threshold * spread(k_pos), 0.01),
        neg_threshold=jnp.maximum(params.neg_threshold * spread(k_neg), 0.01),
        last_event=jnp.full(frame.shape, -jnp.inf, jnp.float32),
        t=jnp.asarray(t0, jnp.float32),
    )


def crossings(params: DVSParams, state: DVSState, frame: jax.Array) -> jax.Array:
    """How many thresholds each pixel's log intensity crosses from its reference to ``frame``, ``(height, width)`` int32.

    `step` makes at most ``max_per_pixel`` of them into events and counts the
    rest as overflow; ``jnp.maximum(crossings - max_per_pixel, 0).sum()`` is that
    share of its overflow, the remainder the events beyond ``capacity``.
    """
    log_frame = jnp.log(jnp.asarray(frame, jnp.float32) + params.eps)
    up = log_frame >= state.reference
    c = jnp.where(up, state.pos_threshold, state.neg_threshold)
    return jnp.floor(jnp.abs(log_frame - state.reference) / c).astype(jnp.int32)


class _Interval(NamedTuple):
    """One interval's crossings made events, per pixel (what `step` and `step_counts` share)."""

    fires: list  # max_per_pixel (height, width) bool: crossing k made an event
    stamps: list  # their times
    polarity: jax.Array  # (height, width) int32
    noise: jax.Array  # (height * width,) bool: a noise event
    noise_polarity: jax.Array
    noise_t: jax.Array
    clipped: jax.Array  # crossings beyond max_per_pixel, summed
    state: DVSState


def _noise(params: DVSParams, key: jax.Array, t0, t, size: int):
    """The interval's shot noise, one draw a pixel: ``(noise, polarity, time)``, each ``(size,)``."""
    k_noise, k_pol, k_time = jax.random.split(key, 3)
    p_noise = -jnp.expm1(-params.noise_rate * (t - t0))
    # `threefry_uniform` is `jax.random.uniform` (the same numbers), drawn in one pass on a CPU.
    noise = threefry_uniform(k_noise, (size,)) < p_noise
    polarity = jnp.where(threefry_uniform(k_pol, (size,)) < 0.5, 1, -1).astype(jnp.int32)
    return noise, polarity, t0 + (t - t0) * threefry_uniform(k_time, (size,), 1e-6, 1.0)


class _Levels(NamedTuple):
    """A pixel's way from its reference to the new frame's log intensity (what both counting paths share)."""

    log_frame: jax.Array
    up: jax.Array  # moving up from the reference: ON crossings
    n: jax.Array  # thresholds crossed, int32
    step: jax.Array  # signed threshold: the reference moves by it at each crossing


def _levels(params: DVSParams, state: DVSState, frame) -> _Levels:
    log_frame = jnp.log(frame + params.eps)
    up = log_frame >= state.reference
    c = jnp.where(up, state.pos_threshold, state.neg_threshold)
    return _Levels(log_frame, up, crossings(params, state, frame), jnp.where(up, 1.0, -1.0) * c)


def _crossing_time(state: DVSState, lv: _Levels, k, t):
    """When the log intensity, moving linearly from the last frame's at ``state.t`` to ``lv``'s at ``t``, crosses level ``k``."""
    l0, l1 = state.log_frame, lv.log_frame
    slope = l1 - l0
    safe = jnp.where(slope == 0, 1.0, slope)
    level = state.reference + k * lv.step
    frac = jnp.clip((level - l0) / safe, 0.0, 1.0)
    return state.t + (t - state.t) * jnp.where(slope == 0, 1.0, frac)


def _next_state(state: DVSState, lv: _Levels, last_event, t) -> DVSState:
    """The pixels after the interval: the reference moved to the last level crossed."""
    return state._replace(
        reference=state.reference + lv.n * lv.step, log_frame=lv.log_frame, last_event=last_event, t=t
    )


def _interval(params: DVSParams, state: DVSState, frame, t, max_per_pixel: int, key: jax.Array) -> _Interval:
    frame = jnp.asarray(frame, jnp.float32)
    t = jnp.asarray(t, jnp.float32)
    lv = _levels(params, state, frame)
    last = state.last_event
    fires, stamps = [], []
    for k in range(1, max_per_pixel + 1):
        tk = _crossing_time(state, lv, k, t)
        fire = (k <= lv.n) & (tk - last >= params.refractory)
        last = jnp.where(fire, tk, last)
        fires.append(fire)
        stamps.append(tk)
    noise, noise_pol, noise_t = _noise(params, key, state.t, t, frame.size)
    return _Interval(
        fires,
        stamps,
        jnp.where(lv.up, 1, -1).astype(jnp.int32),
        noise,
        noise_pol,
        noise_t,
        jnp.sum(jnp.maximum(lv.n - max_per_pixel, 0)),
        _next_state(state, lv, last, t),
    )


def step(
    params: DVSParams,
    state: DVSState,
    frame: jax.Array,
    t,
    *,
    capacity: int,
    max_per_pixel: int = 4,
    key: jax.Array,
) -> tuple[DVSState, Events, jax.Array]:
    """The events of the interval from the last frame to ``frame`` at time ``t``.

    Within the interval each pixel's log intensity moves linearly from the last
    frame's to this one's; it crosses ``reference + k C+`` (or ``reference - k C-``)
    for ``k = 1 .. n`` and emits an event at each crossing's time, the reference
    moving to the last level crossed. A crossing within ``refractory`` of the
    pixel's previous event is dropped (the reference still moves: the change is
    consumed). At most ``max_per_pixel`` events per pixel and interval are made;
    the crossings beyond it are counted in ``overflow``, with the events that
    did not fit in ``capacity``. Noise events (rate ``noise_rate`` per pixel,
    random polarity, uniform time) are drawn from ``key``. Events come sorted by
    time.

    Returns:
        ``(state, events, overflow)``.
    """
    iv = _interval(params, state, frame, t, max_per_pixel, key)
    xs, ys = _pixels(jnp.shape(frame))
    k_all = max_per_pixel + 1
    events, overflow = compact(
        jnp.tile(xs, k_all),
        jnp.tile(ys, k_all),
        jnp.concatenate([s.reshape(-1) for s in iv.stamps] + [iv.noise_t]),
        jnp.concatenate([jnp.tile(iv.polarity.reshape(-1), max_per_pixel), iv.noise_polarity]),
        jnp.concatenate([f.reshape(-1) for f in iv.fires] + [iv.noise]),
        capacity,
    )
    order = jnp.argsort(jnp.where(events.valid, events.t, jnp.inf), stable=True)
    events = jax.tree.map(lambda a: a[order], events)
    return iv.state, events, overflow + iv.clipped


def step_counts(
    params: DVSParams, state: DVSState, frame: jax.Array, t, *, max_per_pixel: int = 4, key: jax.Array
) -> tuple[DVSState, jax.Array, jax.Array]:
    """`step`'s events of the interval counted per pixel, ``(height, width)`` int32, without making the list.

    The same crossings, refractory period, noise draws (from the same ``key``)
    and new state as `step`; the count image equals counting `step`'s events
    (`spikejax.vision.edges.count_image`) whenever none is beyond its
    ``capacity``, and costs elementwise work alone: no compaction, no sort, no
    scatter (for a consumer that reads a frame's events as counts, like
    `spikejax.vision.edges.sync_step`). A count image has no capacity.

    Without a refractory period (``params.refractory == 0``) every crossing up to
    ``max_per_pixel`` is an event, so the count is ``min(crossings, max_per_pixel)``
    and only the last one's time is needed (for the state): the same counts and
    state for a quarter of the crossing-time arithmetic (a third less time for
    the hexapod's vision, docs/BENCHMARKS.md). The choice is made when tracing
    where the refractory period is a constant, by ``lax.cond`` where it is traced.

    Returns:
        ``(state, counts, clipped)``: ``clipped`` the crossings beyond ``max_per_pixel``, summed.
    """

    def every_crossing():
        iv = _interval(params, state, frame, t, max_per_pixel, key)
        counts = sum(f.astype(jnp.int32) for f in iv.fires) + iv.noise.reshape(iv.polarity.shape).astype(jnp.int32)
        return iv.state, counts, iv.clipped

    def without_refractory():
        return _counts_without_refractory(params, state, frame, t, max_per_pixel, key)

    refractory = params.refractory
    if isinstance(refractory, jax.core.Tracer):
        return jax.lax.cond(jnp.any(refractory > 0), every_crossing, without_refractory)
    return every_crossing() if np.any(np.asarray(refractory) > 0) else without_refractory()


def _counts_without_refractory(params: DVSParams, state: DVSState, frame, t, max_per_pixel: int, key: jax.Array):
    """`step_counts` when no crossing is refractory: the first ``min(n, max_per_pixel)`` of a pixel's ``n`` crossings.

    `_interval`'s crossing times never decrease with ``k`` within a pixel (its
    log intensity stays within a threshold of the reference between intervals,
    so a pixel moving against its crossing direction crosses at most once), so
    with a refractory period of 0 each of its first ``max_per_pixel`` crossings
    fires; the pixel's last event is its last such crossing, computed as there.
    """
    frame = jnp.asarray(frame, jnp.float32)
    t = jnp.asarray(t, jnp.float32)
    lv = _levels(params, state, frame)
    fired = jnp.minimum(lv.n, max_per_pixel)
    last = jnp.where(fired > 0, _crossing_time(state, lv, fired.astype(jnp.float32), t), state.last_event)
    noise, _, _ = _noise(params, key, state.t, t, frame.size)
    counts = fired + noise.reshape(frame.shape).astype(jnp.int32)
    return _next_state(state, lv, last, t), counts, jnp.sum(jnp.maximum(lv.n - max_per_pixel, 0))


@functools.partial(jax.jit, static_argnames=("capacity", "max_per_pixel"))
def emulate(
    params: DVSParams,
    frames: jax.Array,
    times: jax.Array,
    *,
    capacity: int,
    max_per_pixel: int = 4,
    key: jax.Array,
) -> tuple[Events, jax.Array]:
    """Run `step` over a sequence of frames, starting from ``frames[0]``.

    Args:
        params: emulator parameters.
        frames: ``(n, height, width)`` intensities in ``[0, 1]``.
        times: ``(n,)`` increasing frame times, seconds.
        capacity, max_per_pixel: as in `step` (static).
        key: PRNG key: the threshold mismatch and every interval's noise derive from it.

    Returns:
        ``(events, overflow)``: events with leaves ``(n - 1, capacity)``, row ``k``
        the interval ``(times[k], times[k + 1]]``; overflow ``(n - 1,)``.
    """
    frames = jnp.asarray(frames, jnp.float32)
    times = jnp.asarray(times, jnp.float32)
    k_init, k_steps = jax.random.split(key)
    state = init(params, frames[0], times[0], key=k_init)
    keys = jax.random.split(k_steps, frames.shape[0] - 1)

    def body(state, inputs):
        frame, t, k = inputs
        state, events, overflow = step(params, state, frame, t, capacity=capacity, max_per_pixel=max_per_pixel, key=k)
        return state, (events, overflow)

    _, (events, overflow) = jax.lax.scan(body, state, (frames[1:], times[1:], keys))
    return events, overflow
