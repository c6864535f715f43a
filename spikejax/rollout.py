"""The closed loop of an env and a controller: one ``lax.scan``, per-member resets, decimated records, resumable chunks.

`rollout` runs a controller against an env for a number of control steps in
one ``lax.scan``. It knows nothing of any robot: the env is an ``env_step``
function on a state shaped like Brax's ``State`` (``.done`` and ``.info`` are
read), the controller a `Controller` pair of functions. It is written for one
member; ``jax.vmap`` makes a batch, in which every member resets on its own.

Resets follow the neurorobotics platform (NRP): when an episode fails
(``done > 0``) or completes (``info["completed"]``), the robot is put back and
the brain is not. The env state is replaced by the user's ``reset`` and the
controller keeps its state (weights, traces, neuron states) except what its
``on_reset`` says it forgets. Both are computed every step and selected per
member with ``jnp.where``, which is what a ``vmap`` does to a branch anyway.

Records are decimated: a run of ``steps`` control steps keeps, per block of
``every`` steps, the mean and the last value of the user's per-step summary,
the failures and completions in the block, and an optional snapshot taken at
the block's end (weights, say), never every state.

`run_chunked` runs a long training as chunks of a compiled ``advance`` (a
jitted, vmapped `rollout`, typically), writes a checkpoint after each chunk
(atomically: temporary file, fsync, rename, as `spikejax.sweep.store` writes
its files) and, run again, resumes from it; a run killed at any moment and
resumed ends with the results of an uninterrupted run, bit for bit.

Example:
    >>> ctrl = Controller(step=my_step, on_reset=lambda params, c: c._replace(integral=0.0))  # doctest: +SKIP
    >>> go = jax.jit(jax.vmap(lambda p, loop: rollout(env.step, my_reset, ctrl, p, loop, 500, every=50)))  # doctest: +SKIP
    >>> loop, records = go(params, jax.vmap(loop_init)(env_states, ctrl_states, key=keys))  # doctest: +SKIP
"""

from __future__ import annotations

import contextlib
import operator
import os
import zipfile
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from spikejax.errors import UserError
from spikejax.files import atomic_file

__all__ = ["CHECKPOINT", "Controller", "LoopState", "loop_init", "rollout", "run_chunked"]

CHECKPOINT = "checkpoint.npz"
_FORMAT = 1
_LOCK = ".checkpoint.lock"


class Controller(NamedTuple):
    """A controller as two pure functions, for one member (no batch axis).

    Attributes:
        step: ``step(params, cstate, env_state, *, key) -> (cstate, action, out)``:
            one control step; it reads the env state the last step left (or the
            fresh one of a reset), learns, and returns the action for
            ``env_step`` and ``out``, a pytree of per-step outputs that the
            summary may use (``{}`` if none).
        on_reset: ``on_reset(params, cstate) -> cstate``: what the controller
            forgets when its member's env is reset (a direction integrator, the
            neurons' potentials); ``lambda params, cstate: cstate`` forgets
            nothing. Learned state (weights) is kept by returning it unchanged.
    """

    step: Callable[..., tuple[Any, Any, Any]]
    on_reset: Callable[[Any, Any], Any]


class LoopState(NamedTuple):
    """The carry of `rollout` for one member; the carry of `run_chunked` when batched.

    Attributes:
        env: the env's state (Brax ``State``-like).
        controller: the controller's state.
        key: the member's PRNG key (typed or raw ``uint32``), split every step.
        steps: int32, control steps done.
        failures: int32, resets due to a failure (``done > 0``).
        completions: int32, episodes completed (``info["completed"]``).
    """

    env: Any
    controller: Any
    key: jax.Array
    steps: jax.Array
    failures: jax.Array
    completions: jax.Array


def loop_init(env_state: Any, controller_state: Any, *, key: jax.Array) -> LoopState:
    """A loop at step 0, no failure, no completion.

    Args:
        env_state: the env's first state (e.g. ``env.reset(rng)``).
        controller_state: the controller's first state.
        key: the member's PRNG key; with a batch, one per member, so that a
            member's run does not depend on the batch it is in.
    """
    zero = jnp.zeros((), jnp.int32)
    return LoopState(env_state, controller_state, key, zero, zero, zero)


