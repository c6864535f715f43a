"""Switching gaits while walking: does a trained SCPG reach the new gait's pattern within one cycle?

The hexapod SCPG paper calls its gait transitions seamless and never measures
them: its CPG is trained and checked only with each gait switched on from rest
(Alg. 1, Fig. 4). In the closed loop (Sec. IV-C, V) the visual SNN changes the
gait-selection input while the CPG is running, so the neurons' potentials and
last spikes carry the old gait into the new one.

`switch_raster` runs gait ``a`` for a while and then gait ``b``, either
carrying the CPG's state over (what the paper's robot does) or resetting it to
rest at the switch (a policy of ours); `transient` is the number of steps
after the switch before the raster is ``b``'s pattern (Fig. 2, in either
phase) for good. `switching_trial` trains one three-gait network (the trial of
``spikejax reproduce gaits``) and measures every ordered pair of gaits
switched at both phases of the cycle, under both policies:
``spikejax reproduce gait-switching`` sweeps it over seeds.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from robots.hexapod.cpg import CPGWeights, cpg_init, cpg_step
from robots.hexapod.gaits import N_GAITS, PATTERNS, PERIOD
from robots.hexapod.training import TrainParams, gait_correct, train
from robots.hexapod.trial import GaitTrialParams
from spikejax.neurons import DiscreteLIFParams
from spikejax.ranges import Range, ranged
from spikejax.sweep import nonfinite

__all__ = ["PAIRS", "switch_raster", "transient", "SwitchTrialResult", "switching_trial", "field"]

# The six ordered pairs of distinct gaits (0-based: G1 forward, G2 left, G3 right).
PAIRS = tuple((a, b) for a in range(N_GAITS) for b in range(N_GAITS) if a != b)


def switch_raster(
    neuron: DiscreteLIFParams,
    weights: CPGWeights,
    before: jax.Array,
    after: jax.Array,
    n_before: int,
    n_after: int,
    reset: jax.Array,
) -> jax.Array:
    """The CPG raster of the ``n_after`` steps after gait ``before`` ran ``n_before`` steps from rest and ``after`` took over.

    Args:
        neuron: the CPG neurons' Eq. (1)-(2) constants.
        weights: the SCPG's synapses.
        before, after: the gaits, 0-based (traced).
        n_before, n_after: steps of each (static); ``n_before % PERIOD`` is the phase of the switch.
        reset: if true, the CPG's potentials and last spikes go to rest at the switch.

    Returns:
        The spikes, shape ``(n_after, 6)``; row 0 is the first step driven by ``after``.
    """
    one_hot = lambda g: jax.nn.one_hot(g, N_GAITS, dtype=jnp.float32)

    def run(state, gait, n):
        return jax.lax.scan(lambda s, _: cpg_step(neuron, weights, s, one_hot(gait)), state, None, length=n)

    state, _ = run(cpg_init(), before, n_before)
    state = jax.tree.map(lambda rest, s: jnp.where(reset, rest, s), cpg_init(), state)
    return run(state, after, n_after)[1]


def transient(raster: jax.Array, gait: jax.Array, min_cycles: int = 2) -> jax.Array:
    """Steps before ``raster`` is ``gait``'s pattern (in either phase) to its end; ``len(raster)`` if never.

    A match must last at least ``min_cycles`` cycles, so the raster's last
    steps alone do not count as having settled.
    """
    n = raster.shape[0]
    j = jnp.arange(n)
    patterns = jnp.asarray(PATTERNS)[gait]
    good = jnp.stack([jnp.all(raster == patterns[(j + s) % PERIOD], axis=1) for s in range(PERIOD)])
    # holds[s, j]: from step j to the end every step matches phase s.
    holds = jnp.flip(jnp.cumprod(jnp.flip(good, axis=1), axis=1), axis=1).astype(bool)
    first = jnp.where(jnp.any(holds, axis=0), j, n).min()
    return jnp.where(first <= n - min_cycles * PERIOD, first, n).astype(jnp.int32)


def field(before: int, after: int, phase: int, reset: bool = False) -> str:
    """The result field of a switch, e.g. ``carry_G1_G2_phase0``."""
    return f"{'reset' if reset else 'carry'}_G{before + 1}_G{after + 1}_phase{phase}"


SwitchTrialResult = NamedTuple(
    "SwitchTrialResult",
    [("converged", jax.Array), ("epochs", jax.Array)]
    + [(field(a, b, ph, r), jax.Array) for r in (False, True) for a, b in PAIRS for ph in range(PERIOD)]
    + [("nonfinite", jax.Array)],
)
SwitchTrialResult.__doc__ = """One row of the switching table.

Attributes:
    converged: the trained network reproduces all three gaits from rest
        (only such networks are switched in the summary).
    epochs: training epochs run.
    carry_Ga_Gb_phaseP: steps after switching from gait a to gait b at phase P
        with the CPG's state carried over, before b's pattern holds
        (`transient`; ``settle_cycles * PERIOD`` if it never does).
    reset_Ga_Gb_phaseP: the same with the state reset to rest at the switch.
    nonfinite: a NaN or infinity in the trained weights or parameters.
"""


@ranged(
    train_cycles=Range(1, integer=True),
    max_epochs=Range(1, integer=True),
    eval_cycles=Range(1, integer=True),
    lead_cycles=Range(1, integer=True),
    settle_cycles=Range(3, integer=True),
)
def switching_trial(
    params: GaitTrialParams,
    key: jax.Array,
    *,
    train_cycles: int = 2,
    max_epochs: int = 200,
    eval_cycles: int = 10,
    lead_cycles: int = 5,
    settle_cycles: int = 10,
) -> SwitchTrialResult:
    """Train an SCPG (as `robots.hexapod.trial.convergence_trial` does) and switch between every pair of gaits.

    With ``params.n_gaits`` below 3 the pairs with an untrained gait are
    measured too, and mean little.

    Each switch runs the first gait ``lead_cycles`` cycles (plus the phase) from
    rest, then the second for ``settle_cycles`` cycles.
    """
    p = TrainParams(*(jnp.asarray(v, jnp.float32) for v in params))
    result = train(p, train_cycles=train_cycles, max_epochs=max_epochs, key=key)
    neuron = DiscreteLIFParams(alpha=p.alpha, v_th=p.v_th)
    n_after = settle_cycles * PERIOD
    fields = {}
    for reset in (False, True):
        for a, b in PAIRS:
            for phase in range(PERIOD):
                raster = switch_raster(
                    neuron, result.weights, a, b, lead_cycles * PERIOD + phase, n_after, jnp.bool_(reset)
                )
                fields[field(a, b, phase, reset)] = transient(raster, b)
    return SwitchTrialResult(
        converged=jnp.all(gait_correct(p, result.weights, eval_cycles) | (jnp.arange(N_GAITS) >= p.n_gaits)),
        epochs=result.epochs,
        nonfinite=nonfinite((result, p, 1.0 / p.alpha)),
        **fields,
    )
