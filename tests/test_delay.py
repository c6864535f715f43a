"""Transmission delays (`spikejax.synapses.DelayLine`) and parrots: closed form and NEST 3.10 live."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from spikejax.errors import UserError
from spikejax.neurons import parrot_step
from spikejax.synapses import delay_init, delay_read, delay_step, delay_steps_of

DT = 0.1  # ms


def _run_line(line, xs):
    def body(line, x):
        due = delay_read(line)
        line, out = delay_step(line, x)
        return line, (due, out)

    return jax.lax.scan(body, line, xs)


@pytest.mark.parametrize("d", [1, 2, 7])
def test_delay_line_closed_form(d):
    steps, n = 40, 3
    xs = jnp.asarray(np.random.default_rng(d).integers(0, 5, (steps, n)), jnp.float32)
    line, (due, out) = jax.jit(_run_line)(delay_init(n, d), xs)
    expected = np.concatenate([np.zeros((d, n)), np.asarray(xs)[:-d]])  # out_k = x_{k-d}, 0 for k < d
    np.testing.assert_array_equal(np.asarray(out), expected)
    np.testing.assert_array_equal(np.asarray(due), expected)  # read before the push: the same values
    # The line holds the last d pushes, the oldest at head.
    np.testing.assert_array_equal(np.roll(np.asarray(line.buffer), -int(line.head), axis=0), np.asarray(xs)[-d:])


def test_delay_line_keeps_dtype_and_vmaps():
    xs = jnp.arange(2 * 10 * 4, dtype=jnp.int32).reshape(2, 10, 4)
    lines = jax.vmap(lambda _: delay_init(4, 3, jnp.int32))(jnp.arange(2))
    _, (_, out) = jax.vmap(_run_line)(lines, xs)
    assert out.dtype == jnp.int32 and out.shape == (2, 10, 4)
    np.testing.assert_array_equal(np.asarray(out[:, 3:]), np.asarray(xs[:, :-3]))
    np.testing.assert_array_equal(np.asarray(out[:, :3]), 0)


def test_delay_steps_rounds_like_nest_and_rejects_bad_values():
    assert delay_steps_of(1.0, 0.1) == 10
    assert delay_steps_of(0.5, 0.1) == 5
    assert delay_steps_of(0.14, 0.1) == 1
    with pytest.raises(UserError):
        delay_steps_of(0.04, 0.1)
    with pytest.raises(UserError):
        delay_init(3, 0)
    with pytest.raises(UserError):
        delay_init(3, 1.5)
    with pytest.raises(UserError):
        delay_init(-1, 2)


def test_parrot_repeats_counts():
    counts = jnp.array([0, 3, 1], jnp.int32)
    np.testing.assert_array_equal(np.asarray(parrot_step(counts)), [0, 3, 1])
    assert parrot_step(counts).dtype == jnp.int32


# Generators' spikes: (generator, time in ms, multiplicity). Generator 0 and 1 both feed
# parrot 0, so their spikes at 1.0 and 2.5 ms arrive together and add up; parrot 3 gets
# parrot 2's and parrot 1's spikes at 5.0 ms in the same step.
SPIKES = [
    (0, 1.0, 1),
    (0, 1.0, 2),
    (0, 2.0, 1),
    (0, 2.5, 3),
    (1, 1.0, 1),
    (1, 2.5, 2),
    (1, 4.2, 1),
    (2, 0.1, 2),
    (2, 4.0, 1),
]
# (source, target, delay ms, weight): g = generator, p = parrot. Parrots ignore the weight.
CONNECTIONS = [
    ("g0", "p0", 1.0, 1.0),
    ("g1", "p0", 1.0, 2.5),
    ("g2", "p1", 0.5, -3.0),
    ("p0", "p2", 0.5, 1.0),
    ("p2", "p3", 1.0, 1.0),
    ("p1", "p3", 0.5, 1.0),
]
N_GEN, N_PARROT, T_SIM = 3, 4, 10.0


def _ours():
    """The chain with one DelayLine per (delay, source population), parrots updated in order."""
    steps = int(round(T_SIM / DT))
    gen = np.zeros((steps, N_GEN), np.int32)
    for g, t, m in SPIKES:
        gen[int(round(t / DT)) - 1, g] += m  # a spike stamped t leaves in step t / DT - 1
    delays = sorted({delay_steps_of(d, DT) for *_, d, _ in CONNECTIONS})
    # to[src_kind][D][src_index, target_parrot] = 1 where a connection of D steps exists
    conn = {k: {d: np.zeros((N_GEN if k == "g" else N_PARROT, N_PARROT), np.int32) for d in delays} for k in "gp"}
    for src, tgt, d, _ in CONNECTIONS:
        conn[src[0]][delay_steps_of(d, DT)][int(src[1:]), int(tgt[1:])] = 1

    def body(lines, g):
        arriving = sum(
            delay_read(lines["g", d]) @ conn["g"][d] + delay_read(lines["p", d]) @ conn["p"][d] for d in delays
        )
        parrots = parrot_step(arriving)
        new = {}
        for d in delays:
            new["g", d], _ = delay_step(lines["g", d], g)
            new["p", d], _ = delay_step(lines["p", d], parrots)
        return new, parrots

    lines = {(k, d): delay_init(N_GEN if k == "g" else N_PARROT, d, jnp.int32) for k in "gp" for d in delays}
    _, out = jax.lax.scan(body, lines, jnp.asarray(gen))
    out = np.asarray(out)
    return [
        sorted((round((k + 1) * DT, 6), int(out[k, j])) for k in np.flatnonzero(out[:, j])) for j in range(N_PARROT)
    ]


def test_parrot_chain_with_delays_matches_nest():
    nest = pytest.importorskip("nest")
    nest.ResetKernel()
    nest.verbosity = nest.VerbosityLevel.ERROR
    nest.resolution = DT
    gens = nest.Create("spike_generator", N_GEN)
    for g in range(N_GEN):
        mine = [(t, m) for i, t, m in SPIKES if i == g]
        gens[g].set(spike_times=[t for t, _ in mine], spike_multiplicities=[m for _, m in mine])
    parrots = nest.Create("parrot_neuron", N_PARROT)
    nodes = {"g": gens, "p": parrots}
    for src, tgt, d, w in CONNECTIONS:
        nest.Connect(nodes[src[0]][int(src[1:])], nodes[tgt[0]][int(tgt[1:])], syn_spec={"delay": d, "weight": w})
    rec = nest.Create("spike_recorder")
    nest.Connect(parrots, rec)
    nest.Simulate(T_SIM)
    ev = rec.get("events")
    theirs = []
    for j in range(N_PARROT):
        times, counts = np.unique(np.round(ev["times"][ev["senders"] == parrots[j].global_id], 6), return_counts=True)
        theirs.append(sorted(zip(times.tolist(), counts.tolist(), strict=True)))

    # Hand-computed from NEST's rule: a parrot's spike is stamped t + d, multiplicities add up.
    assert theirs[0] == [(2.0, 4), (3.0, 1), (3.5, 5), (5.2, 1)]
    assert theirs[1] == [(0.6, 2), (4.5, 1)]
    assert theirs[2] == [(2.5, 4), (3.5, 1), (4.0, 5), (5.7, 1)]
    assert theirs[3] == [(1.1, 2), (3.5, 4), (4.5, 1), (5.0, 6), (6.7, 1)]
    assert _ours() == theirs
