"""``spikejax bench snake``: snake env-steps per second, both physics backends against MuJoCo C physics alone.

An env-step is one control step of one snake: the paper's 20 ms (Sec. II-D
of the snake R-STDP paper), i.e. `robots.snake.physics.make_physics`'s
``substeps`` physics steps (5 of 4 ms with the tuned model). Three
implementations are timed in the same run, at batch sizes 1 to 1024:

- ``MuJoCo C physics only``: the peer. ``mujoco.rollout`` steps the batch
  through the same MJCF and the same servo targets (the gait's, computed
  beforehand), nothing else: on one thread, and on a persistent pool of one
  thread per CPU core (MuJoCo C's own parallelism, ``--threads``).
- ``mujoco backend closed loop``: ``jax.jit(jax.vmap(run))`` where ``run`` is
  a ``lax.scan`` of env steps, each evaluating the gait (Eq. (1), steering,
  head compensation) in JAX, stepping the physics through the ``"mujoco"``
  backend's callback, then moving the target, rendering the head camera and
  making its events in JAX; the backend's C engine on one thread, and on
  one thread per core.
- ``mjx backend closed loop``: the same program with the ``"mjx"`` backend,
  each batch in a fresh process (`spikejax.benchmarking.Processes`): in a
  process where MuJoCo's rollout threads had run, an MJX batch of 256 never returned.
  On a CPU only batches up to `MJX_CPU_MAX_BATCH` are timed: batches of 256
  hung intermittently there even in a fresh process.

The one-thread closed loops (both backends) each run in a process of their
own held to one core (`spikejax.benchmarking.HeldToOneCore`): in a process
free to use every core, XLA spreads a one-device program's large loops over
all of them (the mujoco closed loop at batch 64 ran 7 % faster so).

The closed loops time `robots.snake.env.SnakeEnv`'s ``step`` on the
8-shaped track: the gait, the physics, the target's motion, the head camera's
128 x 128 frame and its frame-difference DVS events, for every snake.

Compile time (``lower(...).compile()``) is reported apart from run time (the
fastest of ``--repeats`` runs; the implementations of a batch are timed once a
round, `spikejax.benchmarking.interleaved`). ``vs_c_physics`` is a row's
env-steps/s over the C physics' at the same batch on as many cores (``cores``:
one thread, or one a core). Each row also gives the simulated seconds per
wall-clock second and how long one training episode of the paper (151,093
control steps, 3,021.86 s simulated, Sec. III-A) takes at that throughput,
one episode per snake of the batch.

`run` writes ``snake.csv`` and ``snake.png`` to ``--out``.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import rollout as mj_rollout

from spikejax.benchmarking import (
    HeldToOneCore,
    Processes,
    add_ratios,
    compile_ahead,
    cores_label,
    held_row,
    interleaved,
    machine_banner,
    plot_rows,
    write_csv,
)
from spikejax.commands import Command, count, writes_output
from spikejax.errors import UserError

# The snake's modules are imported where they are used: they make JAX arrays when
# imported, which would start JAX before another bench of ``spikejax bench``
# (all are loaded to build the command line) presents the CPU as several devices.

__all__ = [
    "BATCHES",
    "EPISODE_STEPS",
    "EPISODE_SECONDS",
    "QUICK_BATCHES",
    "ROW_FIELDS",
    "CPhysicsRun",
    "ClosedLoopRun",
    "bench_c_physics",
    "bench_closed_loop",
    "command",
    "run",
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

ROW_FIELDS = (
    "impl",
    "loop",
    "batch",
    "control_steps",
    "compile_s",
    "run_s",
    "env_steps_per_s",
    "physics_steps_per_s",
    "sim_s_per_wall_s",
    "vs_c_physics",
    "episode_wall_s",
    "cores",
    "parallel",
)


def _control_steps(batch: int, substeps: int, budget: int) -> int:
    return max(MIN_CONTROL_STEPS, budget // (batch * substeps))


def _row(impl, loop, batch, n, compile_s, run_s, substeps, control_dt, threads) -> dict:
    env_steps = batch * n / run_s
    return dict(
        impl=impl,
        loop=loop,
        batch=batch,
        control_steps=n,
        compile_s=compile_s,
        run_s=run_s,
        env_steps_per_s=env_steps,
        physics_steps_per_s=env_steps * substeps,
        sim_s_per_wall_s=env_steps * control_dt,
        vs_c_physics=math.nan,
        episode_wall_s=EPISODE_STEPS * batch / env_steps,
        cores=threads,
        parallel=cores_label(threads, "thread"),
    )


def _steers(batch: int) -> np.ndarray:
    """Each snake of the batch its own steering offset, so that they do not all move alike."""
    return np.linspace(-0.1, 0.1, batch) if batch > 1 else np.zeros(1)


class CPhysicsRun:
    """MuJoCo C alone as a benchmark timer: ``mujoco.rollout`` of ``batch`` snakes for ``n`` control steps.

    The servo targets are precomputed; ``nthread`` threads (1: no pool) step
    the batch. Each call is one rollout and returns its seconds; `info` is
    the row (``run_s``: the fastest call). `close` ends the thread pool.
    """

    def __init__(self, batch: int, n: int, *, nthread: int = 1):
        from robots.snake.gait import gait_params, joint_targets
        from robots.snake.physics import make_physics

        phys = make_physics("mujoco")
        self.model, self.phys, self.batch, self.n = phys.mj_model, phys, batch, n
        gait = gait_params()
        times = jnp.arange(n) * phys.dt * phys.substeps
        targets = jax.jit(jax.vmap(lambda s: jax.vmap(lambda t: joint_targets(gait, t, s))(times)))(_steers(batch))
        self.control = np.repeat(np.asarray(targets, np.float64), phys.substeps, axis=1)  # (batch, n * substeps, 16)
        data = mujoco.MjData(self.model)
        state = np.zeros((batch, mujoco.mj_stateSize(self.model, mujoco.mjtState.mjSTATE_FULLPHYSICS)))
        mujoco.mj_getState(self.model, data, state[0], mujoco.mjtState.mjSTATE_FULLPHYSICS)
        state[:] = state[0]
        self.state = state
        self.threads = nthread if batch >= nthread and nthread > 1 else 0
        self.datas = [mujoco.MjData(self.model) for _ in range(max(self.threads, 1))]
        self.out = np.empty((batch, n * phys.substeps, state.shape[1]))
        self.pool = mj_rollout.Rollout(nthread=self.threads)
        self.pool.__enter__()
        self.run_s = math.inf

    def __call__(self) -> float:
        t0 = time.perf_counter()
        self.pool.rollout(
            [self.model] * self.batch,
            self.datas,
            self.state,
            self.control,
            state=self.out,
            chunk_size=max(1, self.batch // max(self.threads, 1)),
        )
        seconds = time.perf_counter() - t0
        if not np.all(np.isfinite(self.out[:, -1])):
            raise RuntimeError("MuJoCo C rollout diverged")
        self.run_s = min(self.run_s, seconds)
        return seconds

    @property
    def info(self) -> dict:
        threads, phys = max(self.threads, 1), self.phys
        return _row(
            "MuJoCo C physics only",
            f"physics only, {threads} thread(s)",
            self.batch,
            self.n,
            0.0,
            self.run_s,
            phys.substeps,
            phys.dt * phys.substeps,
            threads,
        )

    def close(self) -> None:
        self.pool.__exit__(None, None, None)


def bench_c_physics(batch: int, n: int, *, nthread: int | None = None, repeats: int = 2) -> dict:
    """MuJoCo C alone (`CPhysicsRun`, ``nthread`` threads, default one per core), the fastest of ``repeats``."""
    run = CPhysicsRun(batch, n, nthread=nthread or os.cpu_count() or 1)
    try:
        for _ in range(repeats):
            run()
        return run.info
    finally:
        run.close()


def _env_run(backend: str, nthread: int | None = None):
    """The closed loop timed: ``SnakeEnv.step`` (gait, physics, target, head camera, DVS events) in a ``lax.scan``."""
    from robots.snake.env import SnakeEnv

    env = SnakeEnv("eight", backend, **({} if nthread is None else dict(nthread=nthread)))

    def run(key, steer, n):
        action = jnp.zeros(env.action_size).at[0].set(steer)

        def body(s, _):
            return env.step(s, action), None

        final = jax.lax.scan(body, env.reset(key), None, length=n)[0]
        return final.obs, final.metrics["events"]

    return env, run


class ClosedLoopRun:
    """``jax.jit(jax.vmap(run))`` of ``batch`` snake envs for ``n`` control steps with ``backend``, as a timer.

    Compiled ahead at construction (``compile_s``); each call runs it once and
    returns its seconds, checking the result (finite observations, events in
    every snake's last step). ``nthread``: the C engine's threads
    (``"mujoco"``; None: one per core); `info` is the row.
    """

    def __init__(self, backend: str, batch: int, n: int, nthread: int | None = None):
        env, run = _env_run(backend, nthread)
        self.backend, self.batch, self.n, self.phys = backend, batch, n, env.physics
        self.threads = (nthread or os.cpu_count() or 1) if backend == "mujoco" else 1
        keys = jax.random.split(jax.random.key(0), batch)
        steers = jnp.asarray(_steers(batch) / float(env.params.max_steer), jnp.float32)
        self.compiled, self.compile_s = compile_ahead(jax.vmap(lambda k, s: run(k, s, n)), keys, steers)
        self.args = (keys, steers)
        self.run_s = math.inf

    def __call__(self) -> float:
        t0 = time.perf_counter()
        obs, events = jax.block_until_ready(self.compiled(*self.args))
        seconds = time.perf_counter() - t0
        if not bool(jnp.all(jnp.isfinite(obs))):
            raise RuntimeError(f"{self.backend} closed loop produced non-finite values")
        if not bool(jnp.all(events > 0)):
            raise RuntimeError(f"{self.backend} closed loop: a snake's camera saw no events in its last step")
        self.run_s = min(self.run_s, seconds)
        return seconds

    @property
    def info(self) -> dict:
        phys = self.phys
        return _row(
            f"{self.backend} backend closed loop",
            LOOP,
            self.batch,
            self.n,
            self.compile_s,
            self.run_s,
            phys.substeps,
            phys.dt * phys.substeps,
            self.threads,
        )


def bench_closed_loop(backend: str, batch: int, n: int, *, repeats: int = 2, nthread: int | None = None) -> dict:
    """`ClosedLoopRun`, the fastest of ``repeats`` runs; compile apart."""
    run = ClosedLoopRun(backend, batch, n, nthread)
    for _ in range(repeats):
        run()
    return run.info


def _plot(rows: list[dict], path: Path) -> None:
    plot_rows(
        rows,
        path,
        x="batch",
        y="env_steps_per_s",
        series=lambda r: f"{r['impl']}, {r['parallel']}",
        xbase=2,
        size=(6, 4),
        xlabel="batch (snakes)",
        ylabel="env-steps/s (20 ms control steps)",
        title="snake: throughput, compile time excluded",
    )


def _add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--trials", type=count, default=None, help="the largest batch of snakes (default 1024)")
    parser.add_argument("--out", default=None, help="write snake.csv and snake.png here")
    parser.add_argument("--quick", action="store_true", help="a batch of 2, a short run, no MJX")
    parser.add_argument("--repeats", type=count, default=None, help="timed rounds, the best kept (default 2)")
    parser.add_argument(
        "--threads", type=count, default=None, help="MuJoCo C threads of the all-cores rows (default: one per core)"
    )
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bar")


@writes_output("bench snake")
def run(
    *,
    trials: int | None = None,
    out: str | None = None,
    quick: bool = False,
    repeats: int | None = None,
    threads: int | None = None,
    no_progress: bool = False,
) -> int:
    """``spikejax bench snake``: print the table; write ``snake.csv`` and ``snake.png`` to ``out``.

    Args:
        trials: caps the batch sizes timed (default: up to 1024).
        out: a directory for the table and figure (None: print only).
        quick: time a batch of 2, briefly, without MJX.
        repeats: timed rounds per batch, the best kept (default 2; MJX's rows 1).
        threads: MuJoCo C's threads in the all-cores rows, the peer's and the
            ``"mujoco"`` backend's (default: one per core); the one-core rows use one thread.
        no_progress: hide the progress bar.
    """
    batches = QUICK_BATCHES if quick else BATCHES
    if trials is not None:
        if trials < 1:
            raise UserError(f"--trials must be at least 1, got {trials}")
        batches = tuple(b for b in batches if b <= trials) or (trials,)
    repeats = 2 if repeats is None else repeats
    every = (os.cpu_count() or 1) if threads is None else threads
    backends = ("mujoco",) if quick else ("mujoco", "mjx")
    c_budget = 2_000 if quick else C_BUDGET
    from robots.snake.physics import make_physics

    phys = make_physics("mujoco")
    print(machine_banner(mujoco=mujoco.__version__))
    print(
        f"snake (17 modules, tuned model): control step {phys.dt * phys.substeps * 1e3:.0f} ms = "
        f"{phys.substeps} x {phys.dt * 1e3:.0f} ms physics steps; the paper's episode: {EPISODE_STEPS:,} "
        f"control steps, {EPISODE_SECONDS:,} s simulated"
    )
    from tqdm import tqdm

    mjx_batches = batches
    if jax.devices()[0].platform == "cpu":
        mjx_batches = tuple(b for b in batches if b <= MJX_CPU_MAX_BATCH)
        if mjx_batches != batches:
            print(
                f"mjx on a CPU: batches above {MJX_CPU_MAX_BATCH} skipped (they can hang there, "
                f"docs/ARCHITECTURE.md; and run at a few hundred env-steps/s)"
            )
    rows = []
    bar = tqdm(batches, desc="snake bench", disable=no_progress)
    for batch in bar:
        counts = [1] + ([every] if every > 1 and batch >= every else [])
        n_c = _control_steps(batch, phys.substeps, c_budget)
        with contextlib.ExitStack() as stack:
            runs = {}
            for t in counts:
                runs["c", t] = CPhysicsRun(batch, n_c, nthread=t)
                stack.callback(runs["c", t].close)
            if "mujoco" in backends:
                for t in counts:
                    runs["mujoco", t] = (
                        stack.enter_context(Processes(HeldToOneCore, ClosedLoopRun, "mujoco", batch, n_c, 1))
                        if t == 1
                        else ClosedLoopRun("mujoco", batch, n_c, t)
                    )
            interleaved(runs, repeats)  # each run keeps its best in its row
            new = [held_row(r.info()[0]) if isinstance(r, Processes) else r.info for r in runs.values()]
            if "mjx" in backends and batch in mjx_batches:  # in a fresh process: see the module docstring
                n = _control_steps(batch, phys.substeps, MJX_BUDGET)
                with Processes(HeldToOneCore, ClosedLoopRun, "mjx", batch, n) as mjx:
                    mjx()
                    new.append(held_row(mjx.info()[0]))
        for r in new:
            bar.write(
                f"  {r['impl']}, batch {batch}, {r['parallel']}: {r['env_steps_per_s']:,.0f} env-steps/s "
                f"(compile {r['compile_s']:.1f} s)"
            )
        rows.extend(new)
    add_ratios(
        rows,
        "vs_c_physics",
        "env_steps_per_s",
        lambda p, r: p["impl"].startswith("MuJoCo C") and p["batch"] == r["batch"],
    )
    print(
        f"{'implementation':34s} {'batch':>5s} {'cores':>5s} {'compile s':>9s} {'env-steps/s':>11s} "
        f"{'sim s/s':>8s} {'vs C':>6s} {'episode':>9s}"
    )
    for r in rows:
        print(
            f"{r['impl']:34s} {r['batch']:5d} {r['cores']:5d} {r['compile_s']:9.1f} {r['env_steps_per_s']:11,.0f} "
            f"{r['sim_s_per_wall_s']:8.1f} {r['vs_c_physics']:6.2f} {r['episode_wall_s']:8.0f}s"
        )
    print(
        f"  loop timed: {LOOP}; vs C: against the C physics at the same batch on as many threads; "
        f"episode: wall time of one {EPISODE_STEPS:,}-step episode per snake"
    )
    if out:
        out = Path(out)
        write_csv(out / "snake.csv", rows, ROW_FIELDS)
        _plot(rows, out / "snake.png")
        print(f"wrote {out / 'snake.csv'} and {out / 'snake.png'}")
    return 0


command = Command(
    help="snake env-steps per second, both physics backends against MuJoCo C",
    add_arguments=_add_arguments,
    run=run,
    description=__doc__.splitlines()[0],
)
