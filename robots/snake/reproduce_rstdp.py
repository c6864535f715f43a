"""``spikejax reproduce snake-rstdp`` and ``spikejax evaluate snake-rstdp``: Sec. III-IV of the snake R-STDP paper, many seeds.

``reproduce`` trains every topology (`robots.snake.rstdp.TOPOLOGIES`, and
the separated net with Eq. (13) as printed, ``separated/printed``, beside the
default sign of Eq. (10)) for
``--train-laps`` passes of the 8 (`robots.snake.training.train`, all seeds in
one vmapped program per worker process, ``--workers``, one a core, each a
share of the seeds; checkpointed so a killed run resumes), tests the frozen
networks on one pass of each test track (ladder, zigzag and their mirror
images) and writes, in ``--out``:

* ``snake_rstdp.csv``: per topology, track and metric window, the seeds'
  mean of every metric of `robots.snake.metrics` with a 95 % interval over
  seeds (Student t; Wilson for the share of seeds that ever failed; the share
  of the failures that the body-angle rule fired, `body_rule_share`), beside the
  paper's claim (separated < 2 degrees, basic < 4 degrees, unified resets
  every ~50 s);
* ``weights/TOPOLOGY.npz``: the trained weights of every seed;
* ``training/TOPOLOGY.npz``: the training records, and the figures
  ``snake_rstdp_training.png`` (head and body angle, distance, failures over
  training: Figs. 7-9), ``snake_rstdp_weights.png`` (weights over training:
  Figs. 6, 8a), ``snake_rstdp_test.png`` (angle and decoded directions on each
  test track: Fig. 10) and ``snake_rstdp_trajectories.png``.

The env is `robots.snake.training.env_for`'s; ``--head-compensation`` and
``--lag-tau`` change what its head compensation reads (`env_settings`),
for training and test alike, and the weights files keep them.

``evaluate`` tests saved weights on any track, a name or a CSV of waypoints,
in the env they were trained in.

``reproduce snake-rstdp-choices`` runs ``sweeps/snake_rstdp_choices.toml``
(the rate cap of Eq. (2), the steering range, the scale of ``C_reward``) and
writes ``snake_rstdp_choices.csv`` and ``snake_rstdp_choices.png``, heat maps of
the test's failures per minute and mean head angle over the grid.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from robots.snake import metrics, rstdp, tracks, training
from robots.snake.env import COMPENSATE_FROM, LOST_HEAD_ANGLE
from robots.snake.gait import gait_params, gait_period
from spikejax.benchmarking import write_csv
from spikejax.commands import Command, add_common, count, output_directory
from spikejax.errors import UserError
from spikejax.stats import mean_interval, wilson_interval

__all__ = ["reproduce_command", "evaluate_command", "choices_command", "TEST_TRACKS", "HEADER"]

TEST_TRACKS = ("ladder", "ladder-mirror", "zigzag", "zigzag-mirror")
PAPER = {
    "basic": "mean head angle rarely beyond 4 deg, no failure",
    "basic-head": "unstable in training (not tested)",
    "unified": "never completes a test episode, reset every ~50 s",
    "separated": "mean head angle below 2 deg",
}
HEADER = [
    "topology",
    "track",
    "window_steps",
    "seeds",
    "mean_head_angle_deg",
    "ci_low",
    "ci_high",
    "p95_head_angle_deg",
    "instant_head_angle_deg",
    "failures_per_min",
    "failures_per_min_ci_low",
    "failures_per_min_ci_high",
    "seeds_failed",
    "seeds_failed_ci_low",
    "seeds_failed_ci_high",
    "failures_by_body_rule",
    "completed",
    "steering_changes_per_100s",
    "time_at_limit",
    "paper",
]


DEFAULT_TOPOLOGIES = (*rstdp.TOPOLOGIES, "separated/printed")  # both signs of Eq. (13), measured side by side
VARIANTS = {
    "head": {"hidden_reward": "head"},  # reading B: the synapses onto H keep the head reward
    "printed": {"eq13_sign": "printed"},  # Eq. (13) with the paper's printed minus
    "negative-left": {"joints_left": "negative"},  # the other assignment of joint neurons to the groups
}


def _config(name: str) -> rstdp.NetworkConfig:
    """A topology, or ``TOPOLOGY/VARIANT`` for an ablation (`VARIANTS`)."""
    topology, _, variant = name.partition("/")
    return rstdp.NetworkConfig(topology=topology, **VARIANTS.get(variant, {}))


def _windows(env) -> tuple[int, ...]:
    period = int(round(float(gait_period(gait_params())) / env.dt))
    return (period, metrics.PAPER_WINDOW)


def save_weights(path: Path, topology: str, seeds, loop, training_settings: str = "", env_kwargs=None) -> None:
    """The trained weights of every seed, atomically.

    ``training_settings`` names the training that made them; ``env_kwargs``
    the env's settings beside `robots.snake.training.env_for`'s defaults, read
    back by `trained_env` so that a test runs them in the env they learned in.
    """
    tmp = path.with_suffix(".tmp.npz")
    net = jax.device_get(loop.controller)
    np.savez(
        tmp,
        topology=topology,
        seeds=np.asarray(seeds),
        w_first=net.w_first,
        w_hidden=net.w_hidden,
        training=training_settings,
        env=json.dumps(env_kwargs or {}),
    )
    tmp.replace(path)


def _trained_with(path: Path) -> str:
    """The ``training_settings`` a weights file was saved with ("" for a file saved without)."""
    with np.load(path) as z:
        return str(z["training"]) if "training" in z.files else ""


def trained_env(path: Path) -> dict:
    """The env settings a weights file was trained with (`save_weights`); {} (`env_for`'s defaults) if it has none."""
    with np.load(path) as z:
        return json.loads(str(z["env"])) if "env" in z.files else {}


def env_settings(head_compensation: str, lag_tau: float) -> dict:
    """``--head-compensation`` and ``--lag-tau`` as `robots.snake.training.env_for`'s keyword arguments."""
    if head_compensation not in COMPENSATE_FROM:
        raise UserError(f"--head-compensation must be one of {', '.join(COMPENSATE_FROM)}, got {head_compensation!r}")
    if not lag_tau > 0:
        raise UserError(f"--lag-tau must be positive, got {lag_tau}")
    return {"compensate_from": head_compensation} | ({"lag_tau": lag_tau} if head_compensation == "lagged" else {})


def load_weights(path: Path) -> tuple[str, np.ndarray, np.ndarray, np.ndarray]:
    """``(topology, seeds, w_first, w_hidden)`` of a weights file; a one-line error if it is not one."""
    try:
        with np.load(path) as z:
            topology = str(z["topology"])
            out = topology, z["seeds"], z["w_first"], z["w_hidden"]
    except (OSError, KeyError, ValueError) as e:
        raise UserError(f"{path}: not a snake-rstdp weights file ({e.__class__.__name__})") from None
    base, _, variant = topology.partition("/")
    if base not in rstdp.TOPOLOGIES or (variant and variant not in VARIANTS):
        raise UserError(f"{path}: unknown topology {topology!r}")
    return out


def networks_with(config, params, seeds, w_first, w_hidden):
    """Fresh networks (neurons at rest, as after loading) with the given weights, one per seed."""

    def one(seed, w1, w2):
        k_net, _ = jax.random.split(jax.random.PRNGKey(seed))
        net = rstdp.network_init(config, params, key=k_net)
        return net._replace(w_first=w1, w_hidden=w2)

    return jax.vmap(one)(jnp.asarray(seeds, jnp.uint32), jnp.asarray(w_first), jnp.asarray(w_hidden))


def body_rule_share(trace: training.TestTrace) -> float:
    """The share of a trace's failures that the body-angle rule of Sec. III-B fired (NaN without failures).

    At a failure either ``|a_head|`` passed `robots.snake.env.LOST_HEAD_ANGLE`
    (the head rule) or the body's running-mean angle passed
    ``LOST_BODY_ANGLE``; a failure with the head inside its bound is the
    body rule's. A net with a head controller can keep the target centred
    while its body turns away, and only this rule sees it.
    """
    failed = np.asarray(trace.failed, bool)
    n = int(failed.sum())
    body = int((failed & (np.abs(trace.a_head) <= LOST_HEAD_ANGLE)).sum())
    return body / n if n else float("nan")


def test_rows(topology: str, track_name: str, trace: training.TestTrace, dt: float, windows) -> list[list]:
    """Rows of ``snake_rstdp.csv`` for one topology on one track."""
    rows = []
    n = trace.a_head.shape[0]
    for window in windows:
        per_seed = [
            metrics.seed_metrics(
                trace.a_head[i], trace.d_body[i], trace.failed[i], trace.completed[i], dt=dt, window=window
            )
            for i in range(n)
        ]
        col = lambda k: np.array([m[k] for m in per_seed], float)  # noqa: E731
        mean, lo, hi = mean_interval(col("mean_head_angle_deg"))
        fpm, flo, fhi = mean_interval(col("failures_per_min"))
        failed = int(np.sum(col("failures_per_min") > 0))
        wlo, whi = wilson_interval(failed, n)
        body_rule = body_rule_share(trace)
        rows.append(
            [
                topology,
                track_name,
                window,
                n,
                round(mean, 3),
                round(lo, 3),
                round(hi, 3),
                round(float(np.median(col("p95_head_angle_deg"))), 3),
                round(float(col("instant_head_angle_deg").mean()), 3),
                round(fpm, 3),
                round(flo, 3),
                round(fhi, 3),
                round(failed / n, 3),
                round(float(wlo), 3),
                round(float(whi), 3),
                round(body_rule, 3),
                round(float(col("completed").mean()), 3),
                round(float(col("steering_changes_per_100s").mean()), 3),
                round(float(col("time_at_limit").mean()), 3),
                PAPER[topology] if topology in PAPER else f"ablation of {topology.partition('/')[0]}",
            ]
        )
    return rows


def training_steps(env, train_laps: float, chunk_steps: int | None = None) -> tuple[int, int]:
    """Control steps of a training of ``train_laps`` passes of the 8 (whole blocks, whole chunks), and the chunk."""
    steps = int(np.ceil(train_laps * training.lap_steps(env) / training.BLOCK) * training.BLOCK)
    chunk = min(steps, chunk_steps or 20 * training.BLOCK)
    return int(np.ceil(steps / chunk) * chunk), chunk


def _name(topology: str) -> str:
    return topology.replace("/", "-")


@functools.lru_cache(maxsize=None)
def _test_length(name: str, test_steps: int | None) -> int:
    return test_steps or training.pass_steps(training.env_for(name, camera=False))


def _save_npz(path: Path, **arrays) -> None:
    tmp = path.with_suffix(".tmp.npz")
    np.savez(tmp, **arrays)
    tmp.replace(path)


def _load_npz(path: Path) -> dict:
    with np.load(path) as z:
        return {k: z[k] for k in z.files}


def run_share(
    out: Path,
    topology: str,
    start: int,
    stop: int,
    steps: int,
    chunk: int,
    fingerprint: str,
    test_steps,
    env_kwargs=None,
    progress=None,
) -> None:
    """Seeds ``start .. stop - 1`` of one topology: trained (unless ``out``'s weights have them) and tested.

    Writes ``out/parts/TOPOLOGY/seeds-START-STOP/``: the share's training
    records and weights, and a test trace per track (unless ``out/tests``
    has the whole trace); `run` merges the shares. Each file is written
    atomically and skipped when present, so a killed share resumes (its
    training from its checkpoints). ``progress(phase, done, total)``, if
    given, is called as training advances (``"train"``) and after each test
    track (``"test"``). ``env_kwargs`` go to `robots.snake.training.env_for`.
    """
    config = _config(topology)
    params = rstdp.network_params(config)
    seeds = np.arange(start, stop)
    part = out / "parts" / _name(topology) / f"seeds-{start}-{stop}"
    part.mkdir(parents=True, exist_ok=True)
    merged = out / "weights" / f"{_name(topology)}.npz"
    if merged.exists():
        _, _, w1, w2 = load_weights(merged)
        w1, w2 = w1[start:stop], w2[start:stop]
    else:
        if (part / "weights.npz").exists() and _trained_with(part / "weights.npz") != fingerprint:
            raise UserError(f"{part} holds a share of another training (seeds or --train-laps); give another --out")
        if not (part / "weights.npz").exists():
            result = training.train(
                config,
                params,
                seeds,
                steps,
                env=training.env_for("eight", frame_rows=config.roi[:2], **(env_kwargs or {})),
                chunk_steps=chunk,
                directory=out / "checkpoints" / _name(topology) / f"seeds-{start}-{stop}",
                fingerprint=json.dumps([fingerprint, start, stop]),
                progress=None if progress is None else (lambda done, total: progress("train", done, total)),
            )
            _save_npz(part / "training.npz", **_flatten(jax.device_get(result.records)))
            save_weights(part / "weights.npz", topology, seeds, result.loop, fingerprint, env_kwargs)
        _, _, w1, w2 = load_weights(part / "weights.npz")
    nets = networks_with(config, params, seeds, w1, w2)
    # A track and its mirror image run as one batch of twice the seeds (the same trials as two batches).
    for i, base in enumerate(dict.fromkeys(name.removesuffix("-mirror") for name in TEST_TRACKS)):
        pair = (base, f"{base}-mirror")
        length = _test_length(base, test_steps)
        pieces = [part / f"test-{name}-{length}.npz" for name in pair]
        done = [
            (out / "tests" / f"{_name(topology)}-{name}-{length}.npz").exists() or p.exists()
            for name, p in zip(pair, pieces)
        ]
        if not all(done):
            both = jax.tree.map(lambda x: jnp.concatenate([x, x]), nets)
            mirror = np.repeat([False, True], len(seeds))
            trace = training.test(
                config, params, both, base, test_steps, seeds=np.tile(seeds, 2), mirror=mirror, env_kwargs=env_kwargs
            )
            for k, piece in enumerate(pieces):
                _save_npz(piece, **{f: v[k * len(seeds) : (k + 1) * len(seeds)] for f, v in trace._asdict().items()})
        if progress is not None:
            progress("test", 2 * (i + 1), len(TEST_TRACKS))


def _merge_shares(out: Path, topology: str, ranges, seeds: int, fingerprint: str, test_steps, env_kwargs) -> None:
    """The shares' files of one topology as the whole run's (seed order), then the shares removed."""
    import shutil

    parts = [out / "parts" / _name(topology) / f"seeds-{a}-{b}" for a, b in ranges]
    weights = out / "weights" / f"{_name(topology)}.npz"
    if not weights.exists():
        records = [_load_npz(p / "training.npz") for p in parts]
        _save_npz(
            out / "training" / f"{_name(topology)}.npz",
            **{k: np.concatenate([r[k] for r in records]) for k in records[0]},
        )
        loaded = [load_weights(p / "weights.npz") for p in parts]
        _save_npz(
            weights,
            topology=topology,
            seeds=np.arange(seeds),
            w_first=np.concatenate([w[2] for w in loaded]),
            w_hidden=np.concatenate([w[3] for w in loaded]),
            training=fingerprint,
            env=json.dumps(env_kwargs or {}),
        )
    for name in TEST_TRACKS:
        length = _test_length(name, test_steps)
        whole = out / "tests" / f"{_name(topology)}-{name}-{length}.npz"
        if not whole.exists():
            traces = [_load_npz(p / f"test-{name}-{length}.npz") for p in parts]
            _save_npz(whole, **{k: np.concatenate([t[k] for t in traces]) for k in traces[0]})
    shutil.rmtree(out / "parts" / _name(topology), ignore_errors=True)


class _Bars:
    """A topology's training and test progress bars, summed over its shares."""

    def __init__(self, topology: str, steps: int, n_shares: int, enabled: bool):
        from tqdm import tqdm

        self.done = {}
        self.bars = {
            "train": tqdm(total=steps * n_shares, desc=f"train {topology}", unit="step", disable=not enabled),
            "test": tqdm(total=len(TEST_TRACKS) * n_shares, desc=f"test {topology}", unit="track", disable=not enabled),
        }

    def update(self, share: int, phase: str, done: int) -> None:
        self.done[share, phase] = done
        bar = self.bars[phase]
        bar.n = sum(v for (_, p), v in self.done.items() if p == phase)
        bar.refresh()

    def close(self) -> None:
        for bar in self.bars.values():
            bar.close()


def _share_in_worker(queue, index, *args) -> None:
    run_share(*args, progress=lambda phase, done, total: queue.put((index, phase, done)))


def _run_shares(out, topology, ranges, steps, chunk, fingerprint, test_steps, env_kwargs, bars, executor) -> None:
    """Every share of one topology: in this process (``executor`` None) or one a worker, progress drawn here."""
    if executor is None:
        for i, (a, b) in enumerate(ranges):
            run_share(
                out,
                topology,
                a,
                b,
                steps,
                chunk,
                fingerprint,
                test_steps,
                env_kwargs,
                progress=lambda phase, done, total, i=i: bars.update(i, phase, done),
            )
        return
    import multiprocessing
    import queue as queues

    with multiprocessing.get_context("spawn").Manager() as manager:
        q = manager.Queue()
        futures = [
            executor.submit(
                _share_in_worker, q, i, out, topology, a, b, steps, chunk, fingerprint, test_steps, env_kwargs
            )
            for i, (a, b) in enumerate(ranges)
        ]
        while not all(f.done() for f in futures):
            try:
                bars.update(*q.get(timeout=0.5))
            except queues.Empty:
                pass
        for f in futures:
            f.result()  # a share's exception, raised here


def run(
    out: Path,
    *,
    seeds: int,
    train_laps: float,
    topologies,
    test_steps: int | None = None,
    chunk_steps: int | None = None,
    progress: bool = True,
    workers: int | None = 1,
    env_kwargs=None,
) -> list[list]:
    """Train, test, write everything in the module docstring; returns the table's rows.

    ``workers``: processes, one a core (`spikejax.workers.pool`), each
    training and testing a contiguous share of the seeds; 1 runs everything
    in this process, None one a core. The results do not depend on it.
    ``env_kwargs``: the env's settings beside `robots.snake.training.env_for`'s
    defaults (`env_settings`), for training and test alike.
    """
    from spikejax import workers as pools

    (out / "weights").mkdir(parents=True, exist_ok=True)
    (out / "training").mkdir(exist_ok=True)
    (out / "checkpoints").mkdir(exist_ok=True)
    (out / "tests").mkdir(exist_ok=True)
    env = training.env_for("eight")
    steps, chunk = training_steps(env, train_laps, chunk_steps)
    ranges = pools.shares(seeds, pools.workers_for_run(workers))
    rows, traces, train_records = [], {}, {}
    executor = pools.pool(len(ranges)) if len(ranges) > 1 else None
    try:
        for topology in topologies:
            config, t0 = _config(topology), time.time()
            weights = out / "weights" / f"{_name(topology)}.npz"
            fingerprint = json.dumps([dataclasses.asdict(config), seeds, steps, chunk, env_kwargs or {}])
            if weights.exists() and _trained_with(weights) != fingerprint:
                raise UserError(
                    f"{weights} was trained with other settings (seeds, --train-laps, the env's or the topology's); "
                    "give another --out"
                )
            lengths = [_test_length(name, test_steps) for name in TEST_TRACKS]
            tested = all(
                (out / "tests" / f"{_name(topology)}-{name}-{n}.npz").exists() for name, n in zip(TEST_TRACKS, lengths)
            )
            if not (weights.exists() and tested):
                bars = _Bars(topology, steps, len(ranges), progress)
                try:
                    _run_shares(
                        out, topology, ranges, steps, chunk, fingerprint, test_steps, env_kwargs, bars, executor
                    )
                finally:
                    bars.close()
                _merge_shares(out, topology, ranges, seeds, fingerprint, test_steps, env_kwargs)
            train_records[topology] = _load_npz(out / "training" / f"{_name(topology)}.npz")
            for name, length in zip(TEST_TRACKS, lengths):
                trace = _load_npz(out / "tests" / f"{_name(topology)}-{name}-{length}.npz")
                traces[topology, name] = trace = training.TestTrace(**{k: trace[k] for k in training.TestTrace._fields})
                rows += test_rows(topology, name, trace, env.dt, _windows(env))
            if progress:
                print(f"{topology}: {time.time() - t0:.0f} s")
    finally:
        if executor is not None:
            executor.shutdown(cancel_futures=True)
    if (out / "parts").exists() and not any((out / "parts").iterdir()):
        (out / "parts").rmdir()
    write_csv(out / "snake_rstdp.csv", [dict(zip(HEADER, r)) for r in rows], HEADER)
    _plot_training(out / "snake_rstdp_training.png", train_records, env.dt)
    _plot_weights(out / "snake_rstdp_weights.png", train_records, env.dt)
    _plot_tests(out / "snake_rstdp_test.png", traces, env.dt)
    hidden = {t: r for t, r in train_records.items() if t.partition("/")[0] in ("unified", "separated")}
    if hidden:
        write_csv(out / "snake_rstdp_hidden.csv", hidden_rows(hidden), HIDDEN_HEADER)
        _plot_hidden(out / "snake_rstdp_hidden.png", hidden, env.dt)
    _plot_trajectories(out / "snake_rstdp_trajectories.png", traces)
    return rows


HIDDEN_HEADER = [
    "topology",
    "seeds",
    "reward_ratio",
    "reward_ratio_ci_low",
    "reward_ratio_ci_high",
    "w_balance",
    "w_balance_ci_low",
    "w_balance_ci_high",
]


def hidden_rows(records) -> list[dict]:
    """Why a hidden layer learns or not, per topology, over seeds.

    ``reward_ratio``: the mean ``|r|`` the head neurons ``H_L, H_R`` got from
    Eq. (11) or (13) over the mean ``|r|`` of the body outputs they project to,
    over training (Eq. (11) divides the sum of two opposite rewards, so it
    tends to 0 as a hidden neuron's two weights equalise: the paper's guess for
    the unified net's failure); ``w_balance``: ``|w_R - w_L| / (w_R + w_L)`` of
    the ``H`` neurons' synapses onto the body outputs at the end (1 for the
    separated net, whose ``H`` have one synapse each).
    """
    rows = []
    for topology, r in records.items():
        r_h = np.abs(r["snapshot.r_hidden"][:, :, :2]).mean(axis=(1, 2))
        body = np.abs(r["mean.a_body"]).mean(1) * 1e-4  # |r| of the body pair, C_reward_body |a_body| (block means)
        ratio = r_h / np.maximum(body, 1e-12)
        w = r["snapshot.w_hidden"][:, -1, :2, :]  # (seeds, H, [B_L, B_R])
        balance = (np.abs(w[..., 1] - w[..., 0]) / np.maximum(w.sum(-1), 1e-9)).mean(1)
        m1, l1, h1 = mean_interval(ratio)
        m2, l2, h2 = mean_interval(balance)
        rows.append(
            dict(
                zip(
                    HIDDEN_HEADER,
                    [
                        topology,
                        len(ratio),
                        round(m1, 4),
                        round(l1, 4),
                        round(h1, 4),
                        round(m2, 4),
                        round(l2, 4),
                        round(h2, 4),
                    ],
                )
            )
        )
    return rows


def _plot_hidden(path: Path, records, dt):
    from matplotlib.figure import Figure

    fig = Figure(figsize=(12, 3.0 * len(records)), layout="constrained")
    for i, (topology, r) in enumerate(records.items()):
        t = (np.arange(r["snapshot.r_hidden"].shape[1]) + 1) * training.BLOCK * dt
        ax = fig.add_subplot(len(records), 2, 2 * i + 1)
        ax.plot(t, np.median(np.abs(r["snapshot.r_hidden"][:, :, :2]).mean(-1), 0), label="|r| of H (Eq. 11 / 13)")
        ax.plot(t, np.median(np.abs(r["mean.a_body"]) * 1e-4, 0), label="|r| of the body pair (Eq. 9)")
        ax.set_yscale("log")
        ax.set_title(f"{topology}: rewards over training (median over seeds)", fontsize=9)
        ax.legend(fontsize=7)
        ax = fig.add_subplot(len(records), 2, 2 * i + 2)
        w = r["snapshot.w_hidden"][:, :, :2, :]
        ax.plot(t, np.median(w[..., 1] - w[..., 0], 0), lw=0.8)
        ax.set_title(f"{topology}: w(H -> B_R) - w(H -> B_L) of H_L, H_R (median)", fontsize=9)
        ax.set_ylabel("pA")
    fig.axes[-1].set_xlabel("training time (s)")
    fig.savefig(path, dpi=110)


def _flatten(tree, prefix=""):
    flat = {}
    for k, v in tree.items():
        if isinstance(v, dict):
            flat.update(_flatten(v, f"{prefix}{k}."))
        else:
            flat[prefix + k] = np.asarray(v)
    return flat


def _plot_training(path: Path, records, dt):
    from matplotlib.figure import Figure

    fig = Figure(figsize=(12, 2.6 * len(records)), layout="constrained")
    for i, (topology, r) in enumerate(records.items()):
        t = (np.arange(r["mean.abs_head"].shape[1]) + 1) * training.BLOCK * dt
        ax = fig.add_subplot(len(records), 1, i + 1)
        for key, color, label in (("mean.a_head", "tab:green", "head"), ("mean.a_body", "tab:blue", "body")):
            deg = np.degrees(r[key])
            ax.plot(t, np.median(deg, 0), color=color, lw=0.8, label=f"{label} angle (median over seeds)")
            ax.fill_between(t, *np.percentile(deg, [10, 90], 0), color=color, alpha=0.2, lw=0)
        ax.set_ylabel("deg")
        twin = ax.twinx()
        twin.plot(t, np.median(r["mean.distance"], 0), color="tab:red", lw=0.8, label="distance (m)")
        fails = np.cumsum(r["failures"], 1).mean(0)
        twin.plot(t, fails / max(1.0, fails[-1]) * twin.get_ylim()[1], "k:", lw=0.8, label="failures (scaled)")
        ax.set_title(f"{topology}: training, {r['mean.abs_head'].shape[0]} seeds (10-90 % band)", fontsize=9)
        ax.legend(loc="upper left", fontsize=7)
        twin.legend(loc="upper right", fontsize=7)
    fig.axes[-1].set_xlabel("training time (s)")
    fig.savefig(path, dpi=110)


def _plot_weights(path: Path, records, dt):
    from matplotlib.figure import Figure

    fig = Figure(figsize=(12, 2.6 * len(records)), layout="constrained")
    for i, (topology, r) in enumerate(records.items()):
        hidden = topology.partition("/")[0] in ("unified", "separated")
        w = r["snapshot.w_hidden"] if hidden else r["snapshot.w_first"]
        t = (np.arange(w.shape[1]) + 1) * training.BLOCK * dt
        ax = fig.add_subplot(len(records), 1, i + 1)
        flat = w[0].reshape(w.shape[1], -1)
        ax.plot(t, flat, lw=0.6)
        ax.set_ylabel("weight (pA)")
        which = "hidden -> body" if hidden else "input -> output"
        ax.set_title(f"{topology}: {which} weights over training, seed 0", fontsize=9)
    fig.axes[-1].set_xlabel("training time (s)")
    fig.savefig(path, dpi=110)


def _plot_tests(path: Path, traces, dt):
    from matplotlib.figure import Figure

    topologies = list(dict.fromkeys(k[0] for k in traces))
    fig = Figure(figsize=(14, 2.4 * len(topologies)), layout="constrained")
    for i, topology in enumerate(topologies):
        for j, name in enumerate(TEST_TRACKS):
            tr = traces[topology, name]
            t = (np.arange(tr.a_head.shape[1]) + 1) * dt
            ax = fig.add_subplot(len(topologies), len(TEST_TRACKS), i * len(TEST_TRACKS) + j + 1)
            ax.plot(t, np.degrees(tr.a_head[0]), lw=0.4, color="tab:gray", label="Angle.Head")
            ax.plot(
                t,
                np.degrees(metrics.running_mean(tr.a_head[0], 125, tr.failed[0])),
                color="k",
                lw=0.8,
                label="running mean",
            )
            ax.set_ylim(-45, 45)
            twin = ax.twinx()
            twin.plot(t, tr.d_body[0], color="tab:blue", lw=0.6, label="Direction.Body")
            twin.plot(t, tr.d_head[0], color="tab:orange", lw=0.6, label="Direction.Head")
            twin.set_ylim(-1.1, 1.1)
            for f in np.nonzero(tr.failed[0])[0]:
                ax.axvline((f + 1) * dt, color="r", lw=0.6)
            ax.set_title(f"{topology}, {name}, seed 0", fontsize=8)
            if i == 0 and j == 0:
                ax.legend(fontsize=6, loc="lower left")
                twin.legend(fontsize=6, loc="lower right")
    fig.savefig(path, dpi=110)


def _plot_trajectories(path: Path, traces):
    from matplotlib.figure import Figure

    topologies = list(dict.fromkeys(k[0] for k in traces))
    fig = Figure(figsize=(14, 3.2 * len(topologies)), layout="constrained")
    for i, topology in enumerate(topologies):
        for j, name in enumerate(TEST_TRACKS):
            tr = traces[topology, name]
            ax = fig.add_subplot(len(topologies), len(TEST_TRACKS), i * len(TEST_TRACKS) + j + 1)
            ax.plot(tr.target_xy[0, :, 0], tr.target_xy[0, :, 1], "g-", lw=2, label="target")
            for s in range(min(8, tr.head_xy.shape[0])):
                ax.plot(tr.head_xy[s, :, 0], tr.head_xy[s, :, 1], lw=0.5, label="head (8 seeds)" if s == 0 else None)
            ax.set_aspect("equal", adjustable="datalim")
            ax.set_title(f"{topology}, {name}", fontsize=8)
            if i == 0 and j == 0:
                ax.legend(fontsize=6)
    fig.savefig(path, dpi=110)


def _topologies(text: str) -> tuple[str, ...]:
    names = tuple(t.strip() for t in text.split(",") if t.strip())
    bad = [
        t
        for t in names
        if t.partition("/")[0] not in rstdp.TOPOLOGIES or (t.partition("/")[2] and t.partition("/")[2] not in VARIANTS)
    ]
    if bad or not names:
        raise UserError(
            f"--topologies: unknown {', '.join(bad) or '(none)'}; choose from {', '.join(rstdp.TOPOLOGIES)}"
        )
    return names


def _add_reproduce_arguments(parser) -> None:
    add_common(parser)
    parser.add_argument("--seeds", type=count, default=64, help="seeds per topology (default 64)")
    parser.add_argument(
        "--train-laps",
        type=float,
        default=2.0,
        help="training length in passes of the 8 at the snake's speed (default 2)",
    )
    parser.add_argument(
        "--topologies",
        default=",".join(DEFAULT_TOPOLOGIES),
        help="comma-separated, default the four and separated/printed; TOPOLOGY/head (the hidden synapses keep the "
        "head reward), /printed (Eq. (13) as printed), /negative-left (the joint neurons' other grouping)",
    )
    parser.add_argument(
        "--test-steps", type=count, default=None, help="control steps per test track (default: one pass)"
    )
    parser.add_argument(
        "--head-compensation",
        default=training.COMPENSATION,
        help=f"what the head compensation reads: {', '.join(COMPENSATE_FROM)} (default {training.COMPENSATION}: "
        "the joint targets with the steering low-passed over --lag-tau)",
    )
    parser.add_argument(
        "--lag-tau",
        type=float,
        default=training.LAG_TAU,
        help=f"s, the low-pass of the steering that the lagged compensation reads (default {training.LAG_TAU})",
    )
    parser.add_argument(
        "--workers",
        type=count,
        default=None,
        help="processes, one a core, each training and testing a share of the seeds (default: one per core; "
        "the results do not depend on it)",
    )


def run_reproduce(
    *,
    out,
    seeds,
    train_laps,
    topologies,
    test_steps,
    no_progress,
    workers=None,
    head_compensation=training.COMPENSATION,
    lag_tau=training.LAG_TAU,
) -> int:
    """``spikejax reproduce snake-rstdp --out DIR``: `run`, and its table printed."""
    if not train_laps > 0:
        raise UserError(f"--train-laps must be positive, got {train_laps}")
    names = _topologies(topologies)
    env_kwargs = env_settings(head_compensation, lag_tau)
    with output_directory(out, command="reproduce snake-rstdp") as out:
        rows = run(
            out,
            seeds=seeds,
            train_laps=train_laps,
            topologies=names,
            test_steps=test_steps,
            progress=not no_progress,
            workers=workers,
            env_kwargs=env_kwargs,
        )
        _print(rows)
        print(f"wrote {out}/snake_rstdp.csv, weights/, training/, snake_rstdp_*.png")
    return 0


def _print(rows):
    print("topology    track           window  mean |MA a_head| deg [95% CI]   failures/min  seeds failed")
    for r in rows:
        print(
            f"{r[0]:<11} {r[1]:<15} {r[2]:>6}  {r[4]:7.2f} [{r[5]:.2f}, {r[6]:.2f}]        {r[9]:8.2f}      {r[12]:.2f}"
        )


def _add_evaluate_arguments(parser) -> None:
    add_common(parser)
    parser.add_argument(
        "--weights", required=True, help="a reproduce output directory (its weights/) or a weights .npz"
    )
    parser.add_argument(
        "--track", required=True, help=f"a track name ({', '.join(tracks.TRACKS)}) or a CSV of x, y waypoints"
    )
    parser.add_argument("--steps", type=count, default=None, help="control steps (default: one pass of the track)")


def run_evaluate(*, out, weights, track, steps, no_progress) -> int:
    """``spikejax evaluate snake-rstdp --weights DIR --track FILE --out DIR``: frozen networks on any track."""
    path = Path(weights)
    files = sorted((path / "weights").glob("*.npz")) if path.is_dir() else [path]
    if not files or not all(f.is_file() for f in files):
        raise UserError(f"--weights {weights}: no weights files found (expected DIR/weights/TOPOLOGY.npz or a .npz)")
    the_track, name = tracks.from_argument(track)
    env = training.env_for(the_track)
    with output_directory(out, command="evaluate snake-rstdp") as out:
        rows = []
        for f in files:
            topology, seeds, w1, w2 = load_weights(f)
            config = _config(topology)
            params = rstdp.network_params(config)
            nets = networks_with(config, params, seeds, w1, w2)
            trace = training.test(config, params, nets, the_track, steps, seeds=seeds, env_kwargs=trained_env(f))
            rows += test_rows(topology, name, trace, env.dt, _windows(env))
        write_csv(out / "snake_rstdp.csv", [dict(zip(HEADER, r)) for r in rows], HEADER)
        _print(rows)
        print(f"wrote {out}/snake_rstdp.csv")
    return 0


reproduce_command = Command(
    help="train the snake's four R-STDP networks over many seeds and test them (Sec. III-IV of the paper)",
    add_arguments=_add_reproduce_arguments,
    run=run_reproduce,
)
evaluate_command = Command(
    help="test saved snake R-STDP networks on any track (a name or a CSV of waypoints)",
    add_arguments=_add_evaluate_arguments,
    run=run_evaluate,
)


CHOICE_AXES = ("max_rate", "max_steer", "c_reward_scale")
CHOICE_METRICS = (
    "test_failures_per_min",
    "test_head_angle_deg",
    "test_abs_head_deg",
    "train_failures_per_min",
    "test_failed",
)


def choices_rows(table: dict) -> list[list]:
    """Per cell of the grid: the seeds' mean of each metric and a 95 % interval (Wilson for ``test_failed``)."""
    keys = np.stack([table[a] for a in CHOICE_AXES], axis=1)
    rows = []
    for cell in np.unique(keys, axis=0):
        sel = np.all(keys == cell, axis=1)
        row = [float(v) for v in cell] + [int(sel.sum())]
        for m in CHOICE_METRICS:
            x = np.asarray(table[m], float)[sel]
            if m == "test_failed":
                lo, hi = wilson_interval(int(x.sum()), int(sel.sum()))
                row += [round(float(x.mean()), 3), round(float(lo), 3), round(float(hi), 3)]
            else:
                mean, lo, hi = mean_interval(x)
                row += [round(mean, 3), round(lo, 3), round(hi, 3)]
        rows.append(row)
    return rows


def _plot_choices(path: Path, header, rows) -> None:
    from matplotlib.figure import Figure

    col = {h: i for i, h in enumerate(header)}
    rates = sorted({r[0] for r in rows})
    steers = sorted({r[1] for r in rows})
    scales = sorted({r[2] for r in rows})
    fig = Figure(figsize=(4.2 * len(rates), 6.5), layout="constrained")
    for j, (metric, label) in enumerate(
        (("test_failures_per_min", "test failures / min"), ("test_head_angle_deg", "test mean |MA a_head| (deg)"))
    ):
        for i, rate in enumerate(rates):
            ax = fig.add_subplot(2, len(rates), j * len(rates) + i + 1)
            grid = np.full((len(steers), len(scales)), np.nan)
            for r in rows:
                if r[0] == rate:
                    grid[steers.index(r[1]), scales.index(r[2])] = r[col[metric]]
            im = ax.imshow(grid, cmap="viridis_r", aspect="auto")
            for (a, b), v in np.ndenumerate(grid):
                ax.text(b, a, f"{v:.1f}", ha="center", va="center", color="w", fontsize=8)
            ax.set_xticks(range(len(scales)), [f"{v:g}" for v in scales])
            ax.set_yticks(range(len(steers)), [f"{v:g}" for v in steers])
            ax.set_xlabel("C_reward scale")
            ax.set_ylabel("max steer (rad)")
            cap = "no cap" if rate >= 1e8 else f"cap {rate:g} Hz"
            ax.set_title(f"{label}, {cap}", fontsize=8)
            fig.colorbar(im, ax=ax, shrink=0.8)
    fig.suptitle("Basic SNN trained 60 s on the 8, tested 60 s on the zigzag (mean over seeds)")
    fig.savefig(path, dpi=110)


def _add_choices_arguments(parser) -> None:
    add_common(parser, trials="seeds per cell (default: the sweep file's 8)", chunk_size=True)


def run_choices(*, out, trials, chunk_size, no_progress) -> int:
    """``spikejax reproduce snake-rstdp-choices --out DIR``: the sweep, its table and heat maps."""
    from robots.common import run_named_sweep

    with output_directory(out, command="reproduce snake-rstdp-choices") as out:
        table = run_named_sweep(
            "snake_rstdp_choices", out, trials=trials, chunk_size=chunk_size, progress=not no_progress
        )
        header = (
            list(CHOICE_AXES) + ["seeds"] + [f"{m}{s}" for m in CHOICE_METRICS for s in ("", "_ci_low", "_ci_high")]
        )
        rows = choices_rows(table)
        write_csv(out / "snake_rstdp_choices.csv", [dict(zip(header, r)) for r in rows], header)
        _plot_choices(out / "snake_rstdp_choices.png", header, rows)
        print("max_rate  max_steer  C_reward x  seeds  test failures/min  test |MA a_head| deg")
        for r in rows:
            print(f"{r[0]:8.3g}  {r[1]:9.3g}  {r[2]:10.3g}  {r[3]:5d}  {r[4]:17.2f}  {r[7]:19.2f}")
        print(f"wrote {out}/snake_rstdp_choices.csv, snake_rstdp_choices.png")
    return 0


choices_command = Command(
    help="the unstated choices of the snake R-STDP paper (rate cap, steering range, C_reward) over a grid of seeds",
    add_arguments=_add_choices_arguments,
    run=run_choices,
)
