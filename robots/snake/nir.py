"""The snake's R-STDP networks (`robots.snake.rstdp`) out to NIR, from the weights ``spikejax reproduce snake-rstdp`` saves.

The weights file is ``DIR/weights/TOPOLOGY.npz`` (arrays ``topology``,
``seeds``, ``w_first`` ``(seeds, 10, n_first)``, ``w_hidden`` ``(seeds, 8, 2)``,
pA). The graph of one seed, every time in ms at NEST's resolution 0.1 ms::

    dvs (10) -> dvs_delay (Delay 1 ms) -> dvs_first (Linear w_first) -> first_delay (Delay 1 ms) -> first (CubaLIF)

and, for the multi-layer nets (``unified``, ``separated``), the body layer::

    first[H_L, H_R] -> hidden_body (Linear w_hidden[:2]) --+
    joints (6) -> joints_delay (Delay) -> joints_body (Linear w_hidden[2:]) --+-> body_delay (Delay 1 ms) -> body (CubaLIF)

* the inputs are the Poisson generators' spike counts of each 0.1 ms step; the
  parrot neurons that repeat them (Sec. II-B) are the identity and have no node:
  the first ``Delay`` is the generator-to-parrot connection;
* every LIF is NEST's ``iaf_psc_alpha`` as NIR's ``CubaLIF``, the closest node
  (`spikejax.nir.iaf_psc_alpha_node`: exponential synapse of the alpha
  synapse's charge; the exact NEST parameters in the metadata);
* every connection has the network's 1 ms delay (`robots.snake.rstdp.NetworkConfig.delay`);
* the separated net's missing synapses are zeros of ``w_hidden``;
* the R-STDP rule and the decoding of Eq. (4)-(5) of the snake R-STDP paper stay
  out of the graph: it is the network as trained, frozen.

In: `graph_controller` runs a graph of that shape (inputs ``dvs`` and, for the
multi-layer nets, ``joints``; outputs ``first_spikes`` and ``body_spikes``),
exported by spikejax or written by another tool, as a
`spikejax.rollout.Controller` of the snake env: the encoders and the decoding
are the R-STDP controller's (`robots.snake.rstdp.network_rates`,
`robots.snake.rstdp.network_decode`), the network the graph's, frozen.
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from robots.snake import rstdp
from spikejax import coding
from spikejax import nir as spikejax_nir
from spikejax.errors import UserError
from spikejax.rollout import Controller

__all__ = ["load", "network_graph", "export", "exporter", "GraphState", "graph_controller"]


def load(path) -> tuple[str, np.ndarray, np.ndarray, np.ndarray]:
    """``(topology, seeds, w_first, w_hidden)`` of a weights file; a one-line error if it is not one."""
    try:
        with np.load(path) as z:
            out = str(z["topology"]), z["seeds"], z["w_first"], z["w_hidden"]
    except (OSError, KeyError, ValueError) as e:
        raise UserError(f"{path}: not a snake-rstdp weights file ({e.__class__.__name__})") from None
    if out[0].partition("/")[0] not in rstdp.TOPOLOGIES:
        raise UserError(f"{path}: unknown topology {out[0]!r}")
    return out


def network_graph(topology: str, w_first, w_hidden, *, prefix: str = "", config: rstdp.NetworkConfig | None = None):
    """The nodes and edges of one network; ``topology`` may carry a ``/VARIANT`` (variants change only the learning).

    Returns:
        ``(nodes, edges, inputs, outputs)`` for `spikejax.nir.graph`.
    """
    config = config or rstdp.NetworkConfig(topology=topology.partition("/")[0])
    neuron = rstdp.network_params(config).neuron
    dt, d, x = config.dt, config.delay, prefix
    w_first = np.asarray(w_first, np.float32)
    nf = config.n_first
    if w_first.shape != (rstdp.N_DVS, nf):
        raise UserError(f"w_first of shape {w_first.shape}; the {config.topology} net has {(rstdp.N_DVS, nf)}")
    nodes = {
        f"{x}dvs_delay": spikejax_nir.delay_node(rstdp.N_DVS, d, dt),
        f"{x}dvs_first": spikejax_nir.linear_node(w_first),
        f"{x}first_delay": spikejax_nir.delay_node(nf, d, dt),
        f"{x}first": spikejax_nir.iaf_psc_alpha_node(neuron, nf, dt),
    }
    edges = [
        (f"{x}dvs", f"{x}dvs_delay"),
        (f"{x}dvs_delay", f"{x}dvs_first"),
        (f"{x}dvs_first", f"{x}first_delay"),
        (f"{x}first_delay", f"{x}first"),
    ]
    inputs = {f"{x}dvs": rstdp.N_DVS}
    outputs = {f"{x}first_spikes": f"{x}first"}
    if config.hidden:
        w_hidden = np.asarray(w_hidden, np.float32) * config.hidden_mask
        nodes.update(
            {
                f"{x}joints_delay": spikejax_nir.delay_node(rstdp.N_JOINT, d, dt),
                f"{x}hidden_body": spikejax_nir.linear_node(w_hidden[:2]),
                f"{x}joints_body": spikejax_nir.linear_node(w_hidden[2:]),
                f"{x}body_delay": spikejax_nir.delay_node(2, d, dt),
                f"{x}body": spikejax_nir.iaf_psc_alpha_node(neuron, 2, dt),
            }
        )
        edges += [
            (f"{x}first", f"{x}hidden_body"),
            (f"{x}joints", f"{x}joints_delay"),
            (f"{x}joints_delay", f"{x}joints_body"),
            (f"{x}hidden_body", f"{x}body_delay"),
            (f"{x}joints_body", f"{x}body_delay"),
            (f"{x}body_delay", f"{x}body"),
        ]
        inputs[f"{x}joints"] = rstdp.N_JOINT
        outputs[f"{x}body_spikes"] = f"{x}body"
    return nodes, edges, inputs, outputs


def export(path, seed=None):
    """The NIR graph of a weights file: one seed (a seed number in the file) or all (names ``seed<S>.<node>``)."""
    topology, seeds, w_first, w_hidden = load(path)
    seeds = [int(s) for s in seeds]
    if seed is not None and int(seed) not in seeds:
        raise UserError(f"{path}: no seed {seed} (it has {', '.join(map(str, seeds))})")
    chosen = seeds if seed is None else [int(seed)]
    nodes, edges, inputs, outputs = {}, [], {}, {}
    for s in chosen:
        i = seeds.index(s)
        n, e, ins, outs = network_graph(
            topology, w_first[i], w_hidden[i], prefix="" if seed is not None else f"seed{s}."
        )
        nodes.update(n)
        edges += e
        inputs.update(ins)
        outputs.update(outs)
    config = rstdp.NetworkConfig(topology=topology.partition("/")[0])
    meta = {
        "robot": "snake",
        "network": f"snake R-STDP {topology} network (Sec. II-III of the snake R-STDP paper), frozen",
        "topology": topology,
        "seeds": np.asarray(chosen),
        "dt": float(config.dt),
        "time_unit": "ms",
        "spikes": "generator spike counts per step of dt, held for the step; weights in pA",
        "source": Path(path).name,
    }
    return spikejax_nir.graph(nodes, edges, inputs=inputs, outputs=outputs, metadata=meta)


exporter = spikejax_nir.NIRExporter(
    name="snake-rstdp",
    recognises=lambda keys, z: {"topology", "w_first", "w_hidden"} <= set(keys),
    export=export,
    seeds=lambda path: [int(s) for s in load(path)[1]],
)


class GraphState(NamedTuple):
    """An imported network between control steps, with Eq. (5)'s integrators and the last counts.

    Attributes:
        network: the imported network's state (`spikejax.nir.network_init`).
        d_head, d_body: Eq. (5)'s integrators.
        counts: output spikes of the last control step, ``(n_out,)``.
    """

    network: dict
    d_head: jax.Array
    d_body: jax.Array
    counts: jax.Array


def graph_controller(graph, config: rstdp.NetworkConfig | None = None):
    """A NIR graph of the snake's network shape as a frozen controller of `robots.snake.env.SnakeEnv`.

    Args:
        graph: the ``nir.NIRGraph`` or a path; its inputs ``dvs`` (10) and, if
            the topology has the body layer, ``joints`` (6); its outputs
            ``first_spikes`` and ``body_spikes``.
        config: the topology and timing; default the graph's metadata
            ``topology`` (a spikejax export), learning off.

    Returns:
        ``(controller, params, state)``: the `spikejax.rollout.Controller`, its
        parameters (the graph's node parameters and the encoders' and decoder's
        `robots.snake.rstdp.NetworkParams`) and its initial state.

    Raises:
        UserError: in one line, if the graph lacks an input or output of that shape.
    """
    if isinstance(graph, (str, Path)):
        graph = spikejax_nir.read(graph)
    if config is None:
        topology = graph.metadata.get(spikejax_nir.KEY, {}).get("topology")
        if topology is None:
            raise UserError("the graph states no snake topology (metadata spikejax.topology): pass config")
        config = rstdp.NetworkConfig(topology=str(topology).partition("/")[0], learn=False)
    net, graph_params = spikejax_nir.from_nir(graph, dt=config.dt)
    want_in = {"dvs": rstdp.N_DVS, **({"joints": rstdp.N_JOINT} if config.hidden else {})}
    want_out = {"first_spikes": config.n_first, **({"body_spikes": 2} if config.hidden else {})}
    for names, want, what in ((net.inputs, want_in, "input"), (net.outputs, want_out, "output")):
        if {n: net.size(n) for n in names} != want:
            got = ", ".join(f"{n} ({net.size(n)})" for n in names) or "none"
            expected = ", ".join(f"{n} ({k})" for n, k in want.items())
            raise UserError(f"a snake {config.topology} graph has the {what}s {expected}; this one: {got}")
    params = (graph_params, rstdp.network_params(config))

    def step(params, state, env_state, *, key):
        graph_params, net_params = params
        info = env_state.info
        frames = (info["prev_frame"], info["frame"], info["params"].event_threshold)
        rates = rstdp.network_rates(config, net_params, frames, env_state.obs)
        generated = coding.poisson_count_train(rates, 0.001 * config.dt, config.substeps, key=key)
        inputs = {"dvs": generated[:, : rstdp.N_DVS]}
        if config.hidden:
            inputs["joints"] = generated[:, rstdp.N_DVS :]
        network, out = spikejax_nir.network_run(net, graph_params, state.network, inputs)
        spikes = [out["first_spikes"]] + ([out["body_spikes"]] if config.hidden else [])
        counts = jnp.concatenate(spikes, axis=1).sum(0).astype(jnp.int32)
        state = rstdp.network_decode(config, net_params, state._replace(network=network), counts)
        return state, jnp.stack([state.d_body, state.d_head]), {"d_body": state.d_body, "d_head": state.d_head}

    def on_reset(params, state):
        zero = jnp.zeros((), jnp.float32)
        return state._replace(d_head=zero, d_body=zero)

    zero = jnp.zeros((), jnp.float32)
    state = GraphState(
        network=spikejax_nir.network_init(net, graph_params),
        d_head=zero,
        d_body=zero,
        counts=jnp.zeros((config.n_out,), jnp.int32),
    )
    return Controller(step=step, on_reset=on_reset), params, state
