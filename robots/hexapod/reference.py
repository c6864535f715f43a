"""Alg. 1 and the visual SNN written as plain NumPy loops, one trial at a time: the test oracles and the benchmarks' peers.

This is how the hexapod SCPG paper's algorithms read (and how a researcher
would run them without spikejax): loops over epochs, gaits, time steps and
neurons. `reference_train` uses the same initial weights and the same rule
noise as `robots.hexapod.training.train`, so the two must agree to rounding;
`reference_vision` is Sec. IV's network event by event, as
`spikejax.vision.edges.async_step` runs it.
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


def reference_vision(config, params, xs, ys, ts) -> dict:
    """Sec. IV's visual SNN, one event at a time in Python loops (float64); the spikes of every layer counted.

    Each event adds the filter kernel to the (up to) nine neurons around its
    pixel; a filter neuron above threshold fires, resets, and adds ``column`` to
    its window's vertical neuron of its pixel column and horizontal neuron of its
    pixel row; those add ``window`` to their window's branch neuron, which adds
    its readout weights to the readout neurons. Every neuron decays by
    ``exp(-(t - t_last) / tau)`` when touched (Eq. (1)-(2), leak by event times).

    Args:
        config: a `spikejax.vision.edges.EdgeConfig`.
        params: its `spikejax.vision.edges.EdgeParams`.
        xs, ys, ts: the events' columns, rows and times (polarity is not used).

    Returns:
        ``{"filter", "layer2": int, "windows": (n_rows, n_cols, 2), "out": (n_out,) int arrays}``.
    """
    f = lambda a: np.asarray(a, np.float64)
    kernel = {(dy, dx): float(params.centre) if dy == dx == 0 else float(params.edge) if dy == 0 or dx == 0 else float(params.corner)
              for dy in (-1, 0, 1) for dx in (-1, 0, 1)}  # fmt: skip
    th = float(params.v_th)
    taus = [float(params.tau_filter), float(params.tau_column), float(params.tau_window), float(params.tau_out)]
    readout = f(params.readout)
    win, rows, cols = config.window, *config.used
    layers = [
        {"v": np.zeros(shape), "t": np.zeros(shape)}
        for shape in (
            (config.height, config.width),
            (config.n_rows, cols),
            (rows, config.n_cols),
            (config.n_rows, config.n_cols, 2),
            (config.n_out,),
        )
    ]
    counts = {"filter": 0, "layer2": 0, "windows": np.zeros((config.n_rows, config.n_cols, 2), int)}
    counts["out"] = np.zeros(config.n_out, int)

    def touch(layer, tau, index, drive, t):
        v = layer["v"][index] * np.exp(-(t - layer["t"][index]) / tau) + drive
        layer["t"][index] = t
        fired = v > th
        layer["v"][index] = 0.0 if fired else v
        return fired

    for x, y, t in zip(np.asarray(xs), np.asarray(ys), f(ts)):
        fired_filter = []
        for (dy, dx), k in kernel.items():
            yy, xx = y + dy, x + dx
            if 0 <= yy < config.height and 0 <= xx < config.width and touch(layers[0], taus[0], (yy, xx), k, t):
                fired_filter.append((yy, xx))
        counts["filter"] += len(fired_filter)
        # Layer 2: each neuron once, with all its inputs of this event.
        inputs = {}
        for yy, xx in fired_filter:
            if yy < rows and xx < cols:
                for key in ((1, yy // win, xx), (2, yy, xx // win)):
                    inputs[key] = inputs.get(key, 0) + 1
        window_inputs = {}
        for (layer, i, j), n in inputs.items():
            if touch(layers[layer], taus[1], (i, j), n * float(params.column), t):
                counts["layer2"] += 1
                cell = (i, j // win, 0) if layer == 1 else (i // win, j, 1)
                window_inputs[cell] = window_inputs.get(cell, 0) + 1
        fired_windows = np.zeros((config.n_rows, config.n_cols, 2), bool)
        for cell, n in window_inputs.items():
            fired_windows[cell] = touch(layers[3], taus[2], cell, n * float(params.window), t)
        counts["windows"] += fired_windows
        if fired_windows.any():
            drive = np.einsum("oijb,ijb->o", readout, fired_windows)
            for o in range(config.n_out):
                counts["out"][o] += touch(layers[4], taus[3], o, drive[o], t)
    return counts
