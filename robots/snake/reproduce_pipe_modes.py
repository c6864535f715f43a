"""Synchronous against asynchronous spiking Hough grids in the closed pipe loop, on the same episodes.

The snake pipe-tracking paper claims (abstract, Sec. 2.5, conclusion) that its
SNN is fastest in the synchronous mode on a GPU ("a simplified and
synchronous update rule") and more precise in the asynchronous mode on a
CPU, and gives no precision figure. `compare_modes` settles it in our loop:
the same episodes (keys and placements: those of ``spikejax reproduce
snake-pipe`` for the situation, `robots.snake.pipes.sample` from
``jax.random.split(jax.random.key(0), episodes)``) are run by
`robots.snake.pipe_env.PipeEnv` with the bang-bang controller in each of
`MODES`:

- ``sync``: the grids' Alg. 1 once per control step on the step's summed
  votes (`spikejax.vision.hough.sync_step`), on the contrast-threshold DVS;
- ``async``: every event through Alg. 1 in time order at its own time
  (`spikejax.vision.hough.async_step`), on the same contrast-threshold DVS,
  whose events carry the sub-frame crossing times the asynchronous mode
  needs (with frame differences every event of a step has the step's time
  and the asynchronous mode degenerates to raster order);
- ``sync-frame``: the loop's default, sync on the frame-difference DVS, for
  reference.

Everything else (the tracker's parameters, Alg. 2-3, the controller, the
episodes) is the same, so ``sync`` and ``async`` differ in the update rule
alone. Per mode: success with its 95 % Wilson interval, |Eq. (8) distance -
true depth| at the detections, steering-sign accuracy (as in
`robots.snake.reproduce_pipe.summarize`, whose row is reused), detection
rate, events per step, and env-steps/s (the episodes' wall time, compile
apart); and, paired with ``sync`` episode by episode, the successes only one
of the two has and the mean difference of the per-episode distance error
and sign accuracy with 95 % Student-t intervals (`spikejax.stats.mean_interval`).

On a lying pipe the circle grid runs in the chosen mode too; its
asynchronous mode updates a ring of cells at each radius for every event,
about 200 events/s on a 2-core CPU for the full grid
(`spikejax.commands.detect_pipe`), i.e. seconds per control step: the
measured comparison (docs/BENCHMARKS.md, "Snake pipe loop: sync against
async") is on standing pipes.
"""

from __future__ import annotations

import dataclasses
import math
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from robots.common import write_csv
from spikejax.errors import UserError

__all__ = ["CHUNK", "MODES", "MODE_HEADER", "compare_modes", "env_for", "write_modes_csv"]

MODES = {"sync": ("sync", "contrast"), "async": ("async", "contrast"), "sync-frame": ("sync", "frame")}
CHUNK = 64  # episodes per compiled batch
MODE_HEADER = [
    "mode",
    "grids",
    "dvs",
    "situation",
    "episodes",
    "seconds",
    "successes",
    "success_rate",
    "wilson_low",
    "wilson_high",
    "approached",
    "mean_distance_error_m",
    "detection_rate",
    "sign_accuracy",
    "events_per_step",
    "env_steps_per_s",
    "compile_s",
    "vs_sync_only_this_succeeded",
    "vs_sync_only_sync_succeeded",
    "vs_sync_distance_error_diff_m",
    "vs_sync_distance_error_diff_low",
    "vs_sync_distance_error_diff_high",
    "vs_sync_paired_episodes_distance",
    "vs_sync_sign_accuracy_diff",
    "vs_sync_sign_accuracy_diff_low",
    "vs_sync_sign_accuracy_diff_high",
    "vs_sync_paired_episodes_sign",
]


def env_for(mode: str, situation: str = "standing-right"):
    """The `robots.snake.pipe_env.PipeEnv` of one of `MODES` for ``situation`` (the loop's default tracker, its mode set)."""
    from robots.snake import pipe_env, pipes

    if mode not in MODES:
        raise UserError(f"mode must be one of {', '.join(MODES)}, not {mode!r}")
    if situation not in pipes.SITUATIONS:
        raise UserError(f"situation must be one of {', '.join(pipes.SITUATIONS)}, not {situation!r}")
    grid_mode, dvs = MODES[mode]
    tracker = pipe_env.default_tracker(circle=pipes.SITUATIONS[situation][0] == pipes.LYING)
    # The circle grid once per slot is a synchronous update: the asynchronous mode updates it per event.
    tracker = dataclasses.replace(
        tracker,
        detector=dataclasses.replace(tracker.detector, mode=grid_mode),
        circle_per_slot=tracker.circle_per_slot and grid_mode == "sync",
    )
    return pipe_env.PipeEnv(situation=situation, tracker=tracker, dvs=dvs)


