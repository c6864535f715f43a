"""Physical parameters of the planar RoboBee of Sec. II of the RoboBee paper.

Every value is an array in SI units, so a sweep can ``jax.vmap`` over robots
whose mass, drag and inertia differ (`randomize`).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

__all__ = [
    "RoboBeeParams",
    "max_lift",
    "randomize",
    "robobee_params",
]


class RoboBeeParams(NamedTuple):
    """Physical parameters of the planar RoboBee (Eq. (1)-(5) of the RoboBee paper).

    Attributes:
        mass: body mass ``m``, kg.
        inertia_y: moment of inertia ``I_y`` about the pitch axis ``y`` through the
            centre of mass, kg m^2.
        b_w: stroke-averaged wing drag coefficient, N s/m: ``f_d = -b_w v_w x'``.
        r_w: distance of the wings' centre of pressure above the centre of mass
            along the body axis ``z'``, m (``r_w/G = r_w z'``).
        g: magnitude of the gravitational acceleration, m/s^2 (gravity is ``-g z``).
        lift_limit: the lift is limited to ``[0, lift_limit m g]`` (1.5 in Sec. II-B).
        torque_limit: the control torque is limited to ``[-torque_limit,
            torque_limit]``, N m (1 uN m in Sec. II-B).
    """

    mass: jax.Array
    inertia_y: jax.Array
    b_w: jax.Array
    r_w: jax.Array
    g: jax.Array
    lift_limit: jax.Array
    torque_limit: jax.Array


def robobee_params(
    mass=80e-6,
    inertia_y=1.4e-9,
    b_w=2.0e-4,
    r_w=9e-3,
    g=9.81,
    lift_limit=1.5,
    torque_limit=1e-6,
    dtype=jnp.float32,
) -> RoboBeeParams:
    """The RoboBee of the paper, with the values its references measured.

    Sources:

    - ``mass = 80 mg``: Sec. II-A of the RoboBee paper ("an 80 mg flapping-wing
      robot"), the robot of Ma, Chirarattananon, Fuller and Wood, "Controlled
      flight of a biologically inspired, insect-scale robot", Science 340 (2013)
      (its ref. [15]).
    - ``inertia_y = 1.4e-9 kg m^2``: the pitch/roll moment of inertia of that
      robot from its CAD model, used by Ma et al. 2013 and by Chirarattananon,
      Ma and Wood, "Adaptive control of a millimeter-scale flapping-wing robot",
      Bioinspir. Biomim. 9 (2014) (ref. [17]). S. B. Fuller's public RoboBee
      simulator (2014) gives 1.4e-9 "from [the] Science paper/solidworks"
      (and runs its planar model with 1.5e-9); other public RoboBee simulators
      use 1.42e-9.
    - ``b_w = 2.0e-4 N s/m``: the stroke-averaged drag of the flapping wings,
      linear in their airspeed, measured in a wind tunnel by Fuller, Karpelson,
      Censi, Ma and Wood, "Controlling free flight of a robotic fly using an
      onboard vision sensor inspired by insect ocelli", J. R. Soc. Interface 11
      (2014) (ref. [3], the source of the paper's drag model); the same value
      is in Fuller's simulator ("aero drag on wings from wind tunnel tests").
    - ``r_w = 9 mm``: the height of the wings' centre of pressure above the
      centre of mass of the 80 mg robot (Fuller et al. 2014), the value of
      public RoboBee simulators (Fuller's own uses 7 mm for a 111 mg variant).
    - ``lift_limit = 1.5`` and ``torque_limit = 1 uN m``: Sec. II-B of the
      RoboBee paper.

    Args:
        mass: kg.
        inertia_y: kg m^2.
        b_w: N s/m.
        r_w: m.
        g: m/s^2.
        lift_limit: maximum lift in units of the weight ``m g``.
        torque_limit: N m.
        dtype: floating dtype of every field.

    Returns:
        The parameters, each a scalar array.

    Examples:
        >>> p = robobee_params()
        >>> float(max_lift(p)) > float(p.mass * p.g)
        True
    """
    f = lambda x: jnp.asarray(x, dtype)  # noqa: E731
    return RoboBeeParams(
        mass=f(mass),
        inertia_y=f(inertia_y),
        b_w=f(b_w),
        r_w=f(r_w),
        g=f(g),
        lift_limit=f(lift_limit),
        torque_limit=f(torque_limit),
    )


def max_lift(params: RoboBeeParams) -> jax.Array:
    """Upper limit of the lift, ``f_L,max = lift_limit m g`` (Sec. II-B), N."""
    return params.lift_limit * params.mass * params.g


def randomize(params: RoboBeeParams, spread=0.2, *, key: jax.Array) -> RoboBeeParams:
    """A robot whose mass, drag and inertia differ from ``params`` by up to ``spread``.

    Each of ``mass``, ``b_w`` and ``inertia_y`` is multiplied by its own factor
    drawn from ``U(1 - spread, 1 + spread)``; the geometry (``r_w``), gravity and
    actuator limits are kept (the limits scale with the drawn mass, see
    `max_lift`).

    Args:
        params: the nominal robot.
        spread: relative half-width of the uniform factors, in ``[0, 1)`` (0.2
            gives +-20 %); may be traced.
        key: PRNG key, used once.

    Returns:
        The randomized parameters, same dtypes as ``params``.

    Examples:
        >>> p = randomize(robobee_params(), key=jax.random.key(0))
        >>> bool(0.8 <= p.mass / 80e-6 <= 1.2)
        True
    """
    dtype = params.mass.dtype
    factors = jax.random.uniform(key, (3,), dtype, 1.0 - spread, 1.0 + spread)
    return params._replace(
        mass=params.mass * factors[0],
        b_w=params.b_w * factors[1],
        inertia_y=params.inertia_y * factors[2],
    )
