"""The RoboBee flight summary on hand-made recordings, and `spikejax reproduce robobee` end to end."""

import csv
import subprocess
import sys

import jax.numpy as jnp
import numpy as np
import pytest

from robots.robobee.flight import Recording, flight_plan
from robots.robobee.trial import summarize


def _recording(dist_1, dist_2, theta_max=0.3):
    # 2 hold samples, then two segments of 4 samples; record_every 10 steps of 0.1 ms.
    n = 10
    t = (jnp.arange(n) + 1) * 1e-3
    plan = flight_plan("waypoints")
    target = jnp.concatenate(
        [jnp.tile(plan.q0, (2, 1)), jnp.tile(plan.waypoints[0], (4, 1)), jnp.tile(plan.waypoints[1], (4, 1))]
    )
    q = target.at[2:6, 2].add(jnp.asarray(dist_1)).at[6:, 2].add(jnp.asarray(dist_2))
    q = q.at[4, 0].set(theta_max)
    y_lqr = jnp.zeros(n)
    y_hat = jnp.where(jnp.arange(n) >= 2, 0.5, 7.0)  # the hold's samples do not count
    return Recording(t=t, q=q, target=target, y_hat=y_hat, y_lqr=y_lqr, w_ih_mean=y_lqr, w_ho_mean=y_lqr), plan


def test_summary_hand_computed():
    rec, plan = _recording([0.02, 0.01, 0.004, 0.001], [0.006, 0.003, 0.0, 0.0])
    r = summarize(rec, plan, hold_steps=20, segment_steps=40, record_every=10)
    assert float(r.rms_error) == pytest.approx(0.5, rel=1e-4, abs=1e-7)
    assert float(r.error_1) == pytest.approx(0.001, rel=1e-4, abs=1e-7) and float(r.error_2) == pytest.approx(
        0.0, rel=1e-4, abs=1e-7
    )
    # Below 5 mm from the 3rd sample of segment 1 and the 2nd of segment 2 on.
    assert float(r.settle_1) == pytest.approx(2e-3, rel=1e-4, abs=1e-7) and float(r.settle_2) == pytest.approx(
        1e-3, rel=1e-4, abs=1e-7
    )
    assert bool(r.reached) and bool(r.upright)
    assert float(r.max_theta) == pytest.approx(0.6, rel=1e-4, abs=1e-7)  # q0 tilts by -0.6 rad


def test_summary_failures():
    rec, plan = _recording([0.02, 0.01, 0.004, 0.008], [0.0, 0.0, 0.0, 0.0])
    r = summarize(rec, plan, hold_steps=20, segment_steps=40, record_every=10)
    assert float(r.settle_1) == pytest.approx(4e-3, rel=1e-4, abs=1e-7)  # never settled: the segment's length
    assert not bool(r.reached)
    rec, plan = _recording([0.0] * 4, [0.0] * 4, theta_max=2.0)
    r = summarize(rec, plan, hold_steps=20, segment_steps=40, record_every=10)
    assert not bool(r.upright) and not bool(r.reached)


@pytest.mark.slow  # ~30 s: the command end to end; its summary is checked by hand in the fast suite
def test_reproduce_robobee_small(tmp_path):
    out = tmp_path / "rb"
    run = subprocess.run(
        [
            sys.executable,
            "-m",
            "spikejax.cli",
            "reproduce",
            "robobee",
            "--out",
            str(out),
            "--trials",
            "2",
            "--no-progress",
        ],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert run.returncode == 0, run.stderr
    with open(out / "robobee.csv") as f:
        rows = list(csv.DictReader(f))
    assert [(r["flight"][:8], r["controller"]) for r in rows] == [
        ("flight 1", "SNN"),
        ("flight 1", "LQR"),
        ("flight 2", "SNN"),
        ("flight 2", "LQR"),
    ]
    assert all(int(r["flights"]) == 2 for r in rows)
    # The LQR reaches both waypoints of both flights, and the learning SNN does too.
    assert all(float(r["reached"]) == 1.0 for r in rows)
    for name in ("robobee_flight1.png", "robobee_flight2.png", "robobee_seeds.png"):
        assert (out / name).stat().st_size > 10_000


def test_population_sweep_compiles_one_program_per_size():
    from robots.common import SWEEPS
    from spikejax.sweep import load_sweep

    spec = load_sweep(SWEEPS / "robobee_populations.toml")
    assert {axis.name: axis.static for axis in spec.axes} == {"n_per_input": True, "n_hidden": True}
    assert spec.n_trials == 3 * 4 * 64


def test_success_map_counts_and_intervals(tmp_path):
    from robots.robobee.reproduce import _success_map
    from spikejax.stats import wilson_interval

    table = {
        "n_per_input": np.array([10, 10, 10, 50, 50, 50, 10, 50]),
        "n_hidden": np.array([25, 25, 25, 25, 25, 25, 100, 100]),
        "reached": np.array([1, 0, 0, 1, 1, 1, 0, 1], bool),
        "rms_error": np.array([0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8]),
    }
    rows = _success_map(tmp_path, "map", table, "n_per_input", "n_hidden", ("a", "b"), "t")
    assert [r[:5] for r in rows] == [
        [10, 25, 3, 1, 0.3333],
        [10, 100, 1, 0, 0.0],
        [50, 25, 3, 3, 1.0],
        [50, 100, 1, 1, 1.0],
    ]
    assert rows[0][5] == round(float(wilson_interval(1, 3)[0]), 4) and rows[0][7] == 0.2
    with open(tmp_path / "map.csv") as file:
        assert len(list(csv.reader(file))) == 5
    assert (tmp_path / "map.png").stat().st_size > 0
