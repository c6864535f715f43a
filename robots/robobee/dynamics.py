"""Planar rigid-body dynamics of the RoboBee, Eq. (1)-(5) of the RoboBee paper.

Conventions (Fig. 3 of the paper), used by every RoboBee module:

- ``{x, z}`` is the inertial frame, ``z`` up; ``{x', z'}`` is fixed to the body,
  ``z'`` along the body's long axis, the direction of the lift.
- ``theta`` is the rotation about ``y`` (right-handed, ``y = z cross x``) from
  ``{x, z}`` to ``{x', z'}``: ``z' = (sin theta, cos theta)`` and ``x' = (cos
  theta, -sin theta)`` in ``(x, z)`` components, so a positive ``theta`` tilts
  the lift toward ``+x``. This is MuJoCo's positive rotation about a hinge of
  axis ``(0, 1, 0)``.
- The state is ``q = [theta, theta_dot, x, z, x_dot, z_dot]`` (Eq. (3), whose
  second entry the paper misprints as ``theta``), in rad, rad/s, m, m/s.
- The lateral state is ``[theta, theta_dot, x, x_dot] = q[LATERAL]``.

The functions here accept NumPy arrays (and then compute in NumPy, in the
arrays' precision, as a reference integrator needs) as well as JAX arrays and
tracers (then in JAX, so they jit, vmap and differentiate).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from robots.robobee.params import RoboBeeParams, max_lift

__all__ = [
    "LATERAL",
    "STATE_NAMES",
    "clip_controls",
    "rhs",
]

STATE_NAMES = ("theta", "theta_dot", "x", "z", "x_dot", "z_dot")
# Indices of the lateral state [theta, theta_dot, x, x_dot] in q.
LATERAL = (0, 1, 2, 4)


def _namespace(*trees):
    leaves = jax.tree.leaves(trees)
    return jnp if any(isinstance(leaf, jax.Array) for leaf in leaves) else np


def clip_controls(params: RoboBeeParams, f_lift, tau_c):
    """The actuators' limits of Sec. II-B: ``0 <= f_L <= 1.5 m g``, ``|tau_c| <= 1 uN m``.

    Args:
        params: the robot (``lift_limit``, ``torque_limit``, ``mass``, ``g``).
        f_lift: commanded lift, N, shape ``()``.
        tau_c: commanded torque about ``y``, N m, shape ``()``.

    Returns:
        ``(f_lift, tau_c)`` clipped to what the wings can produce.
    """
    xp = _namespace(params, f_lift, tau_c)
    f_lift = xp.clip(f_lift, 0.0, max_lift(params))
    tau_c = xp.clip(tau_c, -params.torque_limit, params.torque_limit)
    return f_lift, tau_c


def rhs(q, params: RoboBeeParams, f_lift, tau_c):
    """Time derivative of the state, Eq. (4)-(5) of the RoboBee paper.

    Written in the inertial frame ``{x, z}``:

    ``m [x_ddot, z_ddot] = f_L z' + f_d x' - m g z`` (Eq. (1), (4)),

    ``I_y theta_ddot = tau_c + r_w f_d`` (Eq. (2), (5)),

    with the stroke-averaged drag ``f_d = -b_w v_w . x'`` of the wings' centre of
    pressure ``r_w z'`` above the centre of mass, whose velocity is ``v_w = v +
    omega x r_w z' = [x_dot, z_dot] + r_w theta_dot x'``, so that
    ``v_w . x' = x_dot cos theta - z_dot sin theta + r_w theta_dot``. The torque
    of the drag about the centre of mass is ``r_w z' x f_d x' = r_w f_d y``, and
    the lift, acting along ``z'`` through the same point, has none.

    The paper writes Eq. (4) for the velocity in the body frame, which brings the
    term ``-omega x v``; in the inertial frame used here the velocity's
    derivative is the acceleration itself and that term vanishes. The gyroscopic
    term ``omega x I_y omega`` of Eq. (5) is zero in the plane, ``omega = theta_dot
    y`` being a principal axis.

    The inputs are applied as given: clip them first with `clip_controls` to
    respect the actuators' limits.

    Args:
        q: state ``[theta, theta_dot, x, z, x_dot, z_dot]``, shape ``(6,)``.
        params: the robot.
        f_lift: lift ``f_L`` along ``z'``, N, shape ``()``.
        tau_c: control torque about ``y``, N m, shape ``()``.

    Returns:
        ``q_dot = [theta_dot, theta_ddot, x_dot, z_dot, x_ddot, z_ddot]``,
        shape ``(6,)``.

    Examples:
        >>> from robots.robobee.params import robobee_params
        >>> p = jax.tree.map(np.float64, robobee_params())
        >>> q_dot = rhs(np.zeros(6), p, p.mass * p.g, 0.0)  # hover
        >>> bool(np.allclose(q_dot, 0.0))
        True
    """
    xp = _namespace(q, params, f_lift, tau_c)
    theta, theta_dot, _, _, x_dot, z_dot = (q[i] for i in range(6))
    c, s = xp.cos(theta), xp.sin(theta)
    v_w = x_dot * c - z_dot * s + params.r_w * theta_dot
    f_d = -params.b_w * v_w
    x_ddot = (f_lift * s + f_d * c) / params.mass
    z_ddot = (f_lift * c - f_d * s) / params.mass - params.g
    theta_ddot = (tau_c + params.r_w * f_d) / params.inertia_y
    return xp.stack([theta_dot, theta_ddot, x_dot, z_dot, x_ddot, z_ddot])
