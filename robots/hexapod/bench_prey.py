"""``spikejax bench hexapod-prey``: closed-loop hexapod decisions per second, against MuJoCo C and NumPy loops.

A decision is one step of `robots.hexapod.env.HexapodEnv`: one gait cycle of
0.32 s, the CPG's cycle, 160 physics steps of 2 ms, 16 frames of the head
camera at 160 x 256, the DVS emulator, the visual SNN once a frame, the
winner-take-all, the truth and the capture test. Four implementations are
timed in the same run, at batch sizes 1 to 1,024, each on one core and on all:

- ``MuJoCo C physics only``: the peer for the body. ``mujoco.rollout`` steps
  the batch's robots (the env's randomised pool) through G1's servo targets,
  computed beforehand, nothing else; on one thread, and on a persistent pool of
  one thread a core; in a process of its own (with its pool beside the env's,
  the env's two-device loop hung at batch 64).
- ``NumPy visual SNN``: the peer for the brain, the laptop side of the paper's
  setup. `robots.hexapod.reference.reference_vision` (Sec. IV's network event
  by event in Python loops, spike for spike the library's event-driven
  network, ``tests/test_hexapod_vision.py``) on the events of one recorded
  decision (a prey 0.9 m ahead); in one process, and in a pool of one process a
  core, each running its own. It neither renders, nor emulates the DVS, nor
  steps physics: it is given the easiest share of the loop.
- ``spikejax closed loop``: ``jax.jit(jax.vmap(run))``, ``run`` a ``lax.scan``
  of the SNN controller and ``HexapodEnv.step`` (``backend="mujoco"``): all of
  the above, the C engine through the env's callback. One CPU device, the C
  engine on one thread, and on one thread a core (`ClosedLoopRun` says why
  the batch is not split over devices).
- ``spikejax vision only``: the same render, DVS and visual SNN
  (`robots.hexapod.decisions.decide`) along recorded tracks, no physics: what
  the loop spends beside the C engine. One CPU device, and the batch split
  over one device a core (`spikejax.devices.shard_batch`).
- ``spikejax visual SNN only``: the loop's visual SNN alone (`SnnRun`) on
  the NumPy peer's input, the recorded decision's events counted per frame:
  the like-for-like row for the NumPy SNN. The loop runs the network once a
  frame on the frame's counts (`spikejax.vision.edges.sync_step`), the NumPy
  one event by event (the spikes differ where a frame's events would cross
  a threshold between them); the devices as for the vision.

Each spikejax implementation's one-core row runs in a process of its own held
to one core (`ONE_CORE_RUNS`: a one-device program in a process that may use
every core runs its large loops on all of them). On all cores each runs
twice: in this process (the C engine on one thread a core, the vision and
the SNN split over one device a core) and as one process a core, each held to
its core with a share of the batch, as `spikejax.workers` runs long jobs.

Compile time is reported apart from run time (the fastest of ``--repeats``
runs; the implementations of a batch are timed once a round,
`spikejax.benchmarking.interleaved`). ``vs_c_physics`` is a row's decisions/s
over the C physics' at the same batch on as many cores, ``x_numpy`` over the
NumPy SNN's on as many cores. `run` writes ``hexapod_prey_bench.csv`` and
``.png`` to ``--out``.
"""

from __future__ import annotations

import argparse
import contextlib
import math
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
from spikejax.commands import Command, add_cpu_devices, count, writes_output
from spikejax.devices import cpu_devices_for_run, in_chunks_on_cpu, shard_batch
from spikejax.errors import UserError

# The hexapod's env is imported where it is used: it makes JAX arrays when
# imported, which would start JAX before `run` presents the CPU as several devices.

__all__ = [
    "BATCHES",
    "QUICK_BATCHES",
    "ROW_FIELDS",
    "CPhysicsRun",
    "ClosedLoopRun",
    "NumpyVisionRun",
    "SnnRun",
    "VisionRun",
    "command",
    "decision_counts",
    "recorded_decision",
    "run",
]

BATCHES = (1, 4, 16, 64, 256, 1024)
QUICK_BATCHES = (2,)
LOOP_BUDGET = 128  # decisions (batch x steps) a timed run of the closed loop aims at
C_BUDGET = 2048  # decisions of the C physics alone
MIN_STEPS = 2
N_ROBOTS = 16
NUMPY_DECISIONS = 2  # decisions a NumPy process runs in one timed call

