"""The shape every plasticity rule shares."""

from __future__ import annotations

from typing import Any, Callable, NamedTuple

__all__ = ["PlasticityRule"]


class PlasticityRule(NamedTuple):
    """A pair of pure functions implementing a plasticity rule.

    Attributes:
        init: ``init(weights) -> state``: the rule's own state (traces, keys), if any.
        update: ``update(params, state, weights, ...signals) -> (dw, state)``: the
            weight change for this step and the new rule state. The signals a rule
            needs (presynaptic spikes, postsynaptic spikes, a target, a reward, a
            PRNG key) are explicit arguments, never globals.
    """

    init: Callable[..., Any]
    update: Callable[..., Any]
