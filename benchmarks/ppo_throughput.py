"""Brax PPO's training env steps/s on the snake's tracking task, compile apart, beside the env alone and Stable-Baselines3.

    .venv/bin/python benchmarks/ppo_throughput.py [--envs 16,64,256] [--observations grid,angles]
        [--backend mujoco|mjx] [--updates 12] [--peer-rounds 2] [--out DIR]

For each observation variant and number of envs, one after the other: PPO's
steady training rate (env steps between its first and last logged update over
the wall time between them, so compilation and the first update are left
out; three epochs of ``updates / 3`` updates each, the first not timed), and the env alone at the same batch (`robots.snake.ppo.TrackTask`'s
``step`` in a jitted, vmapped ``lax.scan`` of zero actions, compile apart),
so ``ppo_share`` = ``1 - ppo / env`` is what learning costs. Writes
``DIR/ppo_throughput.csv``.

Then the peer a user would otherwise train with: Stable-Baselines3's PPO on
`robots.snake.gym_task.MujocoTrackEnv` (the ``"angles"`` task as a Gymnasium
env on MuJoCo's Python bindings, the env such a user writes), with the same
work per update as `robots.snake.ppo.PPOSettings` (5,120 env steps, 4 passes
over minibatches of 1,280, the same network sizes and activation, observations
normalised), in ``--peer-rounds`` interleaved rounds. Each round runs, each in
a fresh process: Brax and Stable-Baselines3 pinned to one core (64 envs; for
SB3 a ``DummyVecEnv``, torch on one thread), then both given every core: Brax
as `spikejax train ppo` runs (one JAX device, MuJoCo C's threads), SB3 as its
users spread envs over cores (``SubprocVecEnv``, one process an env, with 2
and 4 envs; and 64 envs in one process with torch on every core). The env
alone is timed in each process too (random actions for SB3). Writes
``DIR/ppo_peer.csv`` (one row a run, ``x_peer`` against the fastest SB3 row of
the same cores and round).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp

from robots.snake import ppo
from spikejax.benchmarking import cores_label, machine_banner, write_csv

HEADER = [
    "observation",
    "backend",
    "envs",
    "cores",
    "parallel",
    "ppo_steps_per_s",
    "env_steps_per_s",
    "ppo_share",
    "first_update_s",
]
PEER_HEADER = [
    "round",
    "trainer",
    "vec_env",
    "envs",
    "cores",
    "parallel",
    "ppo_steps_per_s",
    "env_steps_per_s",
    "first_update_s",
    "x_peer",
]


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


def sb3_rate(envs: int, vec_env: str, updates: int) -> dict:
    """Stable-Baselines3's PPO on ``envs`` `MujocoTrackEnv`s with `ppo.PPOSettings`' work per update."""
    import numpy as np
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecNormalize

    from robots.snake.gym_task import make_env

    torch.set_num_threads(len(os.sched_getaffinity(0)))
    settings = ppo.PPOSettings()
    factories = [make_env(seed=i) for i in range(envs)]
    venv = SubprocVecEnv(factories) if vec_env == "SubprocVecEnv" else DummyVecEnv(factories)
    venv = VecNormalize(venv, norm_obs=True, norm_reward=False)
    venv.reset()
    rng, steps, t = np.random.default_rng(0), 0, time.perf_counter()
    while time.perf_counter() - t < 5.0:
        venv.step(rng.uniform(-1, 1, (envs, 2)).astype(np.float32))
        steps += envs
    env_rate = steps / (time.perf_counter() - t)
    model = PPO(
        "MlpPolicy",
        venv,
        n_steps=settings.steps_per_update // envs,
        batch_size=settings.batch_size * settings.unroll_length,
        n_epochs=settings.num_updates_per_batch,
        learning_rate=settings.learning_rate,
        gamma=settings.discounting,
        gae_lambda=settings.gae_lambda,
        ent_coef=settings.entropy_cost,
        clip_range=0.3,  # Brax's clipping_epsilon
        policy_kwargs={"net_arch": {"pi": [32] * 4, "vf": [256] * 5}, "activation_fn": torch.nn.SiLU},
        device="cpu",
        seed=0,
    )
    marks = []

    class Marks(BaseCallback):
        def _on_rollout_start(self) -> None:
            marks.append((self.num_timesteps, time.perf_counter()))

        def _on_step(self) -> bool:
            return True

    t0 = time.perf_counter()
    model.learn(updates * settings.steps_per_update, callback=Marks())
    marks.append((model.num_timesteps, time.perf_counter()))
    venv.close()
    (n0, t_first), (n1, t_last) = marks[1], marks[-1]
    return {
        "ppo_steps_per_s": (n1 - n0) / (t_last - t_first),
        "env_steps_per_s": env_rate,
        "first_update_s": t_first - t0,
    }


def brax_rate(envs: int, updates: int) -> dict:
    """Brax's PPO on the ``"angles"`` task (`ppo_rate`), and its env alone, in this process's cores."""
    task = ppo.make_task("snake-track", "angles")
    rate, first = ppo_rate(task, envs, updates)
    return {"ppo_steps_per_s": rate, "env_steps_per_s": env_rate(task, envs), "first_update_s": first}


def _pinned(spec: dict, cores: int) -> dict:
    """One run of ``spec`` in a fresh process on the first ``cores`` CPUs (set before anything is imported)."""
    cpus = sorted(os.sched_getaffinity(0))[:cores]
    launch = (
        "import os, runpy, sys; "
        f"os.sched_setaffinity(0, {cpus!r}); "
        f"sys.argv = [{__file__!r}, '--child', {json.dumps(spec)!r}]; "
        f"runpy.run_path({__file__!r}, run_name='__main__')"
    )
    out = subprocess.run([sys.executable, "-c", launch], capture_output=True, text=True, check=False)
    if out.returncode:
        raise RuntimeError(f"{spec}: {(out.stderr.strip().splitlines() or ['no output'])[-1]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def peer_runs(rounds: int, updates: int) -> list[dict]:
    """The interleaved rounds of the module docstring: Brax and SB3 on one core, then on every core."""
    every = len(os.sched_getaffinity(0))
    plan = [("brax", "-", 64, 1, "1 device"), ("sb3", "DummyVecEnv", 64, 1, "1 process")]
    if every > 1:
        plan += [
            ("brax", "-", 64, every, "1 device, MuJoCo C threads"),
            ("sb3", "SubprocVecEnv", 2, every, "2 processes"),
            ("sb3", "SubprocVecEnv", 4, every, "4 processes"),
            ("sb3", "DummyVecEnv", 64, every, "1 process, torch threads"),
        ]
    rows = []
    for r in range(rounds):
        for trainer, vec_env, envs, cores, parallel in plan:
            spec = {"trainer": trainer, "vec_env": vec_env, "envs": envs, "updates": updates}
            res = _pinned(spec, cores)
            row = {"round": r, "trainer": trainer, "vec_env": vec_env, "envs": envs, "cores": cores}
            row.update(parallel=parallel, **{k: round(v, 1) for k, v in res.items()})
            rows.append(row)
            print(row, flush=True)
    for row in rows:
        peers = [p for p in rows if p["trainer"] == "sb3" and p["round"] == row["round"] and p["cores"] == row["cores"]]
        best = max((p["ppo_steps_per_s"] for p in peers), default=None)
        row["x_peer"] = round(row["ppo_steps_per_s"] / best, 2) if best else ""
    return rows


def _child(spec: str) -> int:
    spec = json.loads(spec)
    if spec["trainer"] == "brax":
        result = brax_rate(spec["envs"], spec["updates"])
    else:
        result = sb3_rate(spec["envs"], spec["vec_env"], spec["updates"])
    print(json.dumps(result))
    return 0


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--envs", default="16,64,256")
    p.add_argument("--observations", default="grid,angles")
    p.add_argument("--backend", default="mujoco")
    p.add_argument("--updates", type=int, default=12)
    p.add_argument("--peer-rounds", type=int, default=2, help="interleaved rounds against Stable-Baselines3 (0: none)")
    p.add_argument("--no-sweep", action="store_true", help="only the rounds against Stable-Baselines3")
    p.add_argument("--out", default="results/ppo")
    p.add_argument("--child", help=argparse.SUPPRESS)
    a = p.parse_args(argv)
    if a.child:
        return _child(a.child)
    import brax
    import mujoco

    print(machine_banner(brax=brax.__version__, mujoco=mujoco.__version__), flush=True)
    if a.peer_rounds:
        write_csv(Path(a.out) / "ppo_peer.csv", peer_runs(a.peer_rounds, a.updates), PEER_HEADER)
    if a.no_sweep:
        return 0
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
                    "cores": len(os.sched_getaffinity(0)),
                    "parallel": "1 device, MuJoCo C threads"
                    if a.backend == "mujoco"
                    else cores_label(jax.device_count(), "device"),
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
