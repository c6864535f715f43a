"""``spikejax reproduce snake-baselines``: the spiking networks beside a scripted controller and Brax's PPO.

The same test (`robots.snake.training.run_test`: one pass of each test track,
ladder, zigzag and their mirror images, a failure restarting the pass) and the
same metrics (`robots.snake.metrics`, the columns of ``snake_rstdp.csv``) for:

* ``scripted``: `robots.snake.steering`, proportional steering on the true
  body-to-target angle (deterministic: one run);
* ``ppo-grid`` and ``ppo-angles``: Brax's PPO (`robots.snake.ppo`) trained on
  the 8 for ``--ppo-steps`` env steps per seed, on the spiking networks'
  inputs or on the true target angles (`spikejax train ppo`'s output per seed
  in ``DIR/ppo/OBS-seedS``, so a killed run resumes);
* the four R-STDP topologies, trained for ``--train-laps`` passes of the 8
  (`robots.snake.reproduce_rstdp.run` into ``DIR/rstdp``, resumable too).

Writes ``DIR/snake_baselines.csv`` (the ``snake_rstdp.csv`` columns, then
``env_steps_to_learn``: the env steps one seed trained for; 0 for the scripted
controller) and ``DIR/snake_baselines.png`` (mean running-mean head angle in
the paper's window and failures a minute, per controller and track, with the
intervals over seeds).
"""

from __future__ import annotations

import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from robots.snake import metrics, reproduce_rstdp, rstdp, steering, training
from robots.snake.reproduce_ppo import evaluate_rows, train_one
from spikejax.benchmarking import write_csv
from spikejax.commands import Command, add_common, count, output_directory
from spikejax.errors import UserError
from spikejax.rollout import Controller

__all__ = ["command", "run", "HEADER"]

HEADER = [*reproduce_rstdp.HEADER, "env_steps_to_learn"]


def scripted_controller(env) -> Controller:
    """`robots.snake.steering` as a Controller, its gains for ``env``'s steering range and head compensation."""
    params = steering.for_max_steer(float(env.params.max_steer), env.compensate_from)
    dt = env.dt

    def step(_, cstate, env_state, *, key):
        cstate, action = steering.step(params, cstate, env_state.obs, dt)
        return cstate, action, {"d_body": action[0], "d_head": action[1]}

    return Controller(step=step, on_reset=lambda _, cstate: steering.init())


def _scripted_rows(test_steps) -> list[list]:
    rows = []
    for name in reproduce_rstdp.TEST_TRACKS:
        env = training.env_for(name)
        states = jax.tree.map(lambda x: jnp.stack([x]), steering.init())
        trace = training.run_test(scripted_controller(env), None, states, name, test_steps, seeds=np.arange(1))
        for row in reproduce_rstdp.test_rows("scripted", name, trace, env.dt, reproduce_rstdp._windows(env)):
            rows.append(row[:-1] + ["non-spiking baseline (no paper figure)", 0])
    return rows


def run(
    out: Path,
    *,
    seeds: int,
    ppo_steps: int,
    train_laps: float,
    test_steps: int | None = None,
    progress: bool = True,
) -> list[list]:
    """Train what needs training, test everything, write the table and the figure; returns the rows."""
    rows = _scripted_rows(test_steps)
    for observation in ("grid", "angles"):
        dirs = []
        for seed in range(seeds):
            d = out / "ppo" / f"{observation}-seed{seed}"
            d.mkdir(parents=True, exist_ok=True)
            t0 = time.time()
            meta = train_one(d, task="snake-track", observation=observation, steps=ppo_steps, seed=seed, progress=False)
            # Each Brax training compiles programs of its own; XLA's JIT keeps ~1,000-2,000 memory maps for
            # those of each, and after ~30 trainings a process hit the kernel's map limit (65,530) and crashed.
            jax.clear_caches()
            if progress:
                print(f"ppo-{observation} seed {seed}: {meta['env_steps']:,} env steps ({time.time() - t0:.0f} s)")
            dirs.append(d)
        for name in reproduce_rstdp.TEST_TRACKS:
            rows += [r + [meta["env_steps"]] for r in evaluate_rows(dirs, name, name, test_steps)]
    steps, _ = reproduce_rstdp.training_steps(training.env_for("eight"), train_laps)
    rstdp_rows = reproduce_rstdp.run(
        out / "rstdp",
        seeds=seeds,
        train_laps=train_laps,
        topologies=rstdp.TOPOLOGIES,
        test_steps=test_steps,
        progress=progress,
    )
    rows += [r + [steps] for r in rstdp_rows]
    write_csv(out / "snake_baselines.csv", [dict(zip(HEADER, r)) for r in rows], HEADER)
    _plot(out / "snake_baselines.png", rows)
    return rows


