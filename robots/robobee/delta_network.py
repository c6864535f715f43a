"""A delta-synapse variant of the RoboBee network, for comparing simulators: not the controller's network.

The network is the feed-forward LIF network of Sec. III of the RoboBee paper,
without the robot: four input groups of 50 neurons (one per lateral state
variable), a hidden layer of 100 and an output layer of 50 neurons, 30 % random
connectivity input -> hidden and hidden -> output, weights ``U(0, 1)`` times a
scale, thresholds ``U(0.7, 1.7)`` (Sec. V), ``tau_input < tau_hidden <
tau_output`` (Sec. III) and a refractory period. Each input group is driven by a
constant current (the shifted and scaled state ``q_hat`` of Sec. III, held
constant as over the paper's first 500 ms).

How it differs from the closed loop's network (`robots.robobee.controller`,
`controller_step`): it has no plasticity, decoder or robot; its time constants
are `TAUS` (5, 10, 20 ms; the controller's are `controller_params`'s); and its
synapses are delta synapses with a one-step delay (a spike adds ``w`` to the
postsynaptic potential in the next step), the convention that NEST
(``iaf_psc_delta``) and Brian2 share, where the controller injects a current
in the same step. It exists so that spikejax, a NumPy loop
(`robots.robobee.reference.run_numpy`), Brian2 and NEST
(`robots.robobee.peers`) simulate exactly the same network, spike for spike;
``spikejax bench robobee-network`` times them (`robots.robobee.bench_network`).

Every implementation simulates the same network, built on the host from a
NumPy seed (`make_network`, `input_currents`), for the same duration at
``dt = 0.1 ms``; `delta_network_step` is the spikejax step, `simulate` its
``lax.scan``.

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

    Formulations of the spikejax step (`delta_network_params`'s ``synapses``
    and ``weight_dtype``, `simulate`'s ``step`` and ``unroll``): the dense
    masked matrix product in bfloat16 with float32 accumulation and one
    `spikejax.lif_step` per layer are the defaults because they were the
    fastest on a CPU; the measured ratios are in ``docs/BENCHMARKS.md``.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from spikejax.errors import UserError
from spikejax.neurons import LIFParams, LIFState, lif_init, lif_params, lif_step

__all__ = [
    "DT",
    "LAYERS",
    "LAYER_SLICES",
    "N_NEURONS",
    "ROW_FIELDS",
    "DeltaNetworkParams",
    "DeltaNetworkState",
    "NetworkSpec",
    "delta_network_init",
    "delta_network_params",
    "delta_network_step",
    "delta_network_step_fused",
    "input_currents",
    "make_network",
    "n_steps_of",
    "rates_hz",
    "result_row",
    "simulate",
]

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

# The fields of a result row (`result_row`), the same for every implementation.
ROW_FIELDS = (
    "impl",
    "batch",
    "neurons",
    "steps",
    "build_or_compile_s",
    "run_s",
    "neuron_updates_per_s",
    "spikes_input",
    "spikes_hidden",
    "spikes_output",
)


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


def result_row(impl: str, batch: int, steps: int, build_s: float, run_s: float, counts, **extra) -> dict:
    """A result of any implementation: its times, neuron updates per second and spikes per layer (`ROW_FIELDS`).

    ``counts`` (spikes per neuron, ``(..., 350)``) is kept in the row; ``extra`` fields are added.
    """
    counts = np.asarray(counts)
    row = dict(
        impl=impl,
        batch=batch,
        neurons=N_NEURONS,
        steps=steps,
        build_or_compile_s=build_s,
        run_s=run_s,
        neuron_updates_per_s=N_NEURONS * steps * batch / run_s,
    )
    row.update({f"spikes_{name}": int(counts[..., sl].sum()) for name, sl in zip(LAYERS, LAYER_SLICES)})
    row.update(counts=counts, **extra)
    return row


def rates_hz(row: dict) -> dict:
    """Mean firing rate of each layer, Hz, from a result row."""
    duration = row["steps"] * DT
    sizes = dict(input=N_INPUT, hidden=N_HIDDEN, output=N_OUTPUT)
    return {name: row[f"spikes_{name}"] / (sizes[name] * row["batch"] * duration) for name in LAYERS}


class DeltaNetworkParams(NamedTuple):
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


class DeltaNetworkState(NamedTuple):
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


def delta_network_params(spec: NetworkSpec, synapses: str = "dense", weight_dtype=jnp.bfloat16) -> DeltaNetworkParams:
    """JAX parameters of ``spec``: neurons in float32, weights in ``weight_dtype``.

    Args:
        spec: the network.
        synapses: ``"dense"`` (the masked weight matrices, a matrix product of
            the spike vector) or ``"fanin"`` (per postsynaptic neuron, a gather
            of its presynaptic spikes).
        weight_dtype: dtype of the weights, ``bfloat16`` (exact: `make_network`
            rounds them so) or ``float32``; the jumps are summed in float32 either way.
    """
    layers = tuple(lif_params(tau=tau, v_th=spec.v_th[sl], t_ref=T_REF, dt=DT) for tau, sl in zip(TAUS, LAYER_SLICES))
    if synapses == "dense":
        w_ih, w_ho = spec.w_ih, spec.w_ho
        idx_ih = idx_ho = np.zeros((0,), np.int32)
    elif synapses == "fanin":
        (idx_ih, w_ih), (idx_ho, w_ho) = _fanin(spec.conn_ih, spec.w_ih), _fanin(spec.conn_ho, spec.w_ho)
    else:
        raise UserError(f"synapses must be 'dense' or 'fanin', not {synapses!r}")
    return DeltaNetworkParams(
        layers,
        jnp.asarray(w_ih, weight_dtype),
        jnp.asarray(w_ho, weight_dtype),
        jnp.asarray(idx_ih, jnp.int32),
        jnp.asarray(idx_ho, jnp.int32),
    )


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


def delta_network_init(params: DeltaNetworkParams) -> DeltaNetworkState:
    """All neurons at rest, none refractory, no spike in flight."""
    layers = tuple(lif_init(n, p) for n, p in zip((N_INPUT, N_HIDDEN, N_OUTPUT), params.layers))
    counts = tuple(jnp.zeros((n,), jnp.int32) for n in (N_INPUT, N_HIDDEN, N_OUTPUT))
    return DeltaNetworkState(layers, jnp.zeros((N_INPUT,), jnp.float32), jnp.zeros((N_HIDDEN,), jnp.float32), counts)


def _jumps(params: DeltaNetworkParams, state: DeltaNetworkState) -> tuple[jax.Array, jax.Array]:
    """Voltage jumps of the hidden and output neurons from last step's spikes."""
    if params.idx_ih.ndim == 2:  # fan-in gather
        return (
            (state.spikes_in[params.idx_ih] * params.w_ih).sum(-1),
            (state.spikes_hid[params.idx_ho] * params.w_ho).sum(-1),
        )
    f32 = jnp.float32
    return (
        jnp.matmul(state.spikes_in.astype(params.w_ih.dtype), params.w_ih, preferred_element_type=f32),
        jnp.matmul(state.spikes_hid.astype(params.w_ho.dtype), params.w_ho, preferred_element_type=f32),
    )


