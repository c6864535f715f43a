"""The snake's pipe-tracking task as a Brax ``Env``: slither to a pipe seen only through the spiking detector.

The closed loop of the snake pipe-tracking paper (Sec. 2.1, Fig. 1): a DVS
on the head, the spiking Hough grids (Alg. 1-2), the decision maker (Alg. 3)
and the gait. `PipeEnv` subclasses `brax.envs.base.Env` and returns Brax's
`brax.envs.base.State`, like `robots.snake.env.SnakeEnv`, on the world of
`robots.snake.pipes` (no target sphere). One ``step`` is one 20 ms control
step:

1. the gait of Eq. (1) of the snake R-STDP paper (`robots.snake.gait.joint_targets`)
   with ``C_o = action[0] * max_steer`` (positive turns right), from the
   episode's start phase (``random_phase``: drawn from the reset's key; else
   0; ``info["gait_t0"]``, s), held by the
   servos while the physics (with the scene's pipes as mocap bodies,
   `robots.snake.physics.PipeBodies`) advances;
2. the head camera renders the pipe scene (`robots.snake.camera.pipe_scene`);
3. the frame-difference DVS (`spikejax.vision.dvs.frame_difference`, the
   paper's simulator mode: every event stamped with the step's end) makes
   the step's events; or, with ``dvs="contrast"``, the contrast-threshold
   emulator (`spikejax.vision.dvs.step`), which interpolates each pixel's
   log intensity between the step's two frames and stamps every event with
   its crossing time inside the step, the sub-frame times the asynchronous
   mode of the grids needs;
4. the streaming detector (`spikejax.vision.stream`) runs the grids' Alg. 1
   update of the snake pipe-tracking paper on them with the head joint's
   encoder (its Eq. 4-6), and every
   ``slot_steps`` steps Alg. 2 (body / entry) and Alg. 3 (distance by Eq. 8
   with the known size, refined by `DISTANCE_REFINEMENTS`, offsets,
   ``C = sign(offset)``);
5. truth (`robots.snake.pipes.truth`, ``line_offset`` from the central line,
   ``reached``, ``entered``, ``collided``) for the metrics and ``done`` only.

A slot ends at the same control step for every member of a batch (all
episodes start at time 0), so `rollout` scans slots, each a scan of its
steps, and runs the pipe-tracking paper's Alg. 2 once per slot (``step(..., slot_end=True)``);
the Brax ``step`` (``slot_end=None``) decides per step with a ``cond``,
which under ``vmap`` pays for Alg. 2 every step.

Spaces and records:

* ``action`` ``(2,)`` in [-1, 1]: ``action[0]`` the steering; ``action[1]``
  narrows the gait, its lateral amplitude ``A_o`` of Eq. (1) of the snake
  R-STDP paper scaled by ``1 - max(action[1], 0) (1 - narrow)``
  (``narrow``, `PipeEnvParams`: the factor at ``action[1] = 1``). The head
  compensation is kept, as the paper's snake keeps it. The bang-bang
  controller can narrow the gait for
  its blind last stretch into a lying pipe's bore (``narrow`` of
  `robots.snake.pipe_controller.ControllerParams`, off by default), where
  the head swings about +-0.15-0.2 m across the path with the full gait.
* ``obs`` ``(32,)``: the 16 joint angles and the 16 joint velocities (the
  encoders); nothing of the world. The controllers read the detector's
  output from ``info``.
* ``info["slot"]``: the last `spikejax.vision.stream.SlotOutput` (the
  detections, the snake pipe-tracking paper's Alg. 3 estimates and ``control``, the C in force);
  ``info["ended"]`` whether this step ended a slot; ``info["tracker"]`` the
  detector's state; ``info["events"]`` / ``info["overflow"]`` the step's
  events and those that did not fit; ``info["scene"]`` the episode's
  `robots.snake.pipes.PipeScene`.
* ``metrics``: truth and estimate side by side for the target pipe (slot 0
  of the scene): ``depth`` (along the optical axis, what Eq. 8 of the snake
  pipe-tracking paper estimates),
  ``offset_true`` (from the central line: the centre of mass averaged over
  the last gait period, along its mean heading), ``lateral`` (across the
  optical axis), ``d_est`` and ``offset_est`` (the steering detection's, at
  slot ends; ``info["side_est"]`` is its Alg. 3 ``pipeOffset``, across the
  optical axis, without the camera's own offset), ``detected`` (and ``entry_detected``: the steering
  detection, when there is one, is the entry's), ``events``, ``overflow``, and the outcomes
  ``reached``, ``entered``, ``collided``, ``success`` (latched).
* ``reward``: progress towards the target pipe (decrease of the head's
  distance to it, m), plus 1 at success: not the paper's (which has none),
  for learning baselines.
* ``done = 1`` on success (standing pipe: the head within 0.3 m of its
  surface; lying pipe: the head in the bore, `robots.snake.pipes.entered`),
  on a collision with a standing pipe, and at ``max_steps``.

A lying pipe's wall is touched all the way in by a snake crawling in its
bore, so a collision ends an episode only with a standing pipe; it is
recorded for both.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from brax.envs.base import Env, State

from robots.snake import camera as cam
from robots.snake import pipes
from robots.snake.calibration import SWING
from robots.snake.env import SNAKE_SPEED
from robots.snake.gait import GaitParams, gait_params, gait_period, joint_targets
from robots.snake.physics import joint_qpos_index, make_physics, start_at
from spikejax.errors import UserError
from spikejax.vision import detect, dvs, hough, stream

__all__ = [
    "CONTRAST_DVS",
    "DISTANCE_POOLING",
    "DISTANCE_REFINEMENTS",
    "DVS_MODELS",
    "PipeEnv",
    "PipeEnvParams",
    "default_tracker",
    "gait_targets",
    "rollout",
    "rollout_slots",
    "rollout_start",
]

DVS_MODELS = ("frame", "contrast")
CONTRAST_DVS = dvs.dvs_params(pos_threshold=0.6, neg_threshold=0.6)
"""The env's contrast-threshold DVS: 0.6 log units each way, no mismatch, noise or refractory period.

