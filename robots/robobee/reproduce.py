"""``spikejax reproduce robobee`` and ``robobee-learning``: Figs. 8-11 of the RoboBee SNN paper and beyond.

``robobee`` runs ``sweeps/robobee_flights.toml`` (both flights, SNN and LQR,
256 network seeds each) and writes, in ``--out DIR``:

- ``robobee.csv``: per flight and controller, over the seeds: flights, the
  fraction that reached both waypoints and stayed upright, the RMS of the SNN's
  minus the LQR's control (median, 10th and 90th percentiles), the final
  distance to each waypoint and the settling time (medians), the largest tilt;
- ``robobee_flight1.png`` (Figs. 8-10: trajectories of SNN and LQR overlaid,
  the control error over time, SNN and LQR outputs with theta and x below) and
  ``robobee_flight2.png`` (Fig. 11, the landing), for seed 0;
- ``robobee_seeds.png``: the distributions over seeds.

``robobee-learning`` runs ``sweeps/robobee_learning.toml`` and writes
``robobee_learning.csv`` and ``robobee_learning.png``, the success rate over
``mu`` and ``tau`` with randomised robots; ``robobee-populations`` runs
``sweeps/robobee_populations.toml`` and writes ``robobee_populations.csv`` and
``.png``, the success rate over the input and hidden population sizes.
"""

from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from matplotlib.figure import Figure

from robots.common import run_named_sweep, write_csv
from robots.robobee.controller import ControllerConfig, controller_params
from robots.robobee.lqr import altitude_params
from robots.robobee.params import robobee_params
from spikejax.commands import Command, add_common, output_directory
from spikejax.stats import wilson_interval
from spikejax.sweep import trial_key

FLIGHTS = {0: "flight 1 (q0 -> q1 -> q2)", 1: "flight 2 (landing)"}


def flight_rows(table: dict[str, np.ndarray]) -> list[list]:
    """One row per flight and controller (see the module docstring)."""
    rows = []
    for landing in (0, 1):
        for use_snn in (1, 0):
            m = (table["landing"] == landing) & (table["use_snn"] == use_snn)
            n, k = int(m.sum()), int(table["reached"][m].sum())
            low, high = wilson_interval(k, n)
            rms = table["rms_error"][m]
            med = lambda c: float(np.median(table[c][m]))  # noqa: E731
            rows.append(
                [
                    FLIGHTS[landing],
                    "SNN" if use_snn else "LQR",
                    n,
                    round(k / n, 4),
                    round(float(low), 4),
                    round(float(high), 4),
                    round(float(np.median(rms)), 4),
                    round(float(np.percentile(rms, 10)), 4),
                    round(float(np.percentile(rms, 90)), 4),
                    round(med("error_1") * 1e3, 3),
                    round(med("error_2") * 1e3, 3),
                    round(med("settle_1"), 3),
                    round(med("settle_2"), 3),
                    round(float(np.max(table["max_theta"][m])), 3),
                ]
            )
    return rows


HEADER = [
    "flight",
    "controller",
    "flights",
    "reached",
    "ci_low",
    "ci_high",
    "rms_control_error_median",
    "rms_control_error_p10",
    "rms_control_error_p90",
    "error_1_mm",
    "error_2_mm",
    "settle_1_s",
    "settle_2_s",
    "max_theta_rad",
]


def _replay(landing: int, seed: int = 0):
    """Seed ``seed``'s flight with the SNN and the LQR steering, fully recorded."""
    # Imported here: the flight's physics is MJX, and `spikejax reproduce` imports this module to
    # list its flags beside the other reproductions'.
    from robots.robobee.flight import flight_plan, fly
    from robots.robobee.trial import nominal_gain

    robot = robobee_params()
    plan = flight_plan("landing" if landing else "waypoints")
    key_net, _ = jax.random.split(trial_key(0, seed))
    run = jax.jit(
        lambda use: fly(
            ControllerConfig(),
            controller_params(),
            robot,
            jnp.asarray(nominal_gain()),
            altitude_params(),
            plan,
            use,
            key=key_net,
        )
    )
    return plan, jax.device_get(run(True)), jax.device_get(run(False))


