"""The four spiking networks of the snake R-STDP paper, as one controller of `robots.snake.env.SnakeEnv`.

One network description (`NetworkConfig`, static: the topology and the sizes;
`NetworkParams`, traced: every constant) builds all four topologies of the
paper (Sec. II-B, II-C, III-B, III-C):

* ``basic`` (Fig. 2): 10 DVS inputs -> 2 outputs ``[O_L, O_R]`` steering the body;
* ``basic-head`` (Sec. III-B): 10 DVS inputs -> 4 outputs ``[H_L, H_R, B_L, B_R]``,
  the first pair turning the head, the second the body;
* ``unified`` (Fig. 3): 10 DVS inputs -> 2 head outputs ``[H_L, H_R]``; the
  8 neurons of the second layer (``H_L, H_R`` and 6 joint inputs) -> both body
  outputs ``[B_L, B_R]``;
* ``separated`` (Fig. 4): as ``unified``, but the second layer splits into a
  left group of 4 projecting only to ``B_L`` and a right group of 4 projecting
  only to ``B_R``.

Every input is a Poisson generator repeated by a parrot neuron (Sec. II-B: the
input LIFs "parrot these spikes"); every other neuron is NEST's
``iaf_psc_alpha`` (`spikejax.neurons.iaf_psc_alpha_step`), every connection
has the same transmission delay, and every synapse onto a LIF is an R-STDP
synapse (`spikejax.plasticity.rstdp`, Eq. (6)-(8)). One control step (20 ms)
runs `NetworkConfig.substeps` neural steps (0.1 ms, NEST's default
resolution):

1. rewards from the robot's state at the end of the previous step: Eq. (9)
   per output pair (`spikejax.plasticity.reward.pair_rewards`), with
   ``a_head`` for the head pair (and for the basic net, which has no head
   controller) and ``a_body`` of Eq. (12) for the body pair; the hidden
   neurons' rewards back-propagated by Eq. (11) (unified) or Eq. (13)
   (separated) from the body rewards and the current hidden-to-body weights
   (``hidden_reward="backprop"``), or the head pair's own reward
   (``hidden_reward="head"``). Each reward becomes the dopamine concentration
   ``n`` of the synapses onto its neuron (`spikejax.plasticity.rstdp.set_dopamine`),
   as the authors' group set ``n`` with NEST's ``SetStatus`` each step;
2. input rates (held for the control step, each neural step's generator
   counts drawn as NEST's ``poisson_generator`` draws them,
   `spikejax.coding.poisson_count_train`): the frame-difference events of the last step counted in the
   2 x 5 grid of the ROI (Eq. (2), `spikejax.coding.grid_counts` and
   `spikejax.coding.grid_rates`), and for the multi-layer nets the antagonist
   rates of joints 1, 3 and 5 (Eq. (3), `spikejax.coding.antagonist_rates`);
3. the network runs for the control step, learning as it goes (unless
   ``learn=False``: frozen weights for testing);
4. output spike counts per pair decoded by Eq. (4) and integrated by Eq. (5)
   (`spikejax.coding.d_norm`, `spikejax.coding.direction_step`) into the
   body's steering ``D_body`` and the head's ``D_head``, the env's action.

A failure reset forgets only ``D_body`` and ``D_head`` (`controller`'s
``on_reset``): NRP resets the robot, not the brain.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from spikejax import coding
from spikejax.errors import UserError
from spikejax.neurons import IafPscAlphaParams, iaf_psc_alpha_init, iaf_psc_alpha_params, iaf_psc_alpha_step
from spikejax.plasticity import reward as rewards
from spikejax.plasticity.rstdp import RSTDPParams, rstdp, rstdp_params, set_dopamine
from spikejax.rollout import Controller
from spikejax.synapses import delay_init, delay_read, delay_step

__all__ = [
    "TOPOLOGIES",
    "NetworkConfig",
    "NetworkParams",
    "NetworkState",
    "network_params",
    "network_init",
    "network_rewards",
    "network_rates",
    "network_run",
    "network_decode",
    "network_step",
    "controller",
]

TOPOLOGIES = ("basic", "basic-head", "unified", "separated")
N_DVS = 10  # 2 x 5 grid cells (Sec. II-D)
N_JOINT = 6  # antagonist pairs of joints 1, 3, 5 (Sec. II-D, Eq. (3))
N_HIDDEN = 2 + N_JOINT  # H_L, H_R and the joint inputs (Sec. II-C)
JOINTS = (0, 2, 4)  # joints 1, 3, 5 as indices of the env's joint angles


@dataclasses.dataclass(frozen=True)
class NetworkConfig:
    """The static part of a network: topology, sizes, and the choices that change the program.

    Attributes:
        topology: one of `TOPOLOGIES`.
        roi: ``(row0, row1, col0, col1)`` pixels of the DVS frame counted by
            Eq. (2) (unstated in the paper): rows 12-60 hold the target above
            the horizon on this camera, the columns leave 4 pixels each side.
            The horizon (rows 60-68) bobs with the gait and, counted, fires
            every column at once: with rows 16-80 the body pair's ``D_norm``
            was 0.18 with the target 15-30 degrees to a side, with 12-60 0.88
            (basic net, 16 seeds, one lap; README, "Choices the paper leaves open").
        rows, cols: the grid (2 x 5, Sec. II-D).
        dt: neural step, ms (NEST's default resolution).
        substeps: neural steps per 20 ms control step.
        delay: transmission delay of every connection, in neural steps (1 ms).
        hidden_reward: ``"backprop"`` (reading A: Eq. (11)/(13) drive the
            synapses onto ``H``) or ``"head"`` (reading B: they keep the head
            reward of Sec. III-B).
        eq13_sign: ``"eq10"`` (Eq. (13) as Eq. (10) gives it) or ``"printed"``
            (the paper's minus on the left group).
        joints_left: which joint neurons join ``H_L`` in the separated net's
            left group: ``"positive"`` (the ``f_P`` of each joint, angles that
            bend the head to the left) or ``"negative"``.
        schedule: the R-STDP's update points (`spikejax.plasticity.rstdp.rstdp`):
            ``"exact"`` (every spike at its time) or ``"nest"`` (NEST's lazy schedule).
        learn: apply the R-STDP weight changes (``False``: frozen, for testing).
    """

    topology: str = "separated"
    roi: tuple[int, int, int, int] = (12, 60, 4, 124)
    rows: int = 2
    cols: int = 5
    dt: float = 0.1
    substeps: int = 200
    delay: int = 10
    hidden_reward: str = "backprop"
    eq13_sign: str = "eq10"
    joints_left: str = "positive"
    schedule: str = "exact"
    learn: bool = True

    def __post_init__(self):
        choices = {
            "topology": TOPOLOGIES,
            "hidden_reward": ("backprop", "head"),
            "eq13_sign": ("eq10", "printed"),
            "joints_left": ("positive", "negative"),
            "schedule": ("exact", "nest"),
        }
        for name, allowed in choices.items():
            if getattr(self, name) not in allowed:
                raise UserError(f"{name} must be one of {', '.join(allowed)}, got {getattr(self, name)!r}")
        for name in ("rows", "cols", "substeps", "delay"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise UserError(f"{name} must be an int >= 1, got {value!r}")
        if self.rows * self.cols != N_DVS:
            raise UserError(f"the grid must have {N_DVS} cells (Sec. II-D), got {self.rows} x {self.cols}")
        if not self.dt > 0:
            raise UserError(f"dt must be positive, got {self.dt}")

    @property
    def hidden(self) -> bool:
        """Whether the net has the second plastic layer (unified, separated)."""
        return self.topology in ("unified", "separated")

    @property
    def n_first(self) -> int:
        """LIF neurons fed by the DVS inputs."""
        return 4 if self.topology == "basic-head" else 2

    @property
    def n_out(self) -> int:
        """All LIF neurons."""
        return self.n_first + (2 if self.hidden else 0)

    @property
    def hidden_mask(self) -> np.ndarray:
        """``(8, 2)`` existing synapses from ``[H_L, H_R, J1+, J1-, J3+, J3-, J5+, J5-]`` to ``[B_L, B_R]``."""
        if self.topology != "separated":
            return np.ones((N_HIDDEN, 2), bool)
        left = np.zeros(N_HIDDEN, bool)
        left[0] = True
        first = 0 if self.joints_left == "positive" else 1  # f_P at even joint-neuron index
        left[2 + first :: 2] = True
        return np.stack([left, ~left], axis=1)

    @property
    def hidden_side(self) -> np.ndarray:
        """Output side (0 left, 1 right) of each hidden neuron in the separated net."""
        return self.hidden_mask[:, 1].astype(np.int32)


class NetworkParams(NamedTuple):
    """Every constant of the network, traced (a sweep vmaps over any of them).

    Attributes:
        neuron: the LIFs' `spikejax.neurons.IafPscAlphaParams` (NEST defaults).
        first: R-STDP of the synapses from the DVS inputs (onto ``O``, or ``H``
            and ``B``); in the multi-layer nets their ``tau_c`` is ``tau_c_factor``
            times larger and ``A_plus``, ``A_minus`` as many times smaller
            (Sec. III-C-1; `network_params`).
        second: R-STDP of the hidden-to-body synapses (multi-layer nets).
        w_low, w_high: initial weights drawn uniformly from ``[w_low, w_high)``, pA.
        eta_head, eta_body: Eq. (5)'s eta (Sec. III-B: 0.02, 0.07).
        c_reward_head, c_reward_body: Eq. (9)'s C_reward (Sec. III-B: 0.0004,
            0.0001), per radian of ``a_target``.
        k_joint: Eq. (3)'s k, Hz per degree of joint angle.
        max_rate: cap of Eq. (2)'s rates, Hz (``inf``: the literal equation).
    """

    neuron: IafPscAlphaParams
    first: RSTDPParams
    second: RSTDPParams
    w_low: jax.Array
    w_high: jax.Array
    eta_head: jax.Array
    eta_body: jax.Array
    c_reward_head: jax.Array
    c_reward_body: jax.Array
    k_joint: jax.Array
    max_rate: jax.Array


def network_params(
    config: NetworkConfig,
    *,
    tau_c_factor: float = 5.0,
    w_low: float = 200.0,
    w_high: float = 201.0,
    eta_head: float = 0.02,
    eta_body: float = 0.07,
    c_reward_head: float = 0.0004,
    c_reward_body: float = 0.0001,
    k_joint: float = 10.0,
    max_rate: float = 300.0,
    A_plus: float = 1.0,
    A_minus: float = 0.5,
    tau_c: float = 1000.0,
    tau_n: float = 200.0,
    Wmax: float = 3000.0,
) -> NetworkParams:
    """The paper's values where it states them; where it does not, these, each with its reason.

    Stated (Sec. III-B): ``eta`` 0.02 (head) and 0.07 (body), ``C_reward``
    0.0004 (head) and 0.0001 (body). Unstated, and chosen:

    * NEST's ``iaf_psc_alpha`` defaults for every LIF; ``tau_c = 1000`` ms,
      ``tau_n = 200`` ms, ``b = 0``, ``Wmin = 0``, ``Wmax = 3000`` pA, initial
      weights uniform in ``[200, 201)`` pA and ``A_plus = 1`` as in the public
      NEST code of the authors' group for lane keeping;
    * ``A_minus = 0.5``, not that code's 1 (nor NEST's default 1.5): with
      balanced windows and inputs and outputs firing steadily, the eligibility
      of Eq. (6) follows minus the rate of change of each input (depression
      when it switches on), so the inputs seeing the target carried negative
      eligibility while rewarded and every seed learned the crossed mapping
      (right image columns onto the left output); with 0.5 the eligibility
      follows the input and every seed learns right onto right;
    * ``a_target`` of Eq. (9) in radians: in degrees, ``C_reward = 1e-4``
      drove the weights to their bounds within 90 s and tested worse;
    * rates of Eq. (2) capped at 300 Hz, as that lane-keeping code caps its
      inputs (the literal rates reach 18 kHz here and saturate the outputs);
    * ``k_joint = 10`` Hz per degree (Eq. (3)); the hidden layer's ``tau_c``
      five times larger with windows five times smaller (Sec. III-C-1).
    """
    f = lambda v: jnp.asarray(v, jnp.float32)  # noqa: E731
    base = dict(A_plus=A_plus, A_minus=A_minus, tau_c=tau_c, tau_n=tau_n, Wmin=0.0, Wmax=Wmax)
    second = rstdp_params(**base)
    m = tau_c_factor if config.hidden else 1.0
    first = rstdp_params(**dict(base, tau_c=tau_c * m, A_plus=A_plus / m, A_minus=A_minus / m))
    return NetworkParams(
        neuron=iaf_psc_alpha_params(),
        first=first,
        second=second,
        w_low=f(w_low),
        w_high=f(w_high),
        eta_head=f(eta_head),
        eta_body=f(eta_body),
        c_reward_head=f(c_reward_head),
        c_reward_body=f(c_reward_body),
        k_joint=f(k_joint),
        max_rate=f(max_rate),
    )


class NetworkState(NamedTuple):
    """The network between control steps.

    Attributes:
        w_first: ``(10, n_first)`` weights from the DVS inputs, pA.
        w_hidden: ``(8, 2)`` weights from the second layer to ``[B_L, B_R]``
            (zero where no synapse; unused by the basic nets).
        neurons: the LIFs' state, ``[first layer, B_L, B_R]``.
        to_parrots: delay line from the generators to the parrots.
        to_lifs: delay line of the weighted input currents to the LIFs.
        plastic_first, plastic_hidden: the R-STDP states.
        d_head, d_body: Eq. (5)'s integrators.
        counts: output spikes of the last control step, ``(n_out,)``.
        r_first, r_hidden: the rewards set in the last control step: of the
            first layer's neurons ``(n_first,)`` and of the 8 hidden neurons.
    """

    w_first: jax.Array
    w_hidden: jax.Array
    neurons: object
    to_parrots: object
    to_lifs: object
    plastic_first: object
    plastic_hidden: object
    d_head: jax.Array
    d_body: jax.Array
    counts: jax.Array
    r_first: jax.Array
    r_hidden: jax.Array


def _rules(config: NetworkConfig):
    kw = dict(delay_steps=config.delay, schedule=config.schedule)
    return rstdp(N_DVS, config.n_first, **kw), rstdp(N_HIDDEN, 2, **kw)


def network_init(config: NetworkConfig, params: NetworkParams, *, key: jax.Array) -> NetworkState:
    """A fresh network: uniform initial weights, neurons at rest, empty delay lines, zero traces."""
    k1, k2 = jax.random.split(key)
    w_first = jax.random.uniform(k1, (N_DVS, config.n_first), jnp.float32, params.w_low, params.w_high)
    w_hidden = jax.random.uniform(k2, (N_HIDDEN, 2), jnp.float32, params.w_low, params.w_high)
    w_hidden = jnp.where(config.hidden_mask, w_hidden, 0.0)
    first_rule, hidden_rule = _rules(config)
    zero = jnp.zeros((), jnp.float32)
    return NetworkState(
        w_first=w_first,
        w_hidden=w_hidden,
        neurons=iaf_psc_alpha_init(config.n_out, params.neuron),
        to_parrots=delay_init(N_DVS + N_JOINT, config.delay, jnp.float32),
        to_lifs=delay_init(config.n_out, config.delay, jnp.float32),
        plastic_first=first_rule.init(w_first),
        plastic_hidden=hidden_rule.init(w_hidden),
        d_head=zero,
        d_body=zero,
        counts=jnp.zeros((config.n_out,), jnp.int32),
        r_first=jnp.zeros((config.n_first,), jnp.float32),
        r_hidden=jnp.zeros((N_HIDDEN,), jnp.float32),
    )


def network_rewards(config: NetworkConfig, params: NetworkParams, state: NetworkState, a_head, a_body):
    """Rewards ``(r_first, r_body, r_hidden)`` of the first layer's neurons, the body pair and the hidden neurons.

    Eq. (9) per pair, Eq. (11) (unified) or Eq. (13) (separated) for the
    hidden neurons, from ``a_head`` and ``a_body`` in radians (see `network_params`).
    """
    head = rewards.pair_rewards(a_head, params.c_reward_head)
    body = rewards.pair_rewards(a_body, params.c_reward_body)
    if config.topology == "basic":
        # No head controller: the head's angle is the body's (Sec. IV-A), the body's constants (SPEC U22).
        return rewards.pair_rewards(a_head, params.c_reward_body), body, jnp.zeros((N_HIDDEN,), jnp.float32)
    if config.topology == "basic-head":
        return jnp.concatenate([head, body]), body, jnp.zeros((N_HIDDEN,), jnp.float32)
    if config.topology == "unified":
        hidden = rewards.unified_rewards(body, state.w_hidden)
    elif config.eq13_sign == "printed":
        w = jnp.sum(state.w_hidden, axis=1)  # one synapse per hidden neuron
        hidden = rewards.separated_rewards(body, w, jnp.asarray(config.hidden_side), sign="printed")
    else:
        hidden = rewards.backprop_rewards(body, state.w_hidden, jnp.asarray(config.hidden_mask))
    first = hidden[:2] if config.hidden_reward == "backprop" else head
    return first, body, hidden


def network_rates(config: NetworkConfig, params: NetworkParams, frames, obs) -> jax.Array:
    """The 16 generators' rates, Hz: the grid cells of Eq. (2), then (multi-layer nets) Eq. (3) of joints 1, 3, 5.

    Args:
        frames: ``(prev_frame, frame, threshold)``: the camera's last two grey
            frames and the DVS threshold, whose difference is the last step's events.
        obs: the env's observation ``[a_head, a_body, alpha_1 .. alpha_16]`` (rad).
    """
    prev_frame, frame, threshold = frames
    counts = coding.grid_counts(
        prev_frame, frame, threshold=threshold, roi=config.roi, rows=config.rows, cols=config.cols
    )
    rates = coding.grid_rates(counts, 0.001 * config.dt * config.substeps, params.max_rate)
    if config.hidden:
        joint_deg = jnp.rad2deg(obs[2 + jnp.asarray(JOINTS)])
        return jnp.concatenate([rates, coding.antagonist_rates(joint_deg, params.k_joint)])
    return jnp.concatenate([rates, jnp.zeros((N_JOINT,), rates.dtype)])


def network_run(config: NetworkConfig, params: NetworkParams, state: NetworkState, generated, r_first, r_body):
    """The network through one control step, given its generators' spikes and its neurons' rewards.

    Args:
        generated: ``(substeps, 16)`` spike counts of the generators in each neural step, or the
            generators as a `spikejax.coding.PoissonCDF` of 16 (the same counts, drawn inside each step).
        r_first: rewards of the first layer's neurons ``(n_first,)``, set as their synapses' ``n``.
        r_body: rewards of ``[B_L, B_R]`` (multi-layer nets; ignored otherwise).

    Returns:
        The new state (``d_head``, ``d_body`` untouched) and the output spike counts ``(n_out,)``.
    """
    first_rule, hidden_rule = _rules(config)
    mask = jnp.asarray(config.hidden_mask, jnp.float32)
    nf = config.n_first

    drawn = isinstance(generated, coding.PoissonCDF)
    xs = jnp.arange(config.substeps, dtype=jnp.uint32) if drawn else generated

    def substep(carry, x):
        neurons, to_parrots, to_lifs, w1, w2, p1, p2, spikes_total = carry
        gen = coding.poisson_cdf_counts(generated, x) if drawn else x
        to_parrots, parrots = delay_step(to_parrots, gen.astype(jnp.float32))  # NEST's parrots re-emit at once
        dvs, joints = parrots[:N_DVS], parrots[N_DVS:]
        arriving = delay_read(to_lifs)  # excitatory only: Wmin = 0
        neurons, spikes = iaf_psc_alpha_step(params.neuron, neurons, arriving, jnp.zeros_like(arriving), config.dt)
        spikes = spikes.astype(jnp.float32)
        # currents sent now with the weights at the time of sending, arriving one delay later
        current = jnp.zeros((config.n_out,), jnp.float32).at[:nf].set(dvs @ w1)
        hidden_pre = jnp.concatenate([spikes[:2], joints])
        if config.hidden:
            current = current.at[nf:].set(hidden_pre @ w2)
        to_lifs, _ = delay_step(to_lifs, current)
        dw1, p1 = first_rule.update(params.first, p1, w1, dvs, spikes[:nf], 0.0, config.dt)
        if config.learn:
            w1 = w1 + dw1
        if config.hidden:
            dw2, p2 = hidden_rule.update(params.second, p2, w2, hidden_pre, spikes[nf:], 0.0, config.dt)
            if config.learn:
                w2 = w2 + dw2 * mask
        return (neurons, to_parrots, to_lifs, w1, w2, p1, p2, spikes_total + spikes), None

    carry = (
        state.neurons,
        state.to_parrots,
        state.to_lifs,
        state.w_first,
        state.w_hidden,
        set_dopamine(state.plastic_first, r_first),
        set_dopamine(state.plastic_hidden, r_body),
        jnp.zeros((config.n_out,), jnp.float32),
    )
    (neurons, to_parrots, to_lifs, w1, w2, p1, p2, total), _ = jax.lax.scan(substep, carry, xs)
    state = state._replace(
        w_first=w1,
        w_hidden=w2,
        neurons=neurons,
        to_parrots=to_parrots,
        to_lifs=to_lifs,
        plastic_first=p1,
        plastic_hidden=p2,
    )
    return state, total.astype(jnp.int32)


def network_decode(config: NetworkConfig, params: NetworkParams, state: NetworkState, counts) -> NetworkState:
    """Eq. (4)-(5) of the output pairs: the body pair (the last two neurons) and the head pair (the first two)."""
    d_body = coding.direction_step(state.d_body, coding.d_norm(counts[-1], counts[-2]), params.eta_body)
    d_head = state.d_head
    if config.topology != "basic":
        d_head = coding.direction_step(state.d_head, coding.d_norm(counts[1], counts[0]), params.eta_head)
    return state._replace(d_body=d_body, d_head=d_head, counts=counts)


def network_step(
    config: NetworkConfig, params: NetworkParams, state: NetworkState, frames, obs, *, key: jax.Array
) -> tuple[NetworkState, jax.Array]:
    """One control step (see the module docstring); returns the new state and the env's action ``[D_body, D_head]``.

    Args:
        frames: ``(prev_frame, frame, threshold)``, as `network_rates` takes them.
        obs: the env's observation ``[a_head, a_body, alpha_1 .. alpha_16]`` (rad).
    """
    r_first, r_body, r_hidden = network_rewards(config, params, state, obs[0], obs[1])
    rates = network_rates(config, params, frames, obs)
    generated = coding.poisson_cdf(rates, 0.001 * config.dt, key=key)
    state, counts = network_run(config, params, state, generated, r_first, r_body)
    state = network_decode(config, params, state, counts)._replace(r_first=r_first, r_hidden=r_hidden)
    return state, jnp.stack([state.d_body, state.d_head])


def controller(config: NetworkConfig) -> Controller:
    """The network as a `spikejax.rollout.Controller` of the snake env; ``out`` holds the step's decoded values."""

    def step(params, state, env_state, *, key):
        info = env_state.info
        frames = (info["prev_frame"], info["frame"], info["params"].event_threshold)
        state, action = network_step(config, params, state, frames, env_state.obs, key=key)
        return state, action, {"d_body": state.d_body, "d_head": state.d_head}

    def on_reset(params, state):
        zero = jnp.zeros((), jnp.float32)
        return state._replace(d_head=zero, d_body=zero)

    return Controller(step=step, on_reset=on_reset)