def _count(name: str, value: Any, least: int) -> int:
    try:
        if isinstance(value, bool):
            raise TypeError
        number = operator.index(value)
    except TypeError:
        raise UserError(f"{name} must be an integer, got {value!r}") from None
    if number < least:
        raise UserError(f"{name} must be at least {least}, got {number}")
    return number


def _described(tree: Any) -> list[str]:
    return [f"{getattr(leaf, 'dtype', jnp.result_type(leaf))}{list(jnp.shape(leaf))}" for leaf in jax.tree.leaves(tree)]


def _check_like(what: str, new: Any, old: Any) -> None:
    """Raises a UserError unless ``new`` has the structure, shapes and dtypes of ``old``."""
    if jax.tree.structure(new) != jax.tree.structure(old):
        raise UserError(
            f"{what} returned a pytree of another structure than it was given: "
            f"{jax.tree.structure(new)} instead of {jax.tree.structure(old)}"
        )
    for path_leaf, leaf in zip(jax.tree_util.tree_leaves_with_path(old), jax.tree.leaves(new)):
        path, before = path_leaf
        if jnp.shape(leaf) != jnp.shape(before) or jnp.result_type(leaf) != jnp.result_type(before):
            raise UserError(
                f"{what} returned {jax.tree_util.keystr(path) or 'its value'} as {_described(leaf)[0]}, "
                f"it was given {_described(before)[0]}"
            )


def _where(pred: jax.Array, new: Any, old: Any) -> Any:
    return jax.tree.map(lambda a, b: jnp.where(pred, a, b), new, old)


def _completed(env_state: Any) -> jax.Array:
    info = getattr(env_state, "info", None)
    if isinstance(info, Mapping) and "completed" in info:
        return jnp.asarray(info["completed"]) > 0
    return jnp.zeros((), bool)


