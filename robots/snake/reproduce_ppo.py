"""``spikejax train ppo`` and ``spikejax evaluate ppo``: Brax's PPO on the snake's tracking task, saved and tested.

``train ppo snake-track --out DIR`` runs `robots.snake.ppo.train` and writes, in ``DIR``:

* ``policy.params``: the policy in Brax's parameter format (a pickle of
  ``(normalizer, policy, value)``, `brax.io.model.load_params` reads it),
  rewritten after every tenth of the training, so a killed run keeps its
  latest policy; ``policy.json``: the task, observation, seed, backend, the
  `robots.snake.ppo.PPOSettings` and the env steps done;
* ``ppo_training.csv`` and ``ppo_training.png``: the training curve, reward
  per step, mean ``|a_head|``, episode length and failures a minute against
  env steps (Brax's training metrics of the episodes that ended in each
  tenth).

A run started again in the same ``DIR`` goes on from its saved policy for the
steps still missing (the optimiser's moments start afresh, so the result
differs from an uninterrupted run's); a finished one is left as it is.

``evaluate ppo --policy DIR [DIR ...] --track NAME|FILE.csv --out DIR`` tests
saved policies (deterministic actions, the mode of Brax's tanh-normal) on one
pass of a track with `robots.snake.training.run_test`, the spiking networks'
test, and writes ``snake_ppo.csv`` with the columns of ``snake_rstdp.csv``
(`robots.snake.reproduce_rstdp.HEADER`; one row per observation variant and
metric window, intervals over the policies given, each a seed).
"""

from __future__ import annotations

import dataclasses
import json
import pickle
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from robots.snake import ppo, tracks, training
from robots.snake.physics import BACKENDS
from spikejax.benchmarking import write_csv
from spikejax.commands import Command, add_common, count, count_or_zero, output_directory
from spikejax.errors import UserError

__all__ = ["train_command", "evaluate_command", "CURVE_HEADER", "load_policy", "train_one"]

CURVE_HEADER = [
    "env_steps",
    "wall_s",
    "reward_per_step",
    "abs_head_deg",
    "episode_length_s",
    "failed_share",
    "failures_per_min",
]


def load_policy(path: Path) -> tuple[dict, tuple]:
    """The description and parameters of a `train ppo` output directory; a one-line error if it is not one."""
    from brax.io import model

    path = Path(path)
    try:
        meta = json.loads((path / "policy.json").read_text())
        params = model.load_params(str(path / "policy.params"))
    except (OSError, ValueError, EOFError, pickle.UnpicklingError) as e:
        raise UserError(f"{path}: not a saved PPO policy ({e.__class__.__name__}: {e})") from None
    if meta.get("task") not in ppo.TASKS or meta.get("observation") not in ppo.OBSERVATIONS:
        raise UserError(f"{path}: policy.json names no known task and observation")
    return meta, params


def _save_policy(out: Path, meta: dict, params) -> None:
    from brax.io import model

    tmp = out / "policy.params.tmp"
    model.save_params(str(tmp), jax.device_get(params))
    tmp.replace(out / "policy.params")
    tmp = out / "policy.json.tmp"
    tmp.write_text(json.dumps(meta, indent=1))
    tmp.replace(out / "policy.json")


def _curve_row(env_steps: int, wall: float, metrics: dict, dt: float) -> dict | None:
    length = float(metrics.get("episode/length", 0.0))
    if length <= 0:
        return None
    failed = float(metrics["episode/failed"])
    return {
        "env_steps": int(env_steps),
        "wall_s": round(wall, 2),
        "reward_per_step": round(float(metrics["episode/sum_reward"]) / length, 5),
        "abs_head_deg": round(float(np.degrees(float(metrics["episode/abs_head"]) / length)), 4),
        "episode_length_s": round(length * dt, 3),
        "failed_share": round(failed, 4),
        "failures_per_min": round(ppo.failures_per_minute(failed, length, dt), 4),
    }


