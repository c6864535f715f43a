"""The hexapod's predator-prey loop as a Brax ``Env``: a trained SCPG walking the MJCF robot, its head camera, the visual SNN.

`HexapodEnv` subclasses `brax.envs.base.Env` and returns Brax's
`brax.envs.base.State`. It closes the loop of the hexapod SCPG paper (Sec. IV-V):
the gait chosen drives the gait-selection neurons of a trained SCPG
(`robots.hexapod.cpg`), whose spikes move the legs through the step primitive
(`robots.hexapod.legs`) on MuJoCo's C engine; the head camera
(`robots.hexapod.camera`) renders the prey, the DVS emulator turns the frames
into events and the visual SNN counts its gait neurons' spikes
(`robots.hexapod.decisions.decide`).

**One step is one decision: a gait cycle**, two CPG steps of ``dt_cpg`` =
0.16 s (`robots.hexapod.legs.step_params`), 0.32 s, 160 physics steps of 2 ms
and 16 camera frames 20 ms apart. The paper's "step" is a gait cycle ("takes
three forward steps", "7 neurons spike" a step) and its winner-take-all counts
the events of one step ("Locomotion ... generates a new set of events for
every step"), so a decision per CPG step would see half a stride.

Spaces:

* ``action``: the gait, ``0`` G1 forward, ``1`` G2 left, ``2`` G3 right
  (`robots.hexapod.vision.FORWARD`, ``LEFT``, ``RIGHT``), a scalar or a ``(1,)``
  array, rounded and clipped. It drives the chosen gait-selection neuron
  tonically (it spikes at every CPG step, Alg. 1's ``G_i = 1``). **When the
  gait changes the CPG is reset to rest** (potentials 0, no last spikes)
  before its first step: with the state carried over, only 11-73 % of
  converged networks reach the new pattern within a cycle, with the reset
  100 % (`robots.hexapod.switching`, ``spikejax reproduce gait-switching``).
  The legs are not reset: a leg's next spike starts its swing from where its
  hip is (`robots.hexapod.legs`).
* ``obs`` ``(6,)``: the gait neurons' spike counts over the step (G1, G2, G3)
  and the gait in force, one-hot; zeros and G1 after ``reset``.
* ``info``: ``gait_counts`` ``(3,)`` and ``wta`` (`spikejax.vision.edges.winner`
  over them, ties and silence keeping the gait in force: the paper's
  rate-coded winner-take-all); ``gait_counts_ordered`` and ``wta_ordered``, the
  same with the frame's layer-3 spikes reaching the gait neurons one at a time
  (`robots.hexapod.decisions.ordered_readout`, no ceiling of one spike a
  frame); ``events``, ``filter``, ``layer2``, ``layer3``
  (spike totals of the step's layers; ``events`` the DVS events into the
  filter), ``overflow`` (events that did not fit); ``cpg_spikes`` ``(2, 6)``
  (this step's CPG raster); ``torso`` ``(6,)`` the torso's world state
  ``(x, y, z, roll, pitch, yaw)``; the truth: ``truth_gait``
  (`robots.hexapod.prey.truth_gait` from the camera, the oracle's choice),
  ``nearest`` (slot), ``distance`` (m, from the camera) and ``bearing`` (rad);
  ``scene`` (a `robots.hexapod.prey.PreyScene`, captured prey removed),
  ``captures`` ``(MAX_PREY,)`` (the step each slot was captured at, -1 if not
  yet), ``order`` ``(MAX_PREY,)`` (the slots in order of capture, -1 padded),
  ``first_nearest`` (the slot nearest at the start), ``steps``.
* ``reward``: 1 at a capture, else 0. ``done``: every prey captured, the
  time limit (``seconds``, default 12.8 s = 40 steps, SPEC 4.4's budget), or
  every living prey behind the camera (``info["lost"]``, bearing beyond
  `LOST_BEARING` = 90 deg: "the prey left the field of view for good" of the
  reading notes; the paper's rule never turns toward a prey it cannot see, and
  a robot walking forward on silence keeps walking forward).

**Captured** is `robots.hexapod.prey.captured` from the camera's ground point,
with the near boundary of the decisions, ``D_NEAR + size / 2`` (the prey's
front face at the camera's near/far boundary), and a margin of 0.2 m: the
nearest living prey within it and within 15 deg of straight ahead, the paper's
"align itself directly in front of it". A captured prey is removed and the
loop goes on (the paper removes object 1 by hand, Sec. V-B); it is tested
after each step, once (not SPEC 4.4's "2 consecutive steps").

**Prey are only rendered** (`robots.hexapod.camera.prey_scene`'s boxes), never
physical: the robot stops short of them (it turns once they are near), so a
collision never happens in a capture. **The physics runs from the origin**
facing +x, and the track is moved rigidly to the scene's start for the camera
and the truth: the floor is flat and uniform, so this is the same walk, and one
standing state serves every scene. Prey positions and the start are traced
(``reset(rng, scene)``): new scenes never recompile.

**Robots** are drawn per episode from a pool of ``n_robots`` randomised models
(`robots.hexapod.physics.randomised`: friction +-30 %, mass and servo gain
+-20 %), each settled once (`robots.hexapod.physics.standing_state`); the
episode's index into the pool is traced. The C engine runs inside the jitted
step through ``jax.pure_callback`` with ``vmap_method="broadcast_all"`` (a
vmapped batch reaches C as one ``mujoco.rollout`` call on a persistent thread
pool), as the snake's `robots.snake.physics` does; what crosses is MuJoCo's
full physics state in float32 (on one CPU device: `jax.pure_callback` moves a
sharded batch's operands to the first CPU device, and two shards' callbacks at
once deadlocked at batch 64, so this backend is not split with
`spikejax.devices.shard_batch`; the C engine's threads use the cores). The
solver's warm start is not carried between
steps (it is not part of the state): each step starts it from zero.
``backend="mjx"`` steps the same pool with MJX inside the XLA program instead
(`robots.hexapod.physics.mjx_stepper`: one program on an accelerator, no host
round trip), from and to the same state; it walks as the C engine does within
the tolerances of ``tests/test_hexapod_loop.py``.

With ``see=False`` the camera, DVS and SNN are skipped (their info fields are
zeros): for controllers that read only the truth (the oracle, the random
baseline), at a fraction of the cost.
"""