ROW_FIELDS = (
    "impl",
    "batch",
    "decisions",
    "compile_s",
    "run_s",
    "decisions_per_s",
    "physics_steps_per_s",
    "sim_s_per_wall_s",
    "vs_c_physics",
    "x_numpy",
    "cores",
    "parallel",
)


def _steps(batch: int, budget: int) -> int:
    return max(MIN_STEPS, budget // batch)


def _row(impl: str, batch: int, steps: int, compile_s: float, run_s: float, cores: int, unit: str) -> dict:
    from robots.hexapod.env import STEP_S

    rate = batch * steps / run_s
    return dict(
        impl=impl,
        batch=batch,
        decisions=batch * steps,
        compile_s=compile_s,
        run_s=run_s,
        decisions_per_s=rate,
        physics_steps_per_s=rate * round(STEP_S / 0.002),
        sim_s_per_wall_s=rate * STEP_S,
        vs_c_physics=math.nan,
        x_numpy=math.nan,
        cores=cores,
        parallel=cores_label(cores, unit),
    )


class CPhysicsRun:
    """MuJoCo C alone as a timer: ``mujoco.rollout`` of ``batch`` robots of the pool for ``steps`` G1 decisions.

    ``nthread`` threads (1: no pool). Each call is one rollout and returns its
    seconds; `info` is the row (``run_s``: the fastest call). `close` ends the pool.
    """

    def __init__(self, batch: int, steps: int, *, nthread: int = 1):
        from robots.hexapod import physics
        from robots.hexapod.gaits import PERIOD, required_spikes
        from robots.hexapod.legs import servo_targets, step_params

        self.models = [physics.load_model(*d) for d in physics.randomised(N_ROBOTS, seed=0)]
        self.batch, self.steps, self.nthread = batch, steps, nthread
        dt = self.models[0].opt.timestep
        raster = jnp.tile(jnp.asarray(required_spikes(0, PERIOD)), (steps, 1))
        substeps = int(round(0.32 / dt))
        t = jnp.arange(steps * substeps, dtype=jnp.float32) * dt
        control = np.asarray(servo_targets(step_params(), raster, t), np.float64)
        self.control = np.ascontiguousarray(np.broadcast_to(control, (batch, *control.shape)))
        standing = np.stack([physics.standing_state(m) for m in self.models])
        self.robots = [self.models[i % N_ROBOTS] for i in range(batch)]
        self.state = np.stack([standing[i % N_ROBOTS] for i in range(batch)])
        self.threads = nthread if batch >= nthread and nthread > 1 else 0
        self.datas = [mujoco.MjData(self.models[0]) for _ in range(max(self.threads, 1))]
        self.out = np.empty((batch, control.shape[0], self.state.shape[1]))
        self.pool = mj_rollout.Rollout(nthread=self.threads)
        self.pool.__enter__()
        self.run_s = math.inf

    def __call__(self) -> float:
        t0 = time.perf_counter()
        self.pool.rollout(
            self.robots,
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
        return _row("MuJoCo C physics only", self.batch, self.steps, 0.0, self.run_s, self.nthread, "thread")

    def close(self) -> None:
        self.pool.__exit__(None, None, None)


def _scenes(batch: int):
    from robots.hexapod import prey as prey_mod

    keys = jax.random.split(jax.random.key(0), batch)
    return keys, jax.vmap(lambda k: prey_mod.sample_scene(jax.random.fold_in(k, 0), 1))(keys)


class ClosedLoopRun:
    """``jax.jit(jax.vmap(run))`` of ``batch`` hexapods hunting for ``steps`` decisions, the SNN steering, as a timer.

    One CPU device, the C engine on ``threads`` threads (not split over
    devices: `jax.pure_callback` moves every shard's operands to the first CPU
    device, and two shards' physics callbacks at once deadlocked there at
    batch 64); compiled ahead at construction (``compile_s``). Each call runs
    it once. `info` is the row.
    """

    def __init__(self, batch: int, steps: int, threads: int = 1):
        from robots.hexapod import controllers
        from robots.hexapod.env import STEP_S, HexapodEnv

        # A member whose episode ends (a capture) still computes every step and keeps its final state
        # (`HexapodEnv.step`), so each costs the same; the rest run to the time limit.
        env = HexapodEnv(n_robots=N_ROBOTS, seconds=(steps + 1) * STEP_S, nthread=threads)
        init, act = controllers.CONTROLLERS["snn"]

        def one(key, scene):
            state, cstate = env.reset(key, scene), init(jax.random.fold_in(key, 2))

            def body(carry, _):
                s, c = carry
                c, action = act(c, s)
                return (env.step(s, action), c), None

            final = jax.lax.scan(body, (state, cstate), None, length=steps)[0][0]
            return final.info["events"], final.info["steps"]

        self.batch, self.steps, self.threads = batch, steps, threads
        self.args = _scenes(batch)
        self.compiled, self.compile_s = compile_ahead(jax.vmap(one), *self.args)
        self.run_s = math.inf

    def __call__(self) -> float:
        t0 = time.perf_counter()
        events, steps = jax.block_until_ready(self.compiled(*self.args))
        seconds = time.perf_counter() - t0
        if not bool(jnp.all(steps >= 1)) or not bool(jnp.all(events >= 0)):
            raise RuntimeError("the closed loop made no step")
        self.run_s = min(self.run_s, seconds)
        return seconds

    @property
    def info(self) -> dict:
        row = _row("spikejax closed loop", self.batch, self.steps, self.compile_s, self.run_s, self.threads, "thread")
        row["parallel"] = "1 device, " + cores_label(self.threads, "C thread")
        return row


def recorded_decision():
    """One G1 decision of the nominal robot with a prey 0.9 m ahead: ``(track, scene, key)``."""
    from robots.hexapod import decisions
    from robots.hexapod import prey as prey_mod

    track = jnp.asarray(decisions.g1_step_tracks([(0.8, 1.0, 1.0)])[0])
    x0 = float(track[0, 0]) + 0.1 + 0.9
    xy = jnp.full((prey_mod.MAX_PREY, 2), 50.0).at[0].set(jnp.array([x0, 0.0]))
    alive = jnp.zeros((prey_mod.MAX_PREY,), bool).at[0].set(True)
    size = jnp.full((prey_mod.MAX_PREY,), prey_mod.PREY_SIZE)
    return track, prey_mod.PreyScene(jnp.zeros(3), xy, size, alive), jax.random.key(5)


class VisionRun:
    """`decisions.decide` (render, DVS, visual SNN) of ``batch`` recorded decisions ``steps`` times, as a timer."""

    def __init__(self, batch: int, steps: int, devices: int = 1):
        from robots.hexapod import decisions

        track, scene, key = recorded_decision()
        keys = jax.random.split(key, batch)
        # Track and scene are arguments, one a member: as constants XLA would render them at compile time.
        tracks, scenes = jax.tree.map(lambda a: jnp.broadcast_to(a, (batch, *a.shape)), (track, scene))

        def one(k, tr, sc):
            def body(sums, kk):
                # The gaits too: XLA drops the whole visual SNN from a program whose result is the events alone.
                d = decisions.decide(tr, sc, kk)
                return (sums[0] + d.events, sums[1] + d.gait + d.gait_ordered), None

            zero = jnp.zeros((), jnp.int32)
            return jax.lax.scan(body, (zero, zero), jax.random.split(k, steps))[0]

        self.batch, self.steps, self.devices, self.args = batch, steps, devices, (keys, tracks, scenes)
        fn = shard_batch(jax.vmap(one), jax.devices()[:devices])
        self.compiled, self.compile_s = compile_ahead(fn, *self.args)
        self.run_s = math.inf

    def __call__(self) -> float:
        t0 = time.perf_counter()
        events, _ = jax.block_until_ready(self.compiled(*self.args))
        seconds = time.perf_counter() - t0
        if not bool(jnp.all(events > 0)):
            raise RuntimeError("the vision saw no events")
        self.run_s = min(self.run_s, seconds)
        return seconds

    @property
    def info(self) -> dict:
        return _row("spikejax vision only", self.batch, self.steps, self.compile_s, self.run_s, self.devices, "device")


def decision_counts() -> np.ndarray:
    """The recorded decision's DVS events counted per pixel, one image a frame interval: ``(N_FRAMES - 1, h, w)``."""
    from robots.hexapod import decisions

    track, scene, key = recorded_decision()
    # Track and scene as arguments: as constants XLA would render them at compile time.
    _, (counts, _) = jax.jit(lambda *a: decisions.decide(*a, with_spikes=True))(track, scene, key)
    return np.asarray(counts)


def decision_events() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The recorded decision's DVS events ``(xs, ys, ts)``: each frame's counts as that many events at its time."""
    from robots.hexapod import decisions

    counts = decision_counts()
    xs, ys, ts = [], [], []
    for k, image in enumerate(counts, start=1):
        y, x = np.nonzero(image)
        n = image[y, x]
        xs.append(np.repeat(x, n)), ys.append(np.repeat(y, n))
        ts.append(np.full(int(n.sum()), k * decisions.FRAME_S))
    return np.concatenate(xs), np.concatenate(ys), np.concatenate(ts)


class SnnRun:
    """The visual SNN alone, as the loop runs it, on the NumPy peer's input, ``batch`` members ``steps`` times, as a timer.

    `spikejax.vision.edges.sync_step` once a frame over `decision_counts` (the
    count images whose events `NumpyVisionRun` gets), from rest, and the
    winner-take-all: what `decisions.decide` does after its DVS, in its chunks
    of `decisions.DECIDE_CHUNK` members on a CPU. Decision ``k``
    runs ``k`` gait cycles later in time (the same network: each starts at
    rest), so that no run repeats another's arithmetic for XLA to hoist.
    """

    def __init__(self, batch: int, steps: int, devices: int = 1):
        from robots.hexapod import camera as cam
        from robots.hexapod import decisions
        from robots.hexapod.env import STEP_S
        from robots.hexapod.vision import FORWARD, vision_params
        from spikejax.vision import edges

        config, params = cam.EDGE_CONFIG, vision_params(cam.EDGE_CONFIG)
        # Stored a byte a count (at most `decisions.MAX_PER_PIXEL` a pixel and interval, and the noise): reading
        # the stored images is the timer's cost, not the network's (int32 made it about a tenth of the run).
        counts = decision_counts()
        counts = jnp.asarray(counts, jnp.int8 if counts.max() <= np.iinfo(np.int8).max else jnp.int32)
        frame_t = jnp.arange(1, counts.shape[0] + 1, dtype=jnp.float32) * decisions.FRAME_S

        def one(images):
            def decide(total, k):
                t0 = k.astype(jnp.float32) * STEP_S

                def frame(snn, x):
                    return edges.sync_step(config, params, snn, *x)[0], None

                snn = jax.lax.scan(frame, edges.init(config, t0), (images, t0 + frame_t))[0]
                return total + edges.winner(snn.counts["out"], jnp.int32(FORWARD)) + snn.counts["filter"], None

            return jax.lax.scan(decide, jnp.zeros((), jnp.int32), jnp.arange(steps))[0]

        self.batch, self.steps, self.devices = batch, steps, devices
        self.args = (jnp.broadcast_to(counts, (batch, *counts.shape)),)
        # In chunks of members, as `decisions.decide` runs the network in the loop.
        fn = shard_batch(jax.vmap(in_chunks_on_cpu(one, decisions.DECIDE_CHUNK)), jax.devices()[:devices])
        self.compiled, self.compile_s = compile_ahead(fn, *self.args)
        self.run_s = math.inf

    def __call__(self) -> float:
        t0 = time.perf_counter()
        total = jax.block_until_ready(self.compiled(*self.args))
        seconds = time.perf_counter() - t0
        if not bool(jnp.all(total > 0)):
            raise RuntimeError("the visual SNN made no filter spike")
        self.run_s = min(self.run_s, seconds)
        return seconds

    @property
    def info(self) -> dict:
        return _row(
            "spikejax visual SNN only", self.batch, self.steps, self.compile_s, self.run_s, self.devices, "device"
        )


ONE_CORE_RUNS = {"loop": ClosedLoopRun, "vision": VisionRun, "snn": SnnRun}
"""The spikejax timers, each also run on one core in a process of its own (`spikejax.benchmarking.HeldToOneCore`):
a one-device program in a process free to use every core runs its large loops on all of them (at batch 64 the
closed loop took 6.8 ms a decision in a free process and 10.0 held to one core, the vision 4.8 and 7.8;
docs/BENCHMARKS.md)."""


class NumpyVisionRun:
    """`reference.reference_vision` on the recorded decision's events, `NUMPY_DECISIONS` times a call, as a timer.

    ``index`` is the process's place in a pool (`spikejax.benchmarking.Processes`); every process runs its own.
    """

    def __init__(self, index: int = 0):
        from robots.hexapod import camera as cam
        from robots.hexapod.vision import vision_params

        self.config = cam.EDGE_CONFIG
        self.params = vision_params(self.config)
        self.events = decision_events()
        self.run_s = math.inf

    def __call__(self) -> float:
        from robots.hexapod.reference import reference_vision

        t0 = time.perf_counter()
        for _ in range(NUMPY_DECISIONS):
            counts = reference_vision(self.config, self.params, *self.events)
        seconds = time.perf_counter() - t0
        if counts["filter"] == 0:
            raise RuntimeError("the NumPy network made no filter spike")
        self.run_s = min(self.run_s, seconds)
        return seconds

    @property
    def info(self) -> dict:
        return {"events": int(self.events[0].size)}


def _plot(rows: list[dict], path: Path) -> None:
    plot_rows(
        rows,
        path,
        x="batch",
        y="decisions_per_s",
        series=lambda r: f"{r['impl']}, {r['parallel']}",
        xbase=2,
        size=(6.5, 4),
        xlabel="batch (hexapods)",
        ylabel="decisions/s (0.32 s gait cycles)",
        title="hexapod predator-prey loop: throughput, compile time excluded",
    )


def _add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--trials", type=count, default=None, help="the largest batch of hexapods (default 1024)")
    parser.add_argument("--out", default=None, help="write hexapod_prey_bench.csv and .png here")
    parser.add_argument("--quick", action="store_true", help="a batch of 2, a short run")
    parser.add_argument("--repeats", type=count, default=None, help="timed rounds, the best kept (default 2)")
    add_cpu_devices(parser, peers="MuJoCo C's threads and the NumPy pool's processes")
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bar")


@writes_output("bench hexapod-prey")
def run(
    *,
    trials: int | None = None,
    out: str | None = None,
    quick: bool = False,
    repeats: int | None = None,
    cpu_devices: int | None = None,
    no_progress: bool = False,
) -> int:
    """``spikejax bench hexapod-prey``: print the table; write ``hexapod_prey_bench.csv`` and ``.png`` to ``out``.

    Args:
        trials: caps the batch sizes timed (default: up to 1024).
        out: a directory for the table and figure (None: print only).
        quick: time a batch of 2, briefly.
        repeats: timed rounds per batch, the best kept (default 2).
        cpu_devices: CPU devices JAX presents (default: one per core); the
            all-cores rows split the batch over them and give MuJoCo C and the
            NumPy pool as many threads and processes.
        no_progress: hide the progress bar.
    """
    batches = QUICK_BATCHES if quick else BATCHES
    if trials is not None:
        batches = tuple(b for b in batches if b <= trials) or (trials,)
    repeats = 2 if repeats is None else repeats
    if repeats < 1:
        raise UserError(f"--repeats must be at least 1, got {repeats}")
    n_dev = cpu_devices_for_run(cpu_devices)
    loop_budget, c_budget = (4, 8) if quick else (LOOP_BUDGET, C_BUDGET)
    print(machine_banner(n_dev, mujoco=mujoco.__version__))
    print(
        "hexapod decision: a 0.32 s gait cycle = 160 physics steps of 2 ms, 16 frames of 160 x 256, "
        "DVS, visual SNN, winner-take-all"
    )
    from tqdm import tqdm

    cores = [1] + ([n_dev] if n_dev > 1 else [])
    rows = []
    with contextlib.ExitStack() as stack:
        numpy_pools = {p: stack.enter_context(Processes(NumpyVisionRun, processes=p, index_arg="index")) for p in cores}
        events = numpy_pools[1].info()[0]["events"]
        print(f"NumPy peer: the recorded decision's {events:,} events, {NUMPY_DECISIONS} decisions a process a call")
        bar = tqdm(batches, desc="hexapod-prey bench", disable=no_progress)
        for i, batch in enumerate(bar):
            n_loop, n_c = _steps(batch, loop_budget), _steps(batch, c_budget)
            with contextlib.ExitStack() as inner:
                runs = {}
                for p in cores:  # in a process of its own: beside the env's C pool, a second one can hang
                    runs["c", p] = inner.enter_context(Processes(CPhysicsRun, batch, n_c, nthread=p))
                for kind, timer in ONE_CORE_RUNS.items():
                    runs["held", 1, kind] = inner.enter_context(Processes(HeldToOneCore, timer, batch, n_loop, 1))
                if n_dev > 1 and batch >= n_dev:
                    for kind, timer in ONE_CORE_RUNS.items():  # in this process; the C engine on a thread a core
                        runs[kind, n_dev] = timer(batch, n_loop, n_dev)
                    for kind, timer in ONE_CORE_RUNS.items() if batch % n_dev == 0 else ():
                        runs["held", n_dev, kind] = inner.enter_context(
                            Processes(
                                HeldToOneCore, timer, batch // n_dev, n_loop, 1, processes=n_dev, index_arg="index"
                            )
                        )
                if i == 0:
                    runs.update({("numpy", p): pool for p, pool in numpy_pools.items()})
                best = interleaved(runs, repeats)
                for key, timer in runs.items():
                    if key[0] == "held":  # processes held to one core each, each the batch or a share of it
                        p, one = key[1], timer.info()[0]
                        new = _row(one["impl"], batch, n_loop, one["compile_s"], best[key], p, "process")
                        new["parallel"] = (
                            held_row(one)["parallel"]
                            if p == 1
                            else f"{p} processes, one a core, {one['parallel']} each"
                        )
                    elif key[0] == "numpy":
                        p = key[1]
                        new = _row(
                            "NumPy visual SNN (events given)", 1, NUMPY_DECISIONS * p, 0.0, best[key], p, "process"
                        )
                    elif key[0] == "c":
                        new = timer.info()[0]
                    else:
                        new = timer.info
                    rows.append(new)
                    bar.write(
                        f"  {new['impl']}, batch {new['batch']}, {new['parallel']}: "
                        f"{new['decisions_per_s']:,.1f} decisions/s (compile {new['compile_s']:.1f} s)"
                    )
    add_ratios(
        rows,
        "vs_c_physics",
        "decisions_per_s",
        lambda p, r: p["impl"].startswith("MuJoCo") and p["batch"] == r["batch"] and not r["impl"].startswith("NumPy"),
    )
    add_ratios(rows, "x_numpy", "decisions_per_s", lambda p, r: p["impl"].startswith("NumPy"))
    print(
        f"{'implementation':38s} {'batch':>5s} {'cores':>5s} {'compile s':>9s} {'decisions/s':>11s} "
        f"{'sim s/s':>8s} {'vs C':>6s} {'x NumPy':>8s}  how"
    )
    for r in rows:
        print(
            f"{r['impl']:38s} {r['batch']:5d} {r['cores']:5d} {r['compile_s']:9.1f} {r['decisions_per_s']:11,.1f} "
            f"{r['sim_s_per_wall_s']:8.1f} {r['vs_c_physics']:6.2f} {r['x_numpy']:8.1f}  {r['parallel']}"
        )
    print(
        "  vs C: over MuJoCo C's physics alone at the same batch on as many cores; "
        "x NumPy: over the NumPy visual SNN on as many cores"
    )
    if out:
        out = Path(out)
        write_csv(out / "hexapod_prey_bench.csv", rows, ROW_FIELDS)
        _plot(rows, out / "hexapod_prey_bench.png")
        print(f"wrote {out / 'hexapod_prey_bench.csv'} and {out / 'hexapod_prey_bench.png'}")
    return 0


command = Command(
    help="closed-loop hexapod decisions per second, against MuJoCo C physics and the visual SNN in NumPy",
    add_arguments=_add_arguments,
    run=run,
    description=__doc__.splitlines()[0],
)
