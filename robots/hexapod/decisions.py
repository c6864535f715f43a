"""Open-loop prey decisions (ACCEPTANCE A6): one G1 step from rest, its events, the visual SNN's choice.

For each scene the robot stands at its start and walks one tripod (G1) cycle,
two CPG steps of 0.16 s (`robots.hexapod.legs.step_params`), on MuJoCo's C
engine (`physics.walk`, each scene its own randomised robot). The head camera
(`robots.hexapod.camera`) renders a frame every `FRAME_S` = 20 ms (SPEC 4.3:
at least 10 frames a CPG step), 17 frames from the standing one. The
contrast-threshold DVS emulator (`spikejax.vision.dvs.step_counts`, thresholds 0.2
with 3 % mismatch, 0.5 Hz shot noise a pixel, at most `MAX_PER_PIXEL` events
a pixel and interval) turns each interval into events, counted per pixel; the
crossings beyond `MAX_PER_PIXEL` (``clipped``) are counted apart from the
events an event list of `capacity` a frame interval would not hold
(``overflow``: `dvs.step`'s list, whose count image this is whenever that is
0; docs/BENCHMARKS.md gives both and what raising the cap changes);
each frame's events, as a per-pixel count image, drive the visual SNN once at
the frame's time (`spikejax.vision.edges.sync_step`, the paper's weights scaled
to 20-pixel windows by `robots.hexapod.vision.vision_params`). The decision is
the winner-take-all over the gait neurons' spike counts of the whole step
(`edges.winner`, G1 kept on silence: the robot starts forward). A second
readout is computed beside it from the same layer-3 spikes, `ordered_readout`:
the frame's window spikes reach the gait neurons one at a time, as in an
event-driven network, instead of all at once (where a gait neuron fires at
most once a frame).

The truth (`prey.truth_gait`) is measured from the camera's ground point at the
start: forward while the nearest living prey's centre is beyond
``D_NEAR + size / 2`` (its front face beyond the camera's near/far boundary),
else the turn toward its side.

Everything after the physics is one pure function of (torso track, scene,
key), `decide`, batched by ``vmap``; the same seed gives the same decision
whatever the batch.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from robots.hexapod import camera as cam
from robots.hexapod import physics
from robots.hexapod import prey as prey_mod
from robots.hexapod.gaits import PERIOD, required_spikes
from robots.hexapod.legs import servo_targets, step_params
from robots.hexapod.vision import FORWARD, WIRING, vision_params
from spikejax.devices import in_chunks_on_cpu
from spikejax.vision import dvs, edges

__all__ = [
    "FRAME_S",
    "N_FRAMES",
    "CAPACITY",
    "MAX_PER_PIXEL",
    "capacity",
    "g1_step_tracks",
    "ordered_readout",
    "Decision",
    "decide",
    "truth",
]

FRAME_S = 0.02
N_FRAMES = 17  # the standing frame and 16 frames over the 0.32 s cycle
CAPACITY = 8192  # events a frame interval on the 160 x 256 sensor; the overflow is counted
MAX_PER_PIXEL = 4  # events a pixel and frame interval; the crossings beyond are counted apart
_DVS = dvs.dvs_params(threshold_sigma=0.03, noise_rate=0.5)


def capacity(config: edges.EdgeConfig) -> int:
    """`CAPACITY` scaled to ``config``'s pixels (204,800 at the paper's 800 x 1280)."""
    base = cam.EDGE_CONFIG.height * cam.EDGE_CONFIG.width
    return -(-CAPACITY * config.height * config.width // base)


def g1_step_tracks(draws: list[tuple], *, nthread: int | None = None) -> np.ndarray:
    """Torso states ``(x, y, z, roll, pitch, yaw)`` at the frame times, ``(n, N_FRAMES, 6)``: one G1 cycle from rest.

    Each walk is its own robot, one ``(friction, mass_scale, servo_gain)`` of
    ``draws`` each (`physics.randomised`; ``(0.8, 1.0, 1.0)`` is the nominal one).
    """
    p = step_params()
    models = [physics.load_model(*d) for d in draws]
    dt = models[0].opt.timestep
    steps_per_frame = int(round(FRAME_S / dt))
    n_steps = (N_FRAMES - 1) * steps_per_frame
    t = jnp.arange(n_steps, dtype=jnp.float32) * dt
    controls = np.asarray(servo_targets(p, jnp.asarray(required_spikes(0, PERIOD)), t))
    initial = np.stack([physics.standing_state(m) for m in models])
    w = physics.walk(models, controls, nthread=nthread, initial=initial)
    # Walk sample k is the state after step k + 1, at time (k + 1) dt: frame j > 0 is sample j * spf - 1.
    idx = np.arange(1, N_FRAMES) * steps_per_frame - 1
    moving = np.stack([w.xy[:, idx, 0], w.xy[:, idx, 1], w.height[:, idx], w.roll[:, idx], w.pitch[:, idx]], -1)
    moving = np.concatenate([moving, w.yaw[:, idx, None]], axis=-1)
    standing = np.stack([_standing_torso(m, state) for m, state in zip(models, initial)])[:, None]
    return np.concatenate([standing, moving], axis=1).astype(np.float32)


def _standing_torso(model, state) -> np.ndarray:
    qpos = state[1 : 1 + model.nq]
    w = physics.torso_walk(np.zeros(1), qpos[None])
    return np.array([w.xy[0, 0], w.xy[0, 1], w.height[0], w.roll[0], w.pitch[0], w.yaw[0]])


def _to_scene_frame(track: jax.Array, start: jax.Array) -> jax.Array:
    """A track walked from the origin facing +x, moved to start at ``start = (x, y, yaw)``."""
    c, s = jnp.cos(start[2]), jnp.sin(start[2])
    x = start[0] + c * track[:, 0] - s * track[:, 1]
    y = start[1] + s * track[:, 0] + c * track[:, 1]
    return jnp.stack([x, y, track[:, 2], track[:, 3], track[:, 4], track[:, 5] + start[2]], axis=-1)


def ordered_readout(v, n, w, v_th=1.0):
    """A readout neuron given ``n`` input spikes of weight ``w`` one after another: ``(fires, v)``.

    Eq. (1)-(2) of the hexapod paper with no leak between the inputs (they
    come in one frame): from ``v`` the first spike is fired by the
    ``k1 = floor((v_th - v) / w) + 1``-th input, then, from the reset to 0, every
    ``m = floor(v_th / w) + 1``-th (three at 0.4, two at 0.7). This is what the
    readout would do if the frame's layer-3 spikes reached it at their own
    event times, as in the paper's event-driven network; `edges.sync_step`'s
    readout takes them all at once and fires at most once a frame.
    """
    safe_w = jnp.where(w > 0, w, 1.0)
    k1 = jnp.floor((v_th - v) / safe_w) + 1
    m = jnp.floor(v_th / safe_w) + 1
    n = n.astype(jnp.float32)
    fires = jnp.where((w > 0) & (n >= k1), 1 + jnp.floor((n - k1) / m), 0.0)
    v_end = jnp.where(fires > 0, (n - k1 - (fires - 1) * m) * w, v + n * w)
    return fires.astype(jnp.int32), v_end


class Decision(NamedTuple):
    """One scene's step.

    Attributes:
        gait: the winner-take-all's choice (0 G1, 1 G2 left, 2 G3 right).
        truth: `prey.truth_gait` at the start.
        out_counts: the gait neurons' spikes over the step, ``(3,)``.
        gait_ordered, ordered_counts: the same with the frame's layer-3 spikes
            reaching the gait neurons one by one (`ordered_readout`).
        window_counts: layer-3 spikes, ``(8, 12, 2)``.
        events, filter_spikes, layer2_spikes: totals over the step.
        overflow: events beyond `capacity` a frame interval, summed: what an event list would drop (the
            count image keeps them; 0 in every scene of the reproduction).
        clipped: threshold crossings beyond `MAX_PER_PIXEL` a pixel and frame
            interval, made into no event (`spikejax.vision.dvs.crossings`).
    """

    gait: jax.Array
    truth: jax.Array
    out_counts: jax.Array
    gait_ordered: jax.Array
    ordered_counts: jax.Array
    window_counts: jax.Array
    events: jax.Array
    filter_spikes: jax.Array
    layer2_spikes: jax.Array
    overflow: jax.Array
    clipped: jax.Array


def truth(scene: prey_mod.PreyScene, torso0) -> jax.Array:
    """The ground-truth gait from the camera's ground point (module docstring)."""
    return prey_mod.truth_gait(scene, cam.ground_pose(torso0), cam.D_NEAR + 0.5 * scene.size[0])