def _plot(path: Path, rows: list[list]) -> None:
    from matplotlib.figure import Figure

    col = {k: i for i, k in enumerate(HEADER)}
    rows = [r for r in rows if r[col["window_steps"]] == metrics.PAPER_WINDOW]
    controllers = list(dict.fromkeys(r[0] for r in rows))
    names = list(reproduce_rstdp.TEST_TRACKS)
    fig = Figure(figsize=(12, 4), layout="constrained")
    width = 0.8 / len(controllers)
    for k, (key, lo, hi, label) in enumerate(
        [
            ("mean_head_angle_deg", "ci_low", "ci_high", "mean |running mean a_head| (deg), W = 625"),
            ("failures_per_min", "failures_per_min_ci_low", "failures_per_min_ci_high", "failures / min"),
        ]
    ):
        ax = fig.add_subplot(1, 2, k + 1)
        for i, c in enumerate(controllers):
            by_track = {r[1]: r for r in rows if r[0] == c}
            x = np.arange(len(names)) + (i - (len(controllers) - 1) / 2) * width
            y = np.array([float(by_track[n][col[key]]) for n in names])
            err_lo = np.array([float(by_track[n][col[lo]]) for n in names])
            err_hi = np.array([float(by_track[n][col[hi]]) for n in names])
            yerr = np.nan_to_num(np.stack([y - err_lo, err_hi - y]), nan=0.0).clip(0)
            ax.bar(x, y, width, yerr=yerr, capsize=2, label=c)
        ax.set_xticks(np.arange(len(names)), names, fontsize=8)
        ax.set_ylabel(label)
        ax.grid(axis="y", alpha=0.3)
        if k == 0:
            ax.legend(fontsize=7)
    fig.suptitle("Snake target tracking: spiking networks, scripted steering and Brax PPO on the same tests")
    fig.savefig(path, dpi=110)


def _add_arguments(parser) -> None:
    add_common(parser)
    parser.add_argument("--seeds", type=count, default=16, help="seeds per learned controller (default 16)")
    parser.add_argument("--ppo-steps", type=count, default=1_000_000, help="PPO env steps per seed (default 1,000,000)")
    parser.add_argument("--train-laps", type=float, default=2.0, help="R-STDP training in passes of the 8 (default 2)")
    parser.add_argument(
        "--test-steps", type=count, default=None, help="control steps per test track (default: one pass)"
    )


def run_command(*, out, seeds, ppo_steps, train_laps, test_steps, no_progress) -> int:
    """``spikejax reproduce snake-baselines --out DIR``."""
    if not train_laps > 0:
        raise UserError(f"--train-laps must be positive, got {train_laps}")
    with output_directory(out, command="reproduce snake-baselines") as out:
        rows = run(
            out,
            seeds=seeds,
            ppo_steps=ppo_steps,
            train_laps=train_laps,
            test_steps=test_steps,
            progress=not no_progress,
        )
        reproduce_rstdp._print(rows)
        print(f"wrote {out}/snake_baselines.csv, snake_baselines.png, ppo/, rstdp/")
    return 0


command = Command(
    help="the snake's R-STDP networks beside scripted steering and Brax PPO, on the same test tracks",
    add_arguments=_add_arguments,
    run=run_command,
)
