"""`spikejax bench hexapod-prey`'s parts: the peers do the work the loop does, and the rows' arithmetic."""

import math

import jax
import numpy as np
import pytest

from robots.hexapod import bench_prey as bp
from robots.hexapod import decisions


def test_the_numpy_peer_gets_the_recorded_decisions_events():
    xs, ys, ts = bp.decision_events()
    track, scene, key = bp.recorded_decision()
    d = jax.jit(decisions.decide)(track, scene, key)
    assert xs.size == int(d.events) > 1000
    # One frame interval's events carry its time: 16 frames 20 ms apart after the standing one.
    assert set(np.round(np.unique(ts) / decisions.FRAME_S).astype(int)) <= set(range(1, decisions.N_FRAMES))
    assert xs.max() < 256 and ys.max() < 160


def test_c_physics_walks_the_pool_and_its_row_counts_decisions():
    run = bp.CPhysicsRun(3, 2, nthread=1)
    try:
        seconds = run()
        assert seconds > 0 and np.all(np.isfinite(run.out))
        # The torso walks forward under G1: its x (qpos[0], after the time in the state) grows.
        assert np.all(run.out[:, -1, 1] > run.state[:, 1] + 0.05)
        row = run.info
    finally:
        run.close()
    assert row["decisions"] == 6 and row["decisions_per_s"] == pytest.approx(6 / row["run_s"])
    assert row["physics_steps_per_s"] == pytest.approx(160 * row["decisions_per_s"])
    assert row["sim_s_per_wall_s"] == pytest.approx(0.32 * row["decisions_per_s"]) and math.isnan(row["x_numpy"])


def test_the_snn_row_runs_the_loops_network_on_the_numpy_peers_input():
    """`SnnRun` sums each decision's winning gait and filter spikes: `decide`'s, on the same counts, every time."""
    track, scene, key = bp.recorded_decision()
    d = jax.jit(decisions.decide)(track, scene, key)
    run = bp.SnnRun(2, 3)
    assert run() > 0
    total = np.asarray(run.compiled(*run.args))
    # Each of the three decisions starts at rest one gait cycle later: the same network makes the same spikes.
    assert int(d.filter_spikes) > 0
    assert np.all(total == 3 * (int(d.gait) + int(d.filter_spikes)))
    row = run.info
    assert row["impl"] == "spikejax visual SNN only" and row["decisions"] == 6
    assert row["decisions_per_s"] == pytest.approx(6 / row["run_s"])
