"""The hexapod's spiking CPG: 6 fully connected CPG neurons driven by 3 gait-selection neurons.

Fig. 2(a) of the hexapod SCPG paper: every gait-selection neuron ``G_i`` projects
to every CPG neuron ``N_j`` (``w_in``, shape (3, 6)), and every CPG neuron to
every other one (``w_cpg``, shape (6, 6), no self-connections). The neurons are
the discrete LIF of Eq. (1)-(2) (`spikejax.discrete_lif_step`), updated
synchronously: a spike at step ``t`` moves the potentials at step ``t + 1``.

A gait is triggered by switching its gait-selection neuron on: as in Alg. 1
(``Initialize Spikes G_i = 1``, never cleared), ``G_i`` spikes at every step for
as long as the gait runs.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from robots.hexapod.gaits import N_GAITS, N_LEGS
from spikejax import DiscreteLIFParams, DiscreteLIFState, discrete_lif_init, discrete_lif_step

__all__ = ["RECURRENT_MASK", "CPGState", "CPGWeights", "cpg_init", "cpg_step", "cpg_weights_init", "run_gait"]

# w_cpg[i, j] is the synapse from N(i+1) to N(j+1); the diagonal stays zero.
RECURRENT_MASK = 1.0 - jnp.eye(N_LEGS, dtype=jnp.float32)


class CPGWeights(NamedTuple):
    """Synaptic weights of the SCPG.

    Attributes:
        w_in: gait-selection -> CPG, shape (3, 6); ``w_in[i, j]`` is G(i+1) -> N(j+1).
        w_cpg: CPG -> CPG, shape (6, 6); ``w_cpg[i, j]`` is N(i+1) -> N(j+1), zero diagonal.
    """

    w_in: jax.Array
    w_cpg: jax.Array


class CPGState(NamedTuple):
    """Potentials and the spikes of the last step of the 6 CPG neurons."""

    neurons: DiscreteLIFState
    spikes: jax.Array


def cpg_weights_init(low: jax.Array, high: jax.Array, *, key: jax.Array) -> CPGWeights:
    """Random initial weights, ``U(low, high)`` for every synapse (Alg. 1 of the hexapod SCPG paper, line 1)."""
    key_in, key_cpg = jax.random.split(key)
    w_in = jax.random.uniform(key_in, (N_GAITS, N_LEGS), minval=low, maxval=high)
    w_cpg = jax.random.uniform(key_cpg, (N_LEGS, N_LEGS), minval=low, maxval=high)
    return CPGWeights(w_in=w_in, w_cpg=w_cpg * RECURRENT_MASK)


def cpg_init() -> CPGState:
    """All potentials at 0 and no spikes: the SCPG before a gait is triggered."""
    return CPGState(neurons=discrete_lif_init(N_LEGS), spikes=jnp.zeros((N_LEGS,), jnp.float32))


def cpg_step(
    neuron: DiscreteLIFParams, weights: CPGWeights, state: CPGState, gait_spikes: jax.Array
) -> tuple[CPGState, jax.Array]:
    """One synchronous step of the SCPG: Eq. (1)-(2) with ``I = W_in S_in + W_CPG S_CPG``.

    Args:
        neuron: decay factor and threshold of the CPG neurons.
        weights: the SCPG's synapses.
        state: potentials and last spikes of the CPG neurons.
        gait_spikes: spikes of the 3 gait-selection neurons at the last step, shape (3,).

    Returns:
        The new state and the CPG spikes of this step, shape (6,).
    """
    current = gait_spikes @ weights.w_in + state.spikes @ weights.w_cpg
    neurons, spikes = discrete_lif_step(neuron, state.neurons, current)
    return CPGState(neurons=neurons, spikes=spikes), spikes


def run_gait(neuron: DiscreteLIFParams, weights: CPGWeights, gait: jax.Array, n_steps: int) -> jax.Array:
    """The CPG raster, shape (n_steps, 6), when gait ``gait`` (0-based) is switched on from rest."""
    gait_spikes = jax.nn.one_hot(gait, N_GAITS, dtype=jnp.float32)

    def step(state, _):
        return cpg_step(neuron, weights, state, gait_spikes)

    _, raster = jax.lax.scan(step, cpg_init(), None, length=n_steps)
    return raster
