"""``spikejax bench robobee``: closed-loop RoboBee flights per second, spikejax against Brian2.

One flight is the closed loop of Sec. V of the RoboBee paper: the 200-100-50
LIF controller steers the robot laterally while it learns online from the LQR
teacher (reward-modulated Hebbian rule, Eq. (9)-(10), on both weight layers),
the altitude controller sets the lift, and the robot is integrated one physics
step per neural step (``dt = 0.1 ms``). The flight plan is the paper's first
one, ``q0 -> q1 -> q2`` (`robots.robobee.flight.flight_plan("waypoints")`),
scaled to the flight's duration: the first 20 % holds the robot at ``q0`` (the
paper's 500 ms hold of a 2.5 s flight), the rest is split equally between the
two waypoints.

- `run_spikejax_flights`: ``jax.jit(jax.vmap(fly))`` over network seeds (and,
  optionally, robots drawn by `robots.robobee.params.randomize`): SNN,
  plasticity, decoder, teacher and MJX physics in one compiled ``lax.scan``,
  on one device or split over several (`spikejax.devices.shard_batch`).
- `run_brian2_closed_loop`: the paper's own setup, `robots.robobee.peers.Brian2Flight`
  (the same network as spikejax's flight 0 in Brian2's runtime mode, and a
  ``network_operation`` that runs at the end of every step).
  `run_brian2_on_all_cores` runs one such flight per core side by side, as a
  Brian2 user with several cores would.

Each returns a row with compile or build time apart from run time, flights per
second, simulated seconds per wall-clock second and aggregate neuron updates
per second (350 neurons x steps x flights / run seconds), and the cores it used
(``cores``, ``parallel``). `run` builds every row's program first (Brian2 in
processes of its own, `spikejax.benchmarking.Processes`; spikejax compiled
ahead, its one-device rows each in a process held to one core, `HeldFlights`
through `spikejax.benchmarking.HeldToOneCore`: in a free process XLA's
threads made a one-device batch of 64 flights 1.4-1.9x slower), then times
each once a round, the best of ``--repeats`` rounds kept
(`spikejax.benchmarking.interleaved`), prints the closed-loop table and then,
unless ``--no-network``, the network-alone table of
`robots.robobee.bench_network.run`. Every row is quoted against one Brian2
flight on one core (``x_brian2``) and against one flight per core on all cores
(``x_brian2_all_cores``); a row's fair ratio is the one of its ``cores``. Where
the time goes is in ``docs/BENCHMARKS.md``.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import math
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from robots.robobee import bench_network
from robots.robobee.controller import ControllerConfig, ControllerParams, controller_params
from robots.robobee.flight import FlightPlan, flight_plan, fly
from robots.robobee.lqr import AltitudeParams, altitude_params, lateral_gain
from robots.robobee.params import RoboBeeParams, randomize, robobee_params
from robots.robobee.peers import RECORD_EVERY, Brian2FlightRun
from spikejax.benchmarking import (
    HeldToOneCore,
    JaxRun,
    Processes,
    batch_sizes,
    compile_ahead,
    cores_label,
    held_row,
    interleaved,
    machine_banner,
    write_csv,
)
from spikejax.commands import Command, add_cpu_devices, count, positive_float, writes_output
from spikejax.devices import cpu_devices_for_run, shard_batch
from spikejax.errors import UserError

__all__ = [
    "BATCHES",
    "COLUMNS",
    "FlightSetup",
    "HeldFlights",
    "command",
    "flight_setup",
    "flight_steps",
    "network_key",
    "run",
    "run_brian2_closed_loop",
    "run_brian2_on_all_cores",
    "run_spikejax_flights",
    "timed_duration",
]

DT = 1e-4  # s, the neural and physics step
FLIGHT_S = 2.5  # s: hold 0.5 s + 2 x 1 s, the paper's first flight
HOLD_FRACTION = 0.2
# 64: about where the batch's weights (200 KB per flight) stop fitting in a 32 MB L3 cache.
BATCHES = (1, 16, 64, 256, 1024, 4096)
# Flight-steps (flights x steps) one timed spikejax run may take: a batch whose
# whole flights would exceed it flies shorter flights and its flights/s is
# extrapolated to the full flight (every step costs the same, hold included).
STEP_BUDGET = 256 * 25_000
# Distance (x, z) to a waypoint at the end of its segment that counts as reached, m.
REACHED_M = 5e-3
N_NEURONS = 350

ROW_FIELDS = (
    "impl",
    "batch",
    "flight_s",
    "timed_s",
    "build_or_compile_s",
    "run_s",
    "flights_per_s",
    "sim_s_per_wall_s",
    "neuron_updates_per_s",
    "reached_q1",
    "reached_q2",
)
COLUMNS = (*ROW_FIELDS, "devices", "cores", "parallel", "x_brian2", "x_brian2_all_cores")


def timed_duration(batch: int, duration: float, step_budget: int = STEP_BUDGET) -> float:
    """Seconds of each of ``batch`` flights to time: ``duration``, or shorter (at least 0.05 s) to fit ``step_budget``.

    The result is a whole number of `flight_steps` blocks.
    """
    steps = round(duration / DT)
    if batch * steps > step_budget:
        steps = max(step_budget // batch, round(0.05 / DT))
    hold, segment = flight_steps(steps * DT)
    return (hold + 2 * segment) * DT


def flight_steps(duration: float, record_every: int = RECORD_EVERY) -> tuple[int, int]:
    """``(hold_steps, segment_steps)`` of a ``duration``-second flight: 20 % hold, two equal segments.

    Both are multiples of ``record_every``; ``hold + 2 segments`` is ``duration``
    rounded down to whole blocks of ``record_every`` steps (2.5 s: 5,000 and 10,000).
    """
    blocks = round(duration / DT) // record_every
    hold = round(HOLD_FRACTION * blocks)
    segment = (blocks - hold) // 2
    if segment < 1:
        raise UserError(f"a flight of {duration} s is too short for a hold and two segments")
    return hold * record_every, segment * record_every


@dataclasses.dataclass(frozen=True, eq=False)
class FlightSetup:
    """Everything a batch of flights shares or draws, as `fly` takes it (a host-side bundle, never traced).

    Attributes:
        config: network sizes (static).
        cparams: controller parameters (`controller_params` defaults).
        robots: the flown robots, each field ``(batch,)``; the nominal robot
            repeated unless randomized.
        K: the teacher's LQR gain for the nominal robot, ``(4,)``.
        altitude: the altitude controller's gains.
        plan: ``q0`` and the two waypoints of the paper's first flight.
        keys: one network key per flight, ``(batch,)``; flight 0's is the
            network that Brian2 simulates for the same seed.
    """

    config: ControllerConfig
    cparams: ControllerParams
    robots: RoboBeeParams
    K: jax.Array
    altitude: AltitudeParams
    plan: FlightPlan
    keys: jax.Array


def network_key(seed, flight) -> jax.Array:
    """The network key of flight ``flight`` for ``seed``, whatever the batch size."""
    return jax.random.fold_in(jax.random.key(seed), flight)


def flight_setup(batch: int, seed: int, randomize_robots: bool = False) -> FlightSetup:
    """The batch's setup for ``seed``: flight ``b`` has the network of `network_key` ``(seed, b)``.

    The robots are the nominal one, or drawn by `randomize` from ``key(seed + 1)``.
    """
    robot = robobee_params()
    keys = jax.vmap(network_key, in_axes=(None, 0))(seed, jnp.arange(batch))
    if randomize_robots:
        robots = jax.vmap(lambda k: randomize(robot, key=k))(jax.random.split(jax.random.key(seed + 1), batch))
    else:
        robots = jax.tree.map(lambda x: jnp.broadcast_to(x, (batch,)), robot)
    K = jnp.asarray(lateral_gain(robot), jnp.float32).reshape(4)
    return FlightSetup(
        ControllerConfig(), controller_params(), robots, K, altitude_params(), flight_plan("waypoints"), keys
    )


def _reached(t: np.ndarray, q: np.ndarray, plan, hold_steps: int, segment_steps: int) -> tuple[float, float]:
    """Fraction of flights within `REACHED_M` of each waypoint at the end of its segment (``q`` ``(b, n, 6)``)."""
    out = []
    for w in range(2):
        end = (hold_steps + (w + 1) * segment_steps) * DT
        i = min(int(np.searchsorted(t, end - 1e-9)), len(t) - 1)
        target = np.asarray(plan.waypoints[w])
        out.append(float(np.mean(np.hypot(q[:, i, 2] - target[2], q[:, i, 3] - target[3]) < REACHED_M)))
    return out[0], out[1]


def _row(impl, batch, flight_s, timed_s, build_s, run_s, reached=(math.nan, math.nan), **extra) -> dict:
    """A result row; throughputs are for whole ``flight_s`` flights, extrapolated from ``timed_s`` of each."""
    run_per_flight_batch = run_s * flight_s / timed_s
    steps = round(flight_s / DT)
    row = dict(
        impl=impl,
        batch=batch,
        flight_s=flight_s,
        timed_s=timed_s,
        build_or_compile_s=build_s,
        run_s=run_s,
        flights_per_s=batch / run_per_flight_batch,
        sim_s_per_wall_s=batch * flight_s / run_per_flight_batch,
        neuron_updates_per_s=N_NEURONS * steps * batch / run_per_flight_batch,
        reached_q1=reached[0],
        reached_q2=reached[1],
    )
    row.update(extra)
    return row


# ----------------------------------------------------------------- spikejax


def _spikejax_flights(
    batch: int,
    duration: float,
    seed: int,
    *,
    randomize_robots: bool = False,
    step_budget: int = STEP_BUDGET,
    devices: int = 1,
) -> tuple[JaxRun, dict]:
    """The compiled flights of `run_spikejax_flights` and what their row needs besides the run time."""
    setup = flight_setup(batch, seed, randomize_robots)
    timed = timed_duration(batch, duration, step_budget)
    hold_steps, segment_steps = flight_steps(timed)

    def one(robot, key):
        return fly(
            setup.config,
            setup.cparams,
            robot,
            setup.K,
            setup.altitude,
            setup.plan,
            jnp.bool_(True),
            hold_steps=hold_steps,
            segment_steps=segment_steps,
            record_every=RECORD_EVERY,
            key=key,
        )

    if devices > jax.device_count():
        raise UserError(f"{devices} devices asked, JAX presents {jax.device_count()}")
    fn = shard_batch(jax.vmap(one), jax.devices()[:devices])
    compiled, compile_s = compile_ahead(fn, setup.robots, setup.keys)
    impl = "spikejax jit(vmap(fly))" + (" randomized robots" if randomize_robots else "")
    impl += f", {devices} devices" if devices > 1 else ""
    return JaxRun(compiled, setup.robots, setup.keys), dict(
        impl=impl,
        batch=batch,
        duration=duration,
        timed=timed,
        compile_s=compile_s,
        plan=setup.plan,
        hold_steps=hold_steps,
        segment_steps=segment_steps,
        devices=devices,
    )


def _flights_row(info: dict, run_s: float, rec) -> dict:
    rec = jax.tree.map(np.asarray, rec)
    reached = (math.nan, math.nan)
    if math.isclose(info["timed"], info["duration"], abs_tol=DT / 2):
        reached = _reached(rec.t[0], rec.q, info["plan"], info["hold_steps"], info["segment_steps"])
    return _row(
        info["impl"],
        info["batch"],
        info["duration"],
        info["timed"],
        info["compile_s"],
        run_s,
        reached,
        recording=rec,
        devices=info["devices"],
        cores=info["devices"],
        parallel=cores_label(info["devices"], "device"),
    )


class HeldFlights:
    """`_spikejax_flights`'s compiled flights as a timer whose `info` is their row (without the recording).

    For a process of its own (`spikejax.benchmarking.HeldToOneCore`): the
    row is made where the flights ran, from the fastest call.
    """

    def __init__(self, batch: int, duration: float, seed: int, **kwargs):
        self.timer, self._info = _spikejax_flights(batch, duration, seed, **kwargs)
        self.run_s = math.inf

    def __call__(self) -> float:
        seconds = self.timer()
        self.run_s = min(self.run_s, seconds)
        return seconds

    @property
    def info(self) -> dict:
        row = _flights_row(self._info, self.run_s, self.timer.result)
        del row["recording"]
        return row


def run_spikejax_flights(
    batch: int,
    duration: float = FLIGHT_S,
    seed: int = 0,
    *,
    randomize_robots: bool = False,
    step_budget: int = STEP_BUDGET,
    repeats: int = 1,
    devices: int = 1,
) -> dict:
    """``batch`` closed-loop flights of ``duration`` seconds as one ``jax.jit(jax.vmap(fly))``.

    The program is compiled ahead (`spikejax.benchmarking.compile_ahead`,
    ``build_or_compile_s``) and run to completion ``repeats`` times (``run_s``:
    the fastest). With ``devices > 1`` the flights are split evenly over the
    first ``devices`` of ``jax.devices()`` (`spikejax.devices.shard_batch`:
    each CPU device runs on its own core). If ``batch`` whole flights exceed
    ``step_budget`` flight-steps, the flights timed are shortened to fit it
    (same 20 % hold and two segments, at least 0.05 s) and the throughputs
    extrapolated to ``duration``: the scan's steps all cost the same.

    Args:
        batch: flights flown at once, each with its own network seed.
        duration: simulated seconds of one flight (2.5: the paper's hold and two 1 s legs).
        seed: seed of the network keys (flight 0 is Brian2's network for the same seed).
        randomize_robots: fly robots whose mass, drag and inertia differ by up to
            +-20 % (`robots.robobee.params.randomize`), the teacher designed for
            the nominal one.
        step_budget: flight-steps one timed run may take.
        repeats: timed runs.
        devices: devices the batch is split over (1: a plain ``jax.jit``).

    Returns:
        A row (`ROW_FIELDS`, and ``devices``); ``reached_q1``/``reached_q2`` are the fractions of
        flights within 5 mm of each waypoint at the end of its segment (NaN
        when the flights were shortened), ``recording`` the flights'
        `robots.robobee.flight.Recording` (NumPy).
    """
    timer, info = _spikejax_flights(
        batch, duration, seed, randomize_robots=randomize_robots, step_budget=step_budget, devices=devices
    )
    run_s = min(timer() for _ in range(repeats))
    return _flights_row(info, run_s, timer.result)


# ----------------------------------------------------------------- Brian2


def _brian2_args(duration: float, seed: int, target: str, flight_s: float, scale_plan: bool = True) -> tuple:
    """`robots.robobee.peers.Brian2FlightRun`'s arguments for flight 0 of ``seed`` (the key as its data)."""
    hold_steps, segment_steps = flight_steps(duration if scale_plan else flight_s)
    key = np.asarray(jax.random.key_data(network_key(seed, 0)))
    return key, hold_steps, segment_steps, round(duration / DT), target


def _brian2_row(
    info: dict,
    duration: float,
    flight_s: float,
    scale_plan: bool = True,
    processes: int = 1,
    build_s: float | None = None,
    run_s: float | None = None,
) -> dict:
    """The row of a Brian2 flight (`robots.robobee.peers.Brian2FlightRun.info`), or of ``processes`` side by side."""
    hold_steps, segment_steps = flight_steps(duration if scale_plan else flight_s)
    n_steps = round(duration / DT)
    rec = info["recording"]
    reached = []
    for w in range(2):
        if hold_steps + (w + 1) * segment_steps > n_steps:
            reached.append(math.nan)
        else:
            reached.append(_reached(rec["t"], rec["q"][None], flight_plan("waypoints"), hold_steps, segment_steps)[w])
    impl = info["impl"] + (f", {processes} processes at once" if processes > 1 else "")
    extra = (
        dict(
            recording=rec,
            counts=info["counts"],
            w_ih=info["w_ih"],
            w_ho=info["w_ho"],
            op_s=info["op_s"],
            prepare_s=info["prepare_s"],
        )
        if processes == 1
        else {}
    )
    return _row(
        impl,
        processes,
        flight_s,
        n_steps * DT,
        info["build_s"] if build_s is None else build_s,
        info["run_s"] if run_s is None else run_s,
        reached,
        cores=processes,
        parallel=cores_label(processes, "process"),
        devices=1,
        **extra,
    )


def run_brian2_closed_loop(
    duration: float = FLIGHT_S,
    seed: int = 0,
    target: str = "cython",
    *,
    flight_s: float = FLIGHT_S,
    scale_plan: bool = True,
    learn: bool = True,
    use_snn: bool = True,
    warmup_steps: int = RECORD_EVERY,
    repeats: int = 1,
) -> dict:
    """One closed-loop flight in Brian2's runtime mode (`robots.robobee.peers.Brian2FlightRun`), timed on ``duration``.

    The network is spikejax's flight 0 of the same ``seed``. A first run of
    ``warmup_steps`` steps generates (and for Cython compiles, or loads from
    Cython's cache) the code: ``build_or_compile_s`` is the network's
    construction plus that run. Then ``duration`` seconds are timed
    ``repeats`` times, the flight restarted before each (``run_s``: the
    fastest ``Network.run``, its preparation included: ``prepare_s``, the time
    of a further run of ``warmup_steps``, measures that); flights/s is
    extrapolated to a ``flight_s`` flight if ``duration`` is shorter (Brian2's
    time per step is constant). If Cython cannot compile, NumPy runs instead
    and ``impl`` says so. The code generation target is restored after.

    Args:
        duration: simulated seconds to run and time.
        seed: network seed (as `run_spikejax_flights`).
        target: ``"cython"`` or ``"numpy"`` (``brian2.prefs.codegen.target``).
        flight_s: the flight length the throughputs are given for.
        scale_plan: the plan (20 % hold, two segments) is scaled to ``duration``
            (True), or is that of a ``flight_s`` flight, of which the first
            ``duration`` seconds are flown (False: e.g. ``duration = 1.5`` flies
            the hold and the first leg of a 2.5 s flight).
        learn: apply Eq. (10).
        use_snn: the SNN steers (else the teacher).
        warmup_steps: steps of the code-generating first run.
        repeats: timed runs (the recording and weights are those of the first).

    Returns:
        A row (`ROW_FIELDS`) with ``recording`` (`Brian2Flight.recording`),
        ``counts`` (spikes per neuron), ``w_ih``/``w_ho`` (final weights, dense),
        ``op_s`` (time in the network operation, within ``run_s``) and
        ``reached_q1``/``reached_q2`` (within 5 mm at the end of a segment that was flown).
    """
    import brian2 as b2

    old_target = b2.prefs.codegen.target
    try:
        run = Brian2FlightRun(
            *_brian2_args(duration, seed, target, flight_s, scale_plan),
            learn=learn,
            use_snn=use_snn,
            warmup_steps=warmup_steps,
        )
        for _ in range(repeats):
            run()
        info = run.info
    finally:
        b2.prefs.codegen.target = old_target
    return _brian2_row(info, duration, flight_s, scale_plan)


def run_brian2_on_all_cores(
    processes: int,
    duration: float = FLIGHT_S,
    seed: int = 0,
    target: str = "cython",
    *,
    flight_s: float = FLIGHT_S,
    repeats: int = 1,
) -> dict:
    """``processes`` Brian2 flights at once, one process each: what a Brian2 user gets from that many cores.

    Brian2's runtime mode runs one flight on one core; a user with several
    cores runs several flights side by side. Each process builds its flight
    and then all start their timed run together (a barrier,
    `spikejax.benchmarking.Processes`), ``repeats`` times; the row's ``run_s``
    is the slowest process's run, the fastest of the repeats, so its flights/s
    is the aggregate of all of them.

    Returns:
        A row (`ROW_FIELDS`) with ``batch = processes``; ``build_or_compile_s`` is the slowest build.
    """
    with Processes(Brian2FlightRun, *_brian2_args(duration, seed, target, flight_s), processes=processes) as run:
        run_s = min(run() for _ in range(repeats))
        infos = run.info()
    return _brian2_row(
        infos[0], duration, flight_s, processes=processes, build_s=max(i["build_s"] for i in infos), run_s=run_s
    )


# ----------------------------------------------------------------- CLI


def _add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--trials", type=count, default=None, help="the largest batch of flights (default: every batch of 1 .. 4096)"
    )
    parser.add_argument("--out", default=None, help="write bench_robobee.csv (and bench_robobee_network.csv) here")
    parser.add_argument(
        "--duration", type=positive_float, default=None, help=f"simulated seconds of a flight (default {FLIGHT_S})"
    )
    parser.add_argument("--seed", type=int, default=None, help="network seed (default 0)")
    parser.add_argument(
        "--repeats", type=count, default=None, help="timed rounds, Brian2's and spikejax's, the best kept (default 3)"
    )
    parser.add_argument("--randomize", action="store_true", help="also fly randomized robots at the largest batch")
    parser.add_argument(
        "--brian2-target",
        choices=("cython", "numpy"),
        default=None,
        help="Brian2's code generation target (default cython)",
    )
    parser.add_argument(
        "--network",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="then run the network-alone table (default: yes)",
    )
    add_cpu_devices(parser, peers="Brian2's processes")
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bar")


@writes_output("bench robobee", shared_with=("bench robobee-network",))
def run(
    *,
    trials: int | None = None,
    out: str | None = None,
    duration: float | None = None,
    seed: int | None = None,
    repeats: int | None = None,
    randomize: bool = False,
    brian2_target: str | None = None,
    network: bool = True,
    cpu_devices: int | None = None,
    no_progress: bool = False,
) -> int:
    """``spikejax bench robobee``: the closed-loop table, then the network-alone table.

    Args:
        trials: the largest batch of flights (default: every batch of `BATCHES`).
        out: a directory for ``bench_robobee.csv`` (and ``bench_robobee_network.csv``
            from the network table); None: print only.
        duration: simulated seconds of a flight (default 2.5).
        seed: network seed (default 0).
        repeats: timed rounds, Brian2's and spikejax's, the best kept (default 3).
        randomize: also fly randomized robots at the largest batch.
        brian2_target: ``"cython"`` (the default) or ``"numpy"``.
        network: then run the network-alone table (`robots.robobee.bench_network.run`).
        cpu_devices: the CPU devices JAX presents, default one per core (set
            before JAX starts).
        no_progress: hide the progress bar.

    Brian2 runs in fresh processes of its own: one flight on one core (the
    paper's setup, the ``x Brian2`` reference), then as many flights side by
    side as there are devices (`run_brian2_on_all_cores`, the ``x Brian2 on
    all cores`` reference). Each spikejax batch runs on one device, and, from
    a batch of one flight per device on, also split over all devices.
    """
    n_dev = cpu_devices_for_run(cpu_devices)
    duration = FLIGHT_S if duration is None else duration
    seed = 0 if seed is None else seed
    repeats = 3 if repeats is None else repeats
    brian2_target = "cython" if brian2_target is None else brian2_target
    if repeats < 1:
        raise UserError(f"--repeats must be >= 1, not {repeats}")
    batches = batch_sizes(trials, BATCHES)
    print(machine_banner(n_dev))
    hold, segment = flight_steps(duration)
    print(
        f"RoboBee closed loop: 200-100-50 LIF SNN + Hebbian rule (both layers) + Eq. (8) decoder + LQR teacher + "
        f"physics, dt = {DT * 1e3:g} ms; flight q0 -> q1 -> q2 of {duration:g} s "
        f"(hold {hold * DT:g} s, 2 x {segment * DT:g} s), seed {seed}"
    )
    from tqdm import tqdm

    with contextlib.ExitStack() as stack:
        runs, infos = {}, {}
        for processes in [1] + ([n_dev] if n_dev > 1 else []):
            try:
                runs["brian2", processes] = stack.enter_context(
                    Processes(
                        Brian2FlightRun, *_brian2_args(duration, seed, brian2_target, duration), processes=processes
                    )
                )
            except ImportError as err:
                print(f"  skipped: {err}")
                break
        jobs = [dict(batch=b, devices=d) for b in batches for d in [1] + ([n_dev] if n_dev > 1 and b >= n_dev else [])]
        if randomize:
            jobs.append(dict(batch=max(batches), randomize_robots=True, devices=n_dev))
        for job in tqdm(jobs, desc="robobee bench: compiling", disable=no_progress):
            if job["devices"] == 1:  # one core: in a process held to one (`HeldToOneCore`)
                held = Processes(HeldToOneCore, HeldFlights, duration=duration, seed=seed, **job)
                runs["spikejax", len(runs)] = stack.enter_context(held)
            else:
                timer, info = _spikejax_flights(duration=duration, seed=seed, **job)
                runs["spikejax", len(runs)] = timer
                infos[len(runs) - 1] = info
        bar = tqdm(total=len(runs) * repeats, desc="robobee bench: timing", disable=no_progress)
        best = interleaved(runs, repeats, progress=lambda _: bar.update())
        bar.close()
        rows = []
        for key, runner in runs.items():
            if key[0] == "brian2":
                got = runner.info()
                rows.append(
                    _brian2_row(
                        got[0],
                        duration,
                        duration,
                        processes=key[1],
                        build_s=max(i["build_s"] for i in got),
                        run_s=best[key],
                    )
                )
            elif isinstance(runner, Processes):
                rows.append(held_row(runner.info()[0]))
            else:
                rows.append(_flights_row(infos[key[1]], best[key], runner.result))
    for r in rows:
        extra = (
            f", of which network_operation {r['op_s']:.2f} s (first run) and Network.run's preparation about "
            f"{r['prepare_s']:.2f} s"
            if "op_s" in r
            else ""
        )
        print(
            f"  {r['impl']}, batch {r['batch']}: {r['flights_per_s']:.3g} flights/s (timed {r['timed_s']:g} s "
            f"per flight, run {r['run_s']:.2f} s{extra})"
        )
    brian2 = [r for r in rows if r["impl"].startswith("Brian2")]
    one = brian2[0]["flights_per_s"] if brian2 else math.nan
    every = brian2[-1]["flights_per_s"] if brian2 else math.nan
    for r in rows:
        r["x_brian2"] = r["flights_per_s"] / one
        r["x_brian2_all_cores"] = r["flights_per_s"] / every
    print()
    print(
        "| implementation | batch | cores | compile/build (s) | timed (s simulated) | run (s) | flights/s | "
        f"simulated s / s | neuron updates/s | x Brian2 | x Brian2 on {n_dev} cores | reached q1, q2 |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        reached = "-" if math.isnan(r["reached_q1"]) else f"{r['reached_q1']:.0%}, {r['reached_q2']:.0%}"
        print(
            f"| {r['impl']} | {r['batch']} | {r['cores']} ({r['parallel']}) | {r['build_or_compile_s']:.2f} | "
            f"{r['timed_s'] * r['batch']:g} | {r['run_s']:.2f} | {r['flights_per_s']:.4g} | "
            f"{r['sim_s_per_wall_s']:.3g} | {r['neuron_updates_per_s'] / 1e6:,.2f} M | {r['x_brian2']:.1f} | "
            f"{r['x_brian2_all_cores']:.1f} | {reached} |"
        )
    print(
        f"(flights of {duration:g} s; timed: simulated seconds actually run (flights x timed length), the "
        f"throughputs extrapolated from them; run: the best of {repeats} interleaved rounds; reached: within "
        f"{REACHED_M * 1e3:g} mm of each waypoint at the end of its leg; Brian2 flies one flight on one core, or "
        f"{n_dev} side by side in {n_dev} processes; a row on 1 core compares with x Brian2, a row on {n_dev} "
        f"with x Brian2 on {n_dev} cores)"
    )
    if out:
        write_csv(Path(out) / "bench_robobee.csv", rows, COLUMNS)
    if network:
        print()
        bench_network.run(out=out, no_progress=no_progress)
    return 0


command = Command(
    help="closed-loop RoboBee flights per second, spikejax against Brian2",
    add_arguments=_add_arguments,
    run=run,
    description=__doc__.splitlines()[0],
)
