"""``spikejax bench hough``: spiking Hough detectors against scikit-image and OpenCV.

The detectors are those of the pipe paper (Eq. (2)-(3) and Alg. 1, `spikejax.vision.hough`).

Every detector works on the same synthetic event frames: a standing pipe swept
sideways (two edges of opposite polarity, for lines) and a pipe entry drifting
and growing (a ring, for circles), 128 x 128 pixels, about 2,200 and 1,350 events a frame
(`frames`). The peers get, per frame, the binary image of the pixels that
had an event, in the same run:

* scikit-image ``hough_line`` (the bare accumulator, 180 angles) and
  ``hough_circle`` (64 radii, 1 .. 64 pixels);
* OpenCV ``HoughLines`` (accumulator and peak search, 1 pixel x 1 degree) and
  ``HoughCircles`` (``HOUGH_GRADIENT``: edge gradients, centre votes, radii);
* a per-event NumPy loop of Alg. 1 for the asynchronous mode.

spikejax runs the whole detector -- votes, the bipolar LIF of Alg. 1 and lateral
inhibition -- in both modes, ``jax.jit(jax.vmap(...))`` over a batch of streams
(one time slot per frame): `spikejax.vision.hough.sync_run` on the paper's
180 x 180 line grid and 64 x 128 x 128 circle grid, and
`spikejax.vision.hough.async_run` event by event on the line grid.
Compile time (``lower(...).compile()``) is reported apart from run time (the
best of ``--repeats`` runs, every implementation timed once a round,
`spikejax.benchmarking.interleaved`). Frames/s and events/s count every
stream of the batch. Every ratio is quoted one core against one and all cores
against all: the peers run one frame after another in one process, and, with
several cores, in a pool of one process a core (each with the same frames,
started together), as their users would spread frames over cores; spikejax
runs each batch on one CPU device in a process of its own held to one core
(`_OneCoreRun`: XLA's thread pool then has one thread), split over all
devices of this process (`spikejax.devices.shard_batch`), and, from
`PROCESS_MIN_BATCH` streams on, split over one such process a core started
together, as the peers are (and as `spikejax.workers` spreads a
reproduction). ``x_peer`` is a row's rate over its peer's
(skimage ``hough_line``, ``hough_circle``, the NumPy loop) on as many cores.

Formulations measured (ratios in ``docs/ARCHITECTURE.md``, "Hough formulations
(measured)"; ``benchmarks/hough_formulations.py`` measures them side by side),
and why these won:

* Line votes of 32 streams or more (a batch of groups of about 64, a multiple of 32): each stream's
  events summed per pixel into an image laid out (pixel, stream), int8 when
  every pixel's sum fits, and each cell the sum of the image rows of the pixels
  on its line (the table inverted, cells sorted by line length into 32 blocks,
  rows added four at a time): the same integers, 64 streams a vector, about
  0.13 ms a frame whatever its events; the synchronous run keeps the layout
  (cell, stream) from slot to slot. 2-3x the scatter below on these frames.
* Line votes of fewer streams, or of slots too sparse for the dense sums to
  pay: scatter-adds of the ``n_theta`` cells of every event, read from a
  static table of the rho bin of each (pixel, angle) (`spikejax.vision.hough.line_table`),
  gathered as uint16, summed in int32, 576 events at a time (the gathered cells
  stay in the L2 cache), and under ``vmap`` on a CPU one stream after another,
  each into its own accumulator (a custom batching rule): the scatter then runs
  at about 1 ns a vote. A flat scatter of all streams into one accumulator
  (the stream index in the cell index) is 2-3x slower, as its accumulators do
  not stay in the cache. Also beaten: computing rho on the fly (same speed; the
  scatter dominates), dense matmuls of the event image with the static
  pixel -> cell incidence matrix (16384 x 32400, 0.55 % full: 5-7x slower even in
  bfloat16), one-hot matmuls over events (20x slower), segment sums or gathers
  over per-cell pixel lists one stream at a time (3-10x slower; 64 streams a
  row, they are the dense sums above), theta blocks (slower: strided gathers)
  and int16 counts (no faster).
* Lateral inhibition (sync): the 3 x 3 (x 3) dilation as ORs of shifted slices
  of the padded spike mask; ``lax.reduce_window`` is a generic loop on a CPU.
  On the circle grid the last axis is packed 32 cells a word first (1.7x).
* Circle votes: the event image convolved with the 64 ring kernels by FFT,
  each radius at the smallest size without wrap-around for its ring, rounded
  up to a multiple of 8 (136 to 192; 1.5x one size of 192 for all), two radii
  to one complex inverse FFT as its real and imaginary parts (XLA's ``irfft2``
  is about 3x slower per radius), independent of the number of events; scattering every event's ~13,000 ring
  cells is 100x more work. Under ``vmap`` the streams run one after another
  (a stream's 4 MB grid stays in the cache).
* Async: one ``lax.scan`` over event positions for the whole batch; each step
  gathers the ``(v, t_last)`` of the 180 cells of event ``i`` of every stream
  (one complex64 a cell) from a flat state of all streams' grids, decays them
  lazily and writes them back by one scatter-add of the change (XLA updates in
  place after a gather for an add, but copies for a set); inhibition runs in a
  ``lax.cond`` only on steps where some stream fired, its fired cells taken 12
  per stream at a time from their mask packed as bits. Running the streams one
  after another, each grid kept in the cache (a padded complex64 grid, the fired
  cells packed by a cumulative sum), was up to 1.3x faster on a quiet machine on
  one device and 0.75-1.0x on two devices under load: not kept.
* Sync, ``LineGrid(merge_pixels=True)``: a slot's events summed per pixel
  before voting (the same accumulator); not the default, since the bench
  frames have one event a pixel.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.util
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from spikejax.benchmarking import (
    JaxRun,
    Processes,
    add_ratios,
    batch_sizes,
    compile_ahead,
    cores_label,
    interleaved,
    machine_banner,
    plot_rows,
    write_csv,
)
from spikejax.commands import Command, add_cpu_devices, count, writes_output
from spikejax.devices import cpu_devices_for_run, shard_batch
from spikejax.errors import UserError
from spikejax.vision import dvs, hough, scenes
from spikejax.vision.hough.reference import async_run_numpy
from spikejax.workers import hold_to_core

__all__ = ["PEERS", "TABLE1", "command", "frames", "mode_difference", "run"]

# Table 1 of the snake pipe-tracking paper: frames/s of the whole pipe tracker.
TABLE1 = [
    ("Standing pipe in V-REP", "Intel i7-5500U / GeForce 940M", 0.21, 1.71),
    ("Lying pipe in V-REP", "Intel i7-5500U / GeForce 940M", 0.33, 3.22),
    ("Standing pipe in NRP", "Intel i7-4770 / GeForce GTX 645", 1.63, 40.74),
    ("Lying pipe in NRP", "Intel i7-4770 / GeForce GTX 645", 0.36, 22.35),
]
CAPACITY = 2304
N_FRAMES = 8
COLUMNS = [
    "shape",
    "implementation",
    "mode",
    "batch",
    "frames",
    "events",
    "compile_s",
    "run_s",
    "frames_per_s",
    "events_per_s",
    "device",
    "devices",
    "cores",
    "parallel",
    "peer",
    "x_peer",
    "x_opencv",
]


def frames(shape: str, n: int = N_FRAMES) -> tuple:
    """The benchmark's event frames: ``(events (n, CAPACITY), images (n, 128, 128) bool)``.

    ``shape`` is ``"line"`` (a standing pipe, tilted by 0.2 rad, 8 pixels a frame)
    or ``"circle"`` (a pipe entry of radius 30 drifting 8 and growing 4 pixels a
    frame); about 2,200 and 1,350 events a frame, from `spikejax.vision.dvs.frame_difference`.
    """
    if shape == "line":
        scene = scenes.standing_pipe(n_frames=n + 1, speed=8.0, tilt=0.2, start=30.0)
    elif shape == "circle":
        scene = scenes.lying_pipe(n_frames=n + 1, centre=(40.0, 64.0), radius=26.0, speed=8.0, growth=4.0)
    else:
        raise UserError(f"unknown shape {shape!r}")
    events, overflow = dvs.difference_events(scene.frames, scene.times, threshold=0.1, capacity=CAPACITY)
    if int(overflow.sum()):
        raise RuntimeError("benchmark frames overflow their capacity")
    images = np.zeros((n, 128, 128), bool)
    for i in range(n):
        ok = np.asarray(events.valid[i])
        images[i, np.asarray(events.y[i])[ok], np.asarray(events.x[i])[ok]] = True
    return events, images


class _PeerRun:
    """One timed pass of a peer over a stream's frames, one frame at a time (a `Processes` timer).

    ``name`` is one of `PEERS`; ``frames_in`` the binary images (or, for the
    NumPy loop, the events of one stream, NumPy arrays). ``info`` is
    ``(frames, events)`` of one pass.
    """

    def __init__(self, name: str, frames_in, events_per_frame: float):
        if name == "NumPy per-event loop":
            self._fn = _numpy_async(frames_in)
            self.info = (1, float(self._fn.n_events))
            return
        if name.startswith("skimage"):
            from skimage.transform import hough_circle, hough_line

            thetas, radii = hough.LineGrid().skimage_thetas(), np.arange(1, 65)
            one = (lambda im: hough_line(im, thetas)) if "line" in name else (lambda im: hough_circle(im, radii))
        else:
            import cv2

            cv2.setNumThreads(1)
            frames_in = [(im * 255).astype(np.uint8) for im in frames_in]
            if "Lines" in name:
                one = lambda im: cv2.HoughLines(im, 1, np.pi / 180, 60)  # noqa: E731
            else:
                one = lambda im: cv2.HoughCircles(  # noqa: E731
                    im, cv2.HOUGH_GRADIENT, dp=1, minDist=8, param1=100, param2=20, minRadius=1, maxRadius=64
                )
        images = list(frames_in)
        self.info = (len(images), float(events_per_frame) * len(images))

        def run():
            for im in images:
                one(im)

        self._fn = run

    def __call__(self) -> float:
        t0 = time.perf_counter()
        self._fn()
        return time.perf_counter() - t0


# (shape, implementation, mode) of each peer.
PEERS = (
    ("line", "skimage hough_line", "per frame"),
    ("circle", "skimage hough_circle (64 radii)", "per frame"),
    ("line", "OpenCV HoughLines", "per frame"),
    ("circle", "OpenCV HoughCircles", "per frame"),
    ("line", "NumPy per-event loop", "async"),
)
# The OpenCV peer of the line rows, sync and per frame (accumulator and peak search): `x_opencv`.
# (OpenCV's HoughCircles is another algorithm, edge gradients voting for centres, so circle rows have none.)
OPENCV_PEER = {"line": "OpenCV HoughLines"}
# The peer every row's ratio is taken to, by (shape, mode).
RATIO_PEER = {
    ("line", "sync"): "skimage hough_line",
    ("line", "per frame"): "skimage hough_line",
    ("circle", "sync"): "skimage hough_circle",
    ("circle", "per frame"): "skimage hough_circle",
    ("line", "async"): "NumPy per-event loop",
}


def _numpy_async(events):
    """Alg. 1 of the pipe paper event by event in NumPy on the 180 x 180 grid (the first stream): the plain way.

    The loop is `spikejax.vision.hough.reference.async_run_numpy`, the library's
    oracle. Returns a timer: each call runs the loop over the stream once and
    returns its seconds; ``n_events`` is the stream's events.
    """
    params, grid = hough.hough_params(8.0, 50.0), hough.LineGrid()
    stream = jax.tree.map(lambda a: np.asarray(a[:1]), events)

    def timer() -> float:
        t0 = time.perf_counter()
        async_run_numpy(params, grid, stream)
        return time.perf_counter() - t0

    timer.n_events = int(np.asarray(events.valid[0]).sum())
    return timer


def _batched(tree, batch):
    return jax.tree.map(lambda a: jnp.broadcast_to(a, (batch,) + a.shape), tree)


def _on(devices: int) -> str:
    return "" if devices == 1 else f", {devices} devices"


def _spikejax(shape: str, mode: str, events, batch: int, devices: int):
    """A spikejax row's compiled run and its row: ``(JaxRun, row without run_s)``."""
    params = hough.hough_params(8.0, 50.0)
    grid = hough.LineGrid() if shape == "line" else hough.CircleGrid()
    if mode == "sync":
        n_slots = events.x.shape[0]
        times = jnp.arange(1, n_slots + 1, dtype=jnp.float32) * 0.01
        one = lambda e: hough.sync_run(params, grid, e, times)[1]  # noqa: E731
        n_frames, n_events = n_slots * batch, float(events.count().sum()) * batch
    else:
        events = jax.tree.map(lambda a: a[:1], events)
        one = lambda e: hough.async_run(params, grid, e)  # noqa: E731
        n_frames, n_events = batch, float(events.count()[0]) * batch
    fn = shard_batch(jax.vmap(one), jax.devices()[:devices])
    streams = _batched(events, batch)
    compiled, compile_s = compile_ahead(fn, streams)
    row = dict(
        shape=shape,
        implementation=f"spikejax {type(grid).__name__} (votes + LIF + inhibition){_on(devices)}",
        mode=mode,
        batch=batch,
        frames=n_frames,
        events=n_events,
        compile_s=compile_s,
        device=jax.devices()[0].platform,
        devices=devices,
        cores=devices,
        parallel=cores_label(devices, "device"),
    )
    return JaxRun(compiled, streams), row


