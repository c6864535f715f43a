"""``spikejax reproduce snake-pipe``: the closed pipe loop over many placements (the pipe-tracking paper's Sec. 3.2).

The paper ran one trajectory per situation; this runs ``--episodes`` per
situation (standing or lying pipe, left or right: `robots.snake.pipes.SITUATIONS`,
placements from `robots.snake.pipes.sample`), or, with ``--scene FILE``, that
scene in every episode (one row per pipe; the episodes differ in the key
only: the gait's start phase, ``--random-phase``). Each episode is
`robots.snake.pipe_env.PipeEnv` driven by the spiking bang-bang controller
(`robots.snake.pipe_controller.bang_bang`) for ``--seconds``; standing pipes
with the line grid, lying ones with the reduced circle grid alone, as the
paper detects them (`robots.snake.pipe_env.default_tracker`), the lying
ones' grid extended for the last metre and steered by to the end (``--near``,
`robots.snake.pipe_controller.machine_params`), the entry remembered in the
world between detections (``--entry-memory``) and the circle grid updated
every ``--circle-every`` slots on the events of the last ``--circle-window``. The first ``--baselines``
episodes of each situation run again, the same placements and keys, going
straight and with the privileged controller (the true side of the pipe):
the lower and upper bounds of the bang-bang law. They read only the truth,
so they run without the camera and the detector (``PipeEnv(vision=False)``:
the same physics step for step, about a fifth of the cost), and their rows
leave the detection columns empty. A lane whose episode is done (success,
or a collision with a standing pipe, or going straight, the pipe 1 m
behind: `passed`) takes the next episode.

Writes, in ``--out DIR``:

- ``snake_pipe.csv``, one row per situation (or scene pipe) and controller: episodes,
  successes with the 95 % Wilson interval (standing: the head within 0.3 m of
  the surface; lying: the head in the bore), approaches (the head within 0.3 m
  of the pipe or its entry), mean time to success, mean |Eq. (8) distance -
  true depth| at the detections, detection rate (the share of the slots
  ending with the pipe's centre in the image's columns that have a
  detection), the share of the detections made with it out of them (a
  lying entry's ring still in view near the entry, or false positives),
  steering-sign accuracy (the sign of Alg. 3's
  offset against the true offset from the central line, where that is at
  least 0.15 m), and every failure with one label (`LABELS`, first that
  applies): ``never_detected``; ``missed_bore`` (a lying pipe approached,
  not entered); ``wrong_side`` (most of the episode's steering against the
  true offset's side); ``overshoot`` (the pipe ended behind the camera);
  ``lost`` (no detection in the last ``lost_slots`` slots);
  ``timeout`` (still approaching).
- ``snake_pipe_distance.csv``: the distance error of Alg. 3 (Eq. 8 with the
  known size) against the true depth at the spiking controller's
  detections, per situation, kind of detection (body, entry) and 0.5 m bin
  of the true depth (`DISTANCE_BINS`, `distance_rows`).
- ``snake_pipe_trajectories.png``: the head's path of every episode, per
  situation, with the pipes drawn at their places (the paper's Fig. 8).
- With ``--figures`` (the default), the counterparts of Figs. 5-7
  (`robots.snake.reproduce_pipe_figures`): ``snake_pipe_camera_offset.png`` and
  ``.csv`` (the camera's offset on a straight run, its fundamental and
  Eqs. (4)-(6); RMSE and correlation), ``snake_pipe_detections.png`` (the
  detected body or entry over the slot's events at four depths spread over
  an approach) and ``snake_pipe_width_distance.png`` and ``.csv`` (detected
  width and Eq. (8)'s distance against the true depth over an approach; the
  mean error over the first and the last third of the detections), from each
  situation's first placement run again and recorded slot by slot (up to
  `FIGURE_EPISODES` situations or scene pipes).

With ``--compare-modes N``, also ``snake_pipe_modes.csv`` and ``.png``: N
standing-right episodes of ``--seconds`` each in the synchronous and the
asynchronous mode on the contrast-threshold DVS, and in the default sync
mode on frame differences, paired episode by episode
(`robots.snake.reproduce_pipe_modes`).

Defaults: 256 episodes per situation of 60 s each (at about 0.1 m/s the
farthest starts, 4 m, need 40 s straight), 64 of them with the baselines;
each batch split over one CPU device a core (``--cpu-devices``).
Timings and results: docs/BENCHMARKS.md, "Snake pipe loop".
"""

from __future__ import annotations

import argparse
import functools
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from robots.common import write_csv
from spikejax.commands import Command, add_common, count, count_or_zero, output_directory
from spikejax.errors import UserError

# robots.snake.pipes and the env (MuJoCo) are imported by the functions that run the snake:
# `spikejax reproduce` imports this module to list its flags beside the others'.

