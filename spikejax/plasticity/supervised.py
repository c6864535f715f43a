"""Stochastic supervised weight adaptation (Alg. 1 of the hexapod SCPG paper)."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from spikejax.plasticity.base import PlasticityRule

__all__ = ["StochasticSupervisedParams", "StochasticSupervisedState", "stochastic_supervised"]


class StochasticSupervisedParams(NamedTuple):
    """Parameters of the stochastic supervised rule.

    Attributes:
        lr: update scale ``eta`` (Alg. 1 writes none, i.e. ``eta = 1``).
    """

    lr: jax.Array


class StochasticSupervisedState(NamedTuple):
    """The rule keeps no state of its own; its randomness comes in as an argument."""


def stochastic_supervised() -> PlasticityRule:
    """Alg. 1 of the hexapod SCPG paper as an ``(init, update)`` pair.

    The error of each postsynaptic neuron is ``error_j = obtained_j - required_j``
    (+1 for a redundant spike, -1 for a missing one, 0 when correct). Every
    synapse whose presynaptic neuron spiked in the previous step (so that it
    contributed to this step's potential) moves against the error by a random
    amount::

        dW_ij = -eta * pre_i * error_j * u_j,     u_j ~ U(0, 1)

    With ``pre`` the gait-selection spikes this is Alg. 1's ``dW_in = Error x
    random()``; with ``pre`` the CPG's previous spikes it is ``dW_CPG = Error x
    S_CPG-prev x random()``. As in Alg. 1, ``random()`` is drawn once per
    postsynaptic neuron and step (inside its "for neuron" loop), so all the
    synapses onto one neuron move by the same fraction; call ``update`` once per
    presynaptic group to give each group its own draw. The draws come in as an
    argument, so a caller can draw a whole episode's at once (one PRNG call
    instead of one per step, which dominates the cost of small networks). Weights onto a correctly
    firing neuron never change, so a network that produces its pattern stops
    learning.

    Returns:
        ``PlasticityRule(init, update)`` with
        ``update(params, state, weights, pre, post, target, noise) -> (dw, state)``,
        ``weights``/``dw`` of shape ``(n_pre, n_post)``, ``pre`` ``(n_pre,)``,
        ``post`` and ``target`` ``(n_post,)`` of 0/1 spikes, ``noise`` ``(n_post,)``
        of ``U(0, 1)`` draws (e.g. ``jax.random.uniform(key, (n_post,))``).
    """

    def init(weights: jax.Array) -> StochasticSupervisedState:
        del weights
        return StochasticSupervisedState()

    def update(
        params: StochasticSupervisedParams,
        state: StochasticSupervisedState,
        weights: jax.Array,
        pre: jax.Array,
        post: jax.Array,
        target: jax.Array,
        noise: jax.Array,
    ) -> tuple[jax.Array, StochasticSupervisedState]:
        del weights
        error = post - target
        dw = -params.lr * jnp.outer(pre, error * noise)
        return dw, state

    return PlasticityRule(init, update)
