"""The hexapod in MuJoCo: its model, randomised copies, and open-loop walks on MuJoCo's C engine.

``robots/hexapod/hexapod.xml`` is a RaspClaws-like robot (the hexapod SCPG
paper's, Fig. 1(b)) of our own measure, since the paper gives none: a torso
box of 0.20 x 0.12 x 0.04 m and 0.6 kg, six legs of 0.065 kg (a coxa of
0.02 m, a femur of 0.04 m and a tibia reaching 0.06 m down to a sphere foot
0.07 m from the hip axis), 0.99 kg in all; position servos of gain 4 N m/rad
limited to 0.3 N m (a 9 g hobby servo's stall torque is about 0.2-0.3 N m);
foot friction 0.8. All are estimates, and `randomised` varies the three that
matter most for walking: friction, mass and servo gain.

`walk` steps a batch of (possibly different) robots through the same or
different servo-target sequences with ``mujoco.rollout`` (one C thread per
core), from the robot standing still on its six feet; `mjx_walk` does the same
for one robot and a batch of sequences as one XLA program with MJX (for
accelerators), and agrees with it (``tests/test_hexapod_walk.py``).
`mjx_stepper` is the closed loop's MJX physics: a pool of randomised robots,
one picked per call by a traced index, stepped from MuJoCo's full physics state
as `robots.hexapod.env.HexapodEnv`'s C backend steps it.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import NamedTuple

import mujoco
import numpy as np
from mujoco import rollout as mj_rollout

from spikejax.errors import UserError

__all__ = [
    "MODEL_PATH",
    "load_model",
    "randomised",
    "standing_state",
    "Walk",
    "walk",
    "torso_walk",
    "torso_states",
    "mjx_walk",
    "mjx_stepper",
]

MODEL_PATH = Path(__file__).with_name("hexapod.xml")
_STATE = mujoco.mjtState.mjSTATE_FULLPHYSICS
_SETTLE_S = 1.0


def load_model(friction: float = 0.8, mass_scale: float = 1.0, servo_gain: float = 1.0) -> mujoco.MjModel:
    """The hexapod with its foot friction, every body's mass (and inertia) scaled, and its servos' gain scaled."""
    for name, value in (("friction", friction), ("mass_scale", mass_scale), ("servo_gain", servo_gain)):
        if not np.isfinite(value) or value <= 0:
            raise UserError(f"{name} must be a finite number > 0, got {value!r}")
    model = mujoco.MjModel.from_xml_path(str(MODEL_PATH))
    model.pair_friction[:, :2] = friction
    model.body_mass[:] *= mass_scale
    model.body_inertia[:] *= mass_scale
    # A position servo: force = kp (ctrl - q), as gainprm[0] and biasprm[1] = -kp.
    model.actuator_gainprm[:, 0] *= servo_gain
    model.actuator_biasprm[:, 1] *= servo_gain
    return model


def randomised(n: int, *, seed: int, friction=(0.56, 1.04), mass=(0.8, 1.2), gain=(0.8, 1.2)) -> list[tuple]:
    """``n`` draws of ``(friction, mass_scale, servo_gain)``, uniform in the ranges (defaults: +-30 %, +-20 %, +-20 %)."""
    rng = np.random.default_rng(seed)
    return [tuple(float(rng.uniform(*r)) for r in (friction, mass, gain)) for _ in range(n)]


def standing_state(model: mujoco.MjModel) -> np.ndarray:
    """MuJoCo's full physics state after the robot has stood for 1 s with every servo at 0."""
    data = mujoco.MjData(model)
    for _ in range(int(round(_SETTLE_S / model.opt.timestep))):
        mujoco.mj_step(model, data)
    state = np.empty(mujoco.mj_stateSize(model, _STATE))
    mujoco.mj_getState(model, data, state, _STATE)
    state[0] = 0.0  # time restarts at the walk's start
    return state


class Walk(NamedTuple):
    """A batch of walks sampled at every physics step.

    Attributes:
        t: time, s, ``(n_steps,)``.
        xy: torso position on the floor, m, ``(batch, n_steps, 2)``.
        yaw: torso heading, rad, unwrapped, ``(batch, n_steps)`` (counter-clockwise: left).
        roll, pitch: rad, ``(batch, n_steps)``.
        height: torso height, m, ``(batch, n_steps)``.
    """

    t: np.ndarray
    xy: np.ndarray
    yaw: np.ndarray
    roll: np.ndarray
    pitch: np.ndarray
    height: np.ndarray


