"""``spikejax reproduce gaits`` and ``gait-choices``: Fig. 4 of the hexapod SCPG paper and beyond.

``gaits`` runs ``sweeps/gait_convergence.toml`` (and the same study with the
gaits trained one after the other, ``sweeps/gait_convergence_blocked.toml``) and
writes, in ``--out DIR``:

- ``gait_convergence.csv``: n_gaits, trials, converged, fraction, ci_low, ci_high
  (95 % Wilson interval), for the default (interleaved) schedule;
- ``gait_convergence_blocked.csv``: the same for the blocked schedule;
- ``gait_convergence_budget.csv``: the fraction converged within each training budget;
- ``gait_convergence.png``: our bars with their intervals beside the paper's, and
  convergence against the training budget;
- ``sweeps/``: the sweeps' own result tables, from which a rerun resumes.

``gait-choices`` runs ``sweeps/gait_choices.toml`` and writes ``gait_choices.csv``
and ``gait_choices.png``, a heat map of three-gait convergence over the decay
factor, the initial weight range and the update scale.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from robots.common import run_named_sweep, sweep_file, write_csv
from spikejax.commands import Command, add_common, output_directory
from spikejax.stats import wilson_interval

# Fig. 4 and Sec. III-C: "> 80 %" for one and two gaits, "~ 20 %" for three (100 trials each).
PAPER = {1: (0.80, ">"), 2: (0.80, ">"), 3: (0.20, "~")}
BUDGETS = (30, 45, 60, 90, 120, 150, 180, 240, 300, 450, 600)
# A training budget shared by the gaits that comes closest to the paper's three values.
PAPER_LIKE_BUDGET = 150


def _fixed(name: str) -> dict:
    return tomllib.loads(sweep_file(name).read_text(encoding="utf-8")).get("fixed", {})


def summarize(table: dict[str, np.ndarray], by: list[str]) -> list[list]:
    """One row per distinct value of the ``by`` columns: values, trials, converged, fraction, ci_low, ci_high."""
    keys = np.stack([table[b] for b in by], axis=1)
    rows = []
    for point in np.unique(keys, axis=0):
        mask = np.all(keys == point, axis=1)
        n, k = int(mask.sum()), int(table["converged"][mask].sum())
        low, high = wilson_interval(k, n)
        rows.append([*(v.item() for v in point), n, k, round(k / n, 4), round(float(low), 4), round(float(high), 4)])
    return rows


def budget_curve(table: dict[str, np.ndarray], max_epochs: int, budgets=BUDGETS) -> list[list]:
    """Fraction of trials converged within a fixed training budget, per number of gaits.

    The budget counts presentations (one gait, ``train_cycles`` cycles from rest)
    shared by all the gaits being programmed: ``budget // n_gaits`` epochs. Training
    stops at the first error-free epoch and never changes afterwards, so a trial
    that converged after ``e`` epochs converges under any budget of ``>= e``
    epochs and under no smaller one. Budgets beyond the sweep's ``max_epochs``
    are left out.
    """
    rows = []
    for n_gaits in np.unique(table["n_gaits"]):
        mask = table["n_gaits"] == n_gaits
        for b in budgets:
            epochs = b // int(n_gaits)
            if epochs > max_epochs:
                continue
            ok = table["converged"][mask] & (table["epochs"][mask] <= epochs)
            rows.append([int(n_gaits), b, epochs, int(mask.sum()), round(float(ok.mean()), 4)])
    return rows


def _plot_gaits(path: Path, ours: list[list], blocked: list[list], budget: list[list]) -> None:
    fig = Figure(figsize=(11, 4.8))
    ax, bx = fig.subplots(1, 2)
    x = np.arange(len(ours))
    width = 0.27
    for offset, rows, label, color in (
        (-width, ours, "spikejax, interleaved (default)", "tab:blue"),
        (0.0, blocked, "spikejax, blocked (Alg. 1 loops as written)", "tab:orange"),
    ):
        frac = np.array([r[3] for r in rows])
        err = np.array([[r[3] - r[4] for r in rows], [r[5] - r[3] for r in rows]])
        ax.bar(x + offset, 100 * frac, width, yerr=100 * err, capsize=3, color=color, label=f"{label}, n={rows[0][1]}")
    paper = [PAPER[int(r[0])] for r in ours]
    ax.bar(
        x + width,
        [100 * p for p, _ in paper],
        width,
        color="0.8",
        hatch="//",
        edgecolor="0.4",
        label="paper, Fig. 4 (n=100)",
    )
    for xi, (p, rel) in zip(x, paper):
        ax.text(xi + width, 100 * p + 2, f"{rel}{100 * p:.0f}", ha="center", fontsize=8)
    ax.set_xticks(x, ["G1", "G1+G2", "G1+G2+G3"])
    ax.set_ylabel("trials converged (%)")
    ax.set_ylim(0, 112)
    ax.set_title("Gait convergence, 95 % Wilson intervals")
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.1))

    colors = {1: "tab:green", 2: "tab:purple", 3: "tab:red"}
    for n_gaits in sorted({r[0] for r in budget}):
        rows = [r for r in budget if r[0] == n_gaits]
        bx.plot(
            [r[1] for r in rows],
            [100 * r[4] for r in rows],
            "o-",
            color=colors[n_gaits],
            label=f"{n_gaits} gait{'s' if n_gaits > 1 else ''}",
        )
        bx.axhline(100 * PAPER[n_gaits][0], color=colors[n_gaits], ls="--", lw=0.8)
    bx.axvline(PAPER_LIKE_BUDGET, color="0.5", lw=0.8, ls=":")
    bx.set_xscale("log")
    bx.set_xticks(BUDGETS, [str(b) for b in BUDGETS], fontsize=8)
    bx.minorticks_off()
    bx.set_xlabel("training budget shared by the gaits (presentations)")
    bx.set_ylabel("trials converged within budget (%)")
    bx.set_title("Interleaved schedule; dashed: the paper's values", fontsize=10)
    bx.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def _add_arguments(parser) -> None:
    add_common(parser, trials="seeds per condition (default: the sweep file's)", chunk_size=True)


def run_gaits(
    *, out: str | Path, trials: int | None = None, chunk_size: int | None = None, no_progress: bool = False
) -> int:
    """``spikejax reproduce gaits --out DIR [--trials N]``: the files of the module docstring, and a table.

    Args:
        out: output directory.
        trials: seeds per number of gaits (default: the sweep files').
        chunk_size: trials per compiled batch (default: the sweep files').
        no_progress: hide the progress bars.
    """
    with output_directory(out, command="reproduce gaits", shared_with=("reproduce gait-choices",)) as out:
        sweep = dict(trials=trials, chunk_size=chunk_size, progress=not no_progress)
        header = ["n_gaits", "trials", "converged", "fraction", "ci_low", "ci_high"]
        table = run_named_sweep("gait_convergence", out, **sweep)
        ours = summarize(table, ["n_gaits"])
        write_csv(out / "gait_convergence.csv", header, ours)
        blocked = summarize(run_named_sweep("gait_convergence_blocked", out, **sweep), ["n_gaits"])
        write_csv(out / "gait_convergence_blocked.csv", header, blocked)
        budget = budget_curve(table, _fixed("gait_convergence")["max_epochs"])
        write_csv(
            out / "gait_convergence_budget.csv", ["n_gaits", "presentations", "epochs", "trials", "fraction"], budget
        )
        _plot_gaits(out / "gait_convergence.png", ours, blocked, budget)

        print(f"{'gaits':<10}{'interleaved':>22}{'blocked':>22}{'paper':>10}")
        for r, b in zip(ours, blocked):
            p, rel = PAPER[int(r[0])]
            print(
                f"{r[0]:<10}{r[3]:>8.1%} [{r[4]:.1%}, {r[5]:.1%}]{b[3]:>8.1%} [{b[4]:.1%}, {b[5]:.1%}]{rel:>6}{p:.0%}"
            )
        paper_like = {r[0]: r[4] for r in budget if r[1] == PAPER_LIKE_BUDGET}
        print(
            f"within a shared budget of {PAPER_LIKE_BUDGET} presentations: "
            + ", ".join(f"{n} gait(s) {f:.1%}" for n, f in paper_like.items())
        )
        print(f"wrote {out / 'gait_convergence.csv'} and {out / 'gait_convergence.png'}")
        return 0


def _plot_choices(path: Path, table: dict[str, np.ndarray], budgets: tuple[int, ...]) -> None:
    alphas, w_highs, lrs = (np.unique(table[k]) for k in ("alpha", "w_high", "lr"))
    fig = Figure(figsize=(4.2 * len(w_highs) + 1, 3.6 * len(budgets)), layout="constrained")
    axes = fig.subplots(len(budgets), len(w_highs), squeeze=False)
    for i, budget in enumerate(budgets):
        for j, w_high in enumerate(w_highs):
            grid = np.zeros((len(alphas), len(lrs)))
            for a, alpha in enumerate(alphas):
                for l, lr in enumerate(lrs):
                    m = (table["alpha"] == alpha) & (table["w_high"] == w_high) & (table["lr"] == lr)
                    grid[a, l] = np.mean(table["converged"][m] & (table["epochs"][m] <= budget))
            ax = axes[i, j]
            im = ax.imshow(100 * grid, vmin=0, vmax=100, cmap="viridis", origin="lower", aspect="auto")
            for a in range(len(alphas)):
                for l in range(len(lrs)):
                    ax.text(
                        l,
                        a,
                        f"{100 * grid[a, l]:.0f}",
                        ha="center",
                        va="center",
                        fontsize=7,
                        color="w" if grid[a, l] < 0.6 else "k",
                    )
            ax.set_xticks(range(len(lrs)), [f"{v:g}" for v in lrs])
            ax.set_yticks(range(len(alphas)), [f"{v:g}" for v in alphas])
            if i == len(budgets) - 1:
                ax.set_xlabel("update scale eta / V_th")
            if j == 0:
                ax.set_ylabel("decay factor alpha")
            ax.set_title(f"init U(0, {w_high:g} V_th), budget {budget} epochs ({3 * budget} presentations)", fontsize=9)
    fig.colorbar(im, ax=axes, shrink=0.6, label="three-gait convergence (%)")
    fig.suptitle("Three gaits (G1+G2+G3): where convergence is highest")
    fig.savefig(path, dpi=110)


def run_gait_choices(
    *, out: str | Path, trials: int | None = None, chunk_size: int | None = None, no_progress: bool = False
) -> int:
    """``spikejax reproduce gait-choices --out DIR [--trials N]``: ``gait_choices.csv`` and ``.png``, and a table.

    Args:
        out: output directory.
        trials: seeds per grid point (default: the sweep file's).
        chunk_size: trials per compiled batch (default: the sweep file's).
        no_progress: hide the progress bar.
    """
    with output_directory(out, command="reproduce gait-choices", shared_with=("reproduce gaits",)) as out:
        table = run_named_sweep("gait_choices", out, trials=trials, chunk_size=chunk_size, progress=not no_progress)
        rows = summarize(table, ["alpha", "w_high", "lr"])
        for row in rows:
            m = (table["alpha"] == row[0]) & (table["w_high"] == row[1]) & (table["lr"] == row[2])
            ok = table["converged"][m]
            row.append(round(float(np.mean(ok & (table["epochs"][m] <= 50))), 4))
            row.append(float(np.median(table["epochs"][m][ok])) if ok.any() else float("nan"))
        header = [
            "alpha",
            "w_high",
            "lr",
            "trials",
            "converged",
            "fraction",
            "ci_low",
            "ci_high",
            "fraction_50",
            "median_epochs",
        ]
        write_csv(out / "gait_choices.csv", header, rows)
        max_epochs = int(table["epochs"].max())
        _plot_choices(out / "gait_choices.png", table, (50, max(max_epochs, 50)))
        best = sorted(rows, key=lambda r: -r[5])[:5]
        print("highest three-gait convergence (alpha, w_high/V_th, eta/V_th): fraction [95 % CI]")
        for r in best:
            print(f"  alpha={r[0]:g} w_high={r[1]:g} eta={r[2]:g}: {r[5]:.1%} [{r[6]:.1%}, {r[7]:.1%}]")
        print(f"wrote {out / 'gait_choices.csv'} and {out / 'gait_choices.png'}")
        return 0


gaits_command = Command(
    help="gait convergence, Fig. 4 of the hexapod SCPG paper (table + figure)",
    add_arguments=_add_arguments,
    run=run_gaits,
    description="Fig. 4 of the hexapod SCPG paper: convergence of one, two and three gaits, with 95 % Wilson "
    "intervals, for the interleaved and the blocked schedule, and against the training budget.",
)
gait_choices_command = Command(
    help="three-gait convergence over alpha, the initial weights and the update scale",
    add_arguments=_add_arguments,
    run=run_gait_choices,
)
