"""The ``spikejax`` command: ``reproduce``, ``sweep``, ``bench`` and ``info``.

The CLI sits on top of the library and the robots: reproductions and benchmarks
are named here by import path and imported only when asked for, so that
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
    "robobee-populations": "robots.robobee.reproduce:main_populations",
}
BENCHMARKS = {
    "gaits": "robots.hexapod.bench:main",
    "robobee-network": "robots.robobee.bench_network:main_network",
    "robobee": "robots.robobee.bench:main",
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
    sw.add_argument("--no-progress", action="store_true", help="hide the progress bar")

    be = sub.add_parser("bench", help="measure speed against the peers (compile time apart)")
    be.add_argument("target", choices=sorted(BENCHMARKS))
    be.add_argument("--trials", type=int, default=None, help="trials to time")
    be.add_argument("--out", default=None, help="write the figures as CSV here")

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
