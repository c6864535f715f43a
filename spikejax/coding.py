"""Encoders that turn continuous signals into spikes, and the pre-processing before them.

Every function is written for one population (no batch axis: ``jax.vmap`` adds it)
and takes an explicit ``jax.random`` key where it is stochastic, keyword-only and
last (``*, key``).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from spikejax.errors import UserError

__all__ = [
    "DecoderParams",
    "DecoderState",
    "antagonist_currents",
    "decoder_init",
    "decoder_step",
    "poisson_spikes",
    "poisson_train",
    "shift_scale",
]


def poisson_spikes(rates: jax.Array, dt, *, key: jax.Array) -> jax.Array:
    """One time step of independent Poisson spike generators.

    Each neuron spikes with probability ``p = 1 - exp(-rate dt)``, the exact
    probability that a Poisson process of that rate has at least one event in a
    window of length ``dt``. The snake R-STDP paper drives its input layer with
    such Poisson neurons (Section II-B, D).

    Args:
        rates: firing rates, Hz, shape ``(n,)`` (any shape works); negative rates
            are treated as 0.
        dt: step length, s (scalar, may be traced).
        key: PRNG key, used once.

    Returns:
        Spikes as a bool array of the shape of ``rates``.

    Notes:
        ``1 - exp(-rate dt)`` rather than ``rate dt`` clipped to 1: both agree to
        ``O((rate dt)^2)`` when ``rate dt << 1``, but the clipped form is no
        longer a probability of anything once ``rate dt`` approaches 1 and
        saturates abruptly, whereas this one bins a true Poisson process: the
        mean count over ``n`` steps is ``n (1 - exp(-rate dt))``, below
        ``rate n dt`` only by the events that fell into an already-occupied step.

    Examples:
        >>> s = poisson_spikes(jnp.full((4,), 100.0), 1e-3, key=jax.random.key(0))
        >>> s.shape, s.dtype
        ((4,), dtype('bool'))
    """
    rates = jnp.asarray(rates)
    dtype = rates.dtype if jnp.issubdtype(rates.dtype, jnp.floating) else jnp.float32
    p = -jnp.expm1(-jnp.maximum(rates, 0.0) * dt)
    return jax.random.uniform(key, rates.shape, dtype) < p


def poisson_train(rates: jax.Array, dt, n_steps: int, *, key: jax.Array) -> jax.Array:
    """A Poisson spike train of ``n_steps`` steps, `poisson_spikes` scanned over time.

    Step ``k`` uses ``jax.random.split(key, n_steps)[k]``, so it equals
    ``poisson_spikes(rates_k, dt, key=keys[k])`` and a simulation that draws its input
    step by step with those keys sees the same train.

    Args:
        rates: firing rates, Hz: shape ``(n,)`` for constant rates or
            ``(n_steps, n)`` for a rate per step.
        dt: step length, s.
        n_steps: number of steps (static: a ``static_argnames`` entry under ``jit``).
        key: PRNG key, used once.

    Returns:
        Spikes, bool, shape ``(n_steps, n)``.

    Raises:
        UserError: if ``rates`` is 2-D and its first axis is not ``n_steps`` long.

    Examples:
        >>> train = poisson_train(jnp.array([0.0, 50.0]), 1e-3, 100, key=jax.random.key(1))
        >>> train.shape, bool(train[:, 0].any())
        ((100, 2), False)
    """
    rates = jnp.asarray(rates)
    keys = jax.random.split(key, n_steps)
    if rates.ndim == 2:
        if rates.shape[0] != n_steps:
            raise UserError(
                f"rates has shape {rates.shape}: a rate per step needs shape (n_steps, n) with n_steps = {n_steps}"
            )

        def step(carry, xs):
            k, r = xs
            return carry, poisson_spikes(r, dt, key=k)

        _, spikes = jax.lax.scan(step, None, (keys, rates))
    else:

        def step(carry, k):
            return carry, poisson_spikes(rates, dt, key=k)

        _, spikes = jax.lax.scan(step, None, keys)
    return spikes


def shift_scale(q: jax.Array, a: jax.Array, b: jax.Array) -> jax.Array:
    """Shifts and scales a signal before encoding, ``q_hat = a (q + b)``.

    The RoboBee paper (Section III) passes ``q_hat_i = a_i (q_i + b_i)``, with
    positive constants ``a_i`` and ``b_i``, into the network instead of each state
    variable ``q_i``, so that states in their expected range give a positive input
    current that makes the input groups fire.

    Args:
        q: signal, any shape.
        a: scale, broadcasting with ``q``.
        b: shift, in the units of ``q``, broadcasting with ``q``.

    Returns:
        ``a * (q + b)``, the broadcast shape.

    Examples:
        >>> float(shift_scale(jnp.float32(-0.5), 2.0, 1.0))
        1.0
    """
    return a * (q + b)


def antagonist_currents(q_hat: jax.Array, n_per_group: int, gain) -> jax.Array:
    """Input currents of groups of neurons split into antagonist halves, one group per signal.

    The RoboBee paper (Section III) feeds each shifted and scaled state variable
    ``q_hat_g`` (`shift_scale`) to its own input group. Here the first
    ``n_per_group // 2`` neurons of group ``g`` get the current ``gain * q_hat_g``
    and the other ``n_per_group - n_per_group // 2`` get ``gain * (1 - q_hat_g)``:
    whichever way ``q_g`` moves, one half of the group is driven harder, so the
    group never falls silent as a whole and a presynaptic learning rule can push
    the output both ways. The halves are this project's addition to the paper's
    encoder (with one-sided groups a large negative error silenced a whole group
    and the RoboBee's SNN flight tumbled); each neuron's own threshold then makes
    it a different rectified feature of ``q_g``.

    Args:
        q_hat: the shifted and scaled signals, shape ``(n_groups,)``.
        n_per_group: neurons per group (static), >= 1; with 1 the group is one
            antagonist neuron.
        gain: current per unit of ``q_hat``, broadcasting with a scalar.

    Returns:
        Currents, shape ``(n_groups * n_per_group,)``, group-major: neuron
        ``n`` belongs to group ``n // n_per_group`` and is antagonist when
        ``n % n_per_group >= n_per_group // 2``.

    Raises:
        UserError: if ``n_per_group`` is not an int >= 1.

    Examples:
        >>> antagonist_currents(jnp.array([0.25, 1.5]), 3, 2.0).tolist()
        [0.5, 1.5, 1.5, 3.0, -1.0, -1.0]
    """
    if isinstance(n_per_group, bool) or not isinstance(n_per_group, int) or n_per_group < 1:
        raise UserError(f"n_per_group must be an int >= 1, got {n_per_group!r}")
    half = n_per_group // 2
    q_hat = jnp.asarray(q_hat)
    drive = jnp.concatenate(
        [jnp.repeat(q_hat[:, None], half, 1), jnp.repeat(1.0 - q_hat[:, None], n_per_group - half, 1)], axis=1
    )
    return gain * drive.reshape(-1)


class DecoderParams(NamedTuple):
    """Parameters of the leaky-integrator decoder, Eq. (8) of the RoboBee paper.

    Attributes:
        alpha: output per unit of the spike trace (the scale ``alpha``), in the
            units of the decoded signal.
        beta: decay rate ``beta`` of each spike's contribution, 1/s, > 0; ``1 / beta``
            trades a faster response for less noise.
        gamma: offset ``gamma``, units of the decoded signal; ``-gamma`` is the
            output of a silent population.
    """

    alpha: jax.Array
    beta: jax.Array
    gamma: jax.Array


class DecoderState(NamedTuple):
    """State of the decoder.

    Attributes:
        trace: ``sum_{t_f < t} exp(beta (t_f - t))`` over all the population's
            spikes, dimensionless, shape ``()``.
    """

    trace: jax.Array


def decoder_init(dtype=jnp.float32) -> DecoderState:
    """The decoder before any spike: a zero trace (output ``-gamma``)."""
    return DecoderState(trace=jnp.zeros((), dtype))


def decoder_step(params: DecoderParams, state: DecoderState, spikes: jax.Array, dt) -> tuple[DecoderState, jax.Array]:
    """One step of the leaky-integrator population decoder, Eq. (8) of the RoboBee paper.

    Eq. (8), ``y_hat(t) = alpha * sum_{t_f < t} exp(beta (t_f - t)) - gamma``, the
    sum running over the spike times ``t_f`` of every neuron of the population,
    is computed exactly by a trace that takes the spikes stamped ``t_k`` (as
    `spikejax.lif_step` stamps them) and decays over the step::

        trace(t_k + dt) = exp(-beta dt) * (trace(t_k) + n_k),
        y_hat(t_k + dt) = alpha * trace(t_k + dt) - gamma,

    ``n_k`` being the number of spikes in the step. A spike at ``t_k`` thus
    contributes ``alpha exp(-beta dt)`` at ``t_k + dt`` (``t_f < t`` is strict).

    Args:
        params: scale, decay rate and offset.
        state: the trace at ``t_k``.
        spikes: the population's spikes of the step from ``t_k``, bool or 0/1, shape ``(n,)``.
        dt: step length, s.

    Returns:
        The state and the decoded output ``y_hat`` at ``t_k + dt``, shape ``()``.

    Notes:
        For a population of ``N`` neurons each spiking with probability ``p``
        per step (rate ``nu ~ p / dt``), the mean output in the steady state is
        ``alpha * N p exp(-beta dt) / (1 - exp(-beta dt)) - gamma``, about
        ``alpha N nu / beta - gamma`` when ``beta dt << 1``.

    Examples:
        >>> p = DecoderParams(alpha=jnp.float32(1.0), beta=jnp.float32(10.0),
        ...                   gamma=jnp.float32(0.0))
        >>> s, y = decoder_step(p, decoder_init(), jnp.array([True, True]), 0.1)
        >>> round(float(y), 4)
        0.7358
    """
    n = jnp.sum(jnp.asarray(spikes, state.trace.dtype))
    decay = jnp.exp(-params.beta * dt)
    trace = (decay * (state.trace + n)).astype(state.trace.dtype)
    return DecoderState(trace=trace), params.alpha * trace - params.gamma
