"""The snake's R-STDP networks in NEST 3.10, and the paper's closed loop with NEST in it (the snake R-STDP paper).

The paper ran its networks in NEST inside the neurorobotics platform: every
20 ms the platform read the robot, set the inputs' rates and the synapses'
dopamine, and let NEST simulate the step. This module is that setup, as a
user of NEST would write it, for benchmarks (`robots.snake.bench_rstdp`) and
for tests that check `robots.snake.rstdp` against it; it is the only module
of the snake that imports ``nest``, and only inside `NestNetwork`.

- `NestNetwork`: the network of `robots.snake.rstdp` for one topology and one
  `robots.snake.rstdp.network_params` set: 16 ``poisson_generator`` (the 10
  DVS grid cells and the 6 joint antagonists), each repeated by a
  ``parrot_neuron`` (delay 1 ms), ``iaf_psc_alpha`` outputs with NEST's
  defaults, and ``stdp_dopamine_synapse`` connections, one copied model with
  its own ``volume_transmitter`` per synapse group (the first layer, and the
  hidden-to-body layer with its own ``tau_c``), masked as
  `robots.snake.rstdp.NetworkConfig.hidden_mask` says, every delay 1 ms. A
  control step sets each output neuron's reward as the ``n`` of the synapses
  onto it (``SetStatus``, as the authors' group did) and the generators' rates,
  simulates 20 ms and returns the output spike counts of the step.
- `NestLoop` / `nest_in_the_loop`: one snake, the paper's loop: the JAX env
  (`robots.snake.training.env_for`, the ``"mujoco"`` backend on one thread,
  its ``step`` jitted for one snake) stepped 20 ms at a time beside NEST; the
  rates and rewards computed from the env's state in JAX exactly as
  `robots.snake.rstdp.network_rates` and `robots.snake.rstdp.network_rewards`
  compute them, the counts decoded by Eq. (4)-(5) as
  `robots.snake.rstdp.network_decode` does.
"""

from __future__ import annotations

import time
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from robots.snake.rstdp import (
    N_DVS,
    N_HIDDEN,
    N_JOINT,
    NetworkConfig,
    NetworkParams,
    network_decode,
    network_params,
    network_rates,
    network_rewards,
)
from spikejax.errors import UserError

__all__ = ["NestNetwork", "NestLoop", "NestLoopRun", "nest_in_the_loop"]

_RSTDP_KEYS = ("A_plus", "A_minus", "tau_plus", "tau_c", "tau_n", "b", "Wmin", "Wmax")


def _synapse_params(group) -> dict:
    return {k: float(getattr(group, k)) for k in _RSTDP_KEYS}


