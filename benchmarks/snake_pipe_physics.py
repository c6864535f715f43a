"""What physical pipes cost the snake's C physics, measured side by side in one process.

Three models of the same snake, stepped by MuJoCo's C engine through the
physics callback (`robots.snake.physics`, ``"mujoco"`` backend), the slithering
gait held for ``--steps`` control steps in one ``lax.scan`` per batch:

* ``alone``: the snake as ``snake.xml`` has it (`make_physics()`);
* ``parked``: the model with one pipe slot (`robots.snake.pipes.default_bodies`:
  a standing pipe and a 16-stave lying pipe), both parked below the floor;
* ``contact``: the same model with the pipes where the snake meets them: half
  the batch crawls into a standing pipe 0.55 m ahead, half into a lying pipe
  whose entry is 0.35 m ahead (the situations of
  ``tests/test_pipe_world.py``), so that contacts with the pipes are made
  during the run.

The three are interleaved (`spikejax.benchmarking.interleaved`), best of
``--rounds``; compile time is reported apart. Figures: physics control steps
(20 ms of simulated time each) per second, all snakes together.

A second table times MuJoCo's C engine alone on the same three models
(``mujoco.rollout`` on a pool of one thread per core, the gait's servo
targets computed beforehand and, for the piped models, the pipes' mocap
poses in the control vector), which isolates what the contacts cost from the
callback's overhead.

Usage::

    .venv/bin/python benchmarks/snake_pipe_physics.py --batch 1 64 256 --steps 250 --rounds 3
"""

from __future__ import annotations

import argparse
import math
import os
import time

import jax
import jax.numpy as jnp
import mujoco

from robots.snake import pipes
from robots.snake.gait import gait_params, joint_targets
from robots.snake.physics import make_physics, start_at
from spikejax import benchmarking


def _scenes(batch: int) -> pipes.PipeScene:
    standing = pipes.sample(jax.random.key(0), pipes.STANDING, pipes.LEFT)._replace(xy=jnp.array([[0.55, 0.0]]))
    lying = pipes.sample(jax.random.key(0), pipes.LYING, pipes.LEFT)
    lying = lying._replace(xy=jnp.array([[0.35, 0.0]]), yaw=jnp.array([math.pi]))
    half = (batch + 1) // 2
    return jax.tree.map(
        lambda a, b: jnp.concatenate([jnp.stack([a] * half), jnp.stack([b] * half)])[:batch], standing, lying
    )


def _rollout(phys, n_steps, placed: bool):
    gait = gait_params()

    def episode(scene):
        # The start depends on the episode, so that every model steps the whole batch (an unbatched
        # state would reach the physics callback as one snake).
        state = start_at(phys.init(), 0.0 * scene.xy[0, 0], 0.0, 0.0)
        if placed:
            state = pipes.place_pipes(state, scene)

        def body(s, _):
            return phys.step(s, joint_targets(gait, s.time, 0.0, 0.0, True)), None

        return jax.lax.scan(body, state, None, length=n_steps)[0].head_pos

    return jax.vmap(episode)


