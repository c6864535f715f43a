"""``spikejax reproduce hexapod-decisions``: the visual SNN's open-loop choices against the ground truth (ACCEPTANCE A6).

``N`` random scenes (default 2,000): scene ``i`` has ``1 + i % 4`` prey
(`prey.sample_scene`, distances 0.3-3 m, bearings within +-20 deg, its key
``fold_in(key(seed), i)``), its own randomised robot walking one G1 cycle from
rest and its own DVS noise (`robots.hexapod.decisions`). Beside them
``--empty M`` empty arenas (default 200; no prey, so the truth is G1: the
robot keeps walking) and, with ``--full-check K``, the first ``K`` scenes again
at the paper's 800 x 1280 sensor with its 100-pixel windows and own weights
(ACCEPTANCE A11: the scaled network's agreement with the full one).
``--wiring`` picks the readout onto the gait neurons: with the near windows'
veto on G1 (the default) or the paper's alone (`robots.hexapod.vision`). Writes, in
``--out DIR``:

- ``hexapod_decisions.csv``: accuracy (the winner-take-all's gait equal to
  `prey.truth_gait`) with its 95 % Wilson interval, overall, by number of prey,
  by the nearest prey's distance from the camera, by its gap to the second
  nearest, by the truth's gait, and over the scenes with one near prey and at
  least one far one (ACCEPTANCE A6's "nearest" mechanism); the empty arenas
  (``empty``: G1 or no gait spike); the full-resolution check (``full_check``:
  agreement, and each sensor's accuracy on those scenes); for both readouts:
  ``frame`` (`edges.sync_step`'s, at most one gait spike a frame) and
  ``ordered`` (the frame's layer-3 spikes reaching the gait neurons one by one,
  `decisions.ordered_readout`, which takes the excitatory synapses only);
- ``hexapod_confusion.csv``: the confusion matrices (truth by decision), both readouts;
- ``hexapod_decisions.png``: the Fig. 7 counterpart for a near and a far scene:
  the step's DVS events, the filter's spikes, the layer-3 windows' spikes (the
  far/left/right regions outlined) and the gait neurons' counts.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from matplotlib.figure import Figure
from tqdm import tqdm

from robots.common import write_csv
from robots.hexapod import camera as cam
from robots.hexapod import decisions, physics
from robots.hexapod import prey as prey_mod
from robots.hexapod.gaits import GAIT_NAMES
from robots.hexapod.vision import FORWARD, PAPER_SENSOR, WIRING, WIRINGS, check_wiring, regions
from spikejax.commands import Command, count, count_or_zero, output_directory, positive_float
from spikejax.stats import wilson_interval

HEADER = ["readout", "group", "value", "scenes", "correct", "accuracy", "ci_low", "ci_high"]
READOUTS = {"frame": "gait", "ordered": "gait_ordered"}  # column of the CSV -> field of the Decision
DISTANCE_BINS = (0.3, 0.35, 0.4, 0.45, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0)
_CHUNK = 64
_FULL_CHUNK = 2  # scenes a batch at 800 x 1280 (25 times the pixels)


def scenes(
    seed: int, index: jax.Array, n_prey: jax.Array | None = None, size: float = prey_mod.PREY_SIZE
) -> prey_mod.PreyScene:
    """Scene ``index`` of the reproduction: ``n_prey`` prey (default ``1 + index % 4``), its key from ``seed`` and ``index``."""
    key = jax.random.fold_in(jax.random.key(seed), index)
    n = 1 + index % 4 if n_prey is None else n_prey
    return prey_mod.sample_scene(jax.random.fold_in(key, 0), n, distance=(0.3, 3.0), size=size)


def _keys(seed: int, index: jax.Array) -> jax.Array:
    return jax.random.fold_in(jax.random.fold_in(jax.random.key(seed), index), 1)


def _row(group, value, ok) -> list:
    n, k = int(ok.size), int(ok.sum())
    low, high = wilson_interval(k, n)
    return [group, value, n, k, round(k / max(n, 1), 4), round(float(low), 4), round(float(high), 4)]


GAP_BINS = (0.0, 0.25, 0.5, 1.0, np.inf)


def summarize(gait, truth, n_prey, nearest, second=None) -> tuple[list[list], np.ndarray]:
    """The rows of ``hexapod_decisions.csv`` and the confusion matrix ``(3, 3)`` (truth by decision).

    ``second``: the second-nearest prey's distance (inf with one prey), for the
    rows by gap and for the scenes with one near prey and at least one far one.
    """
    ok = gait == truth
    rows = [_row("all", "", ok)]
    rows += [_row("prey", str(k), ok[n_prey == k]) for k in range(1, prey_mod.MAX_PREY + 1)]
    for lo, hi in zip(DISTANCE_BINS[:-1], DISTANCE_BINS[1:]):
        sel = (nearest >= lo) & (nearest < hi)
        if sel.any():
            rows.append(_row("nearest_m", f"{lo:g}-{hi:g}", ok[sel]))
    rows += [_row("truth", GAIT_NAMES[g], ok[truth == g]) for g in range(3) if (truth == g).any()]
    if second is not None:
        gap = second - nearest
        for lo, hi in zip(GAP_BINS[:-1], GAP_BINS[1:]):
            sel = np.isfinite(gap) & (gap >= lo) & (gap < hi)
            if sel.any():
                rows.append(_row("gap_m", f"{lo:g}-{hi:g}", ok[sel]))
        near_far = (truth != 0) & np.isfinite(second) & (second > cam.D_NEAR + 0.05)
        if near_far.any():
            rows.append(_row("near_and_far", "", ok[near_far]))
    confusion = np.zeros((3, 3), np.int64)
    np.add.at(confusion, (truth, gait), 1)
    return rows, confusion


def _nearest_from_camera(scene: prey_mod.PreyScene, track0) -> jax.Array:
    """The nearest and second-nearest living prey's distances from the camera (inf where none)."""
    dist, _ = prey_mod.relative(scene, cam.ground_pose(track0))
    return jnp.sort(jnp.where(scene.alive, dist, jnp.inf))[:2]


