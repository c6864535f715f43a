"""What a sweep on a cluster costs and saves: JAX's persistent compilation cache, and Ray's overhead per chunk.

Two measurements, each in interleaved rounds so that the figures hold on a
machine whose load changes:

``compile-cache``
    The gait (``sweeps/gait_convergence.toml``) and RoboBee
    (``sweeps/robobee_flights.toml``) sweeps, one seed, each run as
    ``spikejax sweep ... --compile-cache DIR`` in a fresh process: "cold" with
    an empty cache directory, "warm" with the directory the cold run filled
    (what a second worker, or the next run, finds). The figure is the run's
    ``compile_seconds`` from ``metadata.json`` (the compilation, or the load
    from the cache, of the chunk's program) and the process's wall time.

``ray-overhead``
    A trial that does next to nothing, in chunks of ``--chunk`` trials, run
    in this process by the local engine and as Ray tasks on a local cluster
    (``--ray-cpus`` workers), after a warm-up run of each that compiles: the
    driver's wall time per chunk, compile time left out. What Ray adds per
    chunk is the difference; a chunk of trials that take longer than that
    hides it.

Run from the repository root::

    python benchmarks/sweep_cluster.py compile-cache --rounds 3 --out results/bench
    python benchmarks/sweep_cluster.py ray-overhead --rounds 3 --out results/bench
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import NamedTuple

import jax

ROOT = Path(__file__).resolve().parents[1]
SWEEPS = {"gait": ROOT / "sweeps" / "gait_convergence.toml", "robobee": ROOT / "sweeps" / "robobee_flights.toml"}


class TinyParams(NamedTuple):
    a: float = 0.0


def tiny_trial(params: TinyParams, key: jax.Array) -> dict[str, jax.Array]:
    """One uniform draw: a chunk of these is all overhead."""
    return {"value": params.a + jax.random.uniform(key)}


def _sweep_once(sweep: Path, out: Path, cache: Path) -> tuple[float, float]:
    """Compile seconds and wall seconds of one run of ``sweep`` (one seed) in a fresh process."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    command = [sys.executable, "-m", "spikejax.cli", "sweep", str(sweep), "--out", str(out)]
    command += ["--seeds", "1", "--compile-cache", str(cache), "--no-progress"]
    began = time.perf_counter()
    subprocess.run(command, env=env, check=True, capture_output=True)
    wall = time.perf_counter() - began
    return json.loads((out / "metadata.json").read_text())["runs"][-1]["compile_seconds"], wall


def compile_cache(rounds: int) -> list[dict]:
    rows = []
    with tempfile.TemporaryDirectory() as scratch:
        for r in range(rounds):
            for name, sweep in SWEEPS.items():
                cache = Path(scratch) / f"cache-{name}-{r}"
                for state in ("cold", "warm"):
                    compile_s, wall_s = _sweep_once(sweep, Path(scratch) / f"out-{name}-{r}-{state}", cache)
                    rows.append({"sweep": name, "cache": state, "round": r, "compile_s": compile_s, "wall_s": wall_s})
                    print(rows[-1], flush=True)
    return rows


def ray_overhead(rounds: int, chunk: int, chunks: int, ray_cpus: int) -> list[dict]:
    from spikejax.sweep import cluster, load_sweep, run_sweep

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    rows = []
    with tempfile.TemporaryDirectory() as scratch:
        path = Path(scratch) / "tiny.toml"
        path.write_text(
            f'[sweep]\nname = "tiny"\ntrial = "sweep_cluster:tiny_trial"\nseeds = {chunk * chunks}\n'
            f"chunk_size = {chunk}\n\n[grid]\na = [0.0]\n"
        )
        spec = load_sweep(path)
        cluster.connect(True, num_cpus=ray_cpus)
        try:
            for r in range(-1, rounds):  # round -1 warms up (compiles, starts the workers)
                for where in ("local", "ray"):
                    out = Path(scratch) / f"out-{where}-{r}"
                    began = time.perf_counter()
                    run_sweep(spec, out, progress=False, ray=where == "ray", compile_cache=Path(scratch) / "cache")
                    wall = time.perf_counter() - began
                    run = json.loads((out / "metadata.json").read_text())["runs"][-1]
                    if r >= 0:
                        per_chunk = (wall - run["compile_seconds"]) / chunks
                        rows.append({"where": where, "round": r, "chunk": chunk, "s_per_chunk": per_chunk})
                        print(rows[-1], flush=True)
        finally:
            cluster.disconnect()
    return rows


def _summary(rows: list[dict], keys: tuple[str, ...], values: tuple[str, ...]) -> None:
    groups: dict[tuple, list[dict]] = {}
    for row in rows:
        groups.setdefault(tuple(row[k] for k in keys), []).append(row)
    for group, members in groups.items():
        medians = ", ".join(f"{v} {statistics.median(m[v] for m in members):.3f}" for v in values)
        print(f"{dict(zip(keys, group))}: median of {len(members)}: {medians}")


def main() -> None:
    from spikejax.benchmarking import machine_banner, write_csv

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("what", choices=["compile-cache", "ray-overhead"])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--chunk", type=int, default=16, help="trials per chunk (ray-overhead)")
    parser.add_argument("--chunks", type=int, default=32, help="chunks per run (ray-overhead)")
    parser.add_argument("--ray-cpus", type=int, default=2, help="CPUs of the local Ray cluster (ray-overhead)")
    parser.add_argument("--out", type=Path, default=Path("results/bench"))
    args = parser.parse_args()
    print(machine_banner())
    if args.what == "compile-cache":
        rows = compile_cache(args.rounds)
        _summary(rows, ("sweep", "cache"), ("compile_s", "wall_s"))
        columns = ("sweep", "cache", "round", "compile_s", "wall_s")
    else:
        rows = ray_overhead(args.rounds, args.chunk, args.chunks, args.ray_cpus)
        _summary(rows, ("where",), ("s_per_chunk",))
        columns = ("where", "round", "chunk", "s_per_chunk")
    args.out.mkdir(parents=True, exist_ok=True)
    print(write_csv(args.out / f"sweep_{args.what.replace('-', '_')}.csv", rows, columns))


if __name__ == "__main__":
    main()