class NestNetwork:
    """The network of `robots.snake.rstdp` built in NEST (see the module docstring), stepped one control step a call.

    Args:
        config: the topology and sizes (``dt`` is NEST's resolution; ``delay``
            the delay of every connection, in neural steps).
        params: the constants (`robots.snake.rstdp.network_params`).
        w_first: ``(10, n_first)`` initial weights from the DVS inputs, pA.
        w_hidden: ``(8, 2)`` initial hidden-to-body weights (multi-layer nets;
            entries outside the mask are ignored).
        seed: NEST's ``rng_seed`` (the Poisson generators' spikes).
        threads: NEST's ``local_num_threads``.

    The kernel is reset: one `NestNetwork` per process at a time.
    """

    def __init__(
        self,
        config: NetworkConfig,
        params: NetworkParams,
        w_first,
        w_hidden=None,
        *,
        seed: int = 1,
        threads: int = 1,
    ):
        import nest

        self.nest, self.config = nest, config
        nf, hidden = config.n_first, config.hidden
        w_first = np.asarray(w_first, np.float64)
        if w_first.shape != (N_DVS, nf):
            raise UserError(f"w_first must be ({N_DVS}, {nf}) for {config.topology}, got {w_first.shape}")
        if hidden:
            if w_hidden is None:
                raise UserError(f"the {config.topology} net needs w_hidden ({N_HIDDEN}, 2)")
            w_hidden = np.asarray(w_hidden, np.float64)
            if w_hidden.shape != (N_HIDDEN, 2):
                raise UserError(f"w_hidden must be ({N_HIDDEN}, 2), got {w_hidden.shape}")
        nest.ResetKernel()
        if hasattr(nest, "VerbosityLevel"):
            nest.verbosity = nest.VerbosityLevel.ERROR
        else:
            nest.set_verbosity("M_ERROR")
        nest.SetKernelStatus({"resolution": float(config.dt), "local_num_threads": int(threads), "rng_seed": int(seed)})
        self.step_ms = float(config.dt) * config.substeps
        delay = float(config.dt) * config.delay
        self.generators = nest.Create("poisson_generator", N_DVS + N_JOINT)
        self.parrots = nest.Create("parrot_neuron", N_DVS + N_JOINT)
        nest.Connect(self.generators, self.parrots, "one_to_one", syn_spec={"delay": delay})
        self.outputs = nest.Create("iaf_psc_alpha", config.n_out)
        # NEST's defaults; the post trace's decay is the neuron's tau_minus in NEST.
        self.outputs.set(V_m=self.outputs.get("E_L")[0], tau_minus=float(params.first.tau_minus))
        self.recorder = nest.Create("spike_recorder")
        nest.Connect(self.outputs, self.recorder)

        self.models = {"first": "snake_rstdp_first"}
        vt_first = nest.Create("volume_transmitter")
        nest.CopyModel(
            "stdp_dopamine_synapse",
            self.models["first"],
            {"volume_transmitter": vt_first, **_synapse_params(params.first)},
        )
        dvs, first = self.parrots[:N_DVS], self.outputs[:nf]
        nest.Connect(
            dvs,
            first,
            "all_to_all",
            syn_spec={"synapse_model": self.models["first"], "weight": w_first.T, "delay": delay},
        )
        self.hidden_pre = None
        if hidden:
            self.models["hidden"] = "snake_rstdp_hidden"
            vt_hidden = nest.Create("volume_transmitter")
            nest.CopyModel(
                "stdp_dopamine_synapse",
                self.models["hidden"],
                {"volume_transmitter": vt_hidden, **_synapse_params(params.second)},
            )
            self.hidden_pre = self.outputs[:2] + self.parrots[N_DVS:]  # [H_L, H_R, J1+, J1-, ..., J5-]
            mask = config.hidden_mask
            for i in range(N_HIDDEN):
                for j in range(2):
                    if mask[i, j]:
                        nest.Connect(
                            self.hidden_pre[i],
                            self.outputs[nf + j],
                            syn_spec={"synapse_model": self.models["hidden"], "weight": w_hidden[i, j], "delay": delay},
                        )
        # The connections onto each output neuron, for its reward, and each group's in (pre, post) order.
        self.onto = [
            nest.GetConnections(target=self.outputs[j], synapse_model=self.models["first" if j < nf else "hidden"])
            for j in range(config.n_out)
        ]
        self.first_id = self.outputs[0].global_id
        self._indices = [self._index("first", self.parrots[:N_DVS], 0)]
        if hidden:
            self._indices.append(self._index("hidden", self.hidden_pre, nf))
        self.time_ms = 0.0

    def connections(self, group: str = "first"):
        """The NEST connections of a synapse group (``"first"`` or ``"hidden"``)."""
        return self.nest.GetConnections(synapse_model=self.models[group])

    def _index(self, group: str, pre, post0: int):
        conns = self.connections(group)
        st = conns.get(["source", "target"])
        ids = {gid: i for i, gid in enumerate(pre.tolist())}
        rows = np.asarray([ids[s] for s in np.atleast_1d(st["source"])], np.intp)
        cols = np.asarray(np.atleast_1d(st["target"]), np.intp) - self.first_id - post0
        return conns, rows, cols

    def weights(self) -> tuple[np.ndarray, np.ndarray]:
        """``(w_first (10, n_first), w_hidden (8, 2))`` as NEST holds them now (``w_hidden`` zero without the layer)."""
        out = [np.zeros((N_DVS, self.config.n_first)), np.zeros((N_HIDDEN, 2))]
        for m, (conns, rows, cols) in zip(out, self._indices):
            m[rows, cols] = conns.get("weight")
        return out[0], out[1]

    def step(self, rates16, r_first, r_body=None) -> np.ndarray:
        """One control step: rewards as the ``n`` of the synapses onto each neuron, the rates, 20 ms simulated.

        Args:
            rates16: the 16 generators' rates, Hz (grid cells, then joint antagonists).
            r_first: rewards of the first layer's neurons ``(n_first,)``.
            r_body: rewards of ``[B_L, B_R]`` (multi-layer nets; ignored otherwise).

        Returns:
            The output spike counts of the step, ``(n_out,)`` int.
        """
        nest, nf = self.nest, self.config.n_first
        rewards = list(np.asarray(r_first, np.float64).reshape(nf))
        if self.config.hidden:
            rewards += list(np.asarray(r_body, np.float64).reshape(2))
        for conns, r in zip(self.onto, rewards):
            conns.set(n=float(r))
        self.generators.set(rate=[float(x) for x in np.asarray(rates16, np.float64).reshape(N_DVS + N_JOINT)])
        nest.Simulate(self.step_ms)
        self.time_ms += self.step_ms
        senders = np.asarray(self.recorder.get("events")["senders"], np.int64)
        self.recorder.n_events = 0  # read incrementally: the next step sees only its own spikes
        return np.bincount(senders - self.first_id, minlength=self.config.n_out)[: self.config.n_out]


