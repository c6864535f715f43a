"""Programming gaits into the SCPG with the stochastic supervised rule (Alg. 1 of the hexapod SCPG paper).

How gaits are trained (the order and interleaving of Alg. 1, made precise):

1. All weights are drawn from ``U(w_low, w_high)`` (Alg. 1, line 1).
2. One *epoch* presents every trained gait once, in order G1, G2, G3 (the
   "for gait = 1 to 3" loop of Alg. 1), interleaved: G1, G2, G3, G1, G2, ...
3. A *presentation* starts the SCPG from rest (potentials 0, no spikes; Alg. 1,
   lines 2 and 5), switches the gait's selection neuron on and runs
   ``train_cycles * PERIOD`` steps. After every step each CPG neuron's spike is
   compared with the gait's required pattern and the rule of
   `spikejax.plasticity.stochastic_supervised` changes the weights onto
   every neuron that erred, online (Alg. 1, lines 13-15).
4. Training stops after the first epoch in which no presentation made a single
   error, or after ``max_epochs``. Nothing changes after such an epoch (a
   network without errors gets no updates), so stopping early never changes a
   result.

What "converged" means: after training, every trained gait, switched on from
rest, reproduces its required pattern exactly, spike for spike, for
``eval_cycles`` cycles (``eval_cycles * PERIOD`` steps), and the gaits not
trained are not checked.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from robots.hexapod.cpg import RECURRENT_MASK, CPGWeights, cpg_init, cpg_step, cpg_weights_init, run_gait
from robots.hexapod.gaits import N_GAITS, N_LEGS, PATTERNS, PERIOD
from spikejax import DiscreteLIFParams
from spikejax.errors import UserError
from spikejax.plasticity import StochasticSupervisedParams, stochastic_supervised
from spikejax.random import hash_seed, hash_uniform

_RULE = stochastic_supervised()


class TrainParams(NamedTuple):
    """Traced parameters of one training run (a sweep may vmap over any of them).

    Attributes:
        n_gaits: gaits to program, 1..3: G1, G1+G2 or G1+G2+G3.
        alpha: decay factor of Eq. (1).
        v_th: threshold of Eq. (2).
        w_low, w_high: range of the uniform initial weights.
        lr: update scale of the rule.
    """

    n_gaits: jax.Array
    alpha: jax.Array
    v_th: jax.Array
    w_low: jax.Array
    w_high: jax.Array
    lr: jax.Array


class TrainResult(NamedTuple):
    """The trained weights and what training took.

    Attributes:
        weights: final SCPG weights.
        epochs: epochs run (the last one error-free if training succeeded).
        errors: per-epoch error count (wrong spikes summed over presentations),
            shape (max_epochs,); zero after the epoch that stopped training.
    """

    weights: CPGWeights
    epochs: jax.Array
    errors: jax.Array


def _presentation(
    params: TrainParams, weights: CPGWeights, gait: int, learn: jax.Array, noise: jax.Array
) -> tuple[CPGWeights, jax.Array]:
    """One presentation of ``gait`` from rest with online updates (step 3 above).

    ``noise`` holds the rule's ``U(0, 1)`` draws, shape (n_steps, 2, 6): per step,
    one per CPG neuron for its input synapses and one for its recurrent ones.
    """
    neuron = DiscreteLIFParams(alpha=params.alpha, v_th=params.v_th)
    rule = StochasticSupervisedParams(lr=params.lr * learn)
    n_steps = noise.shape[0]
    targets = jnp.asarray(PATTERNS[gait][np.arange(n_steps) % PERIOD])
    gait_spikes = jax.nn.one_hot(gait, N_GAITS, dtype=jnp.float32)  # G(gait) alone spikes, every step

    def step(carry, inputs):
        weights, state, rule_in, rule_cpg = carry
        target, u = inputs
        new_state, spikes = cpg_step(neuron, weights, state, gait_spikes)
        dw_in, rule_in = _RULE.update(rule, rule_in, weights.w_in, gait_spikes, spikes, target, u[0])
        dw_cpg, rule_cpg = _RULE.update(rule, rule_cpg, weights.w_cpg, state.spikes, spikes, target, u[1])
        weights = CPGWeights(weights.w_in + dw_in, weights.w_cpg + dw_cpg * RECURRENT_MASK)
        return (weights, new_state, rule_in, rule_cpg), jnp.sum(jnp.abs(spikes - target))

    carry = (weights, cpg_init(), _RULE.init(weights.w_in), _RULE.init(weights.w_cpg))
    (weights, _, _, _), errors = jax.lax.scan(step, carry, (targets, noise))
    return weights, jnp.sum(errors) * learn


def _epoch_noise(seed: jax.Array, block: jax.Array, shape: tuple[int, ...]) -> jax.Array:
    """The rule's U(0, 1) draws for one block of presentations, from a counter-based hash."""
    size = int(np.prod(shape))
    counter = block.astype(jnp.uint32) * jnp.uint32(size) + jnp.arange(size, dtype=jnp.uint32)
    return hash_uniform(seed, counter).reshape(shape)


