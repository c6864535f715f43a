"""``spikejax bench hough``: spiking Hough detectors against scikit-image and OpenCV.

Every detector works on the same synthetic event frames: a standing pipe swept
sideways (two edges of opposite polarity, for lines) and a pipe entry drifting
and growing (a ring, for circles), 128 x 128 pixels, about 2,200 and 1,350 events a frame
(:func:`frames`). The peers get, per frame, the binary image of the pixels that
had an event, in the same run:

* scikit-image ``hough_line`` (the bare accumulator, 180 angles) and
  ``hough_circle`` (64 radii, 1 .. 64 pixels);
* OpenCV ``HoughLines`` (accumulator and peak search, 1 pixel x 1 degree) and
  ``HoughCircles`` (``HOUGH_GRADIENT``: edge gradients, centre votes, radii);
* a per-event NumPy loop of Alg. 1 for the asynchronous mode.

spikejax runs the whole detector -- votes, the bipolar LIF of Alg. 1 and lateral
inhibition -- in both modes, ``jax.jit(jax.vmap(...))`` over a batch of streams
(one time slot per frame): :func:`spikejax.vision.hough.sync_run` on the paper's
180 x 180 line grid and 64 x 128 x 128 circle grid, and
:func:`spikejax.vision.hough.async_run` event by event on the line grid.
Compile time (first call) is reported apart from run time (the median of
repeated calls after it). Frames/s and events/s count every stream of the batch.

Formulations measured (ratios in ``docs/ARCHITECTURE.md``, "Hough formulations
(measured)"; ``benchmarks/hough_formulations.py`` measures them side by side),
and why these won:

* Line votes: scatter-adds of the ``n_theta`` cells of every event, read from a
  static table of the rho bin of each (pixel, angle) (:func:`hough.line_table`),
  gathered as uint16, summed in int32, 576 events at a time (the gathered cells
  stay in the L2 cache), and under ``vmap`` on a CPU one stream after another,
  each into its own accumulator (a custom batching rule): the scatter then runs
  at about 1 ns a vote. A flat scatter of all streams into one accumulator
  (the stream index in the cell index) is 2-3x slower, as its accumulators do
  not stay in the cache. Also beaten: computing rho on the fly (same speed; the
  scatter dominates), dense matmuls of the event image with the static
  pixel -> cell incidence matrix (16384 x 32400, 0.55 % full: 5-7x slower even in
  bfloat16), one-hot matmuls over events (20x slower), segment sums or gathers
  over per-cell pixel lists (3-10x slower), theta blocks (slower: strided
  gathers) and int16 counts (no faster).
* Lateral inhibition (sync): the 3 x 3 (x 3) dilation as ORs of shifted slices
  of the padded spike mask; ``lax.reduce_window`` is a generic loop on a CPU.
* Circle votes: the event image convolved with the 64 ring kernels by FFT
  (one forward, 64 inverse real FFTs of 192 x 192, the smallest size without
  wrap-around), independent of the number of events; scattering every event's
  ~13,000 ring cells is 100x more work.
* Async: one ``lax.scan`` over event positions for the whole batch; each step
  gathers the ``(v, t_last)`` of the 180 cells of event ``i`` of every stream
  from a flat state of all streams' grids, decays them lazily and writes them
  back by one scatter-add of the change (XLA updates in place after a gather
  for an add, but copies for a set); inhibition runs in a ``lax.cond`` only on
  steps where some stream fired, its fired cells packed to the front and
  visited 8 per stream at a time. Running the streams one after another
  (``lax.map``, one event a step, as before) is 1.4-1.7x slower: each step is
  a dozen small XLA operations, about 4 us an event whatever their size.
"""

from __future__ import annotations

import argparse
import csv
import os
import platform
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from spikejax.devices import cpu_devices_for_run
from spikejax.devices import shard_batch
from spikejax.errors import UserError
from spikejax.vision import dvs, hough, scenes

__all__ = ["main", "frames", "mode_difference", "TABLE1"]

# Table 1 of the snake pipe-tracking paper: frames/s of the whole pipe tracker.
TABLE1 = [
    ("Standing pipe in V-REP", "Intel i7-5500U / GeForce 940M", 0.21, 1.71),
    ("Lying pipe in V-REP", "Intel i7-5500U / GeForce 940M", 0.33, 3.22),
    ("Standing pipe in NRP", "Intel i7-4770 / GeForce GTX 645", 1.63, 40.74),
    ("Lying pipe in NRP", "Intel i7-4770 / GeForce GTX 645", 0.36, 22.35),
]
CAPACITY = 2304
N_FRAMES = 8
COLUMNS = ["shape", "implementation", "mode", "batch", "frames", "events", "compile_s", "run_s", "frames_per_s",
           "events_per_s", "device", "devices"]