LABELS = ("never_detected", "missed_bore", "wrong_side", "overshoot", "lost", "timeout")
HEADER = [
    "situation",
    "controller",
    "episodes",
    "successes",
    "success_rate",
    "wilson_low",
    "wilson_high",
    "approached",
    "mean_time_to_success_s",
    "mean_distance_error_m",
    "detection_rate",
    "out_of_view_share",
    "sign_accuracy",
    *(f"fail_{label}" for label in LABELS),
]
DISTANCE_HEADER = [
    "situation",
    "controller",
    "detection",
    "depth_low_m",
    "depth_high_m",
    "detections",
    "mean_abs_error_m",
    "median_abs_error_m",
    "mean_relative_error",
]
DISTANCE_BINS = ((0.5, 1.0), (1.0, 1.5), (1.5, 2.0), (2.0, 2.5), (2.5, 3.0), (3.0, 4.0), (0.5, 3.0))
"""True-depth bins, m, of the distance-error table (ACCEPTANCE.md #3's 0.5 m bins; the last row pools 0.5-3 m)."""
CHUNK = 64  # episodes per compiled batch
# The lying pipes' circle grid on 2 x 2 bins (`spikejax.vision.detect.Detector`'s ``circle_bin``): on the
# reproduction's first 32 episodes a side the same 16 / 13 entered as on every pixel, 2.3x faster (119 against
# 269 s of one core), the entry's distance error at 2-3 m of depth about twice as large (docs/BENCHMARKS.md).
CIRCLE_BIN = 2
NEAR = True  # the lying pipes' near circle grid (`robots.snake.pipe_env.default_tracker`'s ``near``)
# Each episode's gait starts at a phase drawn from its key (`robots.snake.pipe_env.PipeEnv`'s ``random_phase``): at
# phase 0 for all, the lying entries of the default run were 148 / 122 of 256 (left / right), with it 125 / 127
# (docs/BENCHMARKS.md).
RANDOM_PHASE = True
# The lying entry remembered in the world (`robots.snake.pipe_env.PipeEnv`'s ``entry_memory``, this weight) and
# steered at to the end: on the first 32 lying placements a side 23 / 28 entered against 22 / 15 without
# (docs/BENCHMARKS.md). 0: off.
ENTRY_MEMORY = 0.3
# The lying pipes' circle grid updates every CIRCLE_EVERY slots (`robots.snake.pipe_env.PipeEnv`'s
# ``circle_every``), the remembered entry steering between, on the events of the last CIRCLE_WINDOW slots
# (``circle_window``; the earlier ones dropped). On the 256 lying placements a side (entered of 512, mean |Eq. (8)
# distance - depth| of the entry at 0.5-3 m, the lying queue's wall time on one day): every slot 390; every 2
# slots 378, 0.24 m, 15:25; every 4 on all 4 slots 404, 0.31 m, 10:48; every 4 on the last 2 slots 407, 0.24 m,
# 10:16 (docs/BENCHMARKS.md): the update's cost halved, the entry's distance error that of a 2-slot update.
CIRCLE_EVERY = 4
CIRCLE_WINDOW = 2
MIN_LANES = 2
"""The fewest lanes `_episodes` runs on a device: XLA compiles a batch of one lane (its axis of size 1 folded away)
to other floating-point rounding than wider ones, and the closed loop makes the difference another trial (measured:
a standing episode's head moved apart from step 5). From two lanes on an episode's trial does not depend on the batch
(tested), so a run of fewer episodes fills the lanes with copies of them."""
CIRCLE_CHUNK = 32  # with the circle grid (16 a device on two): its spectra per lane outgrow the cache in larger batches
SEGMENT = 20  # slots (2 s) a batch runs between refills of its finished lanes (a multiple of CIRCLE_EVERY)
PASSED = 1.0  # m: a lane going straight ends once its target is this far behind the head (`passed`)


def label_failures(success, approached, lying, detected, sign_right, depth_end, last_seen_slots, lost_slots):
    """One `LABELS` index per episode (-1 for a success), host arrays ``(n,)``; the first label that applies."""
    labels = np.full(success.shape, LABELS.index("timeout"))
    rules = [
        ("lost", last_seen_slots > lost_slots),
        ("overshoot", depth_end < 0),
        ("wrong_side", sign_right < 0.5),
        ("missed_bore", lying & approached),
        ("never_detected", detected == 0),
    ]
    for name, applies in rules:  # later rules take precedence: the list runs from the least to the most basic
        labels = np.where(applies, LABELS.index(name), labels)
    return np.where(success, -1, labels)


def passed(head, start, target, margin: float = PASSED) -> np.ndarray:
    """Per lane: the head has gone ``margin`` m past ``target`` along its course from ``start`` (host arrays).

    ``head`` and ``target`` ``(n, 2)``, ``start`` ``(n, >= 2)``, m. The
    course is the line from the start to the head: a snake that never
    steers (the straight baseline) keeps it, so once its target lies
    ``margin`` behind the head along it, the episode's row can no longer
    change (no approach, no entry; the target stays behind the camera, the
    failure an ``overshoot`` as at the time limit) and `_episodes` gives its
    lane the next episode. Checked on the default run: its CSVs are the
    same byte for byte with and without this rule.
    """
    course = np.asarray(head) - np.asarray(start)[:, :2]
    run = np.linalg.norm(course, axis=1)
    ahead = np.sum((np.asarray(target) - np.asarray(head)) * course, axis=1) / np.maximum(run, 1e-9)
    return (run > margin) & (ahead < -margin)


