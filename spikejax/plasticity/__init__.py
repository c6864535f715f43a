"""Plasticity rules as ``(init, update)`` pairs of pure functions (as optax's transforms).

``update`` returns a weight change ``dw`` and a new rule state; the caller adds
``dw`` to its weights, so rules compose with masks and clipping.
"""

from spikejax.plasticity.base import PlasticityRule
from spikejax.plasticity.hebbian import RewardHebbianParams, RewardHebbianState, reward_modulated_hebbian, row_increment
from spikejax.plasticity.rstdp import RSTDPNestState, RSTDPParams, RSTDPState, replay, rstdp, rstdp_params, set_dopamine
from spikejax.plasticity.supervised import StochasticSupervisedParams, stochastic_supervised

__all__ = [
    "PlasticityRule",
    "RewardHebbianParams",
    "RewardHebbianState",
    "reward_modulated_hebbian",
    "row_increment",
    "RSTDPParams",
    "RSTDPState",
    "RSTDPNestState",
    "rstdp",
    "rstdp_params",
    "set_dopamine",
    "replay",
    "StochasticSupervisedParams",
    "stochastic_supervised",
]