class _Decode(NamedTuple):
    """The fields `robots.snake.rstdp.network_decode` reads and replaces."""

    d_head: jax.Array
    d_body: jax.Array
    counts: jax.Array


class _Weights(NamedTuple):
    """The field `robots.snake.rstdp.network_rewards` reads."""

    w_hidden: jax.Array


class NestLoop:
    """One snake in the paper's loop: the JAX env and a `NestNetwork`, one control step per `step` call.

    Args:
        topology: one of `robots.snake.rstdp.TOPOLOGIES`.
        seed: the initial weights (drawn as `robots.snake.rstdp.network_init`
            draws them from ``[w_low, w_high)``) and NEST's ``rng_seed``.
        config, params: default the topology's `NetworkConfig` and `network_params`.
        nthread: the env's MuJoCo threads (1: the paper's one snake on one core).

    Build (env, NEST network, jitted functions, one warm-up step each) happens here.
    """

    def __init__(self, topology: str = "basic", *, seed: int = 0, config=None, params=None, nthread: int = 1):
        from robots.snake.training import env_for

        config = NetworkConfig(topology=topology) if config is None else config
        params = network_params(config) if params is None else params
        self.config, self.params = config, params
        rng = np.random.default_rng(seed)
        lo, hi = float(params.w_low), float(params.w_high)
        w_first = rng.uniform(lo, hi, (N_DVS, config.n_first))
        w_hidden = np.where(config.hidden_mask, rng.uniform(lo, hi, (N_HIDDEN, 2)), 0.0)
        self.net = NestNetwork(config, params, w_first, w_hidden, seed=seed + 1)
        self.env = env = env_for("eight", nthread=nthread)
        self.initial = env.reset(jax.random.PRNGKey(0), mirror=False)
        self._env_step = jax.jit(env.step)

        @jax.jit
        def inputs(env_state, w_hidden):
            obs, info = env_state.obs, env_state.info
            r_first, r_body, _ = network_rewards(
                config, params, _Weights(w_hidden), jnp.rad2deg(obs[0]), jnp.rad2deg(obs[1])
            )
            frames = (info["prev_frame"], info["frame"], info["params"].event_threshold)
            return network_rates(config, params, frames, obs), r_first, r_body

        @jax.jit
        def decode(d_head, d_body, counts):
            s = network_decode(config, params, _Decode(d_head, d_body, counts), counts)
            return s.d_head, s.d_body

        self._inputs, self._decode = inputs, decode
        self.w_hidden = jnp.asarray(w_hidden, jnp.float32)
        self.reset()
        # compile the jitted parts outside any timing
        zero = jnp.zeros((), jnp.float32)
        jax.block_until_ready(self._inputs(self.state, self.w_hidden))
        jax.block_until_ready(self._decode(zero, zero, jnp.zeros((config.n_out,), jnp.int32)))
        jax.block_until_ready(self._env_step(self.state, jnp.zeros((2,), jnp.float32)))

    def reset(self) -> None:
        """The snake back at the start; the network keeps its weights and state (NRP resets the robot)."""
        self.state = self.initial
        self.mirror = False
        self.d_head = self.d_body = jnp.zeros((), jnp.float32)

    def step(self) -> dict:
        """One control step (rates, rewards, NEST, decoding, env); returns its values (degrees for angles)."""
        if self.config.hidden:  # Eq. (11) and (13) read the current hidden-to-body weights
            self.w_hidden = jnp.asarray(self.net.weights()[1], jnp.float32)
        rates, r_first, r_body = jax.device_get(self._inputs(self.state, self.w_hidden))
        counts = self.net.step(rates, r_first, r_body)
        self.d_head, self.d_body = self._decode(self.d_head, self.d_body, jnp.asarray(counts, jnp.int32))
        action = jnp.stack([self.d_body, self.d_head])
        self.state = self._env_step(self.state, action)
        m = self.state.metrics
        out = {
            "a_head": float(np.rad2deg(m["a_head"])),
            "a_body": float(np.rad2deg(m["a_body"])),
            "d_body": float(self.d_body),
            "d_head": float(self.d_head),
            "counts": counts,
            "failed": bool(self.state.done > 0),
            "completed": bool(self.state.info["completed"]),
        }
        if out["failed"] or out["completed"]:
            mirror = (not self.mirror) if (out["completed"] and not out["failed"]) else self.mirror
            self.state = self.env.restart(self.initial, self.state, mirror)
            self.mirror = mirror
            self.d_head = self.d_body = jnp.zeros((), jnp.float32)
        return out

    def run(self, steps: int) -> dict:
        """``steps`` control steps; per step ``a_head, a_body, d_body, d_head, failed, completed`` and ``counts``."""
        rows = [self.step() for _ in range(steps)]
        return {k: np.asarray([r[k] for r in rows]) for k in rows[0]} if rows else {}


