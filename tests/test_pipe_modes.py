"""The sync-against-async comparison of the pipe loop: its configurations, its inputs, its table."""

import csv

import jax
import numpy as np
import pytest

from robots.snake import reproduce_pipe_modes as pipe_modes
from spikejax.errors import UserError


def test_modes_differ_in_the_update_rule_alone():
    sync, asyn = pipe_modes.env_for("sync"), pipe_modes.env_for("async")
    assert (sync.tracker.detector.mode, sync.dvs) == ("sync", "contrast")
    assert (asyn.tracker.detector.mode, asyn.dvs) == ("async", "contrast")
    # Everything else is the same: the grids, the slot, Alg. 3's parameters, the DVS's.
    assert sync.tracker.detector.line == asyn.tracker.detector.line
    assert sync.tracker.window == asyn.tracker.window and sync.slot_steps == asyn.slot_steps
    for a, b in zip(jax.tree.leaves(sync.tracker_params), jax.tree.leaves(asyn.tracker_params), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        (dict(episodes=0), "episodes"),
        (dict(seconds=0.0), "seconds"),
        (dict(situation="floating"), "situation"),
        (dict(modes=("sync", "later")), "modes"),
    ],
)
def test_bad_arguments_are_one_line_errors(tmp_path, kwargs, match):
    with pytest.raises(UserError, match=match):
        pipe_modes.compare_modes(tmp_path, **{"episodes": 2, "seconds": 1.0, "progress": False, **kwargs})


@pytest.mark.slow  # 60-150 s on 2 cores: two loops compiled, the asynchronous one with its event loop
def test_the_same_episodes_in_both_modes_make_a_paired_table(tmp_path):
    from spikejax.stats import wilson_interval

    rows = pipe_modes.compare_modes(tmp_path, episodes=2, seconds=0.5, modes=("sync", "async"), progress=False)
    with open(tmp_path / "snake_pipe_modes.csv") as f:
        table = list(csv.reader(f))
    assert table[0] == pipe_modes.MODE_HEADER and [r[0] for r in table[1:]] == ["sync", "async"]
    row = {m: dict(zip(pipe_modes.MODE_HEADER, r)) for m, r in zip(("sync", "async"), rows)}
    low, high = wilson_interval(row["async"]["successes"], 2)
    assert row["async"]["wilson_low"] == pytest.approx(float(low)) and row["async"]["wilson_high"] == pytest.approx(
        float(high)
    )
    assert row["sync"]["vs_sync_distance_error_diff_m"] == ""  # sync is the reference
    assert row["async"]["vs_sync_paired_episodes_distance"] >= 1
    assert row["sync"]["env_steps_per_s"] > 0 and row["async"]["env_steps_per_s"] > 0
    assert (tmp_path / "snake_pipe_modes.png").stat().st_size > 0
