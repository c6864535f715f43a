"""The snake's tracking task as a Gymnasium env on MuJoCo's Python bindings: the setup a Stable-Baselines3 user writes.

The peer of Brax's PPO in ``benchmarks/ppo_throughput.py``. A researcher who
trains with Stable-Baselines3 writes the task as a ``gymnasium.Env`` of one
robot, steps MuJoCo from Python (``mujoco.mj_step`` on an ``MjData``), does
the task's arithmetic in NumPy, and vectorises many such envs in one process
or over one process a core. `MujocoTrackEnv` is that env for
`robots.snake.ppo.TrackTask` with the ``"angles"`` observation: the same MJCF
and settings (`robots.snake.physics.load_mj_model`, 5 steps of 4 ms a control
step), the gait of Eq. (1) of the snake R-STDP paper with its head
compensation (`robots.snake.gait.joint_targets`, read from the measured
joints or from the targets with the steering low-passed when the env's
is, with the env's phase-locked
`robots.snake.gait.swing_correction`), the target moved along the
drawn 8 as `robots.snake.tracks.advance` moves it, the angles of Eq. (12),
the reset rule of Sec. III-B, the reward ``1 - |a_head| / 40 deg`` and the
constants of `robots.snake.training.env_for`, each written again in NumPy
(``tests/test_gym_task.py`` holds it to ``TrackTask`` step by step).

What differs from `robots.snake.physics`' C backend, as a hand-written env
differs: the ``MjData`` stays in float64 from step to step and the solver's
warm start carries over (the JAX env rounds the state to float32 and starts
each control step cold), so trajectories agree closely for a while and then
part, as two integrations of a contact-rich gait do.

Gymnasium's split of an episode's end is kept: ``terminated`` when the target
is lost or has finished the 8, ``truncated`` after ``max_steps`` control steps
(one pass of the 8 at the snake's speed, Brax's ``episode_length`` in
`robots.snake.ppo.train`). Each ``reset`` draws the direction of the 8 from
the env's seeded generator, as `robots.snake.ppo.TrackTask.reset` draws it
from its key. Gymnasium is imported here and nowhere else in the snake; it
comes with the ``bench`` and ``test`` extras.
"""

from __future__ import annotations

import functools

import gymnasium
import mujoco
import numpy as np

from robots.snake import gait, tracks, training
from robots.snake.env import LOST_BODY_ANGLE, LOST_HEAD_ANGLE, steering_offset
from robots.snake.physics import joint_qpos_index, load_mj_model
from spikejax.errors import UserError

__all__ = ["MujocoTrackEnv", "make_env"]

_I = np.arange(1, gait.N_JOINTS + 1, dtype=np.float64)
_ODD = np.arange(1, gait.N_JOINTS + 1) % 2 == 1
_COMPENSATION = np.where(_ODD & (_I >= 3), 17.0 - _I, 0.0) / 16.0


def swing_correction(p: gait.GaitParams, t: float, amplitude: float, phase: float) -> float:
    """`robots.snake.gait.swing_correction` in NumPy."""
    ramp = min(max(t * abs(p.omega_o) / (2 * np.pi), 0.0), 1.0)
    return ramp * amplitude * np.sin(p.omega_o * t + phase)


def joint_targets(p: gait.GaitParams, t: float, steer: float, head_offset: float, joints=None) -> np.ndarray:
    """`robots.snake.gait.joint_targets` (compensated, from the measured ``joints`` when given) in NumPy."""
    P = p.P_head + (p.P_tail - p.P_head) * (_I - 1) / (gait.N_JOINTS - 1)
    odd = P * p.A_o * np.sin(_I * p.Omega_o + t * p.omega_o + p.delta_o) + steer
    even = P * p.A_e * np.sin(_I * p.Omega_e + t * p.omega_e) + p.C_e
    alpha = np.where(_ODD, odd, even)
    alpha[0] = -np.dot(_COMPENSATION, alpha if joints is None else joints) + head_offset
    return np.clip(alpha, -gait.JOINT_LIMIT, gait.JOINT_LIMIT)


def _point(track, s: float) -> np.ndarray:
    """`robots.snake.tracks.point` in NumPy (``track`` a tuple of NumPy arrays)."""
    s0, start, heading, curvature, length = track
    s = min(max(s, 0.0), float(length))
    k = min(max(int(np.searchsorted(s0, s, side="right")) - 1, 0), len(s0) - 1)
    ds, th, kappa = s - s0[k], heading[k], curvature[k]
    if abs(kappa) < 1e-9:
        return start[k] + ds * np.array([np.cos(th), np.sin(th)])
    return start[k] + np.array([np.sin(th + kappa * ds) - np.sin(th), np.cos(th) - np.cos(th + kappa * ds)]) / kappa


def _wrap(angle: float) -> float:
    return (angle + np.pi) % (2 * np.pi) - np.pi


@functools.cache
def _constants() -> dict:
    """The task's constants, read once a process from the JAX env of `robots.snake.training.env_for`."""
    env = training.env_for("eight", camera=False)
    track = env.track
    return {
        "lap_steps": training.lap_steps(env),
        "dt": float(env.dt),
        "substeps": int(env.physics.substeps),
        "gait": gait.GaitParams(*(float(x) for x in env.gait)),
        "max_steer": float(env.params.max_steer),
        "steer_threshold": float(env.params.steer_threshold),
        "max_head": float(env.params.max_head_offset),
        "head_swing": (float(env.params.head_swing_amplitude), float(env.params.head_swing_phase)),
        "compensate_from": env.compensate_from,
        "lag": 1.0 - float(np.exp(-env.dt / env.lag_tau)),
        "speed": float(env.params.target_speed),
        "window": int(env.window),
        "origin": np.asarray(env.origin, np.float64),
        "tracks": tuple(tuple(np.asarray(x, np.float64) for x in t) for t in (track, tracks.mirror(track))),
    }