def _pad(a: np.ndarray, steps: int, edge: bool) -> np.ndarray:
    """``a`` ``(n, t, ...)`` padded along time to ``steps``: with its last value (``edge``) or zeros."""
    if a.shape[1] >= steps:
        return a[:, :steps]
    width = [(0, 0), (0, steps - a.shape[1])] + [(0, 0)] * (a.ndim - 2)
    return np.pad(a, width, mode="edge" if edge else "constant")


@functools.cache
def _programs(env, devices: int = 1):
    """The jitted episode start and `SEGMENT` of slots of ``env`` under `robots.snake.pipe_controller.switch`.

    One pair per env serves every controller (the switch is traced), situation of its kind and chunk; the
    batch is split over the first ``devices`` CPU devices (`spikejax.devices.shard_batch`).
    """
    from robots.snake import pipe_controller as pc
    from robots.snake import pipe_env
    from spikejax.devices import shard_batch

    on = jax.devices()[:devices]
    start = shard_batch(jax.vmap(lambda k, s: pipe_env.rollout_start(env, pc.switch, k, s)), on)
    segment = shard_batch(jax.vmap(lambda c, p: pipe_env.rollout_slots(env, pc.switch, p, c, SEGMENT)), on)
    return start, segment


def _episodes(env, scenes, keys, slots, params, progress: bool, desc: str, size: int = CHUNK, devices: int = 1):
    """Each episode of ``keys`` / ``scenes`` for ``slots`` slots, ``size`` lanes at a time, with `robots.snake.pipe_controller.switch`.

    One batch of ``size`` lanes (one compile) runs ``SEGMENT`` slots at a
    time; after each segment a lane whose episode is done (success, a
    collision with a standing pipe, or the env's timeout at the run's length)
    takes the next episode, started afresh at that segment boundary (a
    slot boundary, so the slots of every episode still end at the same
    steps of its own time). Episodes are independent lanes of a ``vmap``:
    an episode's trial does not depend on its lane or its neighbours, so
    refilling changes no result, and the batch never waits for its slowest
    episode. A lane going straight (the ``straight`` baseline) also ends
    once its target is well behind its head (`passed`). A finished
    episode's record is padded to the run's length (outcomes and positions
    held, detections and actions 0), as it is never read past its end.
    """
    from tqdm import tqdm

    from robots.snake import pipe_controller as pc

    start, segment = _programs(env, devices)
    merge = _merge_program()
    zero_pad = ("detected", "entry_detected", "in_view")
    keep = (
        "detected",
        "entry_detected",
        "d_est",
        "depth",
        "offset_est",
        "offset_true",
        "in_view",
        "success",
        "reached",
    )
    steps = slots * env.slot_steps
    n = keys.shape[0]
    pick = lambda tree, idx: jax.tree.map(lambda a: a[idx], tree)  # noqa: E731
    lanes = MIN_LANES * devices
    if n < lanes:  # too few episodes for MIN_LANES a device: copies run beside them
        fill = np.arange(lanes) % n
        res = _episodes(env, pick(scenes, fill), keys[fill], slots, pick(params, fill), progress, desc, lanes, devices)
        return pick(res, slice(0, n))
    size = max(lanes, min(size, n))
    lane = np.arange(size)  # the episode each lane runs
    queue = size  # the next episode to start
    carry = start(keys[lane], pick(scenes, lane))
    lane_params = pick(params, lane)
    straight = np.asarray(params.which) == pc.CONTROLLERS["straight"]  # per episode, for `passed`
    origin, target = np.asarray(scenes.start), np.asarray(scenes.xy)[:, 0]
    parts: list[list] = [[] for _ in range(size)]
    ran = np.zeros(size, int)  # slots each lane's episode has run
    live = np.ones(size, bool)
    results: dict[int, dict] = {}
    bar = tqdm(total=n, desc=desc, disable=not progress, unit="episode")
    while live.any():
        carry, record = segment(carry, lane_params)
        record = jax.tree.map(
            np.asarray, {"metrics": record["metrics"], **{k: record[k] for k in ("head", "action", "done")}}
        )
        ran += SEGMENT
        finished = live & ((np.asarray(carry[0].done) > 0) | (ran >= slots))
        if straight[lane].any():
            finished |= live & straight[lane] & passed(record["head"][:, -1], origin[lane], target[lane])
        for i in np.flatnonzero(live):
            parts[i].append(jax.tree.map(lambda a, i=i: a[i], record))
        for i in np.flatnonzero(finished):
            rec = jax.tree.map(lambda *a: np.concatenate(a, axis=0), *parts[i])
            out = {k: _pad(rec["metrics"][k][None], steps, k not in zero_pad)[0] for k in keep}
            for k in ("head", "action", "done"):
                out[k] = _pad(rec[k][None], steps, k != "action")[0]
            results[int(lane[i])] = out
            parts[i] = []
            bar.update(1)
        fresh = np.zeros(size, bool)
        for i in np.flatnonzero(finished):
            if queue < n:
                lane[i], queue, ran[i], fresh[i] = queue, queue + 1, 0, True
            else:
                live[i] = False
        if fresh.any() and live.any():
            new = start(keys[lane], pick(scenes, lane))  # every lane, one batch shape; only the fresh ones are kept
            carry = merge(jnp.asarray(fresh), new, carry)
            lane_params = pick(params, lane)
    bar.close()
    res = {k: np.stack([results[i][k] for i in range(n)]) for k in results[0]}
    for k in ("success", "reached"):
        res[k] = res[k][:, -1] > 0
    hit = res.pop("done") > 0
    res["end_step"] = np.where(hit.any(1), hit.argmax(1) + 1, steps)  # steps up to and including the end
    return res


