"""``spikejax bench gaits``: three-gait SCPG training trials per second, against plain NumPy loops.

The trials are those of Alg. 1 of the hexapod SCPG paper (the training of `robots.hexapod.training`).

The peer is what a researcher runs without spikejax: Alg. 1 as loops in NumPy,
one trial at a time (`robots.hexapod.reference`, the same algorithm, the same
initial weights and noise), in one process, and over a pool of one process a
core, each with its own trials (how a NumPy user spreads independent trials
over cores). spikejax runs the same trials as one ``jax.jit(jax.vmap(trial))``
over chunks of trials, on one CPU device and split over one device a core
(`spikejax.devices.shard_batch`), compiled ahead and apart (the one-device
rows each in a process held to one core, `spikejax.benchmarking.HeldToOneCore`:
in a free process XLA spread them over every core, 13 % faster on two); and end to end
through the sweep engine (its own compile time, the results written to disk),
which splits every chunk over all devices. The timed runs are interleaved
(`spikejax.benchmarking.interleaved`), the best of ``--repeats`` kept;
``x_numpy`` divides a row's trials/s by the NumPy loops' given the same cores.
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
import time
from pathlib import Path
from typing import TYPE_CHECKING

import jax
import jax.numpy as jnp
import numpy as np

from spikejax.benchmarking import (
    HeldToOneCore,
    Processes,
    add_ratios,
    compile_ahead,
    cores_label,
    held_row,
    interleaved,
    machine_banner,
    write_csv,
)
from spikejax.commands import Command, add_cpu_devices, count, writes_output
from spikejax.devices import cpu_devices_for_run, shard_batch
from spikejax.errors import UserError
from spikejax.sweep import load_sweep, read_results, run_sweep, trial_key

if TYPE_CHECKING:
    from robots.hexapod.trial import GaitTrialParams

# The hexapod's modules are imported where they are used: they make JAX arrays
# when imported, which starts JAX before `run` can present the CPU as several devices.

__all__ = ["COLUMNS", "bench_numpy", "bench_spikejax", "bench_sweep", "command", "run"]

TARGET_TRIALS, TARGET_SECONDS = 100_000, 60.0
COLUMNS = ("impl", "trials", "compile_s", "run_s", "trials_per_s", "converged", "cores", "parallel", "x_numpy")


def _batch(params: GaitTrialParams, start: int, size: int):
    from robots.hexapod.trial import GaitTrialParams

    batch = GaitTrialParams(*(jnp.full((size,), v, jnp.float32) for v in params))
    keys = jax.vmap(lambda s: trial_key(0, s))(jnp.arange(start, start + size))
    return batch, keys


class SpikejaxTrials:
    """``n_trials`` trials in chunks through one compiled ``jax.jit(jax.vmap(convergence_trial))``, as a timer.

    Compiled ahead at construction (``compile_s``), split over the first
    ``devices`` CPU devices; each call runs every chunk and returns its
    seconds; `info` is the row (``run_s``: the fastest call).
    """

    def __init__(self, n_trials: int, chunk_size: int, params: GaitTrialParams, devices: int = 1):
        from robots.hexapod.trial import convergence_trial

        self.n_trials, self.params, self.devices = n_trials, params, devices
        self.size = min(chunk_size, n_trials)
        fn = shard_batch(jax.vmap(convergence_trial), jax.devices()[:devices])
        self.compiled, self.compile_s = compile_ahead(fn, *_batch(params, 0, self.size))
        self.run_s, self.converged = math.inf, None

    def __call__(self) -> float:
        converged = 0
        t0 = time.perf_counter()
        for start in range(0, self.n_trials, self.size):
            result = self.compiled(*_batch(self.params, start, self.size))
            converged += int(np.sum(np.asarray(result.converged)[: self.n_trials - start]))
        seconds = time.perf_counter() - t0
        self.run_s, self.converged = min(self.run_s, seconds), converged / self.n_trials
        return seconds

    @property
    def info(self) -> dict:
        impl = f"spikejax jit+vmap, chunks of {self.size}" + (f", {self.devices} devices" if self.devices > 1 else "")
        return dict(
            impl=impl,
            trials=self.n_trials,
            compile_s=self.compile_s,
            run_s=self.run_s,
            trials_per_s=self.n_trials / self.run_s,
            converged=self.converged,
            cores=self.devices,
            parallel=cores_label(self.devices, "device"),
        )


def bench_spikejax(n_trials: int, chunk_size: int, params: GaitTrialParams, devices: int = 1) -> dict:
    """Compile once (`SpikejaxTrials`), then run ``n_trials`` in chunks once; seconds for each part."""
    run = SpikejaxTrials(n_trials, chunk_size, params, devices)
    run()
    return run.info


class NumpyTrials:
    """Alg. 1 in plain NumPy loops, ``n_trials`` trials one after another from seed ``index * n_trials``, as a timer.

    ``index`` is the process's place in a pool (`spikejax.benchmarking.Processes`), so each process runs its own trials.
    """

    def __init__(self, n_trials: int, params: GaitTrialParams, index: int = 0):
        from robots.hexapod.training import TrainParams

        self.n_trials, self.first = n_trials, index * n_trials
        self.params = TrainParams(*(np.float32(v) for v in params))
        self.run_s, self.converged = math.inf, None

    def __call__(self) -> float:
        from robots.hexapod.reference import reference_gait_correct, reference_train

        p, converged = self.params, 0
        t0 = time.perf_counter()
        for seed in range(self.first, self.first + self.n_trials):
            w_in, w_cpg, _ = reference_train(p, trial_key(0, seed))
            ok = reference_gait_correct(p, w_in, w_cpg)
            converged += bool(np.all(ok[: int(p.n_gaits)]))
        seconds = time.perf_counter() - t0
        self.run_s, self.converged = min(self.run_s, seconds), converged / self.n_trials
        return seconds

    @property
    def info(self) -> dict:
        return dict(
            impl="NumPy loops (Alg. 1 as written)",
            trials=self.n_trials,
            compile_s=0.0,
            run_s=self.run_s,
            trials_per_s=self.n_trials / self.run_s,
            converged=self.converged,
            cores=1,
            parallel="1 process",
        )


def bench_numpy(n_trials: int, params: GaitTrialParams) -> dict:
    """Alg. 1 in plain NumPy loops, one trial after another (`NumpyTrials`, once)."""
    run = NumpyTrials(n_trials, params)
    run()
    return run.info


def bench_sweep(n_trials: int, chunk_size: int) -> dict:
    """The same trials end to end through the sweep engine: compile, run, results written to disk."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "bench.toml"
        path.write_text(
            '[sweep]\nname = "bench_gaits"\ntrial = "robots.hexapod.trial:convergence_trial"\n'
            f"seeds = {n_trials}\nchunk_size = {chunk_size}\n[grid]\nn_gaits = [3]\n"
        )
        t0 = time.perf_counter()
        run_sweep(load_sweep(path), Path(tmp) / "out", progress=False)
        total_s = time.perf_counter() - t0
        table = read_results(Path(tmp) / "out")
        runs = json.loads((Path(tmp) / "out" / "metadata.json").read_text())["runs"]
    compile_s = float(runs[-1].get("compile_seconds", float("nan")))
    n_dev = jax.device_count()
    return dict(
        impl=f"spikejax sweep engine, end to end, chunks of {chunk_size}",
        trials=n_trials,
        compile_s=compile_s,
        run_s=total_s - compile_s,
        trials_per_s=n_trials / (total_s - compile_s),
        converged=float(np.mean(table["converged"])),
        cores=n_dev,
        parallel=cores_label(n_dev, "device"),
    )


