"""``spikejax detect pipe FILE``: pipes in an event recording, printed as a table, written as CSV and a figure.

The detection itself is `spikejax.vision.detect.detect` (Alg. 2-3 of the pipe
paper over the spiking Hough grids); this module is the application around it:
the flags and their checks, the text table, ``detections.csv`` and the overlay
figure ``overlay.png`` (matplotlib, imported only when it is drawn).

The flags are checked, against the ranges declared beside the parameters they
set (`spikejax.ranges`), and the output directory
(`spikejax.commands.output_directory`) before the recording is read.
"""

from __future__ import annotations

import contextlib
import csv
import math
import sys
from pathlib import Path

import jax
import numpy as np

from spikejax.commands import Command, count, output_directory
from spikejax.errors import UserError
from spikejax.ranges import check
from spikejax.vision import hough, io, pipe
from spikejax.vision.detect import Detections, detect, detector_params

__all__ = [
    "COLUMNS",
    "check_flags",
    "command",
    "draw_line",
    "edges",
    "event_frame",
    "format_table",
    "overlay",
    "run",
    "write_csv",
]

COLUMNS = (
    "t",
    "kind",
    "theta_deg",
    "width_px",
    "pos_px",
    "row_px",
    "distance_m",
    "offset_m",
    "control",
    "score",
    "support",
)


def _add_arguments(parser) -> None:
    parser.add_argument("file", help="event recording: .npz, .npy (structured array x, y, t, p) or .aedat4")
    parser.add_argument(
        "--mode", choices=("sync", "async"), default="sync", help="slots at once (default) or event by event"
    )
    parser.add_argument("--out", default=None, help="write detections.csv and overlay.png here")
    parser.add_argument("--slot", type=float, default=0.02, help="time slot, s (default 0.02)")
    parser.add_argument(
        "--sub-slots", type=count, default=5, help="updates per slot; a neuron fires at most once per update"
    )
    parser.add_argument("--capacity", type=count, default=4096, help="events per update (the rest are counted)")
    parser.add_argument(
        "--sensor-size", type=count, nargs=2, metavar=("W", "H"), default=None, help="default: the file's, else 128 128"
    )
    parser.add_argument(
        "--shapes", choices=("both", "lines", "circles"), default="both", help="bodies (lines), entries (circles)"
    )
    parser.add_argument(
        "--v-th", type=float, default=None, help="Hough neuron threshold, votes (default: half the sensor height)"
    )
    parser.add_argument("--decay", type=float, default=50.0, help="decay rate lambda of Alg. 1, votes/s")
    parser.add_argument("--fov", type=float, default=60.0, help="horizontal field of view, degrees")
    parser.add_argument("--pipe-size", type=float, default=0.0, help="pipe diameter, m, if known (distance by Eq. 8)")
    parser.add_argument("--speed", type=float, default=0.0, help="forward speed, m/s (distance by Eq. 9 otherwise)")
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bar")


def run(
    *,
    file: str | Path,
    mode: str = "sync",
    out: str | Path | None = None,
    slot: float = 0.02,
    sub_slots: int = 5,
    capacity: int = 4096,
    sensor_size: tuple[int, int] | None = None,
    shapes: str = "both",
    v_th: float | None = None,
    decay: float = 50.0,
    fov: float = 60.0,
    pipe_size: float = 0.0,
    speed: float = 0.0,
    no_progress: bool = False,
) -> int:
    """Print the detections in ``file``; write ``detections.csv`` and ``overlay.png`` to ``out`` if given.

    Args:
        file: event recording (`spikejax.vision.io.read`).
        mode: ``"sync"`` (slots at once) or ``"async"`` (event by event).
        out: output directory, or None to write nothing.
        slot: time slot, s.
        sub_slots: updates per slot; a neuron fires at most once per update.
        capacity: events per update (the rest are counted and reported).
        sensor_size: ``(width, height)``; default: the file's, else 128 x 128.
        shapes: ``"both"``, ``"lines"`` (bodies) or ``"circles"`` (entries).
        v_th: Hough neuron threshold, votes (default: half the sensor height).
        decay: decay rate lambda of Alg. 1 of the pipe paper, votes/s.
        fov: horizontal field of view, degrees.
        pipe_size: pipe diameter, m, if known (distance by Eq. (8) of the pipe paper).
        speed: forward speed, m/s (distance by Eq. (9) of the pipe paper otherwise).
        no_progress: hide the progress bar.
    """
    check_flags(
        slot=slot,
        sub_slots=sub_slots,
        capacity=capacity,
        v_th=v_th,
        decay=decay,
        fov=fov,
        pipe_size=pipe_size,
        speed=speed,
    )
    with output_directory(out, command="detect pipe") if out else contextlib.nullcontext() as out_dir:
        return _detect(
            file=file, mode=mode, out=out_dir, slot=slot, sub_slots=sub_slots, capacity=capacity,
            sensor_size=sensor_size, shapes=shapes, v_th=v_th, decay=decay, fov=fov, pipe_size=pipe_size,
            speed=speed, no_progress=no_progress,
        )  # fmt: skip


