"""``spikejax bench snake``: snake env-steps per second, both physics backends against MuJoCo C physics alone.

An env-step is one control step of one snake: the paper's 20 ms (Sec. II-D
of the snake R-STDP paper), i.e. `robots.snake.physics.make_physics`'s
``substeps`` physics steps (5 of 4 ms with the tuned model). Three
implementations are timed in the same run, at batch sizes 1 to 1024:

- ``MuJoCo C physics only``: the peer. ``mujoco.rollout`` on a persistent
  pool of one thread per CPU core steps the batch through the same MJCF and
  the same servo targets (the gait's, computed beforehand), nothing else.
- ``mujoco backend closed loop``: ``jax.jit(jax.vmap(run))`` where ``run`` is
  a ``lax.scan`` of env steps, each evaluating the gait (Eq. (1), steering,
  head compensation) in JAX, stepping the physics through the ``"mujoco"``
  backend's callback, then moving the target, rendering the head camera and
  making its events in JAX.
- ``mjx backend closed loop``: the same program with the ``"mjx"`` backend,
  each batch in a fresh process (`robots.common.run_isolated`): in a process
  where MuJoCo's rollout threads had run, an MJX batch of 256 never returned.
  On a CPU only batches up to `MJX_CPU_MAX_BATCH` are timed: batches of 256
  hung intermittently there even in a fresh process.

The closed loops time :class:`robots.snake.env.SnakeEnv`'s ``step`` on the
8-shaped track: the gait, the physics, the target's motion, the head camera's
128 x 128 frame and its frame-difference DVS events, for every snake.

Compile time (``lower(...).compile()``) is reported apart from run time (the
fastest of ``repeats`` runs). Each row also gives the simulated seconds per
wall-clock second and how long one training episode of the paper (151,093
control steps, 3,021.86 s simulated, Sec. III-A) takes at that throughput,
one episode per snake of the batch.

``main`` writes ``snake.csv`` and ``snake.png`` to ``--out``.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import rollout as mj_rollout

from robots.common import run_isolated
from robots.common import write_csv
from robots.snake.env import SnakeEnv
from robots.snake.gait import gait_params
from robots.snake.gait import joint_targets
from robots.snake.physics import make_physics
from spikejax.errors import UserError

__all__ = [
    "BATCHES",
    "EPISODE_STEPS",
    "EPISODE_SECONDS",
    "QUICK_BATCHES",
    "ROW_FIELDS",
    "bench_c_physics",
    "bench_closed_loop",
    "main",
]

BATCHES = (1, 4, 16, 64, 256, 512, 1024)
QUICK_BATCHES = (2,)
EPISODE_STEPS = 151_093  # control steps of the paper's first training episode
EPISODE_SECONDS = 3021.86  # its simulated time, s
# Physics steps (batch x control steps x substeps) a timed run aims at.
C_BUDGET = 400_000
MJX_BUDGET = 10_000
MIN_CONTROL_STEPS = 5
# On a CPU an MJX batch of 256 or more snakes intermittently never returned (jax 0.10.2), also in a fresh process.
MJX_CPU_MAX_BATCH = 64
LOOP = "env step (physics + camera + events)"

ROW_FIELDS = ("impl", "loop", "batch", "control_steps", "compile_s", "run_s", "env_steps_per_s",
              "physics_steps_per_s", "sim_s_per_wall_s", "vs_c_physics", "episode_wall_s")


def _control_steps(batch: int, substeps: int, budget: int) -> int:
    return max(MIN_CONTROL_STEPS, budget // (batch * substeps))


def _row(impl, loop, batch, n, compile_s, run_s, substeps, control_dt) -> dict:
    env_steps = batch * n / run_s
    return dict(impl=impl, loop=loop, batch=batch, control_steps=n, compile_s=compile_s, run_s=run_s,
                env_steps_per_s=env_steps, physics_steps_per_s=env_steps * substeps,
                sim_s_per_wall_s=env_steps * control_dt, vs_c_physics=math.nan,
                episode_wall_s=EPISODE_STEPS * batch / env_steps)


def _steers(batch: int) -> np.ndarray:
    """Each snake of the batch its own steering offset, so that they do not all move alike."""
    return np.linspace(-0.1, 0.1, batch) if batch > 1 else np.zeros(1)


def bench_c_physics(batch: int, n: int, *, nthread: int | None = None, repeats: int = 2) -> dict:
    """MuJoCo C alone: ``mujoco.rollout`` of ``batch`` snakes for ``n`` control steps, servo targets precomputed."""
    phys = make_physics("mujoco")
    model = phys.mj_model
    nthread = nthread or os.cpu_count() or 1
    gait = gait_params()
    times = jnp.arange(n) * phys.dt * phys.substeps
    targets = jax.jit(jax.vmap(lambda s: jax.vmap(lambda t: joint_targets(gait, t, s))(times)))(_steers(batch))
    control = np.repeat(np.asarray(targets, np.float64), phys.substeps, axis=1)  # (batch, n * substeps, 16)
    data = mujoco.MjData(model)
    state = np.zeros((batch, mujoco.mj_stateSize(model, mujoco.mjtState.mjSTATE_FULLPHYSICS)))
    mujoco.mj_getState(model, data, state[0], mujoco.mjtState.mjSTATE_FULLPHYSICS)
    state[:] = state[0]
    threads = nthread if batch >= nthread and nthread > 1 else 0
    datas = [mujoco.MjData(model) for _ in range(max(threads, 1))]
    out = np.empty((batch, n * phys.substeps, state.shape[1]))
    run_s = math.inf
    with mj_rollout.Rollout(nthread=threads) as pool:
        for _ in range(repeats):
            t0 = time.perf_counter()
            pool.rollout([model] * batch, datas, state, control, state=out,
                         chunk_size=max(1, batch // max(threads, 1)))
            run_s = min(run_s, time.perf_counter() - t0)
    if not np.all(np.isfinite(out[:, -1])):
        raise RuntimeError("MuJoCo C rollout diverged")
    loop = f"physics only, {max(threads, 1)} thread(s)"
    return _row("MuJoCo C physics only", loop, batch, n, 0.0, run_s, phys.substeps, phys.dt * phys.substeps)


def _env_run(backend: str):
    """The closed loop timed: ``SnakeEnv.step`` (gait, physics, target, head camera, DVS events) in a ``lax.scan``."""
    env = SnakeEnv("eight", backend)

    def run(key, steer, n):
        action = jnp.zeros(env.action_size).at[0].set(steer)

        def body(s, _):
            return env.step(s, action), None

        final = jax.lax.scan(body, env.reset(key), None, length=n)[0]
        return final.obs, final.metrics["events"]

    return env, run


def bench_closed_loop(backend: str, batch: int, n: int, *, repeats: int = 2) -> dict:
    """``jax.jit(jax.vmap(run))`` of ``batch`` snake envs for ``n`` control steps with ``backend``; compile apart."""
    env, run = _env_run(backend)
    phys = env.physics
    keys = jax.random.split(jax.random.key(0), batch)
    steers = jnp.asarray(_steers(batch) / float(env.params.max_steer), jnp.float32)
    fn = jax.jit(jax.vmap(lambda k, s: run(k, s, n)))
    t0 = time.perf_counter()
    compiled = fn.lower(keys, steers).compile()
    compile_s = time.perf_counter() - t0
    run_s = math.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        obs, events = jax.block_until_ready(compiled(keys, steers))
        run_s = min(run_s, time.perf_counter() - t0)
    if not bool(jnp.all(jnp.isfinite(obs))):
        raise RuntimeError(f"{backend} closed loop produced non-finite values")
    if not bool(jnp.all(events > 0)):
        raise RuntimeError(f"{backend} closed loop: a snake's camera saw no events in its last step")
    return _row(f"{backend} backend closed loop", LOOP, batch, n, compile_s, run_s, phys.substeps,
                phys.dt * phys.substeps)


def _plot(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    for impl in dict.fromkeys(r["impl"] for r in rows):
        sel = [r for r in rows if r["impl"] == impl]
        ax.plot([r["batch"] for r in sel], [r["env_steps_per_s"] for r in sel], "o-", label=impl)
    ax.set_xscale("log", base=2)
    ax.set_yscale("log")
    ax.set_xlabel("batch (snakes)")
    ax.set_ylabel("env-steps/s (20 ms control steps)")
    ax.set_title("snake: throughput, compile time excluded")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(args: argparse.Namespace) -> int:
    """``spikejax bench snake [--trials N] [--out DIR]``; ``args.quick`` (if set) times a batch of 2 without MJX.

    ``--trials`` caps the batch sizes timed (default: up to 1024).
    """
    quick = bool(getattr(args, "quick", False))
    batches = QUICK_BATCHES if quick else BATCHES
    if args.trials is not None:
        if args.trials < 1:
            raise UserError(f"--trials must be at least 1, got {args.trials}")
        batches = tuple(b for b in batches if b <= args.trials) or (args.trials,)
    backends = ("mujoco",) if quick else ("mujoco", "mjx")
    c_budget = 2_000 if quick else C_BUDGET
    phys = make_physics("mujoco")
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"{jax.device_count()} x {jax.devices()[0].platform}, jax {jax.__version__}, mujoco {mujoco.__version__}")
    print(f"snake (17 modules, tuned model): control step {phys.dt * phys.substeps * 1e3:.0f} ms = "
          f"{phys.substeps} x {phys.dt * 1e3:.0f} ms physics steps; the paper's episode: {EPISODE_STEPS:,} "
          f"control steps, {EPISODE_SECONDS:,} s simulated")
    from tqdm import tqdm

    mjx_batches = batches
    if jax.devices()[0].platform == "cpu":
        mjx_batches = tuple(b for b in batches if b <= MJX_CPU_MAX_BATCH)
        if mjx_batches != batches:
            print(f"mjx on a CPU: batches above {MJX_CPU_MAX_BATCH} skipped (they can hang there, "
                  f"docs/ARCHITECTURE.md; and run at a few hundred env-steps/s)")
    jobs = [("c", b) for b in batches] + [("mujoco", b) for b in batches if "mujoco" in backends]
    jobs += [("mjx", b) for b in mjx_batches if "mjx" in backends]
    rows = []
    bar = tqdm(jobs, desc="snake bench", disable=getattr(args, "no_progress", False))
    for kind, batch in bar:
        if kind == "c":
            row = bench_c_physics(batch, _control_steps(batch, phys.substeps, c_budget))
        else:
            budget = MJX_BUDGET if kind == "mjx" else c_budget
            n = _control_steps(batch, phys.substeps, budget)
            if kind == "mjx":  # in a fresh process: see the module docstring
                row = run_isolated(bench_closed_loop, kind, batch, n, repeats=1)
            else:
                row = bench_closed_loop(kind, batch, n)
        rows.append(row)
        bar.write(f"  {row['impl']}, batch {batch}: {row['env_steps_per_s']:,.0f} env-steps/s "
                  f"(compile {row['compile_s']:.1f} s)")
    c_rate = {r["batch"]: r["env_steps_per_s"] for r in rows if r["impl"].startswith("MuJoCo C")}
    for r in rows:
        r["vs_c_physics"] = r["env_steps_per_s"] / c_rate[r["batch"]]
    print(f"{'implementation':34s} {'batch':>5s} {'compile s':>9s} {'env-steps/s':>11s} {'sim s/s':>8s} "
          f"{'vs C':>6s} {'episode':>9s}")
    for r in rows:
        print(f"{r['impl']:34s} {r['batch']:5d} {r['compile_s']:9.1f} {r['env_steps_per_s']:11,.0f} "
              f"{r['sim_s_per_wall_s']:8.1f} {r['vs_c_physics']:6.2f} {r['episode_wall_s']:8.0f}s")
    print(f"  loop timed: {rows[-1]['loop']}; episode: wall time of one {EPISODE_STEPS:,}-step episode per snake")
    if args.out:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        write_csv(out / "snake.csv", list(ROW_FIELDS), [[r[k] for k in ROW_FIELDS] for r in rows])
        _plot(rows, out / "snake.png")
        print(f"wrote {out / 'snake.csv'} and {out / 'snake.png'}")
    return 0
