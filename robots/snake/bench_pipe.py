"""``spikejax bench snake-pipe``: whole-loop env-steps/s of the snake pipe loop, beside Table 1 of the pipe-tracking paper.

One env-step is one 20 ms control step of one snake in
`robots.snake.pipe_env.PipeEnv`, i.e. one camera frame through everything
the snake pipe-tracking paper's Fig. 1 loop does: the gait and the MuJoCo C
physics with the pipe bodies, the 128 x 128 head camera on the pipe scene,
the DVS, the spiking Hough grid(s) (Alg. 1), Alg. 2-3 once per slot of 5
steps, the bang-bang controller with its state machine
(`robots.snake.pipe_controller.bang_bang`) and the truth for the metrics.
Placements are sampled per episode (`robots.snake.pipes.sample`). Cases
(`CASES`):

- ``line-sync``: standing pipes, the paper's 180 x 180 line grid in sync
  mode (`robots.snake.pipe_env.default_tracker`), the frame-difference DVS:
  Table 1's "standing pipe" rows.
- ``circle-sync``: lying pipes, the line grid and the reduced circle grid
  (`default_tracker(circle=True)`: centres every pixel, 32 radii), sync:
  Table 1's "lying pipe" rows.
- ``line-async``: standing pipes, the line grid in async mode (every event
  in time order through Alg. 1) on the contrast-threshold DVS, whose events
  carry sub-frame times (``PipeEnv(dvs="contrast")``).

Each case runs on one core (one CPU device, MuJoCo C on one thread, in a
process of its own held to one core: in a process free to use every core XLA
splits the loop's image-sized work over all of them, 1.5x faster at batch 64,
`spikejax.benchmarking.HeldToOneCore`) and on all cores (the batch split over
every CPU device, `spikejax.devices.shard_batch`, MuJoCo on one thread a
device), at every batch of ``--batches``. Compile
time (``lower(...).compile()``) is reported apart from run time, which is
the fastest of ``--repeats`` rounds; the runs of a batch are timed in
interleaved rounds (`spikejax.benchmarking.interleaved`). A timed run is
at most ``--slots`` slots, fewer at large batches (`BUDGET` env-steps a run,
at least `MIN_SLOTS` slots).

There is no peer in the same run: no other simulator runs this loop. The
figures beside ours are the paper's Table 1 (`TABLE_1`: frames/s of its SNN
alone, single-threaded CPU and a 2014-15 laptop/desktop GPU, the simulator
apart): ``vs_paper_cpu`` and ``vs_paper_gpu`` divide a row by the best
figure of its kind of pipe (standing 1.63 and 40.74, lying 0.36 and 22.35
frames/s, both from the NRP rows), the least flattering reading.

``--stages`` adds a breakdown at one batch (``--stage-batch``, all cores):
the same loop cut after each part, every part cumulative (physics; +
render; + DVS; + the grids' Alg. 1 on every step; the whole loop with Alg.
2-3, control and truth), so a part's cost is the difference of two rows.

`run` writes ``snake_pipe_bench.csv``, ``snake_pipe_bench.png`` and, with
``--stages``, ``snake_pipe_stages.csv`` to ``--out``.
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from spikejax.benchmarking import (
    HeldToOneCore,
    JaxRun,
    Processes,
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
    "BUDGET",
    "CASES",
    "MIN_SLOTS",
    "ROW_FIELDS",
    "STAGES",
    "STAGE_FIELDS",
    "TABLE_1",
    "command",
    "env_for",
    "loop_timer",
    "measure",
    "measure_stages",
    "report",
    "run",
    "stage_timer",
]

BATCHES = (1, 4, 16, 64, 256)
CASES = ("line-sync", "circle-sync", "line-async")
# Env-steps (batch x control steps) a timed run aims at, at most, per case.
BUDGET = {"line-sync": 6_400, "circle-sync": 1_280, "line-async": 3_200}
MIN_SLOTS = 2
# Table 1 of the snake pipe-tracking paper: frames/s of its SNN, CPU (single thread) and GPU.
TABLE_1 = {
    "standing": {"V-REP": (0.21, 1.71), "NRP": (1.63, 40.74)},
    "lying": {"V-REP": (0.33, 3.22), "NRP": (0.36, 22.35)},
}
PIPE_OF_CASE = {"line-sync": "standing", "circle-sync": "lying", "line-async": "standing"}
STAGES = ("physics", "+ render", "+ DVS", "+ grids (Alg. 1)", "whole loop")

ROW_FIELDS = (
    "case",
    "pipe",
    "grids",
    "mode",
    "dvs",
    "batch",
    "control_steps",
    "compile_s",
    "run_s",
    "env_steps_per_s",
    "sim_s_per_wall_s",
    "paper_cpu_fps",
    "paper_gpu_fps",
    "vs_paper_cpu",
    "vs_paper_gpu",
    "events_per_step",
    "detected_slots",
    "cores",
    "parallel",
)
STAGE_FIELDS = (
    "case",
    "stage",
    "batch",
    "control_steps",
    "compile_s",
    "run_s",
    "env_steps_per_s",
    "ms_per_batch_step",
    "cores",
    "parallel",
)


def _best(pipe: str) -> tuple[float, float]:
    rows = TABLE_1[pipe].values()
    return max(r[0] for r in rows), max(r[1] for r in rows)


def env_for(case: str, nthread: int = 1):
    """The `robots.snake.pipe_env.PipeEnv` of a case of `CASES`, MuJoCo C on ``nthread`` threads."""
    from robots.snake import pipe_env

    if case not in CASES:
        raise UserError(f"case must be one of {', '.join(CASES)}, not {case!r}")
    if case == "circle-sync":
        return pipe_env.PipeEnv(situation="lying-right", tracker=pipe_env.default_tracker(circle=True), nthread=nthread)
    if case == "line-async":
        tracker = pipe_env.default_tracker()
        tracker = dataclasses.replace(tracker, detector=dataclasses.replace(tracker.detector, mode="async"))
        return pipe_env.PipeEnv(situation="standing-right", tracker=tracker, dvs="contrast", nthread=nthread)
    return pipe_env.PipeEnv(situation="standing-right", nthread=nthread)


def _slots_for(case: str, batch: int, slots: int, slot_steps: int) -> int:
    return max(MIN_SLOTS, min(slots, BUDGET[case] // (batch * slot_steps)))


def _program(env, slots: int, devices: int):
    """``shard_batch(vmap(episode))`` over ``devices`` CPU devices: per member the detections, events and the final obs."""
    from robots.snake import pipe_controller as pc
    from robots.snake import pipe_env
    from spikejax.devices import shard_batch

    params = pc.ControllerParams()

    def one(key):
        record, final = pipe_env.rollout(env, pc.bang_bang, params, key, slots)
        m = record["metrics"]
        return final.obs, jnp.sum(m["detected"]), jnp.sum(m["events"])

    if devices > jax.device_count():
        raise UserError(f"{devices} devices asked, JAX presents {jax.device_count()}")
    return shard_batch(jax.vmap(one), jax.devices()[:devices])


def loop_timer(case: str, batch: int, slots: int, devices: int):
    """The whole loop of ``case`` for ``batch`` snakes and ``slots`` slots on ``devices`` devices, compiled ahead.

    Returns:
        ``(timer, compile_s, env)``: a `spikejax.benchmarking.JaxRun` (its
        ``result``: final observations, detections and events per member).
    """
    env = env_for(case, nthread=1)
    keys = jax.random.split(jax.random.key(0), batch)
    fn = _program(env, slots, devices)
    t0 = time.perf_counter()
    compiled = fn.compile(keys)
    return JaxRun(compiled, keys), time.perf_counter() - t0, env


class _OneCoreLoop:
    """`loop_timer` on one device (a `spikejax.benchmarking.HeldToOneCore` timer): ``info`` is what `_row` needs of it."""

    def __init__(self, case: str, batch: int, slots: int):
        self._run, self.compile_s, _ = loop_timer(case, batch, slots, 1)

    def __call__(self) -> float:
        return self._run()

    @property
    def info(self) -> dict:
        obs, detected, events = self._run.result
        return {"compile_s": self.compile_s, "result": tuple(np.asarray(a) for a in (obs, detected, events))}


def _row(case, env, batch, slots, compile_s, run_s, cores, result) -> dict:
    steps = slots * env.slot_steps
    per_s = batch * steps / run_s
    cpu, gpu = _best(PIPE_OF_CASE[case])
    det = env.tracker.detector
    obs, detected, events = result
    if not bool(jnp.all(jnp.isfinite(obs))):
        raise RuntimeError(f"{case}, batch {batch}: non-finite observations")
    return dict(
        case=case,
        pipe=PIPE_OF_CASE[case],
        grids="line" + (" + circle" if det.circle is not None else ""),
        mode=det.mode,
        dvs=env.dvs,
        batch=batch,
        control_steps=steps,
        compile_s=compile_s,
        run_s=run_s,
        env_steps_per_s=per_s,
        sim_s_per_wall_s=per_s * env.dt,
        paper_cpu_fps=cpu,
        paper_gpu_fps=gpu,
        vs_paper_cpu=per_s / cpu,
        vs_paper_gpu=per_s / gpu,
        events_per_step=float(jnp.mean(events)) / steps,
        detected_slots=float(jnp.mean(detected)) / slots,
        cores=cores,
        parallel=cores_label(cores, "device" if cores > 1 else "core"),
    )


def _parse(text, allowed=None, name="--batches"):
    if isinstance(text, str):
        items = [t.strip() for t in text.split(",") if t.strip()]
    else:
        items = list(text)
    if allowed is None:
        try:
            items = [int(b) for b in items]
        except ValueError:
            raise UserError(f"{name} takes whole numbers separated by commas, got {text!r}") from None
        if not items or min(items) < 1:
            raise UserError(f"{name} must be whole numbers >= 1, got {text!r}")
        return tuple(items)
    bad = [c for c in items if c not in allowed]
    if bad or not items:
        raise UserError(f"{name} takes some of {', '.join(allowed)} separated by commas, got {text!r}")
    return tuple(items)


def measure(
    *,
    cases=CASES,
    batches=BATCHES,
    slots: int = 20,
    repeats: int = 3,
    cpu_devices: int | None = None,
    no_progress: bool = False,
) -> list[dict]:
    """Time every case at every batch on one core and on all (see the module docstring); returns the rows.

    Args:
        cases: some of `CASES` (a tuple, or ``"line-sync,circle-sync"``).
        batches: snakes per batch (a tuple, or ``"1,64"``).
        slots: slots per timed run at most (5 control steps each; fewer at large batches, `BUDGET`).
        repeats: interleaved timed rounds, the best kept.
        cpu_devices: CPU devices JAX presents (default one per core).
        no_progress: hide the progress bar.
    """
    from tqdm import tqdm

    from spikejax.devices import cpu_devices_for_run

    n_dev = cpu_devices_for_run(cpu_devices)
    cases, batches = _parse(cases, CASES, "--cases"), _parse(batches)
    if slots < 1 or repeats < 1:
        raise UserError(f"--slots and --repeats must be >= 1, got {slots} and {repeats}")
    rows = []
    bar = tqdm([(c, b) for c in cases for b in batches], desc="snake-pipe bench", disable=no_progress)
    for case, batch in bar:
        n = _slots_for(case, batch, slots, 5)
        with Processes(HeldToOneCore, _OneCoreLoop, case, batch, n) as one_core:
            runs = {1: one_core}
            if n_dev > 1 and batch >= n_dev:
                runs[n_dev], compile_all, _ = loop_timer(case, batch, n, n_dev)
            best = interleaved(runs, repeats)
            held = one_core.info()[0]
        env = env_for(case)
        for devices, seconds in best.items():
            compile_s, result = (
                (held["compile_s"], held["result"]) if devices == 1 else (compile_all, runs[devices].result)
            )
            rows.append(_row(case, env, batch, n, compile_s, seconds, devices, result))
            r = rows[-1]
            bar.write(
                f"  {case}, batch {batch}, {r['parallel']}: {r['env_steps_per_s']:,.0f} env-steps/s "
                f"({r['vs_paper_cpu']:,.0f}x the paper's CPU, {r['vs_paper_gpu']:,.1f}x its GPU; compile {compile_s:.1f} s)"
            )
    return rows


# ------------------------------------------------------------------ stages


def stage_timer(case: str, stage: str, batch: int, slots: int, devices: int):
    """The loop of ``case`` cut after ``stage`` (`STAGES`), ``batch`` snakes, ``slots`` slots, compiled ahead.

    The cut loops call the parts the env's step calls (the gait and physics,
    `robots.snake.camera.frame`, `spikejax.vision.dvs.frame_difference` or
    `spikejax.vision.dvs.step`, `spikejax.vision.stream.step`) in a
    ``lax.scan``, and return a sum of the last part's output so that nothing
    is dropped; ``"whole loop"`` is `loop_timer`'s program.

    Returns:
        ``(timer, compile_s, env)``.
    """
    from robots.snake import camera as cam
    from robots.snake import pipes
    from robots.snake.gait import joint_targets
    from spikejax.devices import shard_batch
    from spikejax.vision import dvs, stream

    if stage not in STAGES:
        raise UserError(f"stage must be one of {', '.join(STAGES)}, not {stage!r}")
    if stage == "whole loop":
        return loop_timer(case, batch, slots, devices)
    env = env_for(case, nthread=1)
    level = STAGES.index(stage)
    n = slots * env.slot_steps
    tr, tp = env.tracker, env.tracker_params

    def one(key):
        s = env.reset(key)
        scene, info = s.info["scene"], s.info

        def body(carry, _):
            phys, frame, dstate, tstate, acc = carry
            ctrl = joint_targets(env.gait, phys.time, jnp.zeros(()), 0.0, env.compensate)
            phys = env.physics.step(phys, ctrl)
            out = jnp.sum(phys.qpos)
            if level >= 1:
                new = cam.frame(phys, cam.pipe_scene(pipes.render_pipes(scene)))
                out = jnp.sum(new)
            if level >= 2:
                if env.dvs == "contrast":
                    k = jax.random.fold_in(info["dvs_key"], jnp.round(phys.time / env.dt).astype(jnp.int32))
                    dstate, events, _ = dvs.step(
                        info["dvs_params"], dstate, new, phys.time,
                        capacity=env.event_capacity, max_per_pixel=env.max_per_pixel, key=k,
                    )  # fmt: skip
                else:
                    events, _ = dvs.frame_difference(
                        frame, new, phys.time, threshold=info["params"].event_threshold, capacity=env.event_capacity
                    )
                out = jnp.sum(events.x * events.valid)
            if level >= 3:
                tstate = stream.step(tr, tp, tstate, events, phys.time)  # no slot ends: the buffer drops the rest
                out = jnp.sum(tstate.line_votes)
            frame = new if level >= 1 else frame
            return (phys, frame, dstate, tstate, acc + out), None

        dstate = info.get("dvs_state", jnp.zeros(()))
        carry = (s.pipeline_state, info["frame"], dstate, info["tracker"], jnp.zeros(()))
        carry, _ = jax.lax.scan(body, carry, None, length=n)
        return carry[-1]

    fn = shard_batch(jax.vmap(one), jax.devices()[:devices])
    keys = jax.random.split(jax.random.key(0), batch)
    t0 = time.perf_counter()
    compiled = fn.compile(keys)
    return JaxRun(compiled, keys), time.perf_counter() - t0, env


def measure_stages(
    *, case: str = "line-sync", batch: int = 64, slots: int = 20, repeats: int = 3, cpu_devices=None, no_progress=False
) -> list[dict]:
    """`STAGES` of ``case`` at ``batch`` on all CPU devices, timed in interleaved rounds; the rows of `STAGE_FIELDS`."""
    from tqdm import tqdm

    from spikejax.devices import cpu_devices_for_run

    n_dev = cpu_devices_for_run(cpu_devices)
    devices = n_dev if batch >= n_dev else 1
    n = _slots_for(case, batch, slots, 5)
    runs, made = {}, {}
    for stage in tqdm(STAGES, desc=f"stages of {case}", disable=no_progress):
        timer, compile_s, env = stage_timer(case, stage, batch, n, devices)
        runs[stage], made[stage] = timer, (compile_s, env)
    best = interleaved(runs, repeats)
    rows = []
    for stage, seconds in best.items():
        compile_s, env = made[stage]
        steps = n * env.slot_steps
        rows.append(
            dict(
                case=case,
                stage=stage,
                batch=batch,
                control_steps=steps,
                compile_s=compile_s,
                run_s=seconds,
                env_steps_per_s=batch * steps / seconds,
                ms_per_batch_step=1e3 * seconds / steps,
                cores=devices,
                parallel=cores_label(devices, "device" if devices > 1 else "core"),
            )
        )
    return rows


# ------------------------------------------------------------------ report


def _plot(rows: list[dict], path: Path) -> None:
    def paper(case):
        cpu, gpu = _best(PIPE_OF_CASE[case])
        return [(cpu, f"paper, CPU ({cpu} fps)"), (gpu, f"paper, GPU ({gpu} fps)")]

    plot_rows(
        rows,
        path,
        x="batch",
        y="env_steps_per_s",
        series=lambda r: r["parallel"],
        panel="case",
        lines=paper,
        xbase=2,
        xlabel="batch (snakes)",
        ylabel="env-steps/s (20 ms frames, all snakes)",
        title=lambda case: f"snake pipe loop: {case}",
    )


def report(rows: list[dict], stages: list[dict] | None = None, out=None) -> None:
    """Print the tables; with ``out``, write ``snake_pipe_bench.csv`` / ``.png`` (and ``snake_pipe_stages.csv``)."""
    import mujoco

    print(machine_banner(mujoco=mujoco.__version__))
    print(
        f"{'case':12s} {'batch':>5s} {'cores':>5s} {'steps':>5s} {'compile s':>9s} {'env-steps/s':>11s} "
        f"{'sim s/s':>8s} {'vs CPU':>7s} {'vs GPU':>7s} {'ev/step':>7s} {'det/slot':>8s}"
    )
    for r in rows:
        print(
            f"{r['case']:12s} {r['batch']:5d} {r['cores']:5d} {r['control_steps']:5d} {r['compile_s']:9.1f} "
            f"{r['env_steps_per_s']:11,.0f} {r['sim_s_per_wall_s']:8.1f} {r['vs_paper_cpu']:7,.0f} "
            f"{r['vs_paper_gpu']:7,.1f} {r['events_per_step']:7.0f} {r['detected_slots']:8.2f}"
        )
    print(
        "  vs CPU / GPU: against Table 1 of the pipe-tracking paper, the best figure of the same pipe "
        "(standing 1.63 / 40.74, lying 0.36 / 22.35 frames/s); det/slot: slots with a detection"
    )
    if stages:
        print(f"{'stage':18s} {'batch':>5s} {'cores':>5s} {'env-steps/s':>11s} {'ms/step':>8s} {'part ms':>8s}")
        before = 0.0
        for r in stages:
            print(
                f"{r['stage']:18s} {r['batch']:5d} {r['cores']:5d} {r['env_steps_per_s']:11,.0f} "
                f"{r['ms_per_batch_step']:8.2f} {r['ms_per_batch_step'] - before:8.2f}"
            )
            before = r["ms_per_batch_step"]
        print("  ms/step: wall ms per control step of the whole batch; part: the difference with the row above")
    if out:
        out = Path(out)
        write_csv(out / "snake_pipe_bench.csv", rows, ROW_FIELDS)
        _plot(rows, out / "snake_pipe_bench.png")
        written = ["snake_pipe_bench.csv", "snake_pipe_bench.png"]
        if stages:
            write_csv(out / "snake_pipe_stages.csv", stages, STAGE_FIELDS)
            written.append("snake_pipe_stages.csv")
        print(f"wrote {', '.join(str(out / w) for w in written)}")


def _add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", default=None, help="write snake_pipe_bench.csv and .png (and the stages) here")
    parser.add_argument(
        "--batches", default=None, help=f"batch sizes, comma-separated (default {','.join(map(str, BATCHES))})"
    )
    parser.add_argument("--cases", default=None, help=f"cases, comma-separated (default {','.join(CASES)})")
    parser.add_argument(
        "--slots", type=count, default=None, help="slots of 5 steps per timed run, at most (default 20)"
    )
    parser.add_argument("--repeats", type=count, default=None, help="timed rounds, the best kept (default 3)")
    parser.add_argument("--stages", action="store_true", help="add the per-stage breakdown at --stage-batch")
    parser.add_argument("--stage-batch", type=count, default=None, help="the breakdown's batch (default 64)")
    add_cpu_devices(parser, peers="how the all-core rows split the batch")
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bar")


@writes_output("bench snake-pipe")
def run(
    *,
    out: str | None = None,
    batches: str | None = None,
    cases: str | None = None,
    slots: int | None = None,
    repeats: int | None = None,
    stages: bool = False,
    stage_batch: int | None = None,
    cpu_devices: int | None = None,
    no_progress: bool = False,
) -> int:
    """``spikejax bench snake-pipe``: print the table; write ``snake_pipe_bench.csv`` and ``.png`` to ``out``.

    Args:
        out: a directory for the tables and figure (None: print only).
        batches: comma-separated batch sizes (default `BATCHES`).
        cases: comma-separated cases of `CASES` (default all).
        slots: slots per timed run, at most (default 20).
        repeats: timed rounds, the best kept (default 3).
        stages: add the per-stage breakdown of the first case.
        stage_batch: its batch (default 64).
        cpu_devices: CPU devices JAX presents (default one per core).
        no_progress: hide the progress bar.
    """
    cases = CASES if cases is None else _parse(cases, CASES, "--cases")
    slots = 20 if slots is None else slots
    repeats = 3 if repeats is None else repeats
    rows = measure(
        cases=cases,
        batches=BATCHES if batches is None else batches,
        slots=slots,
        repeats=repeats,
        cpu_devices=cpu_devices,
        no_progress=no_progress,
    )
    parts = None
    if stages:
        parts = measure_stages(
            case=cases[0], batch=stage_batch or 64, slots=slots, repeats=repeats, no_progress=no_progress
        )
    report(rows, parts, out)
    return 0


command = Command(
    help="the snake pipe loop's env-steps per second (physics to control), beside the paper's Table 1",
    add_arguments=_add_arguments,
    run=run,
    description=__doc__.splitlines()[0],
)