@functools.cache
def _merge_program():
    """``merge(mask, new, old)``: per lane (leading axis), ``new`` where ``mask`` holds, else ``old``."""

    def pick(mask, a, b):
        if jax.dtypes.issubdtype(a.dtype, jax.dtypes.prng_key):  # typed keys: choose their data
            return jax.random.wrap_key_data(pick(mask, jax.random.key_data(a), jax.random.key_data(b)))
        return jnp.where(mask.reshape(mask.shape + (1,) * (a.ndim - 1)), a, b)

    def merge(mask, new, old):
        return jax.tree.map(lambda a, b: pick(mask, a, b), new, old)

    return jax.jit(merge)


def summarize(name, controller, res, lying: bool, dt: float, slot_steps: int, lost_slots: int, vision=True) -> list:
    """One CSV row from an `_episodes` result (host arrays).

    ``vision=False`` (a run without the camera and detector: the baselines)
    leaves the detection columns empty (NaN) and labels failures without
    the detection labels (``never_detected``, ``lost``).
    """
    from spikejax.stats import wilson_interval

    n = res["success"].shape[0]
    k = int(res["success"].sum())
    low, high = wilson_interval(k, n)
    det = res["detected"] > 0
    # Outcomes are latched, but the record runs on after done: only the steps up to it count.
    end = res["end_step"]
    steps = det.shape[1]
    live = np.arange(steps)[None, :] < end[:, None]
    used = det & live
    err = np.abs(res["d_est"] - res["depth"])[used]
    ends = np.zeros_like(det)
    ends[:, slot_steps - 1 :: slot_steps] = True
    view = ends & live & (res["in_view"] > 0)
    strong = used & (np.abs(res["offset_true"]) >= 0.15)
    sign_ok = (np.sign(res["offset_est"]) == np.sign(res["offset_true"]))[strong]
    steer = (res["action"] != 0) & live
    agree = np.where(steer, np.sign(res["action"]) == np.sign(res["offset_true"]), False).sum(1)
    sign_right = np.where(steer.any(1), agree / np.maximum(steer.sum(1), 1), 1.0)  # never steered: not "wrong side"
    last = np.array([np.flatnonzero(d[:e])[-1] if d[:e].any() else -1 for d, e in zip(det, end)])
    last_seen_slots = np.where(last >= 0, (end - 1 - last) // slot_steps, 10**9) if vision else np.zeros(n, int)
    depth_end = res["depth"][np.arange(n), end - 1]
    labels = label_failures(
        res["success"],
        res["reached"],
        np.full(n, lying),
        used.sum(1) if vision else np.ones(n, int),
        sign_right,
        depth_end,
        last_seen_slots,
        lost_slots,
    )
    time = res["end_step"][res["success"]] * dt
    rate = lambda a: float(np.mean(a)) if np.size(a) else float("nan")  # noqa: E731
    return [
        name,
        controller,
        n,
        k,
        k / n,
        float(low),
        float(high),
        int(res["reached"].sum()),
        rate(time),
        rate(err) if vision else float("nan"),
        float((used & view).sum() / max(view.sum(), 1)) if vision else float("nan"),
        float((used & ~view).sum() / max(used.sum(), 1)) if vision else float("nan"),
        rate(sign_ok) if vision else float("nan"),
        *(int((labels == i).sum()) for i in range(len(LABELS))),
    ]


def distance_rows(name, controller, res) -> list[list]:
    """`DISTANCE_HEADER` rows: |Eq. (8) distance - true depth| at the detections, per kind and `DISTANCE_BINS` bin.

    A detection counts up to its episode's end and where Alg. 3 gave a
    distance (``d_est > 0``); ``body`` are the slots steered by the body,
    ``entry`` those steered by the entry (the lying pipes' circle grid).
    """
    live = np.arange(res["detected"].shape[1])[None, :] < res["end_step"][:, None]
    det = (res["detected"] > 0) & live & (res["d_est"] > 0)
    entry = res["entry_detected"] > 0
    rows = []
    for kind, which in (("body", det & ~entry), ("entry", det & entry)):
        if not which.any():
            continue
        depth, est = res["depth"][which], res["d_est"][which]
        for low, high in DISTANCE_BINS:
            m = (depth >= low) & (depth < high)
            err = np.abs(est - depth)[m]
            stat = lambda f, e=err: float(f(e)) if e.size else float("nan")  # noqa: E731
            rel = np.abs(est - depth)[m] / depth[m]
            rows.append(
                [name, controller, kind, low, high, int(m.sum()), stat(np.mean), stat(np.median), stat(np.mean, rel)]
            )
    return rows


def _plot(path: Path, results) -> None:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(4 * len(results), 4))
    for i, (name, res, scene) in enumerate(results):
        ax = fig.add_subplot(1, len(results), i + 1)
        for head, ok, end in zip(res["head"], res["success"], res["end_step"]):  # the env runs on after the end
            ax.plot(head[:end, 0], head[:end, 1], lw=0.6, color="tab:green" if ok else "tab:red", alpha=0.6)
        xy = np.asarray(scene.xy).reshape(-1, 2)
        valid = np.asarray(scene.valid).reshape(-1)
        ax.scatter(xy[valid, 0], xy[valid, 1], s=12, color="k", label="pipes")
        ax.set_title(f"{name}: {int(res['success'].sum())}/{res['success'].shape[0]}")
        ax.set_aspect("equal")
        ax.set_xlabel("x, m")
        ax.set_ylabel("y, m")
    fig.suptitle("Head paths (green: success, red: failure); the snake starts at the origin looking along +x")
    fig.savefig(path, dpi=110)


