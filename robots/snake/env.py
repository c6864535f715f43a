"""The snake's target-tracking task as a Brax ``Env``: steer the slithering gait after a moving sphere.

`SnakeEnv` subclasses `brax.envs.base.Env` and returns Brax's
`brax.envs.base.State`, so Brax's wrappers and trainers (e.g. PPO)
drive it as they drive their own envs, and the SNN controllers of the snake
papers drive it through the same ``reset`` / ``step``.

One ``step`` is one control step (20 ms, the snake R-STDP paper's): the gait of Eq. (1)
(`robots.snake.gait.joint_targets`) is evaluated at the step's start
with the action's steering and head offset and held by the servos while the
physics backend (``"mujoco"`` or ``"mjx"``, `robots.snake.physics.make_physics`)
advances; then the target moves along its track (`robots.snake.tracks.advance`),
the head camera renders the scene (`robots.snake.camera`) and the
frame-difference DVS (`spikejax.vision.dvs.frame_difference`, the
papers' simulator mode) turns the change since the last frame into events.

Spaces:

* ``action`` ``(2,)`` in [-1, 1] (clipped): ``action[0]`` the steering input,
  ``C_o = action[0] * max_steer`` (positive turns right, like ``D_t`` of
  Eq. (5) with the right neuron winning), or with a turning threshold
  ``steer_threshold`` the range above it (`steering_offset`); ``action[1]`` the head offset,
  ``action[1] * max_head_offset`` added to the first joint (positive turns the
  head right).
* ``obs`` ``(18,)``: ``[a_head, a_body, alpha_1 .. alpha_16]``: the target's
  angle to the head and to the body (Eq. (12), radians, positive when the
  target is on the right) and the 16 joint angles (radians, joint 1 at the
  head). A flat vector, as Brax's trainers expect.
* ``info["events"]``: the DVS events of the control step, a fixed-capacity
  `spikejax.vision.Events` (``event_capacity`` slots, stamped with the
  step's end time) with ``info["overflow"]`` counting those that did not fit.
  They live in ``info`` rather than ``obs`` because an event buffer is not a
  flat vector; the SNN controllers read them from there. ``info["frame"]`` is
  the camera's last grey-level frame (the reference for the next step's
  events) and ``info["prev_frame"]`` the one before, so that an encoder can
  count the step's events from the dense difference image
  (`spikejax.coding.grid_counts`); ``compact_events=False`` then skips
  building the event buffer (``info["events"]`` stays empty).
* ``reward = -|a_head|``: the head should face the target.
* ``info["params"]``: the episode's `SnakeEnvParams` (``max_steer``,
  ``max_head_offset``, ``target_speed``, ``event_threshold``,
  ``steer_threshold``), traced, so that
  a sweep vmaps over them with one compiled program; the constructor's values
  unless ``reset(rng, params=...)`` was given others.
* ``done = 1`` when the target is lost, the paper's reset rule (section III-B):
  ``|a_head| > 40`` degrees, or the mean of ``a_body`` over the last
  ``body_window`` control steps beyond 35 degrees. The paper's window is 625
  steps, "a movement period of the snake robot"; this gait's period is 125
  steps, the default (``body_window=625`` gives the paper's).
* ``info["completed"]``: the target has reached the end of its track, the
  episode is complete (only tracks with an end, ``drawn=True`` or waypoints,
  ever complete).

Eq. (12), ``a_body = a_head - d_head``, takes ``d_head`` positive when the head
is turned left; the head offset here is positive to the right, so
``d_head = -head_offset``.

The track is static (``track=``, a name or a `robots.snake.tracks.Track`); ``reset(rng, mirror=...)`` mirrors it about
the x axis, which is how the training track alternates direction each episode
(`robots.snake.tracks.training_mirror`). A ``step`` from a state at time
0 starts the episode afresh (target at the start, no events, empty angle
window), so Brax's ``AutoResetWrapper``, which puts back only the physics state
and the observation, restarts the whole task. The tracks are laid out in the
paper's frame (snake at (-5, 0)) and shifted so that the paper's start is the
snake's head at rest. Nothing in the task is random: ``rng`` is accepted for
Brax's interface and kept in ``info["rng"]``.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from brax.envs.base import Env, State

from robots.snake import camera as cam
from robots.snake import tracks
from robots.snake.gait import GaitParams, gait_params, gait_period, joint_targets, swing_correction
from robots.snake.physics import joint_qpos_index, make_physics
from spikejax.errors import UserError
from spikejax.vision import dvs, render

__all__ = [
    "COMPENSATE_FROM",
    "LOST_BODY_ANGLE",
    "LOST_HEAD_ANGLE",
    "SNAKE_SPEED",
    "TURN_THRESHOLD",
    "SnakeEnv",
    "SnakeEnvParams",
    "rollout",
    "steering_offset",
]

SNAKE_SPEED = 0.108  # m/s, straight gait with the default GaitParams and tuned physics (measured)
LOST_HEAD_ANGLE = math.radians(40.0)  # section III-B
LOST_BODY_ANGLE = math.radians(35.0)  # section III-B
# |C_o| below which this snake does not turn at all (measured: `tests/test_snake_env.py`); above it, 2-8 deg/s.
TURN_THRESHOLD = 0.08
COMPENSATE_FROM = ("targets", "joints", "lagged")  # what the head compensation reads: `SnakeEnv`'s compensate_from


class SnakeEnvParams(NamedTuple):
    """The task's traced quantities, those a sweep may vary: ``jax.vmap`` over them compiles once.

    `SnakeEnv` builds them from its constructor's arguments (``env.params``);
    ``env.reset(rng, params=...)`` starts an episode with others, which
    ``step`` reads from ``state.info["params"]``. Each field is a float32 scalar.

    Attributes:
        max_steer: ``C_o`` at full action, rad.
        max_head_offset: head offset at full action, rad.
        target_speed: the target's speed along the track, m/s.
        event_threshold: frame-difference threshold on grey levels in (0, 1].
        steer_threshold: ``|C_o|`` of the smallest nonzero action, rad
            (`steering_offset`); 0 maps the action linearly.
        head_swing_amplitude, head_swing_phase: the phase-locked correction
            of the head compensation (`robots.snake.gait.swing_correction`),
            rad; amplitude 0 (the default) leaves the kinematic compensation alone.
    """

    max_steer: jax.Array
    max_head_offset: jax.Array
    target_speed: jax.Array
    event_threshold: jax.Array
    steer_threshold: jax.Array
    head_swing_amplitude: jax.Array = 0.0
    head_swing_phase: jax.Array = 0.0


def steering_offset(action, max_steer, steer_threshold=0.0):
    """The gait's lateral offset ``C_o`` (Eq. (1)) for a steering action in [-1, 1].

    ``C_o = sign(a) (c + |a| (max_steer - c))`` with ``c = steer_threshold``
    (taken no larger than ``max_steer``): with ``c = 0`` the paper's
    ``C_o = D_t * C_o_max`` (SPEC U23 leaves the projection of Eq. (5)'s
    ``D_t`` to a turning angle open). This snake does not turn at all for
    ``|C_o|`` below `TURN_THRESHOLD` and turns at 2-8 deg/s between it and
    0.125 rad, so a linear map spends two thirds of the action's range on no
    turn; ``c = TURN_THRESHOLD`` gives the whole range to the turning part.
    Works on NumPy and JAX values alike.
    """
    xp = jnp if isinstance(action, jax.Array) else np
    c = xp.minimum(steer_threshold, max_steer)
    return xp.sign(action) * (c + xp.abs(action) * (max_steer - c))


class SnakeEnv(Env):
    """Follow the target sphere along a track with the slithering snake (see the module docstring).

    Args:
        track: one of `robots.snake.tracks.TRACKS`, or a `robots.snake.tracks.Track`
            (e.g. `robots.snake.tracks.load_waypoints`).
        drawn: a named track as drawn in Fig. 5, with an end (`robots.snake.tracks.get`),
            rather than endless.
        body_window: control steps of the failure rule's mean body angle;
            default one gait period (the paper: 625).
        backend: physics backend, ``"mujoco"`` (MuJoCo C, the choice on a CPU) or ``"mjx"``.
        camera: render the head camera and emit events each step; ``False``
            leaves ``info["events"]`` empty (for controllers that only read the
            angles, and for speed).
        event_threshold: frame-difference threshold on grey levels in (0, 1]
            (the default of `SnakeEnvParams`, as are the next three).
        event_capacity: event slots per control step.
        compact_events: build ``info["events"]`` each step; ``False`` for
            controllers that read the frames (faster).
        target_speed: the target's speed along the track, m/s; "a little faster
            than the snake" (section II-A): 1.2 times its straight speed.
        max_steer: ``C_o`` at full action, rad.
        max_head_offset: head offset at full action, rad.
        steer_threshold: ``|C_o|`` at the smallest nonzero steering action,
            rad (`steering_offset`); default 0, the linear map.
        compensate: the gait's head compensation (section II-A).
        compensate_from: what that compensation reads: ``"targets"``, the
            body's joint targets (kinematics of the commanded wave), or
            ``"joints"``, the body's measured joint angles (the head follows
            the body as it is; no whip when the steering jumps: see
            `robots.snake.gait.joint_targets`; a head controller's loop then
            runs back through the neck joints: see
            `robots.snake.steering.for_max_steer`), or ``"lagged"``, the
            targets with the steering ``C_o`` low-passed over ``lag_tau``
            (no whip, and no loop through the neck: the head follows the
            steering's trend, not each flip of a bang-bang controller;
            `robots.snake.training.env_for`'s choice).
        lag_tau: the time constant of ``"lagged"``, s. Not the servos' lag:
            the odd joints follow a step of ``C_o`` within about 0.3 s.
        frame_rows: ``(row0, row1)``: render only those rows of the head
            camera's frame, the others left at 0 (no events); for controllers
            that read a band of the image (Eq. (2)'s region of interest).
            Default: the whole frame.
        head_swing: ``(amplitude, phase)``, rad: a phase-locked correction
            added to that compensation (`robots.snake.gait.swing_correction`;
            `robots.snake.head_swing.HEAD_SWING` cancels this gait's residual
            head swing); default none.
        gait: the gait's parameters (``C_o`` is replaced by the steering).
        pipes: optional pipes in the scene (track frame, as ``render.Cylinders``).
        physics_kwargs: passed to `robots.snake.physics.make_physics`.
    """

    def __init__(
        self,
        track: str | tracks.Track = "eight",
        backend: str = "mujoco",
        *,
        drawn: bool = False,
        body_window: int | None = None,
        camera: bool = True,
        event_threshold: float = 0.05,
        event_capacity: int = 2048,
        compact_events: bool = True,
        target_speed: float = 1.2 * SNAKE_SPEED,
        max_steer: float = 0.25,
        max_head_offset: float = 0.5,
        steer_threshold: float = 0.0,
        compensate: bool = True,
        compensate_from: str = "targets",
        lag_tau: float = 0.5,
        gait: GaitParams | None = None,
        pipes: render.Cylinders | None = None,
        head_swing: tuple[float, float] = (0.0, 0.0),
        frame_rows: tuple[int, int] | None = None,
        **physics_kwargs: Any,
    ):
        if event_capacity < 1:
            raise UserError(f"event_capacity must be at least 1, got {event_capacity}")
        if not event_threshold > 0:
            raise UserError(f"event_threshold must be positive, got {event_threshold}")
        if not target_speed > 0:
            raise UserError(f"target_speed must be positive, got {target_speed}")
        if not 0 <= steer_threshold < max_steer:
            raise UserError(f"steer_threshold must be in [0, max_steer = {max_steer}), got {steer_threshold}")
        if len(head_swing) != 2:
            raise UserError(f"head_swing is (amplitude, phase) in radians, got {head_swing!r}")
        if frame_rows is not None:
            height = cam.HEAD_CAMERA.height
            if len(frame_rows) != 2 or not 0 <= int(frame_rows[0]) < int(frame_rows[1]) <= height:
                raise UserError(
                    f"frame_rows must be (row0, row1) with 0 <= row0 < row1 <= {height}, got {frame_rows!r}"
                )
            frame_rows = (int(frame_rows[0]), int(frame_rows[1]))
        self.frame_rows = frame_rows
        if isinstance(track, tracks.Track):
            self._track, self.track_name = track, "waypoints"
        else:
            self._track = tracks.get(track, drawn=drawn)  # raises UserError for an unknown name
            self.track_name = track
        self.physics = make_physics(backend, **physics_kwargs)
        self._joints = np.asarray(joint_qpos_index(self.physics.mj_model))
        self.camera_on = bool(camera)
        self.event_capacity = int(event_capacity)
        self.compact_events = bool(compact_events)
        self.params = SnakeEnvParams(
            *(
                jnp.asarray(x, jnp.float32)
                for x in (max_steer, max_head_offset, target_speed, event_threshold, steer_threshold, *head_swing)
            )
        )
        self.compensate = bool(compensate)
        if compensate_from not in COMPENSATE_FROM:
            raise UserError(f"compensate_from must be one of {', '.join(COMPENSATE_FROM)}, got {compensate_from!r}")
        self.compensate_from = compensate_from
        if not lag_tau > 0:
            raise UserError(f"lag_tau must be positive, got {lag_tau!r}")
        self.lag_tau = float(lag_tau)
        self.gait = gait_params() if gait is None else gait
        self.pipes = pipes
        if body_window is None:
            body_window = max(1, int(round(float(gait_period(self.gait)) / self.dt)))
        if isinstance(body_window, bool) or not isinstance(body_window, int) or body_window < 1:
            raise UserError(f"body_window must be a whole number of control steps >= 1, got {body_window!r}")
        self.window = body_window
        head0 = np.asarray(self.physics.init().head_pos[:2])
        self.origin = jnp.asarray(head0 - np.asarray(tracks.START), jnp.float32)  # track frame -> world frame

    # ------------------------------------------------------------ Brax interface

    @property
    def track(self) -> tracks.Track:
        """The track as built (not mirrored)."""
        return self._track

    @property
    def dt(self) -> float:
        """Control step, s."""
        return self.physics.dt * self.physics.substeps

    @property
    def observation_size(self) -> int:
        return 2 + 16

    @property
    def action_size(self) -> int:
        return 2

    @property
    def backend(self) -> str:
        return self.physics.backend

    def reset(self, rng: jax.Array, mirror: bool | jax.Array = False, params: SnakeEnvParams | None = None) -> State:
        """The snake at rest at the track's start, the target 1.6 m ahead of its head.

        ``params`` (default ``self.params``, the constructor's) is kept in
        ``info["params"]`` for every ``step`` of the episode; it may be traced.
        """
        params = self.params if params is None else SnakeEnvParams(*(jnp.asarray(x, jnp.float32) for x in params))
        phys = self.physics.init()
        mirror = jnp.asarray(mirror, bool)
        target_xy = self._target_xy(jnp.float32(0.0), mirror)
        frame = self._frame(phys, target_xy)
        a_head, a_body = self._angles(phys, target_xy, jnp.float32(0.0))
        zero = jnp.zeros((), jnp.float32)
        info = {
            "rng": rng,
            "params": params,
            "mirror": mirror,
            "target_s": zero,
            "target_xy": target_xy,
            "frame": frame,
            "prev_frame": frame,
            "events": dvs.frame_difference(
                frame, frame, phys.time, threshold=params.event_threshold, capacity=self.event_capacity
            )[0],
            "overflow": jnp.zeros((), jnp.int32),
            "body_angles": jnp.zeros((self.window,), jnp.float32),
            "control_steps": jnp.zeros((), jnp.int32),
            "completed": jnp.zeros((), bool),
        }
        if self.compensate_from == "lagged":
            info["steer_lag"] = zero  # C_o low-passed over lag_tau
        return State(
            pipeline_state=phys,
            obs=self._obs(phys, a_head, a_body),
            reward=zero,
            done=zero,
            metrics=self._metrics(phys, target_xy, a_head, a_body, info),
            info=info,
        )

    def step(self, state: State, action: jax.Array) -> State:
        """One control step (see the module docstring)."""
        action = jnp.clip(jnp.asarray(action, jnp.float32), -1.0, 1.0)
        params = state.info["params"]
        steer = steering_offset(action[0], params.max_steer, params.steer_threshold)
        head_offset = action[1] * params.max_head_offset
        phys = state.pipeline_state
        # A state at time 0 starts an episode, also when Brax's AutoResetWrapper put back only the physics.
        fresh = phys.time == 0.0
        swing = swing_correction(self.gait, phys.time, params.head_swing_amplitude, params.head_swing_phase)
        joints = phys.qpos[self._joints] if self.compensate_from == "joints" else None
        ctrl = joint_targets(self.gait, phys.time, steer, head_offset + swing, self.compensate, joints)
        lagged = {}
        if self.compensate_from == "lagged":
            lag = jnp.where(fresh, 0.0, state.info["steer_lag"])
            lag = lag + (1.0 - math.exp(-self.dt / self.lag_tau)) * (steer - lag)
            head = joint_targets(self.gait, phys.time, lag, head_offset + swing, self.compensate)[0]
            ctrl = ctrl.at[0].set(head)
            lagged = {"steer_lag": lag}
        phys = self.physics.step(phys, ctrl)

        info = dict(state.info)
        info["target_s"] = jnp.where(fresh, 0.0, info["target_s"])
        info["body_angles"] = jnp.where(fresh, 0.0, info["body_angles"])
        info["control_steps"] = jnp.where(fresh, 0, info["control_steps"])
        mirror = info["mirror"]
        track = self._oriented(mirror)
        head_track = phys.head_pos[:2] - self.origin
        target_s = tracks.advance(track, info["target_s"], head_track, params.target_speed, self.dt)
        target_xy = self._target_xy(target_s, mirror)
        a_head, a_body = self._angles(phys, target_xy, -head_offset)
        frame = self._frame(phys, target_xy)
        previous = jnp.where(fresh, frame, info["frame"])
        if self.camera_on and self.compact_events:
            events, overflow = dvs.frame_difference(
                previous, frame, phys.time, threshold=params.event_threshold, capacity=self.event_capacity
            )
        else:
            events, overflow = info["events"], info["overflow"]
        body_angles = info["body_angles"].at[info["control_steps"] % self.window].set(a_body)
        info.update(
            target_s=target_s,
            target_xy=target_xy,
            frame=frame,
            prev_frame=previous,
            events=events,
            overflow=overflow,
            body_angles=body_angles,
            control_steps=info["control_steps"] + 1,
            completed=target_s >= track.length,
            **lagged,
        )
        lost = (jnp.abs(a_head) > LOST_HEAD_ANGLE) | (jnp.abs(jnp.mean(body_angles)) > LOST_BODY_ANGLE)
        return state.replace(
            pipeline_state=phys,
            obs=self._obs(phys, a_head, a_body),
            reward=-jnp.abs(a_head),
            done=lost.astype(jnp.float32),
            metrics=self._metrics(phys, target_xy, a_head, a_body, info),
            info=info,
        )

    def restart(self, initial: State, state: State, mirror) -> State:
        """``initial`` (a state from `reset`) with ``state``'s params and the given mirror: a new episode.

        No rendering: ``initial`` is computed once, so an in-graph reset of
        one member of a batch costs a selection, not a second camera frame.
        The camera's last frame is kept as both frames (no events until the
        next step renders the restarted scene), which also spares selecting
        whole frames where a batch's members did not restart.
        """
        frame = state.info["frame"]
        info = dict(
            initial.info,
            params=state.info["params"],
            mirror=jnp.asarray(mirror, bool),
            rng=state.info["rng"],
            frame=frame,
            prev_frame=frame,
            events=initial.info["events"] if self.compact_events else state.info["events"],
        )
        return initial.replace(info=info)

    # ------------------------------------------------------------ parts

    def _oriented(self, mirror) -> tracks.Track:
        mirrored = tracks.mirror(self._track)
        return jax.tree.map(lambda a, b: jnp.where(mirror, b, a), self._track, mirrored)

    def _target_xy(self, s, mirror):
        return tracks.point(self._oriented(mirror), s) + self.origin

    def _angles(self, phys, target_xy, d_head):
        return tracks.target_angles(phys.head_pos[:2], phys.head_mat[:2, 0], target_xy, d_head)

    def _frame(self, phys, target_xy):
        if not self.camera_on:
            return jnp.zeros((1, 1), jnp.float32)
        pipes = None
        if self.pipes is not None:
            pipes = self.pipes._replace(center=self.pipes.center + jnp.concatenate([self.origin, jnp.zeros(1)]))
        return cam.frame(phys, cam.scene(target_xy, pipes), rows=self.frame_rows)

    def _obs(self, phys, a_head, a_body):
        return jnp.concatenate([jnp.stack([a_head, a_body]), phys.qpos[self._joints]])

    def _metrics(self, phys, target_xy, a_head, a_body, info):
        return {
            "a_head": a_head,
            "a_body": a_body,
            "distance": jnp.linalg.norm(target_xy - phys.head_pos[:2]),
            "events": info["events"].count().astype(jnp.float32),
            "overflow": info["overflow"].astype(jnp.float32),
        }


def rollout(env: SnakeEnv, policy, policy_state, steps: int, mirror=False, *, params=None, key=None):
    """Run ``policy`` in ``env`` for ``steps`` control steps in one ``lax.scan``; jit and vmap it.

    ``params`` (a `SnakeEnvParams`, default ``env.params``) and ``key`` (the
    reset's ``rng``, default ``jax.random.PRNGKey(0)``) are passed to ``env.reset``.

    ``policy(policy_state, obs, state) -> (policy_state, action)``. Returns the
    stacked per-step `brax.envs.base.State` (without the frames, to keep the
    record small) and the final state. The rollout continues after ``done``;
    ``done`` marks the steps where the target counted as lost.
    """
    key = jax.random.PRNGKey(0) if key is None else key
    state = env.reset(key, mirror, params)

    def body(carry, _):
        state, pstate = carry
        pstate, action = policy(pstate, state.obs, state)
        state = env.step(state, action)
        record = state.replace(info={k: v for k, v in state.info.items() if k not in ("frame", "prev_frame")})
        return (state, pstate), record

    (final, _), record = jax.lax.scan(body, (state, policy_state), None, length=steps)
    return record, final
