"""Spiking neuron models as pure per-population step functions.

Every model is a step ``(params, state, inputs) -> (state, spikes)``, with a
keyword-only ``key`` last where it draws noise (``lif_step(..., *, key=None)``), written
for one population of neurons (no batch axis: ``jax.vmap`` adds it). Parameters
and states are NamedTuples of arrays, so a sweep can ``vmap`` over any parameter
without recompiling.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

__all__ = [
    "DiscreteLIFParams",
    "DiscreteLIFState",
    "discrete_lif_init",
    "discrete_lif_step",
    "LIFParams",
    "LIFState",
    "lif_params",
    "lif_init",
    "lif_step",
    "lif_rate",
    "lif_first_spike_time",
]


class DiscreteLIFParams(NamedTuple):
    """Parameters of the discrete LIF of the hexapod SCPG paper, Eq. (1)-(2).

    Attributes:
        alpha: decay factor, dimensionless, > 0; the potential is divided by it
            every step (``alpha = 1`` is a perfect integrator).
        v_th: spiking threshold (the paper fires when ``V > V_th``).
    """

    alpha: jax.Array
    v_th: jax.Array


class DiscreteLIFState(NamedTuple):
    """State of a population of discrete LIF neurons.

    Attributes:
        v: membrane potentials, shape ``(n,)``.
    """

    v: jax.Array


def discrete_lif_init(n: int, dtype=jnp.float32) -> DiscreteLIFState:
    """A population of ``n`` neurons at rest (``V = 0``)."""
    return DiscreteLIFState(v=jnp.zeros((n,), dtype))


def discrete_lif_step(
    params: DiscreteLIFParams, state: DiscreteLIFState, inputs: jax.Array
) -> tuple[DiscreteLIFState, jax.Array]:
    """One step of the discrete LIF, Eq. (1)-(2) of the hexapod SCPG paper.

    ``V[t+1] = V[t] / alpha + sum_i W_ij S_i[t]``; if ``V[t+1] > V_th`` the neuron
    spikes (``S[t+1] = 1``) and ``V[t+1]`` is reset to the resting potential 0.
    A presynaptic spike therefore moves the postsynaptic potential in the very
    next step (no synaptic delay or dynamics).

    Args:
        params: decay factor and threshold (scalars or shape ``(n,)``).
        state: potentials ``V[t]``, shape ``(n,)``.
        inputs: the summed synaptic input ``sum_i W_ij S_i[t]``, shape ``(n,)``.

    Returns:
        The new state and the spikes ``S[t+1]`` as a float array of 0/1, shape ``(n,)``.
    """
    v = state.v / params.alpha + inputs
    fired = v > params.v_th
    v = jnp.where(fired, jnp.zeros_like(v), v)
    return DiscreteLIFState(v=v), fired.astype(v.dtype)


class LIFParams(NamedTuple):
    """Parameters of the current-driven LIF, Eq. (6)-(7) of the RoboBee paper.

    Each field is a scalar or an array that broadcasts against the population,
    shape ``(n,)``; all are traced, so a sweep can ``vmap`` over any of them. Units
    are SI (seconds, ohms, amperes, volts) or any consistent set, e.g. a
    dimensionless potential with ``r = 1``.

    Attributes:
        tau: membrane time constant, s, > 0.
        r: membrane resistance, ohm; ``r * I`` is in volts.
        v_th: threshold, V; the neuron fires when ``v >= v_th`` (Eq. (7) of the RoboBee paper).
        v_reset: potential after a spike, V (the paper's rest value ``v_r``).
        v_rest: resting potential, V; the potential relaxes to
            ``v_inf = v_rest + r * I``.
        t_ref: absolute refractory period, s, >= 0; ``round(t_ref / dt)`` steps.
            The snake R-STDP paper's "parrot" input neurons are this neuron with
            ``t_ref = 0`` and ``v_th`` close to ``v_rest`` (Section II-B).
        dt: time step, s, > 0.
        sigma: stationary standard deviation of ``v`` under the noise ``xi``,
            V, >= 0 (an Ornstein-Uhlenbeck process); 0 is noiseless.
    """

    tau: jax.Array
    r: jax.Array
    v_th: jax.Array
    v_reset: jax.Array
    v_rest: jax.Array
    t_ref: jax.Array
    dt: jax.Array
    sigma: jax.Array


class LIFState(NamedTuple):
    """State of a population of current-driven LIF neurons.

    Attributes:
        v: membrane potentials, V, shape ``(n,)``.
        refractory: whole steps of refractoriness left at the state's time,
            shape ``(n,)``, stored as floats; a step that starts with
            ``refractory > 0`` holds ``v`` at ``v_reset`` and counts down by one.
    """

    v: jax.Array
    refractory: jax.Array


def lif_params(
    tau=20e-3,
    r=1.0,
    v_th=1.0,
    v_reset=0.0,
    v_rest=0.0,
    t_ref=2e-3,
    dt=1e-4,
    sigma=0.0,
    dtype=jnp.float32,
) -> LIFParams:
    """Builds `LIFParams` from scalars or arrays, with defaults in SI units.

    Args:
        tau: membrane time constant, s.
        r: membrane resistance, ohm.
        v_th: threshold, V.
        v_reset: reset potential, V.
        v_rest: resting potential, V.
        t_ref: absolute refractory period, s.
        dt: time step, s.
        sigma: stationary standard deviation of the membrane noise, V.
        dtype: floating dtype of every field.

    Returns:
        The parameters, each field a ``dtype`` array of the shape it was given.

    Examples:
        >>> p = lif_params(tau=10e-3, t_ref=0.0)
        >>> float(p.t_ref), p.tau.dtype
        (0.0, dtype('float32'))
    """
    return LIFParams(*(jnp.asarray(x, dtype) for x in (tau, r, v_th, v_reset, v_rest, t_ref, dt, sigma)))


def lif_init(n: int, params: LIFParams) -> LIFState:
    """A population of ``n`` neurons at ``v_rest``, none refractory.

    Args:
        n: number of neurons (static).
        params: the population's parameters; ``v_rest`` may be a scalar or ``(n,)``.

    Returns:
        The state, ``v`` and ``refractory`` of shape ``(n,)`` in the dtype of ``v_rest``.
    """
    v_rest = jnp.asarray(params.v_rest)
    v = jnp.broadcast_to(v_rest, (n,))
    return LIFState(v=v, refractory=jnp.zeros((n,), v.dtype))


def lif_step(
    params: LIFParams,
    state: LIFState,
    current: jax.Array,
    *,
    key: jax.Array | None = None,
) -> tuple[LIFState, jax.Array]:
    """One step of the LIF of Eq. (6)-(7) of the RoboBee paper, exact over ``dt``.

    Eq. (6), ``dv/dt = (v_rest + R I - v) / tau + xi``, is integrated exactly for
    an input current held constant over the step::

        v(t + dt) = v_inf + (v(t) - v_inf) exp(-dt / tau)
                    + sigma sqrt(1 - exp(-2 dt / tau)) N(0, 1),
        v_inf = v_rest + R I,

    the noise ``xi`` being an Ornstein-Uhlenbeck term whose exact update is the
    last line, so ``sigma`` is the stationary standard deviation of ``v``
    whatever ``dt``. If ``v(t + dt) >= v_th`` (the firing time of Eq. (7)) the
    neuron spikes, ``v`` is reset to ``v_reset`` and stays there, ignoring its
    input, for the refractory period ``t_ref``.

    Args:
        params: the neurons' parameters (scalars or shape ``(n,)``).
        state: potentials and refractory counters at time ``t_k = k dt``, shape ``(n,)``.
        current: input current ``I``, A, held over ``[t_k, t_k + dt)``, shape ``(n,)``.
        key: PRNG key for the noise. ``None`` means no noise whatever
            ``params.sigma`` is (``sigma`` is traced, so it cannot select the
            noiseless path); pass a key, used once, to draw it.

    Returns:
        The state at ``t_{k+1}`` and the spikes of this step as a bool array,
        shape ``(n,)``.

    Notes:
        Timing follows Brian2 (``method='exact'``, ``refractory=t_ref``), so the
        two produce the same spike steps. The spike of the step from ``t_k`` to
        ``t_{k+1}`` is stamped ``t_k``: the threshold crossing lies in
        ``(t_k, t_{k+1}]``. The neuron is refractory over
        ``[t_k, t_k + t_ref)``: the ``round(t_ref / dt) - 1`` steps after the
        spiking step hold ``v``, and the next integrates again, so no two spikes
        are closer than ``t_ref`` (Brian2 truncates ``t_ref / dt`` instead of
        rounding; the two agree when ``t_ref`` is a multiple of ``dt``). With
        ``t_ref < 1.5 dt`` nothing is held: the parrot neuron.

    Examples:
        >>> p = lif_params()
        >>> s = lif_init(3, p)
        >>> s, spikes = lif_step(p, s, jnp.array([0.0, 1.5, 3.0]))
    """
    v_inf = params.v_rest + params.r * current
    decay = jnp.exp(-params.dt / params.tau)
    v_free = v_inf + (state.v - v_inf) * decay
    if key is not None:
        # 1 - exp(-2x) by expm1 keeps the noise amplitude accurate for dt << tau.
        noise_std = params.sigma * jnp.sqrt(-jnp.expm1(-2.0 * params.dt / params.tau))
        v_free = v_free + noise_std * jax.random.normal(key, jnp.shape(v_free), v_free.dtype)

    held = state.refractory > 0
    fired = jnp.logical_and(~held, v_free >= params.v_th)
    n_ref = jnp.round(params.t_ref / params.dt)
    v_reset = jnp.broadcast_to(params.v_reset, v_free.shape).astype(v_free.dtype)
    v = jnp.where(held | fired, v_reset, v_free)
    refractory = jnp.where(
        fired,
        jnp.maximum(n_ref - 1.0, 0.0),
        jnp.maximum(state.refractory - 1.0, 0.0),
    ).astype(state.refractory.dtype)
    return LIFState(v=v, refractory=refractory), fired


def lif_rate(params: LIFParams, current: jax.Array) -> jax.Array:
    """Closed-form firing rate (f-I curve) of the noiseless LIF of Eq. (6)-(7) of the RoboBee paper.

    ``f = 1 / (t_ref + tau ln((v_inf - v_reset) / (v_inf - v_th)))`` with
    ``v_inf = v_rest + R I`` when ``v_inf > v_th``, else 0 (below rheobase the
    potential never reaches threshold). This is the continuous-time rate; a
    simulation with step ``dt`` quantises each interspike interval to whole
    steps, within ``dt`` of ``1 / f`` (see `lif_step`).

    Args:
        params: the neurons' parameters; assumes ``v_reset < v_th``.
        current: constant input current, A, any shape broadcasting with ``params``.

    Returns:
        Firing rates, Hz.
    """
    v_inf = params.v_rest + params.r * current
    above = v_inf > params.v_th
    # Safe denominators keep the unused branch finite, so gradients stay NaN-free.
    num = jnp.where(above, v_inf - params.v_reset, 2.0)
    den = jnp.where(above, v_inf - params.v_th, 1.0)
    period = params.t_ref + params.tau * jnp.log(num / den)
    return jnp.where(above, 1.0 / period, 0.0)


def lif_first_spike_time(params: LIFParams, current: jax.Array, v0: jax.Array) -> jax.Array:
    """Time for the noiseless LIF of Eq. (6) of the RoboBee paper to reach ``v_th`` from ``v0``.

    ``T = tau ln((v_inf - v0) / (v_inf - v_th))`` with ``v_inf = v_rest + R I``,
    the continuous-time firing time of the RoboBee paper's Eq. (7) under a constant current; 0 when
    ``v0 >= v_th`` and ``inf`` when ``v_inf <= v_th`` (never). A simulation
    started from ``v0`` at ``t = 0`` stamps that spike at step
    ``k = ceil(T / dt) - 1`` (see `lif_step`), so ``k dt`` is within ``dt`` of ``T``.

    Args:
        params: the neurons' parameters (``tau``, ``r``, ``v_rest``, ``v_th``).
        current: constant input current, A.
        v0: initial potential, V.

    Returns:
        First-spike times, s, the broadcast shape of the inputs.
    """
    v_inf = params.v_rest + params.r * current
    reaches = v_inf > params.v_th
    already = v0 >= params.v_th
    ok = reaches & ~already
    num = jnp.where(ok, v_inf - v0, 2.0)
    den = jnp.where(ok, v_inf - params.v_th, 1.0)
    t = params.tau * jnp.log(num / den)
    return jnp.where(already, 0.0, jnp.where(reaches, t, jnp.inf))