def frames(shape: str, n: int = N_FRAMES) -> tuple:
    """The benchmark's event frames: ``(events (n, CAPACITY), images (n, 128, 128) bool)``.

    ``shape`` is ``"line"`` (a standing pipe, tilted by 0.2 rad, 8 pixels a frame)
    or ``"circle"`` (a pipe entry of radius 30 drifting 8 and growing 4 pixels a
    frame); about 2,200 and 1,350 events a frame, from :func:`dvs.frame_difference`.
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


def _time(fn, repeats: int, min_s: float = 0.3) -> float:
    """Median seconds of one call, over ``repeats`` calls (more while under ``min_s`` in all)."""
    times = []
    start = time.perf_counter()
    while len(times) < repeats or time.perf_counter() - start < min_s:
        t = time.perf_counter()
        jax.block_until_ready(fn())
        times.append(time.perf_counter() - t)
        if len(times) >= 1000:
            break
    return float(np.median(times))


def _row(shape, impl, mode, batch, n_frames, n_events, compile_s, run_s, device="cpu", devices=1):
    return dict(shape=shape, implementation=impl, mode=mode, batch=batch, frames=n_frames, events=n_events,
                compile_s=compile_s, run_s=run_s, frames_per_s=n_frames / run_s, events_per_s=n_events / run_s,
                device=device, devices=devices)


def _peer(shape, impl, fn, images, counts, repeats):
    i = [0]

    def one():
        k = i[0] % len(images)
        i[0] += 1
        return fn(images[k])

    run_s = _time(one, repeats * len(images))
    return _row(shape, impl, "per frame", 1, 1, float(np.mean(counts)), None, run_s)


def _peers(line_images, circle_images, line_counts, circle_counts, line_events, repeats):
    from skimage.transform import hough_circle, hough_line

    rows = []
    thetas = hough.LineGrid().skimage_thetas()
    rows.append(_peer("line", "skimage hough_line", lambda im: hough_line(im, thetas), line_images, line_counts, repeats))
    radii = np.arange(1, 65)
    rows.append(_peer("circle", "skimage hough_circle (64 radii)", lambda im: hough_circle(im, radii), circle_images,
                      circle_counts, 1))
    try:
        import cv2
    except ImportError:  # pragma: no cover - OpenCV is a bench extra
        cv2 = None
    if cv2 is not None:
        cv2.setNumThreads(1)
        u8 = lambda ims: [(im * 255).astype(np.uint8) for im in ims]
        rows.append(_peer("line", "OpenCV HoughLines", lambda im: cv2.HoughLines(im, 1, np.pi / 180, 60),
                          u8(line_images), line_counts, repeats))
        rows.append(_peer("circle", "OpenCV HoughCircles", lambda im: cv2.HoughCircles(
            im, cv2.HOUGH_GRADIENT, dp=1, minDist=8, param1=100, param2=20, minRadius=1, maxRadius=64),
            u8(circle_images), circle_counts, repeats))
    rows.append(_numpy_async(line_events, repeats))
    return rows


def _numpy_async(events, repeats):
    """Alg. 1 event by event in NumPy on the 180 x 180 grid (one stream): the plain way."""
    grid = hough.LineGrid()
    table = hough.line_table(grid)
    v_th, decay = 8.0, 50.0
    x, y, t, p, ok = (np.asarray(a[0]) for a in events)
    n = int(ok.sum())
    dk, dj = np.meshgrid(np.arange(-1, 2), np.arange(-1, 2), indexing="ij")

    def run():
        v = np.zeros(grid.size + 1)
        last = np.zeros(grid.size + 1)
        spikes = 0
        for i in range(n):
            cells = table[y[i] * grid.width + x[i]]
            vv = v[cells]
            vv = np.sign(vv) * np.maximum(np.abs(vv) - decay * (t[i] - last[cells]), 0.0) + p[i]
            v[cells] = vv
            last[cells] = t[i]
            fired = np.abs(vv) >= v_th
            if fired.any():
                spikes += int(fired.sum())
                k = np.flatnonzero(fired)
                rho = cells[k] - k * grid.n_rho
                nk, nj = (k[:, None, None] + dk).ravel(), (rho[:, None, None] + dj).ravel()
                inside = (nk >= 0) & (nk < grid.n_theta) & (nj >= 0) & (nj < grid.n_rho)
                v[nk[inside] * grid.n_rho + nj[inside]] = 0.0
        return spikes

    run_s = _time(run, 1, min_s=0.0)
    return _row("line", "NumPy per-event loop", "async", 1, 1, n, None, run_s)


def _batched(tree, batch):
    return jax.tree.map(lambda a: jnp.broadcast_to(a, (batch,) + a.shape), tree)


def _on(devices: int) -> str:
    return "" if devices == 1 else f", {devices} devices"


def _spikejax_sync(shape, grid, events, batch, repeats, device, devices=1):
    params = hough.hough_params(8.0, 50.0)
    n_slots = events.x.shape[0]
    times = jnp.arange(1, n_slots + 1, dtype=jnp.float32) * 0.01
    fn = shard_batch(jax.vmap(lambda e: hough.sync_run(params, grid, e, times)[1]), jax.devices()[:devices])
    streams = _batched(events, batch)
    t = time.perf_counter()
    jax.block_until_ready(fn(streams))
    compile_s = time.perf_counter() - t
    run_s = _time(lambda: fn(streams), repeats)
    n_events = float(events.count().sum()) * batch
    return _row(shape, f"spikejax {type(grid).__name__} (votes + LIF + inhibition){_on(devices)}", "sync", batch,
                n_slots * batch, n_events, compile_s, run_s, device, devices)


def _spikejax_async(grid, events, batch, repeats, device, devices=1):
    params = hough.hough_params(8.0, 50.0)
    fn = shard_batch(jax.vmap(lambda e: hough.async_run(params, grid, e)), jax.devices()[:devices])
    streams = _batched(jax.tree.map(lambda a: a[:1], events), batch)
    t = time.perf_counter()
    jax.block_until_ready(fn(streams))
    compile_s = time.perf_counter() - t
    run_s = _time(lambda: fn(streams), repeats, min_s=0.0)
    n_events = float(events.count()[0]) * batch
    return _row("line", f"spikejax LineGrid (votes + LIF + inhibition){_on(devices)}", "async", batch, batch, n_events,
                compile_s, run_s, device, devices)


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
    return dict(slots=n_slots, sync_spikes=int(np.count_nonzero(sync)), async_spikes=int(np.count_nonzero(asyn)),
                shared=float(both / max(np.count_nonzero(asyn), 1)))


def _batches(largest: int) -> list[int]:
    out, b = [], 1
    while b <= largest:
        out.append(b)
        b *= 4
    if out[-1] != largest:
        out.append(largest)
    return out


def _plot(rows, path: Path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    colours = iter(plt.rcParams["axes.prop_cycle"].by_key()["color"] * 4)
    for ax, shape in zip(axes, ("line", "circle")):
        keys = dict.fromkeys((r["implementation"], r["mode"]) for r in rows if r["shape"] == shape)
        for impl, mode in keys:
            sel = [r for r in rows if r["shape"] == shape and (r["implementation"], r["mode"]) == (impl, mode)]
            colour = next(colours)
            if impl.startswith("spikejax"):
                ax.plot([r["batch"] for r in sel], [r["frames_per_s"] for r in sel], "o-", color=colour,
                        label=f"{impl}, {mode}")
            else:
                ax.axhline(sel[0]["frames_per_s"], ls="--", lw=1, color=colour, label=f"{impl} (one frame at a time)")
        ax.axhline(40.74 if shape == "line" else 22.35, color="k", lw=0.8, ls=":", label="paper's best (GPU, Table 1)")
        ax.set(xscale="log", yscale="log", xlabel="streams in the batch", ylabel="frames / s",
               title=f"{shape} detection, 128 x 128 event frames")
        ax.legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


def main(args: argparse.Namespace) -> int:
    """``spikejax bench hough``: print the table and write ``hough.csv`` and ``hough.png`` to ``--out``.

    Reads ``args.trials`` as the largest batch of streams (default 1024; the
    circle grid, 4 MB of state a stream, stops at 64 streams, the asynchronous
    mode at 256) and ``args.out`` (optional). ``args.repeats`` (optional) sets
    the timed calls per row (default 5). ``args.cpu_devices`` (default: the
    machine's cores) is the number of CPU devices JAX presents; with more than
    one device, every spikejax row from that batch on is also run with the
    streams split over all devices (`spikejax.devices.shard_batch`).
    """
    largest = int(getattr(args, "trials", None) or 1024)
    if largest < 1:
        raise UserError(f"--trials (the largest batch of streams) must be >= 1, not {largest}")
    repeats = int(getattr(args, "repeats", None) or 5)
    n_dev = cpu_devices_for_run(getattr(args, "cpu_devices", None))
    device = jax.devices()[0].platform
    splits = lambda b: [1] + ([n_dev] if n_dev > 1 and b >= n_dev else [])
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, "
          f"{n_dev} x {device}, jax {jax.__version__}")
    line_events, line_images = frames("line")
    circle_events, circle_images = frames("circle")
    line_counts = np.asarray(line_events.count())
    circle_counts = np.asarray(circle_events.count())
    print(f"frames: 128 x 128; line scene {line_counts.mean():.0f} events/frame, circle scene "
          f"{circle_counts.mean():.0f} events/frame ({N_FRAMES} frames each, one event per pixel)")

    from tqdm import tqdm

    jobs = [lambda: _peers(line_images, circle_images, line_counts, circle_counts, line_events, repeats)]
    # Two slots a stream for circles: the circle grid's run time does not depend on the events.
    two = jax.tree.map(lambda a: a[:2], circle_events)
    for b in _batches(largest):
        for d in splits(b):
            jobs.append(lambda b=b, d=d: [_spikejax_sync("line", hough.LineGrid(), line_events, b, repeats, device, d)])
    for b in _batches(min(largest, 64)):
        for d in splits(b):
            jobs.append(lambda b=b, d=d: [_spikejax_sync("circle", hough.CircleGrid(), two, b, repeats, device, d)])
    for b in _batches(min(largest, 256)):
        for d in splits(b):
            jobs.append(lambda b=b, d=d: [_spikejax_async(hough.LineGrid(), line_events, b, repeats, device, d)])
    rows = []
    for job in tqdm(jobs, desc="hough bench", disable=getattr(args, "no_progress", False)):
        rows.extend(job())

    _print(rows)
    diff = mode_difference(line_events)
    print(f"\nsync vs async on the line frames ({diff['slots']} slots of ~{line_counts.mean():.0f} events, "
          f"v_th = 8, decay = 50/s): {diff['sync_spikes']} sync spikes, {diff['async_spikes']} async spikes, "
          f"{100 * diff['shared']:.0f} % of the async spikes also in sync")
    if args.out:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        with open(out / "hough.csv", "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=COLUMNS)
            writer.writeheader()
            writer.writerows(rows)
        _plot(rows, out / "hough.png")
        print(f"wrote {out / 'hough.csv'} and {out / 'hough.png'}")
    return 0


def _print(rows):
    print(f"\n{'shape':7s} {'implementation':58s} {'mode':9s} {'batch':>5s} {'compile s':>9s} {'frames/s':>10s} "
          f"{'M events/s':>10s}")
    for r in rows:
        c = "" if r["compile_s"] is None else f"{r['compile_s']:.1f}"
        print(f"{r['shape']:7s} {r['implementation']:58s} {r['mode']:9s} {r['batch']:5d} {c:>9s} "
              f"{r['frames_per_s']:10.1f} {r['events_per_s'] / 1e6:10.3f}")
    best = lambda shape, mode: max((r for r in rows if r["shape"] == shape and r["mode"] == mode
                                    and r["implementation"].startswith("spikejax")), key=lambda r: r["events_per_s"])
    peer = lambda name: next(r for r in rows if r["implementation"].startswith(name))
    line, circle, asyn = best("line", "sync"), best("circle", "sync"), best("line", "async")
    where = lambda r: f"batch {r['batch']}, {r['devices']} device" + ("s" if r["devices"] > 1 else "")
    print("\nmeasured in this run (ratios to the peer on the same frames; the best row):")
    print(f"  line, sync:    {line['frames_per_s']:.0f} frames/s at {where(line)} = "
          f"{line['frames_per_s'] / peer('skimage hough_line')['frames_per_s']:.2f} x skimage hough_line")
    print(f"  circle, sync:  {circle['frames_per_s']:.1f} frames/s at {where(circle)} = "
          f"{circle['frames_per_s'] / peer('skimage hough_circle')['frames_per_s']:.2f} x skimage hough_circle")
    print(f"  line, async:   {asyn['events_per_s'] / 1e6:.3f} M events/s at {where(asyn)} = "
          f"{asyn['events_per_s'] / peer('NumPy per-event')['events_per_s']:.1f} x the NumPy per-event loop")
    print("\nTable 1 of the paper (whole pipe tracker, frames/s):")
    for case, hw, cpu, gpu in TABLE1:
        print(f"  {case:24s} {hw:34s} CPU {cpu:5.2f}  GPU {gpu:6.2f}")
