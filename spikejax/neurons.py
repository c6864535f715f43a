"""Spiking neuron models as pure per-population step functions.

Every model is a step ``(params, state, inputs[, key]) -> (state, spikes)`` written
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
