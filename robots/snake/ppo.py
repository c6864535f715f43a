"""Brax's PPO on the snake's target-tracking task: the deep-RL baseline beside the spiking controllers.

The task is the snake R-STDP paper's training task as `robots.snake.training`
runs it for the spiking networks: the drawn 8 (`robots.snake.training.env_for`,
the same steering range), the reset rule of Sec. III-B, and the next episode
mirrored after every reset. `TrackTask` wraps `robots.snake.env.SnakeEnv` so
that Brax's own trainer (`brax.training.agents.ppo.train`) runs on it
unchanged:

* observations, two variants: ``"grid"``, what the spiking networks see, the
  rates of Eq. (2) of the snake R-STDP paper over the 2 x 5 grid of the DVS ROI
  (`robots.snake.rstdp.NetworkConfig`'s ROI, capped at 300 Hz as
  `robots.snake.rstdp.network_params` caps them, divided by the cap) and the
  16 joint angles (rad); ``"angles"``, the privileged upper bound: the true
  target angles ``a_head, a_body`` of Eq. (12) and the joint angles;
* actions: the env's, the steering input and the head input in [-1, 1] (the
  SNNs' ``D_body`` and ``D_head`` of Eq. (5));
* reward: ``1 - |a_head| / 40 deg``. Eq. (9) rewards the head angle's
  magnitude, ``-|a_head|`` up to a gain; that alone would pay a policy for
  failing early (an episode that ends stops accruing negative rewards), so
  it is shifted by the reset rule's bound: a step on the track is worth 0 to
  1, a lost target ends the episode. The ranking of the policies is that of
  ``-|a_head|`` on every step the target is kept;
* episodes end when the target is lost (Sec. III-B) or has finished the 8,
  and at the latest after one pass of the 8 at the snake's speed (Brax's
  ``episode_length``). Brax's ``AutoResetWrapper`` puts back the first physics
  state; the env starts the task afresh from it, and `TrackTask` flips the
  mirror then, as `robots.snake.training.train` does. The first episode of
  each of the ``num_envs`` envs is mirrored or not at random (the reset's key),
  so both directions are in every batch.

`train` runs Brax's PPO (`PPOSettings`, its hyperparameters) on the ``mujoco``
backend on a CPU (MuJoCo C called from inside Brax's jitted, vmapped training
step) or on ``mjx``; `policy_controller` turns saved parameters into a
`spikejax.rollout.Controller`, so that `robots.snake.training.run_test` tests
PPO policies on the same tracks, with the same metrics, as the spiking networks.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np
from brax.envs.base import State, Wrapper

from robots.snake import training
from robots.snake.env import LOST_HEAD_ANGLE, SnakeEnv
from robots.snake.rstdp import NetworkConfig
from spikejax import coding
from spikejax.errors import UserError
from spikejax.rollout import Controller

__all__ = [
    "OBSERVATIONS",
    "TASKS",
    "PPOSettings",
    "TrackTask",
    "PipeTask",
    "PIPE_OBSERVATIONS",
    "make_task",
    "make_networks",
    "policy_controller",
    "train",
]

TASKS = ("snake-track", "snake-pipe")
OBSERVATIONS = ("grid", "angles")  # snake-track's; snake-pipe's are PIPE_OBSERVATIONS
PIPE_OBSERVATIONS = ("detector", "truth")
MAX_RATE = 300.0  # Hz, the cap of Eq. (2)'s rates in robots.snake.rstdp.network_params


class TrackTask(Wrapper):
    """The snake R-STDP paper's tracking task for Brax's trainers (see the module docstring).

    Args:
        env: the snake env (`robots.snake.training.env_for`), its camera on for ``"grid"``.
        observation: ``"grid"`` or ``"angles"``.
        network: the grid's ROI, shape and control step (the spiking networks' `NetworkConfig`).
    """

    def __init__(self, env: SnakeEnv, observation: str = "grid", network: NetworkConfig | None = None):
        if observation not in OBSERVATIONS:
            raise UserError(f"unknown observation {observation!r}; choose from {', '.join(OBSERVATIONS)}")
        if observation == "grid" and not env.camera_on:
            raise UserError("the grid observation needs the env's camera (camera=True)")
        super().__init__(env)
        self.observation = observation
        self.network = NetworkConfig() if network is None else network
        if observation == "grid":
            training.check_frame_rows(env, self.network.roi)

    @property
    def observation_size(self) -> int:
        cells = self.network.rows * self.network.cols
        return 2 + 16 if self.observation == "angles" else cells + 16

    @property
    def action_size(self) -> int:
        return 2

    def observe(self, state: State) -> jax.Array:
        """The policy's input from an env state (`SnakeEnv`'s), for one snake."""
        if self.observation == "angles":
            return state.obs
        net = self.network
        counts = coding.grid_counts(
            state.info["prev_frame"],
            state.info["frame"],
            threshold=state.info["params"].event_threshold,
            roi=net.roi,
            rows=net.rows,
            cols=net.cols,
        )
        rates = coding.grid_rates(counts, 0.001 * net.dt * net.substeps, MAX_RATE) / MAX_RATE
        return jnp.concatenate([rates.astype(jnp.float32), state.obs[2:]])

    def reset(self, rng: jax.Array) -> State:
        state = self.env.reset(rng, mirror=jax.random.bernoulli(rng))
        return self._task(state)

    def step(self, state: State, action: jax.Array) -> State:
        info = state.info
        # A state at time 0 after some steps is Brax's auto-reset: the next episode runs mirrored.
        flip = (state.pipeline_state.time == 0.0) & (info["control_steps"] > 0)
        state = state.replace(info={**info, "mirror": jnp.where(flip, ~info["mirror"], info["mirror"])})
        return self._task(self.env.step(state, action))

    def _task(self, state: State) -> State:
        failed = state.done
        done = jnp.maximum(failed, state.info["completed"].astype(jnp.float32))
        reward = 1.0 - jnp.abs(state.metrics["a_head"]) / LOST_HEAD_ANGLE
        metrics = {**state.metrics, "abs_head": jnp.abs(state.metrics["a_head"]), "failed": failed}
        return state.replace(obs=self.observe(state), reward=reward, done=done, metrics=metrics)


def make_task(
    task: str, observation: str, *, backend: str = "mujoco", track="eight", situation="standing-right", **physics
):
    """``task`` (one of `TASKS`) with ``observation`` on ``backend``.

    ``snake-track``: `TrackTask` on the env of the spiking networks' training
    (``track``; ``physics``, e.g. ``nthread``, goes to
    `robots.snake.physics.make_physics`); ``snake-pipe``: `PipeTask` in
    ``situation`` (one of `robots.snake.pipes.SITUATIONS`).
    """
    if task not in TASKS:
        raise UserError(f"unknown task {task!r}; choose from {', '.join(TASKS)}")
    if task == "snake-pipe":
        from robots.snake.pipe_env import PipeEnv

        if observation not in PIPE_OBSERVATIONS:
            raise UserError(f"unknown observation {observation!r} for snake-pipe; choose from detector, truth")
        return PipeTask(PipeEnv(backend, situation=situation), observation)
    env = training.env_for(track, backend=backend, camera=observation == "grid", **physics)
    return TrackTask(env, observation)


class PipeTask(Wrapper):
    """The pipe paper's approach (`robots.snake.pipe_env.PipeEnv`) for Brax's trainers.

    Observations: ``"detector"``, what the bang-bang controller of the snake
    pipe-tracking paper reads, Alg. 3's last distance and offset estimates
    (held between slot ends, 0 before the first), whether the last slot saw a
    body and an entry, and the control ``C`` in force, then the env's 32 joint
    angles and velocities; ``"truth"``, the privileged bound: the target
    pipe's true depth and lateral position in the camera frame and its offset
    from the central line, then the same 32. Actions: ``action[0]`` steers
    (``action[1]`` is ignored, as in the env). Reward and episode ends are the
    env's (progress towards the pipe plus 1 at success; success, a collision
    with a standing pipe, ``max_steps``).

    The env keeps the detector, the latched outcomes and the step count in
    ``info``, which Brax's ``AutoResetWrapper`` does not reset (it puts back
    the first physics state and observation only); `PipeTask` keeps the
    reset's ``info`` and puts it back at the first step from time 0, so every
    episode starts with an empty detector. Each env therefore replays the
    placement its first reset sampled: ``num_envs`` placements in a training.
    """

    def __init__(self, env, observation: str = "detector"):
        if observation not in PIPE_OBSERVATIONS:
            raise UserError(f"unknown observation {observation!r}; choose from {', '.join(PIPE_OBSERVATIONS)}")
        super().__init__(env)
        self.observation = observation

    @property
    def observation_size(self) -> int:
        return (5 if self.observation == "detector" else 3) + 32

    @property
    def action_size(self) -> int:
        return 2

    def observe(self, state: State) -> jax.Array:
        """The policy's input from a `PipeEnv` state, for one snake."""
        if self.observation == "truth":
            m = state.metrics
            head = jnp.stack([m["depth"], m["lateral"], m["offset_true"]])
        else:
            info, slot = state.info, state.info["slot"]
            f32 = lambda x: jnp.asarray(x, jnp.float32)  # noqa: E731
            head = jnp.stack(
                [info["d_est"], info["offset_est"], f32(slot.body.valid), f32(slot.entry.valid), f32(slot.control)]
            )
        return jnp.concatenate([head.astype(jnp.float32), state.obs])

    def reset(self, rng: jax.Array) -> State:
        state = self.env.reset(rng)
        state.info["first_info"] = dict(state.info)
        return state.replace(obs=self.observe(state), metrics={**state.metrics, "succeeded": jnp.zeros(())})

    def step(self, state: State, action: jax.Array) -> State:
        info = state.info
        fresh = (state.pipeline_state.time == 0.0) & (info["control_steps"] > 0)
        first = info["first_info"]
        restored = jax.tree.map(lambda a, b: jnp.where(fresh, a, b), first, {k: info[k] for k in first})
        state = state.replace(info={**info, **restored})
        state = self.env.step(state, action)
        metrics = {**state.metrics, "succeeded": state.metrics["success"] * state.done}
        return state.replace(obs=self.observe(state), metrics=metrics)


