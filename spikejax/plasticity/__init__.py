"""Plasticity rules as ``(init, update)`` pairs of pure functions (as optax's transforms).

``update`` returns a weight change ``dw`` and a new rule state; the caller adds
``dw`` to its weights, so rules compose with masks and clipping.
"""

from spikejax.plasticity.base import PlasticityRule
from spikejax.plasticity.hebbian import RewardHebbianParams
from spikejax.plasticity.hebbian import RewardHebbianState
from spikejax.plasticity.hebbian import reward_modulated_hebbian
from spikejax.plasticity.hebbian import row_increment
from spikejax.plasticity.supervised import StochasticSupervisedParams
from spikejax.plasticity.supervised import stochastic_supervised

__all__ = [
    "PlasticityRule",
    "RewardHebbianParams",
    "RewardHebbianState",
    "reward_modulated_hebbian",
    "row_increment",
    "StochasticSupervisedParams",
    "stochastic_supervised",
]
