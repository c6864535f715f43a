"""Running a sweep: the trials in chunks, each chunk one compiled batch split over the devices.

`run_sweep` runs the trials of a `spikejax.sweep.SweepSpec` that its output
directory does not hold yet. The missing trials are cut into chunks of at most
``chunk_size`` consecutive rows, none crossing a change of the static axes'
values. Every chunk is padded with its last trial to one length, so that one
program, ``jax.vmap`` of the trial compiled ahead of time, serves every chunk
of the same static values (and no result depends on the chunk size). The
program splits each chunk evenly over ``jax.devices()`` with
`spikejax.devices.shard_batch`: the grid's traced fields and the seeds are
split, the fields off the grid go whole to every device. One chunk is in flight
while the one before is written (`spikejax.sweep.store`): dispatch is
asynchronous.

A trial's key is `trial_key` of its seed alone (see `spikejax.sweep`), so no
trial depends on the chunk size or on the other trials of its batch.

Non-finite values. A trial whose state can go non-finite while its results
stay finite (a bool "converged", an int count) says so with a bool result named
``nonfinite``, `nonfinite` of its final state. At the end of a sweep the engine
lists, on stderr and in ``metadata.json`` (``nonfinite_trials``), the trials with
a NaN or infinite float result or that flag set (``nan_trials``: those with a NaN
result).

Errors. An exception the trial raises while it is traced (once, before
anything is compiled) is one line with the file and line of the user's code
that raised it.
"""

from __future__ import annotations

import contextlib
import functools
import logging
import math
import os
import sys
import time
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from tqdm import tqdm

from spikejax.devices import BatchSplit, shard_batch
from spikejax.errors import UserError
from spikejax.sweep import cluster
from spikejax.sweep import store as sweep_store
from spikejax.sweep.spec import SweepSpec, first_line, user_frame
from spikejax.sweep.table import NONFINITE, Column, cells, key_columns, result_dtype

__all__ = ["nonfinite", "run_sweep", "trial_key"]

_NAN_TRIALS_LISTED = 20


def trial_key(base_seed: int, seed: int | jax.Array) -> jax.Array:
    """The key of the trials of seed ``seed``, at every grid point.

    Args:
        base_seed: the sweep's ``base_seed``, ``0 <= base_seed < 2**32``.
        seed: the seed number, ``0 .. seeds-1`` (an int or an int32 array).

    Returns:
        ``jax.random.fold_in(jax.random.key(base_seed), seed)``, a typed key.

    Example:
        >>> u = jax.random.uniform(trial_key(0, 3))  # the draw of seed 3, anywhere
    """
    return jax.random.fold_in(jax.random.key(base_seed), seed)


def nonfinite(tree: Any) -> jax.Array:
    """Whether any floating-point value of ``tree`` (a pytree of arrays) is NaN or infinite.

    A trial returns it as its bool result ``nonfinite`` (of its final state, say)
    and the engine reports the trials where it is true, whatever the other
    results' dtypes.

    Example:
        >>> nonfinite({"w": jnp.array([1.0, jnp.inf]), "n": jnp.array(3)})
        Array(True, dtype=bool)
    """
    flags = [
        ~jnp.all(jnp.isfinite(leaf))
        for leaf in jax.tree.leaves(tree)
        if jnp.issubdtype(jnp.result_type(leaf), jnp.inexact)
    ]
    return jnp.any(jnp.stack(flags)) if flags else jnp.asarray(False)


def _as_result_dict(result: Any, trial_path: str) -> dict[str, Any]:
    if isinstance(result, tuple) and hasattr(result, "_asdict"):
        return dict(result._asdict())
    if isinstance(result, Mapping):
        return dict(result)
    raise UserError(
        f"the trial {trial_path} must return a NamedTuple or a dict of scalars, got {type(result).__name__}"
    )


def _bound_trial(spec: SweepSpec, static_values: Mapping[str, Any]) -> Callable[[Any, jax.Array], Any]:
    static = {**spec.static, **static_values}
    return functools.partial(spec.trial, **static) if static else spec.trial


