"""The closed loop (`spikejax.rollout`) on a toy env whose failures and completions are hand-computable.

The toy: a point on a line, driven by the controller at a constant speed
``v`` (plus ``noise`` times a normal draw), fails when ``|x| > LIMIT`` and
completes its episode after ``N`` steps. From rest, ``x = k v`` after ``k``
steps, so with ``LIMIT = 2.5`` and ``N = 5``:

* ``v = 1``: fails at the 3rd step of each episode (x = 3), never completes;
* ``v = 0.5``: completes at the 5th step (x = 2.5 is not beyond the limit);
* ``v = 0``: completes every 5 steps;
* ``v = 0.75``: fails at the 4th step (x = 3).

The controller learns ``w += |x|`` (kept across resets) and integrates
``i += x`` (forgotten at a reset). The reset mirrors the track after a
completion, so ``info["mirror"]`` is the parity of the completions.
"""

from __future__ import annotations

import functools
import os
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from brax.envs.base import State

from spikejax import rollout as ro
from spikejax.errors import UserError

LIMIT = 2.5
N = 5


class ToyParams(NamedTuple):
    v: jax.Array
    noise: jax.Array


class ToyBrain(NamedTuple):
    w: jax.Array  # learned: survives resets
    integral: jax.Array  # forgotten at a reset


def env_reset(key, mirror=False):
    zero = jnp.zeros((), jnp.float32)
    info = {
        "t": jnp.zeros((), jnp.int32),
        "completed": jnp.zeros((), bool),
        "mirror": jnp.asarray(mirror, bool),
        "rng": key,
        "draw": jax.random.uniform(key),
    }
    return State(pipeline_state=zero, obs=jnp.zeros((1,), jnp.float32), reward=zero, done=zero, metrics={}, info=info)


def env_step(state, action):
    x = state.pipeline_state + action
    t = state.info["t"] + 1
    info = dict(state.info, t=t, completed=t >= N)
    return state.replace(
        pipeline_state=x,
        obs=x[None],
        reward=-jnp.abs(x),
        done=(jnp.abs(x) > LIMIT).astype(jnp.float32),
        info=info,
    )


def reset(state, failed, completed, *, key):
    return env_reset(key, state.info["mirror"] ^ completed)


def brain_step(params, brain, state, *, key):
    x = state.pipeline_state
    action = params.v + params.noise * jax.random.normal(key)
    brain = ToyBrain(w=brain.w + jnp.abs(x), integral=brain.integral + x)
    return brain, action, {"action": action}


CONTROLLER = ro.Controller(step=brain_step, on_reset=lambda params, brain: brain._replace(integral=jnp.float32(0.0)))


def start(key):
    env_key, loop_key = jax.random.split(key)
    brain = ToyBrain(jnp.float32(0.0), jnp.float32(0.0))
    return ro.loop_init(env_reset(env_key), brain, key=loop_key)


def summarize(loop, out, env):
    return {
        "x": env.pipeline_state,
        "failed": env.done > 0,
        "action": out["action"],
        "w": loop.controller.w,
        "obs": env.obs,
    }


def snapshot(loop):
    return {"w": loop.controller.w, "steps": loop.steps, "key": loop.key}


@functools.partial(jax.jit, static_argnames=("steps", "every", "summary"))
def run(params, loop, steps, every=1, summary=True):
    return ro.rollout(
        env_step,
        reset,
        CONTROLLER,
        params,
        loop,
        steps,
        summarize=summarize if summary else None,
        every=every,
        snapshot=snapshot if summary else None,
    )


@functools.partial(jax.jit, static_argnames=("steps", "every"))
def run_batch(params, loop, steps, every=1):
    return jax.vmap(lambda p, lp: run(p, lp, steps, every))(params, loop)


def toy_params(v, noise=0.0):
    v = jnp.asarray(v, jnp.float32)
    return ToyParams(v, jnp.full_like(v, noise))


def batch(n, seed=0):
    return jax.vmap(start)(jax.random.split(jax.random.key(seed), n))


def assert_trees_equal(a, b):
    leaves_a, leaves_b = jax.tree.leaves(a), jax.tree.leaves(b)
    assert jax.tree.structure(a) == jax.tree.structure(b)
    for x, y in zip(leaves_a, leaves_b):
        if jnp.issubdtype(x.dtype, jax.dtypes.prng_key):
            x, y = jax.random.key_data(x), jax.random.key_data(y)
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


# ---------------------------------------------------------------- the loop


