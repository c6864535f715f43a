"""A batch split over devices: every CPU core, or every accelerator, runs its share.

XLA runs most of a CPU program's operations on one thread (scatters and
gathers among them), so a ``jit(vmap(f))`` uses one core whatever the batch.
JAX can present the cores as separate CPU devices (``jax_num_cpu_devices``, set
before JAX starts its backends); `shard_batch` then gives each device an equal
share of the batch with ``jax.shard_map``. On the 2-core CPU this made the
synchronous Hough line detector about twice as fast at 64 streams
(docs/BENCHMARKS.md). The same code spreads a batch over GPUs.

Each batch member is computed alone, and a batch that does not divide evenly
is padded with copies of its last member, which are dropped from the result.
The split program is compiled apart, though, so a chaotic computation can come
out a rounding different from one device (the Hough spikes and the RoboBee
flights did not; some RoboBee sweep trials did, see `spikejax.sweep`).
"""

from __future__ import annotations

import math
import os
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np

from spikejax.errors import UserError

__all__ = ["use_cpu_devices", "cpu_devices_for_run", "shard_batch"]


def use_cpu_devices(n: int) -> None:
    """Presents the host CPU as ``n`` devices; call it before anything runs on JAX.

    Raises:
        UserError: if ``n < 1``, or JAX's backends already started with another count.
    """
    n = int(n)
    if n < 1:
        raise UserError(f"the number of CPU devices must be >= 1, not {n}")
    try:
        jax.config.update("jax_num_cpu_devices", n)
    except RuntimeError as e:
        have = len(jax.devices("cpu"))
        if have != n:
            raise UserError(
                f"JAX already started with {have} CPU device(s); set the count ({n}) before anything runs on JAX"
            ) from e


def cpu_devices_for_run(asked: int | None = None) -> int:
    """The CPU devices a benchmark or run uses: ``asked``, else one per core; returns the count JAX presents.

    A process where JAX already started (a test, a notebook) keeps its devices
    when nothing was asked.

    Raises:
        UserError: if ``asked`` is set and JAX already started with another count.
    """
    try:
        use_cpu_devices(int(asked or os.cpu_count() or 1))
    except UserError:
        if asked:
            raise
    return jax.device_count()


def shard_batch(fn: Callable, devices=None) -> Callable:
    """``jit(fn)`` with its leading (batch) axis split evenly over ``devices``.

    Args:
        fn: a function of arrays (pytrees) that all share a leading batch axis and
            returns arrays with that axis, each member computed independently
            (as ``jax.vmap`` makes one).
        devices: the devices to use (default: ``jax.devices()``).

    Returns:
        A function with ``fn``'s signature. With one device it is ``jax.jit(fn)``.
    """
    devices = list(jax.devices() if devices is None else devices)
    if len(devices) == 1:
        return jax.jit(fn)
    n = len(devices)
    mesh = jax.sharding.Mesh(np.array(devices), ("batch",))
    spec = jax.sharding.PartitionSpec("batch")
    # check_vma=False: fn's scans may start from carries that are the same on every device.
    sharded = jax.jit(jax.shard_map(fn, mesh=mesh, in_specs=spec, out_specs=spec, check_vma=False))

    def run(*args):
        sizes = {jnp.shape(a)[0] for a in jax.tree.leaves(args)}
        if len(sizes) != 1:
            raise UserError(f"every argument needs the same leading batch axis, got sizes {sorted(sizes)}")
        size = sizes.pop()
        padded = math.ceil(size / n) * n
        if padded != size:
            args = jax.tree.map(lambda a: jnp.concatenate([a, jnp.repeat(a[-1:], padded - size, axis=0)]), args)
        out = sharded(*args)
        return out if padded == size else jax.tree.map(lambda a: a[:size], out)

    return run
