"""``spikejax bench robobee``: closed-loop RoboBee flights per second, spikejax against Brian2.

One flight is the closed loop of Sec. V of the RoboBee paper: the 200-100-50
LIF controller steers the robot laterally while it learns online from the LQR
teacher (reward-modulated Hebbian rule, Eq. (9)-(10), on both weight layers),
the altitude controller sets the lift, and the robot is integrated one physics
step per neural step (``dt = 0.1 ms``). The flight plan is the paper's first
one, ``q0 -> q1 -> q2`` (`robots.robobee.flight.flight_plan("waypoints")`),
scaled to the flight's duration: the first 20 % holds the robot at ``q0`` (the
paper's 500 ms hold of a 2.5 s flight), the rest is split equally between the
two waypoints.

- `run_spikejax_flights`: ``jax.jit(jax.vmap(fly))`` over network seeds (and,
  optionally, robots drawn by `robots.robobee.params.randomize`): SNN,
  plasticity, decoder, teacher and MJX physics in one compiled ``lax.scan``,
  on one device or split over several (`spikejax.devices.shard_batch`).
- `run_brian2_closed_loop`: the paper's own setup. "At every time step, the
  simulator calls a function to update the RoboBee state and another function
  to compute the weight changes for each set of synapses following equation
  (10)": the same network (the same drawn weights, connectivity and thresholds
  as spikejax's flight 0) in Brian2's runtime mode, and a
  ``network_operation`` that runs at the end of every step (see
  `Brian2Flight`). `run_brian2_on_all_cores` runs one such flight per core
  side by side, as a Brian2 user with several cores would.

Each returns a row with compile or build time apart from run time, flights per
second, simulated seconds per wall-clock second and aggregate neuron updates
per second (350 neurons x steps x flights / run seconds). `main` prints the
closed-loop table and then the network-alone table of
`robots.robobee.bench_network.main_network`.

Notes:
    What Brian2 does in one step ``k`` (from ``t_k`` to ``t_k + dt``), in the
    order of `controller_step` (every object in one schedule slot, ordered):

    1. The input layer integrates the current that the network operation set
       at the end of the previous step (``method='exact'``, refractory 2 ms),
       tests its thresholds and resets.
    2. The input -> hidden synapses add ``syn_hidden * w`` to the hidden
       neurons' current ``I`` for every input spike of this step (no delay);
       the hidden layer integrates that current over the step, tests and
       resets; the same for hidden -> output (``syn_output``).
    3. The network operation (Python, NumPy) reads the three layers' spikes of
       the step (each group's ``_spikespace``, as ``NeuronGroup.spikes``
       reads it), updates the decoder of Eq. (8), the
       traces of Eq. (9) and, by Eq. (10), the weights of both synapse sets
       in place in Brian2's own arrays (clipped to ``[w_min, w_max]``);
       applies the lift of the altitude controller and the decoded torque to
       the robot, one semi-implicit Euler step (MuJoCo's integrator, so the
       arithmetic of the MJX step of `robots.robobee.physics`) of Eq. (4)-(5),
       `robots.robobee.dynamics.rhs` written out in scalar Python (float64;
       held at ``q0`` during the hold); then computes the next step's target,
       LQR teacher and encoder currents (antagonist halves as in
       `controller_step`) and writes them into the input layer, and zeroes
       the synaptic currents of the other two layers.

    That is the algorithm of `robots.robobee.flight.fly` step for step;
    Brian2 computes in float64 and spikejax in float32, so the spike trains
    part where float32 rounding decides a threshold test, and from there the
    two learning networks drift apart like two seeds (over the first 50 ms of
    a scaled flight they give the same outputs, ``tests/test_robobee_bench.py``).

    Where the time goes, measured on a 2-core CPU (one run, so rough):
    Brian2 takes about 90 us per step, a little over half of it in the network
    operation, and one ``Network.run`` costs about 0.2 s of preparation (so a
    flight is timed whole: a 0.2 s run extrapolated would understate Brian2
    twofold). spikejax takes 3.3-3.8 us per flight-step on one device from 16
    flights on: about 0.8 us the MJX robot where it moves (the hold does not
    step it), the rest the SNN with its plasticity, decoder and teacher. The
    learned weights are kept per presynaptic row and read only for the neurons
    that spiked, found from the spikes packed as bits (`spikejax.synapses`), so
    the step does not read and rewrite every flight's 25,000 weights and large
    batches stay about as fast as small ones. Split over the two cores'
    devices, 16-256 flights take 1.3-1.9 us of wall time per flight-step.
"""

from __future__ import annotations

import argparse
import csv
import math
import multiprocessing
import os
import platform
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from robots.common import run_isolated
from robots.robobee import bench_network
from robots.robobee.controller import TORQUE_UNIT
from robots.robobee.controller import ControllerConfig
from robots.robobee.controller import controller_init
from robots.robobee.controller import controller_params
from robots.robobee.flight import flight_plan
from robots.robobee.flight import fly
from robots.robobee.lqr import altitude_params
from robots.robobee.lqr import lateral_gain
from robots.robobee.params import max_lift
from robots.robobee.params import randomize
from robots.robobee.params import robobee_params
from spikejax.devices import cpu_devices_for_run
from spikejax.devices import shard_batch
from spikejax.errors import UserError