def _row_events(shape: str, mode: str):
    """The events a row runs on: the line frames, or two slots of the circle frames (its cost is event-blind)."""
    if shape == "line":
        return frames("line")[0]
    return jax.tree.map(lambda a: a[:2], frames("circle")[0])


class _OneCoreRun:
    """A spikejax row on one core, built in a process of its own (a `Processes` timer).

    The process is held to one core before JAX starts, so XLA's CPU thread
    pool has one thread, as on a one-core machine: a one-device row is then
    one core against a peer's one process. (In a process that may use every
    core, XLA runs a large loop on all of them, and holding its threads to one
    core afterwards time-slices them.) ``info`` is the row.
    """

    def __init__(self, shape: str, mode: str, batch: int, core: int = 0):
        hold_to_core(core)
        self._run, self.info = _spikejax(shape, mode, _row_events(shape, mode), batch, 1)

    def __call__(self) -> float:
        return self._run()


def _process_row(row: dict, processes: int, batch: int) -> dict:
    """A `_OneCoreRun` row of ``batch // processes`` streams made the row of ``processes`` such runs at once."""
    return dict(
        row,
        implementation=f"{row['implementation']}, {processes} processes",
        batch=batch,
        frames=row["frames"] * processes,
        events=row["events"] * processes,
        cores=processes,
        parallel=cores_label(processes, "process"),
    )


