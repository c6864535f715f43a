"""The snake's NEST peer (`robots.snake.peers`) against `robots.snake.rstdp`, and the R-STDP bench's arithmetic."""

import csv
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from robots.snake.rstdp import N_HIDDEN, NetworkConfig, network_init, network_params, network_run
from spikejax import coding

nest = pytest.importorskip("nest")

from robots.snake.peers import NestNetwork  # noqa: E402

PLASTIC = {"basic": (20, 0), "basic-head": (40, 0), "unified": (20, 16), "separated": (20, 8)}


def _weights(config, seed=0):
    rng = np.random.default_rng(seed)
    w1 = rng.uniform(100.0, 300.0, (10, config.n_first))
    w2 = np.where(config.hidden_mask, rng.uniform(100.0, 300.0, (N_HIDDEN, 2)), 0.0)
    return w1, w2


def _jax_counts(config, params, w1, w2, rates, r_first, r_body, steps, seed):
    """``steps`` control steps of `network_run` at fixed rates and rewards; counts per step and final weights."""
    state = network_init(config, params, key=jax.random.PRNGKey(seed))
    state = state._replace(w_first=jnp.asarray(w1, jnp.float32), w_hidden=jnp.asarray(w2, jnp.float32))
    rates = jnp.asarray(rates, jnp.float32)
    r_first, r_body = jnp.asarray(r_first, jnp.float32), jnp.asarray(r_body, jnp.float32)

    @jax.jit
    def go(state, key):
        def body(s, k):
            gen = coding.poisson_counts(jnp.broadcast_to(rates, (config.substeps, 16)), 0.001 * config.dt, key=k)
            return network_run(config, params, s, gen, r_first, r_body)

        return jax.lax.scan(body, state, jax.random.split(key, steps))

    state, counts = go(state, jax.random.PRNGKey(seed + 100))
    return np.asarray(counts), np.asarray(state.w_first), np.asarray(state.w_hidden)


def _nest_counts(config, params, w1, w2, rates, r_first, r_body, steps, seed):
    net = NestNetwork(config, params, w1, w2, seed=seed)
    counts = np.array([net.step(rates, r_first, r_body) for _ in range(steps)])
    w_first, w_hidden = net.weights()
    return counts, w_first, w_hidden


@pytest.mark.parametrize("topology", list(PLASTIC))
def test_structure_and_weights_as_the_jax_config(topology):
    config = NetworkConfig(topology=topology)
    w1, w2 = _weights(config)
    net = NestNetwork(config, network_params(config), w1, w2)
    first, hidden = PLASTIC[topology]
    assert len(net.connections("first")) == first
    assert len(net.connections("hidden")) == hidden if config.hidden else "hidden" not in net.models
    got1, got2 = net.weights()
    np.testing.assert_allclose(got1, w1)
    np.testing.assert_allclose(got2, w2 if config.hidden else 0.0)
    if config.hidden:  # the masks: exactly the synapses of hidden_mask exist
        np.testing.assert_array_equal(got2 != 0, config.hidden_mask)
    # every connection is plastic with the group's own parameters, 1 ms delay
    p = network_params(config)
    np.testing.assert_allclose(net.connections("first").get("delay"), 1.0)
    first_model = nest.GetDefaults(net.models["first"])  # common properties live on the copied model
    for key in ("tau_c", "A_plus", "A_minus", "tau_n", "Wmax"):
        assert first_model[key] == pytest.approx(float(getattr(p.first, key)))
    if config.hidden:
        assert float(p.first.tau_c) == 5 * float(p.second.tau_c)
        assert nest.GetDefaults(net.models["hidden"])["tau_c"] == pytest.approx(float(p.second.tau_c))


@pytest.mark.parametrize("topology", ["basic", "unified"])
def test_mean_counts_agree_with_jax_without_reward(topology):
    """Same rates, zero rewards (weights frozen): both are iaf_psc_alpha behind parrots, only the Poisson draws differ."""
    config = NetworkConfig(topology=topology)
    params = network_params(config)
    w1 = np.full((10, config.n_first), 200.0)
    w2 = np.where(config.hidden_mask, 200.0, 0.0)
    rates = np.full(16, 100.0)
    zero_first, zero_body = np.zeros(config.n_first), np.zeros(2)
    steps = 300
    jc, jw, _ = _jax_counts(config, params, w1, w2, rates, zero_first, zero_body, steps, 0)
    nc, nw, _ = _nest_counts(config, params, w1, w2, rates, zero_first, zero_body, steps, 1)
    np.testing.assert_allclose(jw, w1, rtol=1e-6)
    np.testing.assert_allclose(nw, w1)
    assert jc.mean() > 1.0  # the outputs fire (about 150 Hz here)
    np.testing.assert_allclose(nc.mean(0), jc.mean(0), rtol=0.05)


def test_reward_potentiates_and_punishment_depresses_in_both():
    """Input only in the right cells; reward on the right neuron, punishment on the left: both learn the same way."""
    config = NetworkConfig(topology="basic")
    params = network_params(config)
    w1 = np.full((10, 2), 200.0)
    rates = np.zeros(16)
    active = [3, 4, 8, 9]  # the two right columns of the 2 x 5 grid
    rates[active] = 150.0
    r = np.array([-0.2, 0.2])
    for counts, w, _ in (
        _jax_counts(config, params, w1, np.zeros((8, 2)), rates, r, np.zeros(2), 20, 0),
        _nest_counts(config, params, w1, np.zeros((8, 2)), rates, r, np.zeros(2), 20, 1),
    ):
        dw = w - w1
        silent = np.setdiff1d(np.arange(10), active)
        np.testing.assert_allclose(dw[silent], 0.0, atol=1e-3)
        assert dw[active, 1].sum() > 100.0
        assert dw[active, 0].sum() < -100.0
        assert counts[-5:, 1].sum() > counts[-5:, 0].sum()


@pytest.mark.slow
def test_bench_smoke_rows_and_ratios(tmp_path):
    """The bench's run at batch 1, 2 steps: the share and the ratios come from the timings it wrote."""
    from robots.snake import bench_rstdp

    rows = bench_rstdp.measure(batches="1", steps=2, repeats=1, no_progress=True, processes=False)
    bench_rstdp.report(rows, tmp_path)
    ours = [r for r in rows if r["impl"] == bench_rstdp.OURS]
    env = {(r["batch"], r["cores"]): r for r in rows if r["impl"] == bench_rstdp.ENV_ONLY}
    peer = {r["cores"]: r for r in rows if r["impl"] == bench_rstdp.PEER}
    assert ours and peer
    for r in ours:
        e = env[r["batch"], r["cores"]]
        assert 0.0 < r["network_share"] < 1.0
        assert math.isclose(r["network_share"], 1.0 - e["run_s"] / r["run_s"], rel_tol=1e-9)
        assert math.isclose(r["vs_nest"], r["steps_per_s"] / peer[r["cores"]]["steps_per_s"], rel_tol=1e-9)
    with open(tmp_path / "snake_rstdp.csv") as f:
        table = list(csv.DictReader(f))
    assert {"vs_nest", "network_share", "steps_per_s", "compile_s"} <= set(table[0])
    assert len(table) == len(rows)
    assert (tmp_path / "snake_rstdp.png").stat().st_size > 0
