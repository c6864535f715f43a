"""The slithering gait of the wheel-less snake: Eq. (1) of the snake R-STDP paper, steering and head compensation.

Eq. (1) of the snake R-STDP paper (Sec. II-A), after the slithering gait of
Bing et al. (IROS 2017, its ref. [17]), gives the position target of joint
``i`` (``1..16``, numbered from the head):

.. math::

    \\alpha_i = \\begin{cases}
        P_i A_o \\sin(i \\Omega_o + t \\omega_o + \\delta_o) + C_o, & i \\text{ odd (lateral, yaw)} \\\\
        P_i A_e \\sin(i \\Omega_e + t \\omega_e) + C_e, & i \\text{ even (dorsal, pitch)}
    \\end{cases}

The lateral (odd) wave bends the body into a serpenoid curve; the dorsal (even)
wave, at twice the lateral spatial and temporal frequency, lifts the body where
the lateral curvature changes sign, so that the grounded parts push sideways
against the floor and the snake advances without wheels. ``C_o`` biases every
lateral joint the same way, bending the body into an arc: this is the paper's
steering input ("the robot is easily controlled in which direction it should go
by just adjusting C_o").

Head compensation (Sec. II-A: "a compensation C_compensation is applied to
the first joint so that the DVS can always sense the environment in front of
the snake robot"; Sec. 2.4.1 of the pipe-tracking paper) is written here as
kinematics rather than a fitted curve: the first joint is set so that the head
points along the mean heading of the 17 modules (`head_compensation`), which is
the body's direction of motion averaged over the wave. Eq. (4)-(6) of the
pipe-tracking paper (the camera's sideways offset estimated from the head
joint) have their one home in `spikejax.vision.pipe.camera_offset`; their
tuple ``(A, alpha, phi_pos)`` is fitted for this gait in
`robots.snake.calibration`.

Sign conventions (those of ``snake.xml``): ``alpha_i > 0`` turns module ``i``
to the left (odd ``i``, about ``+z``) or about ``+y`` (even ``i``) relative to
module ``i - 1``; so the head's yaw relative to module 1 is ``-alpha_1``. With
the default `GaitParams` the snake moves toward its head (``+x`` of the head
at rest), and a positive ``C_o`` turns it clockwise seen from above (to the
right, a negative yaw rate); ``tests/test_snake_gait.py`` checks both.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp

__all__ = [
    "JOINT_LIMIT",
    "N_JOINTS",
    "GaitParams",
    "gait_params",
    "gait_period",
    "head_compensation",
    "swing_correction",
    "joint_targets",
]

N_JOINTS = 16
JOINT_LIMIT = math.pi / 2  # rad, the joints' range of Sec. II-A

_I = jnp.arange(1, N_JOINTS + 1, dtype=jnp.float32)  # joint numbers 1..16
_ODD = jnp.arange(1, N_JOINTS + 1) % 2 == 1


class GaitParams(NamedTuple):
    """Parameters of Eq. (1) of the snake R-STDP paper; every field is a traced scalar a sweep can vmap over.

    Angles in rad, frequencies in rad/s (temporal) or rad per joint number
    (spatial). ``P_i`` (the paper's "linear dependency") is the linear ramp from
    ``P_head`` at joint 1 to ``P_tail`` at joint 16.

    Attributes:
        A_o: lateral amplitude. Default 30 deg: the head joint of the
            paper's robot swings about 35 deg (the pipe-tracking paper's
            Eq. (5) gives ``alpha = 90 deg / a = 2.571`` for NRP, so ``a = 35``
            deg); 30 deg keeps the body's arc below the joint limits with a
            steering offset of up to 0.5 rad.
        Omega_o: lateral spatial frequency, rad per joint number. Default
            ``-2 pi / 16``: one wave along the 16 joints, the fastest of the
            half, one and one-and-a-half waves on this model (about 0.11,
            0.03 and 0.01 m/s); negative, so the wave travels from the head
            to the tail and the snake moves head first.
        omega_o: lateral temporal frequency. Default ``2 pi / 2.5`` (a 2.5 s
            period); the paper's reset window (625 steps of 20 ms, "a movement
            period of the snake robot") is an upper bound of the period of
            its slower Gazebo robot.
        delta_o: phase of the lateral wave relative to the dorsal one.
            Default 0: with ``Omega_e = 2 Omega_o`` the dorsal wave then
            lifts the body at the lateral wave's inflection points.
        C_o: lateral offset, the steering input. Default 0 (straight).
        A_e: dorsal amplitude. Default 5 deg: enough lift for the grounded
            arcs to carry the weight, small enough that the head stays level.
        Omega_e: dorsal spatial frequency. Default ``2 Omega_o``.
        omega_e: dorsal temporal frequency. Default ``2 omega_o``.
        C_e: dorsal offset. Default 0.
        P_head: ``P_1``. Default 1.
        P_tail: ``P_16``. Default 1 (uniform amplitude).
    """

    A_o: jax.Array | float
    Omega_o: jax.Array | float
    omega_o: jax.Array | float
    delta_o: jax.Array | float
    C_o: jax.Array | float
    A_e: jax.Array | float
    Omega_e: jax.Array | float
    omega_e: jax.Array | float
    C_e: jax.Array | float
    P_head: jax.Array | float
    P_tail: jax.Array | float


def gait_params() -> GaitParams:
    """The straight slithering gait (`GaitParams` documents each value's source)."""
    Omega_o = -2 * math.pi / 16
    omega_o = 2 * math.pi / 2.5
    return GaitParams(
        A_o=math.radians(30.0),
        Omega_o=Omega_o,
        omega_o=omega_o,
        delta_o=0.0,
        C_o=0.0,
        A_e=math.radians(5.0),
        Omega_e=2 * Omega_o,
        omega_e=2 * omega_o,
        C_e=0.0,
        P_head=1.0,
        P_tail=1.0,
    )


def gait_period(params: GaitParams) -> jax.Array:
    """Period of the lateral wave, ``2 pi / |omega_o|`` seconds."""
    return 2 * jnp.pi / jnp.abs(params.omega_o)


def _eq1(params: GaitParams, t, C_o) -> jax.Array:
    """Eq. (1) of the snake R-STDP paper for all 16 joints, with the lateral offset ``C_o``."""
    P = params.P_head + (params.P_tail - params.P_head) * (_I - 1) / (N_JOINTS - 1)
    odd = P * params.A_o * jnp.sin(_I * params.Omega_o + t * params.omega_o + params.delta_o) + C_o
    even = P * params.A_e * jnp.sin(_I * params.Omega_e + t * params.omega_e) + params.C_e
    return jnp.where(_ODD, odd, even)


def head_compensation(alpha: jax.Array) -> jax.Array:
    """The first joint's angle that points the head along the body's mean heading.

    In the horizontal plane the yaw of module ``k`` relative to the head is
    ``sum_{odd j <= k} alpha_j``, so the 17 modules' mean yaw relative to the
    head is ``(1/17) sum_{odd j} (17 - j) alpha_j``. Setting it to zero gives

    .. math:: \\alpha_1 = -\\frac{1}{16} \\sum_{j = 3, 5, \\dots, 15} (17 - j) \\alpha_j,

    the head then looks along the mean direction of the body, which over a wave
    is its direction of motion (the role of the paper's ``C_compensation``).

    Args:
        alpha: joint angles ``(16,)`` (only the odd ones from joint 3 are read).

    Returns:
        ``alpha_1``, rad (not clipped).
    """
    weights = jnp.where(_ODD & (_I >= 3), 17.0 - _I, 0.0)
    return -jnp.sum(weights * alpha) / 16.0


def swing_correction(params: GaitParams, t, amplitude, phase) -> jax.Array:
    """A phase-locked addition to the head joint's target, ``amplitude sin(omega_o t + phase)``, rad.

    `head_compensation` is kinematics: it points the head along the modules'
    mean heading as the joint *targets* place them. The servos lag their
    targets, and a body holding one wave does not travel along its mean
    heading at every instant, so the head still swings about the direction
    of travel at the gait's frequency (by 15 degrees with the default gait:
    `robots.snake.head_swing`). This term cancels that swing's fundamental;
    `robots.snake.head_swing.fit` finds ``(amplitude, phase)`` for a gait. It
    fades in over the first period, as the wave itself starts from rest:
    switched on at full amplitude it whips the head at ``t = 0``.

    Args:
        params: the gait (its ``omega_o``).
        t: time, s (scalar, may be traced).
        amplitude, phase: rad (may be traced; amplitude 0 gives 0).
    """
    ramp = jnp.clip(t / gait_period(params), 0.0, 1.0)
    return ramp * amplitude * jnp.sin(params.omega_o * t + phase)


def joint_targets(params: GaitParams, t, steer=0.0, head_offset=0.0, compensate=True, joints=None) -> jax.Array:
    """Position-servo targets of the 16 joints at ``t``: Eq. (1) of the snake R-STDP paper, steered, head-compensated.

    Args:
        params: the gait (`gait_params`); its ``C_o`` is replaced by ``steer``.
        t: time, s (scalar).
        steer: ``C_o`` of Eq. (1) of the snake R-STDP paper, rad: the steering
            input. With the default gait a positive ``steer`` turns the snake
            clockwise (to the right).
        head_offset: added to the first (head yaw) joint, rad, after the
            compensation: the head controller's command. The head's yaw
            relative to module 1 is ``-alpha_1``, so a positive offset turns
            the head to the right.
        compensate: replace the first joint's Eq. (1) target by
            `head_compensation` of the others (the snake R-STDP paper's head compensation);
            ``False`` gives Eq. (1) unchanged (plus ``head_offset``).
        joints: the joints' measured angles ``(16,)``, rad: when given, the
            compensation points the head along the body as it is rather than
            as the targets place it. The servos lag their targets, so a change
            of ``steer`` (which shifts all seven odd joints from joint 3 at
            once) moves the compensated target of joint 1 by ``-3.5`` times
            that change in one step, while the odd joints take about 0.3 s
            to follow it: the head whips, and a network steering bang-bang swings its own
            camera by 20-40 degrees (`robots.snake.training.env_for`).

    Returns:
        Targets ``(16,)`` in rad, joint 1 first, clipped to the joints' range
        of +-90 deg; the order of the actuators in ``snake.xml``.

    Examples:
        >>> p = gait_params()
        >>> alpha = joint_targets(p, 0.0, compensate=False)
        >>> bool(jnp.allclose(alpha[0], p.A_o * jnp.sin(p.Omega_o)))
        True
    """
    t = jnp.asarray(t, jnp.float32)
    alpha = _eq1(params, t, jnp.asarray(steer, jnp.float32))
    body = alpha if joints is None else jnp.asarray(joints, jnp.float32)
    head = jnp.where(compensate, head_compensation(body), alpha[0])
    alpha = alpha.at[0].set(head + head_offset)
    return jnp.clip(alpha, -JOINT_LIMIT, JOINT_LIMIT)
