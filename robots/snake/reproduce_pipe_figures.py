"""The counterparts of Figs. 5-7 of the snake pipe-tracking paper for ``spikejax reproduce snake-pipe``.

The paper's Sec. 3.2 shows, besides the trajectories of Fig. 8
(`robots.snake.reproduce_pipe`'s ``snake_pipe_trajectories.png``):

- **Fig. 5**, the camera offset: the DVS camera's actual lateral offset (a
  rough sine), the offset "analysed by FFT" and the one reconstructed from
  the head joint by Eqs. (4)-(6) with a mean filter. `camera_offset_figure`
  draws them for this snake from a straight run (`robots.snake.calibration`:
  the offset from the camera's central line, its fundamental at the gait's
  frequency, and Eqs. (4)-(6) with the fitted `robots.snake.calibration.SWING`),
  with the reconstruction's RMSE and correlation.
- **Fig. 6**, detections over events: the slot's events with the detected
  body (two edges) or entry (a ring) at several distances. `detections_figure`
  takes them from one recorded episode per situation, at `PANELS`
  detections spread over the approach by true depth (`pick_slots`).
- **Fig. 7**, width and distance over time: the detected width (pixels)
  grows as Alg. 3's distance falls. `distance_figure` draws, per situation,
  the detections' width and Eq. (8)'s distance beside the true depth over
  the recorded episode.

The recorded episodes (`record`) are each situation's first placement and
key of the run, driven by the spiking bang-bang controller in the run's own
env; per slot they keep the slot's events as one signed image (ON minus
OFF), the slot's body and entry (`spikejax.vision.pipe.Pipe`), Alg. 3's
distance of each, the true depth and whether the episode is done.
"""

from __future__ import annotations

import functools
import math
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from robots.snake.reproduce_pipe import MIN_LANES

PANELS = 4  # Fig. 6's columns: detections spread over the approach
OFFSET_PERIODS = 12.0  # gait periods of Fig. 5's straight run


def fundamental(t: np.ndarray, y: np.ndarray, omega: float) -> np.ndarray:
    """``y``'s component at ``omega`` (its FFT coefficient over ``t``, whole periods): ``Re(c e^{i omega t})``."""
    from robots.snake.calibration import fundamental_coefficient

    return np.real(fundamental_coefficient(t, y, omega) * np.exp(1j * omega * t))


def offset_stats(true: np.ndarray, estimate: np.ndarray) -> dict:
    """RMSE (m), its share of the swing's amplitude (``sqrt(2)`` times the true offset's RMS) and the correlation."""
    rmse = float(np.sqrt(np.mean((estimate - true) ** 2)))
    amplitude = float(math.sqrt(2.0) * np.sqrt(np.mean((true - true.mean()) ** 2)))
    corr = float(np.corrcoef(true, estimate)[0, 1])
    return dict(rmse=rmse, amplitude=amplitude, rmse_share=rmse / max(amplitude, 1e-12), correlation=corr)