@dataclasses.dataclass(frozen=True)
class PPOSettings:
    """Brax PPO's hyperparameters for the snake (its argument names; `train` passes them on).

    The defaults were chosen on the ``grid`` task from a handful of short runs:
    64 envs (the batch at which MuJoCo C and the camera reach their
    throughput here), unrolls of 20 control steps (0.4 s, a fifth of a gait
    period), 4 minibatches of 64 x 20 steps and 4 passes over each batch,
    observations normalised by Brax's running statistics, a discount of 0.97
    (a horizon of about 30 steps, 0.6 s). ``episode_length`` ``None`` is one
    pass of the 8 at the snake's straight speed (`robots.snake.training.lap_steps`)
    on ``snake-track``, the env's ``max_steps`` on ``snake-pipe``.
    """

    num_envs: int = 64
    unroll_length: int = 20
    batch_size: int = 64
    num_minibatches: int = 4
    num_updates_per_batch: int = 4
    learning_rate: float = 3e-4
    entropy_cost: float = 1e-3
    discounting: float = 0.97
    gae_lambda: float = 0.95
    normalize_observations: bool = True
    episode_length: int | None = None

    @property
    def steps_per_update(self) -> int:
        """Env steps of one training step (one unroll of every minibatch)."""
        return self.batch_size * self.unroll_length * self.num_minibatches


