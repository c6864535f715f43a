"""``spikejax bench robobee``, the network alone: the RoboBee SNN against Brian2 and NEST.

The network is the feed-forward LIF network of Sec. III of the RoboBee paper,
without the robot: four input groups of 50 neurons (one per lateral state
variable), a hidden layer of 100 and an output layer of 50 neurons, 30 % random
connectivity input -> hidden and hidden -> output, weights ``U(0, 1)`` times a
scale, thresholds ``U(0.7, 1.7)`` (Sec. V), ``tau_input < tau_hidden <
tau_output`` (Sec. III) and a refractory period. Each input group is driven by a
constant current (the shifted and scaled state ``q_hat`` of Sec. III, held
constant as over the paper's first 500 ms).

Every implementation simulates the same network, built on the host from a
NumPy seed (`make_network`, `input_currents`), for the same duration at
``dt = 0.1 ms``:

- `run_spikejax`: one pure JAX step for the whole network, ``jax.lax.scan`` over
  steps, ``jax.vmap`` over networks that share the connectivity and differ in
  their input currents;
- `run_numpy`: the same step as a plain NumPy loop, the reference of the tests;
- `run_brian2_runtime`: Brian2's runtime mode (Cython, or NumPy);
- `run_brian2_standalone`: Brian2's C++ standalone mode, built in a temporary
  directory;
- `run_nest`: NEST's ``iaf_psc_delta`` with ``static_synapse`` connections.

Each returns a dict with the fields of `ROW_FIELDS`: compile or build time apart
from run time, neuron updates per second (neurons x steps x networks / run
seconds) and the spike count of every layer (of the first network for the peers,
of all networks for spikejax).

Notes:
    Conventions, the same in every implementation (the tests check them):

    - Potentials are dimensionless (``R = 1``, ``v_rest = v_reset = 0``, the
      thresholds ``U(0.7, 1.7)``). An input neuron of group ``g`` relaxes to
      ``v_inf = c_g``; hidden and output neurons to 0. In NEST the same numbers
      are millivolts, ``C_m = tau_m`` (pF and ms) so that ``R = 1 GOhm`` and the
      current ``I_e = c_g`` pA gives ``v_inf = c_g`` mV.
    - The leak is integrated exactly over each step (``method='exact'`` in
      Brian2, NEST's exact propagator, `spikejax.lif_step`); a neuron spikes
      when ``v >= v_th`` and is reset to 0.
    - Delta synapses with a one-step delay, NEST's minimum delay: a spike
      emitted in step ``k`` adds ``w`` to the postsynaptic potential in step
      ``k + 1``, after the leak integration and before the threshold test
      (NEST: ``delay = dt``; Brian2: ``delay = 0`` with the synapses scheduled
      between the state update and the threshold test, so a spike is
      propagated in the step after the one that emitted it).
    - Refractory period ``t_ref = 2 ms`` (20 steps): a neuron that spikes in
      step ``j`` is held at reset in steps ``j + 1 .. j + 19``, ignores its
      synaptic input then, and integrates again in step ``j + 20``, so two of
      its spikes are at least ``t_ref`` apart. Brian2: ``refractory=t_ref``,
      ``on_pre='v_post += w*int(not_refractory_post)'``. NEST stamps a spike at
      the end of its step and holds the neuron for ``t_ref`` after that stamp,
      so it gets ``t_ref - dt``; its default ``refractory_input=False`` drops
      the input of refractory neurons.
    - Numbers every implementation reads alike: the weights are rounded to
      bfloat16 (8 significant bits), the thresholds and input currents to
      float32, so spikejax's float32 simulation, with its weight matrix in
      bfloat16, reads exactly the numbers the float64 peers read.

    With these conventions NumPy (float64), Brian2 and NEST give the same spike
    count for every neuron, and spikejax (float32) too, except where the
    float64 run comes within float32 rounding of a threshold tie (the float32
    and float64 potentials drift apart by up to about ``6e-6``, mostly from
    the rounding of ``exp(-dt / tau)``); the tests check all of this.

    Formulation of the spikejax step, measured on a 2-core CPU (see
    `main_network`; the machine was shared, so ratios rather than figures):
    the synaptic input is a matrix product of the spike vector with the dense,
    masked weight matrices; it takes about 3/4 of a float32 step at 1,024
    networks. A gather of each neuron's presynaptic spikes (``synapses="fanin"``,
    7 to 45 times slower) or of the rows of the spiking neurons (top-k or
    ``nonzero`` with a fixed capacity, 2 to 3 times slower) loses on XLA's CPU
    backend. Weights in bfloat16 with float32 accumulation make the whole step
    1.4 to 1.8 times faster at 1,024 networks (no change at 16). The neurons
    are one `spikejax.lif_step` per layer (`net_step`): XLA fuses each layer's
    update into its own loops, and one hand-fused update of all 350 neurons
    (`net_step_fused`) is 1.3 to 2 times slower, by the concatenations it
    needs. A ``lax.scan`` unroll of 4 is within noise at 1,024 networks and 2
    to 3 times slower at 16, so none is used.
"""

