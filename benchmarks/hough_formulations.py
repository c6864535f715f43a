"""Speed ratios of the spiking Hough line detector to its peers, measured side by side.

On a shared machine absolute figures drift from run to run, so this script
reports ratios measured in one process: the candidates are timed in turn
(interleaved), each round keeps the best of ``--repeats`` calls per candidate,
and the ratio of each round is printed with the median over ``--rounds``.

* votes only: `spikejax.vision.hough.line_votes`, ``vmap`` over streams and slots, vs
  ``skimage.transform.hough_line`` (the bare accumulator, 180 angles) on the
  same frames (frames/s);
* whole detector, synchronous: ``vmap`` of `spikejax.vision.hough.sync_run` over streams
  (votes + bipolar LIF + 3 x 3 inhibition, one slot a frame), vs the same
  ``hough_line`` (frames/s);
* asynchronous: ``vmap`` of `spikejax.vision.hough.async_run` over distinct streams (each
  a different order and mirror image of the frames), vs the NumPy per-event
  loop of `spikejax.commands.bench_hough` (events/s).

Also timed: ``LineGrid(merge_pixels=True)`` (a slot's events summed per pixel
before voting) on the frames as they are (one event a pixel) and with every
event twice in its slot, checked to give the same accumulators.

``--baseline FILE`` adds the same rows for a one-file version of the Hough
module, as it was before it became the package `spikejax.vision.hough`
(``git show 575fe44:spikejax/vision/hough.py > /tmp/old_hough.py``), and
checks that it gives the same spikes and potentials. (The package's own fast
path is pinned to its readable Alg. 1, `spikejax.vision.hough.neuron`, by
``tests/test_hough.py``.)

Usage::

    .venv/bin/python benchmarks/hough_formulations.py --batch 64 --async-batch 256
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np
from skimage.transform import hough_line

from spikejax.benchmarking import JaxRun, interleaved, machine_banner
from spikejax.commands import bench_hough
from spikejax.vision import hough


def _load(path):
    spec = importlib.util.spec_from_file_location("hough_baseline", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules["hough_baseline"] = module
    spec.loader.exec_module(module)
    return module


def _distinct_streams(events, batch, n_slots):
    """``batch`` different streams of ``n_slots`` slots: rolled slots, mirrored in x and y."""

    def stream(i):
        e = jax.tree.map(lambda a: jnp.roll(a, i, axis=0)[:n_slots], events)
        if i % 2:
            e = e._replace(x=jnp.where(e.valid, 127 - e.x, e.x))
        if (i // 2) % 2:
            e = e._replace(y=jnp.where(e.valid, 127 - e.y, e.y))
        return e

    return jax.tree.map(lambda *a: jnp.stack(a), *[stream(i) for i in range(batch)])


def _rounds(cands, rounds, repeats):
    """Per round, the best seconds per unit of each candidate (interleaved), as ratios to the first candidate's."""
    ratios = {k: [] for k in cands}
    first = next(iter(cands))
    for _ in range(rounds):
        best = interleaved({k: JaxRun(fn) for k, (fn, _) in cands.items()}, repeats)
        per_unit = {k: best[k] / units for k, (_, units) in cands.items()}
        for k in cands:
            ratios[k].append(per_unit[first] / per_unit[k])
    return ratios


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, default=64, help="streams for the votes and sync rows")
    parser.add_argument("--async-batch", type=int, default=256, help="streams for the async rows")
    parser.add_argument("--async-slots", type=int, default=1, help="slots (frames) per async stream")
    parser.add_argument("--rounds", type=int, default=4)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--baseline", help="a one-file hough.py of an earlier version to compare with")
    args = parser.parse_args(argv)

    events, images = bench_hough.frames("line")
    n_slots = events.x.shape[0]
    thetas = hough.LineGrid().skimage_thetas()
    params = hough.hough_params(8.0, 50.0)
    times = jnp.arange(1, n_slots + 1, dtype=jnp.float32) * 0.01
    streams = jax.tree.map(lambda a: jnp.broadcast_to(a, (args.batch,) + a.shape), events)
    a_streams = _distinct_streams(events, args.async_batch, args.async_slots)
    a_events = float(a_streams.valid.sum())
    print(machine_banner())
    print(
        f"{float(events.count().mean()):.0f} events a frame; "
        f"sync batch {args.batch} x {n_slots} frames, async batch {args.async_batch} x {args.async_slots} frames"
    )

    sync_cands = {"skimage hough_line": (lambda: [hough_line(im, thetas) for im in images], len(images))}
    async_cands = {}
    merged = hough.LineGrid(merge_pixels=True)
    twice = jax.tree.map(lambda a: jnp.concatenate([a, a], axis=-1), streams)
    for label, data in (("", streams), (", every event twice", twice)):
        for g, name in ((hough.LineGrid(), "votes"), (merged, "votes, merge_pixels")):
            fn = jax.jit(jax.vmap(jax.vmap(lambda e, g=g: hough.line_votes(g, e))))
            sync_cands[f"{name}{label}"] = (lambda f=fn, d=data: f(d), args.batch * n_slots)
    modules = [("", hough)] + ([("baseline ", _load(args.baseline))] if args.baseline else [])
    fns = {}
    for label, mod in modules:
        grid = mod.LineGrid()
        votes = jax.jit(jax.vmap(jax.vmap(lambda e, mod=mod, grid=grid: mod.line_votes(grid, e))))
        sync = jax.jit(jax.vmap(lambda e, mod=mod, grid=grid: mod.sync_run(params, grid, e, times)))
        asyn = jax.jit(jax.vmap(lambda e, mod=mod, grid=grid: mod.async_run(params, grid, e)))
        fns[label] = (votes, sync, asyn)
        sync_cands[f"{label}votes only"] = (lambda f=votes: f(streams), args.batch * n_slots)
        sync_cands[f"{label}whole detector, sync"] = (lambda f=sync: f(streams), args.batch * n_slots)
        async_cands[f"{label}async"] = (lambda f=asyn: f(a_streams), a_events)
    t = time.perf_counter()
    for fn, _ in [*sync_cands.values(), *async_cands.values()]:
        jax.block_until_ready(fn())
    print(f"compiled and warmed up in {time.perf_counter() - t:.1f} s")
    if args.baseline:
        for i, (new, old) in enumerate(zip(fns[""], fns["baseline "])):
            arg = a_streams if i == 2 else streams
            same = [np.array_equal(a, b) for a, b in zip(jax.tree.leaves(new(arg)), jax.tree.leaves(old(arg)))]
            print(f"same results as the baseline ({['votes', 'sync', 'async'][i]}): {all(same)}")

    for label in ("", ", every event twice"):
        a, b = (np.asarray(sync_cands[f"{n}{label}"][0]()) for n in ("votes", "votes, merge_pixels"))
        print(f"merge_pixels gives the same accumulators{label}: {np.array_equal(a, b)}")
    ratios = _rounds(sync_cands, args.rounds, args.repeats)
    print(f"\n{'candidate':30s} {'ratio per round':27s} median")
    for k, r in ratios.items():
        print(f"{k:30s} {' '.join(f'{x:5.2f}' for x in r):27s} {np.median(r):5.2f} x skimage hough_line (frames/s)")

    # Async: each round times the NumPy per-event loop (one stream) once, then
    # the candidates (best of --repeats); events/s over all streams.
    rates = {k: [] for k in async_cands}
    loop = []
    numpy_loop = bench_hough._numpy_async(events)
    for _ in range(args.rounds):
        loop.append(numpy_loop.n_events / numpy_loop())
        for k, (fn, units) in async_cands.items():
            rates[k].append(units / min(JaxRun(fn)() for _ in range(args.repeats)))
    print(f"NumPy per-event loop: {np.median(loop) / 1e6:.3f} M events/s (median of {args.rounds})")
    for k, r in rates.items():
        ratio = [a / b for a, b in zip(r, loop)]
        print(
            f"{k:30s} {' '.join(f'{x:5.1f}' for x in ratio):27s} {np.median(ratio):5.1f} x the NumPy loop, "
            f"{np.median(r) / 1e6:.3f} M events/s"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
