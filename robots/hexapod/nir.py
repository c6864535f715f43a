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

The visual SNN (`spikejax.vision.edges`, Sec. IV; `vision_graph`) in its
slotted mode, one step a time slot of ``dt``::

    events (H x W counts) -> filter_conv (Conv2d 3 x 3) -> filter (LIF)
      filter -> columns (SumPool2d (window, 1)) -> Scale (0.06) -> vertical (LIF)
      filter -> rows (SumPool2d (1, window))    -> Scale (0.06) -> horizontal (LIF)
      vertical -> SumPool2d (1, window) -> Scale (0.3) -> windows_v (LIF) -> Flatten -> Linear -+
      horizontal -> SumPool2d (window, 1) -> Scale (0.3) -> windows_h (LIF) -> Flatten -> Linear -+-> gaits (LIF, 3)

Every neuron is the discrete LIF with ``alpha = exp(dt / tau)`` of its layer,
which is the event-time leak of `spikejax.vision.edges` when every slot is
``dt`` long. The vertical layer-2 pooling also covers the columns the
windows ignore (the paper's rightmost 80): their neurons exist in the graph
but feed nothing, since the window pooling's stride drops them. The sums are
SumPool2d nodes weighted by Scale (nir 1.0.8 infers a Conv2d's output shape
from the kernel's height alone, so a (1, n) or (n, 1) convolution would not
read back).
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

__all__ = ["save_weights", "load_weights", "cpg_graph", "export", "exporter", "vision_graph"]


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


def _shaped_lif(alpha, v_th, shape):
    """`spikejax.nir.discrete_lif_node` with its arrays in ``shape`` (a convolution's output)."""
    node = spikejax_nir.discrete_lif_node(DiscreteLIFParams(alpha=alpha, v_th=v_th), int(np.prod(shape)))
    for field in ("tau", "r", "v_leak", "v_threshold", "v_reset"):
        setattr(node, field, np.asarray(getattr(node, field)).reshape(shape))
    node.__post_init__()
    return node


def vision_graph(config, params, dt: float):
    """Sec. IV's visual SNN (`spikejax.vision.edges`) as a NIR graph stepped every ``dt`` seconds (module docstring).

    Args:
        config: the `spikejax.vision.edges.EdgeConfig`.
        params: its `spikejax.vision.edges.EdgeParams` (weights, leaks, threshold).
        dt: the time slot, s; the graph's step.
    """
    import nir

    h, w, win = config.height, config.width, config.window
    alpha = lambda tau: np.exp(dt / float(tau))
    v_th = float(params.v_th)
    k = np.array(
        [[params.corner, params.edge, params.corner], [params.edge, params.centre, params.edge],
         [params.corner, params.edge, params.corner]], np.float32,
    )  # fmt: skip

    def pool(kernel):
        return nir.SumPool2d(kernel_size=np.array(kernel), stride=np.array(kernel), padding=np.array([0, 0]))

    def scale(value, shape):
        return nir.Scale(scale=np.full(shape, value, np.float32))

    n_rows_all, n_cols_all = h // win, w // win
    vertical, horizontal, windows = (1, n_rows_all, w), (1, h, n_cols_all), (1, n_rows_all, n_cols_all)
    nodes = {
        "filter_conv": nir.Conv2d(
            input_shape=(h, w),
            weight=k[None, None],
            stride=1,
            padding=1,
            dilation=1,
            groups=1,
            bias=np.zeros(1, np.float32),
        ),
        "filter": _shaped_lif(alpha(params.tau_filter), v_th, (1, h, w)),
        "columns": pool((win, 1)),
        "column_weight": scale(params.column, vertical),
        "vertical": _shaped_lif(alpha(params.tau_column), v_th, vertical),
        "rows": pool((1, win)),
        "row_weight": scale(params.column, horizontal),
        "horizontal": _shaped_lif(alpha(params.tau_column), v_th, horizontal),
        "vertical_window": pool((1, win)),
        "vertical_window_weight": scale(params.window, windows),
        "windows_v": _shaped_lif(alpha(params.tau_window), v_th, windows),
        "horizontal_window": pool((win, 1)),
        "horizontal_window_weight": scale(params.window, windows),
        "windows_h": _shaped_lif(alpha(params.tau_window), v_th, windows),
        "flat_v": nir.Flatten(input_type={"input": np.array(windows)}, start_dim=0),
        "flat_h": nir.Flatten(input_type={"input": np.array(windows)}, start_dim=0),
        "readout_v": nir.Linear(weight=np.asarray(params.readout, np.float32)[..., 0].reshape(config.n_out, -1)),
        "readout_h": nir.Linear(weight=np.asarray(params.readout, np.float32)[..., 1].reshape(config.n_out, -1)),
        "gaits": spikejax_nir.discrete_lif_node(
            DiscreteLIFParams(alpha=alpha(params.tau_out), v_th=v_th), config.n_out
        ),
    }
    chain = [
        ("events", "filter_conv", "filter"),
        ("filter", "columns", "column_weight", "vertical", "vertical_window", "vertical_window_weight", "windows_v"),
        ("filter", "rows", "row_weight", "horizontal", "horizontal_window", "horizontal_window_weight", "windows_h"),
        ("windows_v", "flat_v", "readout_v", "gaits"),
        ("windows_h", "flat_h", "readout_h", "gaits"),
    ]
    edges = [(a, b) for path in chain for a, b in zip(path, path[1:])]
    meta = {
        "robot": "hexapod",
        "network": "visual SNN of Sec. IV of the hexapod SCPG paper: filter, edge windows, gait selection",
        "dt": float(dt),
        "time_unit": "s",
        "spikes": "a unit signal held for one step; the input is each slot's events per pixel",
    }
    nodes["events"] = nir.Input(input_type=np.array([1, h, w]))
    nodes["gait_spikes"] = nir.Output(output_type=np.array([config.n_out]))
    edges.append(("gaits", "gait_spikes"))
    return nir.NIRGraph(nodes=nodes, edges=edges, metadata={spikejax_nir.KEY: meta})
