"""Summary statistics for sweep tables."""

from __future__ import annotations

import numpy as np

from spikejax.errors import UserError

__all__ = ["mean_interval", "wilson_interval"]


def wilson_interval(successes, trials, z: float = 1.959963984540054) -> tuple[np.ndarray, np.ndarray]:
    """Wilson score interval for a binomial proportion (95 % by default).

    Unlike the normal approximation it stays inside [0, 1] and keeps its width
    when the proportion is 0 or 1, as convergence fractions often are.

    Args:
        successes: number of successes, scalar or array.
        trials: number of trials (> 0), same shape.
        z: the normal quantile; 1.96 for a 95 % interval.

    Returns:
        ``(low, high)`` arrays of the interval's bounds.

    References:
        E. B. Wilson (1927), Probable inference, the law of succession, and
        statistical inference. J. Am. Stat. Assoc. 22(158), 209-212.
    """
    k = np.asarray(successes, dtype=np.float64)
    n = np.asarray(trials, dtype=np.float64)
    if np.any(n <= 0) or np.any(k < 0) or np.any(k > n):
        raise UserError("need 0 <= successes <= trials and trials > 0")
    p = k / n
    denom = 1.0 + z**2 / n
    centre = (p + z**2 / (2 * n)) / denom
    half = z * np.sqrt(p * (1 - p) / n + z**2 / (4 * n**2)) / denom
    return np.clip(centre - half, 0.0, 1.0), np.clip(centre + half, 0.0, 1.0)


def mean_interval(values, level: float = 0.95) -> tuple[float, float, float]:
    """The mean of ``values`` and its Student-t confidence interval (95 % by default).

    Over seeds, which are independent draws, this is the interval a reader
    expects beside a mean; one value gives an interval of NaNs rather than a
    misleading zero width.

    Args:
        values: a 1-D sample, finite.
        level: the interval's coverage in (0, 1).

    Returns:
        ``(mean, low, high)`` as floats.
    """
    from scipy.stats import t

    x = np.asarray(values, dtype=np.float64).reshape(-1)
    if x.size == 0 or not np.all(np.isfinite(x)):
        raise UserError("mean_interval needs at least one value, all finite")
    if not 0 < level < 1:
        raise UserError(f"level must be in (0, 1), got {level}")
    mean = float(x.mean())
    if x.size == 1:
        return mean, float("nan"), float("nan")
    half = float(t.ppf(0.5 + level / 2, x.size - 1) * x.std(ddof=1) / np.sqrt(x.size))
    return mean, mean - half, mean + half
