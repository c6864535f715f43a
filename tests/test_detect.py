"""Pipe detection on synthetic scenes of known geometry, and the ``spikejax detect pipe`` command.

The scenes come from `spikejax.vision.scenes`; their events from the
frame-difference DVS of `spikejax.vision.dvs`. Distances are those of a
pinhole camera with a 60 degree field of view (focal length 110.85 pixels on
128 columns): a pipe of diameter ``l`` at distance ``d`` is ``f l / d`` pixels wide.
"""

import ast
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from spikejax import cli
from spikejax.commands import detect_pipe
from spikejax.vision import detect, dvs, io, scenes
from spikejax.vision import pipe as pp

FOCAL = 64.0 / math.tan(math.radians(30.0))


def _recording(frames, times, threshold=0.1):
    """Frame-difference events of a scene as a canonical structured array (t in us)."""
    events, overflow = dvs.difference_events(frames, times, threshold=threshold, capacity=4096)
    assert int(overflow.sum()) == 0
    return io.to_structured(events)


def _slot_truth(values, fps, slot, n_slots):
    """Mean of a per-frame truth over the frames whose events fall in each slot.

    Frame ``k >= 1`` makes the events stamped ``k / fps``; slots start at the first, frame 1.
    """
    k = np.arange(1, len(values))
    index = np.round((k - 1) / fps * 1e6).astype(int) // int(round(slot * 1e6))
    return np.array([values[k[index == s]].mean() for s in range(n_slots)])


@pytest.fixture(scope="module")
def standing():
    scene = scenes.standing_pipe(key=jax.random.key(0), n_frames=31, pipe_width=24.0, start=30.0, speed=1.5, noise=0.03)
    return scene, _recording(scene.frames, scene.times)


@pytest.mark.parametrize("mode", ["sync", "async"])
def test_standing_pipe_body_and_known_size_distance(standing, mode):
    scene, events = standing
    size = 0.25  # m: the 24-pixel pipe is then at f l / w = 1.155 m
    found = detect.detect(events, (128, 128), mode=mode, slot=0.05, circles=False, track=pp.track_params(size=size))
    b = found.bodies
    assert b.valid.all()
    truth_pos = _slot_truth(scene.truth.pos, 100.0, 0.05, len(b.t))
    theta_error = np.abs(np.degrees(b.theta) - 90.0)
    assert theta_error.mean() < 1.5 and theta_error.max() <= 5.0  # 5 degrees: Alg. 2's parallel tolerance
    np.testing.assert_allclose(b.width, 24.0, atol=3.0)
    # The pipe moves 7.5 pixels in a slot: the pair may come from any part of it.
    np.testing.assert_allclose(b.pos, truth_pos, atol=5.0)
    d_true = FOCAL * size / 24.0
    error = np.abs(found.body_estimates.distance - d_true)
    print(f"{mode}: distance {d_true:.3f} m, mean error {error.mean():.3f} m, max {error.max():.3f} m")
    assert error.mean() < 0.03 * d_true and error.max() < 0.08 * d_true
    # Left of the image centre the pipe is to the left: C = -1 (the camera is on the central line).
    np.testing.assert_array_equal(found.body_estimates.control, np.where(b.pos < 64.0, -1, 1))


def test_lying_pipe_entry_width_and_distance():
    scene = scenes.lying_pipe(n_frames=31, centre=(50.0, 60.0), radius=16.0, speed=1.0, growth=0.5)
    events = _recording(scene.frames, scene.times)
    size = 0.3  # m, the diameter of the opening
    found = detect.detect(events, (128, 128), slot=0.05, lines=False, track=pp.track_params(size=size))
    e = found.entries
    assert e.valid.all() and (e.kind == pp.ENTRY).all()
    n = len(e.t)
    a, r = (_slot_truth(v, 100.0, 0.05, n) for v in (scene.truth.a, scene.truth.r))
    np.testing.assert_allclose(e.pos, a, atol=4.0)
    np.testing.assert_allclose(e.row, 60.0, atol=2.0)
    np.testing.assert_allclose(e.width, 2 * r, atol=4.0)
    d_true = FOCAL * size / (2 * r)
    error = np.abs(found.entry_estimates.distance - d_true)
    print(
        f"entry: distance {d_true.min():.3f}-{d_true.max():.3f} m, mean error {error.mean():.3f} m, max {error.max():.3f} m"
    )
    # The paper finds the entry less precise than the body; so do we (ring of 1-pixel radii).
    assert error.mean() < 0.08 * d_true.mean() and (error / d_true).max() < 0.12


