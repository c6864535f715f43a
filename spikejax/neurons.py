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
    "IafPscAlphaParams",
    "IafPscAlphaState",
    "iaf_psc_alpha_params",
    "iaf_psc_alpha_init",
    "iaf_psc_alpha_step",
    "iaf_refractory_steps",
    "parrot_step",
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


# ------------------------------------------------------------- NEST iaf_psc_alpha

# NEST's default clock: 1000 tics per ms; a duration in ms becomes whole tics, then steps.
_NEST_TICS_PER_MS = 1000.0
# NEST 3.10 (libnestutil/iaf_propagator.h): P31 takes its regular form only if
# h > 1e-7 tau_m^2 / |tau_m - tau_syn|.
_NEST_STABILITY_FACTOR = 1e-7


class IafPscAlphaParams(NamedTuple):
    """Parameters of NEST's ``iaf_psc_alpha``, in NEST's units (pF, ms, mV, pA).

    Each field is a scalar or an array broadcasting against the population,
    shape ``(n,)``; all are traced, so ``jax.vmap`` over a batch of them compiles
    once. NEST's ``V_min`` (lower bound of ``V_m``) is not modelled: it is ``-inf``
    by default in NEST.

    Attributes:
        C_m: membrane capacitance, pF, > 0.
        tau_m: membrane time constant, ms, > 0.
        t_ref: absolute refractory period, ms, >= 0; counted in whole steps as
            NEST counts it, ``ceil(round(1000 t_ref) / round(1000 dt))`` (tics of
            1 us rounded, then rounded up to steps).
        E_L: resting potential, mV.
        V_reset: potential after a spike, mV.
        V_th: threshold, mV; the neuron fires when ``V_m >= V_th``.
        tau_syn_ex: rise time of the excitatory alpha current, ms, > 0.
        tau_syn_in: rise time of the inhibitory alpha current, ms, > 0.
        I_e: constant external current, pA.
    """

    C_m: jax.Array
    tau_m: jax.Array
    t_ref: jax.Array
    E_L: jax.Array
    V_reset: jax.Array
    V_th: jax.Array
    tau_syn_ex: jax.Array
    tau_syn_in: jax.Array
    I_e: jax.Array


def iaf_psc_alpha_params(
    *,
    C_m=250.0,
    tau_m=10.0,
    t_ref=2.0,
    E_L=-70.0,
    V_reset=-70.0,
    V_th=-55.0,
    tau_syn_ex=2.0,
    tau_syn_in=2.0,
    I_e=0.0,
    dtype=jnp.float32,
) -> IafPscAlphaParams:
    """Builds `IafPscAlphaParams` from scalars or arrays; the defaults are NEST 3.10's.

    Args:
        C_m: membrane capacitance, pF.
        tau_m: membrane time constant, ms.
        t_ref: refractory period, ms.
        E_L: resting potential, mV.
        V_reset: reset potential, mV.
        V_th: threshold, mV.
        tau_syn_ex: excitatory synaptic time constant, ms.
        tau_syn_in: inhibitory synaptic time constant, ms.
        I_e: constant external current, pA.
        dtype: floating dtype of every field (``jnp.float64`` to match NEST to
            rounding; needs ``jax_enable_x64``).

    Returns:
        The parameters, each field a ``dtype`` array of the shape it was given.

    Examples:
        >>> p = iaf_psc_alpha_params(I_e=[0.0, 400.0])
        >>> p.I_e.shape, float(p.V_th)
        ((2,), -55.0)
    """
    values = (C_m, tau_m, t_ref, E_L, V_reset, V_th, tau_syn_ex, tau_syn_in, I_e)
    return IafPscAlphaParams(*(jnp.asarray(x, dtype) for x in values))


class IafPscAlphaState(NamedTuple):
    """State of a population of ``iaf_psc_alpha`` neurons, each field ``(n,)``.

    Attributes:
        V_m: membrane potential, mV (absolute, as NEST records it).
        I_ex: excitatory synaptic current, pA.
        dI_ex: its time derivative, pA/ms.
        I_in: inhibitory synaptic current, pA (negative for inhibitory input).
        dI_in: its time derivative, pA/ms.
        refractory: steps of refractoriness left, int32; a step that starts
            with ``refractory > 0`` holds ``V_m`` and counts down by one.
    """

    V_m: jax.Array
    I_ex: jax.Array
    dI_ex: jax.Array
    I_in: jax.Array
    dI_in: jax.Array
    refractory: jax.Array


def iaf_psc_alpha_init(n: int, params: IafPscAlphaParams, dtype=None) -> IafPscAlphaState:
    """A population of ``n`` neurons at rest (``V_m = E_L``), no current, none refractory.

    Args:
        n: number of neurons (static).
        params: the population's parameters.
        dtype: floating dtype of the state; ``None`` takes that of ``params.E_L``.

    Returns:
        The state, every field of shape ``(n,)``.
    """
    e_l = jnp.asarray(params.E_L)
    dtype = e_l.dtype if dtype is None else dtype
    v = jnp.broadcast_to(e_l, (n,)).astype(dtype)
    zero = jnp.zeros((n,), dtype)
    return IafPscAlphaState(V_m=v, I_ex=zero, dI_ex=zero, I_in=zero, dI_in=zero, refractory=jnp.zeros((n,), jnp.int32))


