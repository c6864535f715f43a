"""``spikejax sweep FILE --out DIR``: run a sweep file; run again, it resumes where it stopped."""

from __future__ import annotations

import argparse
from pathlib import Path

from spikejax.commands import Command, count
from spikejax.devices import cpu_devices_for_run
from spikejax.errors import UserError
from spikejax.sweep import load_sweep, run_sweep
from spikejax.sweep.store import check_out


def _add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", help="sweep file (TOML)")
    parser.add_argument("--out", required=True, help="output directory (results table + metadata)")
    parser.add_argument("--chunk-size", type=count, default=None, help="trials per compiled batch")
    parser.add_argument("--seeds", type=count, default=None, help="override the number of seeds")
    parser.add_argument(
        "--cpu-devices",
        type=count,
        default=None,
        help="present the CPU as N devices and split each chunk over them (default: JAX's devices as they are)",
    )
    parser.add_argument(
        "--ray",
        nargs="?",
        const=True,
        default=False,
        metavar="ADDRESS",
        help="run the chunks as tasks on a Ray cluster: the one at ADDRESS (HOST:PORT of its head, or auto), "
        "else $RAY_ADDRESS, else one started on this machine, bound to the loopback address "
        "(needs pip install 'spikejax[ray]')",
    )
    parser.add_argument(
        "--compile-cache",
        default=None,
        metavar="DIR",
        help="JAX's persistent compilation cache, on storage every worker shares (with --ray the default is "
        "$SPIKEJAX_COMPILE_CACHE or ~/.cache/spikejax/jax-compile; without, none)",
    )
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bar")


def run(
    *,
    file: str,
    out: str,
    chunk_size: int | None = None,
    seeds: int | None = None,
    cpu_devices: int | None = None,
    ray: bool | str = False,
    compile_cache: str | None = None,
    no_progress: bool = False,
) -> int:
    """Run the sweep file ``file`` into ``out`` and print the path of its ``results.csv``.

    With ``cpu_devices``, the CPU is presented as that many devices before
    anything runs on JAX, and each chunk is split over them; by default JAX's
    devices are used as they are (one on a CPU, every accelerator otherwise).

    Args:
        file: the sweep file (TOML, see `spikejax.sweep`).
        out: the output directory.
        chunk_size: overrides the file's ``chunk_size``.
        seeds: overrides the file's ``seeds``.
        cpu_devices: the number of CPU devices to present (None: as JAX starts).
        ray: run on a Ray cluster: True for ``$RAY_ADDRESS`` or a local cluster,
            a string for a cluster's address (see `spikejax.sweep.cluster`).
        compile_cache: the directory of JAX's persistent compilation cache.
        no_progress: hide the progress bar.

    Returns:
        The exit status, 0.

    Raises:
        UserError: a bad sweep file, flag or output directory.
    """
    if isinstance(ray, str) and not ray.strip():
        raise UserError("--ray: the address is empty (leave it out for $RAY_ADDRESS or a cluster of this machine)")
    if ray is not False and cpu_devices:
        raise UserError(
            "--cpu-devices splits a chunk over the devices of one process; with --ray every chunk is a task "
            "on one device of a worker: leave out one of them"
        )
    if cpu_devices:
        cpu_devices_for_run(cpu_devices)
    check_out(Path(out))  # before the trial's module is even imported
    spec = load_sweep(file, seeds=seeds, chunk_size=chunk_size)
    results = run_sweep(spec, out, progress=not no_progress, ray=ray, compile_cache=compile_cache)
    print(results)
    return 0


command = Command(
    help="run a sweep file (TOML); resumes where it stopped",
    add_arguments=_add_arguments,
    run=run,
    description="Run every trial of a sweep file's grid times its seeds, chunk by chunk, into --out "
    "(results.csv, metadata.json); run again after an interruption, it goes on where it stopped. With --ray "
    "the chunks run as tasks on a Ray cluster, and this process alone writes the table.",
)
