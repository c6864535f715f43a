"""Networks out and in: export spikejax neurons and weights to NIR graphs, and run NIR graphs in spikejax.

NIR, the Neuromorphic Intermediate Representation (package ``nir``, the extra
``spikejax[nir]``), describes a network as a graph of continuous-time nodes:
neurons (``LIF``, ``CubaLIF``, ``IF``), synapses (``Affine``, ``Linear``,
``Scale``) and ``Delay``. snnTorch, Norse, Spyx, Rockpool, Sinabs, Lava and
several chips' toolchains read it. This module is the robot-free half: each of
spikejax's neuron models and weight matrices becomes NIR nodes with its constants
unchanged (`lif_node`, `iaf_psc_alpha_node`, `discrete_lif_node`, `linear_node`,
`delay_node`, `graph`), and a NIR graph becomes a spikejax network that steps
under ``jit`` and ``vmap`` (`from_nir`, `network_init`, `network_step`,
`network_run`). Which network a robot runs, and with which learned weights, is
the robot's business (``robots/<robot>/nir.py``).

Conventions (also written into every exported graph's metadata):

* **Time.** A spikejax network is stepped at a fixed ``dt``; the graph's
  metadata ``spikejax.dt`` holds it (seconds for the RoboBee, ms for the snake,
  one step for the hexapod). NIR's time constants are in that unit.
* **Spikes are a unit signal held for one step**: a spike in step ``k`` is the
  value 1 (or its multiplicity) over ``[t_k, t_k + dt)``, and a synapse's output
  ``W s`` is a current held over that step. This is how spikejax's layers and
  snnTorch's NIR import read a spike. A consumer that reads spikes as Dirac
  impulses of unit area should multiply every synaptic weight by ``dt``.
* **Weights**: spikejax stores ``(n_pre, n_post)``; NIR's ``weight`` is
  ``(n_post, n_pre)`` (``y = W x``), so `linear_node` transposes.
* **What NIR cannot say** goes into each node's ``metadata["spikejax"]``: the
  model it came from and the constants NIR has no field for (the refractory
  period, the threshold's ``>=``, NEST's alpha synapse, the hexapod's decay
  factor). `from_nir` reads them back, so a round trip is exact; a graph without
  them is run by NIR's equations as written (`from_nir`).

Where a model has no exact NIR node, the node is the closest faithful encoding
and its docstring says what differs (the ``iaf_psc_alpha`` alpha synapse and
the refractory periods); the table is docs/EQUATIONS.md, "NIR".
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from spikejax.errors import UserError
from spikejax.neurons import (
    DiscreteLIFParams,
    DiscreteLIFState,
    IafPscAlphaParams,
    LIFParams,
    LIFState,
    discrete_lif_step,
    iaf_psc_alpha_init,
    iaf_psc_alpha_step,
    lif_step,
)
from spikejax.synapses import delay_init, delay_step

__all__ = [
    "KEY",
    "NIRExporter",
    "lif_node",
    "iaf_psc_alpha_node",
    "discrete_lif_node",
    "linear_node",
    "delay_node",
    "graph",
    "write",
    "read",
    "unit_thresholds",
    "relative_potentials",
    "Network",
    "from_nir",
    "network_init",
    "network_step",
    "network_run",
    "CubaLIFParams",
    "CubaLIFState",
    "cuba_lif_step",
]

KEY = "spikejax"
"""The key of the metadata that spikejax writes into NIR nodes and graphs."""


def _nir():
    try:
        import nir
    except ImportError:
        raise UserError("NIR export and import need the package nir: pip install 'spikejax[nir]'") from None
    return nir


def _f32(x, n: int) -> np.ndarray:
    return np.broadcast_to(np.asarray(x, np.float32), (n,)).copy()


@dataclasses.dataclass(frozen=True)
class NIRExporter:
    """A robot's NIR exporter, registered as an entry point of the group ``spikejax.nir``.

    ``spikejax export nir`` loads every registered exporter and asks each whether
    it ``recognises`` a weights file; the robot's package registers its own, as it
    registers its commands (``robots/<robot>/nir.py``).

    Attributes:
        name: the robot (``--robot NAME`` picks it by this name).
        recognises: ``(keys, npz) -> bool``: whether an opened ``.npz`` (its keys and
            the ``numpy`` archive) is this robot's weights file.
        export: ``(path, seed) -> nir.NIRGraph``; ``seed=None`` exports every seed of the file.
        seeds: ``(path) -> seeds in the file``.
    """

    name: str
    recognises: Any
    export: Any
    seeds: Any


# ------------------------------------------------------------------------------------ export


def lif_node(params: LIFParams, n: int):
    """A population of spikejax's LIF (Eq. (6)-(7) of the RoboBee paper) as a NIR ``LIF`` node.

    NIR's LIF, ``tau dv/dt = (v_leak - v) + R I``, is Eq. (6) with ``v_leak =
    v_rest``; every constant is copied as it is (float32). Two things NIR's LIF
    does not have go into the metadata: the refractory period ``t_ref`` (NIR
    has none: a consumer that ignores it lets a neuron fire again right after its
    reset, so the higher a neuron's rate, the more it fires there) and the
    threshold test (spikejax fires at ``v >= v_th``, NIR at ``v > v_th``; the two
    differ only when ``v`` lands exactly on the threshold). The noise ``sigma``
    must be 0: NIR has no noise.

    Args:
        params: the population's parameters (scalars or ``(n,)``).
        n: neurons.

    Returns:
        ``nir.LIF`` with fields of shape ``(n,)``.

    Raises:
        UserError: if ``sigma`` is not 0.
    """
    nir = _nir()
    if np.any(np.asarray(params.sigma) != 0):
        raise UserError("a noisy LIF (sigma > 0) has no NIR node: NIR's LIF is deterministic")
    meta = {"model": "lif", "t_ref": float(np.max(params.t_ref)), "dt": float(params.dt), "threshold": ">="}
    if np.ndim(params.t_ref):
        meta["t_ref_per_neuron"] = _f32(params.t_ref, n)
    return nir.LIF(
        tau=_f32(params.tau, n),
        r=_f32(params.r, n),
        v_leak=_f32(params.v_rest, n),
        v_threshold=_f32(params.v_th, n),
        v_reset=_f32(params.v_reset, n),
        metadata={KEY: meta},
    )


def iaf_psc_alpha_node(params: IafPscAlphaParams, n: int, dt: float):
    """NEST's ``iaf_psc_alpha`` as a NIR ``CubaLIF`` node: the closest encoding, not an exact one.

    NIR's CubaLIF has an exponential synaptic current (``tau_syn dI/dt = -I +
    w_in S``); ``iaf_psc_alpha``'s current after a spike of weight ``w`` is the
    alpha function ``w e t / tau_syn exp(-t / tau_syn)``, which rises over
    ``tau_syn`` before it decays. The node keeps the membrane exactly (``tau_mem
    = tau_m``, ``R = tau_m / C_m`` in GOhm so that ``R I`` is in mV, ``v_leak =
    E_L``, ``v_threshold = V_th``, ``v_reset = V_reset``) and gives each spike the
    alpha function's charge, ``w e tau_syn``: with spikes held for one step of
    ``dt`` (module docstring), ``w_in = e tau_syn / dt``. An exponential
    synapse therefore delivers the same charge sooner: the same steady rates
    under steady input, earlier first spikes. NIR also has no refractory period
    (``t_ref``), no constant current ``I_e`` and one synaptic time constant (so
    ``tau_syn_ex`` must equal ``tau_syn_in``); the metadata keeps every NEST
    parameter, so `from_nir` rebuilds ``iaf_psc_alpha`` exactly.

    Args:
        params: NEST's parameters (pF, ms, mV, pA), scalars or ``(n,)``.
        n: neurons.
        dt: NEST's resolution, ms.

    Returns:
        ``nir.CubaLIF`` with fields of shape ``(n,)``; times in ms.

    Raises:
        UserError: if ``tau_syn_ex != tau_syn_in``.
    """
    nir = _nir()
    if not np.array_equal(np.asarray(params.tau_syn_ex), np.asarray(params.tau_syn_in)):
        raise UserError("iaf_psc_alpha with tau_syn_ex != tau_syn_in has no CubaLIF (NIR has one tau_syn)")
    tau_syn = _f32(params.tau_syn_ex, n)
    meta = {"model": "iaf_psc_alpha", "dt": float(dt), "threshold": ">=", "synapse": "alpha"}
    meta.update({name: _f32(value, n) for name, value in params._asdict().items()})
    return nir.CubaLIF(
        tau_syn=tau_syn,
        tau_mem=_f32(params.tau_m, n),
        r=_f32(np.asarray(params.tau_m, np.float32) / np.asarray(params.C_m, np.float32), n),
        v_leak=_f32(params.E_L, n),
        v_threshold=_f32(params.V_th, n),
        v_reset=_f32(params.V_reset, n),
        w_in=(math.e * tau_syn / np.float32(dt)).astype(np.float32),
        metadata={KEY: meta},
    )


def discrete_lif_node(params: DiscreteLIFParams, n: int):
    """The discrete LIF of Eq. (1)-(2) of the hexapod SCPG paper as a NIR ``LIF`` (or ``IF``) node.

    Eq. (1), ``V[t+1] = V[t] / alpha + I[t]``, is a map, not an ODE, but for
    ``alpha > 1`` it is exactly what NIR's LIF does over one unit step with the
    input held over the step: ``exp(-1 / tau) = 1 / alpha`` gives ``tau = 1 /
    ln(alpha)`` steps, and the held input moves ``v`` by ``R I (1 - 1 / alpha)``,
    so ``R = alpha / (alpha - 1)`` makes it ``I``. ``alpha = 1`` (a perfect
    integrator) is NIR's IF with ``R = 1``. Eq. (2) fires at ``V > V_th``, NIR's
    test, and resets to 0. ``alpha < 1`` (an amplifying neuron) has no NIR node.
    Time is in steps (``dt = 1``). The metadata keeps ``alpha``, so `from_nir`
    steps Eq. (1)-(2) itself, bit for bit.

    Args:
        params: ``alpha`` and ``v_th`` (scalars or ``(n,)``).
        n: neurons.

    Returns:
        ``nir.LIF``, or ``nir.IF`` if every ``alpha`` is 1.

    Raises:
        UserError: if some ``alpha < 1``, or some but not all are 1.
    """
    nir = _nir()
    alpha = _f32(params.alpha, n).astype(np.float64)
    meta = {"model": "discrete_lif", "dt": 1.0, "threshold": ">", "alpha": _f32(params.alpha, n)}
    if np.any(alpha < 1):
        raise UserError(f"a discrete LIF with alpha < 1 (here {alpha.min():g}) has no NIR node")
    zero = np.zeros(n, np.float32)
    if np.all(alpha == 1):
        return nir.IF(r=np.ones(n, np.float32), v_threshold=_f32(params.v_th, n), v_reset=zero, metadata={KEY: meta})
    if np.any(alpha == 1):
        raise UserError("a discrete LIF population mixing alpha = 1 and alpha > 1 has no single NIR node")
    return nir.LIF(
        tau=(1.0 / np.log(alpha)).astype(np.float32),
        r=(alpha / (alpha - 1.0)).astype(np.float32),
        v_leak=zero,
        v_threshold=_f32(params.v_th, n),
        v_reset=zero,
        metadata={KEY: meta},
    )


def linear_node(weights, bias=None, *, metadata: Mapping | None = None):
    """A spikejax weight matrix ``(n_pre, n_post)`` as NIR ``Linear`` (or ``Affine`` with a bias).

    NIR's ``y = W x`` takes ``W`` as ``(n_post, n_pre)``: the matrix is
    transposed, the values copied as float32. Absent synapses are zeros.
    """
    nir = _nir()
    w = np.ascontiguousarray(np.asarray(weights, np.float32).T)
    meta = {KEY: dict(metadata or {})}
    if bias is None:
        return nir.Linear(weight=w, metadata=meta)
    return nir.Affine(weight=w, bias=_f32(bias, w.shape[0]), metadata=meta)


def delay_node(n: int, steps: int, dt: float):
    """A transmission delay of ``steps`` whole steps (spikejax's `spikejax.synapses.DelayLine`) as NIR ``Delay``.

    NIR's delay is a time, ``steps * dt`` in the graph's unit; the metadata keeps
    the steps, so the delay comes back as the same ring buffer.
    """
    nir = _nir()
    return nir.Delay(delay=np.full(n, steps * dt, np.float32), metadata={KEY: {"steps": int(steps)}})


def graph(nodes: Mapping, edges, *, inputs: Mapping[str, int], outputs: Mapping[str, str], metadata: Mapping):
    """A NIR graph of ``nodes`` and ``edges``, with an ``Input`` per entry of ``inputs`` and an ``Output`` per entry of ``outputs``.

    Args:
        nodes: name -> NIR node.
        edges: ``(source, target)`` names; where several edges enter a node
            their signals add (NIR's convention).
        inputs: input name -> size; connect it with edges from that name.
        outputs: output name -> the node whose signal it is.
        metadata: the graph's metadata (stored under `KEY`, beside ``dt``).

    Returns:
        ``nir.NIRGraph``, type-checked.
    """
    nir = _nir()
    all_nodes = {name: nir.Input(input_type=np.array([int(n)])) for name, n in inputs.items()}
    all_nodes.update(nodes)
    edges = list(edges)
    for name, source in outputs.items():
        all_nodes[name] = nir.Output(output_type=np.array([_size(all_nodes[source])]))
        edges.append((source, name))
    return nir.NIRGraph(nodes=all_nodes, edges=edges, metadata={KEY: dict(metadata)})


def _size(node) -> int:
    shape = list(node.output_type.values())[0]
    return int(np.prod(shape))


def write(path, g) -> Path:
    """Writes a NIR graph (HDF5, NIR's own format) to ``path``; returns the path."""
    nir = _nir()
    path = Path(path)
    nir.write(str(path), g)
    return path


def read(path):
    """Reads a NIR graph; a one-line `UserError` if the file is missing or not a NIR graph."""
    nir = _nir()
    path = Path(path)
    if not path.is_file():
        raise UserError(f"{path}: no such file")
    try:
        return nir.read(str(path))
    except Exception as e:  # h5py and nir raise many types for a foreign file
        raise UserError(f"{path}: not a NIR graph ({e.__class__.__name__})") from None


def _predecessors(g, name):
    return [a for a, b in g.edges if b == name]


def unit_thresholds(g):
    """An equivalent graph whose LIF and CubaLIF nodes all have threshold 1 (and reset 0).

    For a neuron with ``v_leak = v_reset = 0`` the potential's scale is free:
    ``v / v_th`` follows the same equation with input ``I / v_th``, so each
    neuron's threshold can be moved into the rows of the ``Affine`` / ``Linear``
    nodes that feed it. Some consumers need it (snnTorch's import takes one
    threshold per layer). The spikes are the same up to rounding, by NIR's
    equations: the changed neurons lose spikejax's metadata, so `from_nir`
    reads them as NIR's nodes (no refractory period, ``v > v_th``).

    Raises:
        UserError: naming the node, if a neuron node has ``v_leak`` or
            ``v_reset`` not 0 (see `relative_potentials`) or is fed by anything
            but ``Affine`` / ``Linear`` nodes.
    """
    nir = _nir()
    nodes = dict(g.nodes)
    for name, node in g.nodes.items():
        if not isinstance(node, (nir.LIF, nir.CubaLIF)):
            continue
        if np.any(node.v_leak != 0) or np.any(node.v_reset != 0):
            raise UserError(f"NIR node {name!r}: unit_thresholds needs v_leak = v_reset = 0 (see relative_potentials)")
        theta = np.asarray(node.v_threshold, np.float32)
        for pre in _predecessors(g, name):
            syn = nodes[pre]
            if not isinstance(syn, (nir.Affine, nir.Linear)) or len([b for a, b in g.edges if a == pre]) != 1:
                raise UserError(f"NIR node {name!r}: unit_thresholds needs it fed by Affine/Linear nodes of its own")
            w = (syn.weight / theta[:, None]).astype(np.float32)
            if isinstance(syn, nir.Affine):
                nodes[pre] = nir.Affine(weight=w, bias=(syn.bias / theta).astype(np.float32), metadata=syn.metadata)
            else:
                nodes[pre] = nir.Linear(weight=w, metadata=syn.metadata)
        ones = np.ones_like(theta)
        fields = {f.name: getattr(node, f.name) for f in dataclasses.fields(node) if f.init and f.name != "metadata"}
        fields["v_threshold"] = ones
        nodes[name] = type(node)(**fields, metadata=_generic(node.metadata))
    return nir.NIRGraph(nodes=nodes, edges=list(g.edges), metadata=g.metadata)


def relative_potentials(g):
    """An equivalent graph with every LIF / CubaLIF potential measured from its ``v_leak`` (so ``v_leak = 0``).

    ``u = v - v_leak`` obeys the same equations with ``v_leak = 0``,
    ``v_threshold - v_leak`` and ``v_reset - v_leak``; a neuron at rest starts at
    ``u = 0``. (NEST's ``iaf_psc_alpha`` in mV becomes 0 at rest, 15 at threshold.)
    As in `unit_thresholds`, the changed neurons lose spikejax's metadata: the
    result is NIR's reading of the graph.
    """
    nir = _nir()
    nodes = dict(g.nodes)
    for name, node in g.nodes.items():
        if isinstance(node, (nir.LIF, nir.CubaLIF)):
            fields = {
                f.name: getattr(node, f.name) for f in dataclasses.fields(node) if f.init and f.name != "metadata"
            }
            leak = node.v_leak.astype(np.float32)
            fields.update(v_leak=np.zeros_like(leak), v_threshold=node.v_threshold - leak, v_reset=node.v_reset - leak)
            nodes[name] = type(node)(**fields, metadata=_generic(node.metadata))
    return nir.NIRGraph(nodes=nodes, edges=list(g.edges), metadata=g.metadata)


def _generic(metadata):
    """A node's metadata without spikejax's model: after a transformation, NIR's equations are what holds."""
    return {k: v for k, v in metadata.items() if k != KEY}


# ------------------------------------------------------------------------------------ import


class CubaLIFParams(NamedTuple):
    """NIR's CubaLIF as spikejax steps it (`cuba_lif_step`); every field ``(n,)``, times in the graph's unit."""

    tau_syn: jax.Array
    tau_mem: jax.Array
    r: jax.Array
    v_leak: jax.Array
    v_threshold: jax.Array
    v_reset: jax.Array
    w_in: jax.Array
    dt: jax.Array


class CubaLIFState(NamedTuple):
    """Potential ``v`` and synaptic current ``i`` of a CubaLIF population, ``(n,)`` each."""

    v: jax.Array
    i: jax.Array


def cuba_lif_step(params: CubaLIFParams, state: CubaLIFState, x: jax.Array) -> tuple[CubaLIFState, jax.Array]:
    """One step of NIR's CubaLIF, exact for an input ``x`` held over the step.

    ``tau_syn dI/dt = -I + w_in x`` and ``tau_mem dv/dt = (v_leak - v) + R I``
    are linear, so over ``h = dt`` with ``c = w_in x`` constant::

        I(t+h) = c + (I - c) a,                     a = exp(-h / tau_syn)
        v(t+h) = v_inf + (v - v_inf) b + R (I - c) k,  b = exp(-h / tau_mem)
        v_inf = v_leak + R c,  k = tau_syn (a - b) / (tau_syn - tau_mem)

    (``k = (h / tau_mem) b`` when the two time constants are equal). If
    ``v(t+h) > v_threshold`` (NIR's test) the neuron spikes and ``v`` is reset to
    ``v_reset``.

    Returns:
        The new state and the spikes, bool ``(n,)``.
    """
    h = params.dt
    c = params.w_in * x
    a = jnp.exp(-h / params.tau_syn)
    b = jnp.exp(-h / params.tau_mem)
    same = params.tau_syn == params.tau_mem
    denom = jnp.where(same, 1.0, params.tau_syn - params.tau_mem)
    k = jnp.where(same, h / params.tau_mem * b, params.tau_syn * (a - b) / denom)
    v_inf = params.v_leak + params.r * c
    v = v_inf + (state.v - v_inf) * b + params.r * (state.i - c) * k
    i = c + (state.i - c) * a
    fired = v > params.v_threshold
    return CubaLIFState(v=jnp.where(fired, params.v_reset, v), i=i), fired


# Kinds of imported node, and which of them spike.
_NEURONS = ("lif", "discrete_lif", "iaf_psc_alpha", "cuba_lif", "if")


@dataclasses.dataclass(frozen=True)
class Network:
    """The static structure of an imported NIR graph (hashable: a ``jit`` static argument).

    Nodes are stepped in ``order`` (a topological order of the graph without its
    back edges); a node reads each of its ``sources`` as computed in this step,
    except the sources of a back edge (a recurrent loop), read as computed in the
    previous step: a loop carries one step, as in Eq. (1) of the hexapod paper.
    Several sources add.

    Attributes:
        order: node names, in the order they are stepped.
        kinds: each node's kind: ``input``, ``output``, ``affine``, ``linear``,
            ``conv2d``, ``sumpool2d``, ``flatten``, ``scale``, ``delay``, or a neuron (``lif``, ``discrete_lif``,
            ``iaf_psc_alpha``, ``cuba_lif``, ``if``).
        sizes: each node's output size.
        sources: each node's sources, names.
        late: for each source, whether it is read from the previous step.
        delays: each ``delay`` node's steps (0 for other kinds).
        dt: the step, in the graph's unit of time.
        convs: each ``conv2d`` node's ``(input shape (C, H, W), stride, padding,
            dilation, groups)``, each ``sumpool2d`` node's ``(input shape, kernel,
            stride, padding)``, None for other kinds (signals stay flat between
            nodes; a convolution or pooling reshapes its input and flattens its output).
    """

    order: tuple[str, ...]
    kinds: tuple[str, ...]
    sizes: tuple[int, ...]
    sources: tuple[tuple[str, ...], ...]
    late: tuple[tuple[bool, ...], ...]
    delays: tuple[int, ...]
    dt: float
    convs: tuple = ()

    @property
    def inputs(self) -> tuple[str, ...]:
        """The names of the graph's inputs."""
        return tuple(n for n, k in zip(self.order, self.kinds) if k == "input")

    @property
    def outputs(self) -> tuple[str, ...]:
        """The names of the graph's outputs."""
        return tuple(n for n, k in zip(self.order, self.kinds) if k == "output")

    @property
    def neurons(self) -> tuple[str, ...]:
        """The names of the spiking nodes."""
        return tuple(n for n, k in zip(self.order, self.kinds) if k in _NEURONS)

    def size(self, name: str) -> int:
        """A node's output size."""
        return self.sizes[self.order.index(name)]


def _meta(node) -> dict:
    return dict(node.metadata.get(KEY, {})) if isinstance(node.metadata, Mapping) else {}


def _import_node(nir, name, node, dt):
    """``(kind, size, params, delay_steps)`` of one NIR node; a one-line UserError if unsupported."""
    meta = _meta(node)
    kind_name = type(node).__name__

    def arr(x, n=None):
        a = np.asarray(x, np.float32)
        if n is not None:
            a = a.reshape(-1) if a.size == n else np.broadcast_to(a, (n,))
        return jnp.asarray(a)

    def bad(why):
        return UserError(f"NIR node {name!r} ({kind_name}): {why}")

    if isinstance(node, nir.Input):
        n = int(np.prod(list(node.input_type.values())[0]))
        return "input", n, None, 0
    if isinstance(node, nir.Output):
        n = int(np.prod(list(node.output_type.values())[0]))
        return "output", n, None, 0
    if isinstance(node, (nir.Affine, nir.Linear)):
        w = np.asarray(node.weight)
        if w.ndim != 2:
            raise bad(f"weight of shape {w.shape}: only 2-D weights (n_out, n_in) are supported")
        if isinstance(node, nir.Affine):
            b = np.asarray(node.bias)
            if b.shape != (w.shape[0],):
                raise bad(f"bias of shape {b.shape} does not match weight {w.shape}")
            return "affine", w.shape[0], (arr(w.T), arr(b)), 0
        return "linear", w.shape[0], (arr(w.T),), 0
    if isinstance(node, nir.Conv2d):
        w = np.asarray(node.weight, np.float32)
        if w.ndim != 4 or isinstance(node.padding, str) or node.input_shape is None:
            raise bad("only 4-D weights, numeric padding and a known input shape are supported")
        (_, h, wd), stride, pad, dil, _ = _conv_static(node)
        # The output shape as torch (and lax) compute it, from the kernel's own height and width.
        out = [
            (n + 2 * p_ - d * (k - 1) - 1) // s_ + 1 for n, p_, d, k, s_ in zip((h, wd), pad, dil, w.shape[2:], stride)
        ]
        return "conv2d", int(w.shape[0] * out[0] * out[1]), (jnp.asarray(w), arr(node.bias, w.shape[0])), 0
    if isinstance(node, nir.SumPool2d):
        shape, kernel, stride, pad = _pool_static(node)
        out = [(n + 2 * p_ - k) // s_ + 1 for n, p_, k, s_ in zip(shape[1:], pad, kernel, stride)]
        return "sumpool2d", int(shape[0] * out[0] * out[1]), None, 0
    if isinstance(node, nir.Flatten):
        return "flatten", int(np.prod(list(node.input_type.values())[0])), None, 0
    if isinstance(node, nir.Scale):
        s = np.asarray(node.scale).reshape(-1)
        return "scale", s.size, (arr(s),), 0
    if isinstance(node, nir.Delay):
        d = np.asarray(node.delay, np.float64).reshape(-1)
        steps = meta.get("steps")
        if steps is None:
            steps_all = np.round(d / dt)
            if np.unique(steps_all).size != 1:
                raise bad("delays differing across its elements are not supported")
            steps = int(steps_all[0])
        if int(steps) < 1:
            raise bad(f"a delay of {d.max():g} is shorter than half a step of {dt:g}")
        return "delay", d.size, None, int(steps)
    if isinstance(node, nir.LIF):
        n = np.asarray(node.v_threshold).size
        if meta.get("model") == "discrete_lif":
            return "discrete_lif", n, DiscreteLIFParams(alpha=arr(meta["alpha"], n), v_th=arr(node.v_threshold, n)), 0
        tau = np.asarray(node.tau, np.float32)
        if np.any(tau <= 0):
            raise bad("tau must be positive")
        theta = np.asarray(node.v_threshold, np.float32)
        if meta.get("model") == "lif":
            t_ref = meta.get("t_ref_per_neuron", meta.get("t_ref", 0.0))
        else:
            # NIR fires at v > v_th; spikejax's LIF at v >= its v_th: the next float up is the same test.
            theta, t_ref = np.nextafter(theta, np.float32(np.inf)), 0.0
        p = LIFParams(
            tau=arr(tau, n),
            r=arr(node.r, n),
            v_th=arr(theta, n),
            v_reset=arr(node.v_reset, n),
            v_rest=arr(node.v_leak, n),
            t_ref=arr(t_ref, n),
            dt=jnp.asarray(np.float32(dt)),
            sigma=jnp.zeros((), jnp.float32),
        )
        return "lif", n, p, 0
    if isinstance(node, nir.IF):
        n = np.asarray(node.v_threshold).size
        if meta.get("model") == "discrete_lif":
            return "discrete_lif", n, DiscreteLIFParams(alpha=arr(meta["alpha"], n), v_th=arr(node.v_threshold, n)), 0
        return "if", n, (arr(node.r, n), arr(node.v_threshold, n), arr(node.v_reset, n), jnp.float32(dt)), 0
    if isinstance(node, nir.CubaLIF):
        n = np.asarray(node.v_threshold).size
        if meta.get("model") == "iaf_psc_alpha":
            fields = IafPscAlphaParams._fields
            return "iaf_psc_alpha", n, IafPscAlphaParams(*(arr(meta[f], n) for f in fields)), 0
        if np.any(np.asarray(node.tau_syn) <= 0) or np.any(np.asarray(node.tau_mem) <= 0):
            raise bad("tau_syn and tau_mem must be positive")
        p = CubaLIFParams(
            tau_syn=arr(node.tau_syn, n),
            tau_mem=arr(node.tau_mem, n),
            r=arr(node.r, n),
            v_leak=arr(node.v_leak, n),
            v_threshold=arr(node.v_threshold, n),
            v_reset=arr(node.v_reset, n),
            w_in=arr(node.w_in, n),
            dt=jnp.float32(dt),
        )
        return "cuba_lif", n, p, 0
    raise bad(
        "not supported; spikejax imports Input, Output, Affine, Linear, Conv2d, SumPool2d, Flatten, Scale, Delay, "
        "LIF, CubaLIF and IF nodes"
    )


def _pair(v) -> tuple[int, int]:
    v = np.asarray(v).reshape(-1)
    return (int(v[0]), int(v[-1]))


def _conv_static(node) -> tuple:
    """A Conv2d's static shape: ``(input (C, H, W), stride, padding, dilation, groups)``."""
    shape = tuple(int(v) for v in node.input_type["input"])
    return shape, _pair(node.stride), _pair(node.padding), _pair(node.dilation), int(node.groups)


def _pool_static(node) -> tuple:
    """A SumPool2d's static shape: ``(input (C, H, W), kernel, stride, padding)``."""
    shape = tuple(int(v) for v in node.input_type["input"])
    return shape, _pair(node.kernel_size), _pair(node.stride), _pair(node.padding)


def from_nir(g, *, dt: float | None = None) -> tuple[Network, dict]:
    """A NIR graph as a spikejax network: its static structure and its parameters.

    Nodes written by spikejax (their ``metadata["spikejax"]``) come back as the
    model they were (LIF with its refractory period, ``iaf_psc_alpha``, the
    hexapod's discrete LIF), so a round trip gives the same spikes bit for bit.
    Other nodes are run by NIR's equations, with the input held over each step
    of ``dt`` (module docstring): LIF by `spikejax.neurons.lif_step` (exact
    over the step, no refractory period, NIR's ``v > v_th``), CubaLIF by
    `cuba_lif_step`, IF as ``v += R x dt``, firing at ``v > v_th``.

    Args:
        g: the ``nir.NIRGraph`` (or a path to one).
        dt: the step, in the graph's unit of time; default the graph's
            ``metadata["spikejax"]["dt"]``, required if it has none.

    Returns:
        ``(network, params)``: the static `Network` and a dict of each node's
        parameters (arrays, traced), for `network_init` and `network_step`.

    Raises:
        UserError: in one line naming the node, for an unsupported node
            (a nested graph, pooling, ...), a bad shape or an edge to nowhere.
    """
    nir = _nir()
    if isinstance(g, (str, Path)):
        g = read(g)
    if not isinstance(g, nir.NIRGraph):
        raise UserError(f"expected a NIR graph, got {type(g).__name__}")
    meta = _meta(g)
    if dt is None:
        dt = meta.get("dt")
    if dt is None:
        raise UserError("the NIR graph states no time step (metadata spikejax.dt): pass dt")
    dt = float(dt)
    if not dt > 0:
        raise UserError(f"dt must be positive, got {dt}")
    for a, b in g.edges:
        for end in (a, b):
            if end not in g.nodes:
                raise UserError(f"NIR edge ({a!r}, {b!r}): no node named {end!r}")
    info = {name: _import_node(nir, name, node, dt) for name, node in g.nodes.items()}

    # Topological order by depth-first search; an edge into a node on the current path is a back edge.
    succ = {name: [b for a, b in g.edges if a == name] for name in g.nodes}
    back, done, on_path, post = set(), set(), set(), []

    def visit(u):
        on_path.add(u)
        for v in succ[u]:
            if v in on_path:
                back.add((u, v))
            elif v not in done:
                visit(v)
        on_path.discard(u)
        done.add(u)
        post.append(u)

    starts = [n for n, (k, *_) in info.items() if k == "input"] + list(g.nodes)
    for s in starts:
        if s not in done:
            visit(s)
    order = tuple(reversed(post))
    sources, late = [], []
    for name in order:
        pre = [a for a, b in g.edges if b == name]
        sources.append(tuple(pre))
        late.append(tuple((a, name) in back for a in pre))
        kind, size = info[name][0], info[name][1]
        for a in pre:
            if kind == "conv2d":
                c = _conv_static(g.nodes[name])
                if info[a][1] != int(np.prod(c[0])):
                    raise UserError(
                        f"NIR node {name!r}: input from {a!r} has size {info[a][1]}, the convolution {c[0]}"
                    )
                continue
            if kind == "sumpool2d":
                c = _pool_static(g.nodes[name])
                if info[a][1] != int(np.prod(c[0])):
                    raise UserError(f"NIR node {name!r}: input from {a!r} has size {info[a][1]}, the pooling {c[0]}")
                continue
            if kind == "flatten" and info[a][1] == size:
                continue
            if info[a][1] != size and kind not in ("affine", "linear"):
                raise UserError(f"NIR node {name!r}: input from {a!r} has size {info[a][1]}, the node {size}")
            if kind in ("affine", "linear") and info[a][1] != info[name][2][0].shape[0]:
                raise UserError(
                    f"NIR node {name!r}: input from {a!r} has size {info[a][1]}, weight expects {info[name][2][0].shape[0]}"
                )
        if kind == "input" and pre:
            raise UserError(f"NIR node {name!r}: an Input has incoming edges")
        if kind != "input" and not pre:
            raise UserError(f"NIR node {name!r} ({type(g.nodes[name]).__name__}): no incoming edge")
    net = Network(
        order=order,
        kinds=tuple(info[n][0] for n in order),
        sizes=tuple(info[n][1] for n in order),
        sources=tuple(sources),
        late=tuple(late),
        delays=tuple(info[n][3] for n in order),
        dt=dt,
        convs=tuple(
            _conv_static(g.nodes[n])
            if info[n][0] == "conv2d"
            else _pool_static(g.nodes[n])
            if info[n][0] == "sumpool2d"
            else None
            for n in order
        ),
    )
    params = {n: info[n][2] for n in order if info[n][2] is not None}
    return net, params


def network_init(net: Network, params: dict) -> dict:
    """Every node at rest: neurons at their resting potential, delay lines empty, last outputs 0.

    Returns:
        The state, a dict of ``"out"`` (each node's output of the last step,
        ``(size,)`` float32) and ``"node"`` (each stateful node's state).
    """
    out, node = {}, {}
    for name, kind, size, steps in zip(net.order, net.kinds, net.sizes, net.delays):
        out[name] = jnp.zeros((size,), jnp.float32)
        p = params.get(name)
        if kind == "lif":
            node[name] = LIFState(v=jnp.broadcast_to(p.v_rest, (size,)), refractory=jnp.zeros((size,), jnp.float32))
        elif kind == "discrete_lif":
            node[name] = DiscreteLIFState(v=jnp.zeros((size,), jnp.float32))
        elif kind == "iaf_psc_alpha":
            node[name] = iaf_psc_alpha_init(size, p)
        elif kind == "cuba_lif":
            node[name] = CubaLIFState(v=jnp.broadcast_to(p.v_leak, (size,)), i=jnp.zeros((size,), jnp.float32))
        elif kind == "if":
            node[name] = jnp.zeros((size,), jnp.float32)
        elif kind == "delay":
            node[name] = delay_init(size, steps, jnp.float32)
    return {"out": out, "node": node}


def network_step(net: Network, params: dict, state: dict, inputs: Mapping[str, jax.Array]) -> tuple[dict, dict]:
    """One step of an imported network (one instance; ``jax.vmap`` adds a batch).

    Args:
        net: the structure (static).
        params: the nodes' parameters (`from_nir`).
        state: the state (`network_init`).
        inputs: this step's signal for each graph input, ``(size,)``: currents,
            or spike counts (a unit a spike, held for the step).

    Returns:
        The new state and every node's output of this step (spikes as float 0/1),
        by name; the graph's outputs under their ``Output`` names.
    """
    now = {}
    node_state = dict(state["node"])
    for name, kind, srcs, late in zip(net.order, net.kinds, net.sources, net.late):
        if kind == "input":
            now[name] = jnp.asarray(inputs[name], jnp.float32).reshape(-1)
            continue
        xs = [state["out"][s] if is_late else now[s] for s, is_late in zip(srcs, late)]
        p = params.get(name)
        if kind in ("affine", "linear"):
            y = None
            for x in xs:
                y = x @ p[0] if y is None else y + x @ p[0]
            now[name] = y + p[1] if kind == "affine" else y
            continue
        x = xs[0]
        for more in xs[1:]:
            x = x + more
        if kind == "conv2d":
            shape, stride, pad, dilation, groups = net.convs[net.order.index(name)]
            y = jax.lax.conv_general_dilated(
                x.reshape((1, *shape)),
                p[0],
                window_strides=stride,
                padding=[(pad[0], pad[0]), (pad[1], pad[1])],
                rhs_dilation=dilation,
                feature_group_count=groups,
                dimension_numbers=("NCHW", "OIHW", "NCHW"),
            )[0]
            now[name] = (y + p[1][:, None, None]).reshape(-1)
        elif kind == "sumpool2d":
            shape, kernel, stride, pad = net.convs[net.order.index(name)]
            y = jax.lax.reduce_window(
                x.reshape(shape),
                0.0,
                jax.lax.add,
                (1, *kernel),
                (1, *stride),
                [(0, 0), (pad[0], pad[0]), (pad[1], pad[1])],
            )
            now[name] = y.reshape(-1)
        elif kind in ("output", "flatten"):
            now[name] = x
        elif kind == "scale":
            now[name] = x * p[0]
        elif kind == "delay":
            node_state[name], now[name] = delay_step(node_state[name], x)
        elif kind == "lif":
            node_state[name], s = lif_step(p, node_state[name], x)
            now[name] = s.astype(jnp.float32)
        elif kind == "discrete_lif":
            node_state[name], now[name] = discrete_lif_step(p, node_state[name], x)
        elif kind == "iaf_psc_alpha":
            # NEST sorts each arriving event by its weight's sign; for a summed input this is exact
            # when a step's inputs to a neuron share one sign (all excitatory in the snake).
            ex, inh = jnp.maximum(x, 0.0), jnp.minimum(x, 0.0)
            node_state[name], s = iaf_psc_alpha_step(p, node_state[name], ex, inh, net.dt)
            now[name] = s.astype(jnp.float32)
        elif kind == "cuba_lif":
            node_state[name], s = cuba_lif_step(p, node_state[name], x)
            now[name] = s.astype(jnp.float32)
        elif kind == "if":
            r, v_th, v_reset, dt = p
            v = node_state[name] + r * x * dt
            fired = v > v_th
            node_state[name] = jnp.where(fired, v_reset, v)
            now[name] = fired.astype(jnp.float32)
    return {"out": now, "node": node_state}, now


def network_run(net: Network, params: dict, state: dict, inputs: Mapping[str, jax.Array]) -> tuple[dict, dict]:
    """`network_step` scanned over ``inputs`` of shape ``(n_steps, size)`` each.

    Returns:
        The final state and the outputs of every node, ``(n_steps, size)`` each.
    """

    def step(s, x):
        return network_step(net, params, s, x)

    return jax.lax.scan(step, state, dict(inputs))
