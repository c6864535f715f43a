"""Brax PPO's training env steps/s on the snake's tracking task, compile apart, beside the env alone.

    .venv/bin/python benchmarks/ppo_throughput.py [--envs 16,64,256] [--observations grid,angles]
        [--backend mujoco|mjx] [--updates 12] [--out DIR]

For each observation variant and number of envs, one after the other: PPO's
steady training rate (env steps between its first and last logged update over
the wall time between them, so compilation and the first update are left
out; three epochs of ``updates / 3`` updates each, the first not timed), and the env alone at the same batch (`robots.snake.ppo.TrackTask`'s
``step`` in a jitted, vmapped ``lax.scan`` of zero actions, compile apart),
so ``ppo_share`` = ``1 - ppo / env`` is what learning costs. Writes
``DIR/ppo_throughput.csv``.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import jax
import jax.numpy as jnp

from robots.snake import ppo
from spikejax.benchmarking import write_csv

HEADER = ["observation", "backend", "envs", "ppo_steps_per_s", "env_steps_per_s", "ppo_share", "first_update_s"]


def ppo_rate(task, envs: int, updates: int) -> tuple[float, float]:
    settings = ppo.PPOSettings(num_envs=envs, batch_size=max(envs, 64))
    marks = []
    t0 = time.perf_counter()
    ppo.train(
        task,
        updates * settings.steps_per_update,
        settings=settings,
        evals=3,  # several updates an epoch: Brax's per-epoch work is not timed as training
        on_params=lambda n, p: marks.append((n, time.perf_counter())),
    )
    (n0, t_first), (n1, t_last) = marks[1], marks[-1]
    return (n1 - n0) / (t_last - t_first), t_first - t0


def env_rate(task, envs: int, steps: int = 200) -> float:
    def run(keys):
        state = jax.vmap(task.reset)(keys)

        def body(s, _):
            return jax.vmap(task.step)(s, jnp.zeros((envs, 2))), None

        state, _ = jax.lax.scan(body, state, None, length=steps)
        return state.obs

    fn = jax.jit(run)
    keys = jax.random.split(jax.random.PRNGKey(0), envs)
    jax.block_until_ready(fn(keys))
    t = time.perf_counter()
    jax.block_until_ready(fn(keys))
    return envs * steps / (time.perf_counter() - t)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--envs", default="16,64,256")
    p.add_argument("--observations", default="grid,angles")
    p.add_argument("--backend", default="mujoco")
    p.add_argument("--updates", type=int, default=12)
    p.add_argument("--out", default="results/ppo")
    a = p.parse_args(argv)
    rows = []
    for observation in a.observations.split(","):
        task = ppo.make_task("snake-track", observation, backend=a.backend)
        for envs in (int(x) for x in a.envs.split(",")):
            rate, first = ppo_rate(task, envs, a.updates)
            env = env_rate(task, envs)
            rows.append(
                {
                    "observation": observation,
                    "backend": a.backend,
                    "envs": envs,
                    "ppo_steps_per_s": round(rate),
                    "env_steps_per_s": round(env),
                    "ppo_share": round(1 - rate / env, 3),
                    "first_update_s": round(first, 1),
                }
            )
            print(rows[-1], flush=True)
    write_csv(Path(a.out) / "ppo_throughput.csv", rows, HEADER)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
