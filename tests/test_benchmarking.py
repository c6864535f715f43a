"""The benchmark harness: interleaved rounds, ratios on the same cores, atomic tables, peers in processes."""

import csv
import math
import os

import jax
import jax.numpy as jnp
import numpy as np

from spikejax import benchmarking
from spikejax.devices import shard_batch


def test_interleaved_times_every_run_once_a_round_and_keeps_the_best():
    calls = []

    def run(name, seconds):
        def once():
            calls.append(name)
            return seconds.pop(0)

        return once

    best = benchmarking.interleaved({"a": run("a", [3.0, 1.0]), "b": run("b", [2.0, 5.0])}, rounds=2)
    assert calls == ["a", "b", "a", "b"]
    assert best == {"a": 1.0, "b": 2.0}


def test_ratios_are_taken_against_the_peer_on_the_same_cores():
    rows = [
        dict(impl="peer", cores=1, rate=2.0),
        dict(impl="peer", cores=4, rate=6.0),
        dict(impl="ours", cores=1, rate=4.0),
        dict(impl="ours", cores=4, rate=30.0),
        dict(impl="ours", cores=2, rate=1.0),
    ]
    benchmarking.add_ratios(rows, "x_peer", "rate", lambda p, _: p["impl"] == "peer")
    assert [r["x_peer"] for r in rows[:4]] == [1.0, 1.0, 2.0, 5.0]
    assert math.isnan(rows[4]["x_peer"])


def test_write_csv_is_whole_and_leaves_no_temporary_file(tmp_path):
    path = benchmarking.write_csv(tmp_path / "t" / "x.csv", [dict(a=1, b="z"), dict(a=2)], ("a", "b"))
    assert list(csv.DictReader(open(path))) == [dict(a="1", b="z"), dict(a="2", b="")]
    assert os.listdir(tmp_path / "t") == ["x.csv"]


def test_compile_ahead_compiles_a_sharded_function_that_gives_the_same_result():
    fn = shard_batch(jax.vmap(lambda x: jnp.sin(x).sum()), jax.devices())
    x = jnp.arange(6.0).reshape(3, 2)
    compiled, seconds = benchmarking.compile_ahead(fn, x)
    assert seconds > 0
    run = benchmarking.JaxRun(compiled, x)
    assert run() > 0
    np.testing.assert_array_equal(run.result, fn(x))


class _Sleep:
    """A timer for `Processes`: reports its process's index."""

    def __init__(self, seconds, index=0):
        self.seconds, self.info = seconds, dict(index=index, pid=os.getpid())

    def __call__(self):
        return self.seconds * (1 + self.info["index"])


def test_processes_run_each_timer_in_its_own_process_and_report_the_slowest():
    with benchmarking.Processes(_Sleep, 0.5, processes=2, index_arg="index") as run:
        assert run() == 1.0
        info = run.info()
    assert [i["index"] for i in info] == [0, 1]
    assert len({i["pid"] for i in info} | {os.getpid()}) == 3


def _missing_peer():
    import no_such_peer_module  # noqa: F401


def test_processes_raise_the_peers_import_error():
    import pytest

    with pytest.raises(ModuleNotFoundError, match="no_such_peer_module"):
        benchmarking.Processes(_missing_peer)


def test_run_isolated_returns_the_result_of_a_fresh_process():
    assert benchmarking.run_isolated(os.getpid) != os.getpid()


def test_banner_names_the_machine():
    assert benchmarking.machine_banner(1, mujoco="3").startswith("machine: ")
    assert benchmarking.cores_label(1, "process") == "1 process"
    assert benchmarking.cores_label(2, "process") == "2 processes"
    assert benchmarking.cores_label(2, "device") == "2 devices"