The scene's edges then cross 1 (the horizon: sky 0.8 over floor 0.4, 0.69), 2 (a dark wall of 0.1
against the floor) or 3 levels (against the sky); the largest contrast, a bore of 0.05 against the sky
(2.75), crosses 4, the env's default ``max_per_pixel``. Measured: about 3 times the frame-difference
DVS's events (852 against 288 a step over 16 standing-pipe episodes of 30 s, docs/BENCHMARKS.md)."""


DISTANCE_REFINEMENTS = dict(off_axis=True, speed=SNAKE_SPEED)
"""Alg. 3's Eq. (8) in the loop, beyond the snake pipe-tracking paper (`spikejax.vision.pipe.TrackParams`);
how long it pools (``smooth``) is `DISTANCE_POOLING`'s, per kind of pipe.

The distance divided by the cosine of the pipe's bearing, and the median of the
last 10 detections' distances within 3 s, each brought forward by the snake's
speed times its age. Measured offline on the body detections of 32
standing-right episodes (40 s): the mean |d_est - depth| over 0.5-3 m of true
depth falls from 0.177 m (Eq. 8 as the snake pipe-tracking paper has it) to 0.171 m (the bearing alone),
0.127 m (the pooling alone) and 0.102 m (both); the pooling without bringing
the samples forward reads 12 % long at 0.5-1 m (docs/BENCHMARKS.md, "Snake
pipe loop: the reproduction")."""


DISTANCE_POOLING = {"body": (20, 2.0), "entry": (10, 3.0)}
"""What Alg. 3 of the snake pipe-tracking paper pools per detected kind: ``(detections, seconds)``,
`spikejax.vision.stream.Tracker`'s ``pool`` and `spikejax.vision.pipe.TrackParams`'s ``smooth``
(`default_tracker` takes the body's when it runs the line grid; `PipeEnv` the smoothing of its pipe's kind).

The body: every detection of the last 2 s (20 slots) instead of the last 10 within 3 s. On the default
standing run (256 placements a side) the mean |d_est - depth| over 0.5-3 m falls from 0.102 / 0.103 m to
0.099 / 0.100 m, each 0.5 m bin of those lower, standing-left 255 / 256 reached both ways, standing-right 248 against
250 / 256; the detections of too narrow pairs, 12 % of them, come when the pipe sweeps across the image faster
than 3 px a step (30 % of those against 7 %), clustered in the head's swing, and more of them are outvoted.
The entry keeps 10 within 3 s: pooling 20 over 2 s reads 0.216 against 0.213 m offline on 16 lying-right
placements (docs/BENCHMARKS.md, "Snake pipe loop: the reproduction")."""


class PipeEnvParams(NamedTuple):
    """The task's traced quantities (float32 scalars), kept in ``info["params"]``.

    Attributes:
        max_steer: ``C_o`` at full action, rad.
        event_threshold: frame-difference threshold on grey levels in (0, 1].
        narrow: the gait's lateral amplitude factor at ``action[1] = 1``, in (0, 1].
    """

    max_steer: jax.Array
    event_threshold: jax.Array
    narrow: jax.Array


NEAR_RADII = 48  # `default_tracker(near=True)`: radii 4-98 sensor pixels in steps of 2
NEAR_TOP = 32  # sensor rows of circle centres above the image


