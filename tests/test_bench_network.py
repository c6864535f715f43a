"""The delta-synapse RoboBee network of ``spikejax bench robobee-network``: spikejax against NumPy, Brian2 and NEST.

Spike for spike. Nothing here is timed; the benchmark itself is `robots.robobee.bench_network.run`.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from robots.robobee import bench_network, delta_network, peers
from robots.robobee import reference as numpy_reference

SEED = 0
DURATION = 0.05  # s, 500 steps
N_NETWORKS = 32
# spikejax runs in float32, the reference in float64: their potentials drift
# apart by up to about 6e-6 (mostly the float32 rounding of exp(-dt / tau),
# accumulated over an interspike interval). A network whose float64 run never
# comes closer than this to a threshold at a threshold test cannot have a test
# decided differently, so its spikes must be the same, neuron for neuron.
WELL_CONDITIONED = 1e-5
# Any other network may differ where a test was that close to a tie.
SPIKES_SLACK = 2
# The brief's agreement of firing rates between simulators.
RATE_TOLERANCE = 0.2


@functools.cache
def reference(network: int) -> dict:
    """The float64 NumPy loop, one network."""
    return numpy_reference.run_numpy(DURATION, SEED, network=network)


def spikejax_counts(n_networks: int, *, synapses: str = "dense", weight_dtype=jnp.bfloat16, **kw) -> np.ndarray:
    """Spikes per network and neuron of ``n_networks`` networks as ``jit(vmap(simulate))``, as the bench runs them."""
    params = delta_network.delta_network_params(delta_network.make_network(SEED), synapses, weight_dtype)
    currents = jnp.asarray(delta_network.input_currents(SEED, n_networks), jnp.float32)
    one = functools.partial(delta_network.simulate, n_steps=delta_network.n_steps_of(DURATION), **kw)
    return np.asarray(jax.jit(jax.vmap(one, in_axes=(None, 0)))(params, currents))


def well_conditioned(networks) -> list[int]:
    return [b for b in networks if reference(b)["margin"] > WELL_CONDITIONED]


def test_inputs_do_not_depend_on_the_batch_size():
    np.testing.assert_array_equal(delta_network.input_currents(SEED, 3), delta_network.input_currents(SEED, 7)[:3])


def test_network_has_the_papers_structure():
    spec = delta_network.make_network(SEED)
    assert spec.w_ih.shape == (200, 100) and spec.w_ho.shape == (100, 50)
    for conn, w in ((spec.conn_ih, spec.w_ih), (spec.conn_ho, spec.w_ho)):
        assert abs(conn.mean() - delta_network.P_CONNECT) < 0.02
        assert np.all(w[~conn] == 0) and np.all(w[conn] >= 0)
    assert np.all((spec.v_th >= 0.7) & (spec.v_th <= 1.7))
    # The weights are bfloat16 numbers and the thresholds float32 numbers, so
    # every implementation reads the same values.
    np.testing.assert_array_equal(spec.w_ih.astype(jnp.bfloat16).astype(np.float64), spec.w_ih)
    np.testing.assert_array_equal(spec.v_th.astype(np.float32).astype(np.float64), spec.v_th)


def test_reference_rates_are_moderate():
    rates = delta_network.rates_hz(reference(0))
    assert 50 < rates["input"] < 250
    assert 10 < rates["hidden"] < 100
    assert 10 < rates["output"] < 100


def test_spike_is_delivered_in_the_next_step_and_ignored_when_refractory():
    params = delta_network.delta_network_params(delta_network.make_network(SEED), weight_dtype=jnp.float32)
    state = delta_network.delta_network_init(params)
    hidden = state.layers[1]
    held = jnp.zeros(100).at[:50].set(3.0)  # the first half of the hidden layer is refractory
    state = state._replace(
        spikes_in=jnp.zeros(200).at[0].set(1.0),
        layers=(state.layers[0], hidden._replace(refractory=held), state.layers[2]),
    )
    state, fired = delta_network.delta_network_step(params, state, jnp.zeros(200))
    w = np.asarray(params.w_ih[0])
    v = np.asarray(state.layers[1].v)
    # Free neurons: the jump w, undecayed (added after the leak); held ones stay at reset.
    np.testing.assert_allclose(v[50:], w[50:], rtol=1e-6, atol=1e-9)
    np.testing.assert_array_equal(v[:50], 0.0)
    assert w[50:].max() > 0
    # This step's input spikes wait for the next one: the output layer got nothing.
    np.testing.assert_array_equal(np.asarray(state.layers[2].v), 0.0)
    assert not any(np.asarray(f).any() for f in fired[1:])


@pytest.mark.parametrize(
    "kw",
    [
        dict(),
        dict(weight_dtype=jnp.float32),
        dict(step="fused"),
        dict(synapses="fanin", weight_dtype=jnp.float32),
        dict(unroll=4),
    ],
    ids=["layers-dense-bf16", "layers-dense-f32", "fused", "fanin", "unroll4"],
)
def test_spikejax_equals_numpy_reference(kw):
    counts = spikejax_counts(N_NETWORKS, **kw)
    assert counts.shape == (N_NETWORKS, delta_network.N_NEURONS)
    checked = well_conditioned(range(N_NETWORKS))
    assert len(checked) >= 4
    for b in checked:
        np.testing.assert_array_equal(counts[b], reference(b)["counts"], err_msg=f"network {b}")
    for b in range(N_NETWORKS):
        for sl in delta_network.LAYER_SLICES:
            assert abs(int(counts[b, sl].sum()) - int(reference(b)["counts"][sl].sum())) <= SPIKES_SLACK


def test_spikejax_does_not_depend_on_the_batch_size():
    small = spikejax_counts(4)
    large = spikejax_counts(N_NETWORKS)
    np.testing.assert_array_equal(small, large[:4])


def test_benchmark_runs_the_same_networks():
    """The benchmark's spikejax row, on one device and split over the devices JAX presents, counts the same spikes."""
    expected = spikejax_counts(4)
    for devices in sorted({1, jax.device_count()}):
        row = bench_network.run_spikejax(4, DURATION, SEED, devices=devices)
        np.testing.assert_array_equal(row["counts"], expected)
        assert (row["cores"], row["batch"]) == (devices, 4)