def frames(track: jax.Array, scene: prey_mod.PreyScene, camera=cam.CAMERA) -> jax.Array:
    """The head camera's frames along a torso track (from the origin), ``(N_FRAMES, height, width)``."""
    world = cam.prey_scene(scene)
    track = _to_scene_frame(jnp.asarray(track, jnp.float32), scene.start)
    return jax.vmap(lambda torso: cam.frame(torso, world, camera))(track)


def decide(
    track: jax.Array,
    scene: prey_mod.PreyScene,
    key: jax.Array,
    with_spikes: bool = False,
    *,
    config: edges.EdgeConfig = cam.EDGE_CONFIG,
    lens: str = cam.LENS,
    wiring: str = WIRING,
):
    """Render, emulate, filter and choose along one torso track ``(N_FRAMES, 6)``: a `Decision`.

    With ``with_spikes`` also the per-frame ``(events count image, edges.Spikes)`` for figures.
    ``config`` (static) is the sensor: the scaled `camera.EDGE_CONFIG`, or
    `vision.PAPER_SENSOR` for the paper's 800 x 1280 pixels and 100-pixel
    windows with its own weights (ACCEPTANCE A11); the camera's pose, lens,
    DVS noise rate per pixel and the scene are the same. ``lens`` (static,
    `camera.LENSES`): where the optical axis meets the sensor. ``wiring``
    (static, `robots.hexapod.vision.WIRINGS`): the readout onto the gait
    neurons; the ordered readout takes the excitatory synapses only.

    Under ``vmap`` on a CPU the members run `DECIDE_CHUNK` at a time (each
    member's decision is the same whatever the batch).
    """
    return _chunked(bool(with_spikes), config, lens, wiring, DECIDE_CHUNK)(track, scene, key)