@contextlib.contextmanager
def _brax_on_this_jax():
    """``jax.device_put_replicated`` for Brax 0.14's trainer while it runs (JAX 0.10 removed it).

    The replacement is the one JAX's migration guide gives: each leaf stacked
    once per device and put with a sharding over a one-axis mesh. The axis is
    named as Brax's ``pmap`` names its own (``"i"``), so the replicated
    training state has the very sharding of the epoch's outputs: with another
    name the second epoch saw new input shardings and compiled the whole
    training epoch again (7 s here, inside what had been timed as steady
    training).
    """
    if hasattr(jax, "device_put_replicated"):
        yield
        return
    from jax.sharding import Mesh, NamedSharding, PartitionSpec

    def device_put_replicated(x, devices):
        sharding = NamedSharding(Mesh(np.array(devices), ("i",)), PartitionSpec("i"))
        return jax.tree.map(lambda y: jax.device_put(jnp.stack([jnp.asarray(y)] * len(devices)), sharding), x)

    jax.device_put_replicated = device_put_replicated
    try:
        yield
    finally:
        del jax.device_put_replicated


def make_networks(task: TrackTask, settings: PPOSettings):
    """Brax's PPO networks for ``task`` (the trainer's default factory, observations normalised as in training)."""
    from brax.training.acme import running_statistics
    from brax.training.agents.ppo import networks as ppo_networks

    normalize = running_statistics.normalize if settings.normalize_observations else (lambda x, y: x)
    return ppo_networks.make_ppo_networks(task.observation_size, task.action_size, preprocess_observations_fn=normalize)


