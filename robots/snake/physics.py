"""Physics of the wheel-less snake, one MJCF and two backends: MJX and MuJoCo's C engine.

`make_physics` returns a `SnakePhysics` whose ``init()`` and ``step(state,
ctrl)`` are pure functions of one snake, jittable, and batched by
``jax.vmap``; the caller's code is the same for both backends:

- ``"mjx"``: ``mjx.step`` in a ``lax.scan`` over the control step's physics
  steps, everything in one XLA program (the engine for accelerators).
- ``"mujoco"``: the same model stepped by MuJoCo's C engine
  (``mujoco.rollout`` on a persistent pool of ``nthread`` threads), called from
  inside the jitted program through ``jax.pure_callback`` with
  ``vmap_method="broadcast_all"``, so a vmapped batch reaches C as one call
  and is spread over the threads. What crosses the callback is MuJoCo's full
  physics state (``mjSTATE_FULLPHYSICS``: time, qpos, qvel, act for this
  model, checked at load), so the step stays a pure function of
  `PhysState` and the control. This is the backend to use on a CPU, where MJX
  is tens of times slower than C for a contact-rich 17-body chain.

Either way the observations (`PhysState.head_pos`, ``head_mat``, ``com_pos``)
are computed in JAX from ``qpos`` by `forward_kinematics` (DESIGN rule 5:
sensors are JAX functions of the physics state, whichever backend produced it).
The state is float32 (JAX's default), so the C backend rounds its float64
state to float32 once per control step; positions carry about 1e-7 m of
rounding, far below the contact solver's tolerance.

One control step is ``substeps`` physics steps of ``dt`` with the control held;
it is the paper's 20 ms control step by default (Sec. II-D of the snake R-STDP
paper: "a fixed simulating timestep that is 20ms").

Model settings (`load_mj_model`): ``"default"`` is ``snake.xml`` as written
(MuJoCo's default solver: Newton, 100 iterations, 50 line-search iterations;
contacts from contype/conaffinity; ``dt`` 2 ms, 10 per control step);
``"tuned"`` (the default here) replaces the collision filter by explicit
floor-module contact pairs (condim 3, the same friction), uses the conjugate
gradient solver capped at `TUNED_ITERATIONS` iterations and
`TUNED_LS_ITERATIONS` line-search iterations, and doubles the time step to
`TUNED_DT` (5 per control step): half the physics steps, each cheaper.
``tests/test_snake_physics.py`` checks that the straight forward speed and the
turning rate stay within 5 % of the default settings run by MuJoCo's C engine
(measured over 25 s: speed -1.3 %, turning rate +1 %). CG rather than Newton:
under ``vmap`` on a CPU, MJX's Newton solver calls LAPACK's batched Cholesky,
which (jax 0.10.2) can deadlock XLA's intra-op thread pool on two cores; CG
factorises nothing. Newton is faster where it returns, but it did not return
in a process that had already used ``mujoco.rollout``'s thread pool
(docs/BENCHMARKS.md, "Snake env"), and a library cannot tell its users which
backends they may build in one process, so the tuned model keeps CG.

XLA trap (``KNOWN-TRAPS.md``): with jax 0.10.2, XLA's fusion pass on a CPU
took minutes or forever on ``mjx.step`` of a long kinematic chain. The cause:
MJX walks the body tree one depth level at a time (``scan.body_tree``, a
Python loop), and fusion inlines each level's result into every use in the
next, so the fused expressions, compile time and run time grow exponentially
with depth. The MJX backend traces ``mjx.step`` with an
``optimization_barrier`` after each level (`mjx_level_barriers`, scoped to the
tracing of this backend's step: other MJX programs are untouched), which keeps
every level materialised and the compile time bounded (measured:
docs/BENCHMARKS.md, "Snake env"). The model's free joint also sits
on the middle module, so its tree is two chains of 8 rather than one of 16.
`forward_kinematics` avoids the trap by scanning along the chains.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import os
import pathlib
import queue
import threading
from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import rollout as mj_rollout

from spikejax.errors import UserError

__all__ = [
    "BACKENDS",
    "HEAD_BODY",
    "HEAD_SITE",
    "MODEL_PATH",
    "CONTROL_DT",
    "DEFAULT_DT",
    "TUNED_DT",
    "TUNED_ITERATIONS",
    "TUNED_LS_ITERATIONS",
    "ELLIPTIC_TUNED_ITERATIONS",
    "FRICTION_CONES",
    "PARK_DEPTH",
    "PIPE_GROUP",
    "PhysState",
    "PipeBodies",
    "PipeSlot",
    "SnakePhysics",
    "forward_kinematics",
    "joint_qpos_index",
    "load_mj_model",
    "make_physics",
    "mjx_level_barriers",
    "start_at",
]

MODEL_PATH = pathlib.Path(__file__).with_name("snake.xml")
BACKENDS = ("mujoco", "mjx")
MJX_IMPLS = ("jax", "warp")  # MJX's implementations (mjx.put_model's impl)
HEAD_BODY = "module0"
HEAD_SITE = "head_camera"
N_MODULES = 17
TUNED_ITERATIONS = 20
TUNED_LS_ITERATIONS = 20
ELLIPTIC_TUNED_ITERATIONS = 50  # a cold CG start needs 16 on average under the elliptic cone; 20 cut many solves short
TUNED_DT = 0.004  # s
DEFAULT_DT = 0.002  # s
CONTROL_DT = 0.02  # s, the paper's control step
# MuJoCo's friction cones for the floor contacts. "pyramidal" (the default, every result unless said otherwise)
# bounds the friction force by |f_1| + |f_2| <= mu f_n in the contact frame, whose first axis MuJoCo lays along
# each capsule: a module slides 1.4 times as easily at 45 degrees to its axis as along or across it, and the gait
# then keeps its heading for |C_o| < 0.08 rad and turns in jumps above. "elliptic" is isotropic Coulomb friction,
# |f| <= mu f_n: the turning rate is proportional to C_o, and the gait of `gait_params` is half as fast
# (docs/ARCHITECTURE.md, "The snake's friction cone").
FRICTION_CONES = ("pyramidal", "elliptic")


class PhysState(NamedTuple):
    """The state of one snake after a control step (float32).

    Attributes:
        qpos: generalised positions ``(23,)``: the free joint of the middle
            module (position, quaternion), then the hinges in ``snake.xml``'s
            order (`joint_qpos_index` maps joint numbers 1..16 to them).
        qvel: generalised velocities ``(22,)``.
        act: actuator activations ``(0,)`` (position servos have none; kept
            so the state is MuJoCo's full physics state).
        time: simulated time, s, ``()``.
        head_pos: world position of the head camera, m, ``(3,)``.
        head_mat: the head camera's rotation matrix ``(3, 3)``; its columns
            are the camera's axes in the world: ``[:, 0]`` the optical axis
            (forward), ``[:, 1]`` left, ``[:, 2]`` up.
        com_pos: the snake's centre of mass, m, ``(3,)``.
        mocap_pos: positions of the model's mocap bodies (the pipes of a
            model built with `PipeBodies`), m, ``(nmocap, 3)``; ``(0, 3)``
            for the snake alone. They are the episode's placement of the
            pipes: the physics never moves them, the caller sets them
            (``state._replace``), and both backends read them each step.
        mocap_quat: their orientations (unit quaternions ``w, x, y, z``), ``(nmocap, 4)``.
    """

    qpos: jax.Array
    qvel: jax.Array
    act: jax.Array
    time: jax.Array
    head_pos: jax.Array
    head_mat: jax.Array
    com_pos: jax.Array
    mocap_pos: jax.Array
    mocap_quat: jax.Array


@dataclasses.dataclass(frozen=True)
class PipeSlot:
    """The sizes of one pipe slot's two bodies, m: a standing pipe and a lying one.

    Geom sizes are model constants (MuJoCo and MJX take them from the model,
    not the state), so they are static here; where the pipes stand is mocap
    state, traced. A slot holds one standing and one lying body so that a
    batch may mix kinds in one compiled program: the one not used is parked
    far below the floor.
    """

    standing_radius: float = 0.125
    standing_height: float = 2.0
    lying_radius: float = 0.26
    lying_wall: float = 0.01
    lying_length: float = 3.0


@dataclasses.dataclass(frozen=True)
class PipeBodies:
    """Physical pipes added to the snake's model: ``slots`` (`PipeSlot`), each two mocap bodies.

    Slot ``i`` adds mocap body ``2 i``, a standing pipe (a solid cylinder,
    capped, its body frame at the centre of the base, z up), and ``2 i + 1``,
    a lying pipe (``staves`` boxes around the bore, an inscribed polygon of
    the tube's wall, and a disc closing the far end; its body frame at the
    centre of the entry face, x pointing out of the entry, the tube along
    ``-x``). The snake's modules collide with every pipe geom (the head
    through a massless capsule of the head's size: MJX has no cylinder-box
    collision); pipes never collide with the floor or each other.
    """

    slots: tuple[PipeSlot, ...] = (PipeSlot(),)
    staves: int = 16

    def validate(self) -> "PipeBodies":
        if self.staves < 6:
            raise UserError(f"a lying pipe needs at least 6 staves, got {self.staves}")
        for k, slot in enumerate(self.slots):
            sizes = dataclasses.asdict(slot)
            for name, value in sizes.items():
                if not value > 0:
                    raise UserError(f"pipe slot {k}: {name} must be positive, got {value}")
            if slot.lying_wall >= slot.lying_radius:
                raise UserError(f"pipe slot {k}: lying_wall {slot.lying_wall} must be less than lying_radius")
        return self


PARK_DEPTH = -50.0  # m: unused pipe bodies wait this far below the floor
PIPE_GROUP = 1  # geom group of the pipes (the snake and the floor are in group 0)


def _add_pipes(spec, bodies: PipeBodies, settings: str) -> None:
    """Add the mocap pipe bodies of ``bodies`` to ``spec`` (see `PipeBodies`)."""
    group = 2  # collision bit shared by the modules (contype) and the pipes (conaffinity) only
    friction = [0.5, 0.005, 0.0001]
    for geom in spec.geoms:
        if geom.name.startswith("module") and geom.name != HEAD_BODY:
            geom.contype = geom.contype | group
    head = spec.body("module0")
    proxy = head.add_geom()
    proxy.name = "head_proxy"
    proxy.type = mujoco.mjtGeom.mjGEOM_CAPSULE
    proxy.size = [0.035, 0.013, 0.0]
    proxy.quat = [np.cos(np.pi / 4), 0.0, np.sin(np.pi / 4), 0.0]  # capsule axis along the head's x
    proxy.density = 0.0
    proxy.contype = group
    proxy.conaffinity = 0
    proxy.group = 3
    n = bodies.staves
    for k, slot in enumerate(bodies.slots):
        stand = spec.worldbody.add_body(name=f"pipe{k}_standing", mocap=True, pos=[1e3 + 10 * k, 0.0, PARK_DEPTH])
        g = stand.add_geom(name=f"pipe{k}_standing", type=mujoco.mjtGeom.mjGEOM_CYLINDER)
        g.size = [slot.standing_radius, 0.5 * slot.standing_height, 0.0]
        g.pos = [0.0, 0.0, 0.5 * slot.standing_height]
        lying = spec.worldbody.add_body(name=f"pipe{k}_lying", mocap=True, pos=[1e3 + 10 * k, 5.0, PARK_DEPTH])
        r, w, length = slot.lying_radius, slot.lying_wall, slot.lying_length
        mid = r - 0.5 * w
        half_width = mid * np.tan(np.pi / n) + 0.5 * w  # staves meet at the polygon's corners
        for j in range(n):
            phi = 2 * np.pi * j / n
            g = lying.add_geom(name=f"pipe{k}_stave{j}", type=mujoco.mjtGeom.mjGEOM_BOX)
            g.size = [0.5 * length, 0.5 * w, half_width]
            g.pos = [-0.5 * length, mid * np.cos(phi), mid * np.sin(phi)]
            g.quat = [np.cos(phi / 2), np.sin(phi / 2), 0.0, 0.0]  # box y radial
        g = lying.add_geom(name=f"pipe{k}_cap", type=mujoco.mjtGeom.mjGEOM_CYLINDER)
        g.size = [r, 0.5 * w, 0.0]
        g.pos = [-length + 0.5 * w, 0.0, 0.0]
        g.quat = [np.cos(np.pi / 4), 0.0, np.sin(np.pi / 4), 0.0]
    for geom in spec.geoms:
        if geom.name.startswith("pipe"):
            geom.contype = 0
            geom.conaffinity = group
            geom.condim = 3
            geom.friction = friction
            geom.rgba = [0.1, 0.1, 0.1, 1.0]
            geom.group = PIPE_GROUP


@functools.cache
def load_mj_model(
    settings: str = "tuned", dt: float | None = None, pipes: PipeBodies | None = None, friction_cone: str = "pyramidal"
) -> mujoco.MjModel:
    """The compiled snake for MuJoCo's C engine (cached), with ``settings`` and time step ``dt``.

    Args:
        settings: ``"default"``: ``snake.xml`` with MuJoCo's default solver
            settings; ``"tuned"``: explicit contact pairs between the floor and
            each module (no geom-pair filtering at run time, no
            self-collision), the CG solver with `TUNED_ITERATIONS` iterations
            and `TUNED_LS_ITERATIONS` line-search iterations.
        dt: physics time step, s (default: `DEFAULT_DT` or `TUNED_DT`).
        pipes: physical pipes to add (`PipeBodies`: mocap bodies placed
            through `PhysState.mocap_pos`); ``None``, the snake alone, is
            ``snake.xml``'s model unchanged.
        friction_cone: ``"pyramidal"`` (MuJoCo's default, ``snake.xml``) or
            ``"elliptic"`` (isotropic Coulomb friction; with ``"tuned"`` the
            CG solver's cap rises to `ELLIPTIC_TUNED_ITERATIONS`). See
            `FRICTION_CONES`.

    Returns:
        The model (treat it as read-only: it is shared).
    """
    if settings not in ("default", "tuned"):
        raise UserError(f"unknown snake model settings {settings!r}; expected 'default' or 'tuned'")
    if friction_cone not in FRICTION_CONES:
        raise UserError(f"unknown friction cone {friction_cone!r}; expected one of {', '.join(FRICTION_CONES)}")
    if dt is None:
        dt = TUNED_DT if settings == "tuned" else DEFAULT_DT
    if not dt > 0:
        raise UserError(f"physics time step must be positive, got dt={dt}")
    spec = mujoco.MjSpec.from_file(str(MODEL_PATH))
    spec.option.timestep = dt
    if settings == "tuned":
        for geom in spec.geoms:
            geom.contype = 0
            geom.conaffinity = 0
        for k in range(N_MODULES):
            spec.add_pair(
                geomname1="floor", geomname2=f"module{k}", condim=3, friction=[0.5, 0.5, 0.005, 0.0001, 0.0001]
            )
        spec.option.solver = mujoco.mjtSolver.mjSOL_CG
        spec.option.iterations = TUNED_ITERATIONS if friction_cone == "pyramidal" else ELLIPTIC_TUNED_ITERATIONS
        spec.option.ls_iterations = TUNED_LS_ITERATIONS
    if friction_cone == "elliptic":
        spec.option.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
    if pipes is not None:
        _add_pipes(spec, pipes.validate(), settings)
    model = spec.compile()
    size = mujoco.mj_stateSize(model, mujoco.mjtState.mjSTATE_FULLPHYSICS)
    if size != 1 + model.nq + model.nv + model.na:
        raise AssertionError(f"full physics state of {size} numbers is more than time, qpos, qvel, act")
    return model


def joint_qpos_index(model: mujoco.MjModel) -> np.ndarray:
    """``qpos`` index of joints 1..16 (``(16,)`` ints), in the actuators' order."""
    return np.array([model.jnt_qposadr[model.joint(f"joint{i}").id] for i in range(1, 17)])


# ----------------------------------------------------------------- kinematics


def _quat_to_mat(q):
    q = q / jnp.linalg.norm(q)
    w, x, y, z = q
    return jnp.stack(
        [
            jnp.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)]),
            jnp.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)]),
            jnp.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]),
        ]
    )


