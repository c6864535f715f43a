"""The snake R-STDP metrics: running means with resets and per-seed figures, hand-computed."""

import math

import numpy as np
import pytest

from robots.snake import metrics


def test_running_mean_restarts_after_a_reset():
    x = np.array([1.0, 3.0, 5.0, 7.0, 2.0, 4.0])
    resets = np.array([0, 0, 0, 1, 0, 0], bool)  # step 3 ends an episode
    got = metrics.running_mean(x, 2, resets)
    np.testing.assert_allclose(got, [1.0, 2.0, 4.0, 6.0, 2.0, 3.0])
    np.testing.assert_allclose(metrics.running_mean(x, 10), np.cumsum(x) / np.arange(1, 7))


def test_seed_metrics_by_hand():
    dt = 0.5
    a_head = np.radians([2.0, -2.0, 4.0, 4.0, 10.0, 10.0])
    d_body = np.array([0.0, 0.5, 1.0, 1.0, 0.0, -1.0])
    failed = np.array([0, 1, 0, 0, 0, 0], bool)
    completed = np.array([0, 0, 0, 0, 1, 0], bool)  # the pass ends at step 4: step 5 is not counted
    m = metrics.seed_metrics(a_head, d_body, failed, completed, dt=dt, window=2)
    ma = [2.0, 0.0, 4.0, 4.0, 7.0]  # the window restarts after the failure at step 1
    assert m["mean_head_angle_deg"] == pytest.approx(np.mean(ma))
    assert m["instant_head_angle_deg"] == pytest.approx(np.mean([2, 2, 4, 4, 10]))
    assert m["failures_per_min"] == pytest.approx(1 / (5 * dt / 60))
    assert m["steering_changes_per_100s"] == pytest.approx((0.5 + 0.5 + 0 + 1.0) / (5 * dt) * 100)
    assert m["time_at_limit"] == pytest.approx(2 / 5)
    assert m["first_failure_s"] == pytest.approx(2 * dt)
    assert m["completed"] is True
    none = metrics.seed_metrics(a_head, d_body, np.zeros(6, bool), np.zeros(6, bool), dt=dt, window=1)
    assert math.isnan(none["first_failure_s"]) and none["completed"] is False and none["failures_per_min"] == 0
