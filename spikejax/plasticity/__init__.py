"""Plasticity rules as ``(init, update)`` pairs of pure functions (as optax's transforms).

``update`` returns a weight change ``dw`` and a new rule state; the caller adds
``dw`` to its weights, so rules compose with masks and clipping.

``spikejax.plasticity.rstdp`` is the module (``rstdp.rstdp`` the rule,
``rstdp.replay`` one synapse through any protocol, as NEST would run it);
``spikejax.plasticity.reward`` assigns rewards to output and hidden neurons.
"""

from spikejax.plasticity import reward, rstdp
from spikejax.plasticity.base import PlasticityRule
from spikejax.plasticity.hebbian import RewardHebbianParams, RewardHebbianState, reward_modulated_hebbian, row_increment
from spikejax.plasticity.reward import backprop_rewards, pair_rewards, separated_rewards, unified_rewards
from spikejax.plasticity.rstdp import RSTDPNestState, RSTDPParams, RSTDPState, replay, rstdp_params, set_dopamine
from spikejax.plasticity.supervised import StochasticSupervisedParams, stochastic_supervised

__all__ = [
    "PlasticityRule",
    "RewardHebbianParams",
    "RewardHebbianState",
    "reward_modulated_hebbian",
    "row_increment",
    "reward",
    "pair_rewards",
    "backprop_rewards",
    "unified_rewards",
    "separated_rewards",
    "rstdp",
    "RSTDPParams",
    "RSTDPState",
    "RSTDPNestState",
    "rstdp_params",
    "set_dopamine",
    "replay",
    "StochasticSupervisedParams",
    "stochastic_supervised",
]
