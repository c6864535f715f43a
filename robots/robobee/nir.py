"""The RoboBee's 200-100-50 controller (Section III of the RoboBee paper) in and out of NIR, with its learned weights.

A trained controller (`robots.robobee.controller`) is saved with
`save_controller` (one file, every seed of a batch) and exported with
`controller_graph` or `export` (``spikejax export nir --weights FILE``). The
graph, per seed::

    q (4) -> encoder (Affine) -> input (LIF, 200) -> input_hidden (Linear) -> hidden (LIF, 100)
          -> hidden_output (Linear) -> output (LIF, 50) -> spikes (Output)

* the encoder is Section III's ``q_hat = a (q + b)`` with the antagonist halves
  of `spikejax.coding.antagonist_currents`, times ``input_gain``: an affine map
  of ``q``, written as one ``Affine`` node (``encoder=False`` starts the graph at
  the 200 input currents instead);
* each layer is the exact LIF of Eq. (6)-(7) (`spikejax.nir.lif_node`), its own
  thresholds drawn in Section V, ``R = syn_hidden`` (``syn_output``) for the
  hidden (output) layer, so the ``Linear`` weights are the learned weights as the
  controller holds them (0 where no synapse); the 2 ms refractory period is in
  the metadata, not in NIR;
* the decoder of Eq. (8) stays out of the graph (it reads spike counts, not a NIR
  node); its constants are in the graph's metadata.

Times are in seconds and ``dt`` is the controller's 0.1 ms.

In: `graph_controller` turns a NIR graph of that shape (4 inputs, the lateral
state; one spiking output population), exported by spikejax or by another tool
(snnTorch, Norse, ...), into a controller with the RoboBee controller's
interface: ``q_lateral -> y_hat``, the output spikes decoded by Eq. (8).
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from robots.common import load_weights_file, save_weights_file
from robots.robobee.controller import N_LATERAL, ControllerConfig, ControllerParams, ControllerState
from spikejax import nir as spikejax_nir
from spikejax.coding import DecoderParams, DecoderState, decoder_init, decoder_step
from spikejax.errors import UserError
from spikejax.neurons import lif_params

__all__ = [
    "save_controller",
    "load_controller",
    "controller_graph",
    "export",
    "exporter",
    "GraphController",
    "graph_controller",
    "graph_controller_init",
    "graph_controller_step",
]

_PARAMS = ("dt", "a", "b", "input_gain", "tau_input", "tau_hidden", "tau_output", "t_ref", "syn_hidden", "syn_output")
_DECODER = ("alpha", "beta", "gamma")


def save_controller(path, config: ControllerConfig, params: ControllerParams, states: ControllerState, seeds) -> Path:
    """Writes a batch of trained controllers (leading axis: one per seed) to an ``.npz``, atomically.

    The weights are stored dense (0 where no synapse) with their masks, as the
    controller reads them (`ControllerState.w_ih`, ``w_ho``), beside each seed's
    thresholds and the constants a graph needs.
    """
    path = Path(path)
    states = jax.device_get(states)
    seeds = np.atleast_1d(np.asarray(seeds))
    dense = jax.vmap(lambda s: (s.w_ih, s.w_ho, s.mask_ih, s.mask_ho))(states)
    arrays = dict(
        seeds=seeds,
        n_per_input=config.n_per_input,
        n_hidden=config.n_hidden,
        n_output=config.n_output,
        connectivity=config.connectivity,
        w_ih=np.asarray(dense[0]),
        w_ho=np.asarray(dense[1]),
        mask_ih=np.asarray(dense[2]),
        mask_ho=np.asarray(dense[3]),
        v_th_input=np.asarray(states.v_th_input),
        v_th_hidden=np.asarray(states.v_th_hidden),
        v_th_output=np.asarray(states.v_th_output),
        **{f"p_{k}": np.asarray(getattr(params, k)) for k in _PARAMS},
        **{f"p_decoder_{k}": np.asarray(getattr(params.decoder, k)) for k in _DECODER},
    )
    if arrays["w_ih"].shape[0] != seeds.size:
        raise UserError(f"{seeds.size} seeds for a batch of {arrays['w_ih'].shape[0]} controllers")
    return save_weights_file(path, "robobee", **arrays)


def load_controller(path) -> dict:
    """The arrays of a file written by `save_controller`; a one-line error if it is not one."""
    return load_weights_file(path, "robobee", "a RoboBee controller file")


def _encoder(n_per_input: int, a, b, gain):
    """``currents = q @ W + bias`` for Section III's encoder with antagonist halves: ``W`` (4, n_input)."""
    a, b, gain = (np.asarray(x, np.float32) for x in (a, b, gain))
    n_in = N_LATERAL * n_per_input
    w = np.zeros((N_LATERAL, n_in), np.float32)
    bias = np.zeros(n_in, np.float32)
    half = n_per_input // 2
    for g in range(N_LATERAL):
        lo, mid, hi = g * n_per_input, g * n_per_input + half, (g + 1) * n_per_input
        w[g, lo:mid] = gain * a[g]
        bias[lo:mid] = gain * a[g] * b[g]
        w[g, mid:hi] = -gain * a[g]
        bias[mid:hi] = gain * (1.0 - a[g] * b[g])
    return w, bias