def _episodes(env, keys, slots: int, progress: bool, desc: str):
    """The bang-bang episodes of ``keys`` (placements sampled from them), in chunks; host arrays, wall s, compile s."""
    from tqdm import tqdm

    from robots.snake import pipe_controller as pc
    from robots.snake import pipe_env

    params = pc.ControllerParams()

    def one(key):
        scene = env.sample_scene(key)
        record, final = pipe_env.rollout(env, pc.bang_bang, params, key, slots, scene)
        keep = ("detected", "d_est", "depth", "offset_est", "offset_true", "in_view", "events")
        out = {k: record["metrics"][k] for k in keep}
        out.update(head=record["head"], action=record["action"])
        out.update(success=final.metrics["success"] > 0, reached=final.metrics["reached"] > 0)
        hit = record["done"] > 0  # the episode's end: success, a collision, or the timeout
        out["end_step"] = jnp.where(hit.any(), jnp.argmax(hit) + 1, hit.shape[0])
        return out

    n = keys.shape[0]
    size = min(n, CHUNK)
    t0 = time.perf_counter()
    compiled = jax.jit(jax.vmap(one)).lower(keys[:size]).compile()
    compile_s = time.perf_counter() - t0
    parts, wall = [], 0.0
    for lo in tqdm(range(0, n, size), desc=desc, disable=not progress):
        idx = np.arange(lo, min(lo + size, n))
        pad = np.concatenate([idx, np.full(size - idx.size, idx[-1])])
        t0 = time.perf_counter()
        out = jax.block_until_ready(compiled(keys[pad]))
        wall += time.perf_counter() - t0
        parts.append({k: np.asarray(v)[: idx.size] for k, v in out.items()})
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}, wall, compile_s


def _per_episode(res, slot_steps: int):
    """Each episode's mean distance error and sign accuracy at its detections (NaN where it has none)."""
    det = res["detected"] > 0
    used = det & (np.arange(det.shape[1])[None, :] < res["end_step"][:, None])
    err = np.abs(res["d_est"] - res["depth"])
    strong = used & (np.abs(res["offset_true"]) >= 0.15)
    ok = np.sign(res["offset_est"]) == np.sign(res["offset_true"])
    with np.errstate(invalid="ignore", divide="ignore"):
        distance = np.where(used.any(1), (err * used).sum(1) / used.sum(1), np.nan)
        sign = np.where(strong.any(1), (ok & strong).sum(1) / strong.sum(1), np.nan)
    return distance, sign


def _paired(a, b):
    """Mean of ``a - b`` over the episodes where both are defined, its 95 % interval, and their count."""
    from spikejax.stats import mean_interval

    both = np.isfinite(a) & np.isfinite(b)
    if not both.any():
        return math.nan, math.nan, math.nan, 0
    mean, low, high = mean_interval(a[both] - b[both])
    return mean, low, high, int(both.sum())