def _plot_flight(path: Path, landing: int, plan, snn, lqr) -> None:
    fig = Figure(figsize=(12, 8), layout="constrained")
    grid = fig.add_gridspec(3, 2)
    ax = fig.add_subplot(grid[:, 0])
    ax.plot(lqr.q[:, 2] * 100, lqr.q[:, 3] * 100, "k--", lw=1.5, label="LQR")
    ax.plot(snn.q[:, 2] * 100, snn.q[:, 3] * 100, "tab:blue", lw=1.2, label="SNN (learning online)")
    for i, q in enumerate([plan.q0, *plan.waypoints]):
        ax.plot(q[2] * 100, q[3] * 100, "o" if i else "s", color="tab:red", ms=7)
        ax.annotate(f"q{i}", (q[2] * 100, q[3] * 100), textcoords="offset points", xytext=(6, 6))
    if landing:
        ax.axhline(0, color="0.4", lw=2)
    ax.set_xlabel("x (cm)")
    ax.set_ylabel("z (cm)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_title(f"{FLIGHTS[landing]}: trajectories (cf. Fig. {11 if landing else 8})")
    ax.legend()
    t = snn.t
    bx = fig.add_subplot(grid[0, 1])
    bx.plot(t, snn.y_lqr - snn.y_hat, lw=0.6)
    bx.set_ylabel("LQR - SNN (uN m)")
    bx.set_title("control error (cf. Fig. 9)")
    cx = fig.add_subplot(grid[1, 1], sharex=bx)
    cx.plot(t, snn.y_hat, lw=0.6, label="SNN y_hat")
    cx.plot(t, snn.y_lqr, "k", lw=1, label="LQR y")
    cx.set_ylabel("tau_c (uN m)")
    cx.legend(fontsize=8)
    cx.set_title("lateral control (cf. Fig. 10)")
    dx = fig.add_subplot(grid[2, 1], sharex=bx)
    dx.plot(t, snn.q[:, 0], label="theta (rad)")
    dx.plot(t, snn.q[:, 2] * 10, label="x (dm)")
    dx.set_xlabel("t (s)")
    dx.legend(fontsize=8)
    for a in (bx, cx, dx):
        a.axvline(0.5, color="0.6", lw=0.8, ls=":")
        a.axvline(1.5, color="0.6", lw=0.8, ls=":")
    fig.savefig(path, dpi=110)


def _plot_seeds(path: Path, table: dict[str, np.ndarray]) -> None:
    fig = Figure(figsize=(12, 3.6), layout="constrained")
    axes = fig.subplots(1, 3)
    for landing in (0, 1):
        m = (table["landing"] == landing) & (table["use_snn"] == 1)
        axes[0].hist(table["rms_error"][m], bins=30, alpha=0.6, label=FLIGHTS[landing])
        axes[1].hist(np.maximum(table["error_1"][m], table["error_2"][m]) * 1e3, bins=30, alpha=0.6)
        axes[2].hist(table["max_theta"][m], bins=30, alpha=0.6)
    axes[0].set_xlabel("RMS of SNN - LQR control (uN m)")
    axes[0].legend(fontsize=8)
    axes[1].set_xlabel("worst final distance to a waypoint (mm)")
    axes[2].set_xlabel("largest |theta| (rad)")
    for a in axes:
        a.set_ylabel("network seeds")
    fig.suptitle(f"SNN flights over {int(((table['use_snn'] == 1) & (table['landing'] == 0)).sum())} network seeds")
    fig.savefig(path, dpi=110)


def _add_arguments(parser) -> None:
    add_common(parser, trials="seeds per condition (default: the sweep file's)", chunk_size=True)


def run_flights(
    *, out: str | Path, trials: int | None = None, chunk_size: int | None = None, no_progress: bool = False
) -> int:
    """``spikejax reproduce robobee --out DIR [--trials N]``: the files of the module docstring, and a table.

    Args:
        out: output directory.
        trials: network seeds per flight and controller (default: the sweep file's).
        chunk_size: flights per compiled batch (default: the sweep file's).
        no_progress: hide the progress bar.
    """
    with output_directory(
        out, command="reproduce robobee", shared_with=("reproduce robobee-learning", "reproduce robobee-populations")
    ) as out:
        table = run_named_sweep("robobee_flights", out, trials=trials, chunk_size=chunk_size, progress=not no_progress)
        rows = flight_rows(table)
        write_csv(out / "robobee.csv", HEADER, rows)
        for landing in (0, 1):
            plan, snn, lqr = _replay(landing)
            _plot_flight(out / f"robobee_flight{landing + 1}.png", landing, plan, snn, lqr)
        _plot_seeds(out / "robobee_seeds.png", table)
        print(f"{'flight':<28}{'ctrl':<6}{'reached':>22}{'rms err':>9}{'err1 mm':>9}{'err2 mm':>9}{'settle1':>9}")
        for r in rows:
            print(
                f"{r[0]:<28}{r[1]:<6}{r[3]:>8.1%} [{r[4]:.1%}, {r[5]:.1%}]{r[6]:>9.3f}{r[9]:>9.2f}{r[10]:>9.2f}{r[11]:>9.2f}"
            )
        print(f"wrote {out / 'robobee.csv'} and figures in {out}")
        return 0


def _success_map(
    out: Path,
    name: str,
    table: dict[str, np.ndarray],
    rows_axis: str,
    cols_axis: str,
    labels: tuple[str, str],
    title: str,
    fmt=("{:g}".format, "{:g}".format),
) -> list[list]:
    """Success rate over two grid axes: ``out/NAME.csv`` (Wilson intervals) and ``out/NAME.png``."""
    row_values, col_values = np.unique(table[rows_axis]), np.unique(table[cols_axis])
    rows, grid = [], np.zeros((len(row_values), len(col_values)))
    for i, rv in enumerate(row_values):
        for j, cv in enumerate(col_values):
            m = (table[rows_axis] == rv) & (table[cols_axis] == cv)
            n, k = int(m.sum()), int(table["reached"][m].sum())
            low, high = wilson_interval(k, n)
            grid[i, j] = k / n
            rows.append(
                [
                    rv.item(),
                    cv.item(),
                    n,
                    k,
                    round(k / n, 4),
                    round(float(low), 4),
                    round(float(high), 4),
                    round(float(np.median(table["rms_error"][m])), 4),
                ]
            )
    write_csv(
        out / f"{name}.csv",
        [rows_axis, cols_axis, "flights", "reached", "fraction", "ci_low", "ci_high", "rms_control_error_median"],
        rows,
    )
    fig = Figure(figsize=(5.5, 4.2), layout="constrained")
    ax = fig.subplots()
    im = ax.imshow(100 * grid, vmin=0, vmax=100, cmap="viridis", origin="lower")
    for (i, j), v in np.ndenumerate(grid):
        ax.text(j, i, f"{100 * v:.0f}", ha="center", va="center", color="w" if v < 0.6 else "k")
    ax.set_xticks(range(len(col_values)), [fmt[1](v) for v in col_values])
    ax.set_yticks(range(len(row_values)), [fmt[0](v) for v in row_values])
    ax.set_ylabel(labels[0])
    ax.set_xlabel(labels[1])
    ax.set_title(f"{title}\n{rows[0][2]} flights per cell", fontsize=9)
    fig.colorbar(im, ax=ax)
    fig.savefig(out / f"{name}.png", dpi=110)
    for r in rows:
        print(f"{rows_axis}={r[0]:g} {cols_axis}={r[1]:g}: {r[4]:.1%} [{r[5]:.1%}, {r[6]:.1%}] of {r[2]}")
    print(f"wrote {out / (name + '.csv')} and {out / (name + '.png')}")
    return rows


def run_learning(
    *, out: str | Path, trials: int | None = None, chunk_size: int | None = None, no_progress: bool = False
) -> int:
    """``spikejax reproduce robobee-learning --out DIR [--trials N]``: success over mu and tau.

    Args:
        out: output directory.
        trials: seeds (randomised robots) per grid point (default: the sweep file's).
        chunk_size: flights per compiled batch (default: the sweep file's).
        no_progress: hide the progress bar.
    """
    with output_directory(
        out, command="reproduce robobee-learning", shared_with=("reproduce robobee", "reproduce robobee-populations")
    ) as out:
        table = run_named_sweep("robobee_learning", out, trials=trials, chunk_size=chunk_size, progress=not no_progress)
        _success_map(
            out,
            "robobee_learning",
            table,
            "mu",
            "tau_reward",
            ("learning rate mu", "reward time constant tau (ms)"),
            "flight 1, robots +-20 %: both waypoints reached (%)",
            ("{:g}".format, lambda tau: f"{1e3 * tau:g}"),
        )
        return 0


def run_populations(
    *, out: str | Path, trials: int | None = None, chunk_size: int | None = None, no_progress: bool = False
) -> int:
    """``spikejax reproduce robobee-populations --out DIR [--trials N]``: success over the layer sizes.

    Args:
        out: output directory.
        trials: seeds (randomised robots) per grid point (default: the sweep file's).
        chunk_size: flights per compiled batch (default: the sweep file's).
        no_progress: hide the progress bar.
    """
    with output_directory(
        out, command="reproduce robobee-populations", shared_with=("reproduce robobee", "reproduce robobee-learning")
    ) as out:
        table = run_named_sweep(
            "robobee_populations", out, trials=trials, chunk_size=chunk_size, progress=not no_progress
        )
        _success_map(
            out,
            "robobee_populations",
            table,
            "n_per_input",
            "n_hidden",
            ("input neurons per state variable", "hidden neurons"),
            "flight 1, robots +-20 %, 50 output neurons: both waypoints reached (%)",
        )
        return 0


flights_command = Command(
    help="RoboBee flights 1 and 2 with the SNN and the LQR, Figs. 8-11 of the RoboBee SNN paper",
    add_arguments=_add_arguments,
    run=run_flights,
)
learning_command = Command(
    help="RoboBee success over the learning rate mu and the reward time constant tau, robots randomised",
    add_arguments=_add_arguments,
    run=run_learning,
)
populations_command = Command(
    help="RoboBee success over the input and hidden population sizes, robots randomised",
    add_arguments=_add_arguments,
    run=run_populations,
)
