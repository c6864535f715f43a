"""The harness every ``spikejax bench`` command uses: compile apart, interleaved timing, fair peers, one table format.

A benchmark measures one piece of work done by spikejax and by the peer a user
would otherwise run (DESIGN rule 8), in the same run, and reports:

- compile time apart from run time, measured one way: `compile_ahead`
  (``jax.jit(fn).lower(*args).compile()``);
- run time as the best of N timed runs, each blocked until the result is ready
  (`JaxRun`), with peer and candidates measured in interleaved rounds
  (`interleaved`: round ``r`` times every implementation once), so that a
  ratio holds on a machine whose load changes during the run;
- every ratio against a peer twice, one core against one and all cores against
  all, the peer given the cores the way its users would use them: several
  processes (`Processes`: one process a core, a barrier before each timed run),
  its own threads (NEST, MuJoCo C), while spikejax splits its batch over the
  CPU devices of `spikejax.devices`. Every row says what it used in the
  columns of `CORE_COLUMNS` (``cores``, ``parallel``), and `add_ratios`
  divides each row by the peer row with the same ``cores``;
- one banner (`machine_banner`), one CSV writer (`write_csv`, atomic), one
  plot (`plot_rows`).

This module is application code on top of the library: it may import
matplotlib and multiprocessing; the numerical modules of spikejax never import it.
"""

from __future__ import annotations

import csv
import math
import multiprocessing
import os
import platform
import time
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import jax

from spikejax.workers import hold_to_core

__all__ = [
    "CORE_COLUMNS",
    "HeldToOneCore",
    "held_row",
    "JaxRun",
    "Processes",
    "add_ratios",
    "batch_sizes",
    "compile_ahead",
    "cores_label",
    "interleaved",
    "machine_banner",
    "plot_rows",
    "run_isolated",
    "write_csv",
]

# Columns every benchmark row carries: the CPU cores the implementation was
# given, and how it used them ("1 process", "2 processes", "2 devices", "2 threads").
CORE_COLUMNS = ("cores", "parallel")


def machine_banner(devices: int | None = None, **versions: str) -> str:
    """The line every benchmark prints first: processor, cores, JAX devices, versions.

    Args:
        devices: the JAX devices the run uses (default: all JAX presents).
        versions: further ``name=version`` pairs (``mujoco=mujoco.__version__``).
    """
    devices = jax.device_count() if devices is None else devices
    extra = "".join(f", {name} {version}" for name, version in versions.items())
    return (
        f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, "
        f"{devices} x {jax.devices()[0].platform}, jax {jax.__version__}{extra}"
    )


def cores_label(n: int, unit: str) -> str:
    """``"1 process"``, ``"2 devices"``, ...: the ``parallel`` column of a row."""
    return f"{n} {unit}" + ("" if n == 1 else ("es" if unit.endswith("s") else "s"))


def batch_sizes(largest: int | None, sizes: Sequence[int]) -> tuple[int, ...]:
    """The batch sizes of ``sizes`` up to ``largest``, and ``largest`` itself (None: all of ``sizes``)."""
    if largest is None:
        return tuple(sizes)
    return tuple(sorted({b for b in sizes if b <= largest} | {largest}))


def compile_ahead(fn: Callable, *args: Any) -> tuple[Any, float]:
    """``fn`` compiled for ``args`` ahead of any run, and the seconds that took.

    ``fn`` is jitted (``jax.jit``) unless it already is; a function of
    `spikejax.devices.shard_batch` is jitted whole (its padding and the sharded
    program in one executable). The compiled function takes the same ``args``.
    """
    jitted = fn if hasattr(fn, "lower") else jax.jit(fn)
    t0 = time.perf_counter()
    compiled = jitted.lower(*args).compile()
    return compiled, time.perf_counter() - t0


class JaxRun:
    """One timed call of a compiled function: ``run()`` returns its seconds, blocked until the result is ready.

    Attributes:
        result: the first call's result (the others are dropped), None before it.
    """

    def __init__(self, compiled: Callable, *args: Any):
        self.compiled, self.args = compiled, args
        self.result = None

    def __call__(self) -> float:
        t0 = time.perf_counter()
        out = jax.block_until_ready(self.compiled(*self.args))
        seconds = time.perf_counter() - t0
        if self.result is None:
            self.result = out
        return seconds