def camera_offset_figure(path: Path, run=None, periods: float = OFFSET_PERIODS) -> dict:
    """Fig. 5's counterpart from ``run`` (default a fresh `robots.snake.calibration.straight_run` of ``periods``).

    Over whole periods after the first (the start-up; the central line's
    last half period left out, as `robots.snake.calibration.fit` does): the
    camera's offset from its central line, its fundamental at the gait's
    frequency and Eqs. (4)-(6) of the snake pipe-tracking paper with
    `robots.snake.calibration.SWING`. Returns `offset_stats` of the
    reconstruction and of the fundamental against the offset.
    """
    from matplotlib.figure import Figure

    from robots.snake import calibration

    run = calibration.straight_run(periods) if run is None else run
    used = calibration.whole_periods(run)
    t = run.t[used]
    true = calibration.true_offset(run)[used]
    omega = calibration.SWING.omega
    fft = fundamental(t, true, omega)
    rebuilt = calibration.estimate(calibration.SWING, run.angle, run.velocity)[used]
    stats = {"eq_4_6": offset_stats(true, rebuilt), "fft": offset_stats(true, fft)}
    fig = Figure(figsize=(9, 3.6))
    ax = fig.add_subplot(1, 1, 1)
    ax.plot(t, 100 * true, color="tab:blue", lw=1.4, label="actual offset (from the camera's central line)")
    ax.plot(t, 100 * fft, color="tab:red", lw=1.0, label="its fundamental at the gait's frequency (FFT)")
    ax.plot(t, 100 * rebuilt, color="tab:green", lw=1.0, label="Eqs. (4)-(6) from the head joint, mean-filtered")
    s = stats["eq_4_6"]
    ax.set_title(
        f"Camera offset, straight run: Eqs. (4)-(6) RMSE {100 * s['rmse']:.2f} cm "
        f"({100 * s['rmse_share']:.0f} % of the {100 * s['amplitude']:.1f} cm swing), correlation {s['correlation']:.3f}",
        fontsize=9,
    )
    ax.set_xlabel("time, s")
    ax.set_ylabel("offset, cm (right +)")
    ax.legend(fontsize=8, loc="upper right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    return stats


@functools.cache
def _recorder(env, slots: int):
    """The jitted, lane-vmapped recording of ``slots`` slots of ``env`` under `robots.snake.pipe_controller.switch`."""
    from robots.snake import pipe_controller as pc
    from robots.snake import pipe_env
    from spikejax.vision import detect

    act = pc.switch[1]
    det = env.tracker.detector
    k = env.slot_steps

    def one(carry, params, end, circle_update=True, keep_events=True):
        s, c = carry
        c, action = act(params, c, s)
        s = env.step(s, action, slot_end=end, circle_update=circle_update, keep_events=keep_events)
        positive, negative = detect.event_images(det, s.info["events"])
        return (s, c), positive - negative

    def slot(carry, params, schedule):
        carry, images = jax.lax.scan(lambda c, _: one(c, params, False), carry, None, length=k - 1)
        carry, image = one(carry, params, True, *schedule)
        s = carry[0]
        out = s.info["slot"]
        rec = {
            "image": jnp.clip(images.sum(0) + image, -127, 127).astype(jnp.int8),
            "body": out.body,
            "entry": out.entry,
            "body_distance": out.body_estimate.distance,
            "entry_distance": out.entry_estimate.distance,
            "depth": s.metrics["depth"],
            "t": s.pipeline_state.time,
            "done": s.done,
        }
        return carry, rec

    def episode(key, scene, params):
        carry = pipe_env.rollout_start(env, pc.switch, key, scene)

        def group(carry, _):
            recs = []
            for schedule in env.circle_schedule():
                carry, rec = slot(carry, params, schedule)
                recs.append(rec)
            return carry, jax.tree.map(lambda *a: jnp.stack(a), *recs)

        _, rec = jax.lax.scan(group, carry, None, length=slots // env.circle_every)
        return jax.tree.map(lambda a: a.reshape((slots,) + a.shape[2:]), rec)

    return jax.jit(jax.vmap(episode))


def record(env, keys, scenes, params, slots: int) -> dict:
    """Per slot of each lane's episode (leaves ``(lanes, slots, ...)``, host arrays): see the module docstring.

    ``keys`` / ``scenes`` / ``params`` (`robots.snake.pipe_controller.SwitchParams`)
    have one leading lane axis; ``slots`` is rounded down to whole groups of
    ``env.circle_every``. A lane of one is run beside its copy
    (`robots.snake.reproduce_pipe.MIN_LANES`).
    """
    every = env.circle_every
    slots = max(every, slots // every * every)
    n = keys.shape[0]
    if n < MIN_LANES:
        fill = np.zeros(MIN_LANES, int)
        rec = record(
            env, keys[fill], jax.tree.map(lambda a: a[fill], scenes), jax.tree.map(lambda a: a[fill], params), slots
        )
        return jax.tree.map(lambda a: a[:n], rec)
    return jax.tree.map(np.asarray, _recorder(env, slots)(keys, scenes, params))


def lane(rec: dict, i: int) -> dict:
    """Lane ``i`` of `record`'s output up to and including the slot that ended its episode."""
    one = jax.tree.map(lambda a: a[i], rec)
    done = np.flatnonzero(one["done"] > 0)
    end = int(done[0]) + 1 if done.size else one["done"].shape[0]
    return jax.tree.map(lambda a: a[:end], one)


def target_detections(rec: dict, lying: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The slots with a detection of the target's kind (entry for a lying pipe, else body): ``(index, width, distance)``."""
    found = rec["entry" if lying else "body"]
    idx = np.flatnonzero(found.valid)
    distance = rec["entry_distance" if lying else "body_distance"]
    return idx, np.asarray(found.width)[idx], np.asarray(distance)[idx]


def pick_slots(depth: np.ndarray, candidates: np.ndarray, panels: int = PANELS) -> list[int]:
    """``panels`` candidate slots spread over the approach: those whose true depth is nearest ``panels`` depths
    evenly spaced from the farthest candidate's to the nearest's (fewer when there are fewer candidates)."""
    if candidates.size == 0:
        return []
    d = depth[candidates]
    chosen = []
    for target in np.linspace(d.max(), d.min(), min(panels, candidates.size)):
        j = int(candidates[np.argmin(np.abs(d - target))])
        if j not in chosen:
            chosen.append(j)
    return chosen


def detections_figure(path: Path, episodes: list[tuple[str, bool, dict, int]]) -> None:
    """Fig. 6's counterpart: one row per ``(name, lying, lane record, window)``, `PANELS` columns (`pick_slots`).

    A lying pipe's entry is found on the events of the last ``window`` slots
    (the env's ``circle_window``), so its panel sums those slots' images.
    """
    from matplotlib.figure import Figure
    from matplotlib.patches import Circle

    from spikejax.commands.detect_pipe import draw_line, edges

    fig = Figure(figsize=(2.6 * PANELS, 2.8 * len(episodes)))
    axes = fig.subplots(len(episodes), PANELS, squeeze=False)
    for row, (name, lying, rec, window) in zip(axes, episodes):
        idx, _, _ = target_detections(rec, lying)
        size = rec["image"].shape[2], rec["image"].shape[1]
        chosen = pick_slots(rec["depth"], idx)
        for i, ax in enumerate(row):
            ax.set_xticks([])
            ax.set_yticks([])
            if i >= len(chosen):
                ax.set_title(f"{name}: no detection" if not chosen else "", fontsize=8)
                ax.axis("off" if chosen else "on")
                continue
            j = chosen[i]
            span = window if lying else 1
            image = rec["image"][max(0, j - span + 1) : j + 1].astype(np.float32).sum(0)
            lim = max(1.0, float(np.abs(image).max()))
            ax.imshow(image, cmap="bwr", vmin=-lim, vmax=lim, interpolation="nearest")
            if lying:
                e = jax.tree.map(lambda a: float(a[j]), rec["entry"])
                ax.add_patch(Circle((e.pos, e.row), 0.5 * e.width, fill=False, color="green", lw=1.3))
                est = rec["entry_distance"][j]
            else:
                b = jax.tree.map(lambda a: float(a[j]), rec["body"])
                for (theta, rho, ox, oy), colour in zip(edges(b.theta, b.width, b.pos, b.row), ("blue", "green")):
                    draw_line(ax, theta, rho, (ox, oy), size, color=colour, lw=1.3)
                est = rec["body_distance"][j]
            ax.set_xlim(-0.5, size[0] - 0.5)
            ax.set_ylim(size[1] - 0.5, -0.5)
            ax.set_title(f"{name}: depth {rec['depth'][j]:.2f} m, Eq. (8) {est:.2f}", fontsize=8)
    fig.suptitle(
        "Detections over the slot's events (red ON, blue OFF): body edges blue and green, entry ring green",
        fontsize=9,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def distance_figure(path: Path, episodes: list[tuple[str, bool, dict, int]]) -> list[dict]:
    """Fig. 7's counterpart: per episode, the detections' width (px) and Eq. (8)'s distance with the true depth.

    Returns per episode its name, detections and the mean |distance - depth|
    at them (m), over all and over the first and last thirds of the
    detections (the paper: larger early in the run).
    """
    from matplotlib.figure import Figure

    fig = Figure(figsize=(4.2 * len(episodes), 3.6))
    axes = fig.subplots(1, len(episodes), squeeze=False)[0]
    summary, handles = [], []
    for ax, (name, lying, rec, _) in zip(axes, episodes):
        idx, width, distance = target_detections(rec, lying)
        t, depth = rec["t"], rec["depth"]
        err = np.abs(distance - depth[idx])
        third = max(1, idx.size // 3)
        summary.append(
            dict(
                name=name,
                detections=int(idx.size),
                mean_error=float(err.mean()) if idx.size else math.nan,
                first_third=float(err[:third].mean()) if idx.size else math.nan,
                last_third=float(err[-third:].mean()) if idx.size else math.nan,
            )
        )
        ax.plot(t, depth, color="k", lw=1.0, label="true depth")
        ax.plot(t[idx], distance, ".", color="tab:red", ms=3, label="Eq. (8) distance")
        ax.set_xlabel("time, s")
        ax.set_ylabel("distance, m")
        twin = ax.twinx()
        twin.plot(t[idx], width, ".", color="tab:blue", ms=3, label="width, px")
        twin.set_ylabel("detected width, px" + (" (ring diameter)" if lying else ""), color="tab:blue")
        s = summary[-1]
        ax.set_title(f"{name}: mean |error| {s['mean_error']:.2f} m ({s['detections']} detections)", fontsize=9)
        handles = ax.get_legend_handles_labels()[0] + twin.get_legend_handles_labels()[0]
    fig.suptitle("Width and distance over the approach (one episode each)", fontsize=9)
    if handles:
        fig.legend(handles, [h.get_label() for h in handles], loc="lower center", ncol=3, fontsize=8)
    fig.tight_layout(rect=(0, 0.07, 1, 1))
    fig.savefig(path, dpi=110)
    return summary
