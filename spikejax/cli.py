"""The ``spikejax`` command: ``reproduce``, ``sweep``, ``bench``, ``detect`` and ``info``.

The CLI sits on top of the library and the robots: reproductions, benchmarks
and detectors are named here by import path and imported only when asked for, so that
``spikejax`` itself never imports ``robots``.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from spikejax.errors import UserError

# name -> "module:function"; each function takes the parsed argparse.Namespace.
REPRODUCTIONS = {
    "gaits": "robots.hexapod.reproduce:main",
    "gait-choices": "robots.hexapod.reproduce:main_choices",
    "robobee": "robots.robobee.reproduce:main",
    "robobee-learning": "robots.robobee.reproduce:main_learning",
    "snake-gait": "robots.snake.reproduce:main",
    "robobee-populations": "robots.robobee.reproduce:main_populations",
}
# ``spikejax detect TARGET FILE``: "module:function".
DETECTORS = {
    "pipe": "spikejax.vision.detect:main",
}
BENCHMARKS = {
    "gaits": "robots.hexapod.bench:main",
    "robobee-network": "robots.robobee.bench_network:main_network",
    "robobee": "robots.robobee.bench:main",
    "hough": "spikejax.vision.bench_hough:main",
    "snake": "robots.snake.bench:main",
}


def _load(path: str):
    module_name, _, attr = path.partition(":")
    return getattr(importlib.import_module(module_name), attr)


def _build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="spikejax", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)

    rep = sub.add_parser("reproduce", help="reproduce a paper's result (table + figure)")
    rep.add_argument("target", choices=sorted(REPRODUCTIONS))
    rep.add_argument("--out", required=True, help="output directory")
    rep.add_argument("--trials", type=int, default=None, help="seeds per condition (default: the sweep file's)")
    rep.add_argument("--chunk-size", type=int, default=None, help="trials per compiled batch")
    rep.add_argument("--no-progress", action="store_true", help="hide the progress bar")

    sw = sub.add_parser("sweep", help="run a sweep file (TOML); resumes where it stopped")
    sw.add_argument("file", help="sweep file (TOML)")
    sw.add_argument("--out", required=True, help="output directory (results table + metadata)")
    sw.add_argument("--chunk-size", type=int, default=None, help="trials per compiled batch")
    sw.add_argument("--seeds", type=int, default=None, help="override the number of seeds")
    sw.add_argument("--cpu-devices", type=int, default=None,
                    help="present the CPU as N devices and split each chunk over them (default: JAX's devices as they are)")
    sw.add_argument("--no-progress", action="store_true", help="hide the progress bar")

    be = sub.add_parser("bench", help="measure speed against the peers (compile time apart)")
    be.add_argument("target", choices=sorted(BENCHMARKS))
    be.add_argument("--trials", type=int, default=None, help="trials to time")
    be.add_argument("--out", default=None, help="write the figures as CSV here")
    be.add_argument("--quick", action="store_true", help="a short run at small sizes (snake)")
    be.add_argument("--cpu-devices", type=int, default=None,
                    help="CPU devices JAX presents (hough, robobee; default: one per core, the batch split over them)")
    be.add_argument("--no-progress", action="store_true", help="hide the progress bar")

    det = sub.add_parser("detect", help="detect shapes in an event recording")
    det_sub = det.add_subparsers(dest="target", required=True)
    pipe = det_sub.add_parser("pipe", help="pipe bodies and entries (spiking Hough, Alg. 2-3 of the pipe paper)")
    pipe.add_argument("file", help="event recording: .npz, .npy (structured array x, y, t, p) or .aedat4")
    pipe.add_argument("--mode", choices=("sync", "async"), default="sync", help="slots at once (default) or event by event")
    pipe.add_argument("--out", default=None, help="write detections.csv and overlay.png here")
    pipe.add_argument("--slot", type=float, default=0.02, help="time slot, s (default 0.02)")
    pipe.add_argument("--sub-slots", type=int, default=5, help="updates per slot; a neuron fires at most once per update")
    pipe.add_argument("--capacity", type=int, default=4096, help="events per update (the rest are counted)")
    pipe.add_argument("--sensor-size", type=int, nargs=2, metavar=("W", "H"), default=None, help="default: the file's, else 128 128")
    pipe.add_argument("--shapes", choices=("both", "lines", "circles"), default="both", help="bodies (lines), entries (circles)")
    pipe.add_argument("--v-th", type=float, default=None, help="Hough neuron threshold, votes (default: half the sensor height)")
    pipe.add_argument("--decay", type=float, default=50.0, help="decay rate lambda of Alg. 1, votes/s")
    pipe.add_argument("--fov", type=float, default=60.0, help="horizontal field of view, degrees")
    pipe.add_argument("--pipe-size", type=float, default=0.0, help="pipe diameter, m, if known (distance by Eq. 8)")
    pipe.add_argument("--speed", type=float, default=0.0, help="forward speed, m/s (distance by Eq. 9 otherwise)")
    pipe.add_argument("--no-progress", action="store_true", help="hide the progress bar")

    sub.add_parser("info", help="versions and devices")
    return parser


def _info(_: argparse.Namespace) -> int:
    import jax

    import spikejax

    print(f"spikejax {spikejax.__version__}")
    print(f"jax {jax.__version__}, devices: {', '.join(str(d) for d in jax.devices())}")
    return 0


def main(argv: list[str] | None = None) -> int:
    args = _build_parser().parse_args(argv)
    try:
        if args.command == "info":
            return _info(args)
        if args.command == "sweep":
            from spikejax import sweep

            return sweep.main(args)
        if args.command == "detect":
            return int(_load(DETECTORS[args.target])(args) or 0)
        registry = REPRODUCTIONS if args.command == "reproduce" else BENCHMARKS
        return int(_load(registry[args.target])(args) or 0)
    except UserError as err:
        print(f"spikejax {args.command}: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"spikejax {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