def _add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--trials", type=count, default=None, help=f"trials to time (default {TARGET_TRIALS:,})")
    parser.add_argument("--out", default=None, help="write bench_gaits.csv here")
    parser.add_argument("--repeats", type=count, default=None, help="timed rounds, the best kept (default 1)")
    add_cpu_devices(parser, peers="the NumPy pool's processes")
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bar")


@writes_output("bench gaits")
def run(
    *,
    trials: int | None = None,
    out: str | None = None,
    repeats: int | None = None,
    cpu_devices: int | None = None,
    no_progress: bool = False,
) -> int:
    """``spikejax bench gaits``: print the table; write ``bench_gaits.csv`` to ``out``.

    Args:
        trials: trials spikejax runs (default 100,000); the NumPy loops run
            ``max(4, min(20, trials // 1000))`` per process.
        out: a directory for the CSV (None: print only).
        repeats: timed rounds, the best kept (default 1).
        cpu_devices: CPU devices JAX presents (default: one per core): the
            all-cores rows split spikejax's chunks over them and run the NumPy
            loops in that many processes.
        no_progress: hide the progress bar.
    """
    n_trials = TARGET_TRIALS if trials is None else trials
    repeats = 1 if repeats is None else repeats
    if n_trials < 1 or repeats < 1:
        raise UserError(f"--trials and --repeats must be >= 1, not {n_trials} and {repeats}")
    n_dev = cpu_devices_for_run(cpu_devices)
    from robots.hexapod.trial import GaitTrialParams

    params = GaitTrialParams(n_gaits=3)
    print(machine_banner(n_dev))
    print("three-gait SCPG training trials (Alg. 1, interleaved, budget 200 epochs)")
    from tqdm import tqdm

    n_numpy = max(4, min(20, n_trials // 1000))
    cores = [1] + ([n_dev] if n_dev > 1 else [])
    runs = {}
    pools = [Processes(NumpyTrials, n_numpy, params, processes=p, index_arg="index") for p in cores]
    try:
        for p, pool in zip(cores, pools):
            runs["numpy", p] = pool
        for chunk in (5000, 25000):  # one core: each in a process held to one (`HeldToOneCore`)
            pools.append(Processes(HeldToOneCore, SpikejaxTrials, n_trials, chunk, params))
            runs["spikejax", chunk, 1] = pools[-1]
        if n_dev > 1:
            runs["spikejax", 25000, n_dev] = SpikejaxTrials(n_trials, 25000, params, n_dev)
        bar = tqdm(total=len(runs) * repeats, desc="gaits bench", disable=no_progress)
        best = interleaved(runs, repeats, progress=lambda _: bar.update())
        bar.close()
        rows = []
        for key, timer in runs.items():
            if key[0] == "numpy":
                infos = timer.info()
                row = dict(
                    infos[0],
                    trials=n_numpy * key[1],
                    run_s=best[key],
                    cores=key[1],
                    parallel=cores_label(key[1], "process"),
                    converged=float(np.mean([i["converged"] for i in infos])),
                )
                row["trials_per_s"] = row["trials"] / row["run_s"]
                if key[1] > 1:
                    row["impl"] += f", {key[1]} processes"
                rows.append(row)
            elif isinstance(timer, Processes):
                rows.append(held_row(timer.info()[0]))
            else:
                rows.append(timer.info)
    finally:
        for pool in pools:
            pool.close()
    rows.append(bench_sweep(n_trials, 25000))
    add_ratios(rows, "x_numpy", "trials_per_s", lambda p, _: p["impl"].startswith("NumPy"))
    for r in rows:
        total = r["compile_s"] + r["run_s"]
        if r["impl"].startswith("NumPy"):
            print(f"  {r['impl']}: {r['trials_per_s']:.2f} trials/s ({r['trials']} trials, {r['parallel']})")
            continue
        verdict = "meets" if (n_trials >= TARGET_TRIALS and total < TARGET_SECONDS) else "n/a"
        print(
            f"  {r['impl']}: compile {r['compile_s']:.1f} s, run {r['run_s']:.1f} s for {n_trials} trials "
            f"= {r['trials_per_s']:.0f} trials/s; total {total:.1f} s "
            f"(target {TARGET_TRIALS} in < {TARGET_SECONDS:.0f} s: {verdict}); converged {r['converged']:.1%}; "
            f"{r['x_numpy']:.0f}x the NumPy loops on {r['cores']} core{'s' if r['cores'] > 1 else ''}"
        )
    for c in cores:
        sel = [r for r in rows if r["cores"] == c and not r["impl"].startswith("NumPy")]
        if sel:
            print(
                f"  speed-up over NumPy loops, {c} core{'s' if c > 1 else ''} against as many: "
                f"{max(r['x_numpy'] for r in sel):.0f}x"
            )
    if out:
        write_csv(Path(out) / "bench_gaits.csv", rows, COLUMNS)
    return 0


command = Command(
    help="three-gait SCPG training trials per second, against plain NumPy loops",
    add_arguments=_add_arguments,
    run=run,
    description=__doc__.splitlines()[0],
)
