"""The hexapod's spiking CPG (`robots.hexapod.cpg`) in and out of NIR, with its trained weights.

The graph of one trained SCPG (Fig. 2(a) of the hexapod SCPG paper)::

    gait (3) -> gait_cpg (Linear w_in) --> cpg (LIF, 6) -> spikes (Output)
                         cpg -> cpg_cpg (Linear w_cpg) --^   (the recurrent loop)

The CPG neurons are the discrete LIF of Eq. (1)-(2), which NIR has no node
for: the closest faithful encoding is NIR's LIF over a unit step
(`spikejax.nir.discrete_lif_node`: ``tau = 1 / ln(alpha)`` steps, ``R = alpha /
(alpha - 1)``, or IF for ``alpha = 1``), exact when the consumer holds each
input over the step and integrates the step exactly; a forward-Euler consumer
at ``dt = 1`` decays by ``1 - ln(alpha)`` instead of ``1 / alpha``. The loop
carries one step (a spike at ``t`` moves the potentials at ``t + 1``), as every
discrete-time NIR consumer runs a recurrent edge. The gait-selection neurons
are the graph's input: ``G_i`` is 1 at every step while gait ``i`` runs.

Weights files (`save_weights`): ``robot = "hexapod"``, ``seeds``, ``w_in``
``(seeds, 3, 6)``, ``w_cpg`` ``(seeds, 6, 6)``, ``alpha``, ``v_th``.
"""

from __future__ import annotations

from pathlib import Path

import jax
import numpy as np

from robots.common import load_weights_file, save_weights_file
from robots.hexapod.cpg import CPGWeights
from robots.hexapod.gaits import N_GAITS, N_LEGS
from spikejax import nir as spikejax_nir
from spikejax.errors import UserError
from spikejax.neurons import DiscreteLIFParams

__all__ = ["save_weights", "load_weights", "cpg_graph", "export", "exporter"]


def save_weights(path, weights: CPGWeights, neuron: DiscreteLIFParams, seeds) -> Path:
    """Writes trained SCPG weights (leading axis: one per seed, e.g. `robots.hexapod.training.TrainResult.weights`)."""
    path = Path(path)
    weights = jax.device_get(weights)
    seeds = np.atleast_1d(np.asarray(seeds))
    w_in, w_cpg = np.asarray(weights.w_in, np.float32), np.asarray(weights.w_cpg, np.float32)
    if w_in.ndim == 2:
        w_in, w_cpg = w_in[None], w_cpg[None]
    if w_in.shape != (seeds.size, N_GAITS, N_LEGS) or w_cpg.shape != (seeds.size, N_LEGS, N_LEGS):
        raise UserError(f"weights of shapes {w_in.shape}, {w_cpg.shape} for {seeds.size} seeds")
    return save_weights_file(
        path,
        "hexapod",
        seeds=seeds,
        w_in=w_in,
        w_cpg=w_cpg,
        alpha=np.asarray(neuron.alpha, np.float32),
        v_th=np.asarray(neuron.v_th, np.float32),
    )


def load_weights(path) -> dict:
    """The arrays of a file written by `save_weights`; a one-line error if it is not one."""
    return load_weights_file(path, "hexapod", "a hexapod SCPG weights file")


def cpg_graph(w_in, w_cpg, neuron: DiscreteLIFParams, *, prefix: str = ""):
    """The nodes and edges of one SCPG: ``(nodes, edges, inputs, outputs)`` for `spikejax.nir.graph`."""
    x = prefix
    nodes = {
        f"{x}gait_cpg": spikejax_nir.linear_node(w_in),
        f"{x}cpg": spikejax_nir.discrete_lif_node(neuron, N_LEGS),
        f"{x}cpg_cpg": spikejax_nir.linear_node(w_cpg),
    }
    edges = [
        (f"{x}gait", f"{x}gait_cpg"),
        (f"{x}gait_cpg", f"{x}cpg"),
        (f"{x}cpg", f"{x}cpg_cpg"),
        (f"{x}cpg_cpg", f"{x}cpg"),
    ]
    return nodes, edges, {f"{x}gait": N_GAITS}, {f"{x}spikes": f"{x}cpg"}


def export(path, seed=None):
    """The NIR graph of a weights file: one seed (a seed number in the file) or all (names ``seed<S>.<node>``)."""
    arrays = load_weights(path)
    seeds = [int(s) for s in arrays["seeds"]]
    if seed is not None and int(seed) not in seeds:
        raise UserError(f"{path}: no seed {seed} (it has {', '.join(map(str, seeds))})")
    chosen = seeds if seed is None else [int(seed)]
    neuron = DiscreteLIFParams(alpha=arrays["alpha"], v_th=arrays["v_th"])
    nodes, edges, inputs, outputs = {}, [], {}, {}
    for s in chosen:
        i = seeds.index(s)
        n, e, ins, outs = cpg_graph(
            arrays["w_in"][i], arrays["w_cpg"][i], neuron, prefix="" if seed is not None else f"seed{s}."
        )
        nodes.update(n)
        edges += e
        inputs.update(ins)
        outputs.update(outs)
    meta = {
        "robot": "hexapod",
        "network": "spiking CPG, 3 gait-selection inputs, 6 CPG neurons (Fig. 2(a) of the hexapod SCPG paper)",
        "seeds": np.asarray(chosen),
        "dt": 1.0,
        "time_unit": "step",
        "spikes": "a unit signal held for one step",
    }
    return spikejax_nir.graph(nodes, edges, inputs=inputs, outputs=outputs, metadata=meta)


exporter = spikejax_nir.NIRExporter(
    name="hexapod",
    recognises=lambda keys, z: "robot" in keys and str(z["robot"]) == "hexapod",
    export=export,
    seeds=lambda path: [int(s) for s in load_weights(path)["seeds"]],
)
