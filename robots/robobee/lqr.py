"""The RoboBee's teacher: an LQR on the lateral state and a PD altitude controller.

Sec. III-IV of the RoboBee paper: two decoupled controllers. The lateral one
sets the torque ``tau_c`` from ``[theta, theta_dot, x, x_dot]``: an LQR designed
on the dynamics of Eq. (4)-(5) linearized about hover (`linearize`,
`lqr_gain`), the reference that the SNN learns to imitate. The altitude one sets
the lift ``f_L`` from ``z`` and ``z_dot`` (`altitude_control`).

The gains are computed on the host (SciPy's Riccati solver), once per design;
the control laws `lateral_lqr` and `altitude_control` are pure JAX functions of
arrays that jit and vmap (e.g. over robots flown with the same teacher).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import scipy.linalg

from robots.robobee.dynamics import LATERAL, rhs
from robots.robobee.params import RoboBeeParams, max_lift

__all__ = [
    "AltitudeParams",
    "LATERAL_SCALES",
    "altitude_control",
    "altitude_params",
    "bryson_weights",
    "lateral_gain",
    "lateral_lqr",
    "linearize",
    "lqr_gain",
]

# Acceptable excursions of [theta, theta_dot, x, x_dot] (rad, rad/s, m, m/s) in
# Bryson's rule; see `lateral_gain`.
LATERAL_SCALES = (1.0, 30.0, 0.05, 0.4)


@jax.jit
def linearize(params: RoboBeeParams) -> tuple[jax.Array, jax.Array]:
    """Lateral dynamics linearized about hover: ``d/dt e = A e + B tau_c``.

    Jacobians (``jax.jacobian``) of `robots.robobee.dynamics.rhs` at ``q = 0``,
    ``f_L = m g``, ``tau_c = 0``, restricted to the lateral state ``e = [theta,
    theta_dot, x, x_dot]``, which hover decouples from ``z`` and ``z_dot``.
    In closed form,

    ``A = [[0, 1, 0, 0], [0, -b_w r_w^2 / I_y, 0, -b_w r_w / I_y], [0, 0, 0, 1],
    [g, -b_w r_w / m, 0, -b_w / m]]``, ``B = [0, 1 / I_y, 0, 0]^T``,

    with an unstable complex pair (Sec. II-B: the drag's torque turns the
    robot back too late, so it oscillates with growing amplitude).

    Args:
        params: the robot; may be traced (this jits and vmaps).

    Returns:
        ``A``, shape ``(4, 4)``, in SI units of ``e`` per second; ``B``, shape
        ``(4, 1)``, per N m.
    """
    q0 = jnp.zeros(6, params.mass.dtype)
    f0 = params.mass * params.g
    tau0 = jnp.zeros((), params.mass.dtype)
    lat = jnp.asarray(LATERAL)
    jac_q = jax.jacobian(rhs, argnums=0)(q0, params, f0, tau0)
    jac_u = jax.jacobian(rhs, argnums=3)(q0, params, f0, tau0)
    return jac_q[lat][:, lat], jac_u[lat][:, None]


def bryson_weights(state_scales, input_scale) -> tuple[np.ndarray, np.ndarray]:
    """Bryson's rule: ``Q = diag(1 / e_max^2)``, ``R = 1 / u_max^2``.

    Args:
        state_scales: acceptable excursion of each state, shape ``(n,)``.
        input_scale: acceptable magnitude of the input.

    Returns:
        ``Q``, shape ``(n, n)``, and ``R``, shape ``(1, 1)``, float64.
    """
    state_scales = np.asarray(state_scales, np.float64)
    return np.diag(1.0 / state_scales**2), np.array([[1.0 / float(input_scale) ** 2]])


def lqr_gain(A, B, Q, R) -> np.ndarray:
    """Infinite-horizon continuous LQR gain ``K = R^-1 B^T P``.

    ``P`` solves the continuous algebraic Riccati equation ``A^T P + P A - P B
    R^-1 B^T P + Q = 0`` (``scipy.linalg.solve_continuous_are``), so ``u = -K e``
    minimises ``int e^T Q e + u^T R u dt``. The RoboBee's matrices in SI units
    span many orders of magnitude (``B ~ 1 / I_y ~ 1e9``, ``R ~ 1e12``), so the
    equation is solved for the state and input rescaled by ``diag(Q)^(-1/2)``
    and ``diag(R)^(-1/2)``, whose entries are of order one; the scaling leaves
    ``K`` unchanged.

    Args:
        A: state matrix, shape ``(n, n)``.
        B: input matrix, shape ``(n, m)``.
        Q: state weight, symmetric positive semi-definite with a positive
            diagonal, shape ``(n, n)``.
        R: input weight, symmetric positive definite, shape ``(m, m)``.

    Returns:
        ``K``, shape ``(m, n)``, float64 (a host array: call outside ``jit``).
    """
    A, B, Q, R = (np.asarray(a, np.float64) for a in (A, B, Q, R))
    s_x = 1.0 / np.sqrt(np.diag(Q))
    s_u = 1.0 / np.sqrt(np.diag(R))
    a_s = A * s_x[None, :] / s_x[:, None]
    b_s = B * s_u[None, :] / s_x[:, None]
    q_s = Q * s_x[:, None] * s_x[None, :]
    r_s = R * s_u[:, None] * s_u[None, :]
    p_s = scipy.linalg.solve_continuous_are(a_s, b_s, q_s, r_s)
    k_s = np.linalg.solve(r_s, b_s.T @ p_s)
    return k_s * s_u[:, None] / s_x[None, :]


def lateral_gain(params: RoboBeeParams, state_scales=LATERAL_SCALES) -> np.ndarray:
    """The teacher's lateral LQR gain for a robot (host function).

    Bryson's rule (`bryson_weights`) with the acceptable excursions
    ``state_scales`` of ``[theta, theta_dot, x, x_dot]`` and the torque limit
    ``tau_c,max = 1 uN m`` as the acceptable torque, on the linearization of
    `linearize`. The default `LATERAL_SCALES`, ``Q = diag(1/1^2, 1/30^2,
    1/0.05^2, 1/0.4^2)`` and ``R = 1/(1e-6)^2``, mean: tilts up to 1 rad (the
    paper starts at 0.6 rad), 30 rad/s, the 5 cm of the paper's manoeuvres, and
    0.4 m/s, below the ``tau_c,max / (b_w r_w) = 0.56 m/s`` at which the drag's
    torque alone would exceed the torque limit. For the default robot this
    gives ``K = [2.82e-6, 7.93e-8, 2.00e-5, 2.18e-6]`` and closed-loop poles
    ``-32.1, -16.1 +- 20.3j, -6.5`` 1/s; with the plant's saturations it flies
    the paper's ``q0 -> q1 -> q2`` to within 1 mm in 1 s per leg, also for
    robots whose mass, drag and inertia differ by +-20 % from the design.

    Args:
        params: the robot the teacher is designed for (concrete, not traced).
        state_scales: excursions of ``[theta, theta_dot, x, x_dot]``, rad,
            rad/s, m, m/s.

    Returns:
        ``K``, shape ``(1, 4)``, N m per unit of ``[theta, theta_dot, x,
        x_dot]`` (N m/rad, N m s/rad, N m/m, N m s/m), float64.
    """
    A, B = linearize(params)
    Q, R = bryson_weights(state_scales, np.asarray(params.torque_limit))
    return lqr_gain(np.asarray(A, np.float64), np.asarray(B, np.float64), Q, R)


def lateral_lqr(K: jax.Array, q: jax.Array, q_target: jax.Array) -> jax.Array:
    """The LQR lateral control ``u_lat = tau_c = -K e`` (Sec. IV).

    ``e = q[LATERAL] - q_target[LATERAL]`` is the lateral state's error from the
    target: a robot right of its target (``e_x > 0``) or tilted toward ``+x``
    (``e_theta > 0``) gets a negative torque (``K > 0`` element-wise for this
    robot), tilting its lift back toward ``-x``.

    The torque is not clipped here; the plant clips it to ``+-tau_c,max``
    (`robots.robobee.dynamics.clip_controls`).

    Args:
        K: gain, shape ``(1, 4)`` or ``(4,)`` (`lateral_gain`), N m per unit of
            ``[theta, theta_dot, x, x_dot]``.
        q: state ``[theta, theta_dot, x, z, x_dot, z_dot]``, shape ``(6,)``.
        q_target: target state, shape ``(6,)`` (only its lateral entries count).

    Returns:
        ``tau_c``, N m, shape ``()``.
    """
    lat = jnp.asarray(LATERAL)
    e = q[lat] - q_target[lat]
    return -jnp.reshape(jnp.asarray(K, q.dtype), (4,)) @ e


class AltitudeParams(NamedTuple):
    """Gains of `altitude_control`.

    Attributes:
        kp: proportional gain on the altitude error, 1/s^2 (acceleration per m).
        kd: derivative gain on the vertical-velocity error, 1/s.
        cos_min: lower bound of ``cos theta`` in the tilt compensation, so that
            a robot tilted beyond ``arccos(cos_min)`` is not asked for unbounded
            lift.
    """

    kp: jax.Array
    kd: jax.Array
    cos_min: jax.Array


def altitude_params(kp=100.0, kd=20.0, cos_min=0.5, dtype=jnp.float32) -> AltitudeParams:
    """`AltitudeParams`; the defaults are a critically damped ``10 rad/s`` loop.

    Args:
        kp: 1/s^2 (``omega^2``).
        kd: 1/s (``2 zeta omega``).
        cos_min: lower bound of ``cos theta``.
        dtype: floating dtype of every field.

    Returns:
        The gains.
    """
    f = lambda x: jnp.asarray(x, dtype)  # noqa: E731
    return AltitudeParams(kp=f(kp), kd=f(kd), cos_min=f(cos_min))


def altitude_control(gains: AltitudeParams, q: jax.Array, q_target: jax.Array, params: RoboBeeParams) -> jax.Array:
    """The altitude controller ``u_alt``: PD on ``z`` with gravity and tilt compensation.

    ``f_L = m (g + kp (z* - z) + kd (z_dot* - z_dot)) / max(cos theta, cos_min)``,
    clipped to ``[0, 1.5 m g]``. Dividing by ``cos theta`` makes the vertical
    component of the tilted lift the commanded one, so that ``z`` follows the
    PD's second-order response whatever the lateral controller does with
    ``theta``.

    Args:
        gains: PD gains.
        q: state, shape ``(6,)``.
        q_target: target state, shape ``(6,)`` (``z*`` and ``z_dot*`` count).
        params: the robot model the controller assumes (mass, gravity, lift
            limit): the flown robot's own for perfect gravity compensation, the
            nominal one for a controller unaware of the robot's variation.

    Returns:
        ``f_L``, N, shape ``()``.
    """
    z, z_dot = q[3], q[5]
    accel = gains.kp * (q_target[3] - z) + gains.kd * (q_target[5] - z_dot)
    tilt = jnp.maximum(jnp.cos(q[0]), gains.cos_min)
    f_lift = params.mass * (params.g + accel) / tilt
    return jnp.clip(f_lift, 0.0, max_lift(params))