def _plot(path: Path, examples) -> None:
    fig = Figure(figsize=(13, 3.2 * len(examples)))
    axes = fig.subplots(len(examples), 4, squeeze=False)
    region = regions(cam.EDGE_CONFIG)
    win = cam.EDGE_CONFIG.window
    for row, (title, decision, (counts, spikes)) in zip(axes, examples):
        events = np.asarray(counts).sum(0)
        row[0].imshow(events, cmap="gray_r", vmax=max(1, np.percentile(events[events > 0], 95)) if events.any() else 1)
        row[0].set_title(f"{title}: DVS events of the step ({int(decision.events)})", fontsize=9)
        row[1].imshow(np.asarray(spikes.filter).sum(0), cmap="gray_r")
        row[1].set_title(f"filter spikes ({int(decision.filter_spikes)})", fontsize=9)
        w = np.asarray(decision.window_counts)
        row[2].imshow(w.sum(-1), cmap="magma_r")
        far = (region == 0).sum(0).max()
        row[2].axhline(far - 0.5, color="c", lw=1)
        row[2].axvline(region.shape[1] / 2 - 0.5, ymin=0, ymax=1 - far / region.shape[0], color="c", lw=1)
        row[2].set_title(f"layer-3 spikes per {win} px window (both branches)", fontsize=9)
        out = np.asarray(decision.out_counts)
        ordered = np.asarray(decision.ordered_counts)
        names = ["G1 fwd", "G2 left", "G3 right"]
        row[3].bar(np.arange(3) - 0.2, out, 0.4, color="0.5", label="frame readout")
        row[3].bar(np.arange(3) + 0.2, ordered, 0.4, color="tab:orange", label="ordered readout")
        row[3].set_xticks(range(3), names)
        row[3].legend(fontsize=7)
        row[3].set_title(
            f"chose {names[int(decision.gait)]} (frame), {names[int(decision.gait_ordered)]} (ordered); "
            f"truth {names[int(decision.truth)]}",
            fontsize=8,
        )
        for ax in row[:3]:
            ax.set_xticks([])
            ax.set_yticks([])
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def _decide_all(draws, index, n_prey, seed, size, config, chunk, bar, lens=cam.LENS, wiring=WIRING) -> dict:
    """Every scene's `decisions.Decision` fields and nearest distances, as NumPy arrays, ``chunk`` scenes a batch."""
    step = jax.jit(
        jax.vmap(
            lambda track, i, n: (
                decisions.decide(
                    track, scenes(seed, i, n, size), _keys(seed, i), config=config, lens=lens, wiring=wiring
                ),
                _nearest_from_camera(scenes(seed, i, n, size), track[0]),
            )
        )
    )
    parts = []
    for start in range(0, len(index), chunk):
        stop = min(start + chunk, len(index))
        tracks = decisions.g1_step_tracks(draws[start:stop])
        idx, n = index[start:stop], n_prey[start:stop]
        pad = chunk - (stop - start)  # one compiled batch size
        tracks = np.concatenate([tracks, np.repeat(tracks[-1:], pad, 0)])
        idx, n = (np.concatenate([a, np.repeat(a[-1:], pad)]) for a in (idx, n))
        d, near = step(jnp.asarray(tracks), jnp.asarray(idx, jnp.int32), jnp.asarray(n, jnp.int32))
        part = {k: np.asarray(v)[: stop - start] for k, v in d._asdict().items() if k in _KEPT}
        part["nearest"], part["second"] = (np.asarray(near)[: stop - start, j] for j in (0, 1))
        parts.append(part)
        bar.update(stop - start)
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