def interleaved(
    runs: dict[str, Callable[[], float]], rounds: int, progress: Callable[[str], None] | None = None
) -> dict[str, float]:
    """The best seconds of each run over ``rounds`` rounds; round ``r`` calls every run once, in order.

    Args:
        runs: name -> a callable that does one timed run and returns its seconds
            (`JaxRun`, `Processes`, or any peer's own timer).
        rounds: rounds (the N of "best of N").
        progress: called with each name after its run (a progress bar's update).
    """
    best = dict.fromkeys(runs, math.inf)
    for _ in range(rounds):
        for name, run in runs.items():
            best[name] = min(best[name], float(run()))
            if progress is not None:
                progress(name)
    return best


def _serve(conn, factory, args, kwargs, barrier) -> None:
    """A worker of `Processes`: builds the timer, then times one run per request."""
    try:
        timer = factory(*args, **kwargs)
    except BaseException as err:  # noqa: BLE001 - sent to the parent, which raises it
        conn.send(("error", err))
        return
    conn.send(("ready", None))
    while True:
        message = conn.recv()
        if message == "run":
            if barrier is not None:
                barrier.wait()
            conn.send(("ok", float(timer())))
        elif message == "info":
            conn.send(("ok", getattr(timer, "info", None)))
        else:
            conn.send(("ok", None))
            return


class Processes:
    """A peer prepared in fresh processes of its own (``spawn``), one a core, timed together on request.

    Each process calls ``factory(*args, **kwargs)`` once (the peer's build,
    untimed), which returns a timer: a callable doing one timed run and
    returning its seconds, with an optional ``info`` attribute (a picklable
    dict). Each call of the `Processes` object asks every process for one run;
    they wait at a barrier and start together, and the call returns the
    slowest process's seconds, so ``processes`` runs in that time is the
    aggregate throughput of that many cores. With ``index_arg``, process ``i``
    gets the keyword argument ``index_arg=i`` (its share of the work). A process alone has no thread
    pool of another library beside it (XLA's, MuJoCo's, NEST's). Use it as a
    context manager; an exception of ``factory`` (an ImportError of a peer
    that is not installed) is raised by the constructor.
    """

    def __init__(self, factory: Callable, *args: Any, processes: int = 1, index_arg: str | None = None, **kwargs: Any):
        context = multiprocessing.get_context("spawn")
        barrier = context.Barrier(processes) if processes > 1 else None
        self.processes = processes
        self._conns, self._procs = [], []
        for i in range(processes):
            parent, child = context.Pipe()
            kw = kwargs if index_arg is None else {**kwargs, index_arg: i}
            proc = context.Process(target=_serve, args=(child, factory, args, kw, barrier), daemon=True)
            proc.start()
            child.close()  # the child's end lives in the child: a process that dies is then an EOFError here
            self._conns.append(parent)
            self._procs.append(proc)
        try:
            self._gather()
        except BaseException:
            self.close()
            raise

    def _gather(self) -> list:
        out = []
        for conn in self._conns:
            try:
                kind, value = conn.recv()
            except EOFError:
                raise RuntimeError("a benchmark process ended unexpectedly") from None
            if kind == "error":
                raise value
            out.append(value)
        return out

    def _ask(self, message: str) -> list:
        for conn in self._conns:
            conn.send(message)
        return self._gather()

    def __call__(self) -> float:
        return max(self._ask("run"))

    def info(self) -> list:
        """Each process's timer's ``info``."""
        return self._ask("info")

    def close(self) -> None:
        for conn, proc in zip(self._conns, self._procs):
            if proc.is_alive():
                try:
                    conn.send("close")
                    conn.recv()
                except (EOFError, OSError, BrokenPipeError):
                    pass
            proc.join(timeout=30)
            if proc.is_alive():
                proc.terminate()
        self._conns, self._procs = [], []

    def __enter__(self) -> Processes:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class HeldToOneCore:
    """A `Processes` factory: the timer ``make(*args, **kwargs)`` built in a process held to one core.

    The process is held to its ``index``-th core (`spikejax.workers.hold_to_core`)
    before JAX starts a thread pool, so XLA's pool has one thread: a one-core
    row. In a process free to use every core, XLA splits a one-device
    program's large elementwise loops over all of them (the hexapod's vision
    ran 1.6x, the snake pipe loop 1.5x faster so, the RoboBee flights 1.4-1.9x
    slower; docs/BENCHMARKS.md). With
    `Processes`'s ``index_arg="index"``, process ``i`` of a pool holds core ``i``.
    ``info`` is the timer's own.
    """

    def __init__(self, make: Callable, *args: Any, index: int = 0, **kwargs: Any):
        hold_to_core(index)
        self._timer = make(*args, **kwargs)

    def __call__(self) -> float:
        return self._timer()

    @property
    def info(self) -> Any:
        info = getattr(self._timer, "info", None)
        return info() if callable(info) else info


