"""``spikejax train ppo`` and ``spikejax evaluate ppo``: Brax's PPO on the snake's tracking task, saved and tested.

``train ppo snake-track --out DIR`` (or ``snake-pipe``, the pipe paper's
approach in ``--situation``) runs `robots.snake.ppo.train` and writes, in ``DIR``:

* ``policy.params``: the policy in Brax's parameter format (a pickle of
  ``(normalizer, policy, value)``, `brax.io.model.load_params` reads it),
  rewritten after every tenth of the training, so a killed run keeps its
  latest policy; ``policy.json``: the task, observation, seed, backend, the
  `robots.snake.ppo.PPOSettings` and the env steps done;
* ``ppo_training.csv`` and ``ppo_training.png``: the training curve, reward
  per step, episode length, and mean ``|a_head|`` and failures a minute
  (tracking) or the share of episodes ending in success (pipe), against env
  steps (Brax's training metrics of the episodes that ended in each update).

A run started again in the same ``DIR`` goes on from its saved policy for the
steps still missing (the optimiser's moments start afresh, so the result
differs from an uninterrupted run's); a finished one is left as it is.

``evaluate ppo --policy DIR [DIR ...] --track NAME|FILE.csv --out DIR`` tests
saved policies (deterministic actions, the mode of Brax's tanh-normal) on one
pass of a track with `robots.snake.training.run_test`, the spiking networks'
test, and writes ``snake_ppo.csv`` with the columns of ``snake_rstdp.csv``
(`robots.snake.reproduce_rstdp.HEADER`; one row per observation variant and
metric window, intervals over the policies given, each a seed). For
``snake-pipe`` policies it runs ``--episodes`` placements of ``--situation``
instead and writes ``snake_ppo_pipe.csv`` (the share of successes with a
Wilson interval, collisions, the mean time to success).
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
    "episode_length_s",
    "abs_head_deg",
    "failed_share",
    "failures_per_min",
    "success_share",
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
    if meta.get("task") not in ppo.TASKS or meta.get("observation") not in ppo.OBSERVATIONS + ppo.PIPE_OBSERVATIONS:
        raise UserError(f"{path}: policy.json names no known task and observation")
    return meta, params


def _stacked(params: list[tuple]) -> tuple:
    """The ``(normalizer, policy)`` parts of several policies' parameters, stacked along a new leading axis."""
    return jax.tree.map(lambda *xs: jnp.stack([jnp.asarray(x) for x in xs]), *[p[:2] for p in params])


def _save_policy(out: Path, meta: dict, params) -> None:
    from brax.io import model

    tmp = out / "policy.params.tmp"
    model.save_params(str(tmp), jax.device_get(params))
    tmp.replace(out / "policy.params")
    tmp = out / "policy.json.tmp"
    tmp.write_text(json.dumps(meta, indent=1))
    tmp.replace(out / "policy.json")