def _axis_rotation(axis, angle):
    """Rotation by ``angle`` about the unit ``axis`` (Rodrigues)."""
    k = jnp.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]], axis.dtype)
    return jnp.eye(3, dtype=axis.dtype) + jnp.sin(angle) * k + (1 - jnp.cos(angle)) * (k @ k)


class _Chains(NamedTuple):
    """The snake's tree as NumPy constants: the root and its chains of hinged bodies, outward.

    ``body[c, k]`` is the ``k``-th body of chain ``c`` (all chains equally
    long); the per-link arrays are indexed the same way.
    """

    root: int
    root_qadr: int
    body: np.ndarray  # (C, K) body ids
    qadr: np.ndarray  # (C, K) qpos address of each body's hinge
    pos: np.ndarray  # (C, K, 3) body position in its parent
    rot: np.ndarray  # (C, K, 3, 3) body orientation in its parent
    jnt_pos: np.ndarray  # (C, K, 3) hinge anchor in the body
    jnt_axis: np.ndarray  # (C, K, 3) hinge axis in the body
    mass: np.ndarray  # (nbody,)
    ipos: np.ndarray  # (nbody, 3)
    head: int
    site_pos: np.ndarray
    site_rot: np.ndarray


@functools.cache
def _chains(model_key) -> _Chains:
    model = load_mj_model(*model_key)
    free = [j for j in range(model.njnt) if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE]
    root = int(model.jnt_bodyid[free[0]])
    children = {b: [c for c in range(1, model.nbody) if model.body_parentid[c] == b] for b in range(model.nbody)}
    chains = []
    for first in children[root]:
        chain = [first]
        while children[chain[-1]]:
            chain.extend(children[chain[-1]])
        chains.append(chain)
    for chain in chains:
        if len(chain) != len(chains[0]) or any(model.body_jntnum[b] != 1 for b in chain):
            raise AssertionError("the snake must be a root with equal chains of one-hinge bodies")
    body = np.array(chains)
    jnt = model.body_jntadr[body]
    rot = np.zeros(body.shape + (3, 3))
    for c, k in np.ndindex(body.shape):
        mujoco.mju_quat2Mat(rot[c, k].reshape(9), model.body_quat[body[c, k]])
    site = model.site(HEAD_SITE)
    site_rot = np.zeros(9)
    mujoco.mju_quat2Mat(site_rot, site.quat)
    return _Chains(
        root,
        int(model.jnt_qposadr[free[0]]),
        body,
        model.jnt_qposadr[jnt],
        model.body_pos[body],
        rot,
        model.jnt_pos[jnt],
        model.jnt_axis[jnt],
        model.body_mass.copy(),
        model.body_ipos.copy(),
        int(site.bodyid[0]),
        site.pos.copy(),
        site_rot.reshape(3, 3),
    )