_KEPT = ("gait", "gait_ordered", "truth", "out_counts", "overflow", "clipped", "events")


def run(
    *,
    out: str | Path,
    scenes_n: int = 2000,
    seed: int = 0,
    empty_n: int = 200,
    full_check: int = 0,
    prey_size: float = prey_mod.PREY_SIZE,
    lens: str = cam.LENS,
    wiring: str = WIRING,
    no_progress: bool = False,
) -> int:
    """``spikejax reproduce hexapod-decisions --out DIR [--scenes N] [--empty M] [--full-check K] [--prey-size S] [--seed S] [--wiring W]``.

    Args:
        out: output directory.
        scenes_n: random scenes with 1-4 prey.
        seed: seed of the scenes, the robots' randomisation and the DVS noise.
        empty_n: empty arenas (no prey: the truth is G1, keep walking), scenes
            ``scenes_n .. scenes_n + empty_n - 1``, each its own robot and noise.
        full_check: the first ``full_check`` scenes also at the paper's 800 x 1280
            sensor (ACCEPTANCE A11): the agreement of the two decisions.
        prey_size: the cubes' edge, m (`prey.PREY_SIZE`; 0.1 gives the cubes as tall as the camera).
        lens: the camera's optical axis on the windows' centre or, as in the paper, the sensor's (`camera.LENSES`).
        wiring: the readout onto the gait neurons, with the near windows' veto on G1 or the paper's
            (`robots.hexapod.vision.WIRINGS`).
        no_progress: hide the progress bar.
    """
    check_wiring(wiring)
    with output_directory(out, command="reproduce hexapod-decisions") as out:
        draws = physics.randomised(scenes_n + empty_n, seed=seed)
        index = np.arange(scenes_n + empty_n)
        n_prey = np.where(index < scenes_n, 1 + index % prey_mod.MAX_PREY, 0)
        total = scenes_n + empty_n + min(full_check, scenes_n)
        with tqdm(total=total, desc="hexapod decisions", unit="scene", disable=no_progress) as bar:
            res = _decide_all(draws, index, n_prey, seed, prey_size, cam.EDGE_CONFIG, _CHUNK, bar, lens, wiring)
            full = None
            if full_check:
                k = min(full_check, scenes_n)
                full = _decide_all(
                    draws[:k], index[:k], n_prey[:k], seed, prey_size, PAPER_SENSOR, _FULL_CHUNK, bar, lens, wiring
                )
        prey_rows = index < scenes_n
        sub = {k: v[prey_rows] for k, v in res.items()}
        empty = {k: v[~prey_rows] for k, v in res.items()}
        rows, confusions = [], {}
        for readout, field in READOUTS.items():
            r, confusions[readout] = summarize(
                sub[field], sub["truth"], n_prey[prey_rows], sub["nearest"], sub["second"]
            )
            if empty_n:
                r.append(_row("empty", "G1 or silent", empty[field] == FORWARD))
            if full is not None:
                n_full = len(full[field])
                r.append(_row("full_check", "agreement", full[field] == sub[field][:n_full]))
                r.append(_row("full_check", "full accuracy", full[field] == full["truth"]))
                r.append(_row("full_check", "scaled accuracy", sub[field][:n_full] == sub["truth"][:n_full]))
            rows += [[readout, *row] for row in r]
        write_csv(out / "hexapod_decisions.csv", HEADER, rows)
        write_csv(
            out / "hexapod_confusion.csv",
            ["readout", "truth", *(f"chose {g}" for g in GAIT_NAMES)],
            [[k, GAIT_NAMES[g], *c[g].tolist()] for k, c in confusions.items() for g in range(3)],
        )
        examples = []
        for title, want in (
            ("near prey", lambda i: res["truth"][i] != 0),
            ("far prey", lambda i: res["truth"][i] == 0 and n_prey[i] > 0),
        ):
            i = next((i for i in range(scenes_n) if want(i)), None)
            if i is not None:
                track = jnp.asarray(decisions.g1_step_tracks([draws[i]])[0])
                j = jnp.int32(i)
                scene = scenes(seed, j, size=prey_size)
                d = decisions.decide(track, scene, _keys(seed, j), with_spikes=True, lens=lens, wiring=wiring)
                examples.append((title, *d))
        if examples:
            _plot(out / "hexapod_decisions.png", examples)
        for r in rows:
            print(f"{r[0]:<9}{r[1]:<12}{r[2]:<16}{r[3]:>6}  {r[5]:.3f} [{r[6]:.3f}, {r[7]:.3f}]")
        for k, c in confusions.items():
            print(f"confusion, {k} readout (rows truth, columns chosen: G1, G2, G3):")
            print(c)
        if empty_n:
            silent = int((empty["out_counts"].sum(-1) == 0).sum())
            print(f"empty arenas: {silent} of {empty_n} with no gait spike")
        print(
            f"events a step: median {int(np.median(res['events']))}, max {int(res['events'].max())}; "
            f"events beyond the capacity ({decisions.CAPACITY} a frame): median {int(np.median(res['overflow']))}, "
            f"max {int(res['overflow'].max())}; crossings beyond {decisions.MAX_PER_PIXEL} a pixel and frame: "
            f"median {int(np.median(res['clipped']))} a step"
        )
        if full is not None:
            print(
                f"at 800 x 1280: events a step median {int(np.median(full['events']))}; beyond the capacity "
                f"({decisions.capacity(PAPER_SENSOR)} a frame): max {int(full['overflow'].max())}; crossings beyond "
                f"{decisions.MAX_PER_PIXEL} a pixel and frame: median {int(np.median(full['clipped']))} a step"
            )
        print(
            f"d_near = {cam.D_NEAR:.3f} m from the camera (height {cam.camera_height():.3f} m, tilt {cam.TILT_DEG:g} deg); "
            f"prey cubes of {prey_size:g} m"
        )
        print(
            f"wrote {out / 'hexapod_decisions.csv'}, {out / 'hexapod_confusion.csv'} and {out / 'hexapod_decisions.png'}"
        )
        return 0


