"""MJX physics of the planar RoboBee: the MJCF model driven by stroke-averaged wing forces.

`robobee.xml` is one body with slides ``x``, ``z`` and a hinge ``theta`` about
``y`` through the centre of mass (``qpos = [x, z, theta]``). At every step,
`physics_step` writes the robot's traced `RoboBeeParams` (mass, pitch inertia,
gravity) into the MJX model, turns the wings' lift, drag and control torque
into generalised forces (``qfrc_applied``) and takes one ``mjx.step``
(semi-implicit Euler, ``dt = model.opt.timestep``, 0.1 ms by default).

The sign conventions and the state ``q = [theta, theta_dot, x, z, x_dot,
z_dot]`` are those of `robots.robobee.dynamics` (Fig. 3 of the RoboBee paper:
a positive ``theta`` tilts the lift toward ``+x``).

Contacts are disabled (flight needs none, and a constraint solve per step
would dominate MJX's cost); the floor at ``z = 0`` is a clamp after each step
(`physics_step`). Above the floor, the model integrates exactly Eq. (4)-(5) of
`robots.robobee.dynamics.rhs`, to MuJoCo's ``O(dt)`` integration error.
"""

from __future__ import annotations

import functools
import pathlib

import jax
import jax.numpy as jnp
import mujoco
from mujoco import mjx

from robots.robobee.dynamics import clip_controls
from robots.robobee.params import RoboBeeParams

__all__ = [
    "MODEL_PATH",
    "data_at",
    "generalized_forces",
    "load_mj_model",
    "load_model",
    "physics_step",
    "rollout",
    "set_params",
    "state_of",
]

MODEL_PATH = pathlib.Path(__file__).with_name("robobee.xml")
# Body id of the robot (0 is the world).
_BEE = 1
# qpos / qvel index of each joint.
_X, _Z, _THETA = 0, 1, 2


@functools.cache
def load_mj_model() -> mujoco.MjModel:
    """The compiled MJCF model for MuJoCo's C engine (loaded once)."""
    return mujoco.MjModel.from_xml_path(str(MODEL_PATH))


@functools.cache
def load_model() -> mjx.Model:
    """The MJX model on the default device (loaded once).

    Its arrays take JAX's default float dtype (float32 unless ``jax_enable_x64``
    was set before the first call).
    """
    # Built eagerly even when first asked for inside a trace, so the cache never holds a tracer.
    with jax.ensure_compile_time_eval():
        return mjx.put_model(load_mj_model())


def set_params(model: mjx.Model, params: RoboBeeParams) -> mjx.Model:
    """The model with the robot's mass, pitch inertia ``I_y`` and gravity ``g``.

    Only the quantities that the smooth dynamics of this model read are
    replaced (``body_mass``, ``body_inertia``, ``body_subtreemass``,
    ``opt.gravity``); the derived constraint weights (``*_invweight0``) are
    left at their nominal values, which is exact here because the model has
    no constraints.

    Args:
        model: the MJX model of `load_model`.
        params: the robot; its fields may be traced, so this jits and vmaps.

    Returns:
        A model with the same structure, so replacing does not recompile.
    """
    dtype = model.body_mass.dtype
    mass = jnp.asarray(params.mass, dtype)
    return model.replace(
        body_mass=model.body_mass.at[_BEE].set(mass),
        body_subtreemass=model.body_subtreemass.at[_BEE].set(mass).at[0].set(mass),
        body_inertia=model.body_inertia.at[_BEE, 1].set(jnp.asarray(params.inertia_y, dtype)),
        opt=model.opt.replace(gravity=jnp.zeros(3, dtype).at[2].set(-jnp.asarray(params.g, dtype))),
    )


def state_of(data: mjx.Data) -> jax.Array:
    """The paper's state ``q = [theta, theta_dot, x, z, x_dot, z_dot]`` (Eq. (3)).

    Args:
        data: MJX data of this model.

    Returns:
        ``q`` in rad, rad/s, m, m/s, shape ``(6,)``.
    """
    qpos, qvel = data.qpos, data.qvel
    return jnp.stack([qpos[_THETA], qvel[_THETA], qpos[_X], qpos[_Z], qvel[_X], qvel[_Z]])


@jax.jit
def data_at(model: mjx.Model, q: jax.Array) -> mjx.Data:
    """MJX data with the robot at state ``q``, its kinematics computed.

    Jitted, because MJX's kinematics run op by op take seconds on a CPU.

    Args:
        model: the MJX model.
        q: ``[theta, theta_dot, x, z, x_dot, z_dot]``, shape ``(6,)``.

    Returns:
        Data whose ``qpos = [x, z, theta]`` and ``qvel = [x_dot, z_dot,
        theta_dot]``, time 0, and body poses (``xpos``, ``xmat``) at ``q``.
    """
    q = jnp.asarray(q, model.body_mass.dtype)
    data = mjx.make_data(model)
    data = data.replace(
        qpos=jnp.stack([q[2], q[3], q[0]]),
        qvel=jnp.stack([q[4], q[5], q[1]]),
    )
    return mjx.kinematics(model, data)