def mode_difference(events, params=None) -> dict:
    """How far the synchronous mode's spikes are from the asynchronous mode's on the same slots.

    Both modes run on the line grid over the slots of ``events``; returns the
    spike counts of each and the fraction of the asynchronous spikes (cell, slot,
    sign) that the synchronous mode also emits.
    """
    params = hough.hough_params(8.0, 50.0) if params is None else params
    grid = hough.LineGrid()
    n_slots = events.x.shape[0]
    times = jnp.asarray(np.asarray(events.t).max(axis=1))
    _, sync = hough.sync_run(params, grid, events, times)
    _, asyn = hough.async_run(params, grid, events, hough.init(grid, times[0]))
    sync, asyn = np.asarray(sync), np.asarray(asyn)
    both = np.sum((sync == asyn) & (asyn != 0))
    return dict(
        slots=n_slots,
        sync_spikes=int(np.count_nonzero(sync)),
        async_spikes=int(np.count_nonzero(asyn)),
        shared=float(both / max(np.count_nonzero(asyn), 1)),
    )


# The smallest batch also run as one process a core (each process its share of the streams, held to its core):
# the peers' way of using every core, and that of `spikejax.workers`.
PROCESS_MIN_BATCH = 16
# The batch sizes timed: powers of 4 up to --trials, and --trials itself.
POWERS_OF_4 = tuple(4**k for k in range(16))