@pytest.mark.parametrize(
    "v, period, fails",
    [(1.0, 3, True), (0.75, 4, True), (0.5, 5, False), (0.0, 5, False)],
)
def test_counts_and_learned_state_follow_the_schedule(v, period, fails):
    steps = 37
    loop, records = run(toy_params(v), start(jax.random.key(1)), steps, every=1)
    episodes, into = divmod(steps, period)
    assert int(loop.steps) == steps
    assert int(loop.failures) == (episodes if fails else 0)
    assert int(loop.completions) == (0 if fails else episodes)
    # The learned weight sums the |x| = k v it saw (k = 0 .. period - 1 in each episode), resets notwithstanding.
    w = v * (episodes * period * (period - 1) / 2 + into * (into - 1) / 2)
    assert float(loop.controller.w) == pytest.approx(w, rel=1e-6)
    # The integrator is forgotten at each reset: it holds the x of the current episode only.
    # (brain_step integrates the x it sees, before its own action: 0, v, .., (into - 1) v.)
    assert float(loop.controller.integral) == pytest.approx(v * (into - 1) * into / 2, abs=1e-6)
    assert int(loop.env.info["t"]) == into
    assert float(loop.env.pipeline_state) == pytest.approx(v * into)
    assert bool(loop.env.info["mirror"]) == (not fails and episodes % 2 == 1)
    # Per block (every = 1): a failure or a completion at every period-th step.
    ends = (np.arange(1, steps + 1) % period) == 0
    np.testing.assert_array_equal(records["failures"], ends & fails)
    np.testing.assert_array_equal(records["completions"], ends & (not fails))
    np.testing.assert_array_equal(records["last"]["failed"], ends & fails)


def test_a_failure_is_not_also_a_completion():
    # v = 0.6: x = 3.0 at the 5th step, beyond the limit as t reaches N.
    loop, records = run(toy_params(0.6), start(jax.random.key(2)), 20)
    assert int(loop.failures) == 4 and int(loop.completions) == 0
    assert not bool(loop.env.info["mirror"])


def test_reset_keys_are_fresh_each_episode():
    loop, records = run(toy_params(1.0), start(jax.random.key(3)), 9)  # 3 failures
    first = start(jax.random.key(3)).env.info["draw"]
    # The env after the 3rd reset drew its number from a reset key, not the first env's key.
    assert float(loop.env.info["draw"]) != float(first)
    loop2, _ = run(toy_params(1.0), start(jax.random.key(3)), 9)
    assert_trees_equal(loop, loop2)


def test_without_summary_records_hold_the_counts():
    loop, records = run(toy_params(1.0), start(jax.random.key(4)), 12, every=4, summary=False)
    assert records["mean"] == {} and records["last"] == {} and records["snapshot"] is None
    # Failures at steps 3, 6, 9, 12: blocks (1-4, 5-8, 9-12) hold 1, 1, 2.
    np.testing.assert_array_equal(records["failures"], [1, 1, 2])
    np.testing.assert_array_equal(records["completions"], [0, 0, 0])


