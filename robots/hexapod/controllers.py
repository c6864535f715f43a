"""Controllers of the hexapod's predator-prey loop: the paper's visual SNN, an oracle and a random-gait baseline.

Each is an ``(init, act)`` pair of pure functions, like
`robots.snake.pipe_controller`: ``init(key) -> cstate`` and
``act(cstate, state) -> (cstate, action)``, called before every step of
`robots.hexapod.env.HexapodEnv` on the env's last `brax.envs.base.State`; the
action is the gait (int32: 0 G1 forward, 1 G2 left, 2 G3 right). ``jax.vmap``
batches them with the env.

* `snn`: the hexapod SCPG paper's loop (Sec. IV-C, V): the rate-coded
  winner-take-all of the visual SNN's gait neurons over the last step's events
  (``info["wta"]``; ties and silence keep the gait in force, so the robot
  starts forward, "the robot starts moving forward").
* `snn_ordered`: the same over the ordered readout's counts
  (``info["wta_ordered"]``), where the frame's layer-3 spikes reach the gait
  neurons one at a time, so a gait neuron may fire more than once a frame
  (not in ``CONTROLLERS``: a variant, measured in ``docs/BENCHMARKS.md``).
* `oracle`: `robots.hexapod.prey.truth_gait` from the camera's true pose
  (``info["truth_gait"]``): the rule the SNN approximates, fed the truth; the
  upper bound of this task's rule. It turns toward a prey at any bearing,
  seen or not.
* `oracle_in_view`: the rule as the camera's windows apply it, on the truth:
  "near" when the nearest prey's depth along the camera's axis (its row in
  the image, for a level camera) is within ``D_NEAR`` plus half its size
  (that prey's own size, ``info["nearest"]``),
  a turn toward its side then, else forward; while the prey is outside the
  camera's horizontal field of view (`robots.hexapod.camera.HFOV_DEG`) the
  gait is held, as the SNN keeps its gait in silence. What the paper's rule
  can do with what this camera sees.
* `random`: a gait drawn uniformly at each decision from the controller's own
  key: the lower bound.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

from robots.hexapod.camera import D_NEAR, HFOV_DEG
from robots.hexapod.gaits import N_GAITS
from robots.hexapod.vision import FORWARD, LEFT, RIGHT

__all__ = ["CONTROLLERS", "snn", "snn_ordered", "oracle", "oracle_in_view", "random"]


def _keep_key(key):
    return key


def _snn_act(cstate, state):
    return cstate, state.info["wta"].astype(jnp.int32)


def _snn_ordered_act(cstate, state):
    return cstate, state.info["wta_ordered"].astype(jnp.int32)


def _oracle_act(cstate, state):
    return cstate, state.info["truth_gait"].astype(jnp.int32)


def _forward(key):
    return jnp.zeros((), jnp.int32)


def _oracle_in_view_act(gait, state):
    info = state.info
    bearing = info["bearing"]
    size = info["scene"].size[info["nearest"]]
    near = info["distance"] * jnp.cos(bearing) <= D_NEAR + 0.5 * size
    rule = jnp.where(near, jnp.where(bearing > 0, LEFT, RIGHT), FORWARD)
    seen = jnp.abs(bearing) <= math.radians(0.5 * HFOV_DEG)
    gait = jnp.where(seen, rule, gait).astype(jnp.int32)
    return gait, gait


def _random_act(cstate, state):
    key, sub = jax.random.split(cstate)
    return key, jax.random.randint(sub, (), 0, N_GAITS, dtype=jnp.int32)


snn = (_keep_key, _snn_act)
"""The visual SNN's winner-take-all: the paper's closed loop."""

snn_ordered = (_keep_key, _snn_ordered_act)
"""The same winner-take-all over the ordered readout's counts (`robots.hexapod.decisions.ordered_readout`)."""

oracle = (_keep_key, _oracle_act)
"""The ground-truth rule from the true pose (upper bound)."""

oracle_in_view = (_forward, _oracle_in_view_act)
"""The windows' rule on the truth (near by depth) while the nearest prey is in the camera's view, else the gait held."""

random = (_keep_key, _random_act)
"""A uniformly random gait at each decision, keyed (lower bound)."""

CONTROLLERS = {"snn": snn, "oracle": oracle, "oracle_in_view": oracle_in_view, "random": random}
