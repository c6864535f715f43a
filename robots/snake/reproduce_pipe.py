"""``spikejax reproduce snake-pipe``: the closed pipe loop over many placements (the pipe-tracking paper's Sec. 3.2).

The paper ran one trajectory per situation; this runs ``--episodes`` per
situation (standing or lying pipe, left or right: `robots.snake.pipes.SITUATIONS`,
placements from `robots.snake.pipes.sample`), or, with ``--scene FILE``, that
scene in every episode (one row per pipe; the episodes differ in the key
only, which a scene file's fixed placement does not use: they repeat the
same trial, a check of determinism more than a sample). Each episode is
`robots.snake.pipe_env.PipeEnv` driven by the spiking bang-bang controller
(`robots.snake.pipe_controller.bang_bang`) for ``--seconds``; standing pipes
with the line grid, lying ones with the line and the reduced circle grid
(`robots.snake.pipe_env.default_tracker`).

Writes, in ``--out DIR``:

- ``snake_pipe.csv``, one row per situation (or scene pipe): episodes,
  successes with the 95 % Wilson interval (standing: the head within 0.3 m of
  the surface; lying: the head in the bore), approaches (the head within 0.3 m
  of the pipe or its entry), mean time to success, mean |Eq. (8) distance -
  true depth| at the detections, detection rate (slots with a detection among
  slots with the pipe in view), steering-sign accuracy (the sign of Alg. 3's
  offset against the true offset from the central line, where that is at
  least 0.15 m), and every failure with one label (`LABELS`, first that
  applies): ``never_detected``; ``missed_bore`` (a lying pipe approached,
  not entered); ``wrong_side`` (most of the episode's steering against the
  true offset's side); ``overshoot`` (the pipe ended behind the camera);
  ``lost`` (no detection in the last ``lost_slots`` slots);
  ``timeout`` (still approaching).
- ``snake_pipe_trajectories.png``: the head's path of every episode, per
  situation, with the pipes drawn at their places.

Defaults: 256 episodes per situation of 90 s each (ACCEPTANCE.md's standing
episode; at about 0.1 m/s the farthest starts, 4 m, need 40 s straight). The
full run has not been timed on this machine; the lying situations, with the
circle grid, run at about 66 env-steps/s (docs/BENCHMARKS.md). A measured
small run is in docs/BENCHMARKS.md, "Snake pipe loop".
"""

from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from robots.common import write_csv
from spikejax.commands import Command, add_common, output_directory
from spikejax.errors import UserError

# robots.snake.pipes and the env (MuJoCo) are imported by the functions that run the snake:
# `spikejax reproduce` imports this module to list its flags beside the others'.

LABELS = ("never_detected", "missed_bore", "wrong_side", "overshoot", "lost", "timeout")
HEADER = [
    "situation",
    "episodes",
    "successes",
    "success_rate",
    "wilson_low",
    "wilson_high",
    "approached",
    "mean_time_to_success_s",
    "mean_distance_error_m",
    "detection_rate",
    "sign_accuracy",
    *(f"fail_{label}" for label in LABELS),
]
CHUNK = 64  # episodes per compiled batch


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


def _episodes(env, scenes, keys, slots, params, progress: bool, desc: str):
    from tqdm import tqdm

    from robots.snake import pipe_controller as pc
    from robots.snake import pipe_env

    run = jax.jit(jax.vmap(lambda k, s: pipe_env.rollout(env, pc.bang_bang, params, k, slots, s)))
    keep = ("detected", "d_est", "depth", "offset_est", "offset_true", "in_view")
    parts = []
    n = keys.shape[0]
    for lo in tqdm(range(0, n, CHUNK), desc=desc, disable=not progress):
        idx = np.arange(lo, min(lo + CHUNK, n))
        pad = np.concatenate([idx, np.full(CHUNK - idx.size, idx[-1])]) if n > CHUNK else idx
        record, final = run(keys[pad], jax.tree.map(lambda a: a[pad], scenes))
        out = {k: np.asarray(record["metrics"][k])[: idx.size] for k in keep}
        out["head"] = np.asarray(record["head"])[: idx.size]
        out["action"] = np.asarray(record["action"])[: idx.size]
        for k in ("success", "reached"):
            out[k] = np.asarray(final.metrics[k])[: idx.size] > 0
        out["success_step"] = np.asarray(final.info["success_step"])[: idx.size]
        parts.append(out)
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