def forward_kinematics(qpos: jax.Array, settings: str = "tuned", dt: float | None = None):
    """World poses of the snake's bodies, the head camera and the centre of mass from ``qpos``, in JAX.

    The same computation as MuJoCo's ``mj_kinematics`` for this tree (a free
    root body and two chains of hinged bodies), written out so that both
    backends' observations are JAX functions of the state and the MJX program
    needs no extra kinematics pass. Each chain is a ``lax.scan`` outward from
    the root (and the two chains a ``vmap``): unrolled, XLA's fusion would
    inline every parent's pose into its child's and the program would grow
    exponentially along the chain.

    Args:
        qpos: ``(23,)``.
        settings, dt: which `load_mj_model` model (the kinematics are the same for all).

    Returns:
        ``(xpos (18, 3), xmat (18, 3, 3), head_pos (3,), head_mat (3, 3), com_pos (3,))``;
        body 0 is the world.
    """
    tree = _chains((settings, dt))
    dtype = qpos.dtype
    a = tree.root_qadr
    root_pos, root_mat = qpos[a : a + 3], _quat_to_mat(qpos[a + 3 : a + 7])
    links = tuple(jnp.asarray(x, dtype) for x in (tree.pos, tree.rot, tree.jnt_pos, tree.jnt_axis))
    angles = qpos[tree.qadr]

    def link(carry, x):
        pos, mat = carry
        body_pos, body_rot, jnt_pos, axis, angle = x
        pos = pos + mat @ body_pos
        mat = mat @ body_rot
        anchor = pos + mat @ jnt_pos
        mat = mat @ _axis_rotation(axis, angle)
        pos = anchor - mat @ jnt_pos
        return (pos, mat), (pos, mat)

    def chain(*xs):
        _, out = jax.lax.scan(link, (root_pos, root_mat), xs)
        return out

    chain_pos, chain_mat = jax.vmap(chain)(*links, angles)
    nbody = len(tree.mass)
    xpos = jnp.zeros((nbody, 3), dtype).at[tree.root].set(root_pos).at[tree.body].set(chain_pos)
    xmat = jnp.broadcast_to(jnp.eye(3, dtype=dtype), (nbody, 3, 3))
    xmat = xmat.at[tree.root].set(root_mat).at[tree.body].set(chain_mat)
    h = tree.head
    head_pos = xpos[h] + xmat[h] @ jnp.asarray(tree.site_pos, dtype)
    head_mat = xmat[h] @ jnp.asarray(tree.site_rot, dtype)
    mass = jnp.asarray(tree.mass, dtype)
    xipos = xpos + jnp.einsum("bij,bj->bi", xmat, jnp.asarray(tree.ipos, dtype))
    com_pos = jnp.sum(mass[:, None] * xipos, axis=0) / jnp.sum(mass)
    return xpos, xmat, head_pos, head_mat, com_pos


