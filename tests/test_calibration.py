"""The snake's camera-offset calibration (Eqs. 4-6 of the snake pipe-tracking paper, Fig. 5) against the camera's true motion."""

import math

import numpy as np
import pytest

from robots.snake import calibration as cal
from spikejax.errors import UserError
from spikejax.vision import pipe as pp

FIT_PERIODS, TEST_PERIODS = 4, 10


@pytest.fixture(scope="module")
def run():
    return cal.straight_run(FIT_PERIODS + TEST_PERIODS)


def _first(run, periods):
    n = periods * run.steps_per_period
    return cal.Run(run.t[:n], run.angle[:n], run.velocity[:n], run.head[:n], run.com[:n], run.steps_per_period)


def test_fitted_offset_follows_the_cameras_swing_over_ten_periods(run):
    """ACCEPTANCE #6: fitted on the first periods, tested on 10 later ones: RMSE <= 25 % of the swing, r >= 0.9."""
    swing = cal.fit(_first(run, FIT_PERIODS))
    per = run.steps_per_period
    test = slice(FIT_PERIODS * per - per // 2, (FIT_PERIODS + TEST_PERIODS) * per - per // 2)
    truth = cal.true_offset(run)[test]
    est = cal.estimate(swing, run.angle, run.velocity)[test]
    amplitude = math.sqrt(2) * np.std(truth)
    rmse = float(np.sqrt(np.mean((est - truth) ** 2)))
    r = float(np.corrcoef(est, truth)[0, 1])
    print(f"swing {amplitude:.4f} m, RMSE {rmse:.4f} m ({rmse / amplitude:.1%}), r = {r:.4f}; {swing}")
    assert 0.05 < amplitude < 0.15  # the camera swings sideways by several centimetres
    assert rmse <= 0.25 * amplitude and r >= 0.9
    # The recorded default is this fit.
    assert swing.swing_amplitude == pytest.approx(cal.SWING.swing_amplitude, rel=0.02)
    assert swing.swing_ratio == pytest.approx(cal.SWING.swing_ratio, rel=0.01)
    assert abs(swing.swing_phase - cal.SWING.swing_phase) < math.radians(2.0)
    # alpha is the paper's 90 degrees over the head joint's amplitude.
    assert swing.swing_ratio == pytest.approx(0.5 * math.pi / swing.joint_amplitude)


def test_fit_recovers_a_known_tuple():
    """A camera that moves exactly as Eqs. (4)-(6) say, beside a straight central line along +x."""
    per, omega, a = 125, 2 * math.pi / 2.5, 0.6
    t = np.arange(6 * per) * 0.02
    angle = a * np.sin(omega * t + 0.4)
    velocity = a * omega * np.cos(omega * t + 0.4)
    swing = cal.SwingFit(0.08, 0.5 * math.pi / a, 1.1, omega, a, 1, 0.0)
    lateral = cal.estimate(swing, angle, velocity)
    com = np.stack([0.1 * t, np.zeros_like(t)], axis=1)
    head = com + np.stack([np.zeros_like(t), -lateral], axis=1)  # right of +x is -y
    got = cal.fit(cal.Run(t, angle, velocity, head, com, per), window=1)
    assert got.swing_amplitude == pytest.approx(0.08, rel=1e-3)
    assert got.swing_phase == pytest.approx(1.1, abs=1e-3)
    assert got.joint_amplitude == pytest.approx(a, rel=1e-3) and got.rmse < 1e-4
    np.testing.assert_allclose(
        cal.true_offset(cal.Run(t, angle, velocity, head, com, per))[per:-per], lateral[per:-per], atol=1e-6
    )


def test_mean_filter_and_bad_input():
    x = np.arange(10.0)
    np.testing.assert_allclose(pp.causal_mean(x, 3), [0, 0.5, 1, 2, 3, 4, 5, 6, 7, 8])
    ring = np.array([9.0, 7.0, 8.0])  # the last three samples, written in a ring
    assert float(pp.mean_filter(ring, 10)) == pytest.approx(8.0)
    assert float(pp.mean_filter(ring, 2)) == pytest.approx(8.0)  # only rows 0 and 1 written so far
    short = cal.Run(*(np.zeros(10) for _ in range(3)), np.zeros((10, 2)), np.zeros((10, 2)), 125)
    with pytest.raises(UserError, match="at least 3 gait periods"):
        cal.fit(short)
    with pytest.raises(UserError, match="reference must be one of camera, com"):
        cal.true_offset(short, "head")