class MujocoTrackEnv(gymnasium.Env):
    """One snake on the tracking task of `robots.snake.ppo.TrackTask` (``"angles"``), in MuJoCo and NumPy.

    Args:
        max_steps: control steps before an episode is truncated (default: one
            pass of the 8, `robots.snake.training.lap_steps`).
        as_jax: round the physics state to float32 and start the solver cold
            at every control step, as `robots.snake.physics`' C backend does,
            so that the two envs step the same numbers (for the test that
            holds them together; a user's env would not).
    """

    metadata = {"render_modes": []}

    def __init__(self, max_steps: int | None = None, *, as_jax: bool = False):
        c = _constants()
        self.max_steps = c["lap_steps"] if max_steps is None else int(max_steps)
        if self.max_steps < 1:
            raise UserError(f"max_steps must be at least 1, got {max_steps}")
        self.dt, self.substeps, self.gait, self.window = c["dt"], c["substeps"], c["gait"], c["window"]
        self.max_steer, self.max_head, self.speed = c["max_steer"], c["max_head"], c["speed"]
        self.steer_threshold, self.head_swing = c["steer_threshold"], c["head_swing"]
        self.compensate_from, self.lag = c["compensate_from"], c["lag"]
        self.origin, self.tracks = c["origin"], c["tracks"]
        self.model = load_mj_model("tuned")
        self.data = mujoco.MjData(self.model)
        self.joints = np.asarray(joint_qpos_index(self.model))
        self.site = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_SITE, "head_camera")
        self.observation_space = gymnasium.spaces.Box(-np.inf, np.inf, (2 + gait.N_JOINTS,), np.float32)
        self.action_space = gymnasium.spaces.Box(-1.0, 1.0, (2,), np.float32)
        self.mirror = False
        self.as_jax = bool(as_jax)

    def reset(self, *, seed: int | None = None, options=None):
        super().reset(seed=seed)
        mirror = (options or {}).get("mirror")
        self.mirror = bool(self.np_random.random() < 0.5) if mirror is None else bool(mirror)
        mujoco.mj_resetData(self.model, self.data)
        mujoco.mj_forward(self.model, self.data)
        self.target_s, self.steps, self.steer_lag = 0.0, 0, 0.0
        self.body_angles = np.zeros(self.window)
        a_head, a_body = self._angles(0.0)
        return self._obs(a_head, a_body), {}

    def step(self, action):
        action = np.clip(np.asarray(action, np.float64), -1.0, 1.0)
        steer = steering_offset(action[0], self.max_steer, self.steer_threshold)
        head_offset = action[1] * self.max_head
        if self.as_jax:
            d = self.data
            for x in (d.qpos, d.qvel):
                x[:] = x.astype(np.float32)
            d.time = np.float32(d.time)
            d.qacc_warmstart[:] = 0.0
        swing = swing_correction(self.gait, self.data.time, *self.head_swing)
        joints = self.data.qpos[self.joints] if self.compensate_from == "joints" else None
        ctrl = joint_targets(self.gait, self.data.time, steer, head_offset + swing, joints)
        if self.compensate_from == "lagged":
            self.steer_lag += self.lag * (steer - self.steer_lag)
            ctrl[0] = joint_targets(self.gait, self.data.time, self.steer_lag, head_offset + swing)[0]
        self.data.ctrl[:] = ctrl.astype(np.float32) if self.as_jax else ctrl
        mujoco.mj_step(self.model, self.data, nstep=self.substeps)
        mujoco.mj_kinematics(self.model, self.data)  # mj_step leaves the poses of the last substep's start
        track = self.tracks[self.mirror]
        head_xy = self.data.site_xpos[self.site, :2]
        ahead = self.target_s + self.speed * self.dt
        if np.linalg.norm(_point(track, ahead) + self.origin - head_xy) <= tracks.SPAWN_DISTANCE:
            self.target_s = min(ahead, float(track[4]))
        a_head, a_body = self._angles(-head_offset)
        self.body_angles[self.steps % self.window] = a_body
        self.steps += 1
        lost = abs(a_head) > LOST_HEAD_ANGLE or abs(self.body_angles.mean()) > LOST_BODY_ANGLE
        terminated = lost or self.target_s >= float(track[4])
        truncated = not terminated and self.steps >= self.max_steps
        reward = 1.0 - abs(a_head) / LOST_HEAD_ANGLE
        return self._obs(a_head, a_body), reward, terminated, truncated, {"abs_head": abs(a_head), "failed": lost}

    def _angles(self, d_head: float) -> tuple[float, float]:
        """Eq. (12) of the snake R-STDP paper, as `robots.snake.tracks.target_angles`."""
        target = _point(self.tracks[self.mirror], self.target_s) + self.origin
        head_xy = self.data.site_xpos[self.site, :2]
        forward = self.data.site_xmat[self.site].reshape(3, 3)[:2, 0]
        to_target = target - head_xy
        a_head = _wrap(np.arctan2(forward[1], forward[0]) - np.arctan2(to_target[1], to_target[0]))
        return a_head, a_head - d_head

    def _obs(self, a_head: float, a_body: float) -> np.ndarray:
        return np.concatenate([[a_head, a_body], self.data.qpos[self.joints]]).astype(np.float32)


def make_env(seed: int, max_steps: int | None = None):
    """A picklable factory of one seeded `MujocoTrackEnv`, for Stable-Baselines3's vectorised envs."""

    def make():
        env = MujocoTrackEnv(max_steps)
        env.reset(seed=seed)
        return env

    return make
