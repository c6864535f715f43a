"""Alg. 1 written as plain NumPy loops, one trial at a time: the test oracle and the benchmark's peer.

This is how the hexapod SCPG paper's algorithm reads (and how a researcher
would run it without spikejax): loops over epochs, gaits, time steps and
neurons. It uses the same initial weights and the same rule noise as
`robots.hexapod.training.train`, so the two must agree to rounding.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from robots.hexapod import gaits
from robots.hexapod.training import TrainParams, _epoch_noise
from spikejax.random import hash_seed


def reference_train(p: TrainParams, key: jax.Array, train_cycles: int = 2, max_epochs: int = 200):
    """Interleaved training of Alg. 1 in plain loops; returns ``(w_in, w_cpg, epochs)``."""
    alpha, v_th, lr, n_gaits = float(p.alpha), float(p.v_th), float(p.lr), int(p.n_gaits)
    key_init, key_train = jax.random.split(key)
    key_in, key_cpg = jax.random.split(key_init)
    w_in = np.array(jax.random.uniform(key_in, (3, 6), minval=p.w_low, maxval=p.w_high), np.float64)
    w_cpg = np.array(jax.random.uniform(key_cpg, (6, 6), minval=p.w_low, maxval=p.w_high), np.float64)
    w_cpg *= 1 - np.eye(6)
    seed = hash_seed(key=key_train)
    n_steps = train_cycles * gaits.PERIOD
    for epoch in range(max_epochs):
        noise = np.asarray(_epoch_noise(seed, jnp.int32(epoch), (3, n_steps, 2, 6)))
        errors = 0
        for g in range(n_gaits):
            v, s = np.zeros(6), np.zeros(6)
            for t in range(n_steps):
                s_prev, s = s, np.zeros(6)
                for j in range(6):
                    v[j] = v[j] / alpha + w_in[g, j] + s_prev @ w_cpg[:, j]
                    if v[j] > v_th:
                        s[j], v[j] = 1.0, 0.0
                    err = s[j] - gaits.PATTERNS[g][t % gaits.PERIOD][j]
                    errors += abs(err)
                    w_in[g, j] -= lr * err * noise[g, t, 0, j]
                    for i in range(6):
                        if i != j:
                            w_cpg[i, j] -= lr * err * s_prev[i] * noise[g, t, 1, j]
        if errors == 0:
            return w_in, w_cpg, epoch + 1
    return w_in, w_cpg, max_epochs


def reference_gait_correct(p: TrainParams, w_in: np.ndarray, w_cpg: np.ndarray, eval_cycles: int = 10) -> np.ndarray:
    """Whether each gait, switched on from rest, reproduces its pattern; shape (3,)."""
    alpha, v_th = float(p.alpha), float(p.v_th)
    n_steps = eval_cycles * gaits.PERIOD
    ok = np.ones(3, bool)
    for g in range(3):
        v, s = np.zeros(6), np.zeros(6)
        for t in range(n_steps):
            v = v / alpha + w_in[g] + s @ w_cpg
            s = (v > v_th).astype(np.float64)
            v[s > 0] = 0.0
            ok[g] &= np.array_equal(s, gaits.PATTERNS[g][t % gaits.PERIOD])
    return ok
