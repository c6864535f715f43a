"""Independent shares of a job on a pool of processes, one a core.

A batch split over JAX's CPU devices (`spikejax.devices.shard_batch`) runs in
one process: where a program calls back into the host (MuJoCo C stepping the
physics of a closed loop), the devices' callbacks, their Python and XLA's
threads share the process and the cores, and two CPU devices stepped a
closed-loop snake batch only 1.3x faster than one. Two processes, each
pinned to its own core with the same program on half the batch, ran 2.0x
faster (`docs/ARCHITECTURE.md`). `pool` gives such processes: started with
``spawn`` (no JAX state inherited), each pinned to one core before anything
in it starts a thread pool, so XLA and MuJoCo in it see one core.

Results do not depend on the workers: a share is a slice of seeds run as its
own batch, and a seed's trial does not depend on the batch it runs in.
"""

from __future__ import annotations

import multiprocessing
import os
from concurrent.futures import ProcessPoolExecutor

from spikejax.errors import UserError

__all__ = ["cores", "hold_to_core", "workers_for_run", "pool", "shares"]


def cores() -> list[int]:
    """The cores this process may run on."""
    if hasattr(os, "sched_getaffinity"):
        return sorted(os.sched_getaffinity(0))
    return list(range(os.cpu_count() or 1))


def hold_to_core(index: int) -> None:
    """Hold this process to its ``index``-th allowed core (cyclically), before JAX or MuJoCo start a thread pool.

    XLA's CPU thread pool then has one thread, as on a one-core machine; a
    process that may use every core runs a large XLA loop on all of them.
    """
    if hasattr(os, "sched_setaffinity"):
        allowed = cores()
        os.sched_setaffinity(0, {allowed[index % len(allowed)]})


def workers_for_run(asked: int | None = None) -> int:
    """``asked``, else one worker a core of this process.

    Raises:
        UserError: if ``asked`` is below 1.
    """
    if asked is None:
        return len(cores())
    if isinstance(asked, bool) or int(asked) != asked or asked < 1:
        raise UserError(f"workers must be a whole number >= 1, got {asked!r}")
    return int(asked)


def _pin(counter) -> None:
    with counter.get_lock():
        index = counter.value
        counter.value += 1
    hold_to_core(index)  # a spawned process inherits its parent's allowed cores


def pool(workers: int) -> ProcessPoolExecutor:
    """``workers`` fresh processes (``spawn``), the i-th pinned to this process's i-th core (cyclically)."""
    context = multiprocessing.get_context("spawn")
    counter = context.Value("i", 0)
    return ProcessPoolExecutor(workers, mp_context=context, initializer=_pin, initargs=(counter,))


def shares(n: int, workers: int) -> list[tuple[int, int]]:
    """``range(n)`` as at most ``workers`` contiguous, non-empty ``(start, stop)`` slices of near-equal size.

    >>> shares(5, 2)
    [(0, 3), (3, 5)]
    """
    workers = max(1, min(int(workers), int(n)))
    base, extra = divmod(int(n), workers)
    out, start = [], 0
    for i in range(workers):
        stop = start + base + (i < extra)
        out.append((start, stop))
        start = stop
    return out