def _add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--trials",
        type=count,
        default=None,
        help="largest batch of streams (default 1024; circles stop at 64, async at 256)",
    )
    parser.add_argument("--out", default=None, help="write hough.csv and hough.png here")
    parser.add_argument("--repeats", type=count, default=None, help="timed runs per row, the best kept (default 5)")
    add_cpu_devices(parser, peers="the peers' processes")
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bar")


@writes_output("bench hough")
def run(
    *,
    trials: int | None = None,
    out: str | None = None,
    repeats: int | None = None,
    cpu_devices: int | None = None,
    no_progress: bool = False,
) -> int:
    """``spikejax bench hough``: print the table and write ``hough.csv`` and ``hough.png`` to ``out``.

    Args:
        trials: the largest batch of streams (default 1024; the circle grid, 4 MB
            of state a stream, stops at 64 streams, the asynchronous mode at 256).
        out: a directory for the table and figure (None: print only).
        repeats: timed runs per row, interleaved, the best kept (default 5).
        cpu_devices: CPU devices JAX presents (default: one per core). With more
            than one, every spikejax row from that batch on is also run with the
            streams split over all devices, and every peer also runs in that
            many processes at once.
        no_progress: hide the progress bar.
    """
    largest = 1024 if trials is None else trials
    repeats = 5 if repeats is None else repeats
    if largest < 1 or repeats < 1:
        raise UserError(f"--trials and --repeats must be >= 1, not {largest} and {repeats}")
    n_dev = cpu_devices_for_run(cpu_devices)
    splits = lambda b: [1] + ([n_dev] if n_dev > 1 and b >= n_dev else [])  # noqa: E731
    print(machine_banner(n_dev))
    line_events, line_images = frames("line")
    circle_events, circle_images = frames("circle")
    line_counts = np.asarray(line_events.count())
    circle_counts = np.asarray(circle_events.count())
    print(
        f"frames: 128 x 128; line scene {line_counts.mean():.0f} events/frame, circle scene "
        f"{circle_counts.mean():.0f} events/frame ({N_FRAMES} frames each, one event per pixel)"
    )

    from tqdm import tqdm

    numpy_events = jax.tree.map(np.asarray, jax.tree.map(lambda a: a[:1], line_events))
    with contextlib.ExitStack() as stack:
        runs, rows = {}, {}
        for shape, name, mode in PEERS:
            if name.startswith("OpenCV") and importlib.util.find_spec("cv2") is None:  # pragma: no cover - extra
                continue
            data = numpy_events if mode == "async" else (line_images if shape == "line" else circle_images)
            per_frame = float(np.mean(line_counts if shape == "line" else circle_counts))
            for p in [1] + ([n_dev] if n_dev > 1 else []):
                runner = stack.enter_context(Processes(_PeerRun, name, data, per_frame, processes=p))
                units, events = runner.info()[0]
                impl = name + ("" if p == 1 else f", {p} processes")
                runs[impl, mode] = runner
                rows[impl, mode] = dict(
                    shape=shape,
                    implementation=impl,
                    mode=mode,
                    batch=p,
                    frames=units * p,
                    events=events * p,
                    compile_s=None,
                    device="cpu",
                    devices=1,
                    cores=p,
                    parallel=cores_label(p, "process"),
                )
        jobs = [("line", "sync", b) for b in batch_sizes(largest, POWERS_OF_4)]
        jobs += [("circle", "sync", b) for b in batch_sizes(min(largest, 64), POWERS_OF_4)]
        jobs += [("line", "async", b) for b in batch_sizes(min(largest, 256), POWERS_OF_4)]
        for shape, mode, b in tqdm(jobs, desc="hough bench: compiling", disable=no_progress):
            for d in splits(b):
                if d == 1:
                    runner = stack.enter_context(Processes(_OneCoreRun, shape, mode, b))
                    row = runner.info()[0]
                else:
                    runner, row = _spikejax(shape, mode, _row_events(shape, mode), b, d)
                runs[row["implementation"], mode, b] = runner
                rows[row["implementation"], mode, b] = row
                if d > 1 and b >= PROCESS_MIN_BATCH and b % d == 0:
                    runner = stack.enter_context(
                        Processes(_OneCoreRun, shape, mode, b // d, processes=d, index_arg="core")
                    )
                    row = _process_row(runner.info()[0], d, b)
                    runs[row["implementation"], mode, b] = runner
                    rows[row["implementation"], mode, b] = row
        bar = tqdm(total=len(runs) * repeats, desc="hough bench: timing", disable=no_progress)
        best = interleaved(runs, repeats, progress=lambda _: bar.update())
        bar.close()
    rows = list(rows.values())
    for row, run_s in zip(rows, best.values()):
        row.update(run_s=run_s, frames_per_s=row["frames"] / run_s, events_per_s=row["events"] / run_s)
    add_ratios(
        rows, "x_peer", "frames_per_s", lambda p, r: p["implementation"].startswith(RATIO_PEER[r["shape"], r["mode"]])
    )
    add_ratios(
        rows,
        "x_opencv",
        "frames_per_s",
        lambda p, r: r["shape"] == "line"
        and r["mode"] != "async"
        and p["implementation"].startswith(OPENCV_PEER["line"]),
    )
    for r in rows:  # async: a frame is a stream's one slot, the peer's too, so the ratio is that of events/s
        r["peer"] = RATIO_PEER[r["shape"], r["mode"]]

    _print(rows, n_dev)
    diff = mode_difference(line_events)
    print(
        f"\nsync vs async on the line frames ({diff['slots']} slots of ~{line_counts.mean():.0f} events, "
        f"v_th = 8, decay = 50/s): {diff['sync_spikes']} sync spikes, {diff['async_spikes']} async spikes, "
        f"{100 * diff['shared']:.0f} % of the async spikes also in sync"
    )
    if out:
        out = Path(out)
        write_csv(out / "hough.csv", rows, COLUMNS)
        _plot(rows, out / "hough.png")
        print(f"wrote {out / 'hough.csv'} and {out / 'hough.png'}")
    return 0


def _plot(rows: list[dict], path: Path) -> None:
    paper = {"line": 40.74, "circle": 22.35}
    plot_rows(
        rows,
        path,
        x="batch",
        y="frames_per_s",
        panel="shape",
        size=(11, 4.2),
        series=lambda r: (
            f"{r['implementation']}, {r['mode']}"
            if r["implementation"].startswith("spikejax")
            else f"{r['implementation']} (one frame at a time)"
        ),
        flat=lambda r: not r["implementation"].startswith("spikejax"),
        lines=lambda shape: [(paper[shape], "paper's best (GPU, Table 1)")],
        xlabel="streams in the batch",
        ylabel="frames / s",
        title=lambda shape: f"{shape} detection, 128 x 128 event frames",
    )


def _print(rows: list[dict], n_dev: int) -> None:
    print(
        f"\n{'shape':7s} {'implementation':58s} {'mode':9s} {'batch':>5s} {'cores':>5s} {'compile s':>9s} "
        f"{'frames/s':>10s} {'M events/s':>10s} {'x peer':>7s}"
    )
    for r in rows:
        c = "" if r["compile_s"] is None else f"{r['compile_s']:.1f}"
        print(
            f"{r['shape']:7s} {r['implementation']:58s} {r['mode']:9s} {r['batch']:5d} {r['cores']:5d} {c:>9s} "
            f"{r['frames_per_s']:10.1f} {r['events_per_s'] / 1e6:10.3f} {r['x_peer']:7.2f}"
        )
    print(
        "(x peer: against skimage hough_line / hough_circle or the NumPy loop given the same cores; async in events/s;\n"
        " x_opencv in hough.csv: line rows against OpenCV HoughLines given the same cores)"
    )
    print("\nmeasured in this run (ratios to the peer on the same frames and cores; the best row):")
    for cores in sorted({1, n_dev}):
        for shape, mode, unit in (
            ("line", "sync", "frames"),
            ("circle", "sync", "frames"),
            ("line", "async", "events"),
        ):
            sel = [
                r
                for r in rows
                if r["shape"] == shape
                and r["mode"] == mode
                and r["cores"] == cores
                and r["implementation"].startswith("spikejax")
            ]
            if not sel:
                continue
            best = max(sel, key=lambda r: r["x_peer"])
            rate = (
                f"{best['frames_per_s']:.1f} frames/s"
                if unit == "frames"
                else f"{best['events_per_s'] / 1e6:.3f} M events/s"
            )
            opencv = "" if np.isnan(best["x_opencv"]) else f", {best['x_opencv']:.2f} x {OPENCV_PEER[shape]}"
            print(
                f"  {shape}, {mode}, {cores} core{'s' if cores > 1 else ''}: {rate} at batch {best['batch']} = "
                f"{best['x_peer']:.2f} x {best['peer']}{opencv} ({best['parallel']} against "
                f"{cores_label(cores, 'process')})"
            )
    print("\nTable 1 of the paper (whole pipe tracker, frames/s):")
    for case, hw, cpu, gpu in TABLE1:
        print(f"  {case:24s} {hw:34s} CPU {cpu:5.2f}  GPU {gpu:6.2f}")


command = Command(
    help="spiking Hough detectors against scikit-image and OpenCV",
    add_arguments=_add_arguments,
    run=run,
    description=__doc__.splitlines()[0],
)
