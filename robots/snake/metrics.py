"""The tracking metrics of the snake R-STDP experiments, defined once (numpy, per seed).

The paper reports "the mean angle of the head" (Fig. 7-10, Sec. IV-A: it
"rarely surpasses an absolute value of 4 degrees" for the basic net, "below 2
degrees" for the separated one). With the gait's head swing the instantaneous
angle cannot stay that small, so the paper's curve is a running mean; here:

* ``mean_head_angle``: the time average of ``|MA_W(a_head)|``, the absolute
  value of the running mean of ``a_head`` over the last ``W`` control steps
  (`running_mean`; restarted at every reset, shorter windows at an episode's
  start), and ``p95_head_angle`` its 95th percentile over time;
* ``instant_head_angle``: the time average of ``|a_head|``;
* ``failures_per_min``: failure resets per minute of the run;
* ``steering_changes``: ``sum |D_body(t) - D_body(t-1)|`` per 100 s, and
  ``time_at_limit``: the share of steps with ``|D_body| = 1`` (the paper's
  "the directions ... dropped dramatically");
* ``first_failure_s``: the time of the first failure (``nan`` if none).

Every metric is measured from the start of the run to its first completed
pass of the track (the whole run if it never completes).
"""

from __future__ import annotations

import numpy as np

__all__ = ["running_mean", "seed_metrics", "METRICS", "PAPER_WINDOW"]

PAPER_WINDOW = 625  # control steps: the paper's "movement period" (Sec. III-B)
METRICS = (
    "mean_head_angle_deg",
    "p95_head_angle_deg",
    "instant_head_angle_deg",
    "failures_per_min",
    "steering_changes_per_100s",
    "time_at_limit",
    "first_failure_s",
    "completed",
)


def running_mean(x: np.ndarray, window: int, resets: np.ndarray | None = None) -> np.ndarray:
    """The mean of ``x`` over the last ``window`` steps, restarting after each step where ``resets`` is true.

    ``resets[t]`` marks the last step of an episode: the window of step
    ``t + 1`` starts afresh. Early in an episode the mean is over the steps so far.
    """
    x = np.asarray(x, float)
    n = len(x)
    if resets is None:
        resets = np.zeros(n, bool)
    episode = np.concatenate([[0], np.cumsum(np.asarray(resets, bool))[:-1]])
    start = np.zeros(n, int)
    boundaries = np.nonzero(np.diff(episode))[0] + 1
    for b in boundaries:
        start[b:] = b
    idx = np.arange(n)
    lo = np.maximum(start, idx - window + 1)
    c = np.concatenate([[0.0], np.cumsum(x)])
    return (c[idx + 1] - c[lo]) / (idx + 1 - lo)


def seed_metrics(a_head, d_body, failed, completed, *, dt: float, window: int) -> dict:
    """`METRICS` of one seed's test run from its per-step series (radians; ``failed``/``completed`` bools)."""
    a_head, d_body = np.asarray(a_head, float), np.asarray(d_body, float)
    failed, completed = np.asarray(failed, bool), np.asarray(completed, bool)
    done = np.nonzero(completed)[0]
    end = int(done[0]) + 1 if len(done) else len(a_head)
    a_head, d_body, failed = a_head[:end], d_body[:end], failed[:end]
    ma = np.degrees(np.abs(running_mean(a_head, window, failed)))
    minutes = end * dt / 60.0
    fails = np.nonzero(failed)[0]
    return {
        "mean_head_angle_deg": float(ma.mean()),
        "p95_head_angle_deg": float(np.percentile(ma, 95)),
        "instant_head_angle_deg": float(np.degrees(np.abs(a_head)).mean()),
        "failures_per_min": float(len(fails) / minutes),
        "steering_changes_per_100s": float(np.abs(np.diff(d_body, prepend=0.0)).sum() / (end * dt) * 100.0),
        "time_at_limit": float(np.mean(np.abs(d_body) >= 1.0 - 1e-6)),
        "first_failure_s": float((fails[0] + 1) * dt) if len(fails) else float("nan"),
        "completed": bool(len(done)),
    }
