"""``spikejax reproduce gaits`` end to end on a small size, and the benchmark's peer agreeing with spikejax."""

import csv
import subprocess
import sys

from robots.hexapod.bench import bench_numpy, bench_spikejax
from robots.hexapod.trial import GaitTrialParams
from spikejax.stats import wilson_interval
from spikejax.sweep import read_results


def _cli(*args):
    return subprocess.run([sys.executable, "-m", "spikejax.cli", *args], capture_output=True, text=True, timeout=300)


def test_reproduce_gaits_writes_table_and_figure(tmp_path):
    out = tmp_path / "gaits"
    run = _cli("reproduce", "gaits", "--out", str(out), "--trials", "30", "--no-progress")
    assert run.returncode == 0, run.stderr
    with open(out / "gait_convergence.csv") as f:
        rows = list(csv.DictReader(f))
    assert list(rows[0]) == ["n_gaits", "trials", "converged", "fraction", "ci_low", "ci_high"]
    assert [int(r["n_gaits"]) for r in rows] == [1, 2, 3]
    table = read_results(out / "sweeps" / "gait_convergence")
    for r in rows:
        m = table["n_gaits"] == int(r["n_gaits"])
        k, n = int(table["converged"][m].sum()), int(m.sum())
        assert (int(r["trials"]), int(r["converged"])) == (n, k) == (30, k)
        low, high = wilson_interval(k, n)
        assert float(r["ci_low"]) == round(float(low), 4) and float(r["ci_high"]) == round(float(high), 4)
    assert (out / "gait_convergence.png").stat().st_size > 10_000
    with open(out / "gait_convergence_budget.csv") as f:
        budget = [r for r in csv.DictReader(f) if r["n_gaits"] == "3"]
    fractions = [float(r["fraction"]) for r in budget]
    assert fractions == sorted(fractions)  # converging within a budget is monotone in the budget
    assert budget[-1]["epochs"] == "200"  # 600 presentations for 3 gaits: the sweep's whole budget
    assert fractions[-1] == float(rows[2]["fraction"])

    # Run again: everything is on disk, nothing is recomputed, the tables are unchanged.
    before = (out / "gait_convergence.csv").read_bytes()
    again = _cli("reproduce", "gaits", "--out", str(out), "--trials", "30", "--no-progress")
    assert again.returncode == 0 and "compiling" not in again.stderr
    assert (out / "gait_convergence.csv").read_bytes() == before


def test_reproduce_bad_trials_is_refused_by_the_parser_in_one_line(tmp_path):
    # One error line naming the flag; nothing runs.
    run = _cli("reproduce", "gaits", "--out", str(tmp_path / "x"), "--trials", "0")
    assert run.returncode == 2
    assert run.stderr.splitlines() == [
        "spikejax reproduce gaits: error: argument --trials: must be at least 1, got 0 "
        "(see spikejax reproduce gaits --help)"
    ]
    assert not (tmp_path / "x").exists()


def test_benchmark_peer_computes_the_same_trials():
    params = GaitTrialParams(n_gaits=3)
    ours = bench_spikejax(6, 6, params)
    peer = bench_numpy(6, params)
    assert ours["converged"] == peer["converged"]