class NestLoopRun:
    """`NestLoop` as a benchmark timer: each call runs ``steps`` control steps and returns its seconds.

    ``info`` holds the build's seconds (``build_s``) and the fastest run's (``run_s``).
    """

    def __init__(self, topology: str, steps: int, *, seed: int = 0):
        t0 = time.perf_counter()
        self.loop = NestLoop(topology, seed=seed)
        self.build_s = time.perf_counter() - t0
        self.steps, self.run_s = steps, float("inf")

    def __call__(self) -> float:
        t0 = time.perf_counter()
        self.loop.run(self.steps)
        seconds = time.perf_counter() - t0
        self.run_s = min(self.run_s, seconds)
        return seconds

    @property
    def info(self) -> dict:
        return {"build_s": self.build_s, "run_s": self.run_s, "steps": self.steps}


def nest_in_the_loop(topology: str, steps: int, *, seed: int = 0) -> dict:
    """The paper's setup for one snake (`NestLoop`): ``steps`` control steps of training on the 8.

    Returns:
        Per step ``a_head, a_body`` (degrees, after the step's env step),
        ``d_body, d_head``, ``failed``, ``completed`` and the output ``counts``
        ``(steps, n_out)``, and the final ``w_first``, ``w_hidden``.
    """
    loop = NestLoop(topology, seed=seed)
    out = loop.run(steps)
    out["w_first"], out["w_hidden"] = loop.net.weights()
    return out
