"""Reward-modulated STDP, Eq. (6)-(8) of the snake R-STDP paper, as NEST 3.10's ``stdp_dopamine_synapse``.

The paper ran its networks in NEST, so its R-STDP is NEST's ``stdp_dopamine_synapse``
(Potjans et al. 2010). The model, in NEST's names and units (ms; weights in NEST
units, ``dw/dt`` per ms):

* pre trace ``K_plus``: +1 per presynaptic spike, decays with ``tau_plus``;
* post trace ``K_minus``: +1 per postsynaptic spike, decays with ``tau_minus`` (in
  NEST a parameter of the postsynaptic neuron, default 20 ms); the synapse sees post
  spikes one dendritic delay ``d`` late;
* eligibility ``c`` (Eq. (6) of the snake R-STDP paper, ``C_1`` absorbed in ``A_plus``,
  ``A_minus``): at each post spike arriving at ``t`` (emitted at ``t - d``),
  ``c += A_plus * K_plus(t)`` with ``K_plus`` of the pre spikes strictly before ``t``;
  at each pre spike at ``t``, ``c -= A_minus * K_minus(t - d)`` with ``K_minus`` of the
  post spikes emitted strictly before ``t - d``; all-to-all pairing, so a pre spike and
  a post arrival at the same instant do not pair; between spikes ``dc/dt = -c / tau_c``;
* dopamine ``n`` (Eq. (7) of the snake R-STDP paper, ``C_2 = 1``): ``+= m / tau_n`` for
  ``m`` dopamine spikes reaching the volume transmitter, decays with ``tau_n``;
* weight (Eq. (8) of the snake R-STDP paper): ``dw/dt = c (n - b)``, integrated in closed
  form over each interval without spikes (`_weight_piece`) and clipped to
  ``[Wmin, Wmax]`` after each interval.

NEST does not integrate this model at every spike's own time. It updates a synapse
lazily, at its update points, and the order of those points changes the result:

1. Delivery order. A spike emitted in a min-delay slice ``(T - min_delay, T]`` is
   delivered (its synapses updated) at the start of the next slice, after the volume
   transmitter's trigger at ``T`` (every ``deliver_interval * min_delay``) has brought
   every synapse to ``T``. The pre spike at ``t < T`` then integrates ``w``, ``c`` and
   ``K_plus`` back from ``T`` to ``t`` (with ``n`` of ``T`` extrapolated back, so a dopamine
   spike or a ``SetStatus`` of ``n`` in ``(t, T]`` acts as if before ``t``), and a post
   arrival in ``(t, T]``, paired at the trigger without this pre spike, is paired again
   with it at the next update point: NEST reads that stretch of the post history twice.
2. History pruning. The postsynaptic neuron drops a history entry once every incoming
   STDP synapse has read it and the next entry is more than ``max_delay + min_delay``
   older than a new post spike; a pruned entry is not read twice.
3. Clipping only at the ends of NEST's pieces (dopamine spikes, post arrivals, update
   points), not in between.

These are not small. With one synapse, pre and post at 100 Hz each (random, 1 s,
``tau_c`` 300 ms, ``tau_n`` 40 ms, NEST defaults otherwise) NEST ends with ``c`` about
16 % less negative than the exact-time model; at 500 Hz its largest ``c`` is three
times the model's. So this module gives:

* `rstdp` with ``schedule="nest"`` (default): a time-driven rule, one update per
  neural step for a dense group, that performs NEST's update points at NEST's steps
  (delivery at slice starts, triggers at slice ends, pruning), and so equals NEST's
  ``GetStatus`` of every connection at every step to rounding;
* `rstdp` with ``schedule="exact"``: the model itself, every spike at its own time,
  closed form per step, clipping every step; equal to NEST when every pre spike falls
  on a slice end (a multiple of the min delay), up to point 3;
* `replay`: NEST's schedule for one synapse as an event loop in float64, following
  NEST's algorithm step by step, separately from the time-driven code (but with the
  same maths, `_advance`), to check both against NEST.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from spikejax.errors import UserError
from spikejax.plasticity.base import PlasticityRule

__all__ = ["RSTDPParams", "RSTDPState", "RSTDPNestState", "rstdp_params", "rstdp", "set_dopamine", "replay"]

_NEST_DEFAULTS = {
    "A_plus": 1.0,
    "A_minus": 1.5,
    "tau_plus": 20.0,
    "tau_c": 1000.0,
    "tau_n": 200.0,
    "b": 0.0,
    "Wmin": 0.0,
    "Wmax": 200.0,
}
_STDP_EPS = 1e-6  # NEST's stdp_eps, ms: spike times closer than this count as simultaneous.


class RSTDPParams(NamedTuple):
    """Parameters of one group of R-STDP synapses, NEST's names and units.

    Every field is a scalar array (traced), so ``jax.vmap`` over a batch of parameter
    sets compiles once.

    Attributes:
        A_plus: eligibility jump per pre-before-post pairing, times ``K_plus``.
        A_minus: eligibility drop per post-before-pre pairing, times ``K_minus``.
        tau_plus: decay of the presynaptic trace ``K_plus``, ms.
        tau_minus: decay of the postsynaptic trace ``K_minus``, ms (in NEST the
            postsynaptic neuron's ``tau_minus``).
        tau_c: decay of the eligibility ``c`` (Eq. (6) of the snake R-STDP paper), ms.
        tau_n: decay of the dopamine ``n`` (Eq. (7) of the snake R-STDP paper), ms.
        b: dopamine baseline of Eq. (8) of the snake R-STDP paper.
        Wmin: lower weight bound.
        Wmax: upper weight bound.
    """

    A_plus: jax.Array
    A_minus: jax.Array
    tau_plus: jax.Array
    tau_minus: jax.Array
    tau_c: jax.Array
    tau_n: jax.Array
    b: jax.Array
    Wmin: jax.Array
    Wmax: jax.Array


class RSTDPState(NamedTuple):
    """State of one group of R-STDP synapses at the end of a neural step ``t``.

    Attributes:
        k_plus: ``(n_pre,)`` presynaptic traces ``K_plus(t)``, this step's spikes included.
        k_minus: ``(n_post,)`` postsynaptic traces as the synapse sees them,
            ``K_minus(t - d)``, post spikes emitted up to ``t - d`` included.
        c: ``(n_pre, n_post)`` eligibility traces.
        n: ``(n_post,)`` dopamine per postsynaptic neuron (all synapses onto a neuron
            share it).
        post_line: ``(delay_steps, n_post)`` post spike counts on their way along the
            dendritic delay; row 0 arrives next step.
    """

    k_plus: jax.Array
    k_minus: jax.Array
    c: jax.Array
    n: jax.Array
    post_line: jax.Array


def rstdp_params(
    *,
    A_plus=1.0,
    A_minus=1.5,
    tau_plus=20.0,
    tau_minus=20.0,
    tau_c=1000.0,
    tau_n=200.0,
    b=0.0,
    Wmin=0.0,
    Wmax=200.0,
    dtype=jnp.float32,
) -> RSTDPParams:
    """`RSTDPParams` with NEST 3.10's defaults, every field a scalar of ``dtype``.

    Raises:
        UserError: a time constant that is not positive, or ``Wmin > Wmax`` (checked
            when the values are concrete).
    """
    values = dict(
        A_plus=A_plus,
        A_minus=A_minus,
        tau_plus=tau_plus,
        tau_minus=tau_minus,
        tau_c=tau_c,
        tau_n=tau_n,
        b=b,
        Wmin=Wmin,
        Wmax=Wmax,
    )
    _check(values, "rstdp_params")
    return RSTDPParams(**{k: jnp.asarray(v, dtype) for k, v in values.items()})


def _check(values, where):
    concrete = {k: v for k, v in values.items() if not isinstance(v, jax.core.Tracer)}
    for name in ("tau_plus", "tau_minus", "tau_c", "tau_n"):
        if name in concrete and np.any(np.asarray(concrete[name]) <= 0):
            raise UserError(f"{where}: {name} must be > 0 ms, got {concrete[name]}")
    if (
        "Wmin" in concrete
        and "Wmax" in concrete
        and np.any(np.asarray(concrete["Wmin"]) > np.asarray(concrete["Wmax"]))
    ):
        raise UserError(f"{where}: Wmin {concrete['Wmin']} is above Wmax {concrete['Wmax']}")


def _weight_piece(c0, n0, delta, p, xp):
    """Eq. (8) of the snake R-STDP paper over ``delta`` ms without spikes, in closed form.

    With ``c = c0 exp(-s / tau_c)`` and ``n = n0 exp(-s / tau_n)``,
    ``w(delta) - w(0) = c0 n0 tau_s (1 - exp(-delta / tau_s)) - b c0 tau_c (1 - exp(-delta / tau_c))``,
    ``1 / tau_s = 1 / tau_c + 1 / tau_n``, written with ``expm1`` as NEST writes it. A
    negative ``delta`` integrates backwards, as NEST does for late-delivered spikes.
    """
    inv_tau_s = (p.tau_c + p.tau_n) / (p.tau_c * p.tau_n)
    return -c0 * (n0 / inv_tau_s * xp.expm1(-inv_tau_s * delta) - p.b * p.tau_c * xp.expm1(-delta / p.tau_c))


def _advance(w, c, n, delta, p, xp):
    """``w``, ``c``, ``n`` after ``delta`` ms without spikes; ``w`` clipped to ``[Wmin, Wmax]``."""
    w = xp.clip(w + _weight_piece(c, n, delta, p, xp), p.Wmin, p.Wmax)
    return w, c * xp.exp(-delta / p.tau_c), n * xp.exp(-delta / p.tau_n)


def rstdp(
    n_pre: int,
    n_post: int,
    *,
    delay_steps: int = 10,
    schedule: str = "nest",
    min_delay_steps: int | None = None,
    deliver_interval: int = 1,
    max_delay_steps: int | None = None,
    n_incoming: int | None = None,
) -> PlasticityRule:
    """The time-driven R-STDP rule of Eq. (6)-(8) of the snake R-STDP paper for a dense group.

    One ``update`` is one neural step of length ``dt`` ending at ``t``; the step's spikes
    are stamped ``t`` (as NEST stamps them). Spike counts above 1 act as that many
    spikes at the same time (NEST unrolls multiplicities).

    ``schedule="exact"``, per step: (1) post spikes emitted ``delay_steps`` steps ago
    arrive; (2) ``w``, ``c``, ``n`` and both traces advance over ``dt`` in closed form
    (`_advance`), ``w`` clipped; (3) each arrival raises ``c`` by ``A_plus * K_plus``
    (pre spikes before ``t``); (4) each pre spike lowers ``c`` by ``A_minus * K_minus``
    (post spikes emitted before ``t - d``); (5) ``K_plus += pre``, ``K_minus +=
    arrivals``, ``n += dopamine / tau_n``. ``state.c`` is the eligibility at ``t``.

    ``schedule="nest"``, per step: at the start of a min-delay slice, NEST's ``send``
    for each pre spike of the previous slice, in time order; the post spikes of the
    step enter the post history (pruning it); at the end of every ``deliver_interval``
    slices, NEST's ``trigger_update_weight`` for every synapse. ``weights + dw`` and
    ``state.c`` are then NEST's stored weight and ``c`` (``GetStatus``) after
    ``Simulate`` up to ``t``, and ``state.n`` is ``n`` at the last trigger. The weight
    NEST transmits a pre spike with is the one after that spike's delivery, one slice
    later. Slice starts and ends run one lazy update (a scan over ``(deliver_interval
    + 1) * min_delay_steps`` steps) under a ``cond``; other steps skip it, unless
    ``vmap`` batches the step counter, which turns the ``cond`` into a select that pays
    for it every step. All members of a batch share the step, so keep it unbatched::

        axes = RSTDPNestState(*[0] * len(RSTDPNestState._fields))._replace(step=None, t_trig=None)
        step = jax.vmap(rule.update, in_axes=(None, axes, 0, 0, 0, 0, None), out_axes=(0, axes))

    with ``init``'s ``step`` and ``t_trig`` left unbatched (``s._replace(step=s.step[0],
    t_trig=s.t_trig[0])`` after ``jax.vmap(rule.init)``).

    `set_dopamine` acts like ``SetStatus({"n": r})`` between two ``Simulate`` calls: on
    the NEST schedule ``n`` is set as of the last trigger (NEST's ``n`` is referenced
    there as long as no dopamine spike has been processed since), so set it at
    trigger times (the authors' 20 ms control steps are) to set ``n`` itself.

    Args:
        n_pre: number of presynaptic neurons.
        n_post: number of postsynaptic neurons.
        delay_steps: the synapses' dendritic delay in neural steps (NEST's ``delay``
            divided by the resolution), >= 1.
        schedule: ``"nest"`` (NEST's update points) or ``"exact"`` (every spike at its time).
        min_delay_steps: NEST's min delay (of the whole network) in steps, default
            ``delay_steps``; the slice length.
        deliver_interval: the volume transmitter's ``deliver_interval``, in slices.
        max_delay_steps: NEST's max delay (of the whole network) in steps, default
            ``delay_steps``; sets when the post history is pruned.
        n_incoming: STDP synapses onto each postsynaptic neuron, default ``n_pre`` (more
            if the neuron has other plastic afferents); sets when the post history is
            pruned.

    Returns:
        ``PlasticityRule(init, update)``: ``init(weights) -> state`` (`RSTDPState` for
        ``"exact"``, `RSTDPNestState` for ``"nest"``; all traces 0)
        and ``update(params, state, weights, pre, post, dopamine, dt) -> (dw, state)``,
        ``weights`` and ``dw`` ``(n_pre, n_post)``, ``pre`` ``(n_pre,)`` and ``post``
        ``(n_post,)`` spike counts of this step, ``dopamine`` the scalar count of dopamine
        spikes reaching the volume transmitter this step (0 when ``n`` is set with
        `set_dopamine` instead), ``dt`` the step in ms. ``weights + dw`` is clipped to
        ``[Wmin, Wmax]``.

    Raises:
        UserError: a size or step count below 1, ``min_delay_steps > delay_steps``,
            ``max_delay_steps < delay_steps``, ``n_incoming < n_pre``, an unknown schedule.

    Examples:
        >>> rule = rstdp(1, 1, delay_steps=1, schedule="exact")
        >>> p = rstdp_params()
        >>> w = jnp.full((1, 1), 10.0)
        >>> s = rule.init(w)
        >>> _, s = rule.update(p, s, w, jnp.ones(1), jnp.zeros(1), 0.0, 0.1)
        >>> _, s = rule.update(p, s, w, jnp.zeros(1), jnp.ones(1), 0.0, 0.1)
        >>> _, s = rule.update(p, s, w, jnp.zeros(1), jnp.zeros(1), 0.0, 0.1)
        >>> round(float(s.c[0, 0]), 6)  # the post spike of 0.2 ms arrives at 0.3 ms
        0.99005
    """
    md = delay_steps if min_delay_steps is None else min_delay_steps
    for name, v in (
        ("n_pre", n_pre),
        ("n_post", n_post),
        ("delay_steps", delay_steps),
        ("min_delay_steps", md),
        ("deliver_interval", deliver_interval),
    ):
        if not isinstance(v, (int, np.integer)) or v < 1:
            raise UserError(f"rstdp: {name} must be an integer >= 1, got {v!r}")
    if md > delay_steps:
        raise UserError(f"rstdp: min_delay_steps {md} is above delay_steps {delay_steps}")
    max_delay = delay_steps if max_delay_steps is None else max_delay_steps
    n_in = n_pre if n_incoming is None else n_incoming
    if max_delay < delay_steps or n_in < n_pre:
        raise UserError(f"rstdp: max_delay_steps {max_delay} below delay_steps or n_incoming {n_in} below n_pre")
    if schedule == "nest":
        return _nest_schedule_rule(n_pre, n_post, delay_steps, md, deliver_interval, max_delay, n_in)
    if schedule != "exact":
        raise UserError(f"rstdp: schedule must be 'nest' or 'exact', got {schedule!r}")

    def init(weights: jax.Array) -> RSTDPState:
        if weights.shape != (n_pre, n_post):
            raise UserError(f"rstdp: weights of shape {weights.shape}, expected {(n_pre, n_post)}")
        dtype = weights.dtype if jnp.issubdtype(weights.dtype, jnp.floating) else jnp.float32
        return RSTDPState(
            k_plus=jnp.zeros((n_pre,), dtype),
            k_minus=jnp.zeros((n_post,), dtype),
            c=jnp.zeros((n_pre, n_post), dtype),
            n=jnp.zeros((n_post,), dtype),
            post_line=jnp.zeros((delay_steps, n_post), dtype),
        )

    def update(params, state, weights, pre, post, dopamine, dt):
        dtype = state.c.dtype
        pre = jnp.asarray(pre, dtype)
        post = jnp.asarray(post, dtype)
        arrived = state.post_line[0]
        w, c, n = _advance(weights, state.c, state.n[None, :], dt, params, jnp)
        k_plus = state.k_plus * jnp.exp(-dt / params.tau_plus)
        k_minus = state.k_minus * jnp.exp(-dt / params.tau_minus)
        c = c + params.A_plus * k_plus[:, None] * arrived[None, :] - params.A_minus * pre[:, None] * k_minus[None, :]
        new = RSTDPState(
            k_plus=k_plus + pre,
            k_minus=k_minus + arrived,
            c=c.astype(dtype),
            n=(n[0] + jnp.asarray(dopamine, dtype) / params.tau_n).astype(dtype),
            post_line=jnp.concatenate([state.post_line[1:], post[None, :]], axis=0),
        )
        return (w - weights).astype(weights.dtype), new

    return PlasticityRule(init, update)


def set_dopamine(state, n):
    """``state`` (`RSTDPState` or `RSTDPNestState`) with every postsynaptic neuron's dopamine set to ``n``.

    The authors' group sets ``n`` on every connection once per control step
    (``SetStatus(conns, {"n": r})``); call this between two `rstdp` updates, where
    ``SetStatus`` comes between two ``Simulate`` calls (see `rstdp` for the NEST
    schedule). ``n`` is a scalar or ``(n_post,)`` (the reward of each postsynaptic neuron).
    """
    return state._replace(n=jnp.broadcast_to(jnp.asarray(n, state.n.dtype), state.n.shape))


class _NestSynapse:
    """One ``stdp_dopamine_synapse``, its postsynaptic archive and volume transmitter, as NEST runs them."""

    def __init__(self, p, w0, d, max_delay, min_delay, n0):
        self.p, self.d, self.prune_after = p, d, max_delay + min_delay + _STDP_EPS
        self.w, self.c, self.n, self.kplus, self.t_last = float(w0), 0.0, float(n0), 0.0, 0.0
        self.dopa = [(0.0, 0.0)]  # the volume transmitter's list, a pseudo spike at the last trigger first
        self.idx = 0
        self.history = []  # [t, K_minus, access_counter] of the postsynaptic neuron
        self.kminus, self.last_post = 0.0, -1.0

    # The postsynaptic neuron (ArchivingNode::set_spiketime, get_history, get_K_value).
    def post_spike(self, t):
        while len(self.history) > 1 and self.history[0][2] >= 1 and t - self.history[1][0] > self.prune_after:
            self.history.pop(0)
        self.kminus = self.kminus * math.exp((self.last_post - t) / float(self.p.tau_minus)) + 1.0
        self.last_post = t
        self.history.append([t, self.kminus, 0])

    def get_history(self, t1, t2):
        out = [h for h in self.history if t1 + _STDP_EPS <= h[0] < t2 + _STDP_EPS]
        for h in out:
            h[2] += 1
        return out

    def k_value(self, t):
        for h in reversed(self.history):
            if t - h[0] > _STDP_EPS:
                return h[1] * math.exp((h[0] - t) / float(self.p.tau_minus))
        return 0.0

    # The synapse (stdp_dopamine_synapse.h).
    def _piece(self, c0, n0, minus_dt):
        self.w, _, _ = _advance(self.w, c0, n0, -minus_dt, self.p, np)
        self.w = float(self.w)

    def _dopamine_step(self):
        (t_a, _), (t_b, m) = self.dopa[self.idx], self.dopa[self.idx + 1]
        self.idx += 1
        self.n = self.n * math.exp((t_a - t_b) / float(self.p.tau_n)) + m / float(self.p.tau_n)

    def _pending(self, t1):
        return len(self.dopa) > self.idx + 1 and t1 - self.dopa[self.idx + 1][0] > -_STDP_EPS

    def process_dopa(self, t0, t1):
        tau_c, tau_n = float(self.p.tau_c), float(self.p.tau_n)
        if self._pending(t1):
            n0 = self.n * math.exp((self.dopa[self.idx][0] - t0) / tau_n)
            self._piece(self.c, n0, t0 - self.dopa[self.idx + 1][0])
            self._dopamine_step()
            while self._pending(t1):
                cd = self.c * math.exp((t0 - self.dopa[self.idx][0]) / tau_c)
                self._piece(cd, self.n, self.dopa[self.idx][0] - self.dopa[self.idx + 1][0])
                self._dopamine_step()
            cd = self.c * math.exp((t0 - self.dopa[self.idx][0]) / tau_c)
            self._piece(cd, self.n, self.dopa[self.idx][0] - t1)
        else:
            n0 = self.n * math.exp((self.dopa[self.idx][0] - t0) / tau_n)
            self._piece(self.c, n0, t0 - t1)
        self.c = self.c * math.exp((t0 - t1) / tau_c)

    def _facilitations(self, t_end, t_spike=None):
        t0 = self.t_last
        for h in self.get_history(self.t_last - self.d, t_end - self.d):
            self.process_dopa(t0, h[0] + self.d)
            t0 = h[0] + self.d
            if t_spike is None or t_spike - h[0] > _STDP_EPS:
                self.c += float(self.p.A_plus) * self.kplus * math.exp((self.t_last - t0) / float(self.p.tau_plus))
        return t0

    def send(self, t_spike):
        t0 = self._facilitations(t_spike, t_spike)
        self.process_dopa(t0, t_spike)
        self.c -= float(self.p.A_minus) * self.k_value(t_spike - self.d)
        self.kplus = self.kplus * math.exp((self.t_last - t_spike) / float(self.p.tau_plus)) + 1.0
        self.t_last = t_spike

    def trigger(self, t_trig):
        t0 = self._facilitations(t_trig)
        self.process_dopa(t0, t_trig)
        self.n = self.n * math.exp((self.dopa[self.idx][0] - t_trig) / float(self.p.tau_n))
        self.kplus = self.kplus * math.exp((self.t_last - t_trig) / float(self.p.tau_plus))
        self.t_last = t_trig
        self.dopa = [(t_trig, 0.0)]
        self.idx = 0


def _steps(times_ms, h, name, n_steps):
    steps = np.rint(np.asarray(times_ms, np.float64).ravel() / h).astype(np.int64)
    if steps.size and (np.any(np.abs(steps * h - np.asarray(times_ms).ravel()) > 1e-6) or steps.min() < 1):
        raise UserError(f"replay: {name} spike times must be positive multiples of the resolution {h} ms")
    return np.bincount(steps, minlength=n_steps + 2)


def replay(
    params: dict,
    pre_ms,
    post_ms,
    dopa_ms,
    *,
    w0,
    t_sim_ms,
    resolution_ms=0.1,
    delay_ms=1.0,
    tau_minus_ms=20.0,
    dopa_delay_ms=None,
    min_delay_ms=None,
    max_delay_ms=None,
    deliver_interval=1,
    n_set=(),
    n0=0.0,
):
    """One NEST ``stdp_dopamine_synapse`` replayed on NEST 3.10's own schedule, in float64.

    NEST's schedule and its consequences are in the module docstring. The network
    replayed: a presynaptic and a postsynaptic neuron (parrots, say) with
    the plastic synapse between them (``delay_ms``; on a receptor that does not make
    the postsynaptic neuron fire), and a dopamine neuron connected to the synapse's
    volume transmitter (``dopa_delay_ms``). Neurons are created before the volume
    transmitter, so NEST updates them first in each slice. The schedule, per min-delay
    slice ``(T - min_delay, T]``: the pre spikes of the previous slice are delivered
    (processed) at its start, post spikes are archived as they happen, and the volume
    transmitter collects dopamine and, when ``T`` is a multiple of
    ``deliver_interval * min_delay``, brings every synapse to ``T``; the post history is
    pruned as NEST prunes it (one incoming STDP synapse). The maths is the
    time-driven rule's (`_advance`).

    Args:
        params: NEST's parameter names of the synapse model (``A_plus``, ``A_minus``,
            ``tau_plus``, ``tau_c``, ``tau_n``, ``b``, ``Wmin``, ``Wmax``); missing ones take
            NEST's defaults.
        pre_ms, post_ms, dopa_ms: spike times (ms) of the pre, post and dopamine
            neurons as NEST's spike recorders report them; repeated times are
            multiplicities.
        w0: initial weight.
        t_sim_ms: simulated time, ms.
        resolution_ms: NEST's resolution, ms.
        delay_ms: the plastic synapse's (dendritic) delay, ms.
        tau_minus_ms: the postsynaptic neuron's ``tau_minus``, ms.
        dopa_delay_ms: delay from the dopamine neuron to the volume transmitter, ms
            (default ``delay_ms``).
        min_delay_ms, max_delay_ms: the network's smallest and largest delay (default:
            the smallest and largest of ``delay_ms`` and ``dopa_delay_ms``).
        deliver_interval: the volume transmitter's ``deliver_interval``, in min delays.
        n_set: ``(t_ms, n)`` pairs: ``SetStatus({"n": n})`` on the connection after
            ``Simulate`` up to ``t_ms``.
        n0: the connection's initial ``n``.

    Returns:
        ``(t_ms, w, c, n)``, numpy float64 arrays of length ``t_sim_ms / resolution_ms``:
        ``t_ms = resolution, 2 resolution, ..., t_sim_ms`` and what ``GetStatus`` of the
        connection reports after ``Simulate`` up to ``t_ms`` (NEST's stored values: ``c``
        at the last update point, ``n`` at the last dopamine spike or trigger; a value
        ``n_set`` sets at ``t`` shows from the next step on, as ``GetStatus`` before
        ``SetStatus``).

    Raises:
        UserError: spike times off the resolution grid, delays that are not multiples
            of it or below ``min_delay_ms``.
    """
    h = float(resolution_ms)
    unknown = set(params) - set(_NEST_DEFAULTS)
    if unknown:
        raise UserError(f"replay: unknown synapse parameters {sorted(unknown)}")
    values = {**_NEST_DEFAULTS, **params, "tau_minus": tau_minus_ms}
    _check(values, "replay")
    p = RSTDPParams(**{k: np.float64(v) for k, v in values.items()})
    dopa_delay_ms = delay_ms if dopa_delay_ms is None else dopa_delay_ms
    min_delay_ms = min(delay_ms, dopa_delay_ms) if min_delay_ms is None else min_delay_ms
    max_delay_ms = max(delay_ms, dopa_delay_ms) if max_delay_ms is None else max_delay_ms
    to_steps = {}
    for name, v in (("delay_ms", delay_ms), ("dopa_delay_ms", dopa_delay_ms), ("min_delay_ms", min_delay_ms)):
        to_steps[name] = int(round(v / h))
        if to_steps[name] < 1 or abs(to_steps[name] * h - v) > 1e-9:
            raise UserError(f"replay: {name} {v} must be a positive multiple of the resolution {h} ms")
    if min_delay_ms > min(delay_ms, dopa_delay_ms) + 1e-9:
        raise UserError(f"replay: min_delay_ms {min_delay_ms} is above a delay of the network")
    md = to_steps["min_delay_ms"]
    n_steps = int(round(t_sim_ms / h))
    pre = _steps(pre_ms, h, "pre", n_steps)
    post = _steps(post_ms, h, "post", n_steps)
    dopa_arrival = _steps(np.asarray(dopa_ms, np.float64) + dopa_delay_ms, h, "dopamine", n_steps)
    sets = {}
    for t, value in n_set:
        sets[int(round(t / h))] = float(value)

    syn = _NestSynapse(p, w0, float(delay_ms), float(max_delay_ms), float(min_delay_ms), n0)
    out = np.zeros((3, n_steps))
    for s in range(1, n_steps + 1):  # step s runs from (s-1) h to s h
        if s - 1 in sets:
            syn.n = sets[s - 1]
        if (s - 1) % md == 0:
            for k in range(s - md, s):
                for _ in range(int(pre[k]) if k >= 1 else 0):
                    syn.send(k * h)
        for _ in range(int(post[s])):
            syn.post_spike(s * h)
        if dopa_arrival[s]:
            syn.dopa.append((s * h, float(dopa_arrival[s])))
        if s % (deliver_interval * md) == 0:
            syn.trigger(s * h)
        out[:, s - 1] = syn.w, syn.c, syn.n
    return np.arange(1, n_steps + 1) * h, out[0], out[1], out[2]


class RSTDPNestState(NamedTuple):
    """State of a group of R-STDP synapses on NEST's schedule (`rstdp` with ``schedule="nest"``).

    NEST updates a synapse lazily; these are its stored values, plus the recent
    spikes it will read back.

    Attributes:
        k_plus: ``(n_pre,)`` ``K_plus`` at each presynaptic neuron's last update point.
        k_minus: ``(n_post,)`` the postsynaptic traces after this step's spikes (not delayed).
        c: ``(n_pre, n_post)`` eligibility at each row's last update point.
        n: ``(n_post,)`` dopamine at the last volume-transmitter trigger.
        step: index of the last step run (0 before the first).
        t_last: ``(n_pre,)`` step of each row's last update point.
        t_trig: step of the last trigger.
        post_hist: ``(H, n_post)`` post spike counts of the last ``H`` steps, newest last, less
            the entries NEST has pruned from the neuron's history.
        access: ``(H, n_post)`` how often synapses have read each of those history entries.
        kminus_hist: ``(H, n_post)`` the post traces after each of those steps.
        dopa_hist: ``(H,)`` dopamine spikes reaching the volume transmitter in those steps.
        pre_hist: ``(min_delay_steps, n_pre)`` pre spike counts of the current slice, newest last.
    """

    k_plus: jax.Array
    k_minus: jax.Array
    c: jax.Array
    n: jax.Array
    step: jax.Array
    t_last: jax.Array
    t_trig: jax.Array
    post_hist: jax.Array
    access: jax.Array
    kminus_hist: jax.Array
    dopa_hist: jax.Array
    pre_hist: jax.Array


def _nest_schedule_rule(n_pre, n_post, delay_steps, md, di, max_delay, n_incoming):
    """`rstdp` on NEST's schedule; see `rstdp`."""
    span = (di + 1) * md  # the longest stretch one lazy update covers, steps
    keep = max_delay + md  # ArchivingNode prunes an entry once the next is more than this old
    hlen = max(span + delay_steps + md, keep + 1) + 1

    def init(weights):
        if weights.shape != (n_pre, n_post):
            raise UserError(f"rstdp: weights of shape {weights.shape}, expected {(n_pre, n_post)}")
        dtype = weights.dtype if jnp.issubdtype(weights.dtype, jnp.floating) else jnp.float32
        z = jnp.zeros
        return RSTDPNestState(
            k_plus=z((n_pre,), dtype),
            k_minus=z((n_post,), dtype),
            c=z((n_pre, n_post), dtype),
            n=z((n_post,), dtype),
            step=jnp.zeros((), jnp.int32),
            t_last=z((n_pre,), jnp.int32),
            t_trig=jnp.zeros((), jnp.int32),
            post_hist=z((hlen, n_post), dtype),
            access=z((hlen, n_post), dtype),
            kminus_hist=z((hlen, n_post), dtype),
            dopa_hist=z((hlen,), dtype),
            pre_hist=z((md, n_pre), dtype),
        )

    def hist_at(hist, newest, x):
        """Rows of ``hist`` (newest last, the newest being step ``newest``) at steps ``x``; 0 outside."""
        i = hlen - 1 - (newest - x)
        ok = (i >= 0) & (i < hlen)
        return jnp.where(ok.reshape(ok.shape + (1,) * (hist.ndim - 1)), hist[jnp.clip(i, 0, hlen - 1)], 0.0)

    def sweep(p, s, w, c, k_plus, t_ref, rows, t1, pre_win, newest, dt):
        """NEST's lazy update of ``rows`` from step ``t_ref`` to step ``t1`` (per row, ``t_ref <= t1``), over the
        window of ``span`` steps ending at ``newest``: facilitation at post arrivals, dopamine pieces,
        depression and ``K_plus`` at the pre spikes ``pre_win`` (``(span, n_pre)``, one ``send`` each),
        ``w`` clipped at the end of every piece (process_dopa_spikes_). Returns ``w``, ``c`` and
        ``K_plus`` at ``t1``, and the history's read counts."""
        g = newest - span + jnp.arange(1, span + 1, dtype=jnp.int32)  # (span,) grid steps, the ends of the pieces
        dopa = hist_at(s.dopa_hist, newest, g) * (g > s.t_trig)
        n_prev = _n_at(s, g - 1, newest, dt, p)  # (span, n_post): n over the piece ending at g
        arrivals = hist_at(s.post_hist, newest, g - delay_steps)  # (span, n_post)
        # K_minus of the post spikes emitted strictly before g - d (ArchivingNode::get_K_value)
        k_minus = hist_at(s.kminus_hist, newest, g - delay_steps - 1) * jnp.exp(-dt / p.tau_minus)
        decay_c = jnp.exp(-dt / p.tau_c)

        def body(carry, x):
            w, c, k_plus, t_at = carry
            gi, n0, arr, dflag, km, m = x
            active = rows & (t_ref < gi) & (gi <= t1)  # (n_pre,)
            a = active[:, None]
            w = jnp.where(a, w + _weight_piece(c, n0[None, :], dt, p, jnp), w)
            kp = k_plus * jnp.exp(-(gi - t_at).astype(c.dtype) * dt / p.tau_plus)
            c = jnp.where(a, c * decay_c + p.A_plus * kp[:, None] * arr[None, :], c)
            spike = active & (m > 0)
            clip = a & ((arr[None, :] > 0) | (dflag > 0) | spike[:, None] | (gi == t1)[:, None])
            w = jnp.where(clip, jnp.clip(w, p.Wmin, p.Wmax), w)
            c = c - p.A_minus * jnp.where(spike, m, 0.0)[:, None] * km[None, :]
            k_plus = jnp.where(spike, kp + m, k_plus)
            t_at = jnp.where(spike, gi, t_at)
            return (w, c, k_plus, t_at), None

        xs = (g, n_prev, arrivals, dopa, k_minus, pre_win)
        (w, c, k_plus, t_at), _ = jax.lax.scan(body, (w, c, k_plus, t_ref), xs)
        k_plus = k_plus * jnp.exp(-(t1 - t_at).astype(c.dtype) * dt / p.tau_plus)  # K_plus at t1
        # get_history marks the entries it read, emitted in (t_ref - d, t1 - d].
        x = newest - jnp.arange(hlen, dtype=jnp.int32)[::-1]
        read = rows[None, :] & (t_ref[None, :] - delay_steps < x[:, None]) & (x[:, None] <= t1[None, :] - delay_steps)
        access = s.access + jnp.sum(read, axis=1, dtype=c.dtype)[:, None] * (s.post_hist > 0)
        return w, c, k_plus, access

    def deliver_prep(p, s, w, dt):
        """The backward part of delivery and the arguments of its `sweep`."""
        newest = s.step
        steps = newest - md + 1 + jnp.arange(md, dtype=jnp.int32)
        has = s.pre_hist > 0  # (md, n_pre)
        rows = jnp.any(has, axis=0)
        first = jnp.min(jnp.where(has, steps[:, None], newest + 1), axis=0)
        last = jnp.max(jnp.where(has, steps[:, None], newest - md), axis=0)
        m_first = jnp.sum(jnp.where(steps[:, None] == first[None, :], s.pre_hist, 0.0), axis=0)
        # Delivered after the trigger at t_last > first: integrate back to the first spike, depress there.
        back = rows & (first <= s.t_last)
        span_b = (first - s.t_last).astype(s.c.dtype) * dt
        n0 = _n_at(s, s.t_last, newest, dt, p)
        wb = jnp.clip(w + _weight_piece(s.c, n0, span_b[:, None], p, jnp), p.Wmin, p.Wmax)
        w = jnp.where(back[:, None], wb, w)
        c = jnp.where(back[:, None], s.c * jnp.exp(-span_b[:, None] / p.tau_c), s.c)
        k_first = hist_at(s.kminus_hist, newest, first - delay_steps - 1) * jnp.exp(-dt / p.tau_minus)
        c = c - p.A_minus * jnp.where(back, m_first, 0.0)[:, None] * k_first
        k_plus = jnp.where(back, s.k_plus * jnp.exp(-span_b / p.tau_plus) + m_first, s.k_plus)
        t_ref = jnp.where(back, first, s.t_last)
        pre_win = jnp.concatenate([jnp.zeros((span - md, n_pre), s.c.dtype), s.pre_hist])
        return (w, c, k_plus, t_ref, rows, jnp.where(rows, last, t_ref), pre_win), last

    def deliver(p, s, w, dt):
        """At the start of a slice: NEST's ``send`` for the pre spikes of the previous slice, in time order."""
        args, last = deliver_prep(p, s, w, dt)
        w, c, k_plus, access = sweep(p, s, *args, s.step, dt)
        return w, deliver_done(s, c, k_plus, access, args[4], last)

    def deliver_done(s, c, k_plus, access, rows, last):
        return s._replace(c=c, k_plus=k_plus, t_last=jnp.where(rows, last, s.t_last), access=access)

    def trigger_prep(s, w):
        rows = jnp.ones((n_pre,), bool)
        t1 = jnp.full_like(s.t_last, s.step)
        return (w, s.c, s.k_plus, s.t_last, rows, t1, jnp.zeros((span, n_pre), s.c.dtype))

    def trigger(p, s, w, dt):
        """The volume transmitter's trigger at the end of a slice: every row brought to now."""
        w, c, k_plus, access = sweep(p, s, *trigger_prep(s, w), s.step, dt)
        return w, trigger_done(p, s, c, k_plus, access, dt)

    def trigger_done(p, s, c, k_plus, access, dt):
        now = s.step
        n = _n_at(s, now[None], now, dt, p)[0]
        return s._replace(
            c=c,
            access=access,
            n=n.astype(c.dtype),
            k_plus=k_plus,
            t_last=jnp.full_like(s.t_last, now),
            t_trig=now,
        )

    def prune(hist, access, t, newest):
        """ArchivingNode::set_spiketime at step ``t``: drops history entries, oldest first, while the oldest
        has been read by every incoming synapse and the entry after it is more than ``keep`` steps old."""
        x = newest - jnp.arange(hlen, dtype=jnp.int32)[::-1]
        nonempty = hist > 0
        big = jnp.iinfo(jnp.int32).max
        later = jnp.where(nonempty, x[:, None], big)
        # the step of the next non-empty slot after each slot
        nxt = jnp.concatenate([jax.lax.cummin(later[::-1], axis=0)[::-1][1:], jnp.full((1, hist.shape[1]), big)])
        read = access >= n_incoming
        old = t - keep - 1
        pop_all = nonempty & read & (nxt <= old)
        pop_but_one = nonempty & read & (x[:, None] <= old)
        free = jnp.cumprod((pop_all | ~nonempty).astype(jnp.int32), axis=0)
        reach = jnp.concatenate([jnp.ones((1, hist.shape[1]), jnp.int32), free[:-1]]) > 0
        return jnp.where(reach & pop_all, 0.0, jnp.where(reach & pop_but_one, jnp.minimum(hist, 1.0), hist))

    def append(s, pre, post, dopamine, p, dt):
        """The step's spikes: post spikes into the history (NEST prunes it first), dopamine into the
        volume transmitter, pre spikes into the slice buffer."""
        step = s.step + 1
        k_minus = s.k_minus * jnp.exp(-dt / p.tau_minus) + post
        hist = jnp.where(post[None, :] > 0, prune(s.post_hist, s.access, step, s.step), s.post_hist)
        return s._replace(
            step=step,
            k_minus=k_minus,
            post_hist=jnp.concatenate([hist[1:], post[None]]),
            access=jnp.concatenate([s.access[1:], jnp.zeros_like(post)[None]]),
            kminus_hist=jnp.concatenate([s.kminus_hist[1:], k_minus[None]]),
            dopa_hist=jnp.concatenate([s.dopa_hist[1:], jnp.asarray(dopamine, post.dtype)[None]]),
            pre_hist=jnp.concatenate([s.pre_hist[1:], pre[None]]),
        )

    def update(params, state, weights, pre, post, dopamine, dt):
        s = state
        dtype = s.c.dtype
        pre = jnp.asarray(pre, dtype)
        post = jnp.asarray(post, dtype)
        w = weights.astype(dtype)
        # Start of step s.step + 1: deliver the previous slice's pre spikes when a slice begins; end of
        # the step: the trigger, every deliver_interval slices.
        starts = (s.step % md == 0) & (s.step > 0)
        if md == 1:  # both in one step
            w, s = jax.lax.cond(starts, lambda a: deliver(params, a[1], a[0], dt), lambda a: a, (w, s))
            s = append(s, pre, post, dopamine, params, dt)
            trig = s.step % (di * md) == 0
            w, s = jax.lax.cond(trig, lambda a: trigger(params, a[1], a[0], dt), lambda a: a, (w, s))
            return (w - weights).astype(weights.dtype), s
        # At most one of the two per step: one sweep, its arguments chosen. The cond skips it on the
        # other steps when the step counter is not batched (see `rstdp`).
        s_trig = append(s, pre, post, dopamine, params, dt)
        trig = s_trig.step % (di * md) == 0

        def work(operand):
            w, s, s_trig = operand
            d_args, last = deliver_prep(params, s, w, dt)
            pick = lambda a, b: jax.tree.map(lambda x, y: jnp.where(starts, x, y), a, b)  # noqa: E731
            args = pick(d_args, trigger_prep(s_trig, w))
            at = pick(s, s_trig)
            w_new, c, k_plus, access = sweep(params, at, *args, at.step, dt)
            delivered = append(deliver_done(s, c, k_plus, access, args[4], last), pre, post, dopamine, params, dt)
            return w_new, pick(delivered, trigger_done(params, s_trig, c, k_plus, access, dt))

        w, s = jax.lax.cond(starts | trig, work, lambda operand: (operand[0], operand[2]), (w, s, s_trig))
        return (w - weights).astype(weights.dtype), s

    return PlasticityRule(init, update)


def _n_at(s, t, newest, dt, p):
    """Dopamine at steps ``t`` (shape ``(k,)``) as NEST's synapses see it, ``(k, n_post)``: ``n`` at the
    last trigger, decayed (or extrapolated back), plus the dopamine spikes since that trigger up to ``t``.
    ``dopa_hist`` ends at step ``newest``."""
    hlen = s.dopa_hist.shape[0]
    x = newest - jnp.arange(hlen, dtype=jnp.int32)[::-1]  # the steps of dopa_hist
    lag = (t[:, None] - x[None, :]).astype(s.c.dtype)
    take = (x[None, :] > s.t_trig) & (lag >= 0)
    extra = jnp.sum(jnp.where(take, s.dopa_hist[None, :] * jnp.exp(-jnp.where(take, lag, 0.0) * dt / p.tau_n), 0.0), 1)
    decay = jnp.exp(-(t - s.t_trig).astype(s.c.dtype) * dt / p.tau_n)
    return s.n[None, :] * decay[:, None] + (extra / p.tau_n)[:, None]
