"""The snake R-STDP trial that sweep files name: train one network on the 8, test it frozen, summarise as scalars.

The unstated choices of the snake R-STDP paper that matter most (the rate cap
of Eq. (2), the hidden layer's ``tau_c`` factor, the scale of ``C_reward`` of
Eq. (9), the steering range, the DVS threshold) are traced fields of
`RSTDPTrialParams`, so one compiled program trains a whole grid of them
over many seeds (``spikejax sweep sweeps/snake_rstdp_choices.toml``). The
topology, the training and test lengths and the test track are static.
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp

from robots.snake import tracks
from robots.snake.env import SnakeEnvParams
from robots.snake.rstdp import TOPOLOGIES, NetworkConfig, controller, network_init, network_params
from robots.snake.training import BLOCK, env_for
from spikejax import rollout
from spikejax.ranges import POSITIVE, Range, ranged
from spikejax.sweep import nonfinite

__all__ = ["RSTDPTrialParams", "RSTDPTrialResult", "rstdp_trial"]


@ranged(
    max_rate=POSITIVE,
    tau_c_factor=POSITIVE,
    c_reward_scale=POSITIVE,
    max_steer=Range(0, math.pi / 2, low_open=True),
    event_threshold=Range(0, 1, low_open=True),
)
class RSTDPTrialParams(NamedTuple):
    """Traced parameters of a trial.

    Attributes:
        max_rate: cap of Eq. (2)'s rates, Hz (``inf``: the literal equation).
        tau_c_factor: the hidden layer's ``tau_c`` over the output layer's (and
            its STDP amplitudes divided by it), Sec. III-C-1.
        c_reward_scale: both ``C_reward`` of Eq. (9) times this.
        max_steer: ``C_o`` at ``D_body = 1``, rad.
        event_threshold: the DVS's frame-difference threshold.
    """

    max_rate: float = 300.0
    tau_c_factor: float = 5.0
    c_reward_scale: float = 1.0
    max_steer: float = 0.125
    event_threshold: float = 0.05


class RSTDPTrialResult(NamedTuple):
    """One row of a trial table.

    Attributes:
        train_failures_per_min: failure resets per minute of training.
        test_head_angle_deg: the test's mean ``|MA(a_head)|`` over one gait
            period (`robots.snake.metrics`), until the first failure.
        test_abs_head_deg: mean ``|a_head|`` of the test, until the first failure.
        test_failures_per_min: failure resets per minute of the test.
        test_failed: 1 if the test failed at least once.
        nonfinite: a NaN or infinity appeared.
    """

    train_failures_per_min: jax.Array
    test_head_angle_deg: jax.Array
    test_abs_head_deg: jax.Array
    test_failures_per_min: jax.Array
    test_failed: jax.Array
    nonfinite: jax.Array


_ENVS = {}


def _env(track: str):
    if track not in _ENVS:
        with jax.ensure_compile_time_eval():  # the env's constants, not staged into the trial's trace
            _ENVS[track] = env_for(track)
    return _ENVS[track]


@ranged(train_steps=Range(BLOCK, integer=True), test_steps=Range(BLOCK, integer=True), window=Range(1, integer=True))
def rstdp_trial(
    params: RSTDPTrialParams,
    key: jax.Array,
    *,
    topology: str = "basic",
    train_steps: int = 3000,
    test_steps: int = 3000,
    test_track: str = "zigzag",
    window: int = 125,
) -> RSTDPTrialResult:
    """Train a fresh network on the 8 for ``train_steps`` control steps, then test it frozen on ``test_track``."""
    if topology not in TOPOLOGIES:
        from spikejax.errors import UserError

        raise UserError(f"topology must be one of {', '.join(TOPOLOGIES)}, got {topology!r}")
    tracks.get(test_track)  # a one-line error for an unknown name
    config = NetworkConfig(topology=topology)
    base = network_params(config, tau_c_factor=float(RSTDPTrialParams().tau_c_factor))
    f = lambda v: jnp.asarray(v, jnp.float32)  # noqa: E731
    m = f(params.tau_c_factor)
    first = base.first._replace(
        tau_c=base.second.tau_c * m, A_plus=base.second.A_plus / m, A_minus=base.second.A_minus / m
    )
    net_params = base._replace(
        first=first if config.hidden else base.first,
        max_rate=f(params.max_rate),
        c_reward_head=base.c_reward_head * f(params.c_reward_scale),
        c_reward_body=base.c_reward_body * f(params.c_reward_scale),
    )
    k_net, k_train, k_test = jax.random.split(key, 3)

    def run(env, config, net, steps, key, *, mirror_on_completion):
        env_params = env.params._replace(max_steer=f(params.max_steer), event_threshold=f(params.event_threshold))
        initial = env.reset(jax.random.PRNGKey(0), params=SnakeEnvParams(*env_params))
        loop = rollout.loop_init(initial, net, key=key)

        def reset(state, failed, completed, *, key):
            mirror = state.info["mirror"]
            if mirror_on_completion:
                mirror = jnp.where(completed, ~mirror, mirror)
            return env.restart(initial, state, mirror)

        def summarize(lp, out, es):
            return {"a_head": es.metrics["a_head"], "failed": es.done > 0}

        return rollout.rollout(env.step, reset, controller(config), net_params, loop, steps, summarize=summarize)

    trained, train_rec = run(
        _env("eight"),
        config,
        network_init(config, net_params, key=k_net),
        train_steps,
        k_train,
        mirror_on_completion=True,
    )
    frozen = dataclasses.replace(config, learn=False)
    net = trained.controller._replace(d_head=jnp.float32(0.0), d_body=jnp.float32(0.0))
    _, test_rec = run(_env(test_track), frozen, net, test_steps, k_test, mirror_on_completion=False)

    dt = _env("eight").dt
    a_head = test_rec["last"]["a_head"]
    failed = test_rec["last"]["failed"]
    held = jnp.cumsum(failed) - failed == 0  # up to and including the first failure
    c = jnp.cumsum(jnp.where(held, a_head, 0.0))
    idx = jnp.arange(a_head.shape[0])
    lo = jnp.maximum(idx - window, -1)
    ma = (c - jnp.where(lo >= 0, c[jnp.maximum(lo, 0)], 0.0)) / (idx - lo)
    n_held = jnp.maximum(jnp.sum(held), 1)
    result = RSTDPTrialResult(
        train_failures_per_min=jnp.sum(train_rec["failures"]) / (train_steps * dt / 60.0),
        test_head_angle_deg=jnp.degrees(jnp.sum(jnp.where(held, jnp.abs(ma), 0.0)) / n_held),
        test_abs_head_deg=jnp.degrees(jnp.sum(jnp.where(held, jnp.abs(a_head), 0.0)) / n_held),
        test_failures_per_min=jnp.sum(test_rec["failures"]) / (test_steps * dt / 60.0),
        test_failed=(jnp.sum(test_rec["failures"]) > 0).astype(jnp.float32),
        nonfinite=jnp.bool_(False),
    )
    return result._replace(nonfinite=nonfinite(result))
