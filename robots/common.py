"""Plumbing the robots' reproductions share: named sweep files, CSV tables.

A benchmark's plumbing (isolated runs, timing, tables) is `spikejax.benchmarking`.
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

import numpy as np

from spikejax.errors import UserError
from spikejax.sweep import load_sweep, read_results, run_sweep

SWEEPS = Path(__file__).resolve().parents[1] / "sweeps"


def run_named_sweep(name: str, out: Path, args: argparse.Namespace) -> dict[str, np.ndarray]:
    """Run (or resume) ``sweeps/NAME.toml`` into ``out/sweeps/NAME`` and return its table.

    ``args`` carries the CLI's ``trials``, ``chunk_size`` and ``no_progress``.
    """
    path = SWEEPS / f"{name}.toml"
    if not path.exists():
        raise UserError(f"sweep file {path} not found (install spikejax from its source tree: pip install -e .)")
    spec = load_sweep(path, seeds=args.trials, chunk_size=args.chunk_size)
    run_sweep(spec, out / "sweeps" / name, progress=not args.no_progress)
    return read_results(out / "sweeps" / name)


def write_csv(path: Path, header: list[str], rows: list[list]) -> None:
    """Write a table atomically (a temporary file renamed into place)."""
    tmp = path.with_suffix(path.suffix + ".tmp")
    with open(tmp, "w", newline="") as file:
        writer = csv.writer(file)
        writer.writerow(header)
        writer.writerows(rows)
    tmp.replace(path)
