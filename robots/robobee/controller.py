"""The RoboBee's lateral SNN controller: 200-100-50 LIF network trained online on a teacher.

Section III of the RoboBee paper: four input groups of ``n_per_input`` LIF
neurons receive the shifted and scaled lateral state ``q_hat = a (q + b)`` of
``q = [theta, theta_dot, x, x_dot]``; they project to ``n_hidden`` hidden neurons,
which project to ``n_output`` output neurons, each synapse existing with
probability ``connectivity``. The output population's spikes are decoded by the
leaky integrator of Eq. (8) into the lateral control ``y_hat``, and the
reward-modulated Hebbian rule of Eq. (9)-(10) trains both weight layers online
on the error ``y - y_hat`` to a teacher ``y`` (the LQR output).

Units: times in s; potentials are dimensionless (``R = 1``, rest and reset 0,
thresholds ``U(0.7, 1.7)`` as in Section V), so currents are in the same unit.
The control is decoded in units of the torque limit, ``y = tau_c / (1e-6 N m)``
(``tau_c,max = 1 uN m``, Section II-B), so ``|y| <= 1`` is the actuator's range;
multiply by `TORQUE_UNIT` for N m.

What the rule learns: with one global error sign and the presynaptic rule of
`spikejax.plasticity.reward_modulated_hebbian`, the network is an online
adaptive tracker. Learning on, it follows an open-loop teacher ``y = -K q`` to
about 5 % RMS within 0.25 s (the paper's Fig. 9-10 regime, where learning never
stops). It does not store the map ``q -> y`` in its weights: frozen after 1 s of
learning, its output misses the same teacher by about 90 % of the teacher's
RMS: every input neuron's rate rises with its state variable, and all the
synapses leaving a neuron move together, so the weights follow the teacher's
current value rather than its dependence on ``q``. Keep ``learn`` on in closed loop.
(Those figures are for an open-loop-tuned decoder, ``beta = 20/s``, and
``mu = 1e-4``; the defaults, ``beta = 100/s`` and ``mu = 1e-3``, trade a noisier
output for the short lag the closed loop needs, see `controller_params`.)
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp

from spikejax.coding import DecoderParams, DecoderState, antagonist_currents, decoder_init, decoder_step, shift_scale
from spikejax.errors import UserError
from spikejax.neurons import LIFParams, LIFState, lif_init, lif_step
from spikejax.plasticity.hebbian import RewardHebbianParams, RewardHebbianState, reward_modulated_hebbian, row_increment
from spikejax.synapses import RowWeights, add_to_rows, connected, dense, propagate, row_weights

__all__ = [
    "N_LATERAL",
    "TORQUE_UNIT",
    "ControllerConfig",
    "ControllerParams",
    "ControllerState",
    "controller_params",
    "controller_init",
    "controller_step",
]

# Lateral state [theta, theta_dot, x, x_dot]: one input group each.
N_LATERAL = 4
# N m per unit of the decoded control: the torque limit tau_c,max = 1 uN m.
TORQUE_UNIT = 1e-6

_RULE = reward_modulated_hebbian()
# Rows gathered per pass by `spikejax.synapses.propagate` (input->hidden, hidden->output).
# Flight 1 has 5.0 and 2.8 spikes a step on average, up to 67 and 62 in bursts; under
# vmap the busiest flight sets the passes, and small passes were the fastest
# (measured: docs/BENCHMARKS.md, "RoboBee closed loop", notes).
MAX_ROWS = (12, 8)


@dataclasses.dataclass(frozen=True)
class ControllerConfig:
    """Static structure of the network (a change recompiles).

    A frozen dataclass, hashable and not a pytree: ``jit`` takes it as a static
    argument (``static_argnames``) and never traces its sizes.

    Attributes:
        n_per_input: neurons per input group (4 groups: theta, theta_dot, x, x_dot).
        n_hidden: hidden neurons.
        n_output: output neurons.
        connectivity: probability that a given input->hidden or hidden->output
            synapse exists, in (0, 1].
    """

    n_per_input: int = 50
    n_hidden: int = 100
    n_output: int = 50
    connectivity: float = 0.3

    @property
    def n_input(self) -> int:
        """Input neurons in all (4 groups)."""
        return N_LATERAL * self.n_per_input


class ControllerParams(NamedTuple):
    """Traced parameters of the controller (see `controller_params` for the defaults).

    Attributes:
        dt: neural time step, s.
        a: scales of ``q_hat = a (q + b)``, 1 / (units of q), shape ``(4,)``.
        b: shifts, units of q (rad, rad/s, m, m/s), shape ``(4,)``.
        input_gain: input current per unit of ``q_hat``.
        tau_input: membrane time constant of the input layer, s.
        tau_hidden: of the hidden layer, s.
        tau_output: of the output layer, s (``tau_input < tau_hidden < tau_output``).
        t_ref: refractory period of every neuron, s.
        syn_hidden: current into a hidden neuron per unit weight and presynaptic spike.
        syn_output: current into an output neuron per unit weight and presynaptic spike.
        v_th_low: lower end of the uniform threshold distribution.
        v_th_high: upper end.
        w_min: weights are clipped to ``[w_min, w_max]`` after each update.
        w_max: upper clip.
        decoder: ``alpha`` (units of `TORQUE_UNIT`), ``beta`` (1/s), ``gamma`` of Eq. (8).
        mu_hidden: learning rate of Eq. (10) for input->hidden weights.
        mu_output: learning rate for hidden->output weights.
        tau_reward: reward time constant ``tau`` of Eq. (9), s.
    """

    dt: jax.Array
    a: jax.Array
    b: jax.Array
    input_gain: jax.Array
    tau_input: jax.Array
    tau_hidden: jax.Array
    tau_output: jax.Array
    t_ref: jax.Array
    syn_hidden: jax.Array
    syn_output: jax.Array
    v_th_low: jax.Array
    v_th_high: jax.Array
    w_min: jax.Array
    w_max: jax.Array
    decoder: DecoderParams
    mu_hidden: jax.Array
    mu_output: jax.Array
    tau_reward: jax.Array


class ControllerState(NamedTuple):
    """Everything that varies per trial: the drawn network, its potentials, traces and weights.

    The learned weights are kept per presynaptic row (`spikejax.synapses.RowWeights`:
    Eq. (10) moves all the synapses leaving a neuron alike), and read through the
    properties ``w_ih``, ``w_ho`` (dense, zero where no synapse) and ``mask_ih``,
    ``mask_ho`` (1.0 where a synapse exists).

    Attributes:
        ih: input->hidden weights, ``(n_input, n_hidden)``.
        ho: hidden->output weights, ``(n_hidden, n_output)``.
        v_th_input: thresholds of the input neurons, shape ``(n_input,)``.
        v_th_hidden: thresholds of the hidden neurons, ``(n_hidden,)``.
        v_th_output: thresholds of the output neurons, ``(n_output,)``.
        input: LIF state of the input layer.
        hidden: LIF state of the hidden layer.
        output: LIF state of the output layer.
        decoder: trace of Eq. (8).
        rule_ih: Eq. (9) traces of the input neurons.
        rule_ho: Eq. (9) traces of the hidden neurons.
    """

    ih: RowWeights
    ho: RowWeights
    v_th_input: jax.Array
    v_th_hidden: jax.Array
    v_th_output: jax.Array
    input: LIFState
    hidden: LIFState
    output: LIFState
    decoder: DecoderState
    rule_ih: RewardHebbianState
    rule_ho: RewardHebbianState

    @property
    def w_ih(self) -> jax.Array:
        """Input->hidden weights, ``(n_input, n_hidden)``, 0 where no synapse."""
        return dense(self.ih)

    @property
    def w_ho(self) -> jax.Array:
        """Hidden->output weights, ``(n_hidden, n_output)``, 0 where no synapse."""
        return dense(self.ho)

    @property
    def mask_ih(self) -> jax.Array:
        """1.0 where an input->hidden synapse exists, else 0.0."""
        return connected(self.ih).astype(jax.dtypes.canonicalize_dtype(self.ih.w0.dtype))

    @property
    def mask_ho(self) -> jax.Array:
        """1.0 where a hidden->output synapse exists, else 0.0."""
        return connected(self.ho).astype(jax.dtypes.canonicalize_dtype(self.ho.w0.dtype))


def controller_params(
    dt=1e-4,
    q_range=(0.6, 6.0, 0.06, 0.6),
    input_gain=4.0,
    tau_input=2e-3,
    tau_hidden=10e-3,
    tau_output=20e-3,
    t_ref=2e-3,
    syn_hidden=5.0,
    syn_output=12.0,
    v_th_low=0.7,
    v_th_high=1.7,
    w_min=-2.0,
    w_max=2.0,
    alpha=0.04,
    beta=100.0,
    gamma=2.0,
    mu_hidden=1e-3,
    mu_output=1e-3,
    tau_reward=5e-3,
    dtype=jnp.float32,
) -> ControllerParams:
    """Builds `ControllerParams`; the defaults were tuned on an open-loop teacher.

    The defaults make the 200-100-50 network follow a teacher ``y = -K q`` of
    about unit amplitude (a sum of sinusoids of 0.4-0.7 Hz, learning on) to an
    RMS error of 4-5 % of the teacher's RMS within 0.25 s of learning, for every
    seed tried (``tests/test_robobee_controller.py``). The tracking error with
    one default changed at a time is in docs/BENCHMARKS.md, "RoboBee controller
    tuning".

    Args:
        dt: neural time step, s. 0.1 ms resolves the 2 ms refractory period and
            the fastest membrane (2 ms) to 5 % per step.
        q_range: expected magnitude of ``[theta, theta_dot, x, x_dot]`` (rad, rad/s,
            m, m/s); ``b = q_range`` and ``a = 1 / (2 q_range)`` map ``[-q_range,
            q_range]`` onto ``q_hat`` in ``[0, 1]``, positive as Section III asks.
            0.6 rad is the paper's initial attitude; a few cm and tenths of m/s
            are its waypoint offsets and speeds.
        input_gain: input current per unit ``q_hat``. 4 puts the current at
            ``q = 0`` (2) above every threshold of ``U(0.7, 1.7)``, so all input
            neurons fire at rest, and the spread of thresholds makes each a
            different rectified feature of its variable.
        tau_input: input membrane time constant, s. 2 ms: a fast input layer
            follows the state closely and spikes most per unit current, which
            lowers the decoded noise.
        tau_hidden: hidden membrane time constant, s (10 ms, between the others).
        tau_output: output membrane time constant, s. 20 ms; Section III orders
            ``tau_input < tau_hidden < tau_output``.
        t_ref: refractory period, s; 2 ms caps every rate at 500 Hz.
        syn_hidden: hidden current per unit weight and input spike.
        syn_output: output current per unit weight and hidden spike. 5 and 12 put
            the untrained network's hidden and output rates at about 190 and
            100 Hz at ``q = 0``: mid-range, so the rule can move the output
            either way.
        v_th_low: lower end of the threshold distribution (Section V: 0.7).
        v_th_high: upper end (Section V: 1.7).
        w_min: lower weight clip. Negative weights are allowed: the teacher
            decreases with states that every input neuron encodes increasingly.
        w_max: upper weight clip. +-2 bound drift over long runs; 10 s of
            learning on the test teacher never reaches them.
        alpha: decoder scale, units of `TORQUE_UNIT`. With ``beta`` and ``gamma``,
            ``y_hat ~ alpha N nu / beta - gamma = 0.02 nu - 2`` for an output rate
            ``nu`` in Hz: 100 Hz is 0 and 50 or 150 Hz is -1 or +1, the torque limit.
        beta: decoder decay rate, 1/s. 100/s (a 10 ms window) keeps the
            decoder's lag well inside the closed loop's bandwidth (LQR poles up to
            32/s; the robot's unstable pair grows at 7.5/s), so the SNN flights
            reach both waypoints (``tests/test_robobee_flight.py``); open loop, a
            longer window is smoother.
        gamma: decoder offset, units of `TORQUE_UNIT`.
        mu_hidden: learning rate of the input->hidden weights.
        mu_output: learning rate of the hidden->output weights. 1e-3: in closed
            loop the network must follow the teacher within tens of ms. At 1e-4,
            a presynaptic neuron firing at 100 Hz (mean ``r`` about 1.4 at
            ``tau_reward = 5 ms``) moves its weights by up to 1.4 per second,
            fast enough to follow a teacher varying at about 1 Hz open loop.
        tau_reward: reward time constant, s. A presynaptic spike's factor in
            Eq. (9) of the RoboBee paper falls as ``exp(-k dt / tau)`` after ``k``
            steps, so the trace lasts about ``sqrt(2 tau dt) = 1 ms`` (138 units
            of ``r`` per spike).
        dtype: floating dtype of every field.

    Returns:
        The parameters.
    """
    f = lambda x: jnp.asarray(x, dtype)  # noqa: E731
    q_range = f(q_range)
    return ControllerParams(
        dt=f(dt),
        a=0.5 / q_range,
        b=q_range,
        input_gain=f(input_gain),
        tau_input=f(tau_input),
        tau_hidden=f(tau_hidden),
        tau_output=f(tau_output),
        t_ref=f(t_ref),
        syn_hidden=f(syn_hidden),
        syn_output=f(syn_output),
        v_th_low=f(v_th_low),
        v_th_high=f(v_th_high),
        w_min=f(w_min),
        w_max=f(w_max),
        decoder=DecoderParams(alpha=f(alpha), beta=f(beta), gamma=f(gamma)),
        mu_hidden=f(mu_hidden),
        mu_output=f(mu_output),
        tau_reward=f(tau_reward),
    )


def _validate(config: ControllerConfig) -> None:
    for name in ("n_per_input", "n_hidden", "n_output"):
        n = getattr(config, name)
        if not isinstance(n, int) or n < 1:
            raise UserError(f"ControllerConfig.{name} must be a positive int, got {n!r}")
    if not 0.0 < config.connectivity <= 1.0:
        raise UserError(f"ControllerConfig.connectivity must lie in (0, 1], got {config.connectivity!r}")


def _lif(params: ControllerParams, tau: jax.Array, v_th: jax.Array) -> LIFParams:
    zero = jnp.zeros_like(params.dt)
    return LIFParams(
        tau=tau,
        r=jnp.ones_like(params.dt),
        v_th=v_th,
        v_reset=zero,
        v_rest=zero,
        t_ref=params.t_ref,
        dt=params.dt,
        sigma=zero,
    )


def controller_init(config: ControllerConfig, params: ControllerParams, *, key: jax.Array) -> ControllerState:
    """Draws a network as in Section V of the RoboBee paper and puts it at rest.

    Each possible synapse exists with probability ``config.connectivity``; existing
    ones get a weight ``U(0, 1)``; every neuron a threshold
    ``U(v_th_low, v_th_high)`` (``U(0.7, 1.7)`` by default). Potentials start at
    rest, the decoder trace at 0 and no neuron has spiked yet.

    Args:
        config: sizes and connectivity (static).
        params: the controller's parameters (thresholds' range, dtype).
        key: PRNG key, used once.

    Returns:
        The initial state.

    Raises:
        UserError: if a size is not a positive int or ``connectivity`` is not in (0, 1].
    """
    _validate(config)
    n_in, n_h, n_out = config.n_input, config.n_hidden, config.n_output
    dtype = params.dt.dtype
    k_mih, k_mho, k_wih, k_who, k_thi, k_thh, k_tho = jax.random.split(key, 7)
    del key
    mask_ih = jax.random.bernoulli(k_mih, config.connectivity, (n_in, n_h)).astype(dtype)
    mask_ho = jax.random.bernoulli(k_mho, config.connectivity, (n_h, n_out)).astype(dtype)
    w_ih = jax.random.uniform(k_wih, (n_in, n_h), dtype) * mask_ih
    w_ho = jax.random.uniform(k_who, (n_h, n_out), dtype) * mask_ho

    def thresholds(k, n):
        return jax.random.uniform(k, (n,), dtype, params.v_th_low, params.v_th_high)

    v_th_input = thresholds(k_thi, n_in)
    v_th_hidden = thresholds(k_thh, n_h)
    v_th_output = thresholds(k_tho, n_out)
    return ControllerState(
        ih=row_weights(w_ih, mask_ih),
        ho=row_weights(w_ho, mask_ho),
        v_th_input=v_th_input,
        v_th_hidden=v_th_hidden,
        v_th_output=v_th_output,
        input=lif_init(n_in, _lif(params, params.tau_input, v_th_input)),
        hidden=lif_init(n_h, _lif(params, params.tau_hidden, v_th_hidden)),
        output=lif_init(n_out, _lif(params, params.tau_output, v_th_output)),
        decoder=decoder_init(dtype),
        rule_ih=_RULE.init(w_ih),
        rule_ho=_RULE.init(w_ho),
    )


def controller_step(
    config: ControllerConfig,
    params: ControllerParams,
    state: ControllerState,
    q_lateral: jax.Array,
    y_teacher: jax.Array,
    learn: jax.Array,
) -> tuple[ControllerState, jax.Array]:
    """One neural step of the controller, from ``t_k`` to ``t_k + dt``.

    1. Encoding (Section III): ``q_hat = a (q + b)``; in each group of
       ``n_per_input`` neurons, the first half gets the current
       ``input_gain * q_hat_g`` and the second half ``input_gain * (1 - q_hat_g)``
       (antagonist halves, `spikejax.coding.antagonist_currents`), each threshold
       making a neuron a different rectified feature of ``q_g``.
    2. The input, hidden and output layers take one exact LIF step each
       (Eq. (6)-(7)); a layer's spikes of this step drive the next layer in the
       same step, with current ``syn * W^T spikes``.
    3. The output spikes are decoded by Eq. (8) into ``y_hat(t_k + dt)``.
    4. If ``learn``, both weight layers change by Eq. (9)-(10) on the error
       ``y_teacher - y_hat`` (see `spikejax.plasticity.reward_modulated_hebbian`),
       masked to existing synapses and clipped to ``[w_min, w_max]``. The
       rule's traces run whether or not ``learn`` is set.

    Args:
        config: sizes (static).
        params: traced parameters.
        state: the state at ``t_k``.
        q_lateral: ``[theta, theta_dot, x, x_dot]`` at ``t_k`` (rad, rad/s, m, m/s),
            shape ``(4,)``.
        y_teacher: the teacher's control (the LQR output) in units of
            `TORQUE_UNIT`, shape ``()``.
        learn: bool (or 0/1), shape ``()``; traced, so learning can be switched
            on and off inside one compiled loop.

    Returns:
        The state at ``t_k + dt`` and the decoded control ``y_hat(t_k + dt)`` in
        units of `TORQUE_UNIT`, shape ``()``.
    """
    q_hat = shift_scale(q_lateral, params.a, params.b)
    current_in = antagonist_currents(q_hat, config.n_per_input, params.input_gain)
    p_in = _lif(params, params.tau_input, state.v_th_input)
    p_h = _lif(params, params.tau_hidden, state.v_th_hidden)
    p_out = _lif(params, params.tau_output, state.v_th_output)
    dtype = state.ih.w0.dtype
    lif_in, s_in = lif_step(p_in, state.input, current_in)
    current_h = params.syn_hidden * propagate(state.ih, s_in, MAX_ROWS[0])
    lif_h, s_h = lif_step(p_h, state.hidden, current_h)
    current_out = params.syn_output * propagate(state.ho, s_h, MAX_ROWS[1])
    lif_out, s_out = lif_step(p_out, state.output, current_out)
    decoder, y_hat = decoder_step(params.decoder, state.decoder, s_out, params.dt)

    error = y_teacher - y_hat
    gate = jnp.asarray(learn, dtype)
    p_ih = RewardHebbianParams(mu=params.mu_hidden * gate, tau=params.tau_reward, dt=params.dt)
    p_ho = RewardHebbianParams(mu=params.mu_output * gate, tau=params.tau_reward, dt=params.dt)
    d_ih, rule_ih = row_increment(p_ih, state.rule_ih, s_in, error)
    d_ho, rule_ho = row_increment(p_ho, state.rule_ho, s_h, error)
    new = ControllerState(
        ih=add_to_rows(state.ih, d_ih, params.w_min, params.w_max),
        ho=add_to_rows(state.ho, d_ho, params.w_min, params.w_max),
        v_th_input=state.v_th_input,
        v_th_hidden=state.v_th_hidden,
        v_th_output=state.v_th_output,
        input=lif_in,
        hidden=lif_h,
        output=lif_out,
        decoder=decoder,
        rule_ih=rule_ih,
        rule_ho=rule_ho,
    )
    return new, y_hat
