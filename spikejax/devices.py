"""A batch split over devices: every CPU core, or every accelerator, runs its share.

XLA runs most of a CPU program's operations on one thread (scatters and
gathers among them), so a ``jit(vmap(f))`` uses one core whatever the batch.
JAX can present the cores as separate CPU devices (``jax_num_cpu_devices``, set
before JAX starts its backends); `shard_batch` then gives each device an equal
share of the batch with ``jax.shard_map`` (the speed-ups measured are in
docs/BENCHMARKS.md). The same code spreads a batch over GPUs. This module is
the only one that builds a ``Mesh`` or a ``shard_map``.

Each batch member is computed alone, and a batch that does not divide evenly
is padded with copies of its last member, which are dropped from the result.
Arguments that are the same for every member (``in_axes`` None) are not split:
every device gets the whole of them. The split program is compiled apart,
though, so a chaotic computation can come out a rounding different from one
device (the Hough spikes and the RoboBee flights did not; some RoboBee sweep
trials did, see `spikejax.sweep.store`).
"""

from __future__ import annotations

import math
import os
import sys
from typing import Any, Callable

import jax
import jax.numpy as jnp
import numpy as np

from spikejax.errors import UserError

__all__ = ["use_cpu_devices", "cpu_devices_for_run", "shard_batch", "BatchSplit", "in_chunks_on_cpu"]


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
    when nothing was asked. Asking for more devices than the machine has cores
    is allowed (the devices then share the cores) and warned of in one line on
    stderr.

    Raises:
        UserError: if ``asked`` is set and JAX already started with another count.
    """
    cores = os.cpu_count() or 1
    if asked and int(asked) > cores:
        print(
            f"warning: {int(asked)} CPU devices asked for, but this machine has {cores} core{'s' * (cores > 1)}; "
            "the devices share them (no faster than one device per core)",
            file=sys.stderr,
        )
    try:
        use_cpu_devices(int(asked or os.cpu_count() or 1))
    except UserError:
        if asked:
            raise
    return jax.device_count()


def _is_none(x: Any) -> bool:
    return x is None


class BatchSplit:
    """What `shard_batch` returns: ``fn`` jitted, its batch split over the devices.

    Call it like ``fn``, or compile it ahead of time for one shape with
    `compile`.
    """

    def __init__(self, fn: Callable, devices: list[Any], in_axes: Any):
        for axis in jax.tree.leaves(in_axes, is_leaf=_is_none):
            if axis not in (0, None):
                raise UserError(f"shard_batch splits the leading axis: in_axes holds 0 or None, got {axis!r}")
        self.devices = devices
        self.in_axes = in_axes
        if len(devices) == 1:
            self._jitted = jax.jit(fn)
            return
        mesh = jax.sharding.Mesh(np.array(devices), ("batch",))
        split, whole = jax.sharding.PartitionSpec("batch"), jax.sharding.PartitionSpec()
        if isinstance(in_axes, tuple):
            in_specs = jax.tree.map(lambda axis: whole if axis is None else split, in_axes, is_leaf=_is_none)
        else:
            in_specs = whole if in_axes is None else split
        # check_vma=False: fn's scans may start from carries that are the same on every device.
        self._jitted = jax.jit(jax.shard_map(fn, mesh=mesh, in_specs=in_specs, out_specs=split, check_vma=False))

    def padded_size(self, size: int) -> int:
        """The batch a call of ``size`` members runs at: ``size`` rounded up to a multiple of the devices."""
        return math.ceil(size / len(self.devices)) * len(self.devices)

    def __call__(self, *args: Any) -> Any:
        return self._run(self._jitted, args)

    def compile(self, *args: Any) -> Callable:
        """``self``, compiled ahead of time for arguments shaped as ``args`` (``jit(...).lower(...).compile()``).

        Returns:
            A function with ``fn``'s signature that takes arguments of those shapes only.
        """
        padded, _ = self._pad(args)
        compiled = self._jitted.lower(*padded).compile()
        return lambda *call_args: self._run(compiled, call_args)

    def _pad(self, args: tuple[Any, ...]) -> tuple[tuple[Any, ...], int | None]:
        """The arguments padded with their last member to a multiple of the devices, and the size before
        (None: nothing to pad)."""
        if len(self.devices) == 1:
            return args, None
        in_axes = self.in_axes
        batched = jax.tree.map(lambda axis, arg: [] if axis is None else [arg], in_axes, args, is_leaf=_is_none)
        sizes = {jnp.shape(a)[0] for a in jax.tree.leaves(batched)}
        if len(sizes) != 1:
            raise UserError(f"every argument needs the same leading batch axis, got sizes {sorted(sizes)}")
        size = sizes.pop()
        padded = self.padded_size(size)
        if padded == size:
            return args, None

        def pad(axis: Any, arg: Any) -> Any:
            if axis is None:
                return arg
            return jax.tree.map(lambda a: jnp.concatenate([a, jnp.repeat(a[-1:], padded - size, axis=0)]), arg)

        return jax.tree.map(pad, in_axes, args, is_leaf=_is_none), size

    def _run(self, program: Callable, args: tuple[Any, ...]) -> Any:
        padded, size = self._pad(args)
        out = program(*padded)
        return out if size is None else jax.tree.map(lambda a: a[:size], out)


def shard_batch(fn: Callable, devices=None, *, in_axes: Any = 0) -> BatchSplit:
    """``jit(fn)`` with its leading (batch) axis split evenly over ``devices``.

    Args:
        fn: a function of arrays (pytrees) that returns arrays with a leading
            batch axis, each member computed independently (as ``jax.vmap``
            makes one).
        devices: the devices to use (default: ``jax.devices()``).
        in_axes: which arguments carry the batch axis, as ``jax.vmap``'s
            ``in_axes`` but with 0 and None alone: 0 (the default) for every
            argument, or a tuple with one entry per positional argument, each
            0, None, or a pytree prefix of the argument holding 0 and None. An
            argument (or leaf) under None is the same for every member: it is
            neither split nor padded, and every device gets the whole of it.

    Returns:
        A function with ``fn``'s signature (a `BatchSplit`). With one device it
        calls ``jax.jit(fn)``.

    Raises:
        UserError: when called, if the batched arguments' leading axes differ.
    """
    return BatchSplit(fn, list(jax.devices() if devices is None else devices), in_axes)


def in_chunks_on_cpu(fn: Callable, chunk: int | None = None) -> Callable:
    """``fn`` (written for one member, positional array arguments), batched under ``vmap`` in chunks on a CPU.

    On a CPU a ``vmap`` batch runs ``chunk`` members at a time (``lax.map``
    over chunks; None: one at a time): each pass over a member's arrays then
    stays in the cache, where a whole batch's arrays outgrow it (the Hough
    streams' scatters, the hexapod's vision; docs/BENCHMARKS.md). A batch of at
    most ``chunk`` members, and every other backend, is ``vmap``ped whole. Each
    member's result is the same either way.
    """
    batched = jax.custom_batching.custom_vmap(fn)

    @batched.def_vmap
    def _rule(axis_size, in_batched, *args):
        args = jax.tree.map(
            lambda a, b: a if b else jnp.broadcast_to(a, (axis_size, *jnp.shape(a))), args, tuple(in_batched)
        )
        if jax.default_backend() != "cpu" or (chunk is not None and axis_size <= chunk):
            out = jax.vmap(fn)(*args)
        else:
            out = jax.lax.map(lambda a: batched(*a), args, batch_size=chunk)  # an outer vmap meets the rule again
        return out, jax.tree.map(lambda _: True, out)

    return batched