from __future__ import annotations

import functools
import math
import os
import threading

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from brax.envs.base import Env, State
from mujoco import rollout as mj_rollout

from robots.hexapod import camera as cam
from robots.hexapod import decisions, physics
from robots.hexapod import prey as prey_mod
from robots.hexapod.cpg import CPGState, CPGWeights, cpg_init, cpg_step
from robots.hexapod.gaits import N_GAITS, N_LEGS, PERIOD
from robots.hexapod.legs import servo_targets, step_params
from robots.hexapod.training import TrainParams, gait_correct, train
from robots.hexapod.trial import GaitTrialParams
from robots.hexapod.vision import FORWARD, WIRING, check_wiring
from spikejax.errors import UserError
from spikejax.neurons import DiscreteLIFParams
from spikejax.vision import edges

__all__ = [
    "BACKENDS",
    "CAPTURE_MARGIN",
    "LOST_BEARING",
    "STEP_S",
    "HexapodEnv",
    "cpg_cycle",
    "trained_network",
    "world_track",
]

BACKENDS = ("mujoco", "mjx")
CAPTURE_MARGIN = 0.2  # m beyond the near boundary
LOST_BEARING = math.radians(90.0)  # every living prey behind the camera: the episode is lost
_STATE = mujoco.mjtState.mjSTATE_FULLPHYSICS
_FRAMES = decisions.N_FRAMES - 1  # frames rendered a step, after the reference frame
STEP_S = PERIOD * float(step_params().dt_cpg)  # s, one decision: a gait cycle


@functools.cache
def trained_network(seed: int = 0, tries: int = 16) -> CPGWeights:
    """The first of ``tries`` three-gait SCPGs (keys ``fold_in(key(seed), i)``) whose gaits all converge.

    Trained with the convergence study's settings (`robots.hexapod.trial.GaitTrialParams`,
    Alg. 1 of the hexapod SCPG paper). Raises `UserError` if none converges.
    """
    p = TrainParams(*(jnp.asarray(v, jnp.float32) for v in GaitTrialParams()))

    def one(i):
        w = train(p, key=jax.random.fold_in(jax.random.key(seed), i)).weights
        return jnp.all(gait_correct(p, w, 10)), w

    ok, weights = jax.jit(jax.vmap(one))(jnp.arange(tries))
    ok = np.asarray(ok)
    if not ok.any():
        raise UserError(f"none of {tries} SCPGs from seed {seed} converged")
    i = int(np.argmax(ok))
    return jax.tree.map(lambda a: a[i], weights)


