"""``spikejax bench snake-rstdp``: snake R-STDP training, control steps per second, spikejax against NEST in the loop.

A control step is 20 ms of one snake's training (Sec. II-D, III of the snake
R-STDP paper): the physics, the head camera and its events, the grid and
joint encoders (Eq. (2)-(3)), the rewards (Eq. (9)-(13)), 200 neural steps
of 0.1 ms of the network with R-STDP (Eq. (6)-(8)) and the decoding
(Eq. (4)-(5)). Three implementations are timed in the same run:

- ``spikejax closed loop``: ``jax.jit(jax.vmap(rollout))`` of
  `robots.snake.rstdp.controller` on `robots.snake.training.env_for`'s env
  (the ``"mujoco"`` backend), training on the 8 with its resets, at each
  batch; on one device with MuJoCo on one thread (one core), and split over
  every CPU device (`spikejax.devices.shard_batch`) with MuJoCo on one
  thread a core (all cores).
- ``env only``: the same program with a controller that costs nothing (a
  zero action), at the same batch and cores, so that the network's share of a
  batched control step is ``1 - env_s / closed_loop_s`` (``network_share``).
- ``NEST in the loop``: the paper's setup, `robots.snake.peers.NestLoopRun`:
  one snake, the JAX env stepped for it (jitted, one snake) and NEST 3.10
  simulating the network 20 ms a step, the rates and rewards set with
  ``SetStatus``; one process on one core, and one process a core (each its
  own snake and NEST kernel, ``local_num_threads=1``), as a NEST user with
  several cores would run several trainings.

Compile time (``lower(...).compile()``) and NEST's build are reported apart
from run time, which is the fastest of ``--repeats`` interleaved rounds
(`spikejax.benchmarking.interleaved`). ``vs_nest`` is a row's control
steps/s over NEST's on as many cores (one against one, all against all).
A timed run is ``--steps`` control steps, fewer at large batches (at most
`STEP_BUDGET` snake-steps a run, at least `MIN_STEPS` steps).

`run` writes ``snake_rstdp.csv`` and ``snake_rstdp.png`` to ``--out``.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import time
from pathlib import Path

import jax
import jax.numpy as jnp

from spikejax.benchmarking import (
    JaxRun,
    Processes,
    add_ratios,
    cores_label,
    interleaved,
    machine_banner,
    plot_rows,
    write_csv,
)
from spikejax.commands import Command, add_cpu_devices, count, writes_output
from spikejax.errors import UserError

# The snake's modules are imported where they are used: they make JAX arrays when
# imported, which would start JAX before the CPU is presented as several devices.

__all__ = [
    "BATCHES",
    "ENV_ONLY",
    "MIN_STEPS",
    "OURS",
    "PEER",
    "ROW_FIELDS",
    "STEP_BUDGET",
    "closed_loop_timer",
    "command",
    "measure",
    "report",
    "run",
]

BATCHES = (1, 4, 16, 64, 256, 1024)
STEP_BUDGET = 25_600  # snake control steps a timed run of a batch aims at, at most
MIN_STEPS = 5
OURS = "spikejax closed loop"
ENV_ONLY = "env only (zero-cost controller)"
PEER = "NEST in the loop"

ROW_FIELDS = (
    "impl",
    "topology",
    "schedule",
    "batch",
    "control_steps",
    "compile_s",
    "run_s",
    "steps_per_s",
    "sim_s_per_wall_s",
    "network_share",
    "vs_nest",
    "cores",
    "parallel",
)


def _steps_for(batch: int, steps: int) -> int:
    return max(min(MIN_STEPS, steps), min(steps, STEP_BUDGET // batch))


def closed_loop_timer(topology: str, schedule: str, batch: int, steps: int, devices: int, *, env_only: bool = False):
    """``jit(vmap(rollout))`` of ``batch`` snakes training for ``steps`` control steps, compiled ahead; a timer.

    Args:
        topology, schedule: the network (`robots.snake.rstdp.NetworkConfig`).
        batch: snakes (seeds 0 .. batch - 1).
        steps: control steps per timed run (each run starts from the same state).
        devices: CPU devices the batch is split over (MuJoCo gets as many threads).
        env_only: a zero action instead of the network (the env's cost alone).

    Returns:
        ``(timer, compile_s)``: a `spikejax.benchmarking.JaxRun` and the compile seconds.
    """
    from robots.snake import training
    from robots.snake.rstdp import NetworkConfig, controller, network_params
    from spikejax import rollout
    from spikejax.devices import shard_batch

    env = training.env_for("eight", nthread=devices)
    config = NetworkConfig(topology=topology, schedule=schedule)
    params = network_params(config)
    initial, loop = training._members(env, config, params, list(range(batch)), False)
    if env_only:
        ctrl = rollout.Controller(
            step=lambda p, s, env_state, *, key: (s, jnp.zeros((2,), jnp.float32), {}),
            on_reset=lambda p, s: s,
        )
        loop = loop._replace(controller=jnp.zeros((batch,), jnp.float32))
    else:
        ctrl = controller(config)

    def reset(state, failed, completed, *, key):
        mirror = jnp.where(completed, ~state.info["mirror"], state.info["mirror"])
        return env.restart(initial, state, mirror)

    def one(lp):
        lp, _ = rollout.rollout(env.step, reset, ctrl, params, lp, steps, every=steps)
        # The env's frames are returned so that XLA cannot drop the camera from a loop whose controller ignores them.
        return lp.env.obs, lp.steps, jnp.sum(lp.env.info["frame"]) + jnp.sum(lp.env.info["prev_frame"])

    if devices > jax.device_count():
        raise UserError(f"{devices} devices asked, JAX presents {jax.device_count()}")
    fn = shard_batch(jax.vmap(one), jax.devices()[:devices])
    t0 = time.perf_counter()
    compiled = fn.compile(loop)
    return JaxRun(compiled, loop), time.perf_counter() - t0


def _row(impl, topology, schedule, batch, steps, compile_s, run_s, cores, unit, dt_s) -> dict:
    per_s = batch * steps / run_s
    return dict(
        impl=impl,
        topology=topology,
        schedule=schedule,
        batch=batch,
        control_steps=steps,
        compile_s=compile_s,
        run_s=run_s,
        steps_per_s=per_s,
        sim_s_per_wall_s=per_s * dt_s,
        network_share=math.nan,
        vs_nest=math.nan,
        cores=cores,
        parallel=cores_label(cores, unit),
    )


def _parse_batches(batches) -> tuple[int, ...]:
    if batches is None:
        return BATCHES
    if isinstance(batches, str):
        try:
            batches = [int(b) for b in batches.split(",") if b.strip()]
        except ValueError:
            raise UserError(f"--batches takes whole numbers separated by commas, got {batches!r}") from None
    batches = tuple(int(b) for b in batches)
    if not batches or min(batches) < 1:
        raise UserError(f"--batches must be whole numbers >= 1, got {batches}")
    return batches


def measure(
    *,
    batches=None,
    steps: int = 100,
    repeats: int = 2,
    topology: str = "basic",
    schedule: str = "exact",
    cpu_devices: int | None = None,
    processes: bool = True,
    no_progress: bool = False,
) -> list[dict]:
    """Time every implementation (see the module docstring); returns the rows, ratios and shares filled in.

    Args:
        batches: snakes per batch (a tuple, or ``"1,16,256"``).
        steps: control steps per timed run (fewer at large batches: `STEP_BUDGET`).
        repeats: interleaved timed rounds, the best kept.
        topology, schedule: the network timed.
        cpu_devices: CPU devices JAX presents (default one per core); also NEST's processes.
        processes: NEST in processes of its own (False: the one-core peer in this process, no all-cores peer).
        no_progress: hide the progress bar.
    """
    from spikejax.devices import cpu_devices_for_run

    n_dev = cpu_devices_for_run(cpu_devices)
    batches = _parse_batches(batches)
    if steps < 1 or repeats < 1:
        raise UserError(f"--steps and --repeats must be >= 1, got {steps} and {repeats}")
    from robots.snake.peers import NestLoopRun
    from robots.snake.rstdp import NetworkConfig

    config = NetworkConfig(topology=topology, schedule=schedule)  # validates both
    dt_s = 0.001 * config.dt * config.substeps
    from tqdm import tqdm

    rows = []
    with contextlib.ExitStack() as stack:
        peers = {}
        counts = [1] + ([n_dev] if n_dev > 1 and processes else [])
        for p in counts:
            if processes:
                peers[p] = stack.enter_context(Processes(NestLoopRun, topology, steps, processes=p, index_arg="seed"))
            else:
                peers[p] = NestLoopRun(topology, steps)
        bar = tqdm(batches, desc="snake-rstdp bench", disable=no_progress)
        for batch in bar:
            n = _steps_for(batch, steps)
            runs, made = {}, {}
            for devices in [1] + ([n_dev] if n_dev > 1 and batch >= n_dev else []):
                for kind in (OURS, ENV_ONLY):
                    timer, compile_s = closed_loop_timer(
                        topology, schedule, batch, n, devices, env_only=kind == ENV_ONLY
                    )
                    runs[kind, devices] = timer
                    made[kind, devices] = compile_s
            for p, peer in peers.items():
                runs[PEER, p] = peer
            best = interleaved(runs, repeats)
            for (kind, cores), seconds in best.items():
                if kind == PEER:
                    continue
                obs, done, _ = runs[kind, cores].result
                if not bool(jnp.all(jnp.isfinite(obs))) or not bool(jnp.all(done == n)):
                    raise RuntimeError(f"{kind}, batch {batch}: non-finite observations or steps missing")
                unit = "device" if cores > 1 else "core"
                rows.append(_row(kind, topology, schedule, batch, n, made[kind, cores], seconds, cores, unit, dt_s))
            for p, peer in peers.items():
                build = max(i["build_s"] for i in peer.info()) if processes else peer.info["build_s"]
                # p snakes, one a process, each ``steps`` steps in the slowest process's seconds
                rows.append(_row(PEER, topology, schedule, p, steps, build, best[PEER, p], p, "process", dt_s))
            bar.write("  " + ", ".join(f"{r['impl']} {r['cores']}c {r['steps_per_s']:,.0f}/s" for r in rows[-6:]))
    # the peer's rows of every batch: keep the fastest per cores (NEST's one snake does not depend on our batch)
    peer_rows = {}
    for r in rows:
        if r["impl"] == PEER and (r["cores"] not in peer_rows or r["run_s"] < peer_rows[r["cores"]]["run_s"]):
            peer_rows[r["cores"]] = r
    rows = [r for r in rows if r["impl"] != PEER] + list(peer_rows.values())
    for r in rows:
        if r["impl"] == OURS:
            env = next(
                e for e in rows if e["impl"] == ENV_ONLY and e["batch"] == r["batch"] and e["cores"] == r["cores"]
            )
            r["network_share"] = 1.0 - env["run_s"] / r["run_s"]
    add_ratios(rows, "vs_nest", "steps_per_s", lambda p, r: p["impl"] == PEER)
    return rows


def _plot(rows: list[dict], path: Path) -> None:
    plot_rows(
        rows,
        path,
        x="batch",
        y="steps_per_s",
        series=lambda r: f"{r['impl']}, {r['parallel']}",
        flat=lambda r: r["impl"] == PEER,
        xbase=2,
        size=(6.5, 4.2),
        xlabel="batch (snakes)",
        ylabel="control steps/s (20 ms, training)",
        title=f"snake R-STDP training ({rows[0]['topology']}), compile time excluded",
    )


def _add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", default=None, help="write snake_rstdp.csv and snake_rstdp.png here")
    parser.add_argument(
        "--batches", default=None, help=f"batch sizes, comma-separated (default {','.join(map(str, BATCHES))})"
    )
    parser.add_argument("--repeats", type=count, default=None, help="timed rounds, the best kept (default 2)")
    parser.add_argument("--steps", type=count, default=None, help="control steps per timed run (default 100)")
    parser.add_argument("--topology", default=None, help="basic (default), basic-head, unified or separated")
    parser.add_argument("--schedule", default=None, help="R-STDP schedule: exact (default) or nest")
    add_cpu_devices(parser, peers="NEST's processes")
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bar")


@writes_output("bench snake-rstdp")
def run(
    *,
    out: str | None = None,
    batches: str | None = None,
    repeats: int | None = None,
    steps: int | None = None,
    topology: str | None = None,
    schedule: str | None = None,
    cpu_devices: int | None = None,
    no_progress: bool = False,
) -> int:
    """``spikejax bench snake-rstdp``: print the table; write ``snake_rstdp.csv`` and ``.png`` to ``out``.

    Args:
        out: a directory for the table and figure (None: print only).
        batches: comma-separated batch sizes (default `BATCHES`).
        repeats: timed rounds, the best kept (default 2).
        steps: control steps per timed run (default 100; fewer at large batches).
        topology: the network (default ``basic``).
        schedule: the R-STDP schedule (default ``exact``).
        cpu_devices: CPU devices JAX presents and NEST processes (default one per core).
        no_progress: hide the progress bar.
    """
    rows = measure(
        batches=batches,
        steps=100 if steps is None else steps,
        repeats=2 if repeats is None else repeats,
        topology=topology or "basic",
        schedule=schedule or "exact",
        cpu_devices=cpu_devices,
        no_progress=no_progress,
    )
    report(rows, out)
    return 0


def report(rows: list[dict], out=None) -> None:
    """Print the table of `measure`'s rows; with ``out``, write ``snake_rstdp.csv`` and ``snake_rstdp.png`` there."""
    import mujoco
    import nest

    print(machine_banner(mujoco=mujoco.__version__, nest=getattr(nest, "__version__", "3")))
    print(
        f"{'implementation':34s} {'batch':>5s} {'cores':>5s} {'steps':>5s} {'compile s':>9s} {'steps/s':>10s} "
        f"{'sim s/s':>8s} {'net share':>9s} {'vs NEST':>8s}"
    )
    for r in rows:
        share = "" if math.isnan(r["network_share"]) else f"{r['network_share']:.0%}"
        print(
            f"{r['impl']:34s} {r['batch']:5d} {r['cores']:5d} {r['control_steps']:5d} {r['compile_s']:9.1f} "
            f"{r['steps_per_s']:10,.0f} {r['sim_s_per_wall_s']:8.2f} {share:>9s} {r['vs_nest']:8.1f}"
        )
    print(
        "  steps/s: 20 ms control steps of training, all snakes together; net share: 1 - env-only time / "
        "closed-loop time at the same batch and cores; vs NEST: against NEST in the loop on as many cores "
        "(one snake a process); NEST's compile s is its build"
    )
    if out:
        out = Path(out)
        write_csv(out / "snake_rstdp.csv", rows, ROW_FIELDS)
        _plot(rows, out / "snake_rstdp.png")
        print(f"wrote {out / 'snake_rstdp.csv'} and {out / 'snake_rstdp.png'}")


command = Command(
    help="snake R-STDP training control steps per second, spikejax against NEST in the loop",
    add_arguments=_add_arguments,
    run=run,
    description=__doc__.splitlines()[0],
)
