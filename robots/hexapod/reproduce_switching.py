"""``spikejax reproduce gait-switching``: gait transitions of trained SCPGs, measured (the paper claims them seamless).

Runs ``sweeps/gait_switching.toml`` (`robots.hexapod.switching.switching_trial`)
and writes, in ``--out DIR``:

- ``gait_switching.csv``: per ordered pair of gaits, phase of the switch and
  policy (``carry``: the CPG's state carried over, as the paper's robot does;
  ``reset``: to rest at the switch), over the networks that converged: networks,
  how many reach the new gait's pattern within one cycle, that fraction with its
  95 % Wilson interval, the mean transient in steps, and how many never settle;
- ``gait_switching.png``: the within-one-cycle fractions as two heat maps (one
  per phase) for the carried-over state;
- ``sweeps/gait_switching/``: the sweep's table, from which a rerun resumes.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from robots.common import run_named_sweep, sweep_file, write_csv
from robots.hexapod.gaits import GAIT_NAMES, N_GAITS, PERIOD
from robots.hexapod.switching import PAIRS, field
from spikejax.commands import Command, add_common, output_directory
from spikejax.stats import wilson_interval

HEADER = [
    "from", "to", "phase", "policy", "networks", "within_one_cycle", "fraction", "ci_low", "ci_high",
    "mean_transient_steps", "never",
]  # fmt: skip


def summarize(table: dict[str, np.ndarray], settle_steps: int) -> list[list]:
    """One row per switch and policy, over the converged networks (the columns of `HEADER`)."""
    ok = table["converged"].astype(bool) & ~table["nonfinite"].astype(bool)
    rows = []
    for reset in (False, True):
        for a, b in PAIRS:
            for phase in range(PERIOD):
                steps = table[field(a, b, phase, reset)][ok]
                n, k = int(steps.size), int((steps <= PERIOD).sum())
                low, high = wilson_interval(k, n)
                settled = steps[steps < settle_steps]
                rows.append([
                    f"G{a + 1}", f"G{b + 1}", phase, "reset" if reset else "carry", n, k,
                    round(k / max(n, 1), 4), round(float(low), 4), round(float(high), 4),
                    round(float(settled.mean()), 3) if settled.size else "", int((steps >= settle_steps).sum()),
                ])  # fmt: skip
    return rows


def _plot(path: Path, rows: list[list]) -> None:
    fig = Figure(figsize=(9, 4))
    axes = fig.subplots(1, PERIOD)
    for phase, ax in enumerate(axes):
        grid = np.full((N_GAITS, N_GAITS), np.nan)
        for r in rows:
            if r[3] == "carry" and r[2] == phase:
                grid[int(r[0][1]) - 1, int(r[1][1]) - 1] = r[6]
        im = ax.imshow(grid, vmin=0, vmax=1, cmap="viridis")
        for (i, j), v in np.ndenumerate(grid):
            if np.isfinite(v):
                ax.text(j, i, f"{v:.0%}", ha="center", va="center", color="w" if v < 0.6 else "k")
        names = [n.split()[0] for n in GAIT_NAMES]
        ax.set_xticks(range(N_GAITS), names)
        ax.set_yticks(range(N_GAITS), names)
        ax.set_xlabel("to")
        ax.set_ylabel("from")
        ax.set_title(f"switched at phase {phase}", fontsize=10)
    fig.suptitle("the new gait's pattern within one cycle, the CPG's state carried over", fontsize=10)
    fig.colorbar(im, ax=axes, shrink=0.8, label="fraction of converged networks")
    fig.savefig(path, dpi=120)


def run(*, out: str | Path, trials: int | None = None, chunk_size: int | None = None, no_progress: bool = False) -> int:
    """``spikejax reproduce gait-switching --out DIR [--trials N]``: the files of the module docstring, and a table.

    Args:
        out: output directory.
        trials: seeds, one trained network each (default: the sweep file's 1,000).
        chunk_size: trials per compiled batch (default: the sweep file's).
        no_progress: hide the progress bar.
    """
    with output_directory(out, command="reproduce gait-switching") as out:
        table = run_named_sweep("gait_switching", out, trials=trials, chunk_size=chunk_size, progress=not no_progress)
        settle = tomllib.loads(sweep_file("gait_switching").read_text(encoding="utf-8"))["fixed"]["settle_cycles"]
        rows = summarize(table, settle * PERIOD)
        write_csv(out / "gait_switching.csv", HEADER, rows)
        _plot(out / "gait_switching.png", rows)
        n = rows[0][4]
        print(f"{n} converged networks of {table['converged'].size}; new pattern within one cycle, state carried over:")
        for r in rows:
            if r[3] == "carry":
                print(f"  {r[0]} -> {r[1]} at phase {r[2]}: {r[6]:.1%} [{r[7]:.1%}, {r[8]:.1%}], never {r[10]}")
        reset = [r for r in rows if r[3] == "reset"]
        print(f"state reset at the switch: the lowest fraction over the switches {min(r[6] for r in reset):.1%}")
        print(f"wrote {out / 'gait_switching.csv'} and {out / 'gait_switching.png'}")
        return 0


def _add_arguments(parser) -> None:
    add_common(parser, trials="seeds, one trained network each (default: 1000)", chunk_size=True)


command = Command(
    help="gait switching while walking: every pair of gaits at both phases, state carried over or reset",
    add_arguments=_add_arguments,
    run=run,
)