def world_track(track: jax.Array, start: jax.Array) -> jax.Array:
    """Torso states ``(..., 6)`` walked from the origin facing +x, moved rigidly to start at ``start = (x, y, yaw)``."""
    c, s = jnp.cos(start[2]), jnp.sin(start[2])
    x = start[0] + c * track[..., 0] - s * track[..., 1]
    y = start[1] + s * track[..., 0] + c * track[..., 1]
    return jnp.stack([x, y, track[..., 2], track[..., 3], track[..., 4], track[..., 5] + start[2]], axis=-1)


def cpg_cycle(
    neuron: DiscreteLIFParams, weights: CPGWeights, state: CPGState, previous: jax.Array, gait: jax.Array
) -> tuple[CPGState, jax.Array]:
    """One decision's CPG: `PERIOD` steps with ``gait``'s neuron on, from rest if ``gait != previous``.

    The reset at a gait change is `robots.hexapod.switching`'s finding: carried
    over, 11-73 % of converged networks reach the new pattern within a cycle;
    reset, 100 %. Returns the new state and the raster ``(PERIOD, 6)``.
    """
    changed = jnp.asarray(gait) != jnp.asarray(previous)
    state = jax.tree.map(lambda rest, s: jnp.where(changed, rest, s), cpg_init(), state)
    drive = jax.nn.one_hot(gait, N_GAITS, dtype=jnp.float32)
    return jax.lax.scan(lambda s, _: cpg_step(neuron, weights, s, drive), state, None, length=PERIOD)


class _Runner:
    """Steps a batch of robots of the pool through one decision's servo targets on MuJoCo's C engine (host side)."""

    def __init__(self, models: list, nthread: int, frame_every: int):
        self.models = models
        self.nq = models[0].nq
        self.frame_every = frame_every
        self.nthread = nthread
        self.datas = [mujoco.MjData(models[0]) for _ in range(nthread)]
        self.pool = mj_rollout.Rollout(nthread=nthread)
        self.lock = threading.Lock()

    def __call__(self, state, robot, controls):
        batch_shape = robot.shape
        n = int(np.prod(batch_shape, dtype=np.int64))
        state = np.asarray(state, np.float64).reshape(n, -1)
        controls = np.ascontiguousarray(np.asarray(controls, np.float64).reshape(n, *controls.shape[-2:]))
        models = [self.models[int(r)] for r in np.asarray(robot).reshape(n)]
        with self.lock:
            states, _ = self.pool.rollout(models, self.datas, state, controls)
        frames = states[:, self.frame_every - 1 :: self.frame_every]
        w = physics.torso_walk(np.zeros(frames.shape[1]), frames[..., 1 : 1 + self.nq])
        torso = np.stack([w.xy[..., 0], w.xy[..., 1], w.height, w.roll, w.pitch, w.yaw], axis=-1)
        return (
            states[:, -1].astype(np.float32).reshape(*batch_shape, -1),
            torso.astype(np.float32).reshape(*batch_shape, frames.shape[1], 6),
        )