def _alpha_propagators(tau_syn, tau_m, c_m, h):
    """NEST 3.10's ``IAFPropagatorAlpha(tau_syn, tau_m, c_m).evaluate(h)``: ``(P31, P32)``.

    The regular forms divide by ``tau_m - tau_syn``; near ``tau_syn == tau_m``
    NEST switches to the singular limits, and so does this, by the same tests.
    """
    beta = tau_syn * tau_m / (tau_m - tau_syn)  # inf when tau_m == tau_syn, as in NEST
    gamma = beta / c_m
    inv_beta = (tau_m - tau_syn) / (tau_syn * tau_m)
    exp_h_tau_syn = jnp.exp(-h / tau_syn)
    expm1_h_tau = jnp.expm1(h * inv_beta)
    exp_h_tau = jnp.exp(-h / tau_m)

    p32_regular = gamma * exp_h_tau_syn * expm1_h_tau
    normal = jnp.isfinite(p32_regular) & (p32_regular >= jnp.finfo(p32_regular.dtype).tiny)
    p32 = jnp.where(normal, p32_regular, h / c_m * exp_h_tau)

    h_min_regular = _NEST_STABILITY_FACTOR * tau_m * tau_m / jnp.abs(tau_m - tau_syn)
    p31_regular = gamma * exp_h_tau_syn * (beta * expm1_h_tau - h)
    p31 = jnp.where(h > h_min_regular, p31_regular, 0.5 * h * h / c_m * exp_h_tau)
    return p31, p32


def iaf_refractory_steps(t_ref, dt) -> jax.Array:
    """NEST's refractory period in steps: ``Time(Time::ms(t_ref)).get_steps()``.

    ``t_ref`` is rounded to whole tics (1 us, NEST's default clock), then rounded
    up to whole steps of ``dt``, so ``t_ref = 0.25`` at ``dt = 0.1`` holds 3 steps.

    Args:
        t_ref: refractory period, ms, any shape.
        dt: step, ms, a multiple of the tic (0.001 ms).

    Returns:
        Steps, the dtype of ``t_ref``.
    """
    t_ref = jnp.asarray(t_ref)
    tics = jnp.floor(t_ref * _NEST_TICS_PER_MS + 0.5)
    tics_per_step = jnp.round(jnp.asarray(dt, t_ref.dtype) * _NEST_TICS_PER_MS)
    return jnp.ceil(tics / tics_per_step)