def _next_state(state: DeltaNetworkState, layers, fired) -> DeltaNetworkState:
    counts = tuple(c + f.astype(jnp.int32) for c, f in zip(state.counts, fired))
    return DeltaNetworkState(tuple(layers), fired[0].astype(jnp.float32), fired[1].astype(jnp.float32), counts)


def delta_network_step(
    params: DeltaNetworkParams, state: DeltaNetworkState, current: jax.Array
) -> tuple[DeltaNetworkState, tuple[jax.Array, ...]]:
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


def delta_network_step_fused(
    params: DeltaNetworkParams, state: DeltaNetworkState, current: jax.Array
) -> tuple[DeltaNetworkState, tuple[jax.Array, ...]]:
    """The same step as `delta_network_step`, as one exact LIF update of all 350 neurons.

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


STEPS = {"layers": delta_network_step, "fused": delta_network_step_fused}


def simulate(params: DeltaNetworkParams, current: jax.Array, n_steps: int, step: str = "layers", unroll: int = 1):
    """Spike counts per neuron of one network after ``n_steps`` (``n_steps``, ``step``, ``unroll`` static).

    Args:
        params: the network.
        current: input currents ``R I``, ``(200,)``; ``jax.vmap`` over it for a batch.
        n_steps: number of steps of ``dt``.
        step: ``"layers"`` (`delta_network_step`) or ``"fused"`` (`delta_network_step_fused`).
        unroll: ``jax.lax.scan``'s unroll.

    Returns:
        Spikes per neuron, int32 ``(350,)``.
    """
    step_fn = STEPS[step]

    def body(state, _):
        return step_fn(params, state, current)[0], None

    state, _ = jax.lax.scan(body, delta_network_init(params), None, length=n_steps, unroll=unroll)
    return jnp.concatenate(state.counts)