def test_approach_distance_from_expansion():
    """Eq. (9): a pipe of unknown size approached at a constant speed while the camera swings."""
    fps, n, v, d0, l, slot = 50.0, 201, 0.5, 3.0, 0.4, 0.1  # 4 s, from 3 m to 1 m
    t = np.arange(n) / fps
    d = d0 - v * t
    width = FOCAL * l / d
    centre = 64.0 + 18.0 * np.sin(2 * np.pi * 1.5 * t)  # sideways swing: opposite edge polarities
    frames = np.stack(
        [
            np.asarray(scenes.standing_pipe(n_frames=2, pipe_width=w, start=c, speed=0.0).frames[0])
            for w, c in zip(width, centre)
        ]
    )
    events = _recording(frames, t)
    found = detect.detect(events, (128, 128), slot=slot, circles=False, track=pp.track_params(speed=v))
    est = found.body_estimates
    known = est.distance > 0
    assert known.sum() >= 20
    # A slot's widths are measured over the whole slot: compare with the distance at its middle.
    d_slot = d0 - v * (found.bodies.t[known] - 0.5 * slot)
    error = np.abs(est.distance[known] - d_slot)
    print(
        f"Eq. 9: {known.sum()} estimates at {d_slot.min():.2f}-{d_slot.max():.2f} m, "
        f"mean error {error.mean():.3f} m, median {np.median(error):.3f} m"
    )
    # One pixel of width error over the 10-detection interval moves Eq. 9 by 10-15 % here.
    assert np.median(error / d_slot) < 0.15 and np.mean(error / d_slot) < 0.25


def test_detect_vmaps_over_streams_like_a_loop(standing):
    _, events = standing
    det = detect.Detector(line=detect.hough.LineGrid(), circle=None, sub_slots=5)
    params = detect.detector_params(v_th=64.0)
    parts = io.to_slots(events, 0.01, 1024, n_slots=20)
    ev = jax.tree.map(lambda v: np.asarray(v).reshape(4, 5, 1024), parts.events)
    times = ((np.arange(20) + 1) * 0.01).reshape(4, 5)
    _, one, _ = detect.run(det, params, ev, times)
    half = jax.tree.map(lambda v: v[:2], ev)
    batch = jax.tree.map(lambda a, b: np.stack([a, b]), half, jax.tree.map(lambda v: v[2:], ev))
    # Two streams of 2 slots each, vmapped; the first stream equals the first 2 slots of the single run.
    _, both, _ = jax.vmap(detect.run, in_axes=(None, None, 0, 0))(det, params, batch, np.stack([times[:2], times[2:]]))
    np.testing.assert_allclose(both.width[0], one.width[:2])
    np.testing.assert_allclose(both.pos[0], one.pos[:2])


def test_command_writes_table_csv_and_overlay(standing, tmp_path, capsys):
    _, events = standing
    events = events.copy()
    events["t"] += 1_700_000_000_000_000  # Unix microseconds, as AEDAT4 stores them
    path = io.save(tmp_path / "pipe.aedat4", events, (128, 128))
    rc = cli.main(
        [
            "detect",
            "pipe",
            str(path),
            "--out",
            str(tmp_path / "out"),
            "--shapes",
            "lines",
            "--slot",
            "0.05",
            "--pipe-size",
            "0.25",
            "--no-progress",
        ]
    )
    assert rc == 0
    printed = capsys.readouterr().out
    assert "6 slots of 50 ms" in printed and "body" in printed and "1.1" in printed  # distances ~1.155 m
    rows = (tmp_path / "out" / "detections.csv").read_text().splitlines()
    assert rows[0].startswith("t,kind,theta_deg,width_px,pos_px") and len(rows) == 7
    assert (tmp_path / "out" / "overlay.png").stat().st_size > 1000


def test_chunking_does_not_change_the_detections(standing):
    _, events = standing
    whole = detect.detect(events, (128, 128), slot=0.03, circles=False, chunk=64)
    chunked = detect.detect(events, (128, 128), slot=0.03, circles=False, chunk=4)  # 10 slots: 4 + 4 + 2 (padded)
    for a, b in zip(whole.bodies, chunked.bodies):
        np.testing.assert_array_equal(a, b)