def rollout(
    env_step: Callable[[Any, Any], Any],
    reset: Callable[..., Any],
    controller: Controller,
    params: Any,
    loop: LoopState,
    steps: int,
    *,
    summarize: Callable[[LoopState, Any, Any], Mapping[str, Any]] | None = None,
    every: int = 1,
    snapshot: Callable[[LoopState], Any] | None = None,
) -> tuple[LoopState, dict[str, Any]]:
    """Run ``controller`` in the env for ``steps`` control steps, resetting the env where an episode ends.

    Each step, from ``loop``: the key is split into the next loop key, the
    controller's key and the reset's key (from the member's own key, so a
    member's run does not depend on the batch size); the controller steps;
    ``env_step`` applies its action; a failure (``done > 0``) or a completion
    (``info["completed"]`` true, if the env state has it; a step that fails
    does not also complete) is counted; where either happened, the env state
    becomes ``reset(...)`` and the controller state ``controller.on_reset(...)``.

    Args:
        env_step: ``env_step(env_state, action) -> env_state``.
        reset: ``reset(env_state, failed, completed, *, key) -> env_state``: the
            fresh env state for a member whose episode ended, given the state
            the ending step produced (whose ``info`` may say, e.g., which way the
            track ran, to mirror it after a completion) and two bool scalars.
            It is computed every step and used only where an episode ended; it
            must return a state of the structure, shapes and dtypes it is given.
        controller: the `Controller`.
        params: the controller's parameters (traced; vmap over them freely).
        loop: the `LoopState` to start from (`loop_init`, or the last call's).
        steps: control steps to run, a multiple of ``every``.
        summarize: optional ``summarize(loop, out, env_state) -> dict`` of
            per-step values (scalars or arrays): ``loop`` is the `LoopState`
            after the step (counts updated, any reset done), ``out`` the
            controller's output, ``env_state`` the state ``env_step`` produced,
            before any reset (so it shows the failure).
        every: the block of steps each record covers.
        snapshot: optional ``snapshot(loop) -> pytree`` taken at each block's end.

    Returns:
        The loop after the last step, and the records, with ``steps // every``
        blocks on the leading axis of every leaf:

        * ``"mean"``: the summary's mean over each block (``jnp.mean``; ``{}``
          without ``summarize``),
        * ``"last"``: the summary at each block's last step,
        * ``"failures"``, ``"completions"``: int32 counts in each block,
        * ``"snapshot"``: the snapshots (``None`` without ``snapshot``).

    Raises:
        UserError: ``steps`` or ``every`` is not a positive integer, ``steps``
            is not a multiple of ``every``; at trace time, ``env_step``,
            ``reset``, ``controller.step`` or ``controller.on_reset`` returns a
            state unlike the one it was given, or ``summarize`` no mapping.
    """
    steps = _count("steps", steps, 1)
    every = _count("every", every, 1)
    if steps % every:
        raise UserError(f"steps ({steps}) must be a multiple of every ({every})")

    def one_step(loop: LoopState, _):
        key, controller_key, reset_key = jax.random.split(loop.key, 3)
        cstate, action, out = controller.step(params, loop.controller, loop.env, key=controller_key)
        _check_like("controller.step", cstate, loop.controller)
        env = env_step(loop.env, action)
        _check_like("env_step", env, loop.env)
        failed = jnp.asarray(env.done) > 0
        completed = _completed(env) & ~failed
        ended = failed | completed
        fresh = reset(env, failed, completed, key=reset_key)
        _check_like("reset", fresh, env)
        forgot = controller.on_reset(params, cstate)
        _check_like("controller.on_reset", forgot, cstate)
        loop = LoopState(
            env=_where(ended, fresh, env),
            controller=_where(ended, forgot, cstate),
            key=key,
            steps=loop.steps + 1,
            failures=loop.failures + failed.astype(jnp.int32),
            completions=loop.completions + completed.astype(jnp.int32),
        )
        summary = {} if summarize is None else summarize(loop, out, env)
        if not isinstance(summary, Mapping):
            raise UserError(f"summarize must return a dict of per-step values, got {type(summary).__name__}")
        return loop, (dict(summary), failed, completed)

    def block(loop: LoopState, _):
        if every == 1:  # no inner loop: its carry, the whole env state, would be copied in and out every step
            loop, (summary, failed, completed) = one_step(loop, None)
            summary, failed, completed = jax.tree.map(lambda x: x[None], (summary, failed, completed))
        else:
            loop, (summary, failed, completed) = jax.lax.scan(one_step, loop, None, length=every)
        record = {
            "mean": jax.tree.map(lambda x: jnp.mean(x, axis=0), summary),
            "last": jax.tree.map(lambda x: x[-1], summary),
            "failures": jnp.sum(failed, dtype=jnp.int32),
            "completions": jnp.sum(completed, dtype=jnp.int32),
            "snapshot": None if snapshot is None else snapshot(loop),
        }
        return loop, record

    return jax.lax.scan(block, loop, None, length=steps // every)


# ---------------------------------------------------------------- chunks and checkpoints


def _is_key(leaf: Any) -> bool:
    return hasattr(leaf, "dtype") and jnp.issubdtype(leaf.dtype, jax.dtypes.prng_key)


def _to_host(leaf: Any) -> tuple[np.ndarray, str]:
    """A leaf as a numpy array, and its PRNG implementation's name ("" for a plain array)."""
    if _is_key(leaf):
        return np.asarray(jax.random.key_data(leaf)), str(jax.random.key_impl(leaf))
    return np.asarray(leaf), ""


def _from_host(data: np.ndarray, impl: str) -> jax.Array:
    return jax.random.wrap_key_data(jnp.asarray(data), impl=impl) if impl else jnp.asarray(data)


@contextlib.contextmanager
def _locked(directory: Path) -> Iterator[None]:
    try:
        import fcntl
    except ImportError:  # no advisory locks on this OS: runs are not guarded
        yield
        return
    with open(directory / _LOCK, "a") as lock:
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise UserError(f"another run is using the checkpoint directory {directory}") from None
        yield


class _Chunks:
    """The records of the chunks done, per leaf, on the host."""

    def __init__(self, axis: int):
        self.axis = axis
        self.treedef = None
        self.leaves: list[list[np.ndarray]] = []
        self.impls: list[str] = []

    def add(self, records: Any) -> None:
        leaves, treedef = jax.tree.flatten(records)
        hosted = [_to_host(leaf) for leaf in leaves]
        if self.treedef is None:
            self.treedef = treedef
            self.leaves = [[] for _ in leaves]
            self.impls = [impl for _, impl in hosted]
        for parts, (data, _) in zip(self.leaves, hosted):
            parts.append(data)

    def joined(self) -> list[np.ndarray]:
        return [np.concatenate(parts, axis=self.axis) for parts in self.leaves]

    def records(self) -> Any:
        if self.treedef is None:
            return None
        leaves = [_from_host(data, impl) if impl else data for data, impl in zip(self.joined(), self.impls)]
        return jax.tree.unflatten(self.treedef, leaves)


def _normal_axis(record_axis: int, records: Any) -> int:
    """``record_axis`` as a non-negative axis valid for every leaf of ``records`` (shapes, not data)."""
    ndims = {len(jnp.shape(leaf)) for leaf in jax.tree.leaves(records)}
    if not ndims:
        return record_axis if record_axis >= 0 else 0
    low = min(ndims)
    if not -low <= record_axis < low:
        raise UserError(f"record_axis {record_axis} is not an axis of every record (the smallest has {low} axes)")
    if record_axis < 0 and len(ndims) > 1:
        raise UserError(f"record_axis {record_axis} counts from the end, and the records have {sorted(ndims)} axes")
    return record_axis % low


def _save(path: Path, fingerprint: str, done: int, total: int, chunk_steps: int, carry: Any, chunks: _Chunks) -> None:
    arrays: dict[str, np.ndarray] = {
        "format": np.asarray(_FORMAT),
        "fingerprint": np.asarray(fingerprint),
        "done_steps": np.asarray(done, np.int64),
        "total_steps": np.asarray(total, np.int64),
        "chunk_steps": np.asarray(chunk_steps, np.int64),
        "record_axis": np.asarray(chunks.axis, np.int64),
    }
    for i, leaf in enumerate(jax.tree.leaves(carry)):
        arrays[f"carry_{i}"], impl = _to_host(leaf)
        arrays[f"carry_{i}_impl"] = np.asarray(impl)
    for i, (data, impl) in enumerate(zip(chunks.joined(), chunks.impls)):
        arrays[f"records_{i}"] = data
        arrays[f"records_{i}_impl"] = np.asarray(impl)
    with atomic_file(path) as file:
        np.savez(file, **arrays)


def _saved_leaf(saved: Mapping[str, np.ndarray], name: str) -> jax.Array | None:
    """The array saved as ``name``, a PRNG key array again if it was one (None: missing or unreadable)."""
    if name not in saved or f"{name}_impl" not in saved:
        return None
    try:
        return _from_host(saved[name], str(saved[f"{name}_impl"]))
    except (TypeError, ValueError):
        return None


def _held(saved: Mapping[str, np.ndarray], name: str, value: jax.Array | None) -> str:
    if value is not None:
        return _described(value)[0]
    if name in saved:
        return f"{saved[name].dtype}{list(saved[name].shape)} (unreadable)"
    return "nothing"


def _load(
    path: Path,
    fingerprint: str,
    total: int,
    chunk_steps: int,
    template: Any,
    records_shape: Callable[[], Any],
    chunks: _Chunks,
):
    """The steps done and the carry of the checkpoint at ``path``; fills ``chunks`` with its records."""
    where = path.parent
    try:
        with np.load(path, allow_pickle=False) as data:
            saved = {name: data[name] for name in data.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as err:
        raise UserError(f"cannot read the checkpoint {path} ({err}): delete it to start over") from None
    missing = {"format", "fingerprint", "done_steps", "record_axis"} - set(saved)
    if missing or int(saved["format"]) != _FORMAT:
        raise UserError(
            f"{path} is not a checkpoint of spikejax.rollout.run_chunked (format {_FORMAT}): delete it to start over"
        )
    there = str(saved["fingerprint"])
    if there != fingerprint:
        raise UserError(
            f"{where} holds a checkpoint of another run (fingerprint {there!r} there, {fingerprint!r} here): "
            f"choose another directory, or delete {path} to start over"
        )
    done = int(saved["done_steps"])
    if done > total:
        raise UserError(f"{path} has {done} steps done, more than total_steps ({total})")
    if (total - done) % chunk_steps:
        raise UserError(f"the {total - done} steps left in {where} must be a multiple of chunk_steps ({chunk_steps})")

    leaves, treedef = jax.tree.flatten(template)
    n_saved = sum(1 for name in saved if name.startswith("carry_") and not name.endswith("_impl"))
    if n_saved != len(leaves):
        raise UserError(f"{where} holds a carry of {n_saved} arrays, this run's carry has {len(leaves)}")
    carry = []
    for i, (path_in, leaf) in enumerate(jax.tree_util.tree_leaves_with_path(template)):
        value = _saved_leaf(saved, f"carry_{i}")
        if value is None or value.shape != jnp.shape(leaf) or value.dtype != jnp.result_type(leaf):
            raise UserError(
                f"{where} holds carry leaf {jax.tree_util.keystr(path_in)} as {_held(saved, f'carry_{i}', value)}, "
                f"this run's carry has {_described(leaf)[0]}"
            )
        carry.append(value)

    shapes, records_def = jax.tree.flatten(records_shape())
    if int(saved["record_axis"]) != chunks.axis:
        raise UserError(
            f"{where} holds records joined along axis {int(saved['record_axis'])}, "
            f"this run joins them along axis {chunks.axis}"
        )
    n_records = sum(1 for name in saved if name.startswith("records_") and not name.endswith("_impl"))
    if n_records != len(shapes):
        raise UserError(f"{where} holds records of {n_records} arrays, this run's records have {len(shapes)}")
    chunks.treedef = records_def
    chunks.leaves, chunks.impls = [], []
    for i, shape in enumerate(shapes):
        value = _saved_leaf(saved, f"records_{i}")
        if (
            value is None
            or value.dtype != shape.dtype
            or value.ndim != len(shape.shape)
            or any(a != b for axis, (a, b) in enumerate(zip(value.shape, shape.shape)) if axis != chunks.axis)
        ):
            raise UserError(
                f"{where} holds records of other shapes than this run makes (record {i}: "
                f"{_held(saved, f'records_{i}', value)}, a chunk makes {_described(shape)[0]})"
            )
        chunks.leaves.append([saved[f"records_{i}"]])
        chunks.impls.append(str(saved[f"records_{i}_impl"]))
    return done, jax.tree.unflatten(treedef, carry)


def run_chunked(
    advance: Callable[[Any, int], tuple[Any, Any]],
    carry: Any,
    total_steps: int,
    chunk_steps: int,
    *,
    directory: str | os.PathLike[str] | None = None,
    fingerprint: str = "",
    progress: Callable[[int, int], Any] | None = None,
    record_axis: int = 0,
) -> tuple[Any, Any]:
    """Run ``advance`` chunk after chunk for ``total_steps`` steps, checkpointed after each chunk and resumable.

    Results do not depend on the chunking: for a scan such as `rollout`,
    ``total_steps // chunk_steps`` chunks give the carry and records of one
    call for ``total_steps``, bit for bit (one compiled chunk, the same step).

    With a ``directory``, the carry, the records so far, ``fingerprint`` and the
    steps done are written after every chunk to ``directory/checkpoint.npz``,
    whole or not at all (temporary file, fsync, rename). A run that finds a
    checkpoint there resumes from it, so a run killed at any moment (SIGKILL
    included) and started again ends as an uninterrupted run. PRNG keys in the
    carry survive as their key data and implementation (typed keys) or as
    ``uint32`` arrays (raw keys). On resuming, ``advance`` is traced once
    (``jax.eval_shape``, nothing runs) to learn the records' structure. The
    checkpoint stays after the last chunk: run again, the call returns the
    finished results without computing. One run at a time per directory.

    Args:
        advance: ``advance(carry, chunk_steps) -> (carry, records)``, e.g. a
            jitted, vmapped `rollout` with ``steps`` static.
        carry: the carry at step 0 (e.g. a batched `LoopState`); on resuming,
            the template the checkpoint's carry must match (structure, shapes,
            dtypes).
        total_steps: steps in all, a multiple of ``chunk_steps``.
        chunk_steps: steps per call of ``advance`` (one compiled size). A
            resumed run may use another one that divides the steps left.
        directory: where the checkpoint lives (created if missing); None: no checkpoint.
        fingerprint: what identifies the run (its configuration, hashed by the
            caller): a checkpoint of another fingerprint is refused.
        progress: optional ``progress(done_steps, total_steps)``, called at the
            start (with the steps a checkpoint had done) and after each chunk
            once its checkpoint is written.
        record_axis: the axis of every record leaf along which chunks are
            joined: 0 for `rollout` itself, 1 for a vmapped `rollout` (batch
            first).

    Returns:
        The carry after ``total_steps`` steps, and the chunks' records joined
        along ``record_axis``, as numpy arrays (PRNG keys, which numpy cannot
        hold, as JAX key arrays).

    Raises:
        UserError: bad step counts; the checkpoint has another fingerprint, a
            carry or records unlike this run's, more steps done than
            ``total_steps`` or steps left that ``chunk_steps`` does not divide;
            the checkpoint cannot be written or read; another run holds the
            directory.
    """
    chunk_steps = _count("chunk_steps", chunk_steps, 1)
    total_steps = _count("total_steps", total_steps, 1)
    record_axis = operator.index(record_axis)
    if directory is None:
        if total_steps % chunk_steps:
            raise UserError(f"total_steps ({total_steps}) must be a multiple of chunk_steps ({chunk_steps})")
        return _run(advance, carry, 0, total_steps, chunk_steps, _Chunks(record_axis), progress, None, fingerprint)

    where = Path(directory)
    try:
        where.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise UserError(f"cannot create the checkpoint directory {where}: {err.strerror or err}") from None
    path = where / CHECKPOINT
    with _locked(where):
        for temporary in where.glob(f".{CHECKPOINT}.*.tmp"):
            with contextlib.suppress(OSError):
                temporary.unlink()
        done = 0
        chunks = _Chunks(record_axis)
        if path.exists():

            def records_shape():
                shapes = jax.eval_shape(lambda c: advance(c, chunk_steps), carry)[1]
                chunks.axis = _normal_axis(record_axis, shapes)
                return shapes

            done, carry = _load(path, fingerprint, total_steps, chunk_steps, carry, records_shape, chunks)
        elif total_steps % chunk_steps:
            raise UserError(f"total_steps ({total_steps}) must be a multiple of chunk_steps ({chunk_steps})")
        return _run(advance, carry, done, total_steps, chunk_steps, chunks, progress, path, fingerprint)


def _run(advance, carry, done, total, chunk_steps, chunks, progress, path, fingerprint):
    if progress is not None:
        progress(done, total)
    while done < total:
        carry, records = advance(carry, chunk_steps)
        if chunks.treedef is None:
            chunks.axis = _normal_axis(chunks.axis, records)
        elif jax.tree.structure(records) != chunks.treedef:
            raise UserError("advance returned records of another structure than before")
        chunks.add(records)
        done += chunk_steps
        if path is not None:
            _save(path, fingerprint, done, total, chunk_steps, carry, chunks)
        if progress is not None:
            progress(done, total)
    return carry, chunks.records()