def summarize(name, res, lying: bool, dt: float, slot_steps: int, lost_slots: int) -> list:
    """One CSV row from an `_episodes` result (host arrays)."""
    from spikejax.stats import wilson_interval

    n = res["success"].shape[0]
    k = int(res["success"].sum())
    low, high = wilson_interval(k, n)
    det = res["detected"] > 0
    # Outcomes are latched, but the record runs on after done: only the steps up to it count.
    steps = res["detected"].shape[1]
    end = np.where(res["success_step"] > 0, res["success_step"], steps)
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
    sign_right = agree / np.maximum(steer.sum(1), 1)
    last = np.array([np.flatnonzero(d[:e])[-1] if d[:e].any() else -1 for d, e in zip(det, end)])
    last_seen_slots = np.where(last >= 0, (end - 1 - last) // slot_steps, 10**9)
    depth_end = res["depth"][np.arange(n), end - 1]
    labels = label_failures(
        res["success"],
        res["reached"],
        np.full(n, lying),
        used.sum(1),
        sign_right,
        depth_end,
        last_seen_slots,
        lost_slots,
    )
    time = res["success_step"][res["success"]] * dt
    rate = lambda a: float(np.mean(a)) if np.size(a) else float("nan")  # noqa: E731
    return [
        name,
        n,
        k,
        k / n,
        float(low),
        float(high),
        int(res["reached"].sum()),
        rate(time),
        rate(err),
        float(used.sum() / max(view.sum(), 1)),
        rate(sign_ok),
        *(int((labels == i).sum()) for i in range(len(LABELS))),
    ]


def _plot(path: Path, results) -> None:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(4 * len(results), 4))
    for i, (name, res, scene) in enumerate(results):
        ax = fig.add_subplot(1, len(results), i + 1)
        for head, ok in zip(res["head"], res["success"]):
            ax.plot(head[:, 0], head[:, 1], lw=0.6, color="tab:green" if ok else "tab:red", alpha=0.6)
        xy = np.asarray(scene.xy).reshape(-1, 2)
        valid = np.asarray(scene.valid).reshape(-1)
        ax.scatter(xy[valid, 0], xy[valid, 1], s=12, color="k", label="pipes")
        ax.set_title(f"{name}: {int(res['success'].sum())}/{res['success'].shape[0]}")
        ax.set_aspect("equal")
        ax.set_xlabel("x, m")
        ax.set_ylabel("y, m")
    fig.suptitle("Head paths (green: success, red: failure); the snake starts at the origin looking along +x")
    fig.savefig(path, dpi=110)


def run(out: Path, episodes: int, seconds: float, scene_file=None, progress: bool = True) -> list[list]:
    """Everything in the module docstring."""
    from robots.snake import pipe_controller as pc
    from robots.snake import pipe_env, pipes

    if episodes < 1:
        raise UserError(f"--episodes must be at least 1, got {episodes}")
    if not seconds > 0:
        raise UserError(f"--seconds must be positive, got {seconds}")
    machine = pc.ControllerParams()
    rows, results = [], []
    keys = jax.random.split(jax.random.key(0), episodes)
    if scene_file is not None:
        scene = pipes.load_scene(scene_file)
        scene = pipes.load_scene(scene_file, capacity=int(np.asarray(scene.valid).sum()))  # no empty slots to draw
        for k, slot in enumerate(np.flatnonzero(np.asarray(scene.valid))):
            # Each pipe in turn is the target (slot 0); the others stay in the scene.
            order = np.array([slot] + [j for j in range(scene.capacity) if j != slot])
            target = scene._replace(**{f: getattr(scene, f)[order] for f in scene._fields if f != "start"})
            lying = int(np.asarray(scene.kind)[slot]) == pipes.LYING
            env = pipe_env.PipeEnv(scene=target, tracker=pipe_env.default_tracker(circle=bool(lying)))
            slots = max(1, int(round(seconds / env.dt / env.slot_steps)))
            batch = jax.tree.map(lambda a: jnp.broadcast_to(a, (episodes, *a.shape)), target)
            res = _episodes(env, batch, keys, slots, machine, progress, f"snake-pipe pipe {k + 1}")
            name = f"pipe {k + 1} ({'lying' if lying else 'standing'})"
            rows.append(summarize(name, res, bool(lying), env.dt, env.slot_steps, int(machine.lost_slots)))
            results.append((name, res, target))
    else:
        for name, (kind, _) in pipes.SITUATIONS.items():
            lying = kind == pipes.LYING
            env = pipe_env.PipeEnv(situation=name, tracker=pipe_env.default_tracker(circle=lying))
            slots = max(1, int(round(seconds / env.dt / env.slot_steps)))
            scenes = jax.vmap(lambda k, n=name: env.sample_scene(k, n))(keys)
            res = _episodes(env, scenes, keys, slots, machine, progress, f"snake-pipe {name}")
            rows.append(summarize(name, res, lying, env.dt, env.slot_steps, int(machine.lost_slots)))
            results.append((name, res, scenes))
    write_csv(out / "snake_pipe.csv", HEADER, rows)
    _plot(out / "snake_pipe_trajectories.png", results)
    return rows


def _add_arguments(parser) -> None:
    add_common(parser)
    parser.add_argument("--episodes", type=int, default=256, help="episodes per situation (default 256)")
    parser.add_argument("--seconds", type=float, default=90.0, help="simulated seconds per episode (default 90)")
    parser.add_argument("--scene", default=None, help="a scene file (TOML) used by every episode")


def reproduce_command_run(
    *, out: str | Path, episodes: int = 256, seconds: float = 90.0, scene=None, no_progress: bool = False
) -> int:
    """``spikejax reproduce snake-pipe --out DIR [--episodes N] [--seconds S] [--scene FILE]``."""
    with output_directory(out, command="reproduce snake-pipe") as out:
        rows = run(out, episodes, seconds, scene, progress=not no_progress)
        for r in rows:
            print(f"{r[0]:<22} {r[2]}/{r[1]} reached, 95% CI [{r[4]:.2f}, {r[5]:.2f}]")
        print(f"wrote {out}/snake_pipe.csv, snake_pipe_trajectories.png")
        return 0


command = Command(
    help="the snake's closed pipe loop over many placements: success with Wilson intervals, failure labels",
    add_arguments=_add_arguments,
    run=reproduce_command_run,
)