__all__ = [
    "BATCHES",
    "Brian2Flight",
    "FlightSetup",
    "flight_setup",
    "flight_steps",
    "main",
    "network_key",
    "run_brian2_closed_loop",
    "run_brian2_on_all_cores",
    "run_spikejax_flights",
    "timed_duration",
]

DT = 1e-4  # s, the neural and physics step
FLIGHT_S = 2.5  # s: hold 0.5 s + 2 x 1 s, the paper's first flight
HOLD_FRACTION = 0.2
RECORD_EVERY = 10
# 64: about where the batch's weights (200 KB per flight) stop fitting in a 32 MB L3 cache.
BATCHES = (1, 16, 64, 256, 1024, 4096)
# Flight-steps (flights x steps) one timed spikejax run may take: a batch whose
# whole flights would exceed it flies shorter flights and its flights/s is
# extrapolated to the full flight (every step costs the same, hold included).
STEP_BUDGET = 256 * 25_000
# Distance (x, z) to a waypoint at the end of its segment that counts as reached, m.
REACHED_M = 5e-3
N_NEURONS = 350

ROW_FIELDS = ("impl", "batch", "flight_s", "timed_s", "build_or_compile_s", "run_s", "flights_per_s",
              "sim_s_per_wall_s", "neuron_updates_per_s", "reached_q1", "reached_q2")