def check_flags(*, slot, sub_slots, capacity, v_th, decay, fov, pipe_size, speed) -> None:
    """Check the flags against the ranges declared beside the parameters they set (a UserError naming the flag).

    ``--fov`` is in degrees, the field of view of `spikejax.vision.pipe.track_params` in radians.
    """
    check(
        detect,
        {"slot": slot, "sub_slots": sub_slots, "capacity": capacity},
        names={"slot": "--slot", "sub_slots": "--sub-slots", "capacity": "--capacity"},
    )
    check(
        hough.HoughParams,
        {"decay": decay, **({} if v_th is None else {"v_th": v_th})},
        names={"v_th": "--v-th", "decay": "--decay"},
    )
    check(pipe.track_params, {"fov": math.radians(fov)}, names={"fov": "--fov"}, scales={"fov": 180 / math.pi})
    check(pipe.TrackParams, {"size": pipe_size, "speed": speed}, names={"size": "--pipe-size", "speed": "--speed"})


def _detect(
    *, file, mode, out, slot, sub_slots, capacity, sensor_size, shapes, v_th, decay, fov, pipe_size, speed, no_progress
) -> int:
    """`run` once the flags and the output directory are checked."""
    events, size = io.read(file, sensor_size)
    if len(events) == 0:
        raise UserError(f"{file}: no events")
    if mode == "async" and shapes != "lines":
        # Measured on a 2-core CPU: about 200 events/s (each event updates a ring of cells at each of 64 radii).
        print(
            f"note: asynchronous circle detection is slow on a CPU (about 200 events/s; {len(events)} events "
            f"here); --mode sync, or --shapes lines for bodies only, is much faster",
            file=sys.stderr,
        )
    track = pipe.track_params(fov=math.radians(fov), width=size[0], size=pipe_size, speed=speed)
    try:
        found = detect(
            events,
            size,
            mode=mode,
            slot=slot,
            sub_slots=sub_slots,
            capacity=capacity,
            lines=shapes != "circles",
            circles=shapes != "lines",
            params=detector_params(v_th=0.5 * size[1] if v_th is None else v_th, decay=decay),
            track=track,
            progress=not no_progress,
        )
    except UserError as err:  # the recording's span or sensor (the flags were checked above)
        raise UserError(f"{file}: {err}") from None
    rows = found.table()
    duration = (events["t"][-1] - events["t"][0]) * 1e-6
    print(
        f"{file}: {len(events)} event{'' if len(events) == 1 else 's'}, {size[0]}x{size[1]} sensor, "
        f"{duration:.3f} s, {len(found.overflow)} slots of {slot * 1e3:g} ms, mode {mode}"
    )
    if found.overflow.sum():
        print(
            f"warning: {int(found.overflow.sum())} events did not fit (capacity {capacity} per "
            f"part) in {int((found.overflow > 0).sum())} slots; raise --capacity"
        )
    print(format_table(rows))
    if out:
        write_csv(out / "detections.csv", rows)
        overlay(out / "overlay.png", events, size, found, slot)
        print(f"wrote {out / 'detections.csv'} and {out / 'overlay.png'}")
    return 0