def _join(trees):
    """Trees of equal structure concatenated leaf by leaf along the leading axis."""
    return jax.tree.map(lambda *a: jnp.concatenate(a), *trees)


def _switch_params(machine, controller: str, n: int):
    """`robots.snake.pipe_controller.SwitchParams` for ``n`` episodes of one controller (leaves ``(n,)``)."""
    from robots.snake import pipe_controller as pc

    params = pc.SwitchParams(machine, pc.CONTROLLERS[controller])
    return jax.tree.map(lambda a: jnp.broadcast_to(jnp.asarray(a), (n,)), params)


def _conditions(names, envs, scenes, keys, slots, machine, baselines: int, progress: bool, devices: int = 1):
    """The spiking controller on every episode of each situation of ``names``, the baselines on the first
    ``baselines``: ``{name: [(label, res, scenes)]}``.

    ``envs`` is ``(env, blind)``: the spiking controller runs in ``env``, the
    baselines, which read only the truth, in its twin without the camera and
    detector (``vision=False``: the same physics step for step, at a fifth
    of the cost). ``scenes`` holds each name's placements. The situations
    share one queue of lanes (`_episodes`) and the two baselines another (the
    controller is a traced parameter): a batch waits for its slowest
    episodes once a queue, not once a situation. An episode's trial does not
    depend on its lane, so each result is the one it gets alone.
    """
    env, blind = envs
    out = {name: [] for name in names}
    queues = [(env, ("bang-bang",)), (blind, ("straight", "privileged"))]
    for run_in, controllers in queues:
        parts = []  # (name, controller, episodes)
        for controller in controllers:
            n = keys.shape[0] if controller == "bang-bang" else min(baselines, keys.shape[0])
            parts += [(name, controller, n) for name in names if n > 0]
        if not parts:
            continue
        queue_scenes = _join([jax.tree.map(lambda a, n=n: a[:n], scenes[name]) for name, _, n in parts])
        queue_keys = jnp.concatenate([keys[:n] for _, _, n in parts])
        params = _join([_switch_params(machine, controller, n) for _, controller, n in parts])
        circle = run_in.vision and run_in.tracker.detector.circle is not None
        size = min(CIRCLE_CHUNK if circle else CHUNK, queue_keys.shape[0])
        desc = f"snake-pipe {','.join(names)} {'/'.join(controllers)}"
        res = _episodes(run_in, queue_scenes, queue_keys, slots, params, progress, desc, size, devices)
        start = 0
        for name, controller, n in parts:
            own = slice(start, start + n)
            sub = jax.tree.map(lambda a, own=own: a[own], queue_scenes)
            out[name].append((controller, {k: v[own] for k, v in res.items()}, sub))
            start += n
    return out