from __future__ import annotations

import argparse
import csv
import functools
import math
import os
import platform
import tempfile
import time
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from robots.common import run_isolated
from spikejax.neurons import LIFParams
from spikejax.neurons import LIFState
from spikejax.neurons import lif_init
from spikejax.neurons import lif_params
from spikejax.neurons import lif_step

DT = 1e-4  # s
N_GROUPS, GROUP_SIZE = 4, 50
N_INPUT, N_HIDDEN, N_OUTPUT = N_GROUPS * GROUP_SIZE, 100, 50
N_NEURONS = N_INPUT + N_HIDDEN + N_OUTPUT
LAYERS = ("input", "hidden", "output")
LAYER_SLICES = (slice(0, N_INPUT), slice(N_INPUT, N_INPUT + N_HIDDEN), slice(N_INPUT + N_HIDDEN, N_NEURONS))
P_CONNECT = 0.3
TAUS = (5e-3, 10e-3, 20e-3)  # s, input < hidden < output (Sec. III)
T_REF = 2e-3  # s
V_TH_RANGE = (0.7, 1.7)  # Sec. V
# Voltage jump of a weight-1 synapse, per projection: with U(0, 1) weights the
# hidden and output layers fire at about 15-80 Hz on average.
W_SCALES = (0.04, 0.10)
# Input currents R I of the four groups, U(lo, hi) per group and network: an
# input neuron fires at up to about 250 Hz, or not at all if its threshold is
# above its group's current (the input layer's mean is about 100-150 Hz).
INPUT_RANGE = (1.5, 2.0)

ROW_FIELDS = ("impl", "batch", "neurons", "steps", "build_or_compile_s", "run_s", "neuron_updates_per_s",
              "spikes_input", "spikes_hidden", "spikes_output")


class NetworkSpec(NamedTuple):
    """One RoboBee network on the host, float64 NumPy arrays.

    Attributes:
        w_ih: input -> hidden weights as voltage jumps, ``(200, 100)``, 0 where
            not connected (bfloat16 numbers).
        w_ho: hidden -> output weights, ``(100, 50)``, 0 where not connected.
        conn_ih: input -> hidden connectivity, bool ``(200, 100)``.
        conn_ho: hidden -> output connectivity, bool ``(100, 50)``.
        v_th: thresholds of all neurons, input then hidden then output, ``(350,)``
            (float32 numbers).
        tau: membrane time constants, s, ``(350,)``.
    """

    w_ih: np.ndarray
    w_ho: np.ndarray
    conn_ih: np.ndarray
    conn_ho: np.ndarray
    v_th: np.ndarray
    tau: np.ndarray


def make_network(seed: int, w_scales: tuple[float, float] = W_SCALES) -> NetworkSpec:
    """The connectivity, weights and thresholds drawn from ``seed``.

    Args:
        seed: NumPy seed.
        w_scales: voltage jump of a weight-1 synapse, input -> hidden and hidden -> output.

    Returns:
        The network; the same seed gives the same network in every implementation.
    """
    rng = np.random.default_rng(seed)
    conn_ih = rng.random((N_INPUT, N_HIDDEN)) < P_CONNECT
    conn_ho = rng.random((N_HIDDEN, N_OUTPUT)) < P_CONNECT
    w_ih = _bfloat16_exact(np.where(conn_ih, rng.random((N_INPUT, N_HIDDEN)), 0.0) * w_scales[0])
    w_ho = _bfloat16_exact(np.where(conn_ho, rng.random((N_HIDDEN, N_OUTPUT)), 0.0) * w_scales[1])
    v_th = rng.uniform(*V_TH_RANGE, size=N_NEURONS).astype(np.float32).astype(np.float64)
    tau = np.concatenate([np.full(n, t) for n, t in zip((N_INPUT, N_HIDDEN, N_OUTPUT), TAUS)])
    return NetworkSpec(w_ih, w_ho, conn_ih, conn_ho, v_th, tau)


def _bfloat16_exact(w: np.ndarray) -> np.ndarray:
    """``w`` rounded to the nearest bfloat16 (8 significant bits), as float64."""
    return w.astype(jnp.bfloat16).astype(np.float64)


