"""Whole-loop env-steps/s of the snake pipe loop: physics, render, DVS, spiking Hough, Alg. 2-3, control.

Run: ``python benchmarks/pipe_loop.py [--batches 1 64] [--slots 20] [--rounds 3]``; prints a
Markdown table (docs/BENCHMARKS.md, "Snake pipe loop"). One env-step is one 20 ms control step of
`robots.snake.pipe_env.PipeEnv` (128 x 128 head camera, frame-difference DVS, the 180 x 180 line
grid in sync mode, Alg. 2 once per slot of 5 steps) driven by the bang-bang controller
(`robots.snake.pipe_controller.bang_bang`), standing pipes sampled per episode. Compile time is
reported apart; the batches are timed in interleaved rounds and the fastest round is kept.
"""

import argparse
import time

import jax

from robots.snake import pipe_controller as pc
from robots.snake import pipe_env


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batches", type=int, nargs="+", default=[1, 64])
    parser.add_argument("--slots", type=int, default=20)
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args(argv)
    env = pipe_env.PipeEnv()
    params = pc.ControllerParams()
    fn = jax.jit(jax.vmap(lambda k: pipe_env.rollout(env, pc.bang_bang, params, k, args.slots)[0]["metrics"]))
    keys, compile_s, best = {}, {}, {}
    for b in args.batches:
        keys[b] = jax.random.split(jax.random.key(0), b)
        t = time.perf_counter()
        jax.block_until_ready(fn(keys[b]))
        compile_s[b] = time.perf_counter() - t
        best[b] = float("inf")
    for _ in range(args.rounds):
        for b in args.batches:
            t = time.perf_counter()
            jax.block_until_ready(fn(keys[b]))
            best[b] = min(best[b], time.perf_counter() - t)
    steps = args.slots * env.slot_steps
    print("| batch | env-steps/s | simulated s per wall s | first call (compile + run), s |")
    print("|---:|---:|---:|---:|")
    for b in args.batches:
        rate = b * steps / best[b]
        print(f"| {b} | {rate:,.0f} | {rate * env.dt:.1f} | {compile_s[b]:.1f} |")


if __name__ == "__main__":
    main()