def train(
    task: TrackTask,
    steps: int,
    *,
    seed: int = 0,
    settings: PPOSettings = PPOSettings(),
    evals: int = 10,
    progress: Callable[[int, dict], None] | None = None,
    on_params: Callable[[int, tuple], None] | None = None,
    restore: tuple | None = None,
):
    """Brax's PPO on ``task`` for at least ``steps`` env steps; returns the policy's parameters.

    ``progress(env_steps, metrics)`` gets Brax's training metrics ``evals``
    times (``episode/sum_reward``, ``episode/length``, ``episode/failed``,
    ``episode/abs_head``: sums over the episodes that ended since the last
    call, averaged over them); ``on_params(env_steps, params)`` gets the
    parameters at the start and after each of them, so a caller can keep the
    latest. The parameters are Brax's ``(normalizer, policy, value)`` tuple;
    ``restore`` (such a tuple) starts the networks from it instead of afresh.

    On the ``mujoco`` backend the trainer uses one device: its batch reaches
    MuJoCo C in one callback and C spreads it over its threads (a callback in a
    program split over several devices is not safe here, see
    `robots.hexapod.env`); on ``mjx`` it uses every device.
    """
    from brax.training.agents.ppo import train as ppo

    devices = 1 if task.env.backend == "mujoco" else jax.local_device_count()
    if settings.num_envs % devices:
        raise UserError(f"num_envs {settings.num_envs} must be a multiple of the {devices} devices")
    if (settings.batch_size * settings.num_minibatches) % settings.num_envs:
        raise UserError("batch_size x num_minibatches must be a multiple of num_envs (Brax's PPO)")
    if steps < 1:
        raise UserError(f"steps must be at least 1, got {steps}")
    fields = dataclasses.asdict(settings)
    episode_length = fields.pop("episode_length") or (
        training.lap_steps(task.env) if isinstance(task, TrackTask) else task.env.max_steps
    )
    with _brax_on_this_jax():
        _, params, _ = ppo.train(
            task,
            num_timesteps=int(steps),
            episode_length=int(episode_length),
            max_devices_per_host=devices,
            seed=int(seed),
            num_evals=max(1, int(evals)) + 1,
            run_evals=False,
            log_training_metrics=True,
            training_metrics_steps=settings.steps_per_update,
            progress_fn=progress or (lambda *_: None),
            policy_params_fn=(lambda n, make, p: on_params(n, p)) if on_params else (lambda *_: None),
            restore_params=restore,
            **fields,
        )
    return params


def policy_controller(task: TrackTask, settings: PPOSettings, *, deterministic: bool = True) -> Controller:
    """A PPO policy as a `spikejax.rollout.Controller` of the snake env; its state is the policy's parameters.

    The controller's state is Brax's ``(normalizer, policy)`` parameters, so a
    batch of seeds holds one policy per member; ``out`` carries the actions as
    ``d_body`` and ``d_head`` (the steering and head inputs, as the spiking
    networks' decoded directions), which the metrics read.
    """
    from brax.training.agents.ppo import networks as ppo_networks

    networks = make_networks(task, settings)
    make_policy = ppo_networks.make_inference_fn(networks)

    def step(params, cstate, env_state, *, key):
        policy = make_policy(cstate, deterministic=deterministic)
        action, _ = policy(task.observe(env_state), key)
        return cstate, action, {"d_body": action[0], "d_head": action[1]}

    return Controller(step=step, on_reset=lambda params, cstate: cstate)


def failures_per_minute(failed_share: float, length: float, dt: float) -> float:
    """Failures a minute from a share of episodes ending in failure and their mean length in control steps."""
    return float(failed_share) / (float(length) * dt / 60.0) if length > 0 else math.nan