def timed_duration(batch: int, duration: float, step_budget: int = STEP_BUDGET) -> float:
    """Seconds of each of ``batch`` flights to time: ``duration``, or shorter (at least 0.05 s) to fit ``step_budget``.

    The result is a whole number of `flight_steps` blocks.
    """
    steps = round(duration / DT)
    if batch * steps > step_budget:
        steps = max(step_budget // batch, round(0.05 / DT))
    hold, segment = flight_steps(steps * DT)
    return (hold + 2 * segment) * DT


def flight_steps(duration: float, record_every: int = RECORD_EVERY) -> tuple[int, int]:
    """``(hold_steps, segment_steps)`` of a ``duration``-second flight: 20 % hold, two equal segments.

    Both are multiples of ``record_every``; ``hold + 2 segments`` is ``duration``
    rounded down to whole blocks of ``record_every`` steps (2.5 s: 5,000 and 10,000).
    """
    blocks = round(duration / DT) // record_every
    hold = round(HOLD_FRACTION * blocks)
    segment = (blocks - hold) // 2
    if segment < 1:
        raise ValueError(f"a flight of {duration} s is too short for a hold and two segments")
    return hold * record_every, segment * record_every


class FlightSetup(NamedTuple):
    """Everything a batch of flights shares or draws, as `fly` takes it.

    Attributes:
        config: network sizes (static).
        cparams: controller parameters (`controller_params` defaults).
        robots: the flown robots, each field ``(batch,)``; the nominal robot
            repeated unless randomized.
        K: the teacher's LQR gain for the nominal robot, ``(4,)``.
        altitude: the altitude controller's gains.
        plan: ``q0`` and the two waypoints of the paper's first flight.
        keys: one network key per flight, ``(batch,)``; flight 0's is the
            network that Brian2 simulates for the same seed.
    """

    config: ControllerConfig
    cparams: object
    robots: object
    K: jax.Array
    altitude: object
    plan: object
    keys: jax.Array


def network_key(seed, flight) -> jax.Array:
    """The network key of flight ``flight`` for ``seed``, whatever the batch size."""
    return jax.random.fold_in(jax.random.key(seed), flight)


def flight_setup(batch: int, seed: int, randomize_robots: bool = False) -> FlightSetup:
    """The batch's setup for ``seed``: flight ``b`` has the network of `network_key` ``(seed, b)``.

    The robots are the nominal one, or drawn by `randomize` from ``key(seed + 1)``.
    """
    robot = robobee_params()
    keys = jax.vmap(network_key, in_axes=(None, 0))(seed, jnp.arange(batch))
    if randomize_robots:
        robots = jax.vmap(lambda k: randomize(robot, key=k))(jax.random.split(jax.random.key(seed + 1), batch))
    else:
        robots = jax.tree.map(lambda x: jnp.broadcast_to(x, (batch,)), robot)
    K = jnp.asarray(lateral_gain(robot), jnp.float32).reshape(4)
    return FlightSetup(ControllerConfig(), controller_params(), robots, K, altitude_params(), flight_plan("waypoints"),
                       keys)


def _reached(t: np.ndarray, q: np.ndarray, plan, hold_steps: int, segment_steps: int) -> tuple[float, float]:
    """Fraction of flights within `REACHED_M` of each waypoint at the end of its segment (``q`` ``(b, n, 6)``)."""
    out = []
    for w in range(2):
        end = (hold_steps + (w + 1) * segment_steps) * DT
        i = min(int(np.searchsorted(t, end - 1e-9)), len(t) - 1)
        target = np.asarray(plan.waypoints[w])
        out.append(float(np.mean(np.hypot(q[:, i, 2] - target[2], q[:, i, 3] - target[3]) < REACHED_M)))
    return out[0], out[1]


def _row(impl, batch, flight_s, timed_s, build_s, run_s, reached=(math.nan, math.nan), **extra) -> dict:
    """A result row; throughputs are for whole ``flight_s`` flights, extrapolated from ``timed_s`` of each."""
    run_per_flight_batch = run_s * flight_s / timed_s
    steps = round(flight_s / DT)
    row = dict(impl=impl, batch=batch, flight_s=flight_s, timed_s=timed_s, build_or_compile_s=build_s, run_s=run_s,
               flights_per_s=batch / run_per_flight_batch,
               sim_s_per_wall_s=batch * flight_s / run_per_flight_batch,
               neuron_updates_per_s=N_NEURONS * steps * batch / run_per_flight_batch,
               reached_q1=reached[0], reached_q2=reached[1])
    row.update(extra)
    return row


# ----------------------------------------------------------------- spikejax


def run_spikejax_flights(batch: int, duration: float = FLIGHT_S, seed: int = 0, *, randomize_robots: bool = False,
                         step_budget: int = STEP_BUDGET, repeats: int = 1, devices: int = 1) -> dict:
    """``batch`` closed-loop flights of ``duration`` seconds as one ``jax.jit(jax.vmap(fly))``.

    The program is compiled ahead (``lower(...).compile()``, ``build_or_compile_s``)
    and run to completion ``repeats`` times (``run_s``: the fastest). With
    ``devices > 1`` the flights are split evenly over the first ``devices`` of
    ``jax.devices()`` (`spikejax.devices.shard_batch`: each CPU device runs on
    its own core), and the compile time is the first call's time less ``run_s``. If
    ``batch`` whole flights exceed ``step_budget`` flight-steps, the flights
    timed are shortened to fit it (same 20 % hold and two segments, at least
    0.05 s) and the throughputs extrapolated to ``duration``: the scan's steps
    all cost the same.

    Args:
        batch: flights flown at once, each with its own network seed.
        duration: simulated seconds of one flight (2.5: the paper's hold and two 1 s legs).
        seed: seed of the network keys (flight 0 is Brian2's network for the same seed).
        randomize_robots: fly robots whose mass, drag and inertia differ by up to
            +-20 % (`robots.robobee.params.randomize`), the teacher designed for
            the nominal one.
        step_budget: flight-steps one timed run may take.
        repeats: timed runs.
        devices: devices the batch is split over (1: a plain ``jax.jit``).

    Returns:
        A row (`ROW_FIELDS`, and ``devices``); ``reached_q1``/``reached_q2`` are the fractions of
        flights within 5 mm of each waypoint at the end of its segment (NaN
        when the flights were shortened), ``recording`` the flights'
        `robots.robobee.flight.Recording` (NumPy).
    """
    setup = flight_setup(batch, seed, randomize_robots)
    timed = timed_duration(batch, duration, step_budget)
    hold_steps, segment_steps = flight_steps(timed)

    def one(robot, key):
        return fly(setup.config, setup.cparams, robot, setup.K, setup.altitude, setup.plan, jnp.bool_(True),
                   hold_steps=hold_steps, segment_steps=segment_steps, record_every=RECORD_EVERY, key=key)

    if devices > jax.device_count():
        raise UserError(f"{devices} devices asked, JAX presents {jax.device_count()}")
    if devices == 1:
        t0 = time.perf_counter()
        compiled = jax.jit(jax.vmap(one)).lower(setup.robots, setup.keys).compile()
        compile_s = time.perf_counter() - t0
    else:
        compiled = shard_batch(jax.vmap(one), jax.devices()[:devices])
        t0 = time.perf_counter()
        jax.block_until_ready(compiled(setup.robots, setup.keys))
        first_s = time.perf_counter() - t0
    run_s = math.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        rec = jax.block_until_ready(compiled(setup.robots, setup.keys))
        run_s = min(run_s, time.perf_counter() - t0)
    if devices > 1:
        compile_s = max(first_s - run_s, 0.0)
    rec = jax.tree.map(np.asarray, rec)
    reached = (math.nan, math.nan)
    if math.isclose(timed, duration, abs_tol=DT / 2):
        reached = _reached(rec.t[0], rec.q, setup.plan, hold_steps, segment_steps)
    impl = "spikejax jit(vmap(fly))" + (" randomized robots" if randomize_robots else "")
    impl += f", {devices} devices" if devices > 1 else ""
    return _row(impl, batch, duration, timed, compile_s, run_s, reached, recording=rec, devices=devices)


# ----------------------------------------------------------------- Brian2


class Brian2Flight:
    """One closed-loop flight in Brian2's runtime mode: the network in Brian2, the rest in a network operation.

    The network is the one `controller_init` draws from ``key`` (the same
    weights, connectivity and thresholds as the spikejax flight of that key);
    the controller's constants are ``cparams``'s. The schedule and the network
    operation are described in the module's notes.

    Args:
        key: the network's key.
        hold_steps: steps the robot is held at ``q0`` (target ``q0``).
        segment_steps: steps spent on each waypoint.
        learn: apply Eq. (10) (the traces run either way), as `controller_step`'s ``learn``.
        use_snn: the decoded output steers (else the teacher does, the SNN learning beside it).
        robot: the flown robot (`robobee_params` if None); the teacher is designed for the nominal one.
        record_every: the recording's sampling, as in `fly`.

    Attributes:
        net: the `brian2.Network`.
        counts: spikes per neuron so far, input then hidden then output, ``(350,)``.
    """

    def __init__(self, key: jax.Array, hold_steps: int, segment_steps: int, *, learn: bool = True,
                 use_snn: bool = True, robot=None, record_every: int = RECORD_EVERY):
        import brian2 as b2

        config, cp = ControllerConfig(), controller_params()
        f = lambda x: float(np.asarray(x))  # noqa: E731
        self.config = config
        self.hold_steps, self.segment_steps, self.record_every = hold_steps, segment_steps, record_every
        self.n_steps = hold_steps + 2 * segment_steps
        self.learn, self.use_snn = learn, use_snn
        state = jax.tree.map(lambda x: np.asarray(x, np.float64), controller_init(config, cp, key=key))
        self.state0 = state
        nominal = robobee_params()
        self.robot = jax.tree.map(np.float64, nominal if robot is None else robot)
        self.K = np.asarray(jnp.asarray(lateral_gain(nominal), jnp.float32), np.float64).reshape(4)
        alt = jax.tree.map(f, altitude_params())
        self.kp, self.kd, self.cos_min = alt.kp, alt.kd, alt.cos_min
        plan = flight_plan("waypoints")
        self.targets = np.concatenate([np.asarray(plan.q0, np.float64)[None], np.asarray(plan.waypoints, np.float64)])
        self.dt = f(cp.dt)
        self.a, self.b = np.asarray(cp.a, np.float64), np.asarray(cp.b, np.float64)
        self.input_gain = f(cp.input_gain)
        self.alpha, self.gamma = f(cp.decoder.alpha), f(cp.decoder.gamma)
        self.decoder_decay = math.exp(-f(cp.decoder.beta) * self.dt)
        self.mu_h, self.mu_o, self.tau_r = f(cp.mu_hidden), f(cp.mu_output), f(cp.tau_reward)
        self.w_min, self.w_max = f(cp.w_min), f(cp.w_max)
        self.lift_max = float(max_lift(self.robot))
        self.robot_py = {name: float(x) for name, x in self.robot._asdict().items()}
        self.K_py = tuple(float(x) for x in self.K)
        self.targets_py = [tuple(float(x) for x in t) for t in self.targets]
        self.minus_inv_tau_r = -1.0 / self.tau_r
        self.n_input, self.n_hidden = config.n_input, config.n_hidden
        # Encoder: input neuron n reads the lateral error e_g of its group g = n // n_per_input
        # as input_gain * q_hat_g (first half) or input_gain * (1 - q_hat_g) (second half),
        # q_hat = a (e + b), that is offset_n + slope_n e_g.
        n_per = config.n_per_input
        self.group = np.repeat(np.arange(4), n_per)
        antagonist = np.tile(np.arange(n_per) >= n_per // 2, 4)
        a, b = self.a[self.group], self.b[self.group]
        self.slope = np.where(antagonist, -1.0, 1.0) * self.input_gain * a
        self.offset = self.input_gain * np.where(antagonist, 1.0 - a * b, a * b)
        self.e = np.zeros(4)

        b2.defaultclock.dt = self.dt * b2.second
        eqs = """dv/dt = (I - v) / tau : 1 (unless refractory)
        I : 1
        v_th : 1 (constant)
        tau : second (constant)"""
        sizes = (config.n_input, config.n_hidden, config.n_output)
        taus = (f(cp.tau_input), f(cp.tau_hidden), f(cp.tau_output))
        thresholds = (state.v_th_input, state.v_th_hidden, state.v_th_output)
        self.groups = []
        for n, tau, v_th, name in zip(sizes, taus, thresholds, ("input", "hidden", "output")):
            g = b2.NeuronGroup(n, eqs, threshold="v >= v_th", reset="v = 0", refractory=f(cp.t_ref) * b2.second,
                               method="exact", name=f"robobee_{name}*")
            g.v_th = v_th
            g.tau = tau * b2.second
            self.groups.append(g)
        self.synapses, self.pre_index = [], []
        masks = [np.asarray(m, np.float64) for m in (state.mask_ih, state.mask_ho)]
        weights = [np.asarray(w, np.float64) for w in (state.w_ih, state.w_ho)]
        for (pre, post), mask, w, c in zip(zip(self.groups, self.groups[1:]), masks, weights,
                                           (f(cp.syn_hidden), f(cp.syn_output))):
            syn = b2.Synapses(pre, post, "w : 1", on_pre="I_post += c_syn * w", namespace={"c_syn": c})
            i, j = np.nonzero(mask)
            syn.connect(i=i, j=j)
            syn.w = w[i, j]
            self.synapses.append(syn)
            self.pre_index.append(i)
        # Row of each synapse's presynaptic neuron in the rule's traces (input neurons, then hidden ones).
        self.pre_rows = [self.pre_index[0], config.n_input + self.pre_index[1]]
        # One slot, ordered as controller_step: each layer integrates, fires and
        # resets before its spikes reach the next layer in the same step.
        order = []
        for g, syn in zip(self.groups, [*self.synapses, None]):
            order += [g.state_updater, g.thresholder["spike"], g.resetter["spike"]]
            if syn is not None:
                order.append(syn.pre)
        for k, obj in enumerate(order):
            obj.when, obj.order = "groups", k
        self.operation = b2.NetworkOperation(self._step, dt=self.dt * b2.second, when="end")
        self.net = b2.Network(*self.groups, *self.synapses, self.operation)
        self.net.store("start")
        self.reset()

    def reset(self) -> None:
        """Back to the flight's start: the network as drawn (`brian2.Network.restore`), robot at ``q0``."""
        self.net.restore("start")
        n_in, n_h = self.config.n_input, self.config.n_hidden
        self.k = 0
        self.q = tuple(float(x) for x in self.targets[0])
        self.trace = 0.0
        # Eq. (9) for the input neurons, then the hidden ones: time since the last spike and reward trace.
        self.since = np.full(n_in + n_h, np.inf)
        self.r = np.zeros(n_in + n_h)
        self.counts = np.zeros(N_NEURONS, np.int64)
        self.records = []
        self.op_s = 0.0
        # Brian2's own arrays, read and written in place by the network operation.
        self.w = [syn.variables["w"].get_value() for syn in self.synapses]
        self.current = [g.variables["I"].get_value() for g in self.groups]
        self.spikespace = [g.variables["_spikespace"].get_value() for g in self.groups]
        self._set_inputs()

    def _set_inputs(self) -> None:
        """The target, the teacher and the input layer's currents for step ``k`` from the state ``q(t_k)``."""
        k = self.k
        segment = 0 if k < self.hold_steps else min(1 + (k - self.hold_steps) // self.segment_steps, 2)
        self.target = target = self.targets_py[segment]
        q = self.q
        e = self.e
        e[0], e[1], e[2], e[3] = q[0] - target[0], q[1] - target[1], q[2] - target[2], q[4] - target[4]
        K = self.K_py
        y = -(K[0] * e[0] + K[1] * e[1] + K[2] * e[2] + K[3] * e[3]) / TORQUE_UNIT
        self.y_lqr = min(max(y, -1.0), 1.0)
        # input_gain * q_hat or input_gain * (1 - q_hat), q_hat = a (e + b): an affine function of e.
        current = self.current[0]
        np.take(e, self.group, out=current)
        current *= self.slope
        current += self.offset
        self.current[1].fill(0.0)
        self.current[2].fill(0.0)

    def _physics(self, lift: float, torque: float) -> None:
        """One semi-implicit Euler step (MuJoCo's integrator) of Eq. (4)-(5) (`rhs`), then the floor.

        The clipping of `clip_controls` and the dynamics of `rhs` in scalar
        Python (``tests/test_robobee_bench.py`` checks them against both).
        """
        p, dt = self.robot_py, self.dt
        f_lift = min(max(lift, 0.0), self.lift_max)
        tau_c = min(max(torque, -p["torque_limit"]), p["torque_limit"])
        theta, theta_dot, x, z, x_dot, z_dot = self.q
        c, s = math.cos(theta), math.sin(theta)
        f_d = -p["b_w"] * (x_dot * c - z_dot * s + p["r_w"] * theta_dot)
        x_ddot = (f_lift * s + f_d * c) / p["mass"]
        z_ddot = (f_lift * c - f_d * s) / p["mass"] - p["g"]
        theta_ddot = (tau_c + p["r_w"] * f_d) / p["inertia_y"]
        theta_dot, x_dot, z_dot = theta_dot + dt * theta_ddot, x_dot + dt * x_ddot, z_dot + dt * z_ddot
        theta, x, z = theta + dt * theta_dot, x + dt * x_dot, z + dt * z_dot
        if z < 0.0:
            z, z_dot = 0.0, max(z_dot, 0.0)
        self.q = (theta, theta_dot, x, z, x_dot, z_dot)

    def _step(self) -> None:
        """The network operation at the end of step ``k``: decoder, rule, robot, next step's inputs."""
        t0 = time.perf_counter()
        s_in, s_h, s_out = (ss[: ss[-1]] for ss in self.spikespace)
        counts = self.counts
        counts[s_in] += 1
        counts[self.n_input + s_h] += 1
        counts[self.n_input + self.n_hidden + s_out] += 1
        # Eq. (8): the output layer's spikes of this step, decayed over it.
        self.trace = self.decoder_decay * (self.trace + len(s_out))
        y_hat = self.alpha * self.trace - self.gamma
        error = self.y_lqr - y_hat
        sign = 1.0 if error > 0 else (-1.0 if error < 0 else 0.0)
        # Eq. (9) for the input and hidden neurons (the presynaptic ones), then
        # Eq. (10) for the input -> hidden and hidden -> output synapses.
        since, r = self.since, self.r
        since += self.dt
        since[s_in] = 0.0
        since[self.n_input + s_h] = 0.0
        r += sign
        r *= np.exp(since * self.minus_inv_tau_r)
        if self.learn:
            for w, pre, mu in zip(self.w, self.pre_rows, (self.mu_h, self.mu_o)):
                w += mu * r[pre]
                np.clip(w, self.w_min, self.w_max, out=w)
        if self.k % self.record_every == self.record_every - 1:
            self.records.append((*self.q, *self.target, y_hat, self.y_lqr))
        # The robot: the altitude controller's lift and the SNN's (or the teacher's) torque.
        if self.k >= self.hold_steps:
            q, target = self.q, self.target
            accel = self.kp * (target[3] - q[3]) + self.kd * (target[5] - q[5])
            lift = self.robot_py["mass"] * (self.robot_py["g"] + accel) / max(math.cos(q[0]), self.cos_min)
            y = min(max(y_hat, -1.0), 1.0) if self.use_snn else self.y_lqr
            self._physics(lift, y * TORQUE_UNIT)
        self.k += 1
        self._set_inputs()
        self.op_s += time.perf_counter() - t0

    def run(self, n_steps: int) -> None:
        """Runs ``n_steps`` steps from where the flight is."""
        import brian2 as b2

        self.net.run(n_steps * self.dt * b2.second)

    def recording(self) -> dict:
        """What was recorded every ``record_every`` steps: ``t``, ``q``, ``target``, ``y_hat``, ``y_lqr`` (as `fly`)."""
        rec = np.array(self.records, np.float64).reshape(-1, 14)
        n = len(rec)
        return dict(t=(np.arange(n) + 1) * self.record_every * self.dt, q=rec[:, :6], target=rec[:, 6:12],
                    y_hat=rec[:, 12], y_lqr=rec[:, 13])


def run_brian2_closed_loop(duration: float = FLIGHT_S, seed: int = 0, target: str = "cython", *,
                           flight_s: float = FLIGHT_S, scale_plan: bool = True, learn: bool = True,
                           use_snn: bool = True, warmup_steps: int = RECORD_EVERY, barrier=None,
                           repeats: int = 1) -> dict:
    """One closed-loop flight in Brian2's runtime mode (`Brian2Flight`), timed on ``duration`` simulated seconds.

    The network is spikejax's flight 0 of the same ``seed``. A first run of
    ``warmup_steps`` steps generates (and for Cython compiles, or loads from
    Cython's cache) the code: ``build_or_compile_s`` is the network's
    construction plus that run. Then the flight restarts (`Brian2Flight.reset`)
    and ``duration`` seconds are timed ``repeats`` times, the flight restarted
    before each (``run_s``: the fastest ``Network.run``, its
    preparation included: ``prepare_s``, the time of a further run of
    ``warmup_steps``, measures that); flights/s is extrapolated to a
    ``flight_s`` flight if ``duration`` is shorter (Brian2's time per step is
    constant). If Cython cannot compile, NumPy runs instead and ``impl`` says so.

    Args:
        duration: simulated seconds to run and time.
        seed: network seed (as `run_spikejax_flights`).
        target: ``"cython"`` or ``"numpy"`` (``brian2.prefs.codegen.target``).
        flight_s: the flight length the throughputs are given for.
        scale_plan: the plan (20 % hold, two segments) is scaled to ``duration``
            (True), or is that of a ``flight_s`` flight, of which the first
            ``duration`` seconds are flown (False: e.g. ``duration = 1.5`` flies
            the hold and the first leg of a 2.5 s flight).
        learn: apply Eq. (10).
        use_snn: the SNN steers (else the teacher).
        warmup_steps: steps of the code-generating first run.
        barrier: if given (a ``multiprocessing`` barrier), waited on just before each
            timed run, so that flights in several processes are timed together.
        repeats: timed runs (the recording and weights are those of the first).

    Returns:
        A row (`ROW_FIELDS`) with ``recording`` (`Brian2Flight.recording`),
        ``counts`` (spikes per neuron), ``w_ih``/``w_ho`` (final weights, dense),
        ``op_s`` (time in the network operation, within ``run_s``) and
        ``reached_q1``/``reached_q2`` (within 5 mm at the end of a segment that was flown).
    """
    import brian2 as b2

    hold_steps, segment_steps = flight_steps(duration if scale_plan else flight_s)
    n_steps = round(duration / DT)
    key = network_key(seed, 0)
    impl = f"Brian2 runtime ({target}) + network_operation"
    old_target = b2.prefs.codegen.target
    try:
        b2.prefs.codegen.target = target
        t0 = time.perf_counter()
        try:
            flight = Brian2Flight(key, hold_steps, segment_steps, learn=learn, use_snn=use_snn)
            flight.run(warmup_steps)
        except Exception as err:  # noqa: BLE001 - whatever broke the compiler: fall back, and say so
            if target == "numpy":
                raise
            b2.prefs.codegen.target = "numpy"
            impl = f"Brian2 runtime (numpy; {target} failed: {type(err).__name__}) + network_operation"
            flight = Brian2Flight(key, hold_steps, segment_steps, learn=learn, use_snn=use_snn)
            flight.run(warmup_steps)
        build_s = time.perf_counter() - t0
        run_s, result = math.inf, None
        for _ in range(repeats):
            flight.reset()
            if barrier is not None:
                barrier.wait()
            t0 = time.perf_counter()
            flight.run(n_steps)
            run_s = min(run_s, time.perf_counter() - t0)
            if result is None:
                weights = [np.asarray(syn.w[:]) for syn in flight.synapses]
                result = flight.recording(), flight.counts.copy(), flight.op_s, weights
        flight.reset()
        t0 = time.perf_counter()
        flight.run(warmup_steps)
        prepare_s = time.perf_counter() - t0
    finally:
        b2.prefs.codegen.target = old_target
    rec, counts, op_s, weights = result
    reached = []
    for w in range(2):
        end_step = hold_steps + (w + 1) * segment_steps
        if end_step > n_steps:
            reached.append(math.nan)
        else:
            reached.append(_reached(rec["t"], rec["q"][None], flight_plan("waypoints"), hold_steps,
                                    segment_steps)[w])
    dense = []
    for w_syn, mask in zip(weights, (flight.state0.mask_ih, flight.state0.mask_ho)):
        mask = np.asarray(mask)
        w = np.zeros(mask.shape)
        w[np.nonzero(mask)] = w_syn
        dense.append(w)
    return _row(impl, 1, flight_s, n_steps * DT, build_s, run_s, reached, recording=rec, counts=counts,
                w_ih=dense[0], w_ho=dense[1], op_s=op_s, prepare_s=prepare_s)


def run_brian2_on_all_cores(processes: int, duration: float = FLIGHT_S, seed: int = 0, target: str = "cython", *,
                            flight_s: float = FLIGHT_S, repeats: int = 1) -> dict:
    """``processes`` Brian2 flights at once, one process each: what a Brian2 user gets from that many cores.

    Brian2's runtime mode runs one flight on one core; a user with several
    cores runs several flights side by side. Each process builds its flight
    (`run_brian2_closed_loop`) and then all start their timed run together
    (a barrier), ``repeats`` times; the row's ``run_s`` is the slowest
    process's fastest run, so its flights/s is the aggregate of all of them.

    Returns:
        A row (`ROW_FIELDS`) with ``batch = processes``; ``build_or_compile_s`` is the slowest build.
    """
    context = multiprocessing.get_context("spawn")
    with context.Manager() as manager:
        barrier = manager.Barrier(processes)
        with ProcessPoolExecutor(processes, mp_context=context) as pool:
            futures = [pool.submit(run_brian2_closed_loop, duration, seed, target, flight_s=flight_s, barrier=barrier,
                                   repeats=repeats) for _ in range(processes)]
            rows = [f.result() for f in futures]
    impl = f"{rows[0]['impl']}, {processes} processes at once"
    return _row(impl, processes, flight_s, rows[0]["timed_s"], max(r["build_or_compile_s"] for r in rows),
                max(r["run_s"] for r in rows), (rows[0]["reached_q1"], rows[0]["reached_q2"]))


# ----------------------------------------------------------------- CLI


def _batches(trials) -> tuple[int, ...]:
    """`BATCHES` up to ``trials`` (and ``trials`` itself), or all of them."""
    if not trials:
        return BATCHES
    return tuple(sorted({b for b in BATCHES if b <= trials} | {int(trials)}))


def main(args: argparse.Namespace) -> int:
    """``spikejax bench robobee``: the closed-loop table, then the network-alone table.

    Reads from ``args`` (each optional): ``trials`` (the largest batch of
    flights; default: every batch of `BATCHES`), ``out`` (a directory for
    ``bench_robobee.csv``, and ``bench_robobee_network.csv`` from the network
    table), ``duration`` (simulated seconds of a spikejax flight, default 2.5),
    ``seed`` (default 0), ``repeats`` (timed runs per row, Brian2's and
    spikejax's, the fastest kept; default 3), ``randomize`` (also fly randomized robots at the largest
    batch), ``brian2_target`` (``"cython"``, the default, or ``"numpy"``),
    ``network`` (False skips the network-alone table) and ``cpu_devices`` (the
    CPU devices JAX presents, default one per core; set before JAX starts).

    Brian2 runs in fresh processes of its own (`run_isolated`): one flight on
    one core (the paper's setup, the ``x Brian2`` reference), then as many
    flights side by side as there are devices (`run_brian2_on_all_cores`, the
    ``x Brian2 on all cores`` reference). Each spikejax batch runs on one
    device, and, from a batch of one flight per device on, also split over all devices.
    """
    n_dev = cpu_devices_for_run(getattr(args, "cpu_devices", None))
    duration = float(getattr(args, "duration", None) or FLIGHT_S)
    seed = int(getattr(args, "seed", None) or 0)
    repeats = int(getattr(args, "repeats", None) or 3)
    batches = _batches(getattr(args, "trials", None))
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, "
          f"{n_dev} x {jax.devices()[0].platform}, jax {jax.__version__}")
    hold, segment = flight_steps(duration)
    print(f"RoboBee closed loop: 200-100-50 LIF SNN + Hebbian rule (both layers) + Eq. (8) decoder + LQR teacher + "
          f"physics, dt = {DT * 1e3:g} ms; flight q0 -> q1 -> q2 of {duration:g} s "
          f"(hold {hold * DT:g} s, 2 x {segment * DT:g} s), seed {seed}")
    brian2_target = getattr(args, "brian2_target", None) or "cython"
    runs = [lambda: run_isolated(run_brian2_closed_loop, duration, seed, brian2_target, flight_s=duration,
                                 repeats=repeats)]
    if n_dev > 1:
        runs.append(lambda: run_brian2_on_all_cores(n_dev, duration, seed, brian2_target, flight_s=duration,
                                                    repeats=repeats))
    for b in batches:
        for d in [1] + ([n_dev] if n_dev > 1 and b >= n_dev else []):
            runs.append(lambda b=b, d=d: run_spikejax_flights(b, duration, seed, repeats=repeats, devices=d))
    if getattr(args, "randomize", False):
        runs.append(lambda: run_spikejax_flights(max(batches), duration, seed, randomize_robots=True, repeats=repeats,
                                                 devices=n_dev))
    rows = []
    for run in runs:
        try:
            r = run()
        except ImportError as err:
            print(f"  skipped: {err}")
            continue
        rows.append(r)
        extra = (f", of which network_operation {r['op_s']:.2f} s and Network.run's preparation about "
                 f"{r['prepare_s']:.2f} s" if "op_s" in r else "")
        print(f"  {r['impl']}, batch {r['batch']}: {r['flights_per_s']:.3g} flights/s (timed {r['timed_s']:g} s "
              f"per flight, run {r['run_s']:.2f} s{extra})", flush=True)
    brian2 = [r for r in rows if r["impl"].startswith("Brian2")]
    one = brian2[0]["flights_per_s"] if brian2 else math.nan
    every = brian2[-1]["flights_per_s"] if brian2 else math.nan
    for r in rows:
        r["x_brian2"] = r["flights_per_s"] / one
        r["x_brian2_all_cores"] = r["flights_per_s"] / every
    print()
    print("| implementation | batch | compile/build (s) | timed (s simulated) | run (s) | flights/s | "
          f"simulated s / s | neuron updates/s | x Brian2 | x Brian2 on {n_dev} cores | reached q1, q2 |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        reached = "-" if math.isnan(r["reached_q1"]) else f"{r['reached_q1']:.0%}, {r['reached_q2']:.0%}"
        print(f"| {r['impl']} | {r['batch']} | {r['build_or_compile_s']:.2f} | {r['timed_s'] * r['batch']:g} | "
              f"{r['run_s']:.2f} | {r['flights_per_s']:.4g} | {r['sim_s_per_wall_s']:.3g} | "
              f"{r['neuron_updates_per_s'] / 1e6:,.2f} M | {r['x_brian2']:.1f} | {r['x_brian2_all_cores']:.1f} | "
              f"{reached} |")
    print(f"(flights of {duration:g} s; timed: simulated seconds actually run (flights x timed length), the "
          "throughputs extrapolated from them; run: the fastest of "
          f"{repeats}; reached: within {REACHED_M * 1e3:g} mm of each waypoint at the end of its leg; Brian2 flies "
          f"one flight on one core, or {n_dev} side by side in {n_dev} processes; spikejax rows on one device unless "
          "they say so)")
    if getattr(args, "out", None):
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        with open(out / "bench_robobee.csv", "w", newline="") as file:
            writer = csv.DictWriter(file, fieldnames=[*ROW_FIELDS, "devices", "x_brian2", "x_brian2_all_cores"],
                                    extrasaction="ignore", restval=1)
            writer.writeheader()
            writer.writerows(rows)
    if getattr(args, "network", True) is not False:
        print()
        bench_network.main_network(argparse.Namespace(out=getattr(args, "out", None)))
    return 0
