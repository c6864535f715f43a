"""Controllers of the pipe-tracking loop: the paper's bang-bang law with a state machine, and two baselines.

Each is an ``(init, act)`` pair of pure functions, like `robots.snake.steering`,
with ``act(params, cstate, state) -> (cstate, action)`` called before every
control step of `robots.snake.pipe_env.PipeEnv` on the env's last
`brax.envs.base.State`; ``action[0] = C`` in ``{-1, 0, +1}`` (the env scales it
by ``max_steer``: ``C_o = C * max_steer``, positive turning right).

`bang_bang` is the decision maker of the snake pipe-tracking paper (Sec. 2.1
and Alg. 3): ``C = sign(offset)``, the control the streaming detector
(`spikejax.vision.stream`) gives at each slot's end and holds between
detections. The paper has no phases (its pipe is in view from the start and
it claims approach, not entry); ours are (`MODES`):

* ``SEARCH``: nothing detected yet, or lost for more than ``lost_slots``
  slots: go straight (``C = 0``). The starts put the pipe in view, so the
  snake slithers on until a detection arrives.
* ``APPROACH``: a detection steered within the last ``lost_slots`` slots:
  ``C`` is the last detection's (bang-bang), held until the next one. While
  the pipe is lost it is held too, a search turn towards the side it was
  last seen on: a pipe that leaves the view while the snake turns towards it
  leaves on the side the snake is turning to, and comes back into view as
  the turn goes on. The default ``lost_slots`` (10 s) outlasts the longest
  gap between detections measured on successful standing approaches (45
  slots); with the first default, 8 slots (0.8 s), the snake went straight
  once a pipe near its side left the view and passed it: 24 of 32 and 25 of
  32 standing placements reached, against 32 and 31 of the same 32 with 100
  slots (the privileged controller: 32 and 32).
  With ``lead > 0`` (`machine_params` for a lying pipe: 0.25 m) it aims
  past the target's centre on the side of the first detection, ``C =
  sign(offset + lead * side)``: steering at an entry's centre brings the
  snake in from the side it came from, across the bore's axis.
* ``FINAL``: the blind last stretch. Once Alg. 3's distance to the pipe has
  come below ``final_distance`` (`machine_params`: where the lying entry's
  ring leaves the circle grid), the last C is dropped and the
  snake goes straight for the dead-reckoned time ``final_distance / speed``
  plus ``margin`` seconds: vision no longer tells where the pipe is. With
  ``narrow > 0`` the gait is narrowed for it too (``action[1] = narrow``,
  `robots.snake.pipe_env.PipeEnv` scales its lateral amplitude): with the
  full gait the head swings about +-0.15-0.2 m across the path and can
  reach the entry plane at the swing's edge, on the rim of a bore that
  leaves 0.20 m for the head's centre. Off by default: on the same 32
  placements (60 s) narrowing to half the amplitude entered 14 lying-right
  pipes against 10 and 7 lying-left against 8 (and, with a circle grid to
  82 px, 12 against 9 lying-right): within the noise, and the narrow gait
  is slow (on the first 16 lying-right placements 0.7 of the amplitude
  entered 8, 0.3 entered 1; narrowing once Alg. 3's distance is below 1 m,
  while still steering, entered none).
* ``INSIDE``: the dead-reckoned stretch is over (the head should be at or in
  the pipe): straight on, ``C = 0`` (the gait still narrowed by
  ``narrow``), until the episode ends.

An estimated distance of 0 (unknown) never starts ``FINAL``. The baselines
are `straight` (``C = 0`` always: the lower bound) and `privileged` (the same
bang-bang fed the **true** side of the pipe, ``sign(lateral)`` of the env's
metrics: the target's offset across the head camera's optical axis now,
updated at the slot ends like the detector's: the upper bound of what
perfect detection gives this law). The true offset from the central line
(``offset_true``, the centre of mass averaged over a gait period) is what
Alg. 3 estimates, but as a steering signal it lags a turn by a period: fed
it, the same law reached 1 of 4 test placements where the spiking detector
reached 3.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from robots.snake.env import SNAKE_SPEED

__all__ = [
    "APPROACH",
    "CONTROLLERS",
    "FINAL",
    "INSIDE",
    "MODES",
    "SEARCH",
    "ControllerParams",
    "ControllerState",
    "machine_params",
    "SwitchParams",
    "bang_bang",
    "privileged",
    "straight",
    "switch",
]

SEARCH, APPROACH, FINAL, INSIDE = 0, 1, 2, 3
MODES = ("search", "approach", "final", "inside")
DT = 0.02  # s, the control step


class ControllerParams(NamedTuple):
    """Traced parameters of the state machine.

    Attributes:
        lost_slots: slots without a steering detection before APPROACH falls back to SEARCH.
        final_distance: Alg. 3's distance, m, below which the blind FINAL stretch starts.
        speed: forward speed for the dead reckoning, m/s.
        margin: s added to the dead-reckoned FINAL stretch.
        narrow: ``action[1]`` in FINAL and INSIDE, in [0, 1]: how far the env narrows the gait (0: not at all).
        lead: m: APPROACH aims this far past the target's centre, on the side of the first detection,
            ``C = sign(offset + lead * side)`` (0: the paper's ``C = sign(offset)``).
        camera_frame: 1: ``offset`` is the detection's side across the head camera's optical axis (Alg. 3's
            ``pipeOffset``, ``info["side_est"]``), the signal the `privileged` controller gets; 0: the
            paper's ``offset = pipeOffset + cameraOffset``, from the central line (``info["offset_est"]``).
        memory: 1: once the env remembers an entry (`robots.snake.pipe_env.PipeEnv`'s ``entry_memory``), every
            slot's end in APPROACH steers by its side in the camera's frame, ``C = sign(info["mem_side"])``,
            seen this slot or not; 0: by the slot's detection.
    """

    lost_slots: float | jax.Array = 100
    final_distance: float | jax.Array = 0.6
    speed: float | jax.Array = SNAKE_SPEED
    margin: float | jax.Array = 2.0
    narrow: float | jax.Array = 0.0
    lead: float | jax.Array = 0.0
    camera_frame: float | jax.Array = 0.0
    memory: float | jax.Array = 0.0


def machine_params(lying: bool, near: bool = False) -> ControllerParams:
    """The state machine's parameters for a target kind: a lying pipe's approach, with or without the ``near`` grid.

    A lying pipe's entry ring leaves the top of the image below about 0.8 m
    and the reduced circle grid's largest ring (`robots.snake.pipe_env.default_tracker`)
    below 0.44 m: the blind stretch starts at 0.45 m. Measured on 16
    lying-right placements (60 s, the same keys): 7 entered from 0.45 m, 8
    with no blind stretch at all, 1 from 0.6 m, where the heading at the
    stretch's start is not yet good enough to enter; the
    privileged controller, steering by the true side to the end, entered 14.
    A standing pipe, tall and ever wider, stays in view to the end, so the
    bang-bang law steers all the way (``final_distance = 0``). Measured on 64
    standing placements: 49 reached either way, the failures all passing the
    pipe, so the blind stretch is not what fails there.

    Into a lying pipe the approach aims 0.25 m past the entry's centre
    (``lead``): steering at the centre, the snake arrives from the side it
    came from, 0.1-0.35 m off the bore's axis when the blind stretch starts
    in most failures. On the same 32 placements a side (60 s, the side
    known): lying-right / lying-left entered 10 / 8 with no lead, 12 / 10
    with 0.1 m, 16 / 12 with 0.25 m, 8 / 9 with 0.4 m (approached 12 / 14:
    the snake passes beside the entry). Shaped by Alg. 3's distance instead,
    on the reproduction's first 32 episodes a side (16 / 13 with 0.25 m): a
    lead fading linearly from 0.25 m at 1.2 m to 0 at 0.45 m entered 14 / 7, one
    growing to 0.5 m over the same range 8 / 6. Episodes of 120 s instead of
    60 entered the same 16 / 13 (the successes take 40 s on average).

    With ``near`` (the circle grid of `robots.snake.pipe_env.default_tracker`'s
    ``near``, which finds the ring down to about 0.35 m) a lying entry is
    steered at to the end: no blind stretch, no lead, and by the ring's side
    across the camera's optical axis (``camera_frame``), the signal of the
    privileged controller. On the reproduction's first 64 placements a side
    (lying-left / lying-right, docs/BENCHMARKS.md): 26 / 29 entered without
    ``near``; with it, Alg. 3's offset and the blind stretch from 0.3 m 29 /
    33, from 0.4 m 20 / 20 (going straight blind is what fails: holding the
    last C does better), the camera frame with the stretch from 0.3 m 41 /
    25, and with none 44 / 29. It also steers at the entry the env remembers
    (``memory``; `robots.snake.pipe_env.PipeEnv`'s ``entry_memory``), which
    counts only where the env keeps one: on the first 32 placements a side
    23 / 28 entered against 22 / 15 (random phases).
    """
    if lying and near:
        return ControllerParams(final_distance=0.0, lead=0.0, camera_frame=1.0, memory=1.0)
    if lying:
        return ControllerParams(final_distance=0.45, lead=0.25)
    return ControllerParams(final_distance=0.0)


class ControllerState(NamedTuple):
    mode: jax.Array  # int32, one of MODES' indices
    control: jax.Array  # float32, the C in force
    since_seen: jax.Array  # int32, slots since a steering detection
    blind: jax.Array  # float32, s left of the dead-reckoned FINAL stretch
    side: jax.Array  # float32, sign of the first steering detection's offset (0 before it)


def _init() -> ControllerState:
    i, f = jnp.zeros((), jnp.int32), jnp.zeros((), jnp.float32)
    return ControllerState(i, f, i, f, f)


def _action(c, narrow=0.0):
    return jnp.stack([c, jnp.broadcast_to(jnp.asarray(narrow, c.dtype), c.shape)])


def _bang_bang_act(params: ControllerParams, cstate: ControllerState, state):
    info = state.info
    slot, ended = info["slot"], info["ended"]
    seen = ended & (slot.body.valid | slot.entry.valid)
    since = jnp.where(seen, 0, cstate.since_seen + ended.astype(jnp.int32))
    mode = cstate.mode
    d = info["d_est"]
    close = seen & (d > 0) & (d < params.final_distance)
    start_final = (mode <= APPROACH) & close
    blind = jnp.where(start_final, params.final_distance / params.speed + params.margin, cstate.blind - DT)
    searching = jnp.where(seen, APPROACH, jnp.where(since > params.lost_slots, SEARCH, mode))
    mode = jnp.where(
        start_final, FINAL, jnp.where(mode >= FINAL, jnp.where(blind <= 0, INSIDE, mode), searching)
    ).astype(jnp.int32)
    camera = params.camera_frame > 0
    offset = jnp.where(camera, info["side_est"], info["offset_est"])
    side = jnp.where(seen & (cstate.side == 0), jnp.sign(offset), cstate.side)
    # A detection's C is followed; between detections (and while lost, up to lost_slots) the last one is held.
    own = (params.lead > 0) | camera
    steer = jnp.where(own, jnp.sign(offset + params.lead * side), slot.control.astype(jnp.float32))
    held = jnp.where(seen, steer, cstate.control)
    remembered = ended & (params.memory > 0) & info["mem_ok"]
    held = jnp.where(remembered, jnp.sign(info["mem_side"]), held)
    control = jnp.where(mode == APPROACH, held, 0.0)
    narrow = jnp.where(mode >= FINAL, params.narrow, 0.0)
    return ControllerState(mode, control, since, blind, side), _action(control, narrow)


def _straight_act(params, cstate: ControllerState, state):
    return cstate, _action(jnp.zeros((), jnp.float32))


def _privileged_act(params, cstate: ControllerState, state):
    ended = state.info["ended"]
    truth = jnp.sign(state.metrics["lateral"])
    control = jnp.where(ended | (state.info["control_steps"] == 0), truth, cstate.control)
    return cstate._replace(control=control, mode=jnp.full((), APPROACH, jnp.int32)), _action(control)


bang_bang = (_init, _bang_bang_act)
"""The paper's ``C = sign(offset)`` from the spiking detector, with the state machine of the module's notes."""

straight = (_init, _straight_act)
"""Go straight: ``C = 0`` (the lower bound)."""

privileged = (_init, _privileged_act)
"""The bang-bang law fed the pipe's true side in the head camera's frame at each slot's end (the upper bound)."""

CONTROLLERS = {"bang-bang": 0, "straight": 1, "privileged": 2}


class SwitchParams(NamedTuple):
    """`switch`'s parameters: the state machine's and ``which`` (int32, a `CONTROLLERS` value), both traced."""

    machine: ControllerParams
    which: jax.Array


def _switch_act(params: SwitchParams, cstate: ControllerState, state):
    outs = [act(params.machine, cstate, state) for act in (_bang_bang_act, _straight_act, _privileged_act)]
    which = jnp.asarray(params.which, jnp.int32)
    return jax.tree.map(lambda *xs: jnp.select([which == k for k in range(len(xs))], xs), *outs)


switch = (_init, _switch_act)
"""Any of `CONTROLLERS`, chosen by the traced ``params.which``: a batch compares controllers in one program."""