def default_tracker(
    circle: bool = False, sub_slots: int = 5, line: bool = True, circle_bin: int = 1, near: bool = False
) -> stream.Tracker:
    """The loop's detector: the paper's 180 x 180 line grid in sync mode, slots of ``sub_slots`` steps.

    ``line=False`` (with ``circle=True``) drops the line grid and steers by
    the entry alone, as the paper detects a lying pipe (its Sec. 3.2: lines
    for a standing pipe, a circle for a lying one). The reproduction's lying
    situations run so: with both grids, the line grid found no body in any
    slot of 32 lying-right episodes, and it costs about a fifth of the loop.

    ``circle=True`` adds the circle grid (lying pipes' entries) at a reduced
    size (centres every pixel, 32 radii from 4 to 66 px in steps of 2: the
    ring of the default 0.52 m entry between 0.44 and 7 m), updated once per
    slot on the slot's events (`spikejax.vision.stream.Tracker`'s
    ``circle_per_slot``: its votes, a convolution per radius, cost about ten
    times the line grid's), steering by the entry when it is seen, else the
    body. Against radii 4-35 in steps of 1 (the same cost), measured on 16
    lying-right placements: the ring is found down to 0.44 m instead of 0.82
    m, and the mean error of the entry's distance (Eq. 8 of the snake
    pipe-tracking paper) falls from 0.13-0.24
    to 0.10-0.14 m between 0.7 and 2 m of true depth (0.28 against 0.44 m at
    2-3 m): the 2 px annulus each radius votes on matches the width of a
    frame-difference edge better (docs/BENCHMARKS.md, "Snake pipe loop: the
    reproduction").

    ``near=True`` extends the circle grid for the last metre to a lying
    entry: NEAR_RADII radii (4-98 sensor pixels), centres from NEAR_TOP
    sensor rows above the image (`spikejax.vision.detect.Detector`'s
    ``circle_top``: the ring's centre, above the camera, leaves the image
    near 0.4 m) and rings 0.3 in view (`spikejax.vision.detect.NEAR_ENTRY`).
    On 16 lying-left episodes (40 s) the ring was found in 94 % of the slots
    at 0.3-0.45 m of true depth instead of 48 %, and in 84-70 % nearer
    (wrong more often: its side right 81 % of the time at 0.2-0.3 m); a lying
    slot costs about 1.5 times as much (docs/BENCHMARKS.md, "Snake pipe
    loop: the reproduction").
    """
    if not (line or circle):
        raise UserError("default_tracker needs the line grid, the circle grid or both")
    if circle_bin not in (1, 2):
        raise UserError(
            f"circle_bin must be 1 or 2 (the radii are 4-66 sensor pixels in steps of 2), not {circle_bin!r}"
        )
    b = circle_bin
    top, n_r = (NEAR_TOP // b, NEAR_RADII) if near else (0, 32)
    grid = hough.CircleGrid(width=128 // b, height=128 // b + top, n_r=n_r, r_min=4.0 / b, r_step=2.0 / b)
    det = detect.Detector(
        line=hough.LineGrid() if line else None,
        circle=grid if circle else None,
        mode="sync",
        sub_slots=sub_slots,
        circle_bin=b,
        circle_top=top if circle else 0,
    )
    target = ("any" if line else "entry") if circle else "body"
    pool = DISTANCE_POOLING["body" if line else "entry"][0]
    return stream.Tracker(det, pool=pool, window=SWING.window, target=target, circle_per_slot=circle)


def gait_targets(gait: GaitParams, params: PipeEnvParams, t, action, compensate: bool = True) -> jax.Array:
    """The joints' targets for an action: Eq. (1) of the snake R-STDP paper steered by ``action[0]``, narrowed by ``action[1]``.

    ``C_o = action[0] * max_steer``; the lateral amplitude ``A_o`` times
    ``1 - max(action[1], 0) (1 - narrow)``; head-compensated when
    ``compensate`` (`robots.snake.gait.joint_targets`). ``action`` is taken
    as given (`PipeEnv.step` clips it to [-1, 1]).
    """
    amplitude = 1.0 - jnp.maximum(action[1], 0.0) * (1.0 - params.narrow)
    gait = gait._replace(A_o=gait.A_o * amplitude)
    return joint_targets(gait, t, action[0] * params.max_steer, 0.0, compensate)


class PipeEnv(Env):
    """Reach (standing) or enter (lying) a pipe with the slithering snake (see the module docstring).

    Args:
        backend: physics backend, ``"mujoco"`` or ``"mjx"``.
        scene: a fixed `robots.snake.pipes.PipeScene` (e.g. from
            `robots.snake.pipes.load_scene`) used by every ``reset`` unless
            it is given one; default: each reset samples a situation.
        situation: the sampled situation's name (`robots.snake.pipes.SITUATIONS`)
            when there is no scene; ``reset(key, scene=...)`` overrides both.
        placement: the sampler's ranges and sizes.
        tracker: the streaming detector's static configuration
            (default `default_tracker`: the line grid, sync).
        tracker_params: its traced parameters (default
            `spikejax.vision.stream.tracker_params` with the known size of
            the target kind for Alg. 3 of the snake pipe-tracking paper, and
            this snake's camera-offset fit `SWING`).
        max_steps: control steps before the episode times out.
        max_steer: ``C_o`` at full action, rad; 0.1 reached the most pipes of
            0.05, 0.1 and 0.15 on standing pipes 25-28 degrees aside
            (docs/ARCHITECTURE.md, "The closed pipe loop").
        event_threshold, event_capacity: the frame-difference DVS (the
            capacity serves both DVS models).
        dvs: ``"frame"`` (frame differences, all events at the step's end)
            or ``"contrast"`` (the contrast-threshold emulator, events at
            their crossing times inside the step; its state and parameters
            ride in ``info["dvs_state"]`` / ``info["dvs_params"]``, the
            mismatch and noise drawn from the reset's key).
        dvs_params: the contrast emulator's parameters (default
            `CONTRAST_DVS`); ``max_per_pixel``: its crossings kept per pixel
            and step (the rest are counted in ``overflow``).
        compensate: the gait's head compensation.
        gait: the gait's parameters.
        narrow: the factor on the gait's lateral amplitude at ``action[1] =
            1``, in (0, 1] (`robots.snake.pipe_controller`'s ``narrow``
            uses it in the blind last stretch; 0.3 barely moves the snake).
        vision: ``False`` runs no camera, DVS or detector in `step` (the
            slots still end every ``slot_steps`` steps, with no detections):
            for controllers that read only the truth, such as the
            reproduction's baselines, at the cost of the physics alone.
        random_phase: start the gait at a phase drawn from the reset's key
            (its time offset uniform over one period, ``info["gait_t0"]``);
            ``False``: every episode at phase 0. Half a period later the
            gait steered by ``-C_o`` is the mirror image of the gait steered
            by ``C_o`` (the lateral wave changes sign, the dorsal one, at
            twice the frequency, does not), so over random phases a scene
            and its mirror image are the same task; at one fixed phase they
            are not (the snake's start differs, and so does every turn).
        entry_memory: the weight, in (0, 1], with which each entry detection
            at the distance of Alg. 3 of the snake pipe-tracking paper ``>=
            MEMORY_MIN_DEPTH`` moves the remembered entry (`remember_entry`:
            the detection placed in the world by the head camera's pose, an
            exponential average); 0 (default): none.
            ``info["mem_depth"]`` / ``info["mem_side"]`` give the remembered
            entry in the camera's frame at every step, ``info["mem_ok"]``
            whether there is one; `robots.snake.pipe_controller`'s ``memory``
            steers by it.
        circle_every: the circle grid updates at every ``circle_every``-th
            slot's end in `rollout` (on the events of its last
            ``circle_window`` slots; `spikejax.vision.stream.slot_end`'s
            ``circle_update``), for a tracker with ``circle_per_slot`` and no
            line grid; 1 (default): every slot. The other slot ends detect
            nothing; the controller still acts at each (the remembered entry
            steers there). `step` called without ``slot_end`` (Brax's call)
            updates it every slot.
        circle_window: the slots of events each update sees with
            ``circle_every > 1``: the last ``circle_window`` of its group (the
            earlier slots' event images dropped, ``keep_events`` of
            `spikejax.vision.stream.slot_end`); default ``circle_every``, all of
            them.
        physics_kwargs: passed to `robots.snake.physics.make_physics`.
    """

    def __init__(
        self,
        backend: str = "mujoco",
        *,
        scene: pipes.PipeScene | None = None,
        situation: str = "standing-right",
        placement: pipes.Placement = pipes.Placement(),
        tracker: stream.Tracker | None = None,
        tracker_params: stream.TrackerParams | None = None,
        max_steps: int = 1500,
        max_steer: float = 0.1,
        event_threshold: float = 0.05,
        event_capacity: int = 2048,
        compensate: bool = True,
        gait: GaitParams | None = None,
        dvs: str = "frame",
        dvs_params: dvs.DVSParams | None = None,
        max_per_pixel: int = 4,
        narrow: float = 0.5,
        vision: bool = True,
        random_phase: bool = False,
        entry_memory: float = 0.0,
        circle_every: int = 1,
        circle_window: int | None = None,
        **physics_kwargs: Any,
    ):
        if situation not in pipes.SITUATIONS:
            raise UserError(f"situation must be one of {', '.join(pipes.SITUATIONS)}, not {situation!r}")
        if isinstance(max_steps, bool) or not isinstance(max_steps, int) or max_steps < 1:
            raise UserError(f"max_steps must be a whole number of control steps >= 1, got {max_steps!r}")
        if event_capacity < 1:
            raise UserError(f"event_capacity must be at least 1, got {event_capacity}")
        if not 0 < event_threshold <= 1:
            raise UserError(f"event_threshold must be in (0, 1], got {event_threshold}")
        if not max_steer > 0:
            raise UserError(f"max_steer must be positive, got {max_steer}")
        if not 0 < narrow <= 1:
            raise UserError(f"narrow must be in (0, 1], got {narrow}")
        if dvs not in DVS_MODELS:
            raise UserError(f"dvs must be one of {', '.join(DVS_MODELS)}, not {dvs!r}")
        if isinstance(max_per_pixel, bool) or not isinstance(max_per_pixel, int) or max_per_pixel < 1:
            raise UserError(f"max_per_pixel must be a whole number >= 1, got {max_per_pixel!r}")
        self.dvs = dvs
        self.vision = bool(vision)
        self.dvs_params = CONTRAST_DVS if dvs_params is None else dvs_params
        self.max_per_pixel = max_per_pixel
        self.scene = scene
        self.situation = situation
        self.placement = placement
        bodies = pipes.default_bodies(1, placement) if scene is None else pipes.bodies_for(scene)
        self.physics = make_physics(backend, pipes=bodies, **physics_kwargs)
        model = self.physics.mj_model
        self._joints = np.asarray(joint_qpos_index(model))
        self._dofs = np.array([model.jnt_dofadr[model.joint(f"joint{i}").id] for i in range(1, 17)])
        self.tracker = default_tracker() if tracker is None else tracker
        if tracker_params is None:
            kind = pipes.SITUATIONS[situation][0] if scene is None else int(np.asarray(scene.kind)[0])
            size = 2 * (placement.lying_radius if kind == pipes.LYING else placement.standing_radius)
            if scene is not None:
                size = 2 * float(np.asarray(scene.radius)[0])
            smooth = DISTANCE_POOLING["entry" if kind == pipes.LYING else "body"][1]
            track = SWING.track_params(
                size=size,
                width=cam.HEAD_CAMERA.width,
                fov=cam.HEAD_CAMERA.fov,
                smooth=smooth,
                **DISTANCE_REFINEMENTS,
            )
            tracker_params = stream.tracker_params(self.tracker, track=track)
        self.tracker_params = tracker_params
        self.max_steps = max_steps
        self.event_capacity = int(event_capacity)
        self.params = PipeEnvParams(jnp.float32(max_steer), jnp.float32(event_threshold), jnp.float32(narrow))
        self.compensate = bool(compensate)
        self.random_phase = bool(random_phase)
        if not 0.0 <= entry_memory <= 1.0:
            raise UserError(f"entry_memory must be in [0, 1], got {entry_memory}")
        self.entry_memory = float(entry_memory)
        if isinstance(circle_every, bool) or not isinstance(circle_every, int) or circle_every < 1:
            raise UserError(f"circle_every must be a whole number of slots >= 1, got {circle_every!r}")
        if circle_every > 1 and not (self.tracker.circle_per_slot and self.tracker.detector.line is None):
            raise UserError("circle_every > 1 needs a tracker with the circle grid per slot and no line grid")
        self.circle_every = circle_every
        window = circle_every if circle_window is None else circle_window
        if isinstance(window, bool) or not isinstance(window, int) or not 1 <= window <= circle_every:
            raise UserError(f"circle_window must be a whole number of slots in [1, circle_every], got {window!r}")
        self.circle_window = window
        self.gait = gait_params() if gait is None else gait
        self.window = max(1, int(round(float(gait_period(self.gait)) / self.dt)))

    # ------------------------------------------------------------ Brax interface

    @property
    def dt(self) -> float:
        """Control step, s."""
        return self.physics.dt * self.physics.substeps

    @property
    def slot_steps(self) -> int:
        """Control steps per detector slot (the tracker's ``slot_steps``), as a host int."""
        return int(np.asarray(self.tracker_params.slot_steps))

    @property
    def observation_size(self) -> int:
        return 32

    @property
    def action_size(self) -> int:
        return 2

    @property
    def backend(self) -> str:
        return self.physics.backend

    def sample_scene(self, key: jax.Array, situation: str | None = None) -> pipes.PipeScene:
        """A random scene of ``situation`` (default the env's) from ``key``."""
        kind, side = pipes.SITUATIONS[self.situation if situation is None else situation]
        return pipes.sample(key, kind, side, self.placement)

    def reset(self, rng: jax.Array, scene: pipes.PipeScene | None = None, params: PipeEnvParams | None = None) -> State:
        """The snake at rest at the scene's start, the pipes placed; the detector empty.

        ``scene`` defaults to the env's fixed scene, else a sample of its
        situation from ``rng``; it may be traced, so a batch of placements
        runs in one program (the pipes' sizes must be the model's).
        """
        if scene is None:
            scene = self.scene if self.scene is not None else self.sample_scene(rng)
        params = self.params if params is None else PipeEnvParams(*(jnp.asarray(x, jnp.float32) for x in params))
        phys = self.physics.init()
        phys = start_at(phys, scene.start[0], scene.start[1], scene.start[2])
        gait_t0 = jnp.zeros((), jnp.float32)
        if self.random_phase:
            key = jax.random.fold_in(rng, _PHASE_TAG)
            gait_t0 = jax.random.uniform(key, (), jnp.float32, 0.0, gait_period(self.gait))
        phys = pipes.place_pipes(phys, scene)
        frame = self._frame(phys, scene)
        events, _ = dvs.frame_difference(frame, frame, phys.time, threshold=1.0, capacity=self.event_capacity)
        tracker_state = stream.init(self.tracker, phys.time)
        zero, no = jnp.zeros((), jnp.float32), jnp.zeros((), bool)
        com = jnp.broadcast_to(phys.com_pos[:2], (2 * self.window, 2))
        info = {
            "rng": rng,
            "params": params,
            "scene": scene,
            "frame": frame,
            "events": events,
            "overflow": jnp.zeros((), jnp.int32),
            "tracker": tracker_state,
            "slot": stream.no_slot(self.tracker, tracker_state, phys.time),
            "ended": no,
            "com_ring": com,
            "control_steps": jnp.zeros((), jnp.int32),
            "reached": no,
            "entered": no,
            "collided": no,
            "success": no,
            "success_step": jnp.full((), -1, jnp.int32),
            "d_est": zero,
            "offset_est": zero,
            "side_est": zero,
            "distance": self._distance(phys, scene),
            "gait_t0": gait_t0,
            "mem": jnp.zeros(3, jnp.float32),
            "mem_ok": no,
            "mem_depth": zero,
            "mem_side": zero,
        }
        if self.dvs == "contrast":
            key = jax.random.fold_in(rng, _DVS_TAG)
            info["dvs_key"] = key
            info["dvs_params"] = self.dvs_params
            info["dvs_state"] = dvs.init(self.dvs_params, frame, phys.time, key=jax.random.fold_in(key, 0))
        return State(
            pipeline_state=phys,
            obs=self._obs(phys),
            reward=zero,
            done=zero,
            metrics=self._metrics(phys, scene, info),
            info=info,
        )

    def circle_schedule(self) -> tuple[tuple[bool, bool], ...]:
        """Per slot of a group of ``circle_every``: ``(circle_update, keep_events)`` of `step` at its end."""
        every, window = self.circle_every, self.circle_window
        return tuple((i == every - 1, i >= every - window) for i in range(every))

    def step(
        self,
        state: State,
        action: jax.Array,
        slot_end: bool | None = None,
        circle_update: bool = True,
        keep_events: bool = True,
    ) -> State:
        """One control step (see the module docstring).

        ``slot_end``: ``None`` (Brax's call) ends the detector's slot when it
        is due, decided per step; ``True`` / ``False`` (static) says whether
        this step ends a slot, for loops that know it (`rollout`).
        ``circle_update`` (static, with ``slot_end=True``): ``False`` skips
        the circle grid at this slot's end (``circle_every``), ``keep_events``
        (static) whether its events wait for the next update (`circle_schedule`).
        """
        action = jnp.clip(jnp.asarray(action, jnp.float32), -1.0, 1.0)
        info = dict(state.info)
        params, scene = info["params"], info["scene"]
        phys = state.pipeline_state
        ctrl = gait_targets(self.gait, params, phys.time + info["gait_t0"], action, self.compensate)
        phys = self.physics.step(phys, ctrl)
        if not self.vision:
            return self._blind_step(state, info, phys, slot_end)
        tr, tp = self.tracker, self.tracker_params
        frame = self._frame(phys, scene)
        if self.dvs == "contrast":
            key = jax.random.fold_in(info["dvs_key"], info["control_steps"] + 1)
            info["dvs_state"], events, overflow = dvs.step(
                info["dvs_params"], info["dvs_state"], frame, phys.time,
                capacity=self.event_capacity, max_per_pixel=self.max_per_pixel, key=key,
            )  # fmt: skip
        else:
            events, overflow = dvs.frame_difference(
                info["frame"], frame, phys.time, threshold=params.event_threshold, capacity=self.event_capacity
            )
        angle, velocity = phys.qpos[self._joints[0]], phys.qvel[self._dofs[0]]
        tstate = stream.step(tr, tp, info["tracker"], events, phys.time, angle, velocity)
        if slot_end is None:
            ended = stream.due(tp, tstate)
            tstate, out = jax.lax.cond(
                ended,
                lambda s: stream.slot_end(tr, tp, s, phys.time),
                lambda s: (s, stream.no_slot(tr, s, phys.time)),
                tstate,
            )
        elif slot_end:
            tstate, out = stream.slot_end(tr, tp, tstate, phys.time, circle_update, keep_events)
            ended = jnp.ones((), bool)
        else:
            out, ended = stream.no_slot(tr, tstate, phys.time), jnp.zeros((), bool)
        slot = jax.tree.map(lambda new, old: jnp.where(ended, new, old), out, info["slot"])
        slot = slot._replace(control=out.control)
        est = _steering_estimate(tr, out)
        info.update(frame=frame, events=events, overflow=overflow, tracker=tstate, slot=slot, ended=ended)
        info.update(
            d_est=jnp.where(ended & est.valid, est.distance, info["d_est"]),
            offset_est=jnp.where(ended & est.valid, est.offset, info["offset_est"]),
            side_est=jnp.where(ended & est.valid, est.pipe_offset, info["side_est"]),
        )
        if self.entry_memory > 0:
            seen = ended & out.entry.valid & (info["d_est"] >= MEMORY_MIN_DEPTH)
            mem, ok = remember_entry(
                info["mem"], info["mem_ok"], seen, phys.head_pos, phys.head_mat,
                info["d_est"], info["side_est"], self.entry_memory,
            )  # fmt: skip
            depth, side = entry_in_view(mem, phys.head_pos, phys.head_mat)
            info.update(mem=mem, mem_ok=ok, mem_depth=depth, mem_side=side)
        return self._outcome(state, info, phys)

    def _blind_step(self, state: State, info: dict, phys, slot_end) -> State:
        """`step` with ``vision=False``: the physics and the outcomes; the slots end on time, with no detections."""
        if slot_end is None:
            ended = (info["control_steps"] + 1) % self.tracker_params.slot_steps == 0
        else:
            ended = jnp.asarray(bool(slot_end))
        info.update(overflow=jnp.zeros((), jnp.int32), ended=ended)
        return self._outcome(state, info, phys)

    def _outcome(self, state: State, info: dict, phys) -> State:
        """The step's truth, outcomes and `State` from the stepped physics and the detector's ``info``."""
        scene = info["scene"]
        n = info["control_steps"] + 1
        reached = pipes.reached(phys.head_pos, scene)[0]
        entered = pipes.entered(phys.head_pos, phys.head_mat, scene)[0]
        collided = pipes.collided(phys.qpos, scene)[0]
        lying = scene.kind[0] == pipes.LYING
        success_now = jnp.where(lying, entered, reached)
        success = info["success"] | success_now
        distance = self._distance(phys, scene)
        info.update(
            com_ring=info["com_ring"].at[info["control_steps"] % (2 * self.window)].set(phys.com_pos[:2]),
            control_steps=n,
            reached=info["reached"] | reached,
            entered=info["entered"] | entered,
            collided=info["collided"] | collided,
            success=success,
            success_step=jnp.where(success_now & ~info["success"], n, info["success_step"]),
            distance=distance,
        )
        done = success | (collided & ~lying) | (n >= self.max_steps)
        reward = (state.info["distance"] - distance) + success_now.astype(jnp.float32)
        return state.replace(
            pipeline_state=phys,
            obs=self._obs(phys),
            reward=reward,
            done=done.astype(jnp.float32),
            metrics=self._metrics(phys, scene, info),
            info=info,
        )

    # ------------------------------------------------------------ parts

    def _frame(self, phys, scene):
        return cam.frame(phys, cam.pipe_scene(pipes.render_pipes(scene)))

    def _distance(self, phys, scene):
        entry = pipes._axis_frame(scene)[0][0]
        point = jnp.where(scene.kind[0] == pipes.LYING, entry[:2], scene.xy[0])
        return jnp.linalg.norm(point - phys.head_pos[:2])

    def _obs(self, phys):
        return jnp.concatenate([phys.qpos[self._joints], phys.qvel[self._dofs]])

    def central_line(self, info):
        """The central line: the centre of mass averaged over the last gait period, and its heading.

        The heading is the direction from the centre of mass averaged over the
        period before the last to that averaged over the last one (whole
        periods, so the swing averages out; it lags a turn by a period).
        Before two periods have passed, the start's heading.
        """
        ring = info["com_ring"]
        n = self.window
        order = (info["control_steps"] + jnp.arange(2 * n)) % (2 * n)  # oldest first once the ring is full
        path = ring[order]
        older, newer = jnp.mean(path[:n], axis=0), jnp.mean(path[n:], axis=0)
        heading = jnp.arctan2(newer[1] - older[1], newer[0] - older[0])
        heading = jnp.where(info["control_steps"] >= 2 * n, heading, info["scene"].start[2])
        return newer, heading

    def _metrics(self, phys, scene, info):
        truth = pipes.truth(phys.head_pos, phys.head_mat, scene, cam.HEAD_CAMERA)
        point, heading = self.central_line(info)
        slot = info["slot"]
        f32 = lambda x: jnp.asarray(x, jnp.float32)  # noqa: E731
        return {
            "depth": truth.depth[0],
            "lateral": truth.lateral[0],
            "offset_true": pipes.line_offset(scene, point, heading)[0],
            "d_est": info["d_est"],
            "offset_est": info["offset_est"],
            "control": f32(slot.control),
            "detected": f32(info["ended"] & (slot.body.valid | slot.entry.valid)),
            "entry_detected": f32(info["ended"] & slot.entry.valid),
            "in_view": f32(truth.in_view[0]),
            "distance": info["distance"],
            "events": f32(info["events"].count()),
            "overflow": f32(info["overflow"]),
            "reached": f32(info["reached"]),
            "entered": f32(info["entered"]),
            "collided": f32(info["collided"]),
            "success": f32(info["success"]),
        }


_PHASE_TAG = 0x47414954  # folded into the reset's key for the gait's start phase
_DVS_TAG = 0x44565321  # folded into the reset's key for the contrast DVS's mismatch and noise


MEMORY_MIN_DEPTH = 0.3
"""The distance of Alg. 3 of the snake pipe-tracking paper, m, below which an entry detection no longer moves the
remembered entry: below it the ring outgrows the near circle grid and its side is right in 54-81 % of the slots
(against 86-96 % from 0.3 to 1.2 m)."""


def remember_entry(mem, ok, seen, cam_pos, cam_rot, depth, side, weight):
    """The remembered entry after a slot: ``seen``'s detection, ``depth`` ahead and ``side`` to the right of the head
    camera at ``cam_pos`` (3,) with ``cam_rot``'s columns its forward, left and up axes, placed in the world and
    averaged into ``mem`` (3,) with ``weight`` (the first detection is taken whole). Returns ``(mem, ok)``.

    Only differences of the camera's pose enter the steering (`entry_in_view`), so the world frame stands for
    what the head's odometry (an IMU and the joint angles) would integrate over the seconds of an approach; here
    the physics' pose, exact.
    """
    point = cam_pos + depth * cam_rot[:, 0] - side * cam_rot[:, 1]
    moved = jnp.where(ok, (1.0 - weight) * mem + weight * point, point)
    return jnp.where(seen, moved, mem), ok | seen


def entry_in_view(mem, cam_pos, cam_rot):
    """``(depth, side)`` of the remembered point ``mem`` in the camera's frame: m ahead, m to the right."""
    rel = mem - cam_pos
    return rel @ cam_rot[:, 0], -(rel @ cam_rot[:, 1])


def _steering_estimate(tracker: stream.Tracker, out: stream.SlotOutput):
    """The estimate (Alg. 3 of the snake pipe-tracking paper) of the detection that steers (the tracker's ``target``)."""
    if tracker.target == "body":
        return out.body_estimate
    if tracker.target == "entry":
        return out.entry_estimate
    return jax.tree.map(lambda e, b: jnp.where(out.entry.valid, e, b), out.entry_estimate, out.body_estimate)


def rollout(env: PipeEnv, controller, controller_params, key: jax.Array, slots: int, scene=None, params=None):
    """``slots`` detector slots of ``env`` driven by ``controller``: a scan of slots, each a scan of steps.

    ``controller`` is an ``(init, act)`` pair (`robots.snake.pipe_controller`):
    ``init()`` gives its state, ``act(params, cstate, state) -> (cstate,
    action)`` is called before every step. Pure; jit and vmap it over keys
    (and scenes). Returns the per-step record (metrics, done, the
    controller's mode and action, the head's floor position), leaves ``(slots * K, ...)``,
    and the final `brax.envs.base.State`. The episode runs on after ``done``
    (the record says when); the outcomes in ``metrics`` are latched.
    `rollout_start` and `rollout_slots` are its two halves, for a loop that
    runs an episode in parts (and stops once every episode of a batch is done).
    """
    _check_slots(env, slots)  # before the reset, which runs op by op (seconds) when called outside jit
    carry = rollout_start(env, controller, key, scene, params)
    (final, _), record = rollout_slots(env, controller, controller_params, carry, slots)
    return record, final


def rollout_start(env: PipeEnv, controller, key: jax.Array, scene=None, params=None):
    """The carry of `rollout_slots` at an episode's start: ``(env.reset(key, scene, params), init())``."""
    return env.reset(key, scene, params), controller[0]()


def _check_slots(env: PipeEnv, slots: int) -> None:
    """A one-line error unless ``slots`` is whole groups of ``env.circle_every``."""
    if slots % env.circle_every:
        raise UserError(f"rollout_slots runs whole groups of circle_every = {env.circle_every} slots, not {slots}")


def rollout_slots(env: PipeEnv, controller, controller_params, carry, slots: int):
    """``slots`` more slots from ``carry`` (`rollout_start`'s or an earlier call's): ``(carry, record)``."""
    act = controller[1]
    k = env.slot_steps

    def one(carry, end, circle_update=True, keep_events=True):
        s, c = carry
        c, action = act(controller_params, c, s)
        s = env.step(s, action, slot_end=end, circle_update=circle_update, keep_events=keep_events)
        rec = {
            "metrics": s.metrics,
            "done": s.done,
            "mode": c.mode,
            "action": action[0],
            "head": s.pipeline_state.head_pos[:2],
        }
        return (s, c), rec

    _check_slots(env, slots)
    every = env.circle_every

    def slot(carry, schedule):
        carry, inner = jax.lax.scan(lambda c, _: one(c, False), carry, None, length=k - 1)
        carry, last = one(carry, True, *schedule)
        return carry, jax.tree.map(lambda a, b: jnp.concatenate([a, b[None]]), inner, last)

    def group(carry, _):  # the circle grid updates at the group's last slot end (static)
        recs = []
        for schedule in env.circle_schedule():
            carry, rec = slot(carry, schedule)
            recs.append(rec)
        return carry, jax.tree.map(lambda *a: jnp.concatenate(a), *recs)

    carry, record = jax.lax.scan(group, carry, None, length=slots // every)
    record = jax.tree.map(lambda a: a.reshape((slots * k,) + a.shape[2:]), record)
    return carry, record