# ----------------------------------------------------------------- backends


@dataclasses.dataclass(frozen=True, eq=False)
class SnakePhysics:
    """One snake's physics: ``init() -> PhysState``, ``step(state, ctrl) -> PhysState``.

    Static configuration: a frozen dataclass, not a pytree (it holds the MuJoCo
    model and the two functions), hashed by identity, so it can be closed over
    or passed to ``jit`` as a static argument; the traced state is `PhysState`.

    Attributes:
        backend: ``"mujoco"`` or ``"mjx"``.
        dt: physics time step, s.
        substeps: physics steps per control step.
        settings: the model settings (`load_mj_model`).
        mj_model: the MuJoCo model both backends step.
        init: the resting snake: straight, on the floor along ``-x`` from the
            head at the origin, looking along ``+x`` (pipes, if any, parked:
            `PipeBodies`).
        step: one control step: ``substeps`` physics steps with the servo
            targets ``ctrl`` ``(16,)`` (rad, joint 1 first) held and the
            pipes where ``state.mocap_pos`` / ``mocap_quat`` put them. Pure;
            jit and vmap it.
        pipes: the physical pipes of the model (`PipeBodies`), or ``None``.
    """

    backend: str
    dt: float
    substeps: int
    settings: str
    mj_model: mujoco.MjModel
    init: Callable[[], PhysState]
    step: Callable[[PhysState, jax.Array], PhysState]
    pipes: PipeBodies | None = None


