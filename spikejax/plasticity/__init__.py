"""Plasticity rules as ``(init, update)`` pairs of pure functions (as optax's transforms).

``update`` returns a weight change ``dw`` and a new rule state; the caller adds
``dw`` to its weights, so rules compose with masks and clipping.
"""

from spikejax.plasticity.base import PlasticityRule
from spikejax.plasticity.supervised import StochasticSupervisedParams
from spikejax.plasticity.supervised import stochastic_supervised

__all__ = [
    "PlasticityRule",
    "StochasticSupervisedParams",
    "stochastic_supervised",
]