def compare_modes(out_dir, episodes: int = 16, seconds: float = 30.0, situation: str = "standing-right",
                  progress: bool = True, modes=tuple(MODES)) -> list[list]:  # fmt: skip
    """Run the same episodes in each mode of ``modes`` (see the module docstring); write ``snake_pipe_modes.csv``.

    Args:
        out_dir: the directory for ``snake_pipe_modes.csv`` and ``snake_pipe_modes.png`` (None: write nothing).
        episodes: episodes per mode (the same in every mode).
        seconds: simulated seconds per episode.
        situation: one of `robots.snake.pipes.SITUATIONS`.
        progress: show progress bars.
        modes: some of `MODES`; the paired columns compare each with ``sync`` when it is among them.

    Returns:
        One row per mode, the columns of `MODE_HEADER`.
    """
    from robots.snake import pipe_controller as pc
    from robots.snake import pipes
    from robots.snake.reproduce_pipe import HEADER, summarize

    if isinstance(episodes, bool) or not isinstance(episodes, int) or episodes < 1:
        raise UserError(f"episodes must be a whole number >= 1, got {episodes!r}")
    if not seconds > 0:
        raise UserError(f"seconds must be positive, got {seconds}")
    modes = tuple(modes)
    bad = [m for m in modes if m not in MODES]
    if bad or not modes:
        raise UserError(f"modes must be some of {', '.join(MODES)}, got {', '.join(map(str, modes)) or 'none'}")
    if situation not in pipes.SITUATIONS:
        raise UserError(f"situation must be one of {', '.join(pipes.SITUATIONS)}, not {situation!r}")
    lying = pipes.SITUATIONS[situation][0] == pipes.LYING
    keys = jax.random.split(jax.random.key(0), episodes)
    lost = int(pc.ControllerParams().lost_slots)
    results = {}
    for mode in modes:
        env = env_for(mode, situation)
        slots = max(1, int(round(seconds / env.dt / env.slot_steps)))
        res, wall, compile_s = _episodes(env, keys, slots, progress, f"{situation}, {mode}")
        row = dict(zip(HEADER, summarize(mode, "bang-bang", res, lying, env.dt, env.slot_steps, lost)))
        steps = slots * env.slot_steps
        det = env.tracker.detector
        row.update(
            mode=mode,
            grids="line" + (" + circle" if det.circle is not None else ""),
            dvs=env.dvs,
            situation=situation,
            seconds=steps * env.dt,
            events_per_step=float(res["events"].mean()),
            env_steps_per_s=episodes * steps / wall,
            compile_s=compile_s,
        )
        results[mode] = (row, *_per_episode(res, env.slot_steps), res["success"])
    rows = []
    for mode, (row, distance, sign, success) in results.items():
        if "sync" in results and mode != "sync":
            _, d0, s0, ok0 = results["sync"]
            dd, dlo, dhi, dn = _paired(distance, d0)
            sd, slo, shi, sn = _paired(sign, s0)
            row.update(
                vs_sync_only_this_succeeded=int((success & ~ok0).sum()),
                vs_sync_only_sync_succeeded=int((ok0 & ~success).sum()),
                vs_sync_distance_error_diff_m=dd,
                vs_sync_distance_error_diff_low=dlo,
                vs_sync_distance_error_diff_high=dhi,
                vs_sync_paired_episodes_distance=dn,
                vs_sync_sign_accuracy_diff=sd,
                vs_sync_sign_accuracy_diff_low=slo,
                vs_sync_sign_accuracy_diff_high=shi,
                vs_sync_paired_episodes_sign=sn,
            )
        rows.append([row.get(c, "") for c in MODE_HEADER])
    if out_dir is not None:
        out_dir = Path(out_dir)
        out_dir.mkdir(parents=True, exist_ok=True)
        write_modes_csv(out_dir / "snake_pipe_modes.csv", rows)
        _plot(out_dir / "snake_pipe_modes.png", rows)
    return rows


def write_modes_csv(path, rows: list[list]) -> Path:
    """`compare_modes`' rows as ``snake_pipe_modes.csv`` (columns `MODE_HEADER`), written atomically."""
    path = Path(path)
    write_csv(path, MODE_HEADER, rows)
    return path


def _plot(path: Path, rows: list[list]) -> None:
    from matplotlib.figure import Figure

    col = {c: i for i, c in enumerate(MODE_HEADER)}
    names = [r[col["mode"]] for r in rows]
    fig = Figure(figsize=(11, 3.2))
    panels = [
        ("success_rate", "success", ("wilson_low", "wilson_high")),
        ("mean_distance_error_m", "|d_est - depth| at detections, m", None),
        ("sign_accuracy", "steering-sign accuracy", None),
        ("env_steps_per_s", "env-steps/s (compile apart)", None),
    ]
    for i, (key, title, bounds) in enumerate(panels):
        ax = fig.add_subplot(1, len(panels), i + 1)
        values = np.array([float(r[col[key]]) for r in rows])
        err = None
        if bounds:
            low = np.array([float(r[col[bounds[0]]]) for r in rows])
            high = np.array([float(r[col[bounds[1]]]) for r in rows])
            err = np.stack([values - low, high - values])
        ax.bar(names, values, yerr=err, capsize=4, color=["tab:blue", "tab:orange", "tab:gray"][: len(names)])
        ax.set_title(title, fontsize=9)
        ax.tick_params(labelsize=8)
    situation, n = rows[0][col["situation"]], rows[0][col["episodes"]]
    fig.suptitle(f"sync against async grids, the same {n} episodes ({situation}; bars: 95 % Wilson)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
