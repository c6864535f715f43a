"""Oracles in plain NumPy for the RoboBee's models: what the tests and the benchmarks check spikejax against.

- `run_numpy`: the delta-synapse network of `robots.robobee.delta_network`
  (not the controller's network) as a loop over steps, float64 by default.
"""

from __future__ import annotations

import time

import numpy as np

from robots.robobee.delta_network import (
    DT,
    N_HIDDEN,
    N_INPUT,
    N_NEURONS,
    N_OUTPUT,
    T_REF,
    input_currents,
    make_network,
    n_steps_of,
    result_row,
)

__all__ = ["NumpyNetworkRun", "run_numpy"]


def run_numpy(duration: float, seed: int, network: int = 0, dtype=np.float64) -> dict:
    """`robots.robobee.delta_network` as a plain NumPy loop over steps: the oracle of the tests and the benchmark.

    Args:
        duration: simulated time, s.
        seed: seed of `make_network` and `input_currents`.
        network: which network of `input_currents` to simulate.
        dtype: floating dtype of the arithmetic.

    Returns:
        A result row; ``counts`` holds the spikes per neuron and ``margin`` the
        smallest ``|v - v_th|`` met at a threshold test (how far the run is from
        a tie that rounding could break; its bookkeeping is in ``run_s``).
    """
    spec = make_network(seed)
    n_steps = n_steps_of(duration)
    current = input_currents(seed, network + 1)[network].astype(dtype)
    w_ih, w_ho, v_th = spec.w_ih.astype(dtype), spec.w_ho.astype(dtype), spec.v_th.astype(dtype)
    decay = np.exp(-dtype(DT) / spec.tau.astype(dtype))
    v_inf = np.concatenate([current, np.zeros(N_HIDDEN + N_OUTPUT, dtype)])
    n_hold = round(T_REF / DT) - 1
    v = np.zeros(N_NEURONS, dtype)
    refractory = np.zeros(N_NEURONS, np.int64)
    spikes = np.zeros(N_NEURONS, dtype)
    counts = np.zeros(N_NEURONS, np.int64)
    margin = np.inf
    t0 = time.perf_counter()
    for _ in range(n_steps):
        jumps = np.concatenate(
            [np.zeros(N_INPUT, dtype), spikes[:N_INPUT] @ w_ih, spikes[N_INPUT : N_INPUT + N_HIDDEN] @ w_ho]
        )
        v_free = v_inf + (v - v_inf) * decay + jumps
        held = refractory > 0
        margin = min(margin, float(np.abs(v_free[~held] - v_th[~held]).min(initial=np.inf)))
        fired = ~held & (v_free >= v_th)
        v = np.where(held | fired, 0.0, v_free).astype(dtype)
        refractory = np.where(fired, n_hold, np.maximum(refractory - 1, 0))
        spikes = fired.astype(dtype)
        counts += fired
    run_s = time.perf_counter() - t0
    return result_row(f"NumPy loop ({np.dtype(dtype).name})", 1, n_steps, 0.0, run_s, counts, margin=margin)


class NumpyNetworkRun:
    """`run_numpy` as a benchmark timer: each call simulates the network once and returns its seconds.

    Attributes:
        info: the first call's result row (`run_numpy`).
    """

    def __init__(self, duration: float, seed: int):
        self.duration, self.seed = duration, seed
        self.info = None

    def __call__(self) -> float:
        row = run_numpy(self.duration, self.seed)
        if self.info is None:
            self.info = row
        return row["run_s"]