def _observe(qpos, qvel, act, time, mocap_pos, mocap_quat, settings, dt) -> PhysState:
    # The snake's kinematics are those of the model without pipes (mocap bodies add no joints).
    _, _, head_pos, head_mat, com_pos = forward_kinematics(qpos, settings, dt)
    return PhysState(qpos, qvel, act, time, head_pos, head_mat, com_pos, mocap_pos, mocap_quat)


def _initial_state(model: mujoco.MjModel, settings: str, dt: float) -> Callable[[], PhysState]:
    data = mujoco.MjData(model)
    qpos = jnp.asarray(data.qpos, jnp.float32)
    qvel = jnp.zeros(model.nv, jnp.float32)
    act = jnp.zeros(model.na, jnp.float32)
    mocap_pos = jnp.asarray(data.mocap_pos.reshape(model.nmocap, 3), jnp.float32)
    mocap_quat = jnp.asarray(data.mocap_quat.reshape(model.nmocap, 4), jnp.float32)

    @functools.cache
    def resting() -> PhysState:
        # Concrete even when first asked for inside a trace, so the cache never holds a tracer.
        with jax.ensure_compile_time_eval():
            observe = jax.jit(functools.partial(_observe, settings=settings, dt=dt))
            return observe(qpos, qvel, act, jnp.zeros((), jnp.float32), mocap_pos, mocap_quat)

    def init() -> PhysState:
        return resting()

    return init


