"""The RoboBee's peers: its networks and its closed loop in Brian2 and NEST, as their users would write them.

Benchmarks time these against spikejax and tests check spikejax against them;
nothing here imports a benchmark.

- The delta-synapse network of `robots.robobee.delta_network` (not the
  controller's network) in Brian2's runtime mode (`Brian2RuntimeNetwork`,
  `run_brian2_runtime`), Brian2's C++ standalone mode
  (`Brian2StandaloneNetwork`, `run_brian2_standalone`) and NEST's
  ``iaf_psc_delta`` (`NestNetwork`, `run_nest`). Each class is a benchmark
  timer (built once; each call one timed run returning its seconds; ``info``
  its result row, `robots.robobee.delta_network.result_row`); each ``run_*``
  function times one ``repeats`` times and returns the row.
- The closed loop of Sec. V of the RoboBee paper in Brian2 (`Brian2Flight`),
  the paper's own setup: "At every time step, the simulator calls a function
  to update the RoboBee state and another function to compute the weight
  changes for each set of synapses following equation (10)": the controller's
  network (the weights, connectivity and thresholds `controller_init` draws) in
  Brian2's runtime mode, and a ``network_operation`` that runs at the end of
  every step. `Brian2FlightRun` is its benchmark timer.

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
"""

from __future__ import annotations

import math
import os
import tempfile
import time

import jax
import jax.numpy as jnp
import numpy as np

from robots.robobee.controller import TORQUE_UNIT, ControllerConfig, controller_init, controller_params
from robots.robobee.delta_network import (
    DT,
    LAYER_SLICES,
    N_HIDDEN,
    N_INPUT,
    N_NEURONS,
    N_OUTPUT,
    T_REF,
    TAUS,
    NetworkSpec,
    input_currents,
    make_network,
    n_steps_of,
    result_row,
)
from robots.robobee.flight import flight_plan
from robots.robobee.lqr import altitude_params, lateral_gain
from robots.robobee.params import max_lift, robobee_params

__all__ = [
    "Brian2Flight",
    "Brian2FlightRun",
    "Brian2RuntimeNetwork",
    "Brian2StandaloneNetwork",
    "NestNetwork",
    "run_brian2_runtime",
    "run_brian2_standalone",
    "run_nest",
]

# Steps between two samples of a flight's recording (as `robots.robobee.flight.fly`'s ``record_every``).
RECORD_EVERY = 10


# ----------------------------------------------------------------- the network alone


def _brian2_network(spec: NetworkSpec, current: np.ndarray):
    """The network as Brian2 objects in a `brian2.Network` (the active device decides how it runs)."""
    import brian2 as b2

    eqs = """dv/dt = (i_ext - v) / tau : 1 (unless refractory)
    i_ext : 1 (constant)
    v_th : 1 (constant)
    tau : second (constant)"""
    groups = []
    for sl, n in zip(LAYER_SLICES, (N_INPUT, N_HIDDEN, N_OUTPUT)):
        g = b2.NeuronGroup(n, eqs, threshold="v >= v_th", reset="v = 0", refractory=T_REF * b2.second, method="exact")
        g.v_th = spec.v_th[sl]
        g.tau = spec.tau[sl] * b2.second
        groups.append(g)
    groups[0].i_ext = current
    synapses = []
    for pre, post, conn, w in (
        (groups[0], groups[1], spec.conn_ih, spec.w_ih),
        (groups[1], groups[2], spec.conn_ho, spec.w_ho),
    ):
        syn = b2.Synapses(pre, post, "w : 1 (constant)", on_pre="v_post += w * int(not_refractory_post)")
        i, j = np.nonzero(conn)
        syn.connect(i=i, j=j)
        syn.w = w[i, j]
        synapses.append(syn)
    monitors = [b2.SpikeMonitor(g, record=False) for g in groups]
    net = b2.Network(*groups, *synapses, *monitors)
    # Synapses between the state update and the threshold test: a spike is
    # propagated in the step after the one that emitted it (NEST's delay of dt).
    net.schedule = ["start", "groups", "synapses", "thresholds", "resets", "end"]
    return net, monitors