def train(
    params: TrainParams,
    *,
    train_cycles: int = 2,
    max_epochs: int = 200,
    schedule: str = "interleaved",
    key: jax.Array,
) -> TrainResult:
    """Program gaits G1..G(n_gaits) into a fresh SCPG (the schedule in the module docstring).

    Args:
        params: traced training parameters.
        train_cycles: gait cycles per presentation (static).
        max_epochs: most epochs to run (static); with ``schedule="blocked"``, the
            most presentations of each gait.
        schedule: ``"interleaved"`` (G1, G2, G3, G1, ... until an epoch is
            error-free) or ``"blocked"`` (G1 until error-free, then G2, then G3,
            each once through, as Alg. 1's loops are written).
        key: PRNG key of this run.

    Returns:
        The trained weights, the epochs run and the per-epoch error counts.
    """
    if schedule not in ("interleaved", "blocked"):
        raise UserError(f"schedule must be 'interleaved' or 'blocked', got {schedule!r}")
    key_init, key_train = jax.random.split(key)
    weights = cpg_weights_init(params.w_low, params.w_high, key=key_init)
    seed = hash_seed(key=key_train)
    n_steps = train_cycles * PERIOD
    errors = jnp.zeros((max_epochs,), jnp.float32)

    def not_done(carry):
        _, e, clean, _ = carry
        return (e < max_epochs) & ~clean

    if schedule == "interleaved":

        def epoch(carry):
            weights, e, _, errors = carry
            noise = _epoch_noise(seed, e, (N_GAITS, n_steps, 2, N_LEGS))
            total = jnp.zeros((), jnp.float32)
            for g in range(N_GAITS):
                learn = (g < params.n_gaits).astype(jnp.float32)
                weights, err = _presentation(params, weights, g, learn, noise[g])
                total = total + err
            return weights, e + 1, total == 0, errors.at[e].set(total)

        weights, epochs, _, errors = jax.lax.while_loop(
            not_done, epoch, (weights, jnp.int32(0), jnp.bool_(False), errors)
        )
        return TrainResult(weights=weights, epochs=epochs, errors=errors)

    epochs = jnp.int32(0)
    for g in range(N_GAITS):
        learn = (g < params.n_gaits).astype(jnp.float32)

        def presentation(carry, g=g, learn=learn):
            weights, e, _, errors = carry
            noise = _epoch_noise(seed, e * N_GAITS + g, (n_steps, 2, N_LEGS))
            weights, err = _presentation(params, weights, g, learn, noise)
            return weights, e + 1, err == 0, errors.at[e].add(err)

        weights, e, _, errors = jax.lax.while_loop(
            not_done, presentation, (weights, jnp.int32(0), jnp.bool_(False), errors)
        )
        epochs = epochs + e * learn.astype(jnp.int32)
    return TrainResult(weights=weights, epochs=epochs, errors=errors)


def gait_correct(params: TrainParams, weights: CPGWeights, eval_cycles: int) -> jax.Array:
    """Whether each gait, switched on from rest, reproduces its pattern exactly; shape (3,)."""
    neuron = DiscreteLIFParams(alpha=params.alpha, v_th=params.v_th)
    n_steps = eval_cycles * PERIOD
    required = jnp.asarray(PATTERNS)[:, jnp.arange(n_steps) % PERIOD]
    obtained = jax.vmap(lambda g: run_gait(neuron, weights, g, n_steps))(jnp.arange(N_GAITS))
    return jnp.all(obtained == required, axis=(1, 2))
