"""The gait-convergence trial sweep files name: train one SCPG (hexapod SCPG paper, Alg. 1), report if it converged."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from robots.hexapod.gaits import N_GAITS
from robots.hexapod.training import TrainParams, gait_correct, train
from spikejax.ranges import NON_NEGATIVE, POSITIVE, Range, ranged
from spikejax.sweep import nonfinite


@ranged(
    n_gaits=Range(1, N_GAITS, integer=True),
    alpha=POSITIVE,
    v_th=POSITIVE,
    w_low=Range(),
    w_high=Range(),
    lr=NON_NEGATIVE,
)
class GaitTrialParams(NamedTuple):
    """Traced parameters of a gait-convergence trial (see `TrainParams`).

    Valid ranges (checked by the sweep engine before anything compiles):
    ``n_gaits`` a whole number in [1, 3] (the gaits the robot has), the decay
    factor ``alpha`` > 0 (Eq. (1)), the threshold ``v_th`` > 0 (Eq. (2)), the
    update scale ``lr`` >= 0; all finite.
    """

    n_gaits: int = 3
    alpha: float = 2.0
    v_th: float = 1.0
    w_low: float = 0.0
    w_high: float = 1.0
    lr: float = 1.0


class GaitTrialResult(NamedTuple):
    """One row of the convergence table.

    Attributes:
        converged: every trained gait reproduces its pattern from rest.
        g1_ok, g2_ok, g3_ok: each gait on its own (untrained gaits are usually wrong).
        epochs: training epochs run.
        nonfinite: the trained weights, the training errors, the parameters or
            the potentials' per-step factor ``1 / alpha`` are NaN or infinite
            (`spikejax.sweep.nonfinite`; e.g. ``lr = 3e38``, ``alpha = 0``).
    """

    converged: jax.Array
    g1_ok: jax.Array
    g2_ok: jax.Array
    g3_ok: jax.Array
    epochs: jax.Array
    nonfinite: jax.Array


@ranged(
    train_cycles=Range(1, integer=True),
    max_epochs=Range(1, integer=True),
    eval_cycles=Range(1, integer=True),
)
def convergence_trial(
    params: GaitTrialParams,
    key: jax.Array,
    *,
    train_cycles: int = 2,
    max_epochs: int = 200,
    eval_cycles: int = 10,
    schedule: str = "interleaved",
) -> GaitTrialResult:
    """Train an SCPG on G1..G(n_gaits) and check each trained gait from rest for ``eval_cycles`` cycles."""
    p = TrainParams(*(jnp.asarray(v, jnp.float32) for v in params))
    result = train(p, train_cycles=train_cycles, max_epochs=max_epochs, schedule=schedule, key=key)
    ok = gait_correct(p, result.weights, eval_cycles)
    trained = jnp.arange(N_GAITS) < p.n_gaits
    return GaitTrialResult(
        converged=jnp.all(ok | ~trained),
        g1_ok=ok[0],
        g2_ok=ok[1],
        g3_ok=ok[2],
        epochs=result.epochs,
        # The potentials are divided by alpha every step (Eq. (1)): 1 / alpha stands for them.
        nonfinite=nonfinite((result, p, 1.0 / p.alpha)),
    )


def replay_trial(
    params: GaitTrialParams,
    seed: int,
    *,
    base_seed: int = 0,
    train_cycles: int = 2,
    max_epochs: int = 200,
    eval_cycles: int = 10,
    schedule: str = "interleaved",
):
    """Re-run the trial of ``seed`` from a sweep table and return what it learned.

    The key is the sweep engine's (`spikejax.sweep.trial_key`), so the
    replay is the very trial of the table's row with this seed and these params.

    Returns:
        ``(train_result, rasters)``: the `TrainResult` and the CPG raster
        of each gait switched on from rest, shape (3, eval_cycles * PERIOD, 6).
    """
    from robots.hexapod.cpg import run_gait
    from robots.hexapod.gaits import PERIOD
    from spikejax import DiscreteLIFParams
    from spikejax.sweep import trial_key

    p = TrainParams(*(jnp.asarray(v, jnp.float32) for v in params))
    result = train(
        p, train_cycles=train_cycles, max_epochs=max_epochs, schedule=schedule, key=trial_key(base_seed, seed)
    )
    neuron = DiscreteLIFParams(alpha=p.alpha, v_th=p.v_th)
    rasters = jnp.stack([run_gait(neuron, result.weights, g, eval_cycles * PERIOD) for g in range(N_GAITS)])
    return result, rasters