def _brian2_counts(monitors) -> np.ndarray:
    return np.concatenate([np.asarray(m.count[:]) for m in monitors])


class Brian2RuntimeNetwork:
    """Brian2's runtime mode (``target`` ``"cython"`` or ``"numpy"``) on one network, as a benchmark timer.

    The first ``run`` (at construction) generates (and for Cython compiles, or
    loads from Cython's cache) the code. The network is stored before it and
    restored before each further run, so each call repeats the same simulation
    and returns its seconds; `info` is the result row: ``run_s`` the fastest
    call and ``build_or_compile_s`` the first run's excess over it. If Cython
    cannot compile, NumPy runs instead and the row's ``impl`` says so. The
    code generation target stays ``target`` while the object lives.
    """

    def __init__(self, duration: float, seed: int, target: str = "cython"):
        import brian2 as b2

        spec = make_network(seed)
        current = input_currents(seed, 1)[0]
        self.n_steps, self.duration = n_steps_of(duration), duration
        self.impl = f"Brian2 runtime ({target})"
        b2.prefs.codegen.target = target
        b2.defaultclock.dt = DT * b2.second
        self.net, self.monitors = _brian2_network(spec, current)
        self.net.store("start")
        t0 = time.perf_counter()
        try:
            self.net.run(duration * b2.second)
        except Exception as err:  # noqa: BLE001 - whatever broke the compiler: fall back, and say so
            if target == "numpy":
                raise
            b2.prefs.codegen.target = "numpy"
            self.impl = f"Brian2 runtime (numpy; {target} failed: {type(err).__name__})"
            self.net, self.monitors = _brian2_network(spec, current)
            self.net.store("start")
            t0 = time.perf_counter()
            self.net.run(duration * b2.second)
        self.first_s = time.perf_counter() - t0
        self.counts = _brian2_counts(self.monitors)
        self.run_s, self.repeat_equal = math.inf, True

    def __call__(self) -> float:
        import brian2 as b2

        self.net.restore("start")
        t0 = time.perf_counter()
        self.net.run(self.duration * b2.second)
        seconds = time.perf_counter() - t0
        self.run_s = min(self.run_s, seconds)
        self.repeat_equal &= bool(np.array_equal(_brian2_counts(self.monitors), self.counts))
        return seconds

    @property
    def info(self) -> dict:
        return result_row(
            self.impl,
            1,
            self.n_steps,
            max(self.first_s - self.run_s, 0.0),
            self.run_s,
            self.counts,
            first_run_s=self.first_s,
            repeat_equal=self.repeat_equal,
        )


def run_brian2_runtime(duration: float, seed: int, target: str = "cython", repeats: int = 1) -> dict:
    """`Brian2RuntimeNetwork` timed ``repeats`` times; its result row. The codegen target is restored after."""
    import brian2 as b2

    old_target = b2.prefs.codegen.target
    try:
        run = Brian2RuntimeNetwork(duration, seed, target)
        for _ in range(repeats):
            run()
        return run.info
    finally:
        b2.prefs.codegen.target = old_target