_BARRIER_LOCK = threading.RLock()


@contextlib.contextmanager
def mjx_level_barriers():
    """While active, MJX functions traced put an ``optimization_barrier`` after each body-tree level.

    MJX's per-level helper (``mujoco.mjx._src.scan._nvmap``, called once per
    depth level and joint group by ``scan.body_tree`` and ``scan.flat``) is
    wrapped so that its result passes through ``jax.lax.optimization_barrier``.
    Values are unchanged; XLA just may not fuse one level's computation into
    the next. Only what is traced inside the ``with`` block is affected (the
    helper is restored on exit; a lock keeps two tracing threads from
    interleaving).
    """
    from mujoco.mjx._src import scan

    with _BARRIER_LOCK:
        original = scan._nvmap

        def nvmap(f, *args):
            y = original(f, *args)
            return None if y is None else jax.lax.optimization_barrier(y)

        scan._nvmap = nvmap
        try:
            yield
        finally:
            scan._nvmap = original


class _CRunner:
    """Steps batches of snakes through MuJoCo's C engine (host side).

    A batch of at least ``nthread`` snakes goes to ``mujoco.rollout`` on a
    persistent pool of ``nthread`` threads; a smaller one is stepped on the
    calling thread with one ``MjData``, which costs less than a rollout's
    set-up. Both set the full physics state, zero the solver's warm start and
    hold the control for ``substeps`` calls of ``mj_step``, so they give the
    same numbers.
    """

    def __init__(self, model: mujoco.MjModel, substeps: int, nthread: int):
        self.model = model
        self.substeps = substeps
        self.nthread = nthread
        self.spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
        self.nstate = mujoco.mj_stateSize(model, self.spec)
        # Pipes are mocap bodies: their poses travel with the control, held over the substeps.
        self.control_spec = mujoco.mjtState.mjSTATE_CTRL
        if model.nmocap:
            self.control_spec |= mujoco.mjtState.mjSTATE_MOCAP_POS | mujoco.mjtState.mjSTATE_MOCAP_QUAT
        self.nmocap = model.nmocap
        # MjDatas for callers stepping on their own thread (each JAX CPU device its shard, at once). Made here:
        # MuJoCo crashed making one on a callback's thread.
        self.free = queue.SimpleQueue()
        for _ in range(max(2, os.cpu_count() or 1)):
            self.free.put(mujoco.MjData(model))
        self.datas = [mujoco.MjData(model) for _ in range(nthread)]
        self.pool = mj_rollout.Rollout(nthread=nthread) if nthread > 1 else None
        self.buffers = {}
        self.lock = threading.Lock()
        self.nq, self.nv, self.na = model.nq, model.nv, model.na

    def _serial(self, state: np.ndarray, control: np.ndarray) -> np.ndarray:
        model, spec = self.model, self.spec
        data = self.free.get()
        try:
            out = np.empty_like(state)
            for b in range(state.shape[0]):
                mujoco.mj_setState(model, data, state[b], spec)
                data.qacc_warmstart[:] = 0.0
                mujoco.mj_setState(model, data, control[b], self.control_spec)
                mujoco.mj_step(model, data, nstep=self.substeps)
                mujoco.mj_getState(model, data, out[b], spec)
        finally:
            self.free.put(data)
        return out

    def _threaded(self, state: np.ndarray, control: np.ndarray) -> np.ndarray:
        n = state.shape[0]
        if n not in self.buffers:
            self.buffers[n] = (
                [self.model] * n,
                np.zeros((n, self.nv)),
                np.empty((n, self.substeps, self.nstate)),
                np.empty((n, self.substeps, 0)),
            )
        models, warmstart, out, sensordata = self.buffers[n]
        control = np.ascontiguousarray(np.broadcast_to(control[:, None, :], (n, self.substeps, control.shape[1])))
        self.pool.rollout(
            models,
            self.datas,
            state,
            control,
            control_spec=int(self.control_spec),
            skip_checks=True,
            nstep=self.substeps,
            initial_warmstart=warmstart,
            state=out,
            sensordata=sensordata,
            chunk_size=max(1, n // (4 * self.nthread)),
        )
        return out[:, -1, :]

    def __call__(self, qpos, qvel, act, time, ctrl, mocap_pos, mocap_quat):
        batch_shape = time.shape
        n = int(np.prod(batch_shape, dtype=np.int64))
        state = np.concatenate(
            [
                np.asarray(time, np.float64).reshape(n, 1),
                np.asarray(qpos, np.float64).reshape(n, self.nq),
                np.asarray(qvel, np.float64).reshape(n, self.nv),
                np.asarray(act, np.float64).reshape(n, self.na),
            ],
            axis=1,
        )
        # The control vector in mjtState order: ctrl, then mocap positions and quaternions.
        control = np.concatenate(
            [
                np.asarray(ctrl, np.float64).reshape(n, self.model.nu),
                np.asarray(mocap_pos, np.float64).reshape(n, 3 * self.nmocap),
                np.asarray(mocap_quat, np.float64).reshape(n, 4 * self.nmocap),
            ],
            axis=1,
        )
        if self.pool is not None and n >= self.nthread:
            with self.lock:  # one pool and one output buffer per batch size, shared by every caller:
                # copied out before the next caller (another device's shard) writes the buffer again
                final = self._threaded(state, control).astype(np.float32)
        else:
            final = self._serial(state, control).astype(np.float32)
        i = np.cumsum([1, self.nq, self.nv])
        return (
            final[:, i[0] : i[1]].reshape(*batch_shape, self.nq),
            final[:, i[1] : i[2]].reshape(*batch_shape, self.nv),
            final[:, i[2] :].reshape(*batch_shape, self.na),
            final[:, 0].reshape(batch_shape),
        )


def _mujoco_backend(model, substeps, nthread, settings, dt):
    runner = _CRunner(model, substeps, nthread)
    shapes = (
        jax.ShapeDtypeStruct((model.nq,), jnp.float32),
        jax.ShapeDtypeStruct((model.nv,), jnp.float32),
        jax.ShapeDtypeStruct((model.na,), jnp.float32),
        jax.ShapeDtypeStruct((), jnp.float32),
    )

    def step(state: PhysState, ctrl: jax.Array) -> PhysState:
        ctrl = jnp.asarray(ctrl, jnp.float32)
        qpos, qvel, act, time = jax.pure_callback(
            runner,
            shapes,
            state.qpos,
            state.qvel,
            state.act,
            state.time,
            ctrl,
            state.mocap_pos,
            state.mocap_quat,
            vmap_method="broadcast_all",
        )
        return _observe(qpos, qvel, act, time, state.mocap_pos, state.mocap_quat, settings, dt)

    return step


def _mjx_backend(model, substeps, settings, dt, impl="jax"):
    from mujoco import mjx

    with jax.ensure_compile_time_eval():
        mx = mjx.put_model(model, impl=impl)

    def step(state: PhysState, ctrl: jax.Array) -> PhysState:
        data = mjx.make_data(mx, impl=impl).replace(
            qpos=state.qpos,
            qvel=state.qvel,
            act=state.act,
            time=state.time,
            ctrl=jnp.asarray(ctrl, jnp.float32),
            mocap_pos=state.mocap_pos,
            mocap_quat=state.mocap_quat,
        )

        def sub(d, _):
            return mjx.step(mx, d), None

        # The barriers are for XLA's CPU fusion pass on MJX's JAX implementation.
        with mjx_level_barriers() if impl == "jax" else contextlib.nullcontext():
            data, _ = jax.lax.scan(sub, data, None, length=substeps)
        return _observe(data.qpos, data.qvel, data.act, data.time, state.mocap_pos, state.mocap_quat, settings, dt)

    return step


def make_physics(
    backend: str = "mujoco",
    *,
    dt: float | None = None,
    substeps: int | None = None,
    nthread: int | None = None,
    settings: str = "tuned",
    mjx_impl: str = "jax",
    pipes: PipeBodies | None = None,
    friction_cone: str = "pyramidal",
) -> SnakePhysics:
    """The snake's physics with the given backend (see the module's notes).

    Args:
        backend: ``"mujoco"`` (MuJoCo's C engine, threaded; the choice on a
            CPU) or ``"mjx"`` (one XLA program; the choice on an accelerator).
        dt: physics time step, s (default: `TUNED_DT`, 4 ms, or with
            ``settings="default"`` `DEFAULT_DT`, 2 ms).
        substeps: physics steps per control step (default: as many as make
            the paper's 20 ms control step, `CONTROL_DT`).
        nthread: threads of the C backend's pool (default: the CPU cores this
            process may run on, so a process pinned to one core steps on one
            thread); ignored by ``"mjx"``.
        settings: ``"tuned"`` or ``"default"`` model settings (`load_mj_model`).
        mjx_impl: MJX's implementation for ``"mjx"``: ``"jax"`` (anywhere) or
            ``"warp"`` (MJX-Warp, which MuJoCo points users of large or
            contact-rich scenes to; needs ``mujoco-warp`` and a CUDA GPU).
        pipes: physical pipes (`PipeBodies`), placed per episode through the
            state's mocap fields without recompiling (`robots.snake.pipes.place_pipes`);
            ``None`` for the snake alone.
        friction_cone: ``"pyramidal"`` or ``"elliptic"`` (`FRICTION_CONES`).

    Returns:
        A `SnakePhysics`.

    Examples:
        >>> phys = make_physics("mujoco")
        >>> state = phys.step(phys.init(), jnp.zeros(16))
        >>> round(float(state.time), 3)
        0.02
    """
    if backend not in BACKENDS:
        raise UserError(f"unknown physics backend {backend!r}; expected one of {', '.join(BACKENDS)}")
    if mjx_impl not in MJX_IMPLS:
        raise UserError(f"unknown MJX implementation {mjx_impl!r}; expected one of {', '.join(MJX_IMPLS)}")
    if backend == "mjx" and mjx_impl == "warp":
        try:
            import mujoco_warp  # noqa: F401
        except ImportError:
            raise UserError("mjx_impl='warp' needs MJX-Warp: pip install mujoco-warp (on a CUDA GPU)") from None
    if settings not in ("default", "tuned"):
        raise UserError(f"unknown snake model settings {settings!r}; expected 'default' or 'tuned'")
    if dt is None:
        dt = TUNED_DT if settings == "tuned" else DEFAULT_DT
    if substeps is None:
        substeps = max(1, round(CONTROL_DT / dt))
    if int(substeps) != substeps or substeps < 1:
        raise UserError(f"substeps must be a positive integer, got {substeps}")
    if nthread is None:
        nthread = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    if nthread < 1:
        raise UserError(f"nthread must be at least 1, got {nthread}")
    if pipes is not None and not isinstance(pipes, PipeBodies):
        raise UserError(f"pipes must be a PipeBodies, got {type(pipes).__name__}")
    model = load_mj_model(settings, dt, pipes, friction_cone)  # raises UserError for an unknown cone
    if backend == "mujoco":
        step = _mujoco_backend(model, int(substeps), int(nthread), settings, dt)
    else:
        step = _mjx_backend(model, int(substeps), settings, dt, mjx_impl)
    init = _initial_state(model, settings, dt)
    return SnakePhysics(backend, dt, int(substeps), settings, model, init, step, pipes)


def start_at(state: PhysState, x, y, yaw, settings: str = "tuned", dt: float | None = None) -> PhysState:
    """``state``'s snake moved rigidly so that its head camera is at ``(x, y)`` and looks along ``yaw``.

    A rotation about the vertical through the head camera and a translation,
    applied to the free joint's position and quaternion (the hinges, the
    velocities and the pipes are kept; velocities are meant to be zero, as
    after ``init()``). ``yaw`` in radians from the world x axis; pure and
    traced, so each episode of a batch may start elsewhere.
    """
    qpos = state.qpos
    turn = yaw - jnp.arctan2(state.head_mat[1, 0], state.head_mat[0, 0])
    c, s = jnp.cos(turn), jnp.sin(turn)
    head = state.head_pos
    root = qpos[:3] - head
    moved = jnp.stack([x + c * root[0] - s * root[1], y + s * root[0] + c * root[1], qpos[2]])
    half = 0.5 * turn
    qz = jnp.stack([jnp.cos(half), 0.0 * half, 0.0 * half, jnp.sin(half)])
    w0, v0 = qz[0], qz[1:]
    q = qpos[3:7]
    w1, v1 = q[0], q[1:]
    quat = jnp.concatenate([(w0 * w1 - v0 @ v1)[None], w0 * v1 + w1 * v0 + jnp.cross(v0, v1)])
    qpos = qpos.at[:3].set(moved.astype(qpos.dtype)).at[3:7].set(quat.astype(qpos.dtype))
    return _observe(qpos, state.qvel, state.act, state.time, state.mocap_pos, state.mocap_quat, settings, dt)