class HexapodEnv(Env):
    """Hunt prey with the hexapod: the gait is the action, the visual SNN's counts the observation (module docstring).

    Args:
        backend: physics backend: ``"mujoco"`` (MuJoCo's C engine, the choice on a CPU) or ``"mjx"``
            (MJX in the XLA program, the choice on an accelerator).
        n_robots: randomised robots in the pool (`physics.randomised`), one drawn per episode.
        robot_seed: seed of the pool's randomisation.
        network_seed: seed of the trained SCPG (`trained_network`).
        seconds: time limit of an episode, s (rounded to whole steps of `STEP_S`).
        see: render, emulate the DVS and run the visual SNN each step.
        nthread: C threads (default: the cores).
        lens: where the head camera's optical axis meets its sensor
            (`robots.hexapod.camera.LENSES`; default centred on the windows).
        wiring: the visual SNN's readout onto the gait neurons
            (`robots.hexapod.vision.WIRINGS`; default with the near windows' veto on G1).
    """

    def __init__(
        self,
        backend: str = "mujoco",
        *,
        n_robots: int = 16,
        robot_seed: int = 0,
        network_seed: int = 0,
        seconds: float = 12.8,
        see: bool = True,
        nthread: int | None = None,
        lens: str = cam.LENS,
        wiring: str = WIRING,
    ):
        if backend not in BACKENDS:
            raise UserError(f"unknown hexapod physics backend {backend!r}; expected one of {', '.join(BACKENDS)}")
        if not (isinstance(n_robots, int) and n_robots >= 1):
            raise UserError(f"n_robots must be a positive integer, got {n_robots!r}")
        if not (math.isfinite(seconds) and seconds >= STEP_S):
            raise UserError(f"seconds must be at least one step ({STEP_S:g} s), got {seconds!r}")
        self.max_steps = int(round(seconds / STEP_S))
        self.see = bool(see)
        cam.sensor_camera(cam.EDGE_CONFIG, lens)  # raises UserError for an unknown lens
        self.lens = lens
        self.wiring = check_wiring(wiring)
        self.step_params = step_params()
        self.weights = trained_network(network_seed)
        alpha, v_th = GaitTrialParams().alpha, GaitTrialParams().v_th
        self.neuron = DiscreteLIFParams(alpha=jnp.float32(alpha), v_th=jnp.float32(v_th))
        models = [physics.load_model(*d) for d in physics.randomised(n_robots, seed=robot_seed)]
        self.dt = models[0].opt.timestep
        self.substeps = int(round(STEP_S / self.dt))
        frame_every = int(round(decisions.FRAME_S / self.dt))
        if frame_every * _FRAMES != self.substeps:
            raise UserError("the camera's frames must divide the decision step")
        standing = np.stack([physics.standing_state(m) for m in models])
        self.standing = jnp.asarray(standing, jnp.float32)
        nq = models[0].nq
        w = physics.torso_walk(np.zeros(n_robots), standing[:, 1 : 1 + nq])
        torso0 = np.stack([w.xy[:, 0], w.xy[:, 1], w.height, w.roll, w.pitch, w.yaw], axis=-1)
        self.torso0 = jnp.asarray(torso0, jnp.float32)
        self.n_robots = n_robots
        self._backend = backend
        if backend == "mjx":
            self._mjx = physics.mjx_stepper(models, frame_every)
        else:
            self._runner = _Runner(models, nthread or os.cpu_count() or 1, frame_every)
        self._shapes = (
            jax.ShapeDtypeStruct((standing.shape[1],), jnp.float32),
            jax.ShapeDtypeStruct((_FRAMES, 6), jnp.float32),
        )

    @property
    def observation_size(self) -> int:
        return 2 * N_GAITS

    @property
    def action_size(self) -> int:
        return 1

    @property
    def backend(self) -> str:
        return self._backend

    def _truth(self, scene, torso_world):
        pose = cam.ground_pose(torso_world)
        slot, dist, bearing = prey_mod.nearest(scene, pose)
        gait = prey_mod.truth_gait(scene, pose, cam.D_NEAR + 0.5 * scene.size[0])
        return {"truth_gait": gait, "nearest": slot.astype(jnp.int32), "distance": dist, "bearing": bearing}

    def _obs(self, counts, gait):
        return jnp.concatenate([counts.astype(jnp.float32), jax.nn.one_hot(gait, N_GAITS, dtype=jnp.float32)])

    def reset(self, rng: jax.Array, scene: prey_mod.PreyScene | None = None) -> State:
        """A robot of the pool standing at the scene's start; ``scene`` default: one random prey (`prey.sample_scene`)."""
        k_robot, k_scene, k_run = jax.random.split(rng, 3)
        if scene is None:
            scene = prey_mod.sample_scene(k_scene, 1)
        robot = jax.random.randint(k_robot, (), 0, self.n_robots)
        torso = world_track(self.torso0[robot], scene.start)
        truth = self._truth(scene, torso)
        zero, zeros3 = jnp.zeros((), jnp.int32), jnp.zeros((N_GAITS,), jnp.int32)
        gait = jnp.int32(FORWARD)
        info = {
            "rng": k_run,
            "robot": robot,
            "phys": self.standing[robot],
            "track": self.torso0[robot],  # the torso in the physics frame (from the origin)
            "torso": torso,
            "cpg": cpg_init(),
            "raster": jnp.zeros((PERIOD * self.max_steps, N_LEGS), jnp.float32),
            "cpg_spikes": jnp.zeros((PERIOD, N_LEGS), jnp.float32),
            "gait": gait,
            "gait_counts": zeros3,
            "wta": gait,
            "gait_counts_ordered": zeros3,
            "wta_ordered": gait,
            "events": zero,
            "filter": zero,
            "layer2": zero,
            "layer3": zero,
            "overflow": zero,
            "scene": scene,
            "captures": jnp.full((prey_mod.MAX_PREY,), -1, jnp.int32),
            "order": jnp.full((prey_mod.MAX_PREY,), -1, jnp.int32),
            "first_nearest": truth["nearest"],
            "steps": zero,
            "lost": jnp.zeros((), bool),
            **truth,
        }
        return State(
            pipeline_state=None,
            obs=self._obs(zeros3, gait),
            reward=jnp.zeros((), jnp.float32),
            done=jnp.zeros((), jnp.float32),
            metrics={"captured": zero},
            info=info,
        )

    def step(self, state: State, action: jax.Array) -> State:
        """One gait cycle with the chosen gait (module docstring); a finished episode is left as it is."""
        info = state.info
        gait = jnp.clip(jnp.round(jnp.reshape(jnp.asarray(action, jnp.float32), (-1,))[0]), 0, N_GAITS - 1)
        gait = gait.astype(jnp.int32)
        cpg, rows = cpg_cycle(self.neuron, self.weights, info["cpg"], info["gait"], gait)
        k = info["steps"]
        raster = jax.lax.dynamic_update_slice(info["raster"], rows, (PERIOD * k, 0))
        t = (k * self.substeps + jnp.arange(self.substeps)).astype(jnp.float32) * self.dt
        controls = servo_targets(self.step_params, raster, t)
        if self._backend == "mjx":
            phys, frames = self._mjx(info["phys"], info["robot"], controls)
        else:
            phys, frames = jax.pure_callback(
                self._runner, self._shapes, info["phys"], info["robot"], controls, vmap_method="broadcast_all"
            )
        scene = info["scene"]
        rng, k_see = jax.random.split(info["rng"])
        if self.see:
            track = jnp.concatenate([info["track"][None], frames], axis=0)
            d = decisions.decide(track, scene, k_see, lens=self.lens, wiring=self.wiring)
            counts = d.out_counts.astype(jnp.int32)
            ordered = d.ordered_counts.astype(jnp.int32)
            seen = {
                "events": d.events,
                "filter": d.filter_spikes,
                "layer2": d.layer2_spikes,
                "layer3": jnp.sum(d.window_counts, dtype=jnp.int32),
                "overflow": d.overflow,
            }
        else:
            counts = ordered = jnp.zeros((N_GAITS,), jnp.int32)
            seen = {f: jnp.zeros((), jnp.int32) for f in ("events", "filter", "layer2", "layer3", "overflow")}
        torso = world_track(frames[-1], scene.start)
        pose = cam.ground_pose(torso)
        slot, _, _ = prey_mod.nearest(scene, pose)
        caught = prey_mod.captured(scene, pose, cam.D_NEAR + 0.5 * scene.size[0], CAPTURE_MARGIN)
        slots = jnp.arange(prey_mod.MAX_PREY)
        hit = caught & (slots == slot)
        scene = scene._replace(alive=scene.alive & ~hit)
        captures = jnp.where(hit, k + 1, info["captures"])
        n_caught = jnp.sum(info["captures"] >= 0)
        order = jnp.where(caught & (slots == n_caught), slot, info["order"]).astype(jnp.int32)
        steps = k + 1
        _, bearings = prey_mod.relative(scene, pose)
        lost = jnp.any(scene.alive) & jnp.all((jnp.abs(bearings) > LOST_BEARING) | ~scene.alive)
        done = ~jnp.any(scene.alive) | (steps >= self.max_steps) | lost
        new_info = {
            **info,
            "rng": rng,
            "phys": phys,
            "track": frames[-1],
            "torso": torso,
            "cpg": cpg,
            "raster": raster,
            "cpg_spikes": rows,
            "gait": gait,
            "gait_counts": counts,
            "wta": edges.winner(counts, gait),
            "gait_counts_ordered": ordered,
            "wta_ordered": edges.winner(ordered, gait),
            **seen,
            "scene": scene,
            "captures": captures,
            "order": order,
            "steps": steps,
            "lost": lost,
            **self._truth(scene, torso),
        }
        new = State(
            pipeline_state=None,
            obs=self._obs(counts, gait),
            reward=caught.astype(jnp.float32),
            done=done.astype(jnp.float32),
            metrics={"captured": jnp.sum(captures >= 0).astype(jnp.int32)},
            info=new_info,
        )
        # A finished episode stays as it ended (Brax's wrappers reset it; the reproduction refills it).
        finished = state.done > 0
        return jax.tree.map(lambda old, nxt: jnp.where(finished, old, nxt), state, new)