def _static_values(spec: SweepSpec, trial: int) -> dict[str, Any]:
    """The static axes' values of trial ``trial`` (empty without static axes)."""
    coords = np.unravel_index(trial // spec.seeds, spec.grid_shape)
    return {axis.name: axis.values[int(c)] for axis, c in zip(spec.axes, coords) if axis.static}


def _example_params(spec: SweepSpec) -> Any:
    values = dict(spec.traced)
    for axis in spec.axes:
        if not axis.static:
            values[axis.name] = axis.array()[0]
    return spec.params_type(**values)


def _result_columns(spec: SweepSpec) -> list[Column]:
    """The result columns, found by tracing one trial (nothing is compiled)."""
    trial = _bound_trial(spec, _static_values(spec, 0))
    names: list[Any] = []

    def probe(params: Any, key: jax.Array) -> dict[str, Any]:
        result = _as_result_dict(trial(params, key), spec.trial_path)
        names.extend(result)  # dicts come back with sorted keys; keep the trial's order
        return result

    try:
        shapes = jax.eval_shape(probe, _example_params(spec), jax.random.key(0))
    except UserError:
        raise
    except (ValueError, TypeError) as err:
        # A trial that validates its own arguments (a bad [fixed] choice, say) says why here.
        raise UserError(
            f"the trial {spec.trial_path} rejects the sweep's values: {first_line(err)} (at {user_frame(err)})"
        ) from None
    except Exception as err:  # noqa: BLE001 - whatever the user's trial raises is theirs to fix
        raise UserError(
            f"the trial {spec.trial_path} raised {type(err).__name__} at {user_frame(err)}: {first_line(err)}"
        ) from None
    taken = {column.name for column in key_columns(spec)}
    columns = []
    for name in names:
        if not isinstance(name, str) or name in taken:
            raise UserError(
                f"the trial {spec.trial_path} returns a result named {name!r}, which is not a free column name"
            )
        shape = shapes[name]
        if not isinstance(shape, jax.ShapeDtypeStruct) or shape.shape != ():
            raise UserError(
                f"result '{name}' of the trial {spec.trial_path} must be a scalar, got "
                f"{getattr(shape, 'shape', type(shape).__name__)}"
            )
        columns.append(Column(name, result_dtype(shape.dtype, name, spec.trial_path)))
        if name == NONFINITE and columns[-1].dtype != "bool":
            raise UserError(
                f"result '{NONFINITE}' of the trial {spec.trial_path} must be a bool "
                f"(spikejax.sweep.nonfinite of its state), got {shape.dtype}"
            )
        taken.add(name)
    if not columns:
        raise UserError(f"the trial {spec.trial_path} returns no results")
    return columns


def _batched_trial(
    spec: SweepSpec, results: list[Column], static_values: Mapping[str, Any], devices: list[Any]
) -> BatchSplit:
    """The trial for these static values, vmapped over a chunk and split over ``devices``.

    Each trial is computed alone either way, but XLA compiles the split program
    apart, and a chaotic trial can come out a rounding different on another
    number of devices (the toy trials of the tests do not), so a table is only
    resumed on as many devices as it was started on (`spikejax.sweep.store`).
    """
    trial = _bound_trial(spec, static_values)
    on_grid = {axis.name for axis in spec.axes if not axis.static}
    params_axes = spec.params_type(**{field: 0 if field in on_grid else None for field in spec.params_type._fields})

    def one(params: Any, seed: jax.Array) -> tuple[jax.Array, ...]:
        result = _as_result_dict(trial(params, trial_key(spec.base_seed, seed)), spec.trial_path)
        return tuple(jnp.asarray(result[column.name]).astype(column.dtype) for column in results)

    return shard_batch(jax.vmap(one, in_axes=(params_axes, 0)), devices, in_axes=(params_axes, 0))


def _chunk_inputs(spec: SweepSpec, start: int, end: int, size: int) -> tuple[Any, np.ndarray]:
    """Params and seeds of the trials ``start .. end-1``, padded to ``size`` with the last."""
    index = np.minimum(np.arange(start, start + size), end - 1)
    point, seed = np.divmod(index, spec.seeds)
    coords = np.unravel_index(point, spec.grid_shape)
    values = dict(spec.traced)
    for axis, coord in zip(spec.axes, coords):
        if not axis.static:
            values[axis.name] = axis.array()[coord]
    return spec.params_type(**values), seed.astype(np.int32)


def _chunks(missing: list[tuple[int, int]], size: int, block: int | None = None) -> Iterator[tuple[int, int]]:
    """Chunks of at most ``size`` trials covering ``missing``, none crossing a multiple of ``block``."""
    for start, end in missing:
        chunk_start = start
        while chunk_start < end:
            chunk_end = min(chunk_start + size, end)
            if block is not None:
                chunk_end = min(chunk_end, (chunk_start // block + 1) * block)
            yield chunk_start, chunk_end
            chunk_start = chunk_end


def _static_block(spec: SweepSpec) -> int | None:
    """Trials that share the static axes' values come in runs of this length (None: no static axis)."""
    static = [i for i, axis in enumerate(spec.axes) if axis.static]
    if not static:
        return None
    return spec.seeds * math.prod(spec.grid_shape[static[-1] + 1 :])


def _progress_bar(spec: SweepSpec, done: int, enabled: bool) -> tqdm:
    interactive = sys.stderr.isatty() and os.environ.get("CI", "").lower() not in ("1", "true")
    return tqdm(
        total=spec.n_trials,
        initial=done,
        desc=spec.name,
        unit=" trials",
        file=sys.stderr,
        disable=not enabled,
        dynamic_ncols=interactive,
        mininterval=0.5 if interactive else 30.0,
        smoothing=0.05,
    )


def run_sweep(
    spec: SweepSpec,
    out_dir: str | os.PathLike[str],
    progress: bool = True,
    *,
    ray: bool | str = False,
    compile_cache: str | os.PathLike[str] | None = None,
    ray_cpus: int | None = None,
) -> Path:
    """Run the trials of ``spec`` that ``out_dir`` does not hold yet.

    The trials run in chunks of ``spec.chunk_size`` consecutive rows through one
    compiled ``jax.jit(jax.vmap(trial))``, split evenly over ``jax.devices()``
    (the accelerators, or the CPU's cores when ``--cpu-devices`` presents them
    as devices); each chunk is written to disk as soon as it is done. Run it
    again after an interruption and it goes on where it stopped; on a finished
    sweep it computes nothing. See `spikejax.sweep.store` for the files in
    ``out_dir``, how they are kept whole, and the rules of resuming.

    Args:
        spec: the sweep, from `spikejax.sweep.load_sweep`.
        out_dir: the output directory; created if missing.
        progress: show a progress bar (trials/s, ETA) on stderr.
        ray: run the chunks as tasks on a Ray cluster (`spikejax.sweep.cluster`):
            True for ``$RAY_ADDRESS`` or else a cluster started on this machine
            (loopback only), a string for the address of a running cluster.
            False: in this process.
        compile_cache: a directory for JAX's persistent compilation cache (a Ray
            run's default: `spikejax.sweep.cluster.default_compile_cache`; a
            local run uses none unless given one).
        ray_cpus: the CPUs of a Ray cluster started here (default: all).

    Returns:
        The path of ``results.csv``.

    Raises:
        UserError: ``out_dir`` cannot be used (a file, below a file, not
            writable, a non-empty directory of no sweep), holds another sweep,
            another run is going on in it, the table would not fit on its disk,
            the trial does not return a NamedTuple or dict of scalars, or raises
            while traced (the message names the user's file and line). All are
            found before anything is compiled. Later: the disk fills up (the
            files stay whole; run again to resume), or a static value the trial
            rejects when its chunks come. With ``ray``: Ray is not installed or no
            cluster answers (before anything is written), a trial raises (the
            chunk and the trial are named, the finished chunks kept).
    """
    out = Path(out_dir)
    # A Ray task runs its chunk on one device of its worker.
    metadata, missing = sweep_store.existing(out, spec, devices=1 if ray else None)
    if metadata is not None and not missing:
        columns = sweep_store.recorded_columns(metadata)
    else:
        columns = key_columns(spec) + _result_columns(spec)
        sweep_store.check_columns(out, metadata, columns)
    first_result = len(key_columns(spec))
    if missing:
        sweep_store.check_space(out, spec, columns)
    cache = None
    if compile_cache is not None or (ray and missing):
        cache = cluster.check_compile_cache(compile_cache or cluster.default_compile_cache())
        if not ray:
            cluster.use_compile_cache(cache)
    connected = cluster.is_connected()
    on_ray = cluster.connect(ray, num_cpus=ray_cpus) if ray and missing else None
    try:
        with sweep_store.opened(out, spec, metadata, columns, spec.chunk_size) as store:
            if cache is not None:
                store.run["compile_cache"] = str(cache)
            try:
                _run_missing(spec, store, columns[first_result:], progress, on_ray, cache)
            finally:
                store.publish()
            if store.done == spec.n_trials:
                _finish(spec, store, columns, first_result)
    finally:
        if on_ray is not None and not connected:
            cluster.disconnect()
    return sweep_store.results_path(out)


def _run_missing(
    spec: SweepSpec,
    store: sweep_store.Store,
    results: list[Column],
    progress: bool,
    on_ray: cluster.Cluster | None = None,
    cache: Path | None = None,
) -> None:
    missing = store.missing()
    if not missing:
        return
    block = _static_block(spec)
    chunks = list(_chunks(missing, spec.chunk_size, block))
    # Every chunk is padded with its last trial to the longest: one program serves them all.
    length = max(end - start for start, end in chunks)
    if on_ray is not None:
        _run_on_ray(spec, store, results, progress, on_ray, cache, chunks, length)
        return
    devices = jax.devices()
    store.begin_compute(len(devices))
    programs: dict[tuple[Any, ...], Callable[..., tuple[jax.Array, ...]]] = {}

    def program(start: int) -> Callable[..., tuple[jax.Array, ...]]:
        static_values = _static_values(spec, start)
        signature = tuple(static_values.items())
        if signature not in programs:
            batched = _batched_trial(spec, results, static_values, devices)
            if progress:
                shown = "".join(f", {name} = {value}" for name, value in signature)
                print(
                    f"{spec.name}: compiling for chunks of {batched.padded_size(length)} trials{shown}",
                    file=sys.stderr,
                    flush=True,
                )
            began = time.perf_counter()
            try:
                programs[signature] = batched.compile(*_chunk_inputs(spec, 0, 1, length))
            except UserError:
                raise
            except Exception as err:  # noqa: BLE001 - a static axis's later value the trial rejects
                shown_values = ", ".join(f"{name} = {value!r}" for name, value in signature)
                raise UserError(
                    f"the trial {spec.trial_path} failed for {shown_values or 'these values'} at {user_frame(err)}: "
                    f"{type(err).__name__}: {first_line(err)} (the trials done so far are kept)"
                ) from None
            store.add_compile_seconds(time.perf_counter() - began)
        return programs[signature]

    def run(first: int, last: int) -> list[np.ndarray]:
        outputs = program(first)(*_chunk_inputs(spec, first, last, length))
        return [np.asarray(values)[: last - first] for values in outputs]

    def write(start: int, end: int, outputs: tuple[jax.Array, ...]) -> None:
        try:  # the chunk's results, waited for: what the trial raised comes out here
            values = [np.asarray(column)[: end - start] for column in outputs]
        except Exception as err:  # noqa: BLE001 - the trial raised while its chunk ran
            raise chunk_failed(spec, start, end, error_text(err), first_failing(run, start, end)) from None
        store.add(start, end, cells(spec, start, end, values))
        bar.update(end - start)

    with _progress_bar(spec, store.done, progress) as bar, quiet_callback_errors():
        # One chunk in flight while the previous one is written: dispatch is asynchronous.
        pending = None
        for start, end in chunks:
            try:
                outputs = program(start)(*_chunk_inputs(spec, start, end, length))
            except BaseException as err:
                if pending is not None:  # the chunk before is done: keep it
                    write(*pending)
                if isinstance(err, Exception) and not isinstance(err, UserError):
                    raise chunk_failed(spec, start, end, error_text(err), first_failing(run, start, end)) from None
                raise
            if pending is not None:
                write(*pending)
            pending = (start, end, outputs)
        if pending is not None:
            write(*pending)


def trial_text(spec: SweepSpec, trial: int) -> str:
    """``trial T (seed S, a = 1.0, ...)``: a trial, its seed and its grid values."""
    point, seed = divmod(trial, spec.seeds)
    coords = np.unravel_index(point, spec.grid_shape)
    values = ", ".join(f"{axis.name} = {axis.values[int(c)]!r}" for axis, c in zip(spec.axes, coords))
    return f"trial {trial} (seed {seed}{', ' + values if values else ''})"


def error_text(err: BaseException) -> str:
    """One line for an exception of the trial: where a traced one was raised, or a host callback's last line."""
    text = str(err).strip()
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    if len(lines) > 1 and "Traceback (most recent call last)" in text:
        # A host callback's exception comes back inside XLA's message, its traceback as text.
        files = [line for line in lines if line.startswith('File "')]
        user = [line for line in files if "site-packages" not in line and f"{os.sep}jax{os.sep}" not in line]
        where = ""
        if user:
            name, _, rest = user[-1][len('File "') :].partition('", line ')
            where = f" (at {name}:{rest.split(',')[0]})"
        return f"{lines[-1]}{where}"
    return f"{type(err).__name__}: {first_line(err)} (at {user_frame(err)})"


@contextlib.contextmanager
def quiet_callback_errors() -> Iterator[None]:
    """JAX's log of a host callback's exception held back: the engine reports it, in one line."""
    logger = logging.getLogger("jax._src.debugging")
    level = logger.level
    logger.setLevel(logging.CRITICAL)
    try:
        yield
    finally:
        logger.setLevel(level)


def first_failing(run: Callable[[int, int], Any], start: int, end: int) -> int | None:
    """The first trial of ``start .. end-1`` for which ``run(first, last)`` raises, found by halves.

    ``run(first, last)`` computes the trials ``first .. last-1`` alone (the chunk is
    padded with its last trial). A trial that raises only beside others gives None.
    """
    low, high = start, end
    while high - low > 1:
        middle = (low + high) // 2
        try:
            run(low, middle)
        except Exception:  # noqa: BLE001
            high = middle
        else:
            low = middle
    try:
        run(low, low + 1)
    except Exception:  # noqa: BLE001
        return low
    return None


def chunk_failed(spec: SweepSpec, start: int, end: int, message: str, trial: int | None) -> UserError:
    """The one-line error of a chunk whose trial raised: the chunk, the trial, what it raised."""
    at = f", at {trial_text(spec, trial)}" if trial is not None else ""
    return UserError(
        f"sweep '{spec.name}': the chunk of trials {start}..{end - 1} failed{at}: the trial {spec.trial_path}: "
        f"{message} (the chunks done so far are kept)"
    )


def _run_on_ray(
    spec: SweepSpec,
    store: sweep_store.Store,
    results: list[Column],
    progress: bool,
    on_ray: cluster.Cluster,
    cache: Path | None,
    chunks: list[tuple[int, int]],
    length: int,
) -> None:
    store.begin_compute(1)
    store.run["ray"] = on_ray.record()
    if progress:
        print(
            f"{spec.name}: {len(chunks)} chunks of {length} trials as Ray tasks on {on_ray.nodes} node(s), "
            f"{on_ray.cpus:g} CPUs, {on_ray.gpus:g} GPUs ({on_ray.address})",
            file=sys.stderr,
            flush=True,
        )
    with _progress_bar(spec, store.done, progress) as bar:

        def write(start: int, end: int, outputs: list[np.ndarray]) -> None:
            store.add(start, end, cells(spec, start, end, outputs))
            bar.update(end - start)

        cluster.run_chunks(spec, store, results, chunks, length, bar, on_ray, cache, write)


def _finish(spec: SweepSpec, store: sweep_store.Store, columns: list[Column], first_result: int) -> None:
    _, trials = store.finish(columns, first_result)
    if trials:
        listed = ", ".join(str(trial) for trial in trials[:_NAN_TRIALS_LISTED])
        more = f", ... ({len(trials) - _NAN_TRIALS_LISTED} more)" if len(trials) > _NAN_TRIALS_LISTED else ""
        print(
            f"warning: sweep '{spec.name}': non-finite values (NaN or inf) in {len(trials)} of {spec.n_trials} "
            f"trials: {listed}{more} (all in {store.metadata_path}, nonfinite_trials)",
            file=sys.stderr,
        )