def _read_curve(path: Path) -> list[dict]:
    import csv

    if not path.exists():
        return []
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def _plot_curve(path: Path, rows: list[dict], title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    x = np.array([float(r["env_steps"]) for r in rows])
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.2))
    for ax, key, label in zip(
        axes,
        ("reward_per_step", "abs_head_deg", "failures_per_min"),
        ("reward per step", "mean |a_head| (deg)", "failures / min"),
    ):
        ax.plot(x, [float(r[key]) for r in rows], "o-", ms=3)
        ax.set_xlabel("env steps")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def train_one(
    out: Path,
    *,
    task: str,
    observation: str,
    steps: int,
    seed: int,
    backend: str = "mujoco",
    settings: ppo.PPOSettings = ppo.PPOSettings(),
    evals: int = 10,
    progress: bool = True,
) -> dict:
    """Train (or go on training) one policy into ``out``; returns its ``policy.json`` description."""
    the_task = ppo.make_task(task, observation, backend=backend)
    evals = max(1, min(int(evals), -(-int(steps) // settings.steps_per_update)))  # no more tenths than updates
    meta = {
        "task": task,
        "observation": observation,
        "seed": int(seed),
        "backend": backend,
        "settings": dataclasses.asdict(settings),
        "target_steps": int(steps),
        "env_steps": 0,
    }
    restore, done_steps = None, 0
    if (out / "policy.json").exists():
        old, old_params = load_policy(out)
        same = {k: old.get(k) for k in ("task", "observation", "seed", "settings")}
        if same != {k: meta[k] for k in same}:
            raise UserError(
                f"{out} holds another training ({old['observation']}, seed {old['seed']}); use another --out"
            )
        done_steps = int(old["env_steps"])
        if done_steps >= steps:
            return old
        restore = old_params if done_steps > 0 else None
    curve = [r for r in _read_curve(out / "ppo_training.csv") if int(r["env_steps"]) <= done_steps]
    t0, dt = time.time(), the_task.env.dt
    wall0 = float(curve[-1]["wall_s"]) if curve else 0.0

    def on_params(n, params):
        if n > 0 or restore is None:
            _save_policy(out, {**meta, "env_steps": done_steps + int(n)}, params)

    shown = [done_steps]

    def on_metrics(n, metrics):
        row = _curve_row(done_steps + n, wall0 + time.time() - t0, metrics, dt)
        if row is not None:
            curve.append(row)
            write_csv(out / "ppo_training.csv", curve, CURVE_HEADER)
        if progress and row is not None and row["env_steps"] >= shown[0] + steps / 10:  # about ten lines
            shown[0] = row["env_steps"]
            print(
                f"  {row['env_steps']:>10,} steps  reward/step {row['reward_per_step']:.3f}  "
                f"|a_head| {row['abs_head_deg']:.1f} deg  episodes {row['episode_length_s']:.0f} s  "
                f"failures/min {row['failures_per_min']:.2f}  ({row['wall_s']:.0f} s)",
                flush=True,
            )

    ppo.train(
        the_task,
        steps - done_steps,
        seed=seed,
        settings=settings,
        evals=evals,
        progress=on_metrics,
        on_params=on_params,
        restore=restore,
    )
    meta = json.loads((out / "policy.json").read_text())
    if curve:
        _plot_curve(out / "ppo_training.png", curve, f"PPO on {task} ({observation} observation), seed {seed}")
    return meta


def _add_train_arguments(parser) -> None:
    add_common(parser)
    parser.add_argument("task", choices=ppo.TASKS, help="the task (the snake R-STDP paper's: the 8, mirrored)")
    parser.add_argument(
        "--observation",
        choices=ppo.OBSERVATIONS,
        default="grid",
        help="grid: the DVS grid rates and joint angles the spiking nets see (default); angles: the true target angles",
    )
    parser.add_argument("--steps", type=count, default=1_000_000, help="env steps (default 1,000,000)")
    parser.add_argument("--seed", type=count_or_zero, default=0, help="the trainer's seed (default 0)")
    parser.add_argument("--backend", choices=BACKENDS, default="mujoco", help="physics backend (default mujoco)")
    parser.add_argument("--envs", type=count, default=ppo.PPOSettings.num_envs, help="parallel envs (default 64)")


def run_train(*, out, task, observation, steps, seed, backend, envs, no_progress) -> int:
    """``spikejax train ppo TASK --out DIR``."""
    defaults = ppo.PPOSettings()
    settings = dataclasses.replace(defaults, num_envs=envs, batch_size=max(envs, defaults.batch_size))
    with output_directory(out, command="train ppo") as out:
        meta = train_one(
            out,
            task=task,
            observation=observation,
            steps=steps,
            seed=seed,
            backend=backend,
            settings=settings,
            progress=not no_progress,
        )
        print(f"trained {meta['env_steps']:,} env steps; wrote {out}/policy.params, ppo_training.csv, .png")
    return 0


def evaluate_rows(policies: list[Path], track, name: str, steps: int | None) -> list[list]:
    """Rows of ``snake_ppo.csv``: each observation variant's saved policies on one pass of ``track``."""
    from robots.snake.reproduce_rstdp import _windows, test_rows

    loaded = [load_policy(p) for p in policies]
    rows = []
    for observation in ppo.OBSERVATIONS:
        group = [(m, p) for m, p in loaded if m["observation"] == observation]
        if not group:
            continue
        settings = ppo.PPOSettings(**group[0][0]["settings"])
        task = ppo.make_task(group[0][0]["task"], observation)
        ctrl = ppo.policy_controller(task, settings)
        stacked = jax.tree.map(lambda *xs: jnp.stack([jnp.asarray(x) for x in xs]), *[p[:2] for _, p in group])
        seeds = np.array([m["seed"] for m, _ in group])
        trace = training.run_test(ctrl, None, stacked, track, steps, seeds=seeds)
        env = training.env_for(track)
        for row in test_rows(f"ppo-{observation}", name, trace, env.dt, _windows(env)):
            rows.append(row[:-1] + ["PPO baseline (no paper figure)"])
    return rows


def _add_evaluate_arguments(parser) -> None:
    add_common(parser)
    parser.add_argument("--policy", nargs="+", required=True, help="train ppo output directories (one a seed)")
    parser.add_argument(
        "--track", required=True, help=f"a track name ({', '.join(tracks.TRACKS)}) or a CSV of x, y waypoints"
    )
    parser.add_argument("--steps", type=count, default=None, help="control steps (default: one pass of the track)")


def run_evaluate(*, out, policy, track, steps, no_progress) -> int:
    """``spikejax evaluate ppo --policy DIR ... --track NAME|FILE --out DIR``."""
    from robots.snake.reproduce_rstdp import HEADER, _print

    if track in tracks.TRACKS:
        the_track, name = track, track
    else:
        the_track, name = tracks.load_waypoints(track), Path(track).name
    paths = [Path(p) for p in policy]
    for p in paths:
        load_policy(p)
    with output_directory(out, command="evaluate ppo") as out:
        rows = evaluate_rows(paths, the_track, name, steps)
        write_csv(out / "snake_ppo.csv", [dict(zip(HEADER, r)) for r in rows], HEADER)
        _print(rows)
        print(f"wrote {out}/snake_ppo.csv")
    return 0


train_command = Command(
    help="train Brax's PPO on the snake's tracking task (the spiking nets' inputs, or the true angles)",
    add_arguments=_add_train_arguments,
    run=run_train,
)
evaluate_command = Command(
    help="test saved PPO policies of the snake on any track, with the spiking networks' metrics",
    add_arguments=_add_evaluate_arguments,
    run=run_evaluate,
)