def run(
    out: Path,
    episodes: int,
    seconds: float,
    scene_file=None,
    progress: bool = True,
    baselines: int = 64,
    situations: list[str] | None = None,
    devices: int = 1,
    lead: float | None = None,
    circle_bin: int = CIRCLE_BIN,
    near: bool = NEAR,
    random_phase: bool = RANDOM_PHASE,
    entry_memory: float = ENTRY_MEMORY,
    circle_every: int = CIRCLE_EVERY,
    circle_window: int | None = None,
    figures: bool = True,
) -> list[list]:
    """Everything in the module docstring; each batch split over the first ``devices`` CPU devices.

    ``lead``: m, how far the approach to a lying entry aims past its centre
    (`robots.snake.pipe_controller.ControllerParams`; default that of
    `robots.snake.pipe_controller.machine_params`, 0 the paper's ``C = sign(offset)``).
    ``circle_bin``: the lying pipes' circle grid on bins of that many sensor
    pixels a side (`CIRCLE_BIN`; 1: every pixel). ``near``: the lying pipes'
    circle grid extended for the last metre and their state machine to match
    (`NEAR`). ``random_phase``: each episode's gait starts at a phase drawn
    from its key (`RANDOM_PHASE`); else all at phase 0. ``entry_memory``: the
    lying entry's memory weight (`ENTRY_MEMORY`; 0: steer by each slot's
    detection); with ``near`` only. ``circle_every``: the lying pipes'
    circle grid updates every that many slots (`CIRCLE_EVERY`; a divisor of
    `SEGMENT`; 1: every slot). ``circle_window``: each update sees the
    events of the last that many of its slots (default `CIRCLE_WINDOW`, at
    most ``circle_every``). ``figures``: also the counterparts of
    Figs. 5-7 (`write_figures`).
    """
    from robots.snake import pipe_controller as pc
    from robots.snake import pipe_env, pipes

    if episodes < 1:
        raise UserError(f"--episodes must be at least 1, got {episodes}")
    if not seconds > 0:
        raise UserError(f"--seconds must be positive, got {seconds}")
    if baselines < 0:
        raise UserError(f"--baselines must be >= 0, got {baselines}")
    if lead is not None and not 0 <= lead < 2:
        raise UserError(f"--lead must be in [0, 2) m, got {lead}")
    if circle_bin not in (1, 2):
        raise UserError(f"--circle-bin must be 1 or 2, got {circle_bin}")
    if not 0 <= entry_memory <= 1:
        raise UserError(f"--entry-memory must be in [0, 1], got {entry_memory}")
    if (
        isinstance(circle_every, bool)
        or not isinstance(circle_every, int)
        or circle_every < 1
        or SEGMENT % circle_every
    ):
        raise UserError(f"--circle-every must be a whole number of slots dividing {SEGMENT}, got {circle_every}")
    if circle_window is None:
        circle_window = min(CIRCLE_WINDOW, circle_every)
    if isinstance(circle_window, bool) or not isinstance(circle_window, int) or not 1 <= circle_window <= circle_every:
        raise UserError(f"--circle-window must be a whole number of slots in [1, --circle-every], got {circle_window}")
    rows, results, distance = [], [], []
    keys = jax.random.split(jax.random.key(0), episodes)

    def steps_for(env):
        return max(1, int(round(seconds / env.dt / env.slot_steps)))

    jobs = []  # (name, lying, env factory, scenes)
    if scene_file is not None:
        scene = pipes.load_scene(scene_file)
        scene = pipes.load_scene(scene_file, capacity=int(np.asarray(scene.valid).sum()))  # no empty slots to draw
        for k, slot in enumerate(np.flatnonzero(np.asarray(scene.valid))):
            # Each pipe in turn is the target (slot 0); the others stay in the scene.
            order = np.array([slot] + [j for j in range(scene.capacity) if j != slot])
            target = scene._replace(**{f: getattr(scene, f)[order] for f in scene._fields if f != "start"})
            lying = int(np.asarray(scene.kind)[slot]) == pipes.LYING
            batch = jax.tree.map(lambda a, t=target: jnp.broadcast_to(a, (episodes, *a.shape)), target)
            name = f"pipe {k + 1} ({'lying' if lying else 'standing'})"
            jobs.append((name, bool(lying), dict(scene=target), batch))
    else:
        # One env per kind of pipe (its grids and known size): left and right share its programs.
        first = {}
        chosen = list(pipes.SITUATIONS) if situations is None else situations
        unknown = [name for name in chosen if name not in pipes.SITUATIONS]
        if unknown or not chosen:
            raise UserError(f"--situations takes names among {', '.join(pipes.SITUATIONS)}, not {unknown or chosen}")
        for name in chosen:
            kind = pipes.SITUATIONS[name][0]
            first.setdefault(kind, name)
            jobs.append((name, kind == pipes.LYING, dict(situation=first[kind]), None))
    envs, groups = {}, {}  # situations sharing an env run in one queue (`_conditions`)
    for name, lying, where, scenes in jobs:
        key = tuple(sorted((k, id(v)) for k, v in where.items()))
        if key not in envs:
            tracker = pipe_env.default_tracker(
                circle=lying, line=not lying, circle_bin=circle_bin if lying else 1, near=near and lying
            )
            env = pipe_env.PipeEnv(**where, tracker=tracker)
            envs[key] = tuple(
                pipe_env.PipeEnv(
                    **where,
                    tracker=tracker,
                    max_steps=steps_for(env) * env.slot_steps,
                    vision=vision,
                    random_phase=random_phase,
                    entry_memory=entry_memory if (lying and near) else 0.0,
                    circle_every=circle_every if lying else 1,
                    circle_window=circle_window if lying else 1,
                )
                for vision in (True, False)
            )
        env = envs[key][0]
        if scenes is None:
            scenes = jax.vmap(lambda k, n=name: env.sample_scene(k, n))(keys)
        groups.setdefault(key, []).append((name, lying, scenes))
    outcomes, recorded = {}, []
    for key, group in groups.items():
        env, lying = envs[key][0], group[0][1]
        machine = pc.machine_params(lying, near=near)
        if lying and lead is not None:
            machine = machine._replace(lead=lead)
        names = [name for name, _, _ in group]
        scenes = {name: sc for name, _, sc in group}
        runs = _conditions(names, envs[key], scenes, keys, steps_for(env), machine, baselines, progress, devices)
        for name in names:
            outcomes[name] = (runs[name], lying, env, int(machine.lost_slots))
        recorded.append((env, lying, machine, names, scenes, steps_for(env)))
    for name, _, _, _ in jobs:
        runs, lying, env, lost = outcomes[name]
        for controller, res, sub in runs:
            vision = controller == "bang-bang"
            rows.append(summarize(name, controller, res, lying, env.dt, env.slot_steps, lost, vision))
            if controller == "bang-bang":
                results.append((name, res, sub))
                distance += distance_rows(name, controller, res)
    write_csv(out / "snake_pipe.csv", HEADER, rows)
    write_csv(out / "snake_pipe_distance.csv", DISTANCE_HEADER, distance)
    _plot(out / "snake_pipe_trajectories.png", results)
    if figures:
        write_figures(out, recorded, keys[0], [name for name, _, _, _ in jobs][:FIGURE_EPISODES])
    return rows


