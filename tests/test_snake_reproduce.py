"""``spikejax reproduce snake-gait`` end to end at a tiny size, and its tables checked by hand."""

import csv

import numpy as np
import pytest

from robots.snake import reproduce
from spikejax import cli


@pytest.mark.slow  # ~25 s on 2 cores; its tables' arithmetic stays in the fast suite below
def test_reproduce_snake_gait_writes_its_tables_and_figures(tmp_path, monkeypatch):
    monkeypatch.setenv("SPIKEJAX_SNAKE_SCALE", "0.05")
    assert cli.main(["reproduce", "snake-gait", "--out", str(tmp_path), "--no-progress"]) == 0
    for name in (
        "snake_gait.csv",
        "snake_tracking.csv",
        "snake_trajectories.png",
        "snake_events.png",
        "snake_tracking.png",
        "snake.gif",
    ):
        assert (tmp_path / name).stat().st_size > 0, name
    gait = list(csv.DictReader(open(tmp_path / "snake_gait.csv")))
    assert [float(r["C_o_rad"]) for r in gait] == list(reproduce.STEERS) + [0.0]
    straight = next(r for r in gait if float(r["C_o_rad"]) == 0.0 and r["compensation"] == "1")
    assert float(straight["forward_speed_m_s"]) > 0.05
    tracking = list(csv.DictReader(open(tmp_path / "snake_tracking.csv")))
    assert [r["track"] for r in tracking] == [
        "eight",
        "eight-mirror",
        "ladder",
        "ladder-mirror",
        "zigzag",
        "zigzag-mirror",
    ]


def test_gait_rows_by_hand():
    # A body moving along +x at 0.1 m/s while its heading turns at 2 deg/s and swings +-10 deg.
    period = float(reproduce.gait_period(reproduce.gait_params()))
    t = np.arange(1, 4 * int(round(period / 0.02)) + 1) * 0.02
    com = np.stack([0.1 * t, 0 * t, 0 * t], axis=1)[None]
    yaw = (np.radians(2.0) * t + np.radians(10.0) * np.sin(2 * np.pi * t / period))[None]
    (row,) = reproduce.gait_rows([(0.1, True)], t, com, yaw)
    assert row[2] == pytest.approx(0.1, rel=1e-3)
    assert row[3] == pytest.approx(2.0, rel=1e-2)
    assert row[4] == pytest.approx(10.0, rel=5e-2)  # the fitted trend takes a little of the swing


def test_track_rows_stop_at_the_first_loss():
    time = np.arange(1, 11) * 0.5
    done = np.zeros(10)
    done[[4, 7]] = 1
    a = np.radians(np.arange(10.0))
    results = {"x": dict(time=time, a_head=a, a_body=-a, distance=np.ones(10), done=done)}
    (row,) = reproduce.track_rows(results)
    assert row[2] == pytest.approx(2.0) and row[3] == pytest.approx(2.0)  # mean of 0..4 degrees
    assert row[4] == pytest.approx(2.5)
