"""``spikejax bench gaits``: three-gait SCPG training trials per second, against plain NumPy loops.

The peer is what a researcher runs without spikejax: Alg. 1 as loops in NumPy,
one trial at a time (:mod:`robots.hexapod.reference`, the same algorithm, the
same initial weights and noise). spikejax runs the same trials as one
``jax.jit(jax.vmap(trial))`` over chunks of trials. Both run in the same
process, on the same trials; spikejax's compile time is reported apart.
"""

from __future__ import annotations

import argparse
import csv
import json
import platform
import tempfile
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from spikejax.sweep import load_sweep, read_results, run_sweep, trial_key
from robots.hexapod.reference import reference_gait_correct, reference_train
from robots.hexapod.training import TrainParams
from robots.hexapod.trial import GaitTrialParams, convergence_trial

TARGET_TRIALS, TARGET_SECONDS = 100_000, 60.0


def _batch(params: GaitTrialParams, start: int, size: int):
    batch = GaitTrialParams(*(jnp.full((size,), v, jnp.float32) for v in params))
    keys = jax.vmap(lambda s: trial_key(0, s))(jnp.arange(start, start + size))
    return batch, keys


def bench_spikejax(n_trials: int, chunk_size: int, params: GaitTrialParams) -> dict:
    """Compile once, then run ``n_trials`` in chunks; seconds for each part."""
    fn = jax.jit(jax.vmap(convergence_trial))
    size = min(chunk_size, n_trials)
    t0 = time.perf_counter()
    compiled = fn.lower(*_batch(params, 0, size)).compile()
    compile_s = time.perf_counter() - t0
    converged = 0
    t0 = time.perf_counter()
    for start in range(0, n_trials, size):
        result = compiled(*_batch(params, start, size))
        converged += int(np.sum(np.asarray(result.converged)[: n_trials - start]))
    run_s = time.perf_counter() - t0
    return dict(impl=f"spikejax jit+vmap, chunks of {size}", trials=n_trials, compile_s=compile_s, run_s=run_s,
                trials_per_s=n_trials / run_s, converged=converged / n_trials)


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
    return dict(impl=f"spikejax sweep engine, end to end, chunks of {chunk_size}", trials=n_trials,
                compile_s=compile_s, run_s=total_s - compile_s, trials_per_s=n_trials / (total_s - compile_s),
                converged=float(np.mean(table["converged"])))


def bench_numpy(n_trials: int, params: GaitTrialParams) -> dict:
    """Alg. 1 in plain NumPy loops, one trial after another."""
    p = TrainParams(*(np.float32(v) for v in params))
    converged = 0
    t0 = time.perf_counter()
    for seed in range(n_trials):
        w_in, w_cpg, _ = reference_train(p, trial_key(0, seed))
        ok = reference_gait_correct(p, w_in, w_cpg)
        converged += bool(np.all(ok[: int(p.n_gaits)]))
    run_s = time.perf_counter() - t0
    return dict(impl="NumPy loops (Alg. 1 as written)", trials=n_trials, compile_s=0.0, run_s=run_s,
                trials_per_s=n_trials / run_s, converged=converged / n_trials)


def main(args: argparse.Namespace) -> int:
    """``spikejax bench gaits [--trials N] [--out DIR]``."""
    n_trials = args.trials or TARGET_TRIALS
    params = GaitTrialParams(n_gaits=3)
    print(f"machine: {platform.processor() or platform.machine()}, {jax.device_count()} x {jax.devices()[0].platform}, "
          f"jax {jax.__version__}")
    print("three-gait SCPG training trials (Alg. 1, interleaved, budget 200 epochs)")
    rows = [bench_numpy(max(4, min(20, n_trials // 1000)), params)]
    print(f"  {rows[0]['impl']}: {rows[0]['trials_per_s']:.2f} trials/s ({rows[0]['trials']} trials)")
    runs = [lambda c=c: bench_spikejax(n_trials, c, params) for c in (5000, 25000)]
    runs.append(lambda: bench_sweep(n_trials, 25000))
    for run in runs:
        rows.append(run())
        r = rows[-1]
        total = r["compile_s"] + r["run_s"]
        verdict = "meets" if (n_trials >= TARGET_TRIALS and total < TARGET_SECONDS) else "n/a"
        print(f"  {r['impl']}: compile {r['compile_s']:.1f} s, run {r['run_s']:.1f} s for {n_trials} trials "
              f"= {r['trials_per_s']:.0f} trials/s; total {total:.1f} s "
              f"(target {TARGET_TRIALS} in < {TARGET_SECONDS:.0f} s: {verdict}); converged {r['converged']:.1%}")
    print(f"  speed-up over NumPy loops: {max(r['trials_per_s'] for r in rows[1:]) / rows[0]['trials_per_s']:.0f}x")
    if args.out:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        with open(out / "bench_gaits.csv", "w", newline="") as file:
            writer = csv.DictWriter(file, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)
    return 0
