"""``spikejax bench hough`` on one stream: the table it writes and the frames it times."""

import csv
import subprocess
import sys

import numpy as np
import pytest
from skimage.transform import hough_line

from spikejax.commands import bench_hough
from spikejax.vision import hough


def test_bench_frames_are_the_peers_frames():
    events, images = bench_hough.frames("line", n=2)
    counts = np.asarray(events.count())
    assert np.all((counts > 1500) & (counts < bench_hough.CAPACITY))
    assert images[0].sum() == counts[0]  # one event per pixel: the peers see every event
    d = int(np.ceil(np.hypot(128, 128)))
    grid = hough.LineGrid(n_rho=2 * d + 1, origin=(0, 0), rho_offset=d)
    ours = np.asarray(hough.line_votes(grid, type(events)(*(a[0] for a in events)), signed=False))
    np.testing.assert_array_equal(ours, hough_line(images[0], grid.skimage_thetas())[0].T)


@pytest.mark.slow  # ~14 s: the bench end to end; the equality of its implementations is in tests/test_hough.py
def test_bench_writes_every_implementation(tmp_path):
    assert bench_hough.run(trials=1, out=str(tmp_path), repeats=1, cpu_devices=1, no_progress=True) == 0
    with open(tmp_path / "hough.csv") as f:
        rows = list(csv.DictReader(f))
    names = {(r["shape"], r["implementation"], r["mode"]) for r in rows}
    for shape, name, mode in [
        ("line", "skimage hough_line", "per frame"),
        ("circle", "skimage hough_circle (64 radii)", "per frame"),
        ("line", "OpenCV HoughLines", "per frame"),
        ("circle", "OpenCV HoughCircles", "per frame"),
        ("line", "NumPy per-event loop", "async"),
        ("line", "spikejax LineGrid (votes + LIF + inhibition)", "sync"),
        ("circle", "spikejax CircleGrid (votes + LIF + inhibition)", "sync"),
        ("line", "spikejax LineGrid (votes + LIF + inhibition)", "async"),
    ]:
        assert (shape, name, mode) in names
    for r in rows:
        assert np.isclose(float(r["frames_per_s"]) * float(r["run_s"]), float(r["frames"]))
        if r["implementation"].startswith("spikejax"):
            assert float(r["compile_s"]) > 0  # reported apart from the run time
        assert (r["cores"], r["parallel"]) == (
            "1",
            "1 device" if r["implementation"].startswith("spikejax") else "1 process",
        )
        assert float(r["x_peer"]) > 0
        if r["shape"] == "line" and r["mode"] != "async":  # the ratio to OpenCV's HoughLines, same cores
            opencv = next(o for o in rows if o["implementation"] == "OpenCV HoughLines")
            assert np.isclose(float(r["x_opencv"]), float(r["frames_per_s"]) / float(opencv["frames_per_s"]))
        else:
            assert r["x_opencv"] == "nan"
    sync_line = next(r for r in rows if r["mode"] == "sync" and r["shape"] == "line")
    assert int(sync_line["frames"]) == bench_hough.N_FRAMES
    assert (tmp_path / "hough.png").stat().st_size > 0


def test_modes_agree_on_sparse_slots_and_differ_on_dense_ones():
    import jax

    events, _ = bench_hough.frames("line", n=1)
    first = jax.tree.map(lambda a: a[0, :400], events)
    sparse = bench_hough.mode_difference(jax.tree.map(lambda a: a[:, None], first))
    assert sparse["async_spikes"] > 0
    assert sparse["sync_spikes"] == sparse["async_spikes"] and sparse["shared"] == 1.0
    dense = bench_hough.mode_difference(jax.tree.map(lambda a: a[None], first))
    assert dense["sync_spikes"] != dense["async_spikes"]


@pytest.mark.slow  # ~40 s: the whole bench over two devices; the split's equality is in tests/test_devices.py
def test_bench_splits_the_streams_over_two_cpu_devices(tmp_path):
    """``--cpu-devices 2``: each spikejax row from batch 2 on is run again over both devices."""
    run = subprocess.run(
        [
            sys.executable,
            "-m",
            "spikejax.cli",
            "bench",
            "hough",
            "--trials",
            "2",
            "--cpu-devices",
            "2",
            "--no-progress",
            "--out",
            str(tmp_path),
        ],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert run.returncode == 0, run.stderr[-3000:]
    assert "2 x cpu" in run.stdout
    with open(tmp_path / "hough.csv") as f:
        rows = list(csv.DictReader(f))
    split = [r for r in rows if r["implementation"].endswith(", 2 devices")]
    assert {(r["shape"], r["mode"], r["batch"]) for r in split} == {
        ("line", "sync", "2"),
        ("circle", "sync", "2"),
        ("line", "async", "2"),
    }
    for r in split:
        one = next(
            o
            for o in rows
            if o["implementation"] == r["implementation"].removesuffix(", 2 devices")
            and o["mode"] == r["mode"]
            and o["batch"] == r["batch"]
        )
        assert r["frames"] == one["frames"] and r["events"] == one["events"]
        assert (r["devices"], one["devices"]) == ("2", "1")
        assert (r["cores"], r["parallel"]) == ("2", "2 devices")
    # Every peer also on both cores, one process each: the all-cores ratios are against these.
    pooled = {r["implementation"] for r in rows if r["parallel"] == "2 processes"}
    assert pooled == {f"{name}, 2 processes" for _, name, _ in bench_hough.PEERS}


def test_a_process_row_counts_the_work_of_every_process():
    one = dict(implementation="spikejax LineGrid", batch=32, frames=256, events=569_856.0, cores=1, devices=1)
    row = bench_hough._process_row(one, 2, 64)
    assert row["implementation"] == "spikejax LineGrid, 2 processes" and row["parallel"] == "2 processes"
    assert (row["batch"], row["frames"], row["events"], row["cores"], row["devices"]) == (64, 512, 1_139_712.0, 2, 1)