def test_spikejax_step_is_the_same_under_jit_and_eagerly():
    params = delta_network.delta_network_params(delta_network.make_network(SEED))
    current = jnp.asarray(delta_network.input_currents(SEED, 1)[0], jnp.float32)
    step = functools.partial(delta_network.delta_network_step, params)
    state_eager = state_jit = delta_network.delta_network_init(params)
    jitted = jax.jit(step)
    for _ in range(60):  # input spikes start after about 25 steps and reach the hidden layer
        state_eager, _ = step(state_eager, current)
        state_jit, _ = jitted(state_jit, current)
    for a, b in zip(jax.tree.leaves(state_eager), jax.tree.leaves(state_jit)):
        np.testing.assert_allclose(np.asarray(a, np.float64), np.asarray(b, np.float64), rtol=1e-6, atol=1e-7)
    assert int(sum(c.sum() for c in state_eager.counts[:2])) > 0


def _assert_same_network_activity(row: dict, ref: dict):
    """Rates within the brief's 20 % per layer, and here, with the same conventions, equal counts."""
    for layer, rate in delta_network.rates_hz(row).items():
        ref_rate = delta_network.rates_hz(ref)[layer]
        assert abs(rate - ref_rate) <= RATE_TOLERANCE * ref_rate, (layer, rate, ref_rate)
    np.testing.assert_array_equal(row["counts"], ref["counts"])


def test_brian2_runtime_equals_numpy_reference():
    pytest.importorskip("brian2")
    row = peers.run_brian2_runtime(DURATION, SEED, target="numpy")
    assert row["repeat_equal"]
    _assert_same_network_activity(row, reference(0))


def test_nest_equals_numpy_reference():
    pytest.importorskip("nest")
    _assert_same_network_activity(peers.run_nest(DURATION, SEED), reference(0))


@pytest.mark.slow
def test_main_network_writes_the_table(tmp_path):
    """All implementations in one table (Brian2 standalone compiles C++: about 20 s)."""
    pytest.importorskip("brian2")
    assert (
        bench_network.run(duration=0.01, seed=SEED, batches=[1, 2], repeats=1, out=str(tmp_path), no_progress=True) == 0
    )
    text = (tmp_path / "bench_robobee_network.csv").read_text().splitlines()
    header, lines = text[0].split(","), [line.split(",") for line in text[1:]]
    assert header[: len(delta_network.ROW_FIELDS)] == list(delta_network.ROW_FIELDS)
    one_network = [line for line in lines if line[1] == "1"]
    assert any(line[0].startswith("Brian2 C++ standalone") for line in one_network)
    spikes = {tuple(line[7:10]) for line in one_network}
    assert len(spikes) == 1, spikes  # every implementation, the same spikes per layer