def input_currents(seed: int, n_networks: int) -> np.ndarray:
    """Input currents ``R I`` of the input neurons of ``n_networks`` networks, ``(n_networks, 200)``.

    Network ``b`` draws its four group currents from the seed ``(seed, b)``, so a
    network's input does not depend on how many are simulated beside it. The
    currents are float32 numbers (as float64).
    """
    out = np.empty((n_networks, N_INPUT))
    for b in range(n_networks):
        groups = np.random.default_rng((seed, b)).uniform(*INPUT_RANGE, size=N_GROUPS)
        out[b] = np.repeat(groups, GROUP_SIZE)
    return out.astype(np.float32).astype(np.float64)


def n_steps_of(duration: float) -> int:
    """Whole steps of ``DT`` in ``duration`` seconds."""
    return round(duration / DT)


def _row(impl, batch, steps, build_s, run_s, counts, **extra) -> dict:
    counts = np.asarray(counts)
    row = dict(impl=impl, batch=batch, neurons=N_NEURONS, steps=steps, build_or_compile_s=build_s, run_s=run_s,
               neuron_updates_per_s=N_NEURONS * steps * batch / run_s)
    row.update({f"spikes_{name}": int(counts[..., sl].sum()) for name, sl in zip(LAYERS, LAYER_SLICES)})
    row.update(counts=counts, **extra)
    return row


def rates_hz(row: dict) -> dict:
    """Mean firing rate of each layer, Hz, from a result row."""
    duration = row["steps"] * DT
    sizes = dict(input=N_INPUT, hidden=N_HIDDEN, output=N_OUTPUT)
    return {name: row[f"spikes_{name}"] / (sizes[name] * row["batch"] * duration) for name in LAYERS}


# ----------------------------------------------------------------- spikejax


class NetParams(NamedTuple):
    """Traced parameters of one network; the networks of a batch share them.

    Attributes:
        layers: `spikejax.LIFParams` of the input, hidden and output layers,
            thresholds of shape ``(n,)``, the other fields scalars.
        w_ih: input -> hidden jumps, ``(200, 100)``; with ``synapses="fanin"``
            each hidden neuron's presynaptic weights instead, ``(100, k_ih)``.
        w_ho: hidden -> output jumps, ``(100, 50)``; or fan-in weights ``(50, k_ho)``.
        idx_ih: fan-in presynaptic indices ``(100, k_ih)`` (``"fanin"``), else ``(0,)``.
        idx_ho: fan-in presynaptic indices ``(50, k_ho)`` (``"fanin"``), else ``(0,)``.
    """

    layers: tuple[LIFParams, LIFParams, LIFParams]
    w_ih: jax.Array
    w_ho: jax.Array
    idx_ih: jax.Array
    idx_ho: jax.Array


class NetState(NamedTuple):
    """State of one network: its layers, last step's spikes in flight and the spike counts so far.

    Attributes:
        layers: `spikejax.LIFState` of the input, hidden and output layers.
        spikes_in: the input layer's spikes of the last step, 0/1 floats ``(200,)``.
        spikes_hid: the hidden layer's spikes of the last step, ``(100,)``.
        counts: spikes per neuron so far, one int32 array per layer.
    """

    layers: tuple[LIFState, LIFState, LIFState]
    spikes_in: jax.Array
    spikes_hid: jax.Array
    counts: tuple[jax.Array, jax.Array, jax.Array]


def net_params(spec: NetworkSpec, synapses: str = "dense", weight_dtype=jnp.bfloat16) -> NetParams:
    """JAX parameters of ``spec``: neurons in float32, weights in ``weight_dtype``.

    Args:
        spec: the network.
        synapses: ``"dense"`` (the masked weight matrices, a matrix product of
            the spike vector) or ``"fanin"`` (per postsynaptic neuron, a gather
            of its presynaptic spikes).
        weight_dtype: dtype of the weights, ``bfloat16`` (exact: `make_network`
            rounds them so) or ``float32``; the jumps are summed in float32 either way.
    """
    layers = tuple(
        lif_params(tau=tau, v_th=spec.v_th[sl], t_ref=T_REF, dt=DT) for tau, sl in zip(TAUS, LAYER_SLICES)
    )
    if synapses == "dense":
        w_ih, w_ho = spec.w_ih, spec.w_ho
        idx_ih = idx_ho = np.zeros((0,), np.int32)
    elif synapses == "fanin":
        (idx_ih, w_ih), (idx_ho, w_ho) = _fanin(spec.conn_ih, spec.w_ih), _fanin(spec.conn_ho, spec.w_ho)
    else:
        raise ValueError(f"synapses must be 'dense' or 'fanin', not {synapses!r}")
    return NetParams(layers, jnp.asarray(w_ih, weight_dtype), jnp.asarray(w_ho, weight_dtype),
                     jnp.asarray(idx_ih, jnp.int32), jnp.asarray(idx_ho, jnp.int32))


