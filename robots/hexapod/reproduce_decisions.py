"""``spikejax reproduce hexapod-decisions``: the visual SNN's open-loop choices against the ground truth (ACCEPTANCE A6).

``N`` random scenes (default 2,000): scene ``i`` has ``1 + i % 4`` prey
(`prey.sample_scene`, distances 0.3-3 m, bearings within +-20 deg, its key
``fold_in(key(seed), i)``), its own randomised robot walking one G1 cycle from
rest and its own DVS noise (`robots.hexapod.decisions`). Writes, in ``--out DIR``:

- ``hexapod_decisions.csv``: accuracy (the winner-take-all's gait equal to
  `prey.truth_gait`) with its 95 % Wilson interval, overall, by number of prey,
  by the nearest prey's distance from the camera, by its gap to the second
  nearest, by the truth's gait, and over the scenes with one near prey and at
  least one far one (ACCEPTANCE A6's "nearest" mechanism), for
  both readouts: ``frame`` (`edges.sync_step`'s, at most one gait spike a
  frame) and ``ordered`` (the frame's layer-3 spikes reaching the gait neurons
  one by one, `decisions.ordered_readout`);
- ``hexapod_confusion.csv``: the confusion matrices (truth by decision), both readouts;
- ``hexapod_decisions.png``: the Fig. 7 counterpart for a near and a far scene:
  the step's DVS events, the filter's spikes, the layer-3 windows' spikes (the
  far/left/right regions outlined) and the gait neurons' counts.
"""

from __future__ import annotations

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
from robots.hexapod.vision import regions
from spikejax.commands import Command, count, output_directory
from spikejax.stats import wilson_interval

HEADER = ["readout", "group", "value", "scenes", "correct", "accuracy", "ci_low", "ci_high"]
READOUTS = {"frame": "gait", "ordered": "gait_ordered"}  # column of the CSV -> field of the Decision
DISTANCE_BINS = (0.3, 0.35, 0.4, 0.45, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0)
_CHUNK = 64


def scenes(seed: int, index: jax.Array) -> prey_mod.PreyScene:
    """Scene ``index`` of the reproduction: ``1 + index % 4`` prey, its key folded from ``seed`` and ``index``."""
    key = jax.random.fold_in(jax.random.key(seed), index)
    return prey_mod.sample_scene(jax.random.fold_in(key, 0), 1 + index % 4, distance=(0.3, 3.0))


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


def run(*, out: str | Path, scenes_n: int = 2000, seed: int = 0, no_progress: bool = False) -> int:
    """``spikejax reproduce hexapod-decisions --out DIR [--scenes N] [--seed S]``: the module docstring's files.

    Args:
        out: output directory.
        scenes_n: random scenes.
        seed: seed of the scenes, the robots' randomisation and the DVS noise.
        no_progress: hide the progress bar.
    """
    with output_directory(out, command="reproduce hexapod-decisions") as out:
        draws = physics.randomised(scenes_n, seed=seed)
        step = jax.jit(
            jax.vmap(
                lambda track, i: (
                    decisions.decide(track, scenes(seed, i), _keys(seed, i)),
                    _nearest_from_camera(scenes(seed, i), track[0]),
                )
            )
        )
        parts = []
        with tqdm(total=scenes_n, desc="hexapod decisions", unit="scene", disable=no_progress) as bar:
            for start in range(0, scenes_n, _CHUNK):
                stop = min(start + _CHUNK, scenes_n)
                tracks = decisions.g1_step_tracks(draws[start:stop])
                index = np.arange(start, stop)
                pad = _CHUNK - (stop - start)  # one compiled batch size
                tracks = np.concatenate([tracks, np.repeat(tracks[-1:], pad, 0)])
                index = np.concatenate([index, np.repeat(index[-1:], pad)])
                d, near = step(jnp.asarray(tracks), jnp.asarray(index, jnp.int32))
                parts.append(
                    {
                        "gait": np.asarray(d.gait)[: stop - start],
                        "gait_ordered": np.asarray(d.gait_ordered)[: stop - start],
                        "truth": np.asarray(d.truth)[: stop - start],
                        "nearest": np.asarray(near)[: stop - start, 0],
                        "second": np.asarray(near)[: stop - start, 1],
                        "overflow": np.asarray(d.overflow)[: stop - start],
                        "events": np.asarray(d.events)[: stop - start],
                    }
                )
                bar.update(stop - start)
        res = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
        n_prey = 1 + np.arange(scenes_n) % prey_mod.MAX_PREY
        rows, confusions = [], {}
        for readout, field in READOUTS.items():
            r, confusions[readout] = summarize(res[field], res["truth"], n_prey, res["nearest"], res["second"])
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
            ("far prey", lambda i: res["truth"][i] == 0),
        ):
            i = next((i for i in range(scenes_n) if want(i)), None)
            if i is not None:
                track = jnp.asarray(decisions.g1_step_tracks([draws[i]])[0])
                j = jnp.int32(i)
                examples.append((title, *decisions.decide(track, scenes(seed, j), _keys(seed, j), with_spikes=True)))
        if examples:
            _plot(out / "hexapod_decisions.png", examples)
        for r in rows:
            print(f"{r[0]:<9}{r[1]:<10}{r[2]:<16}{r[3]:>6}  {r[5]:.3f} [{r[6]:.3f}, {r[7]:.3f}]")
        for k, c in confusions.items():
            print(f"confusion, {k} readout (rows truth, columns chosen: G1, G2, G3):")
            print(c)
        print(f"events a step: median {int(np.median(res['events']))}; clipped crossings a step: "
              f"median {int(np.median(res['overflow']))} (dvs max_per_pixel and capacity overflow)")  # fmt: skip
        print(
            f"d_near = {cam.D_NEAR:.3f} m from the camera (height {cam.camera_height():.3f} m, tilt {cam.TILT_DEG:g} deg)"
        )
        print(
            f"wrote {out / 'hexapod_decisions.csv'}, {out / 'hexapod_confusion.csv'} and {out / 'hexapod_decisions.png'}"
        )
        return 0


def _add_arguments(parser) -> None:
    parser.add_argument("--out", required=True, help="output directory")
    parser.add_argument("--scenes", dest="scenes_n", type=count, default=2000, help="random scenes (default 2000)")
    parser.add_argument("--seed", type=int, default=0, help="seed of scenes, robots and DVS noise (default 0)")
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bar")


command = Command(
    help="open-loop prey decisions of the visual SNN over random scenes, against the ground truth (accuracy, confusion)",
    add_arguments=_add_arguments,
    run=run,
)