FIGURE_EPISODES = 4  # situations (or scene pipes) in the Fig. 6 and 7 counterparts


def write_figures(out: Path, recorded, key, names: list[str]) -> None:
    """The counterparts of Figs. 5-7 (`robots.snake.reproduce_pipe_figures`) in ``out``.

    ``recorded``: ``(env, lying, machine, names, scenes, slots)`` per env of
    the run; the first placement of each of ``names`` runs again with ``key``
    (the first episode's) and the spiking controller, recorded slot by slot.
    Writes ``snake_pipe_camera_offset.png`` and ``.csv``,
    ``snake_pipe_detections.png`` and ``snake_pipe_width_distance.png`` and
    ``.csv`` (per recorded episode: its detections of the target's kind and
    the mean |Eq. (8) distance - true depth| at them, m, over all and over
    the first and the last third of them).
    """
    from robots.snake import reproduce_pipe_figures as pipe_figures

    episodes = {}
    for env, lying, machine, group, scenes, slots in recorded:
        chosen = [name for name in group if name in names]
        if not chosen:
            continue
        first = _join([jax.tree.map(lambda a: a[:1], scenes[n]) for n in chosen])
        keys = jnp.stack([key] * len(chosen))
        rec = pipe_figures.record(env, keys, first, _switch_params(machine, "bang-bang", len(chosen)), slots)
        for i, name in enumerate(chosen):
            episodes[name] = (name, lying, pipe_figures.lane(rec, i), env.circle_window)
    episodes = [episodes[name] for name in names if name in episodes]
    stats = pipe_figures.camera_offset_figure(out / "snake_pipe_camera_offset.png")
    write_csv(
        out / "snake_pipe_camera_offset.csv",
        OFFSET_HEADER,
        [[curve, *(s[k] for k in OFFSET_HEADER[1:])] for curve, s in stats.items()],
    )
    pipe_figures.detections_figure(out / "snake_pipe_detections.png", episodes)
    summary = pipe_figures.distance_figure(out / "snake_pipe_width_distance.png", episodes)
    write_csv(
        out / "snake_pipe_width_distance.csv", APPROACH_HEADER, [[s[k] for k in APPROACH_HEADER] for s in summary]
    )


OFFSET_HEADER = ["curve", "rmse", "amplitude", "rmse_share", "correlation"]
APPROACH_HEADER = ["name", "detections", "mean_error", "first_third", "last_third"]