def controller_graph(arrays: dict, index: int = 0, *, encoder: bool = True, prefix: str = ""):
    """The nodes and edges of one seed's controller (``arrays`` as `load_controller` returns them).

    Returns:
        ``(nodes, edges, inputs, outputs)`` for `spikejax.nir.graph`; names start with ``prefix``.
    """
    p = {k: arrays[f"p_{k}"] for k in _PARAMS}
    n_per = int(arrays["n_per_input"])
    n_in, n_h, n_out = N_LATERAL * n_per, int(arrays["n_hidden"]), int(arrays["n_output"])

    def lif(tau, v_th, r):
        return lif_params(tau=tau, r=r, v_th=v_th, v_reset=0.0, v_rest=0.0, t_ref=p["t_ref"], dt=p["dt"], sigma=0.0)

    x = prefix
    nodes = {
        f"{x}input": spikejax_nir.lif_node(lif(p["tau_input"], arrays["v_th_input"][index], 1.0), n_in),
        f"{x}input_hidden": spikejax_nir.linear_node(arrays["w_ih"][index]),
        f"{x}hidden": spikejax_nir.lif_node(lif(p["tau_hidden"], arrays["v_th_hidden"][index], p["syn_hidden"]), n_h),
        f"{x}hidden_output": spikejax_nir.linear_node(arrays["w_ho"][index]),
        f"{x}output": spikejax_nir.lif_node(lif(p["tau_output"], arrays["v_th_output"][index], p["syn_output"]), n_out),
    }
    edges = [
        (f"{x}input", f"{x}input_hidden"),
        (f"{x}input_hidden", f"{x}hidden"),
        (f"{x}hidden", f"{x}hidden_output"),
        (f"{x}hidden_output", f"{x}output"),
    ]
    if encoder:
        w, bias = _encoder(n_per, p["a"], p["b"], p["input_gain"])
        nodes[f"{x}encoder"] = spikejax_nir.linear_node(
            w, bias, metadata={"what": "q_hat = a (q + b), antagonist halves, x input_gain"}
        )
        edges = [(f"{x}q", f"{x}encoder"), (f"{x}encoder", f"{x}input")] + edges
        inputs = {f"{x}q": N_LATERAL}
    else:
        edges = [(f"{x}currents", f"{x}input")] + edges
        inputs = {f"{x}currents": n_in}
    return nodes, edges, inputs, {f"{x}spikes": f"{x}output"}


def export(path, seed=None, *, encoder: bool = True):
    """The NIR graph of a controller file: one seed (``seed``, a seed number in the file) or all.

    With every seed, each seed's nodes are named ``seed<S>.<node>`` and its
    input and output ``seed<S>.q``, ``seed<S>.spikes``.
    """
    arrays = load_controller(path)
    seeds = [int(s) for s in arrays["seeds"]]
    if seed is not None and int(seed) not in seeds:
        raise UserError(f"{path}: no seed {seed} (it has {', '.join(map(str, seeds))})")
    chosen = seeds if seed is None else [int(seed)]
    nodes, edges, inputs, outputs = {}, [], {}, {}
    for s in chosen:
        prefix = "" if seed is not None else f"seed{s}."
        n, e, i, o = controller_graph(arrays, seeds.index(s), encoder=encoder, prefix=prefix)
        nodes.update(n)
        edges += e
        inputs.update(i)
        outputs.update(o)
    meta = {
        "robot": "robobee",
        "network": "lateral controller 4 x n_per_input - n_hidden - n_output (Section III of the RoboBee paper)",
        "seeds": np.asarray(chosen),
        "dt": float(arrays["p_dt"]),
        "time_unit": "s",
        "spikes": "a unit signal held for one step of dt",
        "decoder": "Eq. (8): y_hat(t) = alpha sum_{t_f < t} exp(beta (t_f - t)) - gamma over the output spikes",
        **{f"decoder_{k}": float(arrays[f"p_decoder_{k}"]) for k in _DECODER},
    }
    return spikejax_nir.graph(nodes, edges, inputs=inputs, outputs=outputs, metadata=meta)