def _fanin(conn: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per postsynaptic neuron, its presynaptic indices and weights, padded with weight 0."""
    k = int(conn.sum(0).max())
    idx = np.zeros((conn.shape[1], k), np.int32)
    weights = np.zeros((conn.shape[1], k))
    for j in range(conn.shape[1]):
        pre = np.flatnonzero(conn[:, j])
        idx[j, : len(pre)] = pre
        weights[j, : len(pre)] = w[pre, j]
    return idx, weights


def net_init(params: NetParams) -> NetState:
    """All neurons at rest, none refractory, no spike in flight."""
    layers = tuple(lif_init(n, p) for n, p in zip((N_INPUT, N_HIDDEN, N_OUTPUT), params.layers))
    counts = tuple(jnp.zeros((n,), jnp.int32) for n in (N_INPUT, N_HIDDEN, N_OUTPUT))
    return NetState(layers, jnp.zeros((N_INPUT,), jnp.float32), jnp.zeros((N_HIDDEN,), jnp.float32), counts)


def _jumps(params: NetParams, state: NetState) -> tuple[jax.Array, jax.Array]:
    """Voltage jumps of the hidden and output neurons from last step's spikes."""
    if params.idx_ih.ndim == 2:  # fan-in gather
        return ((state.spikes_in[params.idx_ih] * params.w_ih).sum(-1),
                (state.spikes_hid[params.idx_ho] * params.w_ho).sum(-1))
    f32 = jnp.float32
    return (jnp.matmul(state.spikes_in.astype(params.w_ih.dtype), params.w_ih, preferred_element_type=f32),
            jnp.matmul(state.spikes_hid.astype(params.w_ho.dtype), params.w_ho, preferred_element_type=f32))


def _next_state(state: NetState, layers, fired) -> NetState:
    counts = tuple(c + f.astype(jnp.int32) for c, f in zip(state.counts, fired))
    return NetState(tuple(layers), fired[0].astype(jnp.float32), fired[1].astype(jnp.float32), counts)


def net_step(params: NetParams, state: NetState, current: jax.Array) -> tuple[NetState, tuple[jax.Array, ...]]:
    """One step of the network: `spikejax.lif_step` for each layer, Eq. (6)-(7) of the RoboBee paper.

    The input layer integrates its currents; the hidden and output layers
    integrate no current and receive the jumps of the spikes their presynaptic
    layers emitted in the last step, added after the leak and before the
    threshold test (the module's notes). ``lif_step`` integrates ``v`` from the
    start of the step, so a jump ``w`` added after the leak is a jump
    ``w / exp(-dt / tau)`` added before it; a refractory neuron ignores it, as
    ``lif_step`` holds it at reset.

    Args:
        params: the network (shared by a batch).
        state: the network's state at step ``k``.
        current: input currents ``R I`` of the input neurons, held over the step, ``(200,)``.

    Returns:
        The state at step ``k + 1`` and this step's spikes of each layer (bool).
    """
    j_hid, j_out = _jumps(params, state)
    layers, fired = [], []
    for p, s, i_in, jump in zip(params.layers, state.layers, (current, None, None), (None, j_hid, j_out)):
        if jump is not None:
            s = s._replace(v=s.v + jump / jnp.exp(-p.dt / p.tau))
            i_in = jnp.zeros_like(s.v)
        s, f = lif_step(p, s, i_in)
        layers.append(s)
        fired.append(f)
    return _next_state(state, layers, fired), tuple(fired)


def net_step_fused(params: NetParams, state: NetState, current: jax.Array) -> tuple[NetState, tuple[jax.Array, ...]]:
    """The same step as `net_step`, as one exact LIF update of all 350 neurons.

    ``v <- v_inf + (v - v_inf) exp(-dt / tau) + jump`` with per-neuron ``tau``,
    ``v_th`` and ``v_inf`` (the currents, then zeros), then the threshold,
    reset and refractory rules of `spikejax.lif_step` (``v_reset``, ``t_ref``
    and ``dt`` are the input layer's, the same in every layer).
    """
    j_hid, j_out = _jumps(params, state)
    sizes = (N_INPUT, N_HIDDEN, N_OUTPUT)

    def per_neuron(field: str) -> jax.Array:
        return jnp.concatenate([jnp.broadcast_to(getattr(p, field), (n,)) for p, n in zip(params.layers, sizes)])

    tau, v_th = per_neuron("tau"), per_neuron("v_th")
    p0 = params.layers[0]
    v = jnp.concatenate([s.v for s in state.layers])
    refractory = jnp.concatenate([s.refractory for s in state.layers])
    v_inf = jnp.concatenate([current, jnp.zeros((N_HIDDEN + N_OUTPUT,), current.dtype)])
    jumps = jnp.concatenate([jnp.zeros((N_INPUT,), current.dtype), j_hid, j_out])
    v_free = v_inf + (v - v_inf) * jnp.exp(-p0.dt / tau) + jumps
    held = refractory > 0
    fired = ~held & (v_free >= v_th)
    v = jnp.where(held | fired, p0.v_reset, v_free)
    n_ref = jnp.round(p0.t_ref / p0.dt)
    refractory = jnp.where(fired, jnp.maximum(n_ref - 1.0, 0.0), jnp.maximum(refractory - 1.0, 0.0))
    bounds = np.cumsum(sizes)[:-1]
    layers = [LIFState(a, b) for a, b in zip(jnp.split(v, bounds), jnp.split(refractory, bounds))]
    fired = tuple(jnp.split(fired, bounds))
    return _next_state(state, layers, fired), fired


STEPS = {"layers": net_step, "fused": net_step_fused}


def simulate(params: NetParams, current: jax.Array, n_steps: int, step: str = "layers", unroll: int = 1):
    """Spike counts per neuron of one network after ``n_steps`` (``n_steps``, ``step``, ``unroll`` static).

    Args:
        params: the network.
        current: input currents ``R I``, ``(200,)``; ``jax.vmap`` over it for a batch.
        n_steps: number of steps of ``dt``.
        step: ``"layers"`` (`net_step`) or ``"fused"`` (`net_step_fused`).
        unroll: ``jax.lax.scan``'s unroll.

    Returns:
        Spikes per neuron, int32 ``(350,)``.
    """
    step_fn = STEPS[step]

    def body(state, _):
        return step_fn(params, state, current)[0], None

    state, _ = jax.lax.scan(body, net_init(params), None, length=n_steps, unroll=unroll)
    return jnp.concatenate(state.counts)


def run_spikejax(n_networks: int, duration: float, seed: int, *, step: str = "layers", synapses: str = "dense",
                 weight_dtype=jnp.bfloat16, unroll: int = 1, repeats: int = 1) -> dict:
    """``n_networks`` networks (same connectivity, own input currents) as one ``jit(vmap(scan))``.

    The program is compiled ahead (``lower(...).compile()``, ``build_or_compile_s``)
    and then run to completion (``block_until_ready``) ``repeats`` times; the
    fastest run is ``run_s``.

    Args:
        n_networks: batch size.
        duration: simulated time, s.
        seed: seed of `make_network` and `input_currents`.
        step: ``"layers"`` or ``"fused"`` (see `simulate`).
        synapses: ``"dense"`` or ``"fanin"`` (see `net_params`).
        weight_dtype: ``bfloat16`` or ``float32`` (see `net_params`).
        unroll: ``jax.lax.scan``'s unroll.
        repeats: timed runs.

    Returns:
        A result row (`ROW_FIELDS`); ``counts`` holds the spikes per network and neuron.
    """
    n_steps = n_steps_of(duration)
    params = net_params(make_network(seed), synapses, weight_dtype)
    currents = jnp.asarray(input_currents(seed, n_networks), jnp.float32)
    fn = jax.jit(jax.vmap(functools.partial(simulate, n_steps=n_steps, step=step, unroll=unroll), in_axes=(None, 0)))
    t0 = time.perf_counter()
    compiled = fn.lower(params, currents).compile()
    compile_s = time.perf_counter() - t0
    run_s = math.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        counts = compiled(params, currents).block_until_ready()
        run_s = min(run_s, time.perf_counter() - t0)
    impl = f"spikejax {step} {synapses} {jnp.dtype(weight_dtype).name}" + (f" unroll {unroll}" if unroll != 1 else "")
    return _row(impl, n_networks, n_steps, compile_s, run_s, np.asarray(counts))


# ----------------------------------------------------------------- NumPy reference


def run_numpy(duration: float, seed: int, network: int = 0, dtype=np.float64) -> dict:
    """The same network and step convention as plain NumPy loops over steps: the tests' reference.

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
        jumps = np.concatenate([np.zeros(N_INPUT, dtype), spikes[:N_INPUT] @ w_ih,
                                spikes[N_INPUT:N_INPUT + N_HIDDEN] @ w_ho])
        v_free = v_inf + (v - v_inf) * decay + jumps
        held = refractory > 0
        margin = min(margin, float(np.abs(v_free[~held] - v_th[~held]).min(initial=np.inf)))
        fired = ~held & (v_free >= v_th)
        v = np.where(held | fired, 0.0, v_free).astype(dtype)
        refractory = np.where(fired, n_hold, np.maximum(refractory - 1, 0))
        spikes = fired.astype(dtype)
        counts += fired
    run_s = time.perf_counter() - t0
    return _row(f"NumPy loop ({np.dtype(dtype).name})", 1, n_steps, 0.0, run_s, counts, margin=margin)


# ----------------------------------------------------------------- Brian2


def _brian2_network(spec: NetworkSpec, current: np.ndarray):
    """The network as Brian2 objects in a `brian2.Network` (the active device decides how it runs)."""
    import brian2 as b2

    eqs = """dv/dt = (i_ext - v) / tau : 1 (unless refractory)
    i_ext : 1 (constant)
    v_th : 1 (constant)
    tau : second (constant)"""
    groups = []
    for sl, n in zip(LAYER_SLICES, (N_INPUT, N_HIDDEN, N_OUTPUT)):
        g = b2.NeuronGroup(n, eqs, threshold="v >= v_th", reset="v = 0", refractory=T_REF * b2.second,
                           method="exact")
        g.v_th = spec.v_th[sl]
        g.tau = spec.tau[sl] * b2.second
        groups.append(g)
    groups[0].i_ext = current
    synapses = []
    for pre, post, conn, w in ((groups[0], groups[1], spec.conn_ih, spec.w_ih),
                               (groups[1], groups[2], spec.conn_ho, spec.w_ho)):
        syn = b2.Synapses(pre, post, "w : 1 (constant)", on_pre="v_post += w * int(not_refractory_post)")
        i, j = np.nonzero(conn)
        syn.connect(i=i, j=j)
        syn.w = w[i, j]
        synapses.append(syn)
    monitors = [b2.SpikeMonitor(g, record=False) for g in groups]
    net = b2.Network(*groups, *synapses, *monitors)
    # Synapses between the state update and the threshold test: a spike is
    # propagated in the step after the one that emitted it (NEST's delay of dt).
    net.schedule = ["start", "groups", "synapses", "thresholds", "resets", "end"]
    return net, monitors


def _brian2_counts(monitors) -> np.ndarray:
    return np.concatenate([np.asarray(m.count[:]) for m in monitors])


def run_brian2_runtime(duration: float, seed: int, target: str = "cython", repeats: int = 1) -> dict:
    """Brian2's runtime mode (``target`` ``"cython"`` or ``"numpy"``), one network.

    The first ``run`` generates (and for Cython compiles, or loads from
    Cython's cache) the code. The network is stored before it and restored
    after, so each of ``repeats`` further ``run`` calls repeats the same
    simulation: the fastest is ``run_s``, and ``build_or_compile_s`` is the
    first run's excess over it. If Cython cannot compile, NumPy runs instead and
    the row's ``impl`` says so.
    """
    import brian2 as b2

    spec = make_network(seed)
    current = input_currents(seed, 1)[0]
    n_steps = n_steps_of(duration)
    impl = f"Brian2 runtime ({target})"
    old_target = b2.prefs.codegen.target
    try:
        b2.prefs.codegen.target = target
        b2.defaultclock.dt = DT * b2.second
        net, monitors = _brian2_network(spec, current)
        net.store("start")
        t0 = time.perf_counter()
        try:
            net.run(duration * b2.second)
        except Exception as err:  # noqa: BLE001 - whatever broke the compiler: fall back, and say so
            if target == "numpy":
                raise
            b2.prefs.codegen.target = "numpy"
            impl = f"Brian2 runtime (numpy; {target} failed: {type(err).__name__})"
            net, monitors = _brian2_network(spec, current)
            net.store("start")
            t0 = time.perf_counter()
            net.run(duration * b2.second)
        first_s = time.perf_counter() - t0
        counts = _brian2_counts(monitors)
        run_s, repeat_equal = math.inf, True
        for _ in range(repeats):
            net.restore("start")
            t0 = time.perf_counter()
            net.run(duration * b2.second)
            run_s = min(run_s, time.perf_counter() - t0)
            repeat_equal &= bool(np.array_equal(_brian2_counts(monitors), counts))
    finally:
        b2.prefs.codegen.target = old_target
    return _row(impl, 1, n_steps, max(first_s - run_s, 0.0), run_s, counts, first_run_s=first_s,
                repeat_equal=repeat_equal)


def run_brian2_standalone(duration: float, seed: int, threads: int = 0, repeats: int = 1) -> dict:
    """Brian2's C++ standalone mode, one network, built in a temporary directory.

    The project is generated and compiled (``device.build(run=False)``: code
    generation and the C++ build, ``build_or_compile_s``), then run
    ``repeats`` times (``device.run``); ``run_s`` is the fastest simulation loop
    as the binary times it (``device._last_run_time``), ``run_wall_s`` the
    fastest whole ``run`` (process start and result files included). The
    device is reset to runtime afterwards, so that other runs in the same
    process still work.

    Args:
        duration: simulated time, s.
        seed: seed of `make_network` and `input_currents`.
        threads: OpenMP threads (0: none, Brian2's default).
        repeats: timed runs of the binary.
    """
    import brian2 as b2
    from brian2.devices.device import reset_device

    spec = make_network(seed)
    current = input_currents(seed, 1)[0]
    n_steps = n_steps_of(duration)
    with tempfile.TemporaryDirectory(prefix="brian2_standalone_") as tmp:
        b2.set_device("cpp_standalone", directory=tmp, build_on_run=False)
        try:
            b2.prefs.devices.cpp_standalone.openmp_threads = threads
            b2.defaultclock.dt = DT * b2.second
            net, monitors = _brian2_network(spec, current)
            net.run(duration * b2.second)
            t0 = time.perf_counter()
            b2.device.build(directory=tmp, compile=True, run=False, with_output=False)
            build_s = time.perf_counter() - t0
            run_s = run_wall_s = math.inf
            for _ in range(repeats):
                t0 = time.perf_counter()
                b2.device.run(directory=tmp, with_output=False)
                run_wall_s = min(run_wall_s, time.perf_counter() - t0)
                run_s = min(run_s, float(b2.device._last_run_time))
            counts = _brian2_counts(monitors)
        finally:
            b2.device.reinit()
            b2.prefs.devices.cpp_standalone.openmp_threads = 0
            reset_device("runtime")
    impl = "Brian2 C++ standalone" + (f" ({threads} OpenMP threads)" if threads else "")
    return _row(impl, 1, n_steps, build_s, run_s, counts, run_wall_s=run_wall_s)


# ----------------------------------------------------------------- NEST


def run_nest(duration: float, seed: int, threads: int = 1, repeats: int = 1) -> dict:
    """NEST's ``iaf_psc_delta`` network, one network, ``threads`` local threads.

    ``build_or_compile_s`` is ``Create`` + ``Connect`` + ``Prepare``, ``run_s``
    the ``Run`` of ``duration``, the fastest of ``repeats`` builds and runs.
    Units: ms, mV, pA, pF with ``C_m = tau_m`` (see the module's notes).
    """
    nest = _import_nest()
    spec = make_network(seed)
    current = input_currents(seed, 1)[0]
    n_steps = n_steps_of(duration)
    build_s = run_s = math.inf
    for _ in range(repeats):
        nest.ResetKernel()
        nest.verbosity = nest.VerbosityLevel.ERROR
        nest.SetKernelStatus({"resolution": DT * 1e3, "local_num_threads": threads, "print_time": False})
        t0 = time.perf_counter()
        layers = []
        for sl, n, tau_s in zip(LAYER_SLICES, (N_INPUT, N_HIDDEN, N_OUTPUT), TAUS):
            tau_ms = tau_s * 1e3
            layers.append(nest.Create("iaf_psc_delta", n, params={
                "tau_m": tau_ms, "C_m": tau_ms, "E_L": 0.0, "V_reset": 0.0, "V_m": 0.0,
                "t_ref": (T_REF - DT) * 1e3, "I_e": 0.0, "V_th": list(spec.v_th[sl])}))
        layers[0].I_e = list(current)
        for pre, post, conn, w in ((layers[0], layers[1], spec.conn_ih, spec.w_ih),
                                   (layers[1], layers[2], spec.conn_ho, spec.w_ho)):
            i, j = np.nonzero(conn)
            nest.Connect(np.asarray(pre.tolist())[i], np.asarray(post.tolist())[j], "one_to_one",
                         {"synapse_model": "static_synapse", "weight": w[i, j], "delay": np.full(len(i), DT * 1e3)})
        recorder = nest.Create("spike_recorder")
        nest.Connect(layers[0] + layers[1] + layers[2], recorder)
        nest.Prepare()
        build_s = min(build_s, time.perf_counter() - t0)
        t0 = time.perf_counter()
        nest.Run(duration * 1e3)
        run_s = min(run_s, time.perf_counter() - t0)
        nest.Cleanup()
    senders = np.asarray(recorder.get("events")["senders"], np.int64)
    counts = np.bincount(senders - layers[0].tolist()[0], minlength=N_NEURONS)
    return _row(f"NEST iaf_psc_delta ({threads} thread{'s' if threads > 1 else ''})", 1, n_steps, build_s,
                run_s, counts)


def _import_nest():
    """``nest``, imported without its banner (it prints one unless ``PYNEST_QUIET`` is set)."""
    os.environ.setdefault("PYNEST_QUIET", "1")
    import nest

    return nest


# ----------------------------------------------------------------- CLI

BATCHES = (1, 16, 256, 1024)


def _runs(duration: float, seed: int, batches: tuple[int, ...], repeats: int) -> list:
    """The table's rows to measure, in order, as thunks."""
    big = max(batches)
    kw = dict(repeats=repeats)
    runs = [
        lambda: run_isolated(run_numpy, duration, seed),
        lambda: run_isolated(run_brian2_runtime, duration, seed, **kw),
        lambda: run_isolated(run_brian2_standalone, duration, seed, **kw),
        lambda: run_isolated(run_nest, duration, seed, threads=1, **kw),
        lambda: run_isolated(run_nest, duration, seed, threads=2, **kw),
    ]
    runs += [lambda b=b: run_spikejax(b, duration, seed, **kw) for b in batches]
    # The formulations that lost, at the largest batch (the gather at 16: it is slow).
    runs += [
        lambda: run_spikejax(big, duration, seed, weight_dtype=jnp.float32, **kw),
        lambda: run_spikejax(big, duration, seed, step="fused", **kw),
        lambda: run_spikejax(big, duration, seed, unroll=4, **kw),
        lambda: run_spikejax(min(big, 16), duration, seed, synapses="fanin", weight_dtype=jnp.float32, **kw),
    ]
    return runs


def main_network(args: argparse.Namespace) -> int:
    """The network-alone table of ``spikejax bench robobee``.

    Reads from ``args`` (each optional): ``duration`` (simulated seconds,
    default 1), ``seed`` (default 0), ``batches`` (spikejax batch sizes, default
    `BATCHES`), ``repeats`` (timed runs per row, the fastest kept; default 3)
    and ``out`` (a directory for ``bench_robobee_network.csv``). Each peer runs
    in a fresh process of its own; one that is not installed is skipped with a
    note.
    """
    duration = float(getattr(args, "duration", None) or 1.0)
    seed = int(getattr(args, "seed", None) or 0)
    batches = tuple(getattr(args, "batches", None) or BATCHES)
    repeats = int(getattr(args, "repeats", None) or 3)
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, "
          f"{jax.device_count()} x {jax.devices()[0].platform}, jax {jax.__version__}")
    print(f"RoboBee network alone: {N_INPUT}-{N_HIDDEN}-{N_OUTPUT} LIF, {P_CONNECT:.0%} connectivity, "
          f"dt = {DT * 1e3:g} ms, {duration:g} s = {n_steps_of(duration)} steps, seed {seed}")
    rows = []
    for run in _runs(duration, seed, batches, repeats):
        try:
            row = run()
        except ImportError as err:
            print(f"  skipped: {err}")
            continue
        rows.append(row)
        rates = ", ".join(f"{k} {v:.1f}" for k, v in rates_hz(row).items())
        print(f"  {row['impl']}, batch {row['batch']}: {row['neuron_updates_per_s'] / 1e6:,.1f} M neuron updates/s;"
              f" rates (Hz): {rates}", flush=True)
    peers = {name: max((r["neuron_updates_per_s"] for r in rows if r["impl"].startswith(name)), default=math.nan)
             for name in ("NEST", "Brian2 C++ standalone")}
    print()
    print("| implementation | batch | compile/build (s) | run (s) | neuron updates/s | x NEST | x Brian2 standalone |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        ups = r["neuron_updates_per_s"]
        r["x_nest"] = ups / peers["NEST"]
        r["x_brian2_standalone"] = ups / peers["Brian2 C++ standalone"]
        print(f"| {r['impl']} | {r['batch']} | {r['build_or_compile_s']:.2f} | {r['run_s']:.3f} | "
              f"{ups / 1e6:,.1f} M | {r['x_nest']:.2f} | {r['x_brian2_standalone']:.2f} |")
    print(f"(run: the fastest of {repeats}; x NEST, x Brian2 standalone: against the fastest row of each; "
          "Brian2 standalone's run is the simulation loop as the binary times it)")
    if getattr(args, "out", None):
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        with open(out / "bench_robobee_network.csv", "w", newline="") as file:
            writer = csv.DictWriter(file, fieldnames=[*ROW_FIELDS, "x_nest", "x_brian2_standalone"],
                                    extrasaction="ignore")
            writer.writeheader()
            writer.writerows(rows)
    return 0