def generalized_forces(q: jax.Array, params: RoboBeeParams, f_lift: jax.Array, tau_c: jax.Array) -> jax.Array:
    """The wings' forces as generalised forces on ``(x, z, theta)``.

    The lift ``f_L z'`` and the drag ``f_d x'`` act at the wings' centre of
    pressure ``p_w = [x + r_w sin theta, z + r_w cos theta]``; a force ``F`` there
    maps to ``J_w^T F`` with the Jacobian ``J_w = d p_w / d (x, z, theta)``, whose
    ``theta`` column also gives the wing point's velocity ``v_w = J_w
    [x_dot, z_dot, theta_dot]``. The drag is ``f_d = -b_w v_w . x'``
    (Sec. II-B), and the control torque ``tau_c`` acts on ``theta`` directly.

    Args:
        q: state ``[theta, theta_dot, x, z, x_dot, z_dot]``, shape ``(6,)``.
        params: the robot.
        f_lift: lift along ``z'``, N (applied as given, not clipped).
        tau_c: control torque about ``y``, N m (applied as given).

    Returns:
        ``[F_x, F_z, tau_y]`` in N, N, N m, shape ``(3,)``.
    """
    theta, theta_dot, _, _, x_dot, z_dot = (q[i] for i in range(6))
    tau_c = jnp.asarray(tau_c, q.dtype)
    c, s = jnp.cos(theta), jnp.sin(theta)
    e_x = jnp.stack([c, -s])
    e_z = jnp.stack([s, c])
    jac_w = jnp.stack(
        [
            jnp.stack([jnp.ones_like(c), jnp.zeros_like(c), params.r_w * c]),
            jnp.stack([jnp.zeros_like(c), jnp.ones_like(c), -params.r_w * s]),
        ]
    )
    v_w = jac_w @ jnp.stack([x_dot, z_dot, theta_dot])
    f_d = -params.b_w * (v_w @ e_x)
    force = f_lift * e_z + f_d * e_x
    zero = jnp.zeros_like(tau_c)
    return jac_w.T @ force + jnp.stack([zero, zero, tau_c])


def physics_step(
    model: mjx.Model,
    data: mjx.Data,
    params: RoboBeeParams,
    u_lift: jax.Array,
    u_torque: jax.Array,
) -> mjx.Data:
    """One physics step of the RoboBee from ``t`` to ``t + dt``.

    1. The commands are clipped to the actuators' limits of Sec. II-B
       (`robots.robobee.dynamics.clip_controls`): ``0 <= f_L <= 1.5 m g``,
       ``|tau_c| <= 1 uN m``.
    2. The lift, the drag of the wings and the torque, evaluated at the state at
       ``t`` and held over the step (stroke-averaged forces), become
       ``qfrc_applied`` (`generalized_forces`).
    3. ``mjx.step`` on the model carrying ``params`` (`set_params`) integrates
       Eq. (1)-(2) with gravity by semi-implicit Euler.
    4. The floor: ``z`` is clamped to ``>= 0`` and a downward ``z_dot`` on it is
       zeroed (a perfectly inelastic, frictionless floor under the centre of
       mass; the attitude is free). In flight (``z > 0``) this does nothing.

    Args:
        model: the MJX model (`load_model`).
        data: the state at ``t``.
        params: the robot (traced, so one compiled step serves any robot).
        u_lift: commanded lift, N, shape ``()``.
        u_torque: commanded torque about ``y``, N m, shape ``()``.

    Returns:
        The data at ``t + dt``.

    Examples:
        >>> from robots.robobee.params import robobee_params
        >>> p, model = robobee_params(), load_model()
        >>> d = data_at(model, jnp.zeros(6).at[3].set(0.05))
        >>> q = state_of(physics_step(model, d, p, p.mass * p.g, 0.0))  # hover
        >>> bool(jnp.allclose(q, jnp.array([0.0, 0.0, 0.0, 0.05, 0.0, 0.0]), atol=1e-6))
        True
    """
    q = state_of(data)
    f_lift, tau_c = clip_controls(params, jnp.asarray(u_lift), jnp.asarray(u_torque))
    qfrc = generalized_forces(q, params, f_lift, tau_c).astype(data.qpos.dtype)
    data = mjx.step(set_params(model, params), data.replace(qfrc_applied=qfrc))
    z, z_dot = data.qpos[_Z], data.qvel[_Z]
    below = z < 0.0
    return data.replace(
        qpos=data.qpos.at[_Z].set(jnp.where(below, 0.0, z)),
        qvel=data.qvel.at[_Z].set(jnp.where(below, jnp.maximum(z_dot, 0.0), z_dot)),
    )


def rollout(
    model: mjx.Model,
    params: RoboBeeParams,
    q0: jax.Array,
    u_lift: jax.Array,
    u_torque: jax.Array,
) -> jax.Array:
    """Open-loop flight: `physics_step` under given commands, as one ``lax.scan``.

    Args:
        model: the MJX model.
        params: the robot.
        q0: initial state, shape ``(6,)``.
        u_lift: lift command of each step, N, shape ``(n,)``.
        u_torque: torque command of each step, N m, shape ``(n,)``.

    Returns:
        The states at ``t = 0, dt, ..., n dt``, shape ``(n + 1, 6)``.
    """

    def step(data, u):
        data = physics_step(model, data, params, u[0], u[1])
        return data, state_of(data)

    data = data_at(model, q0)
    _, qs = jax.lax.scan(step, data, jnp.stack([u_lift, u_torque], axis=-1))
    return jnp.concatenate([state_of(data)[None], qs])
