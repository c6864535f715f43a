"""``spikejax bench snake-pipe``: its inputs and, slowly, one small run's table beside the paper's Table 1."""

import csv

import pytest

from robots.snake import bench_pipe
from spikejax.errors import UserError


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        (dict(cases="line-sync,hexagon"), "--cases"),
        (dict(batches="1,x"), "--batches"),
        (dict(batches="0"), "--batches"),
    ],
)
def test_bad_flags_are_one_line_errors(kwargs, match):
    with pytest.raises(UserError, match=match):
        bench_pipe.measure(**{"slots": 2, "repeats": 1, "no_progress": True, **kwargs})


def test_the_paper_figures_beside_ours_are_table_1s_best_per_pipe():
    assert bench_pipe.TABLE_1["standing"]["NRP"] == (1.63, 40.74)
    assert bench_pipe.TABLE_1["lying"]["V-REP"] == (0.33, 3.22)
    assert {bench_pipe.PIPE_OF_CASE[c] for c in bench_pipe.CASES} == {"standing", "lying"}


@pytest.mark.slow  # 20-60 s on 2 cores: one loop compiled twice (one device, all devices)
def test_a_small_run_writes_the_table_and_the_figure(tmp_path):
    out = tmp_path / "out"
    assert bench_pipe.run(out=str(out), batches="2", cases="line-sync", slots=2, repeats=1, no_progress=True) == 0
    with open(out / "snake_pipe_bench.csv") as f:
        rows = list(csv.DictReader(f))
    assert rows and list(rows[0]) == list(bench_pipe.ROW_FIELDS)
    for r in rows:
        rate = float(r["env_steps_per_s"])
        assert int(r["control_steps"]) == 10 and rate > 0
        assert float(r["vs_paper_cpu"]) == pytest.approx(rate / 1.63, rel=1e-6)
        assert float(r["vs_paper_gpu"]) == pytest.approx(rate / 40.74, rel=1e-6)
    assert (out / "snake_pipe_bench.png").stat().st_size > 0