def iaf_psc_alpha_step(
    params: IafPscAlphaParams,
    state: IafPscAlphaState,
    ex: jax.Array,
    inh: jax.Array,
    dt,
) -> tuple[IafPscAlphaState, jax.Array]:
    """One step of NEST 3.10's ``iaf_psc_alpha``, exact integration, same update order.

    The subthreshold dynamics ``C_m dV/dt = -(V - E_L) C_m / tau_m + I_ex + I_in
    + I_e``, with each synaptic current an alpha function ``w e t / tau_syn
    exp(-t / tau_syn)`` per input spike of weight ``w`` (pA, its peak), are
    linear, so one step of length ``h = dt`` is an exact propagator matrix
    product (Rotter and Diesmann 1999). The step from ``t_k = k h`` to
    ``t_{k+1}``, in NEST's order (``models/iaf_psc_alpha.cpp``, ``update``), with
    ``y = V_m - E_L``:

    1. if not refractory, ``y <- P30 I_e + P31_ex dI_ex + P32_ex I_ex + P31_in
       dI_in + P32_in I_in + expm1(-h / tau_m) y + y``; else the counter drops
       by one and ``V_m`` is held;
    2. ``I <- h P11 dI + P11 I``, ``dI <- P11 dI`` with ``P11 = exp(-h / tau_syn)``
       (each channel with its own ``tau_syn``);
    3. the input arriving this step is added: ``dI_ex += e / tau_syn_ex * ex``,
       ``dI_in += e / tau_syn_in * inh``; it therefore first moves ``V_m`` in the
       next step;
    4. if ``V_m >= V_th``: spike, ``V_m <- V_reset``, refractory for
       `iaf_refractory_steps` ``(t_ref, dt)`` steps (the held steps follow this one).

    Args:
        params: the neurons' parameters (scalars or shape ``(n,)``).
        state: the state at ``t_k``, fields ``(n,)``.
        ex: summed weights, pA, of the excitatory spikes arriving in this step,
            ``(n,)``, each spike counted with its multiplicity.
        inh: the same for the inhibitory spikes, as negative numbers. NEST sorts
            each arriving event by the sign of weight x multiplicity (> 0 to
            ``ex``, else to ``inh``), so sum positive and negative weights apart:
            ``ex = counts @ max(W, 0)``, ``inh = counts @ min(W, 0)``.
        dt: step ``h``, ms (NEST's resolution).

    Returns:
        The state at ``t_{k+1}`` and the spikes of this step, bool ``(n,)``.

    Notes:
        Timing, as NEST does it. A spike emitted by the update of step ``k`` is
        stamped ``t_{k+1} = (k + 1) dt`` (what a ``spike_recorder`` records).
        Sent over a connection of delay ``d = D dt`` (``D >= 1``), it is in the
        target's ``ex`` / ``inh`` at step ``k + D`` (NEST delivers it to the
        ring-buffer slot ``stamp + D - 1``), arriving at ``t_{k+D+1} = stamp +
        d``, and first changes the target's ``V_m`` in step ``k + D + 1``.
        `spikejax.synapses.delay_read` of a `spikejax.synapses.DelayLine` of
        ``D`` steps, fed each step's spikes after the update, gives exactly
        this. A NEST ``multimeter`` at interval ``dt`` records, at ``t_{k+1}``,
        ``V_m`` after the update of step ``k``.

    Examples:
        >>> p = iaf_psc_alpha_params(I_e=1000.0)
        >>> s = iaf_psc_alpha_init(2, p)
        >>> s, spikes = iaf_psc_alpha_step(p, s, jnp.zeros(2), jnp.zeros(2), 0.1)
    """
    dtype = state.V_m.dtype
    p = IafPscAlphaParams(*(jnp.asarray(x, dtype) for x in params))
    h = jnp.asarray(dt, dtype)
    ex = jnp.asarray(ex, dtype)
    inh = jnp.asarray(inh, dtype)

    p11_ex = jnp.exp(-h / p.tau_syn_ex)
    p11_in = jnp.exp(-h / p.tau_syn_in)
    expm1_tau_m = jnp.expm1(-h / p.tau_m)
    p30 = -p.tau_m / p.C_m * expm1_tau_m
    p21_ex = h * p11_ex
    p21_in = h * p11_in
    p31_ex, p32_ex = _alpha_propagators(p.tau_syn_ex, p.tau_m, p.C_m, h)
    p31_in, p32_in = _alpha_propagators(p.tau_syn_in, p.tau_m, p.C_m, h)
    e = jnp.asarray(jnp.e, dtype)

    y3 = state.V_m - p.E_L
    # NEST's order of operations, so that float64 results agree to rounding.
    free = (
        p30 * p.I_e
        + p31_ex * state.dI_ex
        + p32_ex * state.I_ex
        + p31_in * state.dI_in
        + p32_in * state.I_in
        + expm1_tau_m * y3
        + y3
    )
    held = state.refractory > 0
    y3 = jnp.where(held, y3, free)
    refractory = jnp.where(held, state.refractory - 1, state.refractory)

    i_ex = p21_ex * state.dI_ex + p11_ex * state.I_ex
    di_ex = state.dI_ex * p11_ex + e / p.tau_syn_ex * ex
    i_in = p21_in * state.dI_in + p11_in * state.I_in
    di_in = state.dI_in * p11_in + e / p.tau_syn_in * inh

    fired = y3 >= p.V_th - p.E_L
    n_ref = iaf_refractory_steps(p.t_ref, h).astype(jnp.int32)
    refractory = jnp.where(fired, n_ref, refractory)
    y3 = jnp.where(fired, p.V_reset - p.E_L, y3)
    v = jnp.broadcast_to(y3 + p.E_L, state.V_m.shape)
    bshape = lambda x: jnp.broadcast_to(x, state.V_m.shape)  # noqa: E731
    new = IafPscAlphaState(
        V_m=v,
        I_ex=bshape(i_ex),
        dI_ex=bshape(di_ex),
        I_in=bshape(i_in),
        dI_in=bshape(di_in),
        refractory=jnp.broadcast_to(refractory, state.refractory.shape).astype(jnp.int32),
    )
    return new, jnp.broadcast_to(fired, state.V_m.shape)


def parrot_step(counts: jax.Array) -> jax.Array:
    """NEST's ``parrot_neuron``: repeats, in the step they arrive, the spikes it receives.

    NEST's parrot sums, per step, the multiplicities of the spikes arriving on
    its receptor port 0 (the connection weights are ignored; spikes on port 1
    are dropped) and, if the sum ``m`` is positive, sends one spike event of
    multiplicity ``m`` in that same step, stamped at the step's end like any
    spike (a ``spike_recorder`` records ``m`` spike times, all equal). So a
    spike that leaves a generator stamped ``t`` over a connection of delay
    ``d`` leaves the parrot stamped ``t + d``, with its multiplicity; a target
    receives ``m`` times the connection's weight. The parrot has no state.

    Args:
        counts: multiplicities arriving this step (after the delay), summed
            over the presynaptic spikes, ``(n,)``, nonnegative integers (any
            numeric dtype).

    Returns:
        The multiplicities the parrots emit this step, ``counts`` itself,
        ``(n,)``, same dtype.

    Examples:
        >>> parrot_step(jnp.array([0, 2, 1]))
        Array([0, 2, 1], dtype=int32)
    """
    return jnp.asarray(counts)