def _add_arguments(parser) -> None:
    add_common(parser)
    parser.add_argument("--episodes", type=int, default=256, help="episodes per situation (default 256)")
    parser.add_argument("--seconds", type=float, default=60.0, help="simulated seconds per episode (default 60)")
    parser.add_argument("--scene", default=None, help="a scene file (TOML) used by every episode")
    parser.add_argument(
        "--situations",
        type=lambda text: [name.strip() for name in text.split(",") if name.strip()],
        default=None,
        help="comma-separated situations to run (default all: standing-left, standing-right, lying-left, "
        "lying-right); ignored with --scene",
    )
    parser.add_argument(
        "--baselines",
        type=int,
        default=64,
        help="episodes (the first of each situation) also run going straight and with the privileged controller "
        "(default 64)",
    )
    parser.add_argument(
        "--lead",
        type=float,
        default=None,
        metavar="M",
        help="m the approach to a lying pipe aims past its entry's centre, on the side first seen (default 0, "
        "0.25 with --no-near; 0 gives the paper's C = sign(offset))",
    )
    parser.add_argument(
        "--circle-bin",
        type=int,
        choices=(1, 2),
        default=CIRCLE_BIN,
        help="the lying pipes' circle grid on bins of N x N sensor pixels (default 2: a 64 x 64 grid, 2.3x faster "
        "with the same entries measured; 1: every pixel)",
    )
    parser.add_argument(
        "--near",
        action=argparse.BooleanOptionalAction,
        default=NEAR,
        help="extend the lying pipes' circle grid to the last metre (larger rings, centres above the image) and "
        "steer by it to the end (default on; --no-near: the grid to 0.44 m and a blind last stretch)",
    )
    parser.add_argument(
        "--random-phase",
        action=argparse.BooleanOptionalAction,
        default=RANDOM_PHASE,
        help="start each episode's gait at a phase drawn from its seed (default on; --no-random-phase: all at phase "
        "0, and a scene and its mirror image are different tasks)",
    )
    parser.add_argument(
        "--entry-memory",
        type=float,
        default=ENTRY_MEMORY,
        metavar="W",
        help="with --near, remember a lying entry in the world (each detection from 0.3 m on moves it by this "
        f"weight) and steer at it to the end (default {ENTRY_MEMORY}; 0: by each slot's detection)",
    )
    parser.add_argument(
        "--circle-every",
        type=int,
        default=CIRCLE_EVERY,
        metavar="N",
        help=f"update the lying pipes' circle grid every N slots, on their events (default {CIRCLE_EVERY}; 1: every "
        f"slot; N divides {SEGMENT})",
    )
    parser.add_argument(
        "--circle-window",
        type=int,
        default=None,
        metavar="W",
        help="each circle-grid update sees the events of the last W of its --circle-every slots (default "
        f"{CIRCLE_WINDOW}, or --circle-every when that is smaller)",
    )
    parser.add_argument(
        "--figures",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="also draw the counterparts of Figs. 5-7 (camera offset, detections over events, width and distance; "
        "one more episode per situation, recorded; default on)",
    )
    parser.add_argument(
        "--compare-modes",
        type=count_or_zero,
        default=0,
        metavar="N",
        help="also run N standing-right episodes in the sync and async modes on the contrast DVS and with frame "
        "differences, paired (robots.snake.reproduce_pipe_modes; writes snake_pipe_modes.csv and .png; default 0)",
    )
    parser.add_argument(
        "--cpu-devices",
        type=count,
        default=None,
        help="CPU devices each batch of episodes is split over (default: one per core)",
    )


def reproduce_command_run(
    *,
    out: str | Path,
    episodes: int = 256,
    seconds: float = 60.0,
    scene=None,
    baselines: int = 64,
    situations: list[str] | None = None,
    compare_modes: int = 0,
    cpu_devices: int | None = None,
    no_progress: bool = False,
    lead: float | None = None,
    circle_bin: int = CIRCLE_BIN,
    near: bool = NEAR,
    random_phase: bool = RANDOM_PHASE,
    entry_memory: float = ENTRY_MEMORY,
    circle_every: int = CIRCLE_EVERY,
    circle_window: int | None = None,
    figures: bool = True,
) -> int:
    """``spikejax reproduce snake-pipe --out DIR [--episodes N] [--seconds S] [--scene FILE] [--baselines B]``."""
    from spikejax.devices import cpu_devices_for_run

    with output_directory(out, command="reproduce snake-pipe") as out:
        devices = cpu_devices_for_run(cpu_devices)
        rows = run(
            out,
            episodes,
            seconds,
            scene,
            progress=not no_progress,
            baselines=baselines,
            situations=situations,
            devices=devices,
            lead=lead,
            circle_bin=circle_bin,
            near=near,
            random_phase=random_phase,
            entry_memory=entry_memory,
            circle_every=circle_every,
            circle_window=circle_window,
            figures=figures,
        )
        for r in rows:
            print(f"{r[0]:<22} {r[1]:<11} {r[3]}/{r[2]} succeeded, 95% CI [{r[5]:.2f}, {r[6]:.2f}]")
        print(f"wrote {out}/snake_pipe.csv, snake_pipe_distance.csv, snake_pipe_trajectories.png")
        if figures:
            print(
                f"wrote {out}/snake_pipe_camera_offset.png and .csv, snake_pipe_detections.png, "
                "snake_pipe_width_distance.png and .csv"
            )
        if compare_modes:
            from robots.snake.reproduce_pipe_modes import MODE_HEADER
            from robots.snake.reproduce_pipe_modes import compare_modes as run_modes

            for r in run_modes(out, episodes=compare_modes, seconds=seconds, progress=not no_progress):
                r = dict(zip(MODE_HEADER, r))
                print(
                    f"{r['mode']:<11} {r['successes']}/{r['episodes']} succeeded, {r['env_steps_per_s']:.0f} env-steps/s"
                )
            print(f"wrote {out}/snake_pipe_modes.csv, snake_pipe_modes.png")
        return 0


command = Command(
    help="the snake's closed pipe loop over many placements: success with Wilson intervals, failure labels",
    add_arguments=_add_arguments,
    run=reproduce_command_run,
)
