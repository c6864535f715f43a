"""``spikejax reproduce snake-gait``: the slithering snake, its head camera, and the scripted tracking baseline.

Writes, in ``--out DIR``:

- ``snake_gait.csv``: for each steering input ``C_o`` (with the head
  compensation, and ``C_o = 0`` without it): forward speed (path length of the
  centre of mass per second), turning rate (degrees per second, positive
  counter-clockwise, from the head's heading averaged over each gait period)
  and the head's yaw amplitude about its trend (degrees), measured after the
  first gait period;
- ``snake_trajectories.png``: top-down paths of the centre of mass of the
  batch of snakes, one per ``C_o``;
- ``snake_events.png``: a strip of head-camera frames with the DVS events of
  the control step drawn over them (red brighter, blue darker), the snake
  following the target;
- ``snake.gif``: a short animation of the same run, top-down view beside the
  camera's events;
- ``snake_tracking.csv`` and ``snake_tracking.png``: the scripted steering
  controller (`robots.snake.steering`) on each track of Fig. 5 (8,
  ladder, zigzag and their mirror images): mean absolute head-to-target angle
  (while the target is held), and the time at which the target is first lost
  (the paper's reset rule; empty when it never is).

Everything runs with the ``mujoco`` physics backend. ``SPIKEJAX_SNAKE_SCALE``
(default 1) scales every duration, for quick runs.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING

import jax
import jax.numpy as jnp
import numpy as np
from matplotlib.figure import Figure

from robots.common import write_csv
from robots.snake import steering, tracks
from robots.snake.gait import gait_params, gait_period, joint_targets
from spikejax.commands import Command, add_common, output_directory
from spikejax.errors import UserError

if TYPE_CHECKING:
    from robots.snake.env import SnakeEnv

# robots.snake.env and robots.snake.physics (MuJoCo and MJX) are imported by the functions that
# run the snake: `spikejax reproduce` imports this module to list its flags beside the others'.

STEERS = (-0.2, -0.1, -0.05, 0.0, 0.05, 0.1, 0.2)  # C_o, rad
GAIT_PERIODS = 8  # gait periods per steering rollout
STRIP_STEPS = 300  # control steps of the camera run (6 s)
TRACK_SECONDS = 400.0  # the steering baseline's time on each track: at 0.1 m/s, both lobes of the 8
GAIT_HEADER = ["C_o_rad", "compensation", "forward_speed_m_s", "turning_rate_deg_s", "head_yaw_amplitude_deg"]
TRACK_HEADER = [
    "track",
    "seconds",
    "mean_abs_head_angle_deg",
    "mean_abs_body_angle_deg",
    "lost_at_s",
    "mean_distance_m",
]


def _scale() -> float:
    raw = os.environ.get("SPIKEJAX_SNAKE_SCALE", "1")
    try:
        scale = float(raw)
    except ValueError:
        raise UserError(f"SPIKEJAX_SNAKE_SCALE must be a number, got {raw!r}") from None
    if not scale > 0:
        raise UserError(f"SPIKEJAX_SNAKE_SCALE must be positive, got {raw!r}")
    return scale


def _yaw(mat):
    return np.unwrap(np.arctan2(mat[..., 1, 0], mat[..., 0, 0]), axis=-1)


def gait_rollouts(periods: int = GAIT_PERIODS, steers=STEERS):
    """Batched open-loop rollouts of the gait: each ``C_o`` with compensation, and ``C_o = 0`` without.

    Returns ``(cases, times, com (n, T, 3), head yaw (n, T), xpos (n, T, 18, 3))``.
    """
    from robots.snake.physics import forward_kinematics, make_physics

    phys = make_physics("mujoco")
    gait = gait_params()
    n = int(round(periods * float(gait_period(gait)) / (phys.dt * phys.substeps)))
    cases = [(s, True) for s in steers] + [(0.0, False)]

    def run(steer, compensate):
        def body(state, _):
            state = phys.step(state, joint_targets(gait, state.time, steer, 0.0, compensate))
            return state, (state.time, state.com_pos, state.head_mat, forward_kinematics(state.qpos)[0])

        return jax.lax.scan(body, phys.init(), None, length=n)[1]

    time, com, mat, xpos = jax.jit(jax.vmap(run))(jnp.array([c[0] for c in cases]), jnp.array([c[1] for c in cases]))
    return cases, np.asarray(time[0]), np.asarray(com), _yaw(np.asarray(mat)), np.asarray(xpos)


def gait_rows(cases, time, com, yaw) -> list[list]:
    """The rows of ``snake_gait.csv`` (see the module docstring)."""
    period = float(gait_period(gait_params()))
    dt = float(time[1] - time[0])
    per = int(round(period / dt))
    rows = []
    for k, (steer, compensate) in enumerate(cases):
        c, y, t = com[k, per:], yaw[k, per:], time[per:]
        whole = (len(t) // per) * per
        ends = c[per - 1 : whole : per, :2]  # the centre of mass once a period
        speed = np.linalg.norm(np.diff(ends, axis=0), axis=1).sum() / (period * max(len(ends) - 1, 1))
        mean_yaw = y[:whole].reshape(-1, per).mean(axis=1)
        turn = np.degrees((mean_yaw[-1] - mean_yaw[0]) / (period * max(len(mean_yaw) - 1, 1)))
        trend = np.polyval(np.polyfit(t, y, 1), t)
        amplitude = np.degrees(np.sqrt(2.0) * np.std(y - trend))
        rows.append([steer, int(compensate), round(float(speed), 4), round(float(turn), 3), round(float(amplitude), 3)])
    return rows


def _plot_trajectories(path: Path, cases, com) -> None:
    fig = Figure(figsize=(6, 6), layout="constrained")
    ax = fig.add_subplot()
    for k, (steer, compensate) in enumerate(cases):
        style = "-" if compensate else "k--"
        ax.plot(com[k, :, 0], com[k, :, 1], style, label=f"C_o = {steer:+.2f}" + ("" if compensate else ", no comp."))
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title("Centre of mass, top-down (start at the origin, heading +x)")
    ax.legend(fontsize=7)
    fig.savefig(path, dpi=120)


def _event_image(frame, events):
    """An RGB image: the grey frame, events drawn over it (red brighter, blue darker)."""
    rgb = np.repeat(np.asarray(frame)[..., None], 3, axis=-1) * 0.6
    valid = np.asarray(events.valid)
    x, y, p = np.asarray(events.x)[valid], np.asarray(events.y)[valid], np.asarray(events.p)[valid]
    rgb[y[p > 0], x[p > 0]] = (1.0, 0.2, 0.2)
    rgb[y[p < 0], x[p < 0]] = (0.2, 0.4, 1.0)
    return np.clip(rgb, 0.0, 1.0)


def camera_run(steps: int = STRIP_STEPS):
    """One snake following the target on the 8 with the scripted controller, camera on: frames and events."""
    from robots.snake.env import SnakeEnv

    env = SnakeEnv("eight")
    params = steering.SteeringParams()
    key = jax.random.PRNGKey(0)
    state = env.reset(key)

    def body(carry, _):
        state, pstate = carry
        pstate, action = steering.step(params, pstate, state.obs, env.dt)
        state = env.step(state, action)
        return (state, pstate), (
            state.info["frame"],
            state.info["events"],
            state.pipeline_state.qpos,
            state.info["target_xy"],
            state.metrics["a_head"],
        )

    _, record = jax.jit(lambda s: jax.lax.scan(body, (s, steering.init()), None, length=steps))(state)
    return env, jax.device_get(record)


def _plot_strip(path: Path, record, panels: int = 6) -> None:
    frames, events = record[0], record[1]
    n = frames.shape[0]
    picks = np.linspace(1, n - 1, panels).astype(int)
    fig = Figure(figsize=(2.2 * panels, 2.6), layout="constrained")
    for i, k in enumerate(picks):
        ax = fig.add_subplot(1, panels, i + 1)
        ax.imshow(_event_image(frames[k], jax.tree.map(lambda a: a[k], events)), interpolation="nearest")
        ax.set_title(f"t = {0.02 * (k + 1):.2f} s, {int(events.valid[k].sum())} ev.", fontsize=8)
        ax.axis("off")
    fig.suptitle("Head camera (128 x 128) with the DVS events of each 20 ms step: red brighter, blue darker")
    fig.savefig(path, dpi=110)


def _animate(path: Path, env: SnakeEnv, record, frames: int = 40) -> None:
    from matplotlib.animation import PillowWriter
    from matplotlib.patches import Circle

    from robots.snake.physics import forward_kinematics

    images, events, qpos, target, _ = record
    bodies = [env.physics.mj_model.body(f"module{k}").id for k in range(17)]
    xpos = np.asarray(jax.jit(jax.vmap(lambda q: forward_kinematics(q)[0]))(jnp.asarray(qpos)))[:, bodies]
    picks = np.linspace(0, len(qpos) - 1, min(frames, len(qpos))).astype(int)
    fig = Figure(figsize=(8, 4), layout="constrained")
    top, eye = fig.add_subplot(1, 2, 1), fig.add_subplot(1, 2, 2)
    writer = PillowWriter(fps=10)
    with writer.saving(fig, str(path), dpi=80):
        for k in picks:
            top.cla()
            eye.cla()
            top.plot(xpos[k, :, 0], xpos[k, :, 1], "o-", color="tab:orange", ms=3)
            top.plot(xpos[k, 0, 0], xpos[k, 0, 1], "ks", ms=5)
            top.add_patch(Circle(target[k], tracks.TARGET_RADIUS, color="tab:green"))
            centre = 0.5 * (xpos[k].mean(axis=0)[:2] + target[k])
            top.set_xlim(centre[0] - 2.0, centre[0] + 2.0)
            top.set_ylim(centre[1] - 2.0, centre[1] + 2.0)
            top.set_aspect("equal")
            top.set_title(f"top-down, t = {0.02 * (k + 1):.1f} s")
            eye.imshow(_event_image(images[k], jax.tree.map(lambda a: a[k], events)), interpolation="nearest")
            eye.set_title("head camera + events")
            eye.axis("off")
            writer.grab_frame()


def track_runs(seconds: float = TRACK_SECONDS, progress: bool = True):
    """The scripted controller on every track, mirrored and not; per track a dict of per-step series."""
    from tqdm import tqdm

    from robots.snake.env import SnakeEnv, rollout

    params = steering.SteeringParams()
    results = {}
    for base in tqdm(("eight", "ladder", "zigzag"), desc="snake tracks", disable=not progress):
        env = SnakeEnv(base, camera=False)
        steps = max(2, int(round(seconds / env.dt)))
        policy = lambda ps, obs, st, env=env: steering.step(params, ps, obs, env.dt)  # noqa: E731
        run = jax.jit(
            jax.vmap(lambda m, env=env, policy=policy, steps=steps: rollout(env, policy, steering.init(), steps, m)[0])
        )
        record = jax.device_get(run(jnp.array([False, True])))
        for i, name in enumerate((base, base + "-mirror")):
            results[name] = {
                "time": np.arange(1, steps + 1) * env.dt,
                "a_head": np.asarray(record.metrics["a_head"][i]),
                "a_body": np.asarray(record.metrics["a_body"][i]),
                "distance": np.asarray(record.metrics["distance"][i]),
                "done": np.asarray(record.done[i]),
                "head": np.asarray(record.pipeline_state.head_pos[i, :, :2]),
                "target": np.asarray(record.info["target_xy"][i]),
            }
    return results


def track_rows(results) -> list[list]:
    """The rows of ``snake_tracking.csv`` (see the module docstring)."""
    rows = []
    for name, r in results.items():
        lost = np.nonzero(r["done"] > 0)[0]
        held = slice(0, lost[0] + 1 if len(lost) else None)
        rows.append(
            [
                name,
                round(float(r["time"][-1]), 2),
                round(float(np.degrees(np.abs(r["a_head"][held]).mean())), 3),
                round(float(np.degrees(np.abs(r["a_body"][held]).mean())), 3),
                round(float(r["time"][lost[0]]), 2) if len(lost) else "",
                round(float(r["distance"][held].mean()), 3),
            ]
        )
    return rows


def _plot_tracks(path: Path, results) -> None:
    fig = Figure(figsize=(13, 7), layout="constrained")
    names = list(results)
    for i, name in enumerate(names):
        r = results[name]
        ax = fig.add_subplot(2, len(names), i + 1)
        ax.plot(r["target"][:, 0], r["target"][:, 1], "g-", lw=2, label="target")
        ax.plot(r["head"][:, 0], r["head"][:, 1], "-", color="tab:orange", lw=0.8, label="head")
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_title(name, fontsize=9)
        if i == 0:
            ax.legend(fontsize=7)
        ax = fig.add_subplot(2, len(names), len(names) + i + 1)
        ax.plot(r["time"], np.degrees(r["a_body"]), lw=0.4, color="tab:gray", label="body")
        ax.plot(r["time"], np.degrees(r["a_head"]), lw=0.4, color="tab:blue", label="head")
        lost = np.nonzero(r["done"] > 0)[0]
        if len(lost):
            ax.axvline(r["time"][lost[0]], color="r", ls="--")
        ax.set_xlabel("t (s)")
        if i == 0:
            ax.set_ylabel("angle to target (deg)")
            ax.legend(fontsize=7)
    fig.suptitle("Scripted steering baseline on the tracks of Fig. 5 (red: target first lost)")
    fig.savefig(path, dpi=110)


def run(out: Path, scale: float = 1.0, progress: bool = True) -> dict[str, list[list]]:
    """Everything in the module docstring, durations times ``scale``."""
    out.mkdir(parents=True, exist_ok=True)
    cases, time, com, yaw, _ = gait_rollouts(max(3, int(round(GAIT_PERIODS * scale))))
    gait = gait_rows(cases, time, com, yaw)
    write_csv(out / "snake_gait.csv", GAIT_HEADER, gait)
    _plot_trajectories(out / "snake_trajectories.png", cases, com)

    env, record = camera_run(max(12, int(round(STRIP_STEPS * scale))))
    _plot_strip(out / "snake_events.png", record)
    _animate(out / "snake.gif", env, record)

    results = track_runs(TRACK_SECONDS * scale, progress)
    tracking = track_rows(results)
    write_csv(out / "snake_tracking.csv", TRACK_HEADER, tracking)
    _plot_tracks(out / "snake_tracking.png", results)
    return {"gait": gait, "tracking": tracking}


def _add_arguments(parser) -> None:
    add_common(parser)


def run_gait(*, out: str | Path, no_progress: bool = False) -> int:
    """``spikejax reproduce snake-gait --out DIR``: `robots.snake.reproduce.run`, and its tables printed.

    Durations are scaled by ``SPIKEJAX_SNAKE_SCALE`` (see the module docstring).

    Args:
        out: output directory.
        no_progress: hide the progress bar.
    """
    with output_directory(out, command="reproduce snake-gait") as out:
        rows = run(out, _scale(), progress=not no_progress)
        print("C_o  comp  speed m/s  turn deg/s  head yaw amp deg")
        for r in rows["gait"]:
            print(f"{r[0]:+.2f}  {r[1]}     {r[2]:.3f}      {r[3]:+7.2f}     {r[4]:.2f}")
        print("track            mean |a_head| deg   lost at s")
        for r in rows["tracking"]:
            print(f"{r[0]:<16} {r[2]:8.2f}           {r[4] or 'never'}")
        print(
            f"wrote {out}/snake_gait.csv, snake_tracking.csv, snake_trajectories.png, snake_events.png, "
            f"snake_tracking.png, snake.gif"
        )
        return 0


gait_command = Command(
    help="the snake's gait, its head-camera events and the scripted tracking baseline (tables + figures)",
    add_arguments=_add_arguments,
    run=run_gait,
)
