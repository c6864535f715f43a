"""Plumbing the robots' reproductions share: named sweep files, CSV tables, saved weights files.

A benchmark's plumbing (isolated runs, timing, tables) is `spikejax.benchmarking`.
"""

from __future__ import annotations

import csv
from importlib import resources
from importlib.resources.abc import Traversable
from pathlib import Path

import numpy as np

from spikejax.errors import UserError
from spikejax.files import atomic_file
from spikejax.sweep import load_sweep, read_results, run_sweep

# The sweep files of the reproductions, shipped as package data of ``robots``
# (``sweeps/`` of the repository; see pyproject.toml), so that an installed
# wheel finds them as a source checkout does.
SWEEPS: Traversable = resources.files("robots") / "sweeps"


def sweep_file(name: str) -> Traversable:
    """The shipped sweep file ``NAME.toml`` (a UserError if there is none)."""
    file = SWEEPS / f"{name}.toml"
    if not file.is_file():
        raise UserError(f"no sweep file {name}.toml among the package data of robots ({SWEEPS})")
    return file


def run_named_sweep(
    name: str, out: Path, *, trials: int | None = None, chunk_size: int | None = None, progress: bool = True
) -> dict[str, np.ndarray]:
    """Run (or resume) the shipped sweep ``NAME.toml`` into ``out/sweeps/NAME`` and return its table.

    Args:
        name: the sweep file's name without ``.toml`` (``gait_convergence``).
        out: the reproduction's output directory.
        trials: seeds per condition (default: the sweep file's).
        chunk_size: trials per compiled batch (default: the sweep file's).
        progress: show a progress bar.
    """
    with resources.as_file(sweep_file(name)) as path:
        spec = load_sweep(path, seeds=trials, chunk_size=chunk_size)
        run_sweep(spec, out / "sweeps" / name, progress=progress)
    return read_results(out / "sweeps" / name)


def write_csv(path: Path, header: list[str], rows: list[list]) -> None:
    """Write a table atomically (a temporary file renamed into place)."""
    tmp = path.with_suffix(path.suffix + ".tmp")
    with open(tmp, "w", newline="") as file:
        writer = csv.writer(file)
        writer.writerow(header)
        writer.writerows(rows)
    tmp.replace(path)


def save_weights_file(path, robot: str, **arrays) -> Path:
    """``arrays`` and the tag ``robot`` as one ``.npz`` file, written whole or not at all; returns the path."""
    path = Path(path)
    with atomic_file(path) as file:
        np.savez(file, robot=robot, **arrays)
    return path


def load_weights_file(path, robot: str, what: str) -> dict:
    """The arrays of a `save_weights_file` file tagged ``robot``; a one-line error naming ``what`` if it is not one."""
    try:
        with np.load(path) as z:
            if str(z["robot"]) != robot:
                raise KeyError("robot")
            return {k: z[k] for k in z.files}
    except (OSError, KeyError, ValueError) as e:
        raise UserError(f"{path}: not {what} ({e.__class__.__name__})") from None