def held_row(row: dict) -> dict:
    """``row``, the info of a timer run under `HeldToOneCore`, its ``parallel`` saying so."""
    return {**row, "parallel": f"{row['parallel']}, held to 1 core"}


def run_isolated(fn: Callable, *args: Any, **kwargs: Any) -> Any:
    """``fn(*args, **kwargs)`` in a fresh Python process; returns its result.

    A benchmark runs a peer alone in its process, so that no thread pool of
    another library (XLA's, MuJoCo's rollout threads, a NEST kernel's OpenMP
    threads) competes with its threads or shares its state (Brian2's device
    starts clean). The process ends normally, so its libraries' exit handlers
    run (Brian2's removes its log files).
    """
    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as pool:
        return pool.submit(fn, *args, **kwargs).result()


def add_ratios(rows: list[dict], column: str, value: str, is_peer: Callable[[dict, dict], bool]) -> None:
    """Set ``row[column]`` to ``row[value]`` over its peer's: the peer given the same cores.

    The peer of a row is, among the rows ``p`` with ``is_peer(p, row)`` and the
    row's ``cores``, the one with the largest ``value``; NaN where there is
    none. So one core is compared with one, and all cores with all.
    """
    for row in rows:
        peers = [p for p in rows if p["cores"] == row["cores"] and is_peer(p, row)]
        peer = max(peers, key=lambda p: p[value], default=None)
        row[column] = row[value] / peer[value] if peer else math.nan


def write_csv(path: Path, rows: Iterable[dict], columns: Sequence[str]) -> Path:
    """Write ``rows`` (dicts; a missing column is empty) as a CSV table, atomically (temporary file, renamed)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + ".tmp")
    with open(tmp, "w", newline="") as file:
        writer = csv.DictWriter(file, fieldnames=list(columns), extrasaction="ignore", restval="")
        writer.writeheader()
        writer.writerows(rows)
    tmp.replace(path)
    return path


def plot_rows(
    rows: list[dict],
    path: Path,
    *,
    x: str,
    y: str,
    series: Callable[[dict], str],
    xlabel: str,
    ylabel: str,
    title: str | Callable[[Any], str],
    panel: str | None = None,
    flat: Callable[[dict], bool] | None = None,
    lines: Callable[[Any], list[tuple[float, str]]] | None = None,
    xbase: int = 10,
    size: tuple[float, float] | None = None,
) -> Path:
    """One log-log figure of ``y`` against ``x``: a line per ``series``, a panel per value of ``panel``.

    Args:
        rows: the benchmark's rows.
        path: the PNG to write.
        x, y: the columns plotted.
        series: a row's label; rows with the same label form one line.
        xlabel, ylabel: axis labels.
        title: the title, or a function of the panel's value.
        panel: a column whose values get a panel each (None: one panel).
        flat: rows (e.g. a peer timed one frame at a time) drawn as a dashed
            horizontal line at their first ``y``.
        lines: per panel value, extra reference lines ``(y, label)`` (dotted).
        xbase: the base of the log x axis.
        size: the figure's size in inches.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = list(dict.fromkeys(r[panel] for r in rows)) if panel else [None]
    fig, axes = plt.subplots(1, len(panels), figsize=size or (5.5 * len(panels), 4.2), squeeze=False)
    colours = iter(plt.rcParams["axes.prop_cycle"].by_key()["color"] * 8)
    for ax, value in zip(axes[0], panels):
        sel = [r for r in rows if panel is None or r[panel] == value]
        for label in dict.fromkeys(series(r) for r in sel):
            line = [r for r in sel if series(r) == label]
            colour = next(colours)
            if flat is not None and flat(line[0]):
                ax.axhline(line[0][y], ls="--", lw=1, color=colour, label=label)
            else:
                ax.plot([r[x] for r in line], [r[y] for r in line], "o-", color=colour, label=label)
        for level, label in lines(value) if lines else []:
            ax.axhline(level, color="k", lw=0.8, ls=":", label=label)
        ax.set_xscale("log", base=xbase)
        ax.set_yscale("log")
        ax.set(xlabel=xlabel, ylabel=ylabel, title=title(value) if callable(title) else title)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)
    return Path(path)
