"""Per-slot detection and false-positive rates of the pipe detector, with and without the judgment beyond Section 2.3.

Run: ``python benchmarks/pipe_detection_rates.py [--scenes N] [--size S] [--noise SD]``; prints a
Markdown table (docs/BENCHMARKS.md, "Pipe detection: false positives and detection rates").
Scenes: `spikejax.vision.scenes.random_view` (standing pipe only, entry only, horizon only), both
grids in the synchronous mode, one update per 20 ms frame, slots of 5 frames.
"""

import argparse
import dataclasses

from spikejax.vision import detect, hough, scenes
from spikejax.vision import pipe as pp

ROWS = ("paper", "paper+classify", "ours")


def _rates(params, kw, separate=False):
    """Both grids in one detector, or (``separate``) each grid in a detector of its own: no classification."""
    if not separate:
        return scenes.detection_rates(params=params, **kw)
    size = kw["size"]
    both = detect.Detector(
        line=hough.LineGrid(size, size, n_rho=int(size * 2**0.5) + 3),
        circle=hough.CircleGrid(size, size, n_r=size // 2),
        sub_slots=5,
    )
    lines = scenes.detection_rates(params=params, det=dataclasses.replace(both, circle=None), **kw)
    circles = scenes.detection_rates(params=params, det=dataclasses.replace(both, line=None), **kw)
    return {k: {**lines[k], "entry": circles[k]["entry"], "entry_in_view": circles[k]["entry_in_view"]} for k in lines}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=32)
    parser.add_argument("--size", type=int, default=128)
    parser.add_argument("--frames", type=int, default=31)
    parser.add_argument("--noise", type=float, default=0.02)
    parser.add_argument("--rows", nargs="+", choices=ROWS, default=list(ROWS))
    args = parser.parse_args(argv)
    kw = dict(n_scenes=args.scenes, size=args.size, n_frames=args.frames, noise=args.noise)
    v_th = 0.5 * args.size
    paper = detect.detector_params(v_th=v_th, body=pp.BodyParams(), entry=pp.EntryParams())
    rows = {
        "paper": ("Section 2.3's conditions, each grid alone", paper, True),
        "paper+classify": ("Section 2.3's conditions, both grids, one kind per object", paper, False),
        "ours": ("upright and drawn edges, drawn rings, one kind per object", detect.detector_params(v_th=v_th), False),
    }
    print(f"{args.scenes} scenes per kind, {args.size}x{args.size}, noise {args.noise}, {args.frames - 1} frames")
    print(
        "| detector | standing: body (in view) | standing: entry | entry: entry (in view) | entry: body | horizon: body | horizon: entry |"
    )
    print("|---|---|---|---|---|---|---|")
    for row in args.rows:
        name, params, separate = rows[row]
        r = _rates(params, kw, separate)
        s, e, h = r["standing"], r["lying"], r["empty"]
        print(
            f"| {name} | {s['body_in_view']:.1%} ({s['in_view']} slots) | {s['entry']:.1%} | "
            f"{e['entry_in_view']:.1%} ({e['in_view']} slots) | {e['body']:.1%} | {h['body']:.1%} | {h['entry']:.1%} |"
        )


if __name__ == "__main__":
    main()