class Brian2StandaloneNetwork:
    """Brian2's C++ standalone mode on one network, built in a temporary directory, as a benchmark timer.

    The project is generated and compiled at construction (``device.build(run=False)``:
    code generation and the C++ build, ``build_or_compile_s``); each call
    runs the binary (``device.run``) and returns the simulation loop's seconds
    as the binary times it (``device._last_run_time``). `info` is the result
    row: ``run_s`` the fastest loop, ``run_wall_s`` the fastest whole ``run``
    (process start and result files included). `close` resets the device to
    runtime, so that other runs in the same process still work.

    Args:
        duration: simulated time, s.
        seed: seed of `make_network` and `input_currents`.
        threads: OpenMP threads (0: none, Brian2's default).
    """

    def __init__(self, duration: float, seed: int, threads: int = 0):
        import brian2 as b2

        spec = make_network(seed)
        current = input_currents(seed, 1)[0]
        self.n_steps, self.threads = n_steps_of(duration), threads
        self._tmp = tempfile.TemporaryDirectory(prefix="brian2_standalone_")
        b2.set_device("cpp_standalone", directory=self._tmp.name, build_on_run=False)
        try:
            b2.prefs.devices.cpp_standalone.openmp_threads = threads
            b2.defaultclock.dt = DT * b2.second
            net, self.monitors = _brian2_network(spec, current)
            net.run(duration * b2.second)
            t0 = time.perf_counter()
            b2.device.build(directory=self._tmp.name, compile=True, run=False, with_output=False)
            self.build_s = time.perf_counter() - t0
        except BaseException:
            self.close()
            raise
        self.run_s = self.run_wall_s = math.inf
        self.counts = None

    def __call__(self) -> float:
        import brian2 as b2

        t0 = time.perf_counter()
        b2.device.run(directory=self._tmp.name, with_output=False)
        self.run_wall_s = min(self.run_wall_s, time.perf_counter() - t0)
        seconds = float(b2.device._last_run_time)
        self.run_s = min(self.run_s, seconds)
        self.counts = _brian2_counts(self.monitors)
        return seconds

    @property
    def info(self) -> dict:
        impl = "Brian2 C++ standalone" + (f" ({self.threads} OpenMP threads)" if self.threads else "")
        return result_row(impl, 1, self.n_steps, self.build_s, self.run_s, self.counts, run_wall_s=self.run_wall_s)

    def close(self) -> None:
        import brian2 as b2
        from brian2.devices.device import reset_device

        b2.device.reinit()
        b2.prefs.devices.cpp_standalone.openmp_threads = 0
        reset_device("runtime")
        self._tmp.cleanup()


def run_brian2_standalone(duration: float, seed: int, threads: int = 0, repeats: int = 1) -> dict:
    """`Brian2StandaloneNetwork` run ``repeats`` times; its result row (the device reset to runtime after)."""
    run = Brian2StandaloneNetwork(duration, seed, threads)
    try:
        for _ in range(repeats):
            run()
        return run.info
    finally:
        run.close()


# ----------------------------------------------------------------- NEST


class NestNetwork:
    """NEST's ``iaf_psc_delta`` network, one network, ``threads`` local threads, as a benchmark timer.

    Each call builds the network (``Create`` + ``Connect`` + ``Prepare``, the
    row's ``build_or_compile_s``: the fastest) and times the ``Run`` of
    ``duration`` (returned; ``run_s``: the fastest). Units: ms, mV, pA, pF
    with ``C_m = tau_m`` (see `robots.robobee.delta_network`'s notes).
    """

    def __init__(self, duration: float, seed: int, threads: int = 1):
        self.nest = _import_nest()
        self.spec, self.current = make_network(seed), input_currents(seed, 1)[0]
        self.duration, self.n_steps, self.threads = duration, n_steps_of(duration), threads
        self.build_s = self.run_s = math.inf
        self.counts = None

    def __call__(self) -> float:
        nest, spec = self.nest, self.spec
        nest.ResetKernel()
        nest.verbosity = nest.VerbosityLevel.ERROR
        nest.SetKernelStatus({"resolution": DT * 1e3, "local_num_threads": self.threads, "print_time": False})
        t0 = time.perf_counter()
        layers = []
        for sl, n, tau_s in zip(LAYER_SLICES, (N_INPUT, N_HIDDEN, N_OUTPUT), TAUS):
            tau_ms = tau_s * 1e3
            layers.append(
                nest.Create(
                    "iaf_psc_delta",
                    n,
                    params={
                        "tau_m": tau_ms,
                        "C_m": tau_ms,
                        "E_L": 0.0,
                        "V_reset": 0.0,
                        "V_m": 0.0,
                        "t_ref": (T_REF - DT) * 1e3,
                        "I_e": 0.0,
                        "V_th": list(spec.v_th[sl]),
                    },
                )
            )
        layers[0].I_e = list(self.current)
        for pre, post, conn, w in (
            (layers[0], layers[1], spec.conn_ih, spec.w_ih),
            (layers[1], layers[2], spec.conn_ho, spec.w_ho),
        ):
            i, j = np.nonzero(conn)
            nest.Connect(
                np.asarray(pre.tolist())[i],
                np.asarray(post.tolist())[j],
                "one_to_one",
                {"synapse_model": "static_synapse", "weight": w[i, j], "delay": np.full(len(i), DT * 1e3)},
            )
        recorder = nest.Create("spike_recorder")
        nest.Connect(layers[0] + layers[1] + layers[2], recorder)
        nest.Prepare()
        self.build_s = min(self.build_s, time.perf_counter() - t0)
        t0 = time.perf_counter()
        nest.Run(self.duration * 1e3)
        seconds = time.perf_counter() - t0
        self.run_s = min(self.run_s, seconds)
        nest.Cleanup()
        senders = np.asarray(recorder.get("events")["senders"], np.int64)
        self.counts = np.bincount(senders - layers[0].tolist()[0], minlength=N_NEURONS)
        return seconds

    @property
    def info(self) -> dict:
        impl = f"NEST iaf_psc_delta ({self.threads} thread{'s' if self.threads > 1 else ''})"
        return result_row(impl, 1, self.n_steps, self.build_s, self.run_s, self.counts)