exporter = spikejax_nir.NIRExporter(
    name="robobee",
    recognises=lambda keys, z: "robot" in keys and str(z["robot"]) == "robobee",
    export=export,
    seeds=lambda path: [int(s) for s in load_controller(path)["seeds"]],
)


class GraphController(NamedTuple):
    """An imported network as a RoboBee lateral controller (`graph_controller`).

    Attributes:
        network: the graph's static structure (`spikejax.nir.Network`); keep it
            static under ``jit`` (a closure or ``static_argnames``).
        params: its nodes' parameters (traced).
        decoder: Eq. (8)'s ``alpha``, ``beta``, ``gamma``.
        dt: the step, s.
    """

    network: spikejax_nir.Network
    params: dict
    decoder: DecoderParams
    dt: float


def graph_controller(graph, *, decoder: DecoderParams | None = None, dt: float | None = None) -> GraphController:
    """A NIR graph with one 4-wide input (the lateral state) and one spiking output as a RoboBee controller.

    Args:
        graph: the ``nir.NIRGraph`` or a path to one.
        decoder: Eq. (8)'s constants; default the graph's metadata (a spikejax export), else required.
        dt: the step, s; default the graph's ``metadata["spikejax"]["dt"]``.

    Raises:
        UserError: in one line, if the graph has not one input of size 4 and one
            output, or states no decoder and none is given.
    """
    if isinstance(graph, (str, Path)):
        graph = spikejax_nir.read(graph)
    network, params = spikejax_nir.from_nir(graph, dt=dt)
    if len(network.inputs) != 1 or network.size(network.inputs[0]) != N_LATERAL:
        sizes = ", ".join(f"{n} ({network.size(n)})" for n in network.inputs) or "none"
        raise UserError(
            f"a RoboBee controller graph takes one input of size {N_LATERAL}, the lateral state; this one: {sizes}"
        )
    if len(network.outputs) != 1:
        raise UserError(
            f"a RoboBee controller graph has one output, the spikes to decode; this one {len(network.outputs)}"
        )
    if decoder is None:
        meta = graph.metadata.get(spikejax_nir.KEY, {})
        if not all(f"decoder_{k}" in meta for k in _DECODER):
            raise UserError(
                "the graph states no decoder (Eq. (8) of the RoboBee paper): pass decoder=DecoderParams(...)"
            )
        decoder = DecoderParams(*(jnp.float32(meta[f"decoder_{k}"]) for k in _DECODER))
    return GraphController(network=network, params=params, decoder=decoder, dt=network.dt)


def graph_controller_init(controller: GraphController) -> tuple[dict, DecoderState]:
    """The imported network at rest and the decoder's trace at 0."""
    return spikejax_nir.network_init(controller.network, controller.params), decoder_init()


def graph_controller_step(
    controller: GraphController, state, q_lateral
) -> tuple[tuple[dict, DecoderState], jnp.ndarray]:
    """One step: the lateral state ``[theta, theta_dot, x, x_dot]`` in, ``y_hat`` (units of `TORQUE_UNIT`) out.

    The same interface as `robots.robobee.controller.controller_step` without learning:
    a frozen network, trained in spikejax or elsewhere.
    """
    net_state, dec = state
    net = controller.network
    net_state, out = spikejax_nir.network_step(net, controller.params, net_state, {net.inputs[0]: q_lateral})
    dec, y_hat = decoder_step(controller.decoder, dec, out[net.outputs[0]], controller.dt)
    return (net_state, dec), y_hat