def walk(
    models: list[mujoco.MjModel], controls: np.ndarray, nthread: int | None = None, initial: np.ndarray | None = None
) -> Walk:
    """Step each model from standing through its servo targets.

    Args:
        models: one per walk (the same object may repeat); equal size signatures.
        controls: servo targets per physics step, ``(n_steps, 12)`` for all or ``(batch, n_steps, 12)``.
        nthread: C threads (default: the cores).
        initial: the models' `standing_state` ``(batch, nstate)``, if the caller has them already.
    """
    controls = np.asarray(controls, np.float64)
    if controls.ndim == 2:
        controls = np.broadcast_to(controls, (len(models), *controls.shape))
    if controls.shape[0] != len(models) or controls.shape[-1] != models[0].nu:
        raise UserError(f"controls must be (n_steps, {models[0].nu}) or ({len(models)}, n_steps, {models[0].nu})")
    if initial is None:
        initial = np.stack([standing_state(m) for m in models])
    nthread = nthread or os.cpu_count() or 1
    datas = [mujoco.MjData(models[0]) for _ in range(nthread)]
    states, _ = mj_rollout.rollout(list(models), datas, initial, np.ascontiguousarray(controls))
    t = (np.arange(controls.shape[1]) + 1) * models[0].opt.timestep
    return torso_walk(t, states[..., 1 : 1 + models[0].nq])


def torso_walk(t, qpos) -> Walk:
    """The `Walk` of torso positions ``qpos[..., :7]`` (free joint) sampled at times ``t``."""
    w, x, y, z = (qpos[..., 3 + i] for i in range(4))
    yaw = np.unwrap(np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z)), axis=-1)
    roll = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2 * (w * y - z * x), -1, 1))
    return Walk(t=t, xy=qpos[..., :2], yaw=yaw, roll=roll, pitch=pitch, height=qpos[..., 2])


def mjx_walk(model: mujoco.MjModel, controls) -> Walk:
    """`walk` on MJX: one robot, a batch of servo-target sequences ``(batch, n_steps, 12)``, one XLA program."""
    import jax
    from mujoco import mjx

    controls = np.asarray(controls, np.float32)
    if controls.ndim != 3 or controls.shape[-1] != model.nu:
        raise UserError(f"controls must be (batch, n_steps, {model.nu})")
    data = mujoco.MjData(model)
    mujoco.mj_setState(model, data, standing_state(model), _STATE)
    mujoco.mj_forward(model, data)
    mx, dx = mjx.put_model(model), mjx.put_data(model, data)

    def one(u):
        def step(d, c):
            d = mjx.step(mx, d.replace(ctrl=c))
            return d, d.qpos

        return jax.lax.scan(step, dx, u)[1]

    qpos = np.asarray(jax.jit(jax.vmap(one))(controls), np.float64)
    return torso_walk((np.arange(controls.shape[1]) + 1) * model.opt.timestep, qpos)


def torso_states(qpos):
    """The torso's ``(x, y, z, roll, pitch, yaw)`` from ``qpos[..., n_samples, :7]`` in JAX, yaw unwrapped over the samples.

    `torso_walk`'s angles, for a traced ``qpos`` of shape ``(..., n_samples, nq)``.
    """
    import jax.numpy as jnp

    w, x, y, z = (qpos[..., 3 + i] for i in range(4))
    yaw = jnp.unwrap(jnp.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z)), axis=-1)
    roll = jnp.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = jnp.arcsin(jnp.clip(2 * (w * y - z * x), -1, 1))
    return jnp.stack([qpos[..., 0], qpos[..., 1], qpos[..., 2], roll, pitch, yaw], axis=-1)


def mjx_stepper(models: list[mujoco.MjModel], sample_every: int):
    """The MJX twin of ``mujoco.rollout`` for a pool of robots: ``step(state, robot, controls) -> (state, torso)``.

    ``models`` differ only in their values (`randomised` draws of one MJCF):
    their MJX models are stacked and ``robot`` (traced int) picks one, so a
    ``vmap`` over episodes walks different robots in one program. ``state`` is
    MuJoCo's full physics state (``mjSTATE_FULLPHYSICS``: time, qpos, qvel; the
    hexapod has no actuator state, history or plugins), ``controls`` the servo
    targets of each physics step ``(n_steps, nu)``; the torso ``(n_steps //
    sample_every, 6)`` (`torso_states`) is sampled after every
    ``sample_every``-th step. The solver starts each call from a zero warm
    start, as the C backend does.
    """
    import jax
    import jax.numpy as jnp
    from mujoco import mjx

    m = models[0]
    if m.na or mujoco.mj_stateSize(m, _STATE) != 1 + m.nq + m.nv:
        raise UserError("mjx_stepper needs a model whose full physics state is (time, qpos, qvel)")
    pool = jax.tree.map(lambda *xs: jnp.stack(xs), *[mjx.put_model(x) for x in models])
    blank = mjx.make_data(mjx.put_model(m))
    nq, nv = m.nq, m.nv

    def step(state, robot, controls):
        mx = jax.tree.map(lambda a: a[robot], pool)
        d = blank.replace(time=state[0], qpos=state[1 : 1 + nq], qvel=state[1 + nq : 1 + nq + nv])

        def substep(d, c):
            d = mjx.step(mx, d.replace(ctrl=c))
            return d, d.qpos

        d, qpos = jax.lax.scan(substep, d, controls.astype(jnp.float32))
        full = jnp.concatenate([d.time[None], d.qpos, d.qvel]).astype(jnp.float32)
        return full, torso_states(qpos[sample_every - 1 :: sample_every])

    return step