DECIDE_CHUNK = 4
"""Members `decide` runs at a time under ``vmap`` on a CPU (``lax.map`` over chunks): the DVS's and the SNN's
image-sized arrays of a few members stay in the cache, those of a whole batch do not. At a batch of 256 on one core
a decision of the vision took 1.45x as long whole as in chunks of 4 (1.27x against chunks of 16), the closed loop's
1.39x (docs/BENCHMARKS.md)."""


@functools.cache
def _chunked(with_spikes: bool, config: edges.EdgeConfig, lens: str, wiring: str, chunk: int):
    """`_decide` for these static arguments, batched by ``vmap`` in chunks of ``chunk`` on a CPU."""
    return in_chunks_on_cpu(
        lambda track, scene, key: _decide(track, scene, key, with_spikes, config, lens, wiring), chunk
    )


def _decide(track, scene, key, with_spikes: bool, config: edges.EdgeConfig, lens: str, wiring: str):
    """`decide` for one member."""
    params = vision_params(config, wiring)
    cap = capacity(config)
    camera = cam.sensor_camera(config, lens)
    world = cam.prey_scene(scene)
    poses = _to_scene_frame(jnp.asarray(track, jnp.float32), scene.start)
    times = jnp.arange(N_FRAMES, dtype=jnp.float32) * FRAME_S
    k_init, k_steps = jax.random.split(key)
    # Each frame is rendered where the DVS takes it: 17 frames of a batch held at once would not stay in cache.
    dvs_state = dvs.init(_DVS, cam.frame(poses[0], world, camera), times[0], key=k_init)
    snn = edges.init(config, times[0])

    w_out = jnp.max(params.readout, axis=(1, 2, 3))  # one weight a gait neuron (0.4, 0.7, 0.7)
    inputs_of = params.readout > 0

    def body(carry, inputs):
        dvs_state, snn, (overflow, clipped), (v_ord, t_ord, n_ord) = carry
        pose, t, k = inputs
        image = cam.frame(pose, world, camera)
        dvs_state, count, clip = dvs.step_counts(_DVS, dvs_state, image, t, max_per_pixel=MAX_PER_PIXEL, key=k)
        beyond = jnp.maximum(jnp.sum(count) - cap, 0)
        snn, spikes = edges.sync_step(config, params, snn, count, t)
        n_in = jnp.sum(inputs_of & spikes.windows[None], axis=(1, 2, 3))
        touched = n_in > 0
        v_leaked = v_ord * jnp.exp(-(t - t_ord) / params.tau_out)
        fires, v_new = ordered_readout(v_leaked, n_in, w_out, params.v_th)
        ordered = (jnp.where(touched, v_new, v_ord), jnp.where(touched, t, t_ord), n_ord + fires)
        out = (count, spikes) if with_spikes else None
        return (dvs_state, snn, (overflow + beyond, clipped + clip), ordered), out

    keys = jax.random.split(k_steps, N_FRAMES - 1)
    zeros = jnp.zeros((config.n_out,), jnp.float32)
    ordered0 = (zeros, zeros + times[0], jnp.zeros((config.n_out,), jnp.int32))
    zero = jnp.zeros((), jnp.int32)
    (_, snn, (overflow, clipped), (_, _, n_ordered)), per_frame = jax.lax.scan(
        body, (dvs_state, snn, (zero, zero), ordered0), (poses[1:], times[1:], keys)
    )
    c = snn.counts
    decision = Decision(
        gait=edges.winner(c["out"], jnp.int32(FORWARD)),
        truth=truth(scene, _to_scene_frame(jnp.asarray(track[:1], jnp.float32), scene.start)[0]),
        out_counts=c["out"],
        gait_ordered=edges.winner(n_ordered, jnp.int32(FORWARD)),
        ordered_counts=n_ordered,
        window_counts=c["windows"],
        events=c["events"],
        filter_spikes=c["filter"],
        layer2_spikes=c["layer2"],
        overflow=overflow,
        clipped=clipped,
    )
    return (decision, per_frame) if with_spikes else decision