def test_decimated_records_are_numpy_over_the_full_trace():
    params, every, steps = toy_params([1.0, 0.5, 0.75], noise=0.1), 4, 24
    loop1, full = run_batch(params, batch(3, seed=5), steps, every=1)
    loop4, dec = run_batch(params, batch(3, seed=5), steps, every=every)
    assert_trees_equal(loop1, loop4)
    for name, trace in full["last"].items():
        trace = np.asarray(trace)
        blocks = trace.reshape(3, steps // every, every, *trace.shape[2:])
        np.testing.assert_array_equal(dec["last"][name], blocks[:, :, -1])
        np.testing.assert_allclose(dec["mean"][name], blocks.mean(axis=2, dtype=np.float64), rtol=2e-6, atol=1e-7)
    assert dec["mean"]["obs"].shape == (3, steps // every, 1)
    for name in ("failures", "completions"):
        trace = np.asarray(full[name]).reshape(3, steps // every, every)
        np.testing.assert_array_equal(dec[name], trace.sum(axis=2))
    # Snapshots are taken at each block's end.
    np.testing.assert_array_equal(dec["snapshot"]["steps"], np.tile(np.arange(every, steps + 1, every), (3, 1)))
    np.testing.assert_array_equal(dec["snapshot"]["w"], np.asarray(full["snapshot"]["w"])[:, every - 1 :: every])


def test_members_are_independent_of_the_batch():
    params = toy_params(np.linspace(0.0, 1.2, 8), noise=0.3)
    loops = batch(8, seed=6)
    together = run_batch(params, loops, 30, every=5)
    for i in range(8):
        alone = run(jax.tree.map(lambda a: a[i], params), jax.tree.map(lambda a: a[i], loops), 30, every=5)
        assert_trees_equal(jax.tree.map(lambda a: a[i], together), alone)
    three = run_batch(jax.tree.map(lambda a: a[2:5], params), jax.tree.map(lambda a: a[2:5], loops), 30, every=5)
    assert_trees_equal(jax.tree.map(lambda a: a[2:5], together), three)


def test_bad_arguments_are_user_errors():
    loop = start(jax.random.key(0))
    with pytest.raises(UserError, match="multiple of every"):
        ro.rollout(env_step, reset, CONTROLLER, toy_params(1.0), loop, 10, every=3)
    with pytest.raises(UserError, match="steps must be at least 1"):
        ro.rollout(env_step, reset, CONTROLLER, toy_params(1.0), loop, 0)
    with pytest.raises(UserError, match="every must be an integer"):
        ro.rollout(env_step, reset, CONTROLLER, toy_params(1.0), loop, 10, every=2.0)

    def bad_reset(state, failed, completed, *, key):
        return state.replace(done=jnp.zeros((), jnp.int32))

    with pytest.raises(UserError, match=r"reset returned .*done.* as int32\[\]"):
        ro.rollout(env_step, bad_reset, CONTROLLER, toy_params(1.0), loop, 2)
    with pytest.raises(UserError, match="summarize must return a dict"):
        ro.rollout(env_step, reset, CONTROLLER, toy_params(1.0), loop, 2, summarize=lambda lp, o, e: e.obs)


# ---------------------------------------------------------------- chunks and checkpoints

TOTAL, CHUNK, EVERY = 24, 6, 2


def _advance(carry, steps):
    params, loop = carry
    loop, records = run_batch(params, loop, steps, every=EVERY)
    return (params, loop), records


def _carry(raw_keys=False):
    params = toy_params([1.0, 0.5, 0.75, 0.2], noise=0.2)
    loops = batch(4, seed=7)
    if raw_keys:
        info = dict(loops.env.info, rng=jax.random.key_data(loops.env.info["rng"]))
        loops = loops._replace(key=jax.random.key_data(loops.key), env=loops.env.replace(info=info))
    return params, loops


def _uninterrupted(raw_keys=False):
    params, loops = _carry(raw_keys)
    loop, records = run_batch(params, loops, TOTAL, every=EVERY)
    return (params, loop), records


def test_chunked_equals_unchunked():
    expected = _uninterrupted()
    seen = []
    got = ro.run_chunked(_advance, _carry(), TOTAL, CHUNK, record_axis=1, progress=lambda d, t: seen.append((d, t)))
    assert_trees_equal(got, expected)
    assert seen == [(0, TOTAL), (6, TOTAL), (12, TOTAL), (18, TOTAL), (24, TOTAL)]
    assert got[1]["failures"].shape == (4, TOTAL // EVERY)
    assert isinstance(got[1]["mean"]["x"], np.ndarray) and got[1]["snapshot"]["key"].dtype == jax.random.key(0).dtype


class Killed(Exception):
    pass


@pytest.mark.parametrize("raw_keys", [False, True], ids=["typed-keys", "raw-keys"])
@pytest.mark.parametrize("where", ["progress", "advance"])
def test_killed_then_resumed_equals_uninterrupted(tmp_path, where, raw_keys):
    expected = _uninterrupted(raw_keys)
    calls = []

    def advance(carry, steps):
        if not isinstance(carry[1].steps, jax.core.Tracer):
            calls.append(steps)
            if where == "advance" and len(calls) == 3:
                raise Killed
        return _advance(carry, steps)

    def progress(done, total):
        if where == "progress" and done == 2 * CHUNK:
            raise Killed

    with pytest.raises(Killed):
        ro.run_chunked(advance, _carry(raw_keys), TOTAL, CHUNK, directory=tmp_path, progress=progress, record_axis=1)
    assert (tmp_path / ro.CHECKPOINT).exists()
    calls.clear()
    seen = []
    got = ro.run_chunked(
        advance, _carry(raw_keys), TOTAL, CHUNK, directory=tmp_path, progress=lambda d, t: seen.append(d), record_axis=1
    )
    assert seen == [12, 18, 24] and len(calls) == 2
    assert_trees_equal(got, expected)
    # Finished: run again, the results come from the checkpoint without computing.
    calls.clear()
    again = ro.run_chunked(advance, _carry(raw_keys), TOTAL, CHUNK, directory=tmp_path, record_axis=1)
    assert calls == []
    assert_trees_equal(again, expected)


def test_resume_with_another_chunk_size_and_a_longer_run(tmp_path):
    ro.run_chunked(_advance, _carry(), 12, CHUNK, directory=tmp_path, record_axis=1)
    got = ro.run_chunked(_advance, _carry(), TOTAL, 4, directory=tmp_path, record_axis=1)
    assert_trees_equal(got, _uninterrupted())
    with pytest.raises(UserError, match="the 4 steps left in .* must be a multiple of chunk_steps"):
        ro.run_chunked(_advance, _carry(), 28, 3, directory=tmp_path, record_axis=1)
    with pytest.raises(UserError, match="more than total_steps"):
        ro.run_chunked(_advance, _carry(), 12, CHUNK, directory=tmp_path, record_axis=1)


def test_fingerprint_mismatch_is_refused(tmp_path):
    ro.run_chunked(_advance, _carry(), CHUNK, CHUNK, directory=tmp_path, fingerprint="abc", record_axis=1)
    with pytest.raises(UserError) as err:
        ro.run_chunked(_advance, _carry(), TOTAL, CHUNK, directory=tmp_path, fingerprint="xyz", record_axis=1)
    message = str(err.value)
    assert str(tmp_path) in message and "'abc' there" in message and "'xyz' here" in message


def test_another_carry_is_refused(tmp_path):
    ro.run_chunked(_advance, _carry(), CHUNK, CHUNK, directory=tmp_path, record_axis=1)
    params, loops = _carry()
    smaller = (jax.tree.map(lambda a: a[:2], params), jax.tree.map(lambda a: a[:2], loops))
    with pytest.raises(UserError, match=f"{tmp_path} holds carry leaf"):
        ro.run_chunked(_advance, smaller, TOTAL, CHUNK, directory=tmp_path, record_axis=1)


def test_a_garbled_checkpoint_is_refused(tmp_path):
    (tmp_path / ro.CHECKPOINT).write_bytes(b"PK\x03\x04 not a zip")
    with pytest.raises(UserError, match="cannot read the checkpoint"):
        ro.run_chunked(_advance, _carry(), TOTAL, CHUNK, directory=tmp_path, record_axis=1)


def test_checkpoint_write_is_atomic(tmp_path, monkeypatch):
    stale = tmp_path / f".{ro.CHECKPOINT}.999.0.tmp"  # left by a run killed while writing
    stale.write_bytes(b"half a checkpoint")
    ro.run_chunked(_advance, _carry(), CHUNK, CHUNK, directory=tmp_path, record_axis=1)
    assert not stale.exists()
    before = (tmp_path / ro.CHECKPOINT).read_bytes()
    real_savez = np.savez

    def savez_then_fail(file, **arrays):
        real_savez(file, **arrays)
        file.write(b"half")
        raise Killed

    monkeypatch.setattr(np, "savez", savez_then_fail)
    with pytest.raises(Killed):
        ro.run_chunked(_advance, _carry(), TOTAL, CHUNK, directory=tmp_path, record_axis=1)
    assert (tmp_path / ro.CHECKPOINT).read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir() if p.name != ".checkpoint.lock") == [ro.CHECKPOINT]

    def fail_on_rename(src, dst):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(np, "savez", real_savez)
    monkeypatch.setattr(os, "replace", fail_on_rename)
    with pytest.raises(UserError, match="cannot write"):
        ro.run_chunked(_advance, _carry(), TOTAL, CHUNK, directory=tmp_path, record_axis=1)
    assert (tmp_path / ro.CHECKPOINT).read_bytes() == before
    assert not list(tmp_path.glob("*.tmp"))
    monkeypatch.undo()
    assert_trees_equal(
        ro.run_chunked(_advance, _carry(), TOTAL, CHUNK, directory=tmp_path, record_axis=1), _uninterrupted()
    )


def test_chunk_arguments_are_checked():
    with pytest.raises(UserError, match="multiple of chunk_steps"):
        ro.run_chunked(_advance, _carry(), 25, CHUNK, record_axis=1)
    with pytest.raises(UserError, match="chunk_steps must be at least 1"):
        ro.run_chunked(_advance, _carry(), TOTAL, 0)
    with pytest.raises(UserError, match="record_axis 3 is not an axis"):
        ro.run_chunked(_advance, _carry(), TOTAL, CHUNK, record_axis=3)
