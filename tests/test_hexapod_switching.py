"""Gait switching while walking (`robots.hexapod.switching`, ``spikejax reproduce gait-switching``)."""

import csv

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from robots.hexapod.cpg import run_gait
from robots.hexapod.gaits import PATTERNS, PERIOD
from robots.hexapod.switching import PAIRS, switch_raster, transient
from robots.hexapod.training import TrainParams, train
from robots.hexapod.trial import GaitTrialParams
from spikejax.neurons import DiscreteLIFParams


def _pattern(gait, n, shift=0):
    return jnp.asarray(PATTERNS[gait][(np.arange(n) + shift) % PERIOD])


def test_transient_counts_the_steps_before_the_pattern_holds_in_either_phase():
    n = 12
    assert int(transient(_pattern(1, n), 1)) == 0
    assert int(transient(_pattern(1, n, shift=1), 1)) == 0
    # Two wrong steps, then G2 in the other phase.
    raster = _pattern(1, n, shift=1).at[:2].set(jnp.asarray(PATTERNS[0][:2]))
    assert int(transient(raster, 1)) == 2
    # A pattern broken late never settled; one that matches only in its last cycle does not count.
    assert int(transient(_pattern(1, n).at[9].set(1.0), 1)) == n
    assert int(transient(jnp.zeros((n, 6)).at[n - 2 :].set(jnp.asarray(PATTERNS[1])), 1)) == n


@pytest.fixture(scope="module")
def trained():
    p = TrainParams(*(jnp.float32(v) for v in GaitTrialParams()))
    return p, jax.jit(jax.vmap(lambda k: train(p, key=k).weights))(jax.random.split(jax.random.key(4), 2))


def test_a_switch_with_a_reset_is_the_new_gait_from_rest_and_without_one_keeps_the_state(trained):
    p, weights = trained
    neuron = DiscreteLIFParams(alpha=p.alpha, v_th=p.v_th)
    one = jax.tree.map(lambda a: a[0], weights)
    for a, b in PAIRS:
        reset = switch_raster(neuron, one, a, b, 11, 20, jnp.bool_(True))
        np.testing.assert_array_equal(np.asarray(reset), np.asarray(run_gait(neuron, one, b, 20)))
    # Without the reset, the switch is the raster of one run whose input changes at step 11.
    gait_in = jnp.concatenate([jnp.zeros(11, int), jnp.full(20, 2)])
    from robots.hexapod.cpg import cpg_init, cpg_step

    def step(s, g):
        return cpg_step(neuron, one, s, jax.nn.one_hot(g, 3, dtype=jnp.float32))

    whole = jax.lax.scan(step, cpg_init(), gait_in)[1]
    np.testing.assert_array_equal(
        np.asarray(switch_raster(neuron, one, 0, 2, 11, 20, jnp.bool_(False))), np.asarray(whole[11:])
    )


def test_the_command_writes_the_table_and_the_reset_policy_is_always_right(tmp_path, capsys):
    """Over 16 seeds' converged networks: with a reset every switch is the new gait at once (a converged
    network from rest is its pattern from the first step); carrying the state over is not seamless for all.
    """
    from robots.hexapod.reproduce_switching import HEADER, run

    assert run(out=tmp_path, trials=16, no_progress=True) == 0
    with open(tmp_path / "gait_switching.csv") as f:
        rows = list(csv.reader(f))
    assert rows[0] == HEADER and len(rows) == 1 + 2 * len(PAIRS) * PERIOD
    for row in rows[1:]:
        n, k, frac = int(row[4]), int(row[5]), float(row[6])
        assert 0 <= k <= n and abs(frac - k / n) < 1e-4 and float(row[7]) <= frac <= float(row[8])
        assert n >= 12
        if row[3] == "reset":
            assert k == n and float(row[9]) == 0.0 and int(row[10]) == 0
    carried = [float(r[6]) for r in rows[1:] if r[3] == "carry"]
    assert min(carried) < 1.0
    assert (tmp_path / "gait_switching.png").stat().st_size > 10_000
    assert "converged networks of 16" in capsys.readouterr().out