def _c_rates(batch: int, n_steps: int, rounds: int, nthread: int) -> dict[str, float]:
    """Control steps/s of ``mujoco.rollout`` alone for the three models (see the module docstring)."""
    import numpy as np
    from mujoco import rollout

    from robots.snake.physics import TUNED_DT, joint_qpos_index, load_mj_model

    substeps = round(0.02 / TUNED_DT)
    gait = gait_params()
    times = jnp.arange(n_steps, dtype=jnp.float32) * 0.02
    targets = np.asarray(jax.vmap(lambda t: joint_targets(gait, t, 0.0, 0.0, True))(times), np.float64)
    ctrl = np.repeat(targets, substeps, axis=0)  # (n_steps * substeps, 16)
    scenes = _scenes(batch)
    runs = {}
    pool = rollout.Rollout(nthread=nthread)
    for name in ("alone", "parked", "contact"):
        model = load_mj_model() if name == "alone" else load_mj_model(pipes=pipes.default_bodies(1))
        spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
        data = mujoco.MjData(model)
        state0 = np.empty(mujoco.mj_stateSize(model, spec))
        mujoco.mj_getState(model, data, state0, spec)
        assert np.all(joint_qpos_index(model) > 6)
        control_spec = mujoco.mjtState.mjSTATE_CTRL
        control = np.broadcast_to(ctrl, (batch,) + ctrl.shape)
        if name != "alone":
            control_spec |= mujoco.mjtState.mjSTATE_MOCAP_POS | mujoco.mjtState.mjSTATE_MOCAP_QUAT
            init = make_physics("mujoco", pipes=pipes.default_bodies(1), nthread=1).init()
            if name == "contact":
                placed = jax.vmap(lambda sc: pipes.place_pipes(init, sc))(scenes)
                pos, quat = np.asarray(placed.mocap_pos), np.asarray(placed.mocap_quat)
            else:
                pos = np.broadcast_to(np.asarray(init.mocap_pos), (batch, model.nmocap, 3))
                quat = np.broadcast_to(np.asarray(init.mocap_quat), (batch, model.nmocap, 4))
            mocap = np.concatenate([pos.reshape(batch, -1), quat.reshape(batch, -1)], axis=1)
            mocap = np.broadcast_to(mocap[:, None, :], (batch, ctrl.shape[0], mocap.shape[1]))
            control = np.concatenate([control, mocap], axis=2)
        control = np.ascontiguousarray(control)
        initial = np.ascontiguousarray(np.broadcast_to(state0, (batch, state0.size)))
        datas = [mujoco.MjData(model) for _ in range(nthread)]

        def run(model=model, datas=datas, initial=initial, control=control, control_spec=control_spec):
            t0 = time.perf_counter()
            pool.rollout([model] * batch, datas, initial, control, control_spec=int(control_spec))
            return time.perf_counter() - t0

        runs[name] = run
    best = benchmarking.interleaved(runs, rounds)
    return {name: batch * n_steps / seconds for name, seconds in best.items()}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, nargs="+", default=[1, 64, 256])
    parser.add_argument("--steps", type=int, default=250)
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args(argv)
    nthread = os.cpu_count() or 1
    alone = make_physics("mujoco", nthread=nthread)
    piped = make_physics("mujoco", nthread=nthread, pipes=pipes.default_bodies(1))
    print(benchmarking.machine_banner(mujoco=mujoco.__version__))
    print(f"{'batch':>6} {'model':>8} {'steps/s':>10} {'vs alone':>9} {'compile s':>10}")
    for batch in args.batch:
        scenes = _scenes(batch)
        runs, compile_s = {}, {}
        for name, phys, placed in [("alone", alone, False), ("parked", piped, False), ("contact", piped, True)]:
            compiled, compile_s[name] = benchmarking.compile_ahead(_rollout(phys, args.steps, placed), scenes)
            runs[name] = benchmarking.JaxRun(compiled, scenes)
        best = benchmarking.interleaved(runs, args.rounds)
        for name, seconds in best.items():
            rate = batch * args.steps / seconds
            ratio = best["alone"] / seconds
            print(f"{batch:>6} {name:>8} {rate:>10.0f} {ratio:>9.2f} {compile_s[name]:>10.1f}")
    print("MuJoCo C alone (mujoco.rollout):")
    print(f"{'batch':>6} {'model':>8} {'steps/s':>10} {'vs alone':>9}")
    for batch in args.batch:
        rates = _c_rates(batch, args.steps, args.rounds, nthread)
        for name, rate in rates.items():
            print(f"{batch:>6} {name:>8} {rate:>10.0f} {rate / rates['alone']:>9.2f}")


if __name__ == "__main__":
    main()