def run_nest(duration: float, seed: int, threads: int = 1, repeats: int = 1) -> dict:
    """`NestNetwork` built and run ``repeats`` times; its result row."""
    run = NestNetwork(duration, seed, threads)
    for _ in range(repeats):
        run()
    return run.info


def _import_nest():
    """``nest``, imported without its banner (it prints one unless ``PYNEST_QUIET`` is set)."""
    os.environ.setdefault("PYNEST_QUIET", "1")
    import nest

    return nest


# ----------------------------------------------------------------- the closed loop


class Brian2Flight:
    """One closed-loop flight in Brian2's runtime mode: the network in Brian2, the rest in a network operation.

    The network is the one `controller_init` draws from ``key`` (the same
    weights, connectivity and thresholds as the spikejax flight of that key);
    the controller's constants are `controller_params`'s defaults. The schedule
    and the network operation are described in the module's notes.

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

    def __init__(
        self,
        key: jax.Array,
        hold_steps: int,
        segment_steps: int,
        *,
        learn: bool = True,
        use_snn: bool = True,
        robot=None,
        record_every: int = RECORD_EVERY,
    ):
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
        # q_hat = a (e + b), that is offset_n + slope_n e_g: the layout of
        # `spikejax.coding.antagonist_currents(shift_scale(e, a, b), n_per_input, input_gain)` in float64.
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
            g = b2.NeuronGroup(
                n,
                eqs,
                threshold="v >= v_th",
                reset="v = 0",
                refractory=f(cp.t_ref) * b2.second,
                method="exact",
                name=f"robobee_{name}*",
            )
            g.v_th = v_th
            g.tau = tau * b2.second
            self.groups.append(g)
        self.synapses, self.pre_index = [], []
        masks = [np.asarray(m, np.float64) for m in (state.mask_ih, state.mask_ho)]
        weights = [np.asarray(w, np.float64) for w in (state.w_ih, state.w_ho)]
        for (pre, post), mask, w, c in zip(
            zip(self.groups, self.groups[1:]), masks, weights, (f(cp.syn_hidden), f(cp.syn_output))
        ):
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
        self.counts = np.zeros(n_in + n_h + self.config.n_output, np.int64)
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
        return dict(
            t=(np.arange(n) + 1) * self.record_every * self.dt,
            q=rec[:, :6],
            target=rec[:, 6:12],
            y_hat=rec[:, 12],
            y_lqr=rec[:, 13],
        )


class Brian2FlightRun:
    """One closed-loop flight in Brian2's runtime mode (`Brian2Flight`) as a benchmark timer.

    At construction the flight is built and a first run of ``warmup_steps``
    steps generates (and for Cython compiles, or loads from Cython's cache)
    the code: ``build_s`` is the construction plus that run. Each call
    restarts the flight (`Brian2Flight.reset`) and runs ``n_steps`` steps; it
    returns the seconds of that ``Network.run``, its preparation included.
    `info` holds the impl, ``build_s``, ``run_s`` (the fastest call),
    ``prepare_s`` (the time of a further run of ``warmup_steps``, which
    measures that preparation), and of the first call the recording, the spike
    counts, ``op_s`` (time in the network operation) and the final weights,
    dense (``w_ih``, ``w_ho``). If Cython cannot compile, NumPy runs instead
    and ``impl`` says so; the code generation target stays set while the object lives.

    Args:
        key: the network's key (or its `jax.random.key_data`, so that it can be
            sent to another process).
        hold_steps, segment_steps: the flight plan (as `Brian2Flight`).
        n_steps: steps of each timed run.
        target: ``"cython"`` or ``"numpy"`` (``brian2.prefs.codegen.target``).
        learn, use_snn: as `Brian2Flight`.
        warmup_steps: steps of the code-generating first run.
    """

    def __init__(
        self,
        key,
        hold_steps: int,
        segment_steps: int,
        n_steps: int,
        target: str = "cython",
        *,
        learn: bool = True,
        use_snn: bool = True,
        warmup_steps: int = RECORD_EVERY,
    ):
        import brian2 as b2

        if isinstance(key, np.ndarray):
            key = jax.random.wrap_key_data(jnp.asarray(key))
        self.n_steps, self.warmup_steps = n_steps, warmup_steps
        self.impl = f"Brian2 runtime ({target}) + network_operation"
        b2.prefs.codegen.target = target
        t0 = time.perf_counter()
        try:
            self.flight = Brian2Flight(key, hold_steps, segment_steps, learn=learn, use_snn=use_snn)
            self.flight.run(warmup_steps)
        except Exception as err:  # noqa: BLE001 - whatever broke the compiler: fall back, and say so
            if target == "numpy":
                raise
            b2.prefs.codegen.target = "numpy"
            self.impl = f"Brian2 runtime (numpy; {target} failed: {type(err).__name__}) + network_operation"
            self.flight = Brian2Flight(key, hold_steps, segment_steps, learn=learn, use_snn=use_snn)
            self.flight.run(warmup_steps)
        self.build_s = time.perf_counter() - t0
        self.run_s = math.inf
        self._first = None
        self._prepare_s = None

    def __call__(self) -> float:
        flight = self.flight
        flight.reset()
        t0 = time.perf_counter()
        flight.run(self.n_steps)
        seconds = time.perf_counter() - t0
        self.run_s = min(self.run_s, seconds)
        if self._first is None:
            dense = []
            for syn, mask in zip(flight.synapses, (flight.state0.mask_ih, flight.state0.mask_ho)):
                mask = np.asarray(mask)
                w = np.zeros(mask.shape)
                w[np.nonzero(mask)] = np.asarray(syn.w[:])
                dense.append(w)
            self._first = dict(
                recording=flight.recording(),
                counts=flight.counts.copy(),
                op_s=flight.op_s,
                w_ih=dense[0],
                w_ho=dense[1],
            )
        return seconds

    @property
    def info(self) -> dict:
        if self._prepare_s is None and self._first is not None:
            self.flight.reset()
            t0 = time.perf_counter()
            self.flight.run(self.warmup_steps)
            self._prepare_s = time.perf_counter() - t0
        return dict(
            impl=self.impl, build_s=self.build_s, run_s=self.run_s, prepare_s=self._prepare_s, **(self._first or {})
        )