def _curve_row(env_steps: int, wall: float, metrics: dict, dt: float) -> dict | None:
    """One row of the training curve from Brax's episode metrics (tracking: failures; pipe: successes)."""
    length = float(metrics.get("episode/length", 0.0))
    if length <= 0:
        return None
    row = {
        "env_steps": int(env_steps),
        "wall_s": round(wall, 2),
        "reward_per_step": round(float(metrics["episode/sum_reward"]) / length, 5),
        "episode_length_s": round(length * dt, 3),
    }
    if "episode/failed" in metrics:
        failed = float(metrics["episode/failed"])
        row["abs_head_deg"] = round(float(np.degrees(float(metrics["episode/abs_head"]) / length)), 4)
        row["failed_share"] = round(failed, 4)
        row["failures_per_min"] = round(ppo.failures_per_minute(failed, length, dt), 4)
    if "episode/succeeded" in metrics:
        row["success_share"] = round(float(metrics["episode/succeeded"]), 4)
    return row


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
    panels = [
        (k, label)
        for k, label in (
            ("reward_per_step", "reward per step"),
            ("abs_head_deg", "mean |a_head| (deg)"),
            ("failures_per_min", "failures / min"),
            ("success_share", "episodes ending in success"),
            ("episode_length_s", "episode length (s)"),
        )
        if rows[0].get(k) not in (None, "")
    ][:3]
    fig, axes = plt.subplots(1, len(panels), figsize=(4 * len(panels), 3.2))
    for ax, (key, label) in zip(np.atleast_1d(axes), panels):
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
    situation: str = "standing-right",
    settings: ppo.PPOSettings = ppo.PPOSettings(),
    evals: int = 10,
    progress: bool = True,
) -> dict:
    """Train (or go on training) one policy into ``out``; returns its ``policy.json`` description."""
    the_task = ppo.make_task(task, observation, backend=backend, situation=situation)
    evals = max(1, min(int(evals), -(-int(steps) // settings.steps_per_update)))  # no more tenths than updates
    meta = {
        "task": task,
        "observation": observation,
        "seed": int(seed),
        "backend": backend,
        "situation": situation if task == "snake-pipe" else None,
        "settings": dataclasses.asdict(settings),
        "target_steps": int(steps),
        "env_steps": 0,
    }
    restore, done_steps = None, 0
    if (out / "policy.json").exists():
        old, old_params = load_policy(out)
        same = {k: old.get(k) for k in ("task", "observation", "seed", "situation", "settings")}
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
            task_part = (
                f"|a_head| {row['abs_head_deg']:.1f} deg  failures/min {row['failures_per_min']:.2f}"
                if "abs_head_deg" in row
                else f"success {row['success_share']:.2f}"
            )
            print(
                f"  {row['env_steps']:>10,} steps  reward/step {row['reward_per_step']:.3f}  "
                f"episodes {row['episode_length_s']:.0f} s  {task_part}  ({row['wall_s']:.0f} s)",
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
    parser.add_argument(
        "task", choices=ppo.TASKS, help="snake-track (the R-STDP paper's 8, mirrored) or snake-pipe (the pipe paper's)"
    )
    parser.add_argument(
        "--observation",
        choices=ppo.OBSERVATIONS + ppo.PIPE_OBSERVATIONS,
        default=None,
        help="snake-track: grid (the DVS grid rates and joint angles the spiking nets see, default) or angles (the "
        "true target angles); snake-pipe: detector (Alg. 3's estimates, default) or truth",
    )
    parser.add_argument("--situation", default="standing-right", help="snake-pipe's situation (default standing-right)")
    parser.add_argument("--steps", type=count, default=1_000_000, help="env steps (default 1,000,000)")
    parser.add_argument("--seed", type=count_or_zero, default=0, help="the trainer's seed (default 0)")
    parser.add_argument("--backend", choices=BACKENDS, default="mujoco", help="physics backend (default mujoco)")
    parser.add_argument("--envs", type=count, default=ppo.PPOSettings.num_envs, help="parallel envs (default 64)")


def run_train(*, out, task, observation, situation, steps, seed, backend, envs, no_progress) -> int:
    """``spikejax train ppo TASK --out DIR``."""
    from robots.snake.pipes import SITUATIONS

    if observation is None:
        observation = "grid" if task == "snake-track" else "detector"
    if situation not in SITUATIONS:
        raise UserError(f"--situation must be one of {', '.join(SITUATIONS)}, not {situation!r}")
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
            situation=situation,
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
        stacked = _stacked([p for _, p in group])
        seeds = np.array([m["seed"] for m, _ in group])
        trace = training.run_test(ctrl, None, stacked, track, steps, seeds=seeds)
        env = training.env_for(track)
        for row in test_rows(f"ppo-{observation}", name, trace, env.dt, _windows(env)):
            rows.append(row[:-1] + ["PPO baseline (no paper figure)"])
    return rows


PIPE_HEADER = [
    "policy",
    "situation",
    "seeds",
    "episodes",
    "success",
    "success_ci_low",
    "success_ci_high",
    "collided",
    "mean_time_to_success_s",
]


def pipe_rows(policies: list[Path], situation: str, episodes: int) -> list[list]:
    """Rows of ``snake_ppo_pipe.csv``: each variant's policies over ``episodes`` placements of ``situation``.

    Placement ``i`` is `robots.snake.pipe_env.PipeEnv`'s sample from
    ``jax.random.PRNGKey(i)``, the same for every policy; an episode runs the
    env's ``max_steps`` with deterministic actions and counts as a success if
    the env's latched outcome is, at any step.
    """
    from brax.training.agents.ppo import networks as ppo_networks

    from spikejax.stats import wilson_interval

    loaded = [load_policy(p) for p in policies]
    rows = []
    for observation in ppo.PIPE_OBSERVATIONS:
        group = [(m, p) for m, p in loaded if m["observation"] == observation and m["task"] == "snake-pipe"]
        if not group:
            continue
        settings = ppo.PPOSettings(**group[0][0]["settings"])
        task = ppo.make_task("snake-pipe", observation, situation=situation)
        make_policy = ppo_networks.make_inference_fn(ppo.make_networks(task, settings))
        stacked = _stacked([p for _, p in group])

        def episode(params, key):
            policy = make_policy(params, deterministic=True)

            def body(state, _):
                action, _ = policy(state.obs, key)
                return task.step(state, action), None

            state, _ = jax.lax.scan(body, task.reset(key), None, length=task.env.max_steps)
            return state.info["success"], state.info["collided"], state.info["success_step"]

        keys = jnp.stack([jax.random.PRNGKey(i) for i in range(episodes)])
        run = jax.jit(jax.vmap(lambda p: jax.vmap(lambda k: episode(p, k))(keys)))
        success, collided, step = (np.asarray(x) for x in run(stacked))
        n, wins = success.size, int(success.sum())
        lo, hi = wilson_interval(wins, n)
        times = step[success] * task.env.dt
        rows.append(
            [
                f"ppo-{observation}",
                situation,
                len(group),
                episodes,
                round(wins / n, 4),
                round(float(lo), 4),
                round(float(hi), 4),
                round(float(collided.mean()), 4),
                round(float(times.mean()), 2) if wins else "",
            ]
        )
    return rows


def _add_evaluate_arguments(parser) -> None:
    add_common(parser)
    parser.add_argument("--policy", nargs="+", required=True, help="train ppo output directories (one a seed)")
    parser.add_argument(
        "--track", help=f"snake-track policies: a track name ({', '.join(tracks.TRACKS)}) or a CSV of x, y waypoints"
    )
    parser.add_argument("--steps", type=count, default=None, help="control steps (default: one pass of the track)")
    parser.add_argument("--situation", default=None, help="snake-pipe policies: the situation (default: trained)")
    parser.add_argument("--episodes", type=count, default=64, help="snake-pipe policies: placements (default 64)")


def run_evaluate(*, out, policy, track, steps, situation, episodes, no_progress) -> int:
    """``spikejax evaluate ppo --policy DIR ... (--track NAME|FILE | --situation S) --out DIR``."""
    from robots.snake.reproduce_rstdp import HEADER, _print

    paths = [Path(p) for p in policy]
    metas = [load_policy(p)[0] for p in paths]
    if {m["task"] for m in metas} == {"snake-pipe"}:
        from robots.snake.pipes import SITUATIONS

        situation = situation or metas[0]["situation"]
        if situation not in SITUATIONS:
            raise UserError(f"--situation must be one of {', '.join(SITUATIONS)}, not {situation!r}")
        with output_directory(out, command="evaluate ppo") as out:
            rows = pipe_rows(paths, situation, episodes)
            write_csv(out / "snake_ppo_pipe.csv", [dict(zip(PIPE_HEADER, r)) for r in rows], PIPE_HEADER)
            for r in rows:
                print(f"{r[0]:<13} {r[1]}: success {r[4]:.2f} [{r[5]:.2f}, {r[6]:.2f}] over {r[3]} placements")
            print(f"wrote {out}/snake_ppo_pipe.csv")
        return 0
    if len({m["task"] for m in metas}) > 1:
        raise UserError("--policy: give policies of one task (snake-track or snake-pipe) at a time")
    if track is None:
        raise UserError("--track is needed for snake-track policies")
    the_track, name = tracks.from_argument(track)
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