def format_table(rows: list[dict]) -> str:
    """The detections as an aligned text table (distance ``-`` where unknown)."""
    if not rows:
        return "no pipe detected"
    head = f"{'t (s)':>9} {'kind':<5} {'theta':>6} {'width':>6} {'pos':>6} {'distance':>9} {'C':>2} {'spikes':>6}"
    lines = [head]
    for r in rows:
        d = f"{r['distance_m']:.3f} m" if r["distance_m"] > 0 else "-"
        lines.append(
            f"{r['t']:9.3f} {r['kind']:<5} {r['theta_deg']:6.1f} {r['width_px']:6.1f} {r['pos_px']:6.1f} "
            f"{d:>9} {r['control']:>2d} {r['score']:6.0f}"
        )
    return "\n".join(lines)


def write_csv(path: Path, rows: list[dict]) -> None:
    """All detections, one row each (columns `COLUMNS`), written atomically."""
    tmp = path.with_suffix(path.suffix + ".tmp")
    with open(tmp, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=COLUMNS)
        writer.writeheader()
        writer.writerows(rows)
    tmp.replace(path)


def edges(pipe_theta: float, width: float, pos: float, row: float) -> list[tuple[float, float, float, float]]:
    """The two edges of a body as ``(theta, rho, ox=pos, oy=row)`` lines: ``rho = +-w/2`` about its centre."""
    return [(pipe_theta, -0.5 * width, pos, row), (pipe_theta, 0.5 * width, pos, row)]


def draw_line(ax, theta, rho, origin, size, **kw):
    """Draw ``rho = (x - ox) sin(theta) + (y - oy) cos(theta)`` across an image of ``size``."""
    width, height = size
    s, c = math.sin(theta), math.cos(theta)
    if abs(s) >= abs(c):
        y = np.array([0.0, height - 1.0])
        x = origin[0] + (rho - (y - origin[1]) * c) / s
    else:
        x = np.array([0.0, width - 1.0])
        y = origin[1] + (rho - (x - origin[0]) * s) / c
    ax.plot(x, y, **kw)


def event_frame(events: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Sum of polarities per pixel, ``(height, width)``."""
    frame = np.zeros((size[1], size[0]), np.float32)
    np.add.at(frame, (events["y"], events["x"]), events["p"])
    return frame


def overlay(path: Path, events: np.ndarray, size, found: Detections, slot: float, panels: int = 4) -> None:
    """Up to ``panels`` slots with detections: their events, the body's edges and the entry's ring."""
    from matplotlib.figure import Figure
    from matplotlib.patches import Circle

    found_any = np.flatnonzero(found.bodies.valid | found.entries.valid)
    if len(found_any) == 0:
        found_any = np.array([int(np.argmax(np.bincount(((events["t"] - found.t0) * 1e-6 // slot).astype(int))))])
    chosen = found_any[np.linspace(0, len(found_any) - 1, min(panels, len(found_any))).round().astype(int)]
    fig = Figure(figsize=(3.2 * len(chosen), 3.4))
    axes = fig.subplots(1, len(chosen), squeeze=False)
    seconds = (events["t"] - found.t0) * 1e-6
    for ax, i in zip(axes[0], chosen):
        in_slot = events[(seconds >= i * slot) & (seconds < (i + 1) * slot)]
        frame = event_frame(in_slot, size)
        lim = max(1.0, np.abs(frame).max())
        ax.imshow(frame, cmap="bwr", vmin=-lim, vmax=lim, interpolation="nearest")
        if found.bodies.valid[i]:
            b = jax.tree.map(lambda v: v[i], found.bodies)
            for theta, rho, ox, oy in edges(float(b.theta), float(b.width), float(b.pos), float(b.row)):
                draw_line(ax, theta, rho, (ox, oy), size, color="lime", lw=1.2)
        if found.entries.valid[i]:
            e = jax.tree.map(lambda v: v[i], found.entries)
            ax.add_patch(Circle((float(e.pos), float(e.row)), 0.5 * float(e.width), fill=False, color="gold", lw=1.2))
        ax.set_xlim(-0.5, size[0] - 0.5)
        ax.set_ylim(size[1] - 0.5, -0.5)
        ax.set_title(f"t = {(i + 1) * slot:.3f} s", fontsize=9)
        ax.set_xticks([])
        ax.set_yticks([])
    fig.suptitle("events (red ON, blue OFF); body edges green, entry gold", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


command = Command(
    help="pipe bodies and entries (spiking Hough, Alg. 2-3 of the pipe paper)",
    add_arguments=_add_arguments,
    run=run,
)
