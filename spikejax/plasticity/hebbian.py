"""Reward-modulated Hebbian plasticity, Eq. (9)-(10) of the RoboBee paper."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from spikejax.plasticity.base import PlasticityRule

__all__ = [
    "RewardHebbianParams",
    "RewardHebbianState",
    "reward_modulated_hebbian",
    "row_increment",
]


class RewardHebbianParams(NamedTuple):
    """Parameters of the reward-modulated Hebbian rule.

    All fields are traced scalars (or arrays broadcasting against the presynaptic
    population), so a sweep can ``vmap`` over them.

    Attributes:
        mu: learning rate ``mu`` of Eq. (10), weight units per unit reward and step.
        tau: reward time constant ``tau`` of Eq. (9), s, > 0.
        dt: time step ``Delta t``, s, > 0.
    """

    mu: jax.Array
    tau: jax.Array
    dt: jax.Array


class RewardHebbianState(NamedTuple):
    """Per presynaptic neuron state of the rule.

    Attributes:
        since: time since the neuron's last spike, ``t - t_i``, s, shape ``(n_pre,)``;
            ``inf`` before its first spike.
        r: the reward trace ``r_i(t)`` of Eq. (9), dimensionless, shape ``(n_pre,)``.
    """

    since: jax.Array
    r: jax.Array


def reward_modulated_hebbian() -> PlasticityRule:
    """The reward-modulated Hebbian rule of Eq. (9)-(10) of the RoboBee paper.

    Every presynaptic neuron ``i`` keeps a reward trace updated once per step,

        r_i(t) = [sgn(y - y_hat) + r_i(t - dt)] * exp((t_i - t) / tau),     (9)

    with ``t_i`` the time of neuron ``i``'s last spike at or before ``t``, and every
    existing synapse from it changes by

        dw_ij(t) = mu * r_i(t) * m_ij,                                      (10)

    ``m_ij`` being 1 where the synapse ``i -> j`` exists and 0 elsewhere.

    Which synapses a reward updates (the paper leaves this open): all existing
    synapses leaving a presynaptic neuron ``i`` change by the same amount,
    whatever their postsynaptic neuron did. ``r_i`` grows while ``i`` fires (its
    factor is 1 at a spike and falls below 1/e about ``sqrt(2 tau dt)`` after
    it), so ``sum_t dw_ij`` is ``sgn(y - y_hat)`` times a multiple of the
    presynaptic rate: the sign-error LMS update of a rate readout, ``dw_ij ~
    sgn(e) * nu_i``, without the (non-negative) slope of the postsynaptic
    neuron's rate. With one global error sign this moves all the weights from
    active neurons up or down together, which is what moves a population-rate
    decoder (Eq. (8)) towards the teacher. Gating by postsynaptic spikes
    would also zero the update onto silent neurons, so a population driven
    below threshold could never be raised again.

    Sign convention: ``error = y - y_hat`` with ``y`` the teacher (the LQR output)
    and ``y_hat`` the decoded network output. A positive error (output too low)
    makes ``r`` positive and strengthens the synapses of recently active
    presynaptic neurons; a negative one weakens them.

    Timing: ``update`` is the rule at the time ``t`` of the spikes it is given
    (stamped as `spikejax.lif_step` stamps them), so a neuron spiking in this
    step has ``t_i = t`` and factor 1, and one that spiked ``k`` steps earlier
    factor ``exp(-k dt / tau)``. A neuron that never spiked has ``r = 0``.
    Eq. (9) is a recursion over steps (``sgn`` is added every step), so ``r``
    depends on ``dt`` as well as on ``tau``: one isolated spike under a constant
    sign adds up to ``sum_t r = 138`` at ``tau = 5 ms``, ``dt = 0.1 ms``.

    Returns:
        ``PlasticityRule(init, update)`` with ``init(weights) -> state`` and
        ``update(params, state, weights, pre, post, error, mask) -> (dw, state)``:
        ``weights``, ``mask`` and ``dw`` of shape ``(n_pre, n_post)``, ``pre``
        ``(n_pre,)`` and ``post`` ``(n_post,)`` spikes (bool or 0/1; ``post`` is
        unused, kept for the shared signature), ``error`` the scalar ``y - y_hat``.

    Examples:
        >>> rule = reward_modulated_hebbian()
        >>> w = jnp.zeros((3, 2))
        >>> p = RewardHebbianParams(mu=jnp.float32(0.1), tau=jnp.float32(5e-3),
        ...                         dt=jnp.float32(1e-4))
        >>> dw, s = rule.update(p, rule.init(w), w, jnp.array([1, 0, 0]),
        ...                     jnp.zeros(2), jnp.float32(0.5), jnp.ones((3, 2)))
        >>> dw[:, 0].tolist()
        [0.10000000149011612, 0.0, 0.0]
    """

    def init(weights: jax.Array) -> RewardHebbianState:
        n_pre = weights.shape[0]
        dtype = weights.dtype if jnp.issubdtype(weights.dtype, jnp.floating) else jnp.float32
        return RewardHebbianState(since=jnp.full((n_pre,), jnp.inf, dtype), r=jnp.zeros((n_pre,), dtype))

    def update(
        params: RewardHebbianParams,
        state: RewardHebbianState,
        weights: jax.Array,
        pre: jax.Array,
        post: jax.Array,
        error: jax.Array,
        mask: jax.Array,
    ) -> tuple[jax.Array, RewardHebbianState]:
        del post
        increment, state = row_increment(params, state, pre, error)
        dw = increment[:, None] * jnp.asarray(mask, weights.dtype)
        return dw.astype(weights.dtype), state

    return PlasticityRule(init, update)


def row_increment(
    params: RewardHebbianParams, state: RewardHebbianState, pre: jax.Array, error: jax.Array
) -> tuple[jax.Array, RewardHebbianState]:
    """Eq. (9)-(10) as one number per presynaptic neuron: ``dw_ij = increment_i * m_ij``.

    The rule moves every synapse leaving neuron ``i`` alike, so a network can keep
    its weights as `spikejax.synapses.RowWeights` and add this increment to
    rows, instead of adding the dense ``dw`` of `reward_modulated_hebbian`'s
    ``update`` (which is built from it).

    Args:
        params: learning rate, reward time constant and step.
        state: the traces at the previous step.
        pre: ``(n_pre,)`` spikes of this step, bool or 0/1.
        error: scalar ``y - y_hat``.

    Returns:
        ``(mu * r, state)``: the increment ``(n_pre,)`` and the new traces.
    """
    since = jnp.where(jnp.asarray(pre, bool), 0.0, state.since + params.dt)
    since = since.astype(state.since.dtype)
    r = (jnp.sign(error) + state.r) * jnp.exp(-since / params.tau)
    return (params.mu * r).astype(state.r.dtype), RewardHebbianState(since=since, r=r.astype(state.r.dtype))