def _prey_size(text: str) -> float:
    """``argparse`` type of ``--prey-size``: a cube's edge in (0, 1] m, as a scene file takes."""
    value = positive_float(text)
    if value > 1:
        raise argparse.ArgumentTypeError(f"must be at most 1 m, got {text}")
    return value


def _add_arguments(parser) -> None:
    parser.add_argument("--out", required=True, help="output directory")
    parser.add_argument("--scenes", dest="scenes_n", type=count, default=2000, help="random scenes (default 2000)")
    parser.add_argument(
        "--empty", dest="empty_n", type=count_or_zero, default=200, help="empty arenas, no prey (default 200)"
    )
    parser.add_argument(
        "--full-check",
        dest="full_check",
        type=count_or_zero,
        default=0,
        help="the first K scenes also at the paper's 800 x 1280 sensor: agreement (ACCEPTANCE A11; default 0)",
    )
    parser.add_argument(
        "--prey-size",
        dest="prey_size",
        type=_prey_size,
        default=prey_mod.PREY_SIZE,
        help=f"the prey cubes' edge, m (default {prey_mod.PREY_SIZE:g})",
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of scenes, robots and DVS noise (default 0)")
    parser.add_argument(
        "--lens",
        choices=cam.LENSES,
        default=cam.LENS,
        help="the camera's optical axis on the windows' centre (default) or, as in the paper, on the sensor's centre",
    )
    parser.add_argument(
        "--wiring",
        choices=WIRINGS,
        default=WIRING,
        help="the readout onto the gait neurons: with the near windows' veto on G1 (default) or the paper's alone",
    )
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bar")


command = Command(
    help="open-loop prey decisions of the visual SNN over random scenes, against the ground truth (accuracy, confusion)",
    add_arguments=_add_arguments,
    run=run,
)
