"""``spikejax bench robobee-network``: the RoboBee network alone, spikejax against Brian2 and NEST.

The network is the delta-synapse variant of the RoboBee network
(`robots.robobee.delta_network`: 200-100-50 LIF, 30 % connectivity, one-step
delays, 2 ms refractoriness, ``dt = 0.1 ms``), the same network (connectivity,
weights, thresholds, input currents) in every implementation, all of which fire
the same spikes (``tests/test_bench_network.py``):

- spikejax: `robots.robobee.delta_network.simulate` as one
  ``jit(vmap(scan))`` over networks that share the connectivity and differ in
  their input currents (`run_spikejax`), on one CPU device and, from a batch of
  one network per device on, split over all of them
  (`spikejax.devices.shard_batch`); the formulations that lost at the largest
  batch (float32 weights, the fused step, an unrolled scan, fan-in gathers);
- the NumPy loop (`robots.robobee.reference.run_numpy`);
- Brian2's runtime mode and C++ standalone mode (`robots.robobee.peers`), one
  network in one process, and the standalone binary in one process per core at
  once (how a Brian2 user runs independent networks on several cores);
- NEST's ``iaf_psc_delta``, one thread and one thread per core (NEST's own
  parallelism).

Each peer runs in processes of its own (`spikejax.benchmarking.Processes`),
built once; then every implementation is timed once a round
(`spikejax.benchmarking.interleaved`), the best of ``--repeats`` rounds kept;
compile and build times are reported apart. Neuron updates/s are aggregate
(neurons x steps x networks / run seconds); ``x_nest`` and
``x_brian2_standalone`` divide a row's by the NEST and Brian2 standalone row
given the same cores (``cores``: 1, or all of them).
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from robots.robobee.delta_network import (
    DT,
    N_HIDDEN,
    N_INPUT,
    N_OUTPUT,
    P_CONNECT,
    ROW_FIELDS,
    delta_network_params,
    input_currents,
    make_network,
    n_steps_of,
    rates_hz,
    result_row,
    simulate,
)
from robots.robobee.peers import Brian2RuntimeNetwork, Brian2StandaloneNetwork, NestNetwork
from robots.robobee.reference import NumpyNetworkRun
from spikejax.benchmarking import (
    JaxRun,
    Processes,
    add_ratios,
    compile_ahead,
    cores_label,
    interleaved,
    machine_banner,
    write_csv,
)
from spikejax.commands import Command, add_cpu_devices, count, positive_float, writes_output
from spikejax.devices import cpu_devices_for_run, shard_batch
from spikejax.errors import UserError

__all__ = ["BATCHES", "COLUMNS", "command", "run", "run_spikejax"]

BATCHES = (1, 16, 256, 1024)
COLUMNS = (*ROW_FIELDS, "cores", "parallel", "x_nest", "x_brian2_standalone")


def _spikejax(
    n_networks: int,
    duration: float,
    seed: int,
    *,
    step: str = "layers",
    synapses: str = "dense",
    weight_dtype=jnp.bfloat16,
    unroll: int = 1,
    devices: int = 1,
) -> tuple[JaxRun, dict]:
    """The compiled run of `run_spikejax` and its row so far (``impl``, ``batch``, compile time, cores)."""
    n_steps = n_steps_of(duration)
    params = delta_network_params(make_network(seed), synapses, weight_dtype)
    currents = jnp.asarray(input_currents(seed, n_networks), jnp.float32)
    one = functools.partial(simulate, n_steps=n_steps, step=step, unroll=unroll)
    if devices == 1:
        compiled, compile_s = compile_ahead(jax.vmap(one, in_axes=(None, 0)), params, currents)
        timer = JaxRun(compiled, params, currents)
    else:
        fn = shard_batch(jax.vmap(lambda c: one(params, c)), jax.devices()[:devices])
        compiled, compile_s = compile_ahead(fn, currents)
        timer = JaxRun(compiled, currents)
    impl = f"spikejax {step} {synapses} {jnp.dtype(weight_dtype).name}" + (f" unroll {unroll}" if unroll != 1 else "")
    impl += f", {devices} devices" if devices > 1 else ""
    return timer, dict(
        impl=impl,
        batch=n_networks,
        steps=n_steps,
        build_s=compile_s,
        cores=devices,
        parallel=cores_label(devices, "device"),
    )


def run_spikejax(
    n_networks: int,
    duration: float,
    seed: int,
    *,
    step: str = "layers",
    synapses: str = "dense",
    weight_dtype=jnp.bfloat16,
    unroll: int = 1,
    repeats: int = 1,
    devices: int = 1,
) -> dict:
    """``n_networks`` networks (same connectivity, own input currents) as one ``jit(vmap(scan))``.

    The program is compiled ahead (`spikejax.benchmarking.compile_ahead`,
    ``build_or_compile_s``) and then run to completion ``repeats`` times; the
    fastest run is ``run_s``.

    Args:
        n_networks: batch size.
        duration: simulated time, s.
        seed: seed of `make_network` and `input_currents`.
        step: ``"layers"`` or ``"fused"`` (see `robots.robobee.delta_network.simulate`).
        synapses: ``"dense"`` or ``"fanin"`` (see `robots.robobee.delta_network.delta_network_params`).
        weight_dtype: ``bfloat16`` or ``float32`` (likewise).
        unroll: ``jax.lax.scan``'s unroll.
        repeats: timed runs.
        devices: CPU devices the batch is split over (`spikejax.devices.shard_batch`).

    Returns:
        A result row (`ROW_FIELDS`, ``cores``, ``parallel``); ``counts`` holds the spikes per network and neuron.
    """
    timer, row = _spikejax(
        n_networks,
        duration,
        seed,
        step=step,
        synapses=synapses,
        weight_dtype=weight_dtype,
        unroll=unroll,
        devices=devices,
    )
    run_s = min(timer() for _ in range(repeats))
    return _row(row, run_s, np.asarray(timer.result))


def _row(row: dict, run_s: float, counts) -> dict:
    out = result_row(row["impl"], row["batch"], row["steps"], row["build_s"], run_s, counts)
    out.update(cores=row["cores"], parallel=row["parallel"])
    return out


def _add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--duration", type=positive_float, default=None, help="simulated seconds (default 1)")
    parser.add_argument("--seed", type=int, default=None, help="network and input seed (default 0)")
    parser.add_argument(
        "--batches",
        type=count,
        nargs="+",
        default=None,
        help=f"spikejax batch sizes (default {' '.join(map(str, BATCHES))})",
    )
    parser.add_argument("--repeats", type=count, default=None, help="timed rounds, the best kept (default 3)")
    parser.add_argument("--out", default=None, help="write bench_robobee_network.csv here")
    add_cpu_devices(parser, peers="the peers' processes and threads")
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bar")


@writes_output("bench robobee-network", shared_with=("bench robobee",))
def run(
    *,
    duration: float | None = None,
    seed: int | None = None,
    batches: list[int] | None = None,
    repeats: int | None = None,
    out: str | None = None,
    cpu_devices: int | None = None,
    no_progress: bool = False,
) -> int:
    """``spikejax bench robobee-network``: print the network-alone table, write ``bench_robobee_network.csv``.

    Args:
        duration: simulated seconds (default 1).
        seed: seed of the network and its inputs (default 0).
        batches: spikejax batch sizes (default `BATCHES`).
        repeats: timed rounds, the best kept (default 3).
        out: a directory for the CSV (None: print only).
        cpu_devices: CPU devices JAX presents (default one per core): the
            all-cores rows split spikejax's batch over them, run Brian2
            standalone in that many processes and NEST with that many threads.
        no_progress: hide the progress bar.
    """
    duration = 1.0 if duration is None else duration
    seed = 0 if seed is None else seed
    batches = BATCHES if batches is None else tuple(batches)
    repeats = 3 if repeats is None else repeats
    if not batches or min(batches) < 1 or repeats < 1:
        raise UserError(f"--batches and --repeats must be >= 1, got {list(batches)} and {repeats}")
    n_dev = cpu_devices_for_run(cpu_devices)
    print(machine_banner(n_dev))
    print(
        f"RoboBee network alone: {N_INPUT}-{N_HIDDEN}-{N_OUTPUT} LIF, {P_CONNECT:.0%} connectivity, "
        f"dt = {DT * 1e3:g} ms, {duration:g} s = {n_steps_of(duration)} steps, seed {seed}"
    )
    from tqdm import tqdm

    n_steps = n_steps_of(duration)
    peers = [
        (NumpyNetworkRun, {}, 1, 1),
        (Brian2RuntimeNetwork, {}, 1, 1),
        (Brian2StandaloneNetwork, {}, 1, 1),
        (NestNetwork, dict(threads=1), 1, 1),
    ]
    if n_dev > 1:
        peers += [(Brian2StandaloneNetwork, {}, n_dev, n_dev), (NestNetwork, dict(threads=n_dev), 1, n_dev)]
    with contextlib.ExitStack() as stack:
        runs, rows = {}, {}
        for factory, kw, processes, cores in peers:
            try:
                runner = stack.enter_context(Processes(factory, duration, seed, processes=processes, **kw))
            except ImportError as err:
                print(f"  skipped {factory.__name__}: {err}")
                continue
            key = (factory.__name__, processes, cores)
            runs[key] = runner
            rows[key] = dict(
                processes=processes,
                cores=cores,
                parallel=cores_label(processes, "process")
                if processes > 1
                else cores_label(kw.get("threads", 1), "thread")
                if "threads" in kw
                else "1 process",
            )
        big = max(batches)
        jobs = [
            dict(n_networks=b, devices=d) for b in batches for d in [1] + ([n_dev] if n_dev > 1 and b >= n_dev else [])
        ]
        # The formulations that lost, at the largest batch (the gather at 16: it is slow).
        jobs += [
            dict(n_networks=big, weight_dtype=jnp.float32),
            dict(n_networks=big, step="fused"),
            dict(n_networks=big, unroll=4),
            dict(n_networks=min(big, 16), synapses="fanin", weight_dtype=jnp.float32),
        ]
        for job in tqdm(jobs, desc="robobee network: compiling", disable=no_progress):
            timer, row = _spikejax(duration=duration, seed=seed, **job)
            runs[row["impl"], row["batch"]] = timer
            rows[row["impl"], row["batch"]] = row
        bar = tqdm(total=len(runs) * repeats, desc="robobee network: timing", disable=no_progress)
        best = interleaved(runs, repeats, progress=lambda _: bar.update())
        bar.close()
        table = []
        for key, row in rows.items():
            if isinstance(runs[key], Processes):
                infos = runs[key].info()
                info = infos[0]
                impl = info["impl"] + (f", {row['processes']} processes at once" if row["processes"] > 1 else "")
                build_s = max(i["build_or_compile_s"] for i in infos)
                r = result_row(impl, row["processes"], n_steps, build_s, best[key], info["counts"])
                for extra in ("margin", "repeat_equal", "run_wall_s"):
                    if extra in info:
                        r[extra] = info[extra]
                r.update(cores=row["cores"], parallel=row["parallel"])
            else:
                r = _row(row, best[key], np.asarray(runs[key].result))
            table.append(r)
    for r in table:
        rates = ", ".join(f"{k} {v:.1f}" for k, v in rates_hz(r).items())
        print(
            f"  {r['impl']}, batch {r['batch']}: {r['neuron_updates_per_s'] / 1e6:,.1f} M neuron updates/s;"
            f" rates (Hz): {rates}"
        )
    add_ratios(table, "x_nest", "neuron_updates_per_s", lambda p, _: p["impl"].startswith("NEST"))
    add_ratios(
        table, "x_brian2_standalone", "neuron_updates_per_s", lambda p, _: p["impl"].startswith("Brian2 C++ standalone")
    )
    print()
    print(
        "| implementation | batch | cores | compile/build (s) | run (s) | neuron updates/s | x NEST | "
        "x Brian2 standalone |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for r in table:
        print(
            f"| {r['impl']} | {r['batch']} | {r['cores']} ({r['parallel']}) | {r['build_or_compile_s']:.2f} | "
            f"{r['run_s']:.3f} | {r['neuron_updates_per_s'] / 1e6:,.1f} M | {r['x_nest']:.2f} | "
            f"{r['x_brian2_standalone']:.2f} |"
        )
    print(
        f"(run: the best of {repeats} interleaved rounds; x NEST, x Brian2 standalone: against the row of each "
        "given the same cores; Brian2 standalone's run is the simulation loop as the binary times it)"
    )
    for cores in sorted({1, n_dev}):
        sel = [r for r in table if r["cores"] == cores and r["impl"].startswith("spikejax")]
        if sel and not all(math.isnan(r["x_nest"]) for r in sel):
            top = max(sel, key=lambda r: r["neuron_updates_per_s"])
            print(
                f"  {cores} core{'s' if cores > 1 else ''}: spikejax at batch {top['batch']} = "
                f"{top['x_nest']:.2f} x NEST, {top['x_brian2_standalone']:.2f} x Brian2 standalone"
            )
    if out:
        path = write_csv(f"{out}/bench_robobee_network.csv", table, COLUMNS)
        print(f"wrote {path}")
    return 0


command = Command(
    help="the RoboBee network alone: spikejax against NumPy, Brian2 and NEST",
    add_arguments=_add_arguments,
    run=run,
    description=__doc__.splitlines()[0],
)
