import numpy as np
import pytest

from spikejax.errors import UserError
from spikejax.stats import wilson_interval


def test_wilson_hand_computed():
    # k = 8, n = 10, z = 1.96: centre (0.8 + 0.19208) / 1.38416 = 0.71675,
    # half 1.96 sqrt(0.016 + 0.0096040) / 1.38416 = 0.22658.
    low, high = wilson_interval(8, 10)
    assert low == pytest.approx(0.49016, abs=1e-4)
    assert high == pytest.approx(0.94334, abs=1e-4)


def test_wilson_edges_and_coverage():
    low, high = wilson_interval(0, 100)
    assert low == pytest.approx(0.0, abs=1e-12) and high == pytest.approx(3.8415 / 103.8415, abs=1e-4)
    low, high = wilson_interval(100, 100)
    assert high == pytest.approx(1.0, abs=1e-12) and low == pytest.approx(1 - 3.8415 / 103.8415, abs=1e-4)
    # Coverage of the 95 % interval for p = 0.2, n = 100 is close to 95 %.
    rng = np.random.default_rng(0)
    k = rng.binomial(100, 0.2, size=20000)
    low, high = wilson_interval(k, np.full_like(k, 100))
    assert 0.93 < np.mean((low <= 0.2) & (0.2 <= high)) < 0.97


def test_wilson_rejects_bad_counts():
    with pytest.raises(UserError):
        wilson_interval(5, 4)
    with pytest.raises(UserError):
        wilson_interval(0, 0)


def test_mean_interval_hand_computed_and_edges():
    from spikejax.stats import mean_interval

    # n = 4, mean 2.5, sd = sqrt(5/3); t(0.975, 3) = 3.182446305284263
    mean, low, high = mean_interval([1.0, 2.0, 3.0, 4.0])
    half = 3.182446305284263 * np.sqrt(5 / 3) / 2
    assert (mean, low, high) == pytest.approx((2.5, 2.5 - half, 2.5 + half), rel=1e-12)
    assert mean_interval([3.0, 3.0, 3.0]) == (3.0, 3.0, 3.0)
    one = mean_interval([7.0])
    assert one[0] == 7.0 and np.isnan(one[1]) and np.isnan(one[2])
    for bad in ([], [1.0, float("nan")]):
        with pytest.raises(UserError):
            mean_interval(bad)