def test_overflow_is_counted_per_slot_and_reported(standing, tmp_path, capsys):
    _, events = standing
    found = detect.detect(events, (128, 128), slot=0.05, sub_slots=5, capacity=500, circles=False)
    part = ((events["t"] - events["t"][0]) // 10_000).astype(int)  # 10 ms parts
    per_part = np.maximum(np.bincount(part, minlength=30) - 500, 0)
    np.testing.assert_array_equal(found.overflow, per_part[: 5 * len(found.overflow)].reshape(-1, 5).sum(1))
    assert found.overflow.sum() > 0
    path = io.save(tmp_path / "pipe.npz", events, (128, 128))
    assert (
        cli.main(
            ["detect", "pipe", str(path), "--shapes", "lines", "--slot", "0.05", "--capacity", "500", "--no-progress"]
        )
        == 0
    )
    assert f"warning: {int(found.overflow.sum())} events did not fit (capacity 500 per part)" in capsys.readouterr().out


def test_command_reports_bad_input(tmp_path, capsys):
    a = np.zeros(3, io.EVENT_DTYPE)
    a["t"] = [0, 10, 5]
    a["p"] = 1
    np.save(tmp_path / "back.npy", a)
    assert cli.main(["detect", "pipe", str(tmp_path / "back.npy")]) == 2
    assert "time stamps go backwards at event 2" in capsys.readouterr().err
    assert cli.main(["detect", "pipe", str(tmp_path / "back.npy"), "--slot", "0"]) == 2
    assert "--slot must be > 0" in capsys.readouterr().err


def test_async_circles_warn_that_they_are_slow(tmp_path, capsys):
    a = np.zeros(20, io.EVENT_DTYPE)
    a["x"], a["y"], a["t"], a["p"] = np.arange(20) + 40, 64, np.arange(20) * 100, 1
    np.save(tmp_path / "few.npy", a)
    assert (
        cli.main(
            ["detect", "pipe", str(tmp_path / "few.npy"), "--mode", "async", "--shapes", "circles", "--no-progress"]
        )
        == 0
    )
    assert "asynchronous circle detection is slow" in capsys.readouterr().err
    assert cli.main(["detect", "pipe", str(tmp_path / "few.npy"), "--shapes", "circles", "--no-progress"]) == 0
    assert "slow" not in capsys.readouterr().err


def test_the_library_module_imports_no_app_code():
    tree = ast.parse(open(detect.__file__).read())
    imported = {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    imported |= {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
    app = {"argparse", "csv", "matplotlib", "spikejax.cli", "spikejax.commands", "robots"}
    assert not {name for name in imported if name.split(".")[0] in app or name in app}
    assert not {"main", "format_table", "write_csv", "overlay"} & set(vars(detect))


def test_format_table_and_csv(tmp_path):
    rows = [
        dict(
            t=0.05,
            kind="body",
            theta_deg=90.0,
            width_px=24.0,
            pos_px=40.0,
            row_px=64.0,
            distance_m=1.155,
            offset_m=-0.1,
            control=-1,
            score=12.0,
            support=0.9,
        ),
        dict(
            t=0.1,
            kind="entry",
            theta_deg=0.0,
            width_px=30.0,
            pos_px=50.0,
            row_px=60.0,
            distance_m=0.0,
            offset_m=0.0,
            control=1,
            score=3.0,
            support=0.75,
        ),
    ]
    assert detect_pipe.format_table([]) == "no pipe detected"
    assert detect_pipe.format_table(rows).splitlines() == [
        "    t (s) kind   theta  width    pos  distance  C spikes",
        "    0.050 body    90.0   24.0   40.0   1.155 m -1     12",
        "    0.100 entry    0.0   30.0   50.0         -  1      3",
    ]
    detect_pipe.write_csv(tmp_path / "d.csv", rows)
    lines = (tmp_path / "d.csv").read_text().splitlines()
    assert lines[0] == ",".join(detect_pipe.COLUMNS) and lines[2] == "0.1,entry,0.0,30.0,50.0,60.0,0.0,0.0,1,3.0,0.75"


def test_a_circle_grid_on_2x2_bins_finds_the_entry_in_sensor_pixels():
    """``Detector(circle_bin=2)``: a 64 x 64 grid on the 128 x 128 sensor's events, summed over 2 x 2 bins."""
    from spikejax.vision import hough

    scene = scenes.lying_pipe(n_frames=31, centre=(50.0, 60.0), radius=16.0, speed=1.0, growth=0.5)
    events, overflow = dvs.difference_events(scene.frames, scene.times, threshold=0.1, capacity=4096)
    assert int(overflow.sum()) == 0
    events = jax.tree.map(lambda v: v.reshape(6, 5, -1), events)  # 6 slots of 5 frames
    times = np.asarray(scene.times[1:], np.float32).reshape(6, 5)
    det = detect.Detector(line=None, circle=hough.CircleGrid(64, 64, n_r=32, r_min=1.0, r_step=1.0), circle_bin=2)
    assert det.sensor == (128, 128)
    _, _, e = detect.run(det, detect.detector_params(v_th=64.0), events, times)
    assert np.asarray(e.valid).all()
    a, r = (_slot_truth(v, 100.0, 0.05, 6) for v in (scene.truth.a, scene.truth.r))
    np.testing.assert_allclose(e.pos, a, atol=4.0)  # sensor pixels, as the full grid's (test above)
    np.testing.assert_allclose(e.row, 60.0, atol=2.0)
    np.testing.assert_allclose(e.width, 2 * r, atol=4.0)


def test_a_circle_grid_with_centres_above_the_image_finds_a_ring_whose_lower_arc_alone_is_in_view():
    """``Detector(circle_top=16)``: a near entry's ring, centred 30 pixels above the sensor, 70-85 pixels across.

    Only its lower arc is in view (a quarter of the ring); the grid without rows above the image puts the
    centre on the image and the column more than 10 pixels off.
    """
    from spikejax.vision import hough

    scene = scenes.lying_pipe(n_frames=31, centre=(50.0, -30.0), radius=70.0, speed=1.0, growth=0.5)
    events, overflow = dvs.difference_events(scene.frames, scene.times, threshold=0.1, capacity=8192)
    assert int(overflow.sum()) == 0
    events = jax.tree.map(lambda v: v.reshape(6, 5, -1), events)
    times = np.asarray(scene.times[1:], np.float32).reshape(6, 5)
    params = detect.detector_params(v_th=64.0, entry=detect.NEAR_ENTRY)
    a, r = (_slot_truth(v, 100.0, 0.05, 6) for v in (scene.truth.a, scene.truth.r))
    found = {}
    for top in (16, 0):
        grid = hough.CircleGrid(64, 64 + top, n_r=48, r_min=2.0, r_step=1.0)
        det = detect.Detector(line=None, circle=grid, circle_bin=2, circle_top=top)
        assert det.sensor == (128, 128)
        _, _, found[top] = detect.run(det, params, events, times)
    e = found[16]
    assert np.asarray(e.valid).all()
    np.testing.assert_allclose(e.pos, a, atol=3.0)
    np.testing.assert_allclose(e.row, -30.0, atol=10.0)  # a partial arc pulls the centre towards it
    np.testing.assert_allclose(e.width, 2 * r, rtol=0.12)
    assert np.abs(np.asarray(found[0].pos) - a).max() > 10.0 and (np.asarray(found[0].row) >= 0).all()
    with pytest.raises(detect.UserError, match="circle_top .64. leaves none of the circle grid.s 64 rows"):
        detect.Detector(line=None, circle=hough.CircleGrid(64, 64), circle_top=64)


def test_circle_bins_sum_the_image_and_move_the_events():
    det = detect.Detector(line=None, circle=detect.hough.CircleGrid(3, 2, n_r=1), circle_bin=2)
    assert det.sensor == (4, 6)
    image = np.arange(24.0).reshape(4, 6)
    top = [0 + 1 + 6 + 7, 2 + 3 + 8 + 9, 4 + 5 + 10 + 11]
    bottom = [12 + 13 + 18 + 19, 14 + 15 + 20 + 21, 16 + 17 + 22 + 23]
    np.testing.assert_array_equal(detect.circle_image(det, jnp.asarray(image)), [top, bottom])
    one = detect.Events(np.array([5]), np.array([3]), np.zeros(1, np.float32), np.ones(1, np.int32), np.ones(1, bool))
    ev = detect.circle_events(det, one)
    assert (int(ev.x[0]), int(ev.y[0])) == (2, 1)
    above = detect.Detector(line=None, circle=detect.hough.CircleGrid(3, 3, n_r=1), circle_bin=2, circle_top=1)
    assert above.sensor == (4, 6)
    ev = detect.circle_events(above, one)
    assert (int(ev.x[0]), int(ev.y[0])) == (2, 2)
    np.testing.assert_array_equal(detect.circle_image(above, jnp.asarray(image)), [[0, 0, 0], top, bottom])
    np.testing.assert_array_equal(detect.binned_image(above, jnp.asarray(image)), [top, bottom])
    with pytest.raises(detect.UserError, match="covers 256 x 256 pixels, not the line grid.s 64 x 64"):
        detect.Detector(line=detect.hough.LineGrid(64, 64), circle=detect.hough.CircleGrid(), circle_bin=1 + 1)
