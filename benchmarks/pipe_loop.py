"""Whole-loop env-steps/s of the snake pipe loop: now ``spikejax bench snake-pipe`` (`robots.snake.bench_pipe`).

Run: ``python benchmarks/pipe_loop.py [--batches 1 64] [--slots 20] [--rounds 3]``: the line grid in
sync mode on standing pipes (``--cases line-sync`` of the command), on one core and on all, beside
the paper's Table 1. The command has every case, the CSV, the figure and the per-stage breakdown.
"""

import argparse

from robots.snake import bench_pipe


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batches", type=int, nargs="+", default=[1, 64])
    parser.add_argument("--slots", type=int, default=20)
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args(argv)
    batches = ",".join(map(str, args.batches))
    return bench_pipe.run(batches=batches, cases="line-sync", slots=args.slots, repeats=args.rounds)


if __name__ == "__main__":
    main()
