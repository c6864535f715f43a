"""``spikejax reproduce hexapod-walk``: each gait of a trained SCPG walking the MJCF hexapod, over randomised robots.

The hexapod SCPG paper shows its gaits only as rasters (Fig. 2) and never
measures how the robot moves on them. Here, per robot (``--robots N``, default
64): a three-gait SCPG is trained from the robot's seed (the convergence
study's settings; seeds that do not converge are replaced by the next ones),
each gait is switched on from rest for ``--cycles`` cycles (default 10), its
raster drives the legs through the step primitive (`robots.hexapod.legs`), and
the robot, randomised in foot friction (+-30 %), mass and servo gain (+-20 %),
walks on MuJoCo's C engine (`robots.hexapod.physics`). Written in ``--out DIR``:

- ``gait_table.csv``: per gait, the mean over robots with its 95 % Student-t
  interval of forward speed (m/s and m per cycle, along the initial heading),
  lateral drift (m per cycle), turn rate (deg/s and deg per cycle), distance
  travelled per cycle, and the largest roll and pitch and the lowest torso
  height over all robots;
- ``walk_trajectories.png``: every robot's path for each gait.
"""

from __future__ import annotations

import functools
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from matplotlib.figure import Figure

from robots.common import write_csv
from robots.hexapod import physics
from robots.hexapod.cpg import run_gait
from robots.hexapod.gaits import GAIT_NAMES, N_GAITS, PERIOD
from robots.hexapod.legs import servo_targets, step_params
from robots.hexapod.training import TrainParams, gait_correct, train
from robots.hexapod.trial import GaitTrialParams
from spikejax.commands import Command, count, output_directory
from spikejax.neurons import DiscreteLIFParams
from spikejax.stats import mean_interval

HEADER = ["gait", "robots", "quantity", "mean", "ci_low", "ci_high"]


@functools.cache
def _trainer(n_steps: int):
    p = TrainParams(*(jnp.asarray(v, jnp.float32) for v in GaitTrialParams()))
    neuron = DiscreteLIFParams(alpha=p.alpha, v_th=p.v_th)

    def one(key):
        w = train(p, key=key).weights
        rasters = jax.vmap(lambda g: run_gait(neuron, w, g, n_steps))(jnp.arange(N_GAITS))
        return jnp.all(gait_correct(p, w, 10)), rasters

    return jax.jit(jax.vmap(one))


def trained_rasters(n: int, n_steps: int, seed: int = 0) -> np.ndarray:
    """Rasters ``(n, 3, n_steps, 6)`` of ``n`` converged three-gait SCPGs, each gait switched on from rest."""
    batch = max(2 * n, 16)
    ok, rasters = _trainer(n_steps)(jax.random.split(jax.random.key(seed), batch))
    ok = np.asarray(ok)
    if ok.sum() < n:
        raise RuntimeError(f"only {ok.sum()} of {batch} networks converged")
    return np.asarray(rasters)[ok][:n]


def measure(walk: physics.Walk, cycle_s: float) -> dict[str, np.ndarray]:
    """Per robot: speed along and drift across the initial heading, turn rate, path per cycle, roll, pitch, height."""
    duration = walk.t[-1]
    d = walk.xy[:, -1] - walk.xy[:, 0]
    h0 = walk.yaw[:, 0]
    along = d[:, 0] * np.cos(h0) + d[:, 1] * np.sin(h0)
    across = -d[:, 0] * np.sin(h0) + d[:, 1] * np.cos(h0)
    turn = np.degrees(walk.yaw[:, -1] - walk.yaw[:, 0])
    cycles = duration / cycle_s
    path = np.sum(np.hypot(*np.diff(walk.xy, axis=1).transpose(2, 0, 1)), axis=1)
    return {
        "speed_m_per_s": along / duration,
        "speed_m_per_cycle": along / cycles,
        "drift_m_per_cycle": across / cycles,
        "turn_deg_per_s": turn / duration,
        "turn_deg_per_cycle": turn / cycles,
        "path_m_per_cycle": path / cycles,
    }


def _plot(path: Path, walks: list[physics.Walk]) -> None:
    fig = Figure(figsize=(12, 4))
    for g, (ax, w) in enumerate(zip(fig.subplots(1, N_GAITS), walks)):
        for xy in w.xy:
            ax.plot(xy[:, 0] - xy[0, 0], xy[:, 1] - xy[0, 1], lw=0.6, alpha=0.6)
        ax.plot(0, 0, "k^", ms=6)
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_title(GAIT_NAMES[g], fontsize=10)
        ax.set_xlabel("x (m), start heading +x")
        ax.set_ylabel("y (m)")
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def run(*, out: str | Path, robots: int = 64, cycles: int = 10, seed: int = 0) -> int:
    """``spikejax reproduce hexapod-walk --out DIR [--robots N] [--cycles N] [--seed S]``: the module docstring's files.

    Args:
        out: output directory.
        robots: randomised robots (one trained SCPG each).
        cycles: gait cycles walked per gait.
        seed: seed of the networks and of the robots' randomisation.
    """
    with output_directory(out, command="reproduce hexapod-walk") as out:
        p = step_params()
        n_steps = cycles * PERIOD
        rasters = trained_rasters(robots, n_steps, seed)
        models = [physics.load_model(*d) for d in physics.randomised(robots, seed=seed)]
        dt = models[0].opt.timestep
        t = jnp.arange(int(round(n_steps * float(p.dt_cpg) / dt))) * dt
        targets = jax.jit(jax.vmap(jax.vmap(lambda r: servo_targets(p, r, t))))(jnp.asarray(rasters))
        rows, walks = [], []
        for g in range(N_GAITS):
            w = physics.walk(models, np.asarray(targets[:, g]))
            walks.append(w)
            for name, values in measure(w, PERIOD * float(p.dt_cpg)).items():
                rows.append([GAIT_NAMES[g], robots, name, *(round(v, 5) for v in mean_interval(values))])
            for name, values in (
                ("max_roll_deg", np.degrees(np.abs(w.roll).max())),
                ("max_pitch_deg", np.degrees(np.abs(w.pitch).max())),
                ("min_height_m", w.height.min()),
            ):
                rows.append([GAIT_NAMES[g], robots, name, round(float(values), 5), "", ""])
        write_csv(out / "gait_table.csv", HEADER, rows)
        _plot(out / "walk_trajectories.png", walks)
        for r in rows:
            if r[2] in ("speed_m_per_s", "turn_deg_per_s", "drift_m_per_cycle"):
                print(f"{r[0]:<15}{r[2]:<20}{r[3]:>10.4f} [{r[4]:.4f}, {r[5]:.4f}]")
        print(f"wrote {out / 'gait_table.csv'} and {out / 'walk_trajectories.png'}")
        return 0


def _add_arguments(parser) -> None:
    parser.add_argument("--out", required=True, help="output directory")
    parser.add_argument(
        "--robots", type=count, default=64, help="randomised robots, one trained SCPG each (default 64)"
    )
    parser.add_argument("--cycles", type=count, default=10, help="gait cycles walked per gait (default 10)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the networks and the randomisation (default 0)")


command = Command(
    help="each gait of a trained SCPG walking the MJCF hexapod: speed, drift, turn rate over randomised robots",
    add_arguments=_add_arguments,
    run=run,
)
