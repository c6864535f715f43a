"""The snake's R-STDP networks: topologies, rewards (Eq. (9)-(13)), the spike path through the layers, decoding."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from robots.snake import rstdp
from spikejax.errors import UserError
from spikejax.neurons import iaf_psc_alpha_init, iaf_psc_alpha_step
from spikejax.plasticity.reward import backprop_rewards, separated_rewards, unified_rewards


def _net(topology, **config):
    config = rstdp.NetworkConfig(topology=topology, **config)
    params = rstdp.network_params(config)
    return config, params, rstdp.network_init(config, params, key=jax.random.PRNGKey(0))


def test_topologies_have_the_papers_synapses():
    plastic = {}
    for topology in rstdp.TOPOLOGIES:
        config, _, state = _net(topology)
        n = state.w_first.size + (int(config.hidden_mask.sum()) if config.hidden else 0)
        plastic[topology] = n
    # Sec. II-B, III-B, Fig. 3, Fig. 4: 10x2; 10x4; 10x2 + 8x2; 10x2 + 8 (one per hidden neuron)
    assert plastic == {"basic": 20, "basic-head": 40, "unified": 36, "separated": 28}
    config, _, state = _net("separated")
    mask = config.hidden_mask
    assert mask.sum(0).tolist() == [4, 4] and mask.sum(1).tolist() == [1] * 8
    assert mask[0, 0] and mask[1, 1]  # H_L joins the left group, H_R the right one
    assert mask[2::2, 0].all() and mask[3::2, 1].all()  # f_P of joints 1, 3, 5 go left by default
    flipped = rstdp.NetworkConfig(topology="separated", joints_left="negative").hidden_mask
    assert flipped[3::2, 0].all() and flipped[2::2, 1].all()
    assert (np.asarray(state.w_hidden)[~mask] == 0).all()
    w = np.asarray(state.w_first)
    assert (w >= 200).all() and (w < 201).all()  # U18: U(200, 201) pA


def test_bad_configs_get_one_line_errors():
    for kwargs, words in (
        ({"topology": "deep"}, "topology"),
        ({"hidden_reward": "x"}, "hidden_reward"),
        ({"rows": 3}, "10 cells"),
        ({"substeps": 0}, "substeps"),
    ):
        with pytest.raises(UserError, match=words) as e:
            rstdp.NetworkConfig(**kwargs)
        assert "\n" not in str(e.value)


def test_rewards_by_hand():
    a_head, a_body = 10.0, -4.0  # any unit: Eq. (9) scales them
    config, params, state = _net("basic")
    first, _, _ = rstdp.network_rewards(config, params, state, a_head, a_body)
    np.testing.assert_allclose(first, [-10.0 * 1e-4, 10.0 * 1e-4], rtol=1e-6)  # Eq. (9), body constants (U22)

    config, params, state = _net("basic-head")
    first, body, _ = rstdp.network_rewards(config, params, state, a_head, a_body)
    np.testing.assert_allclose(first, [-4e-3, 4e-3, 4e-4, -4e-4], rtol=1e-6)  # head pair 0.0004, body pair 0.0001
    np.testing.assert_allclose(body, [4e-4, -4e-4], rtol=1e-6)

    config, params, state = _net("unified")
    w = jnp.asarray(np.linspace(100.0, 900.0, 16).reshape(8, 2), jnp.float32)
    state = state._replace(w_hidden=w)
    first, body, hidden = rstdp.network_rewards(config, params, state, a_head, a_body)
    np.testing.assert_allclose(hidden, unified_rewards(body, w), rtol=1e-6)  # Eq. (11)
    by_hand = (body[0] * w[:, 0] + body[1] * w[:, 1]) / (2 * jnp.maximum(w[:, 0], w[:, 1]))
    np.testing.assert_allclose(hidden, by_hand, rtol=1e-5)
    np.testing.assert_allclose(first, hidden[:2], rtol=0)  # reading A: H learns from the back-propagated reward
    head_config = rstdp.NetworkConfig(topology="unified", hidden_reward="head")
    first_b, _, _ = rstdp.network_rewards(head_config, params, state, a_head, a_body)
    np.testing.assert_allclose(first_b, [-4e-3, 4e-3], rtol=1e-6)  # reading B

    config, params, state = _net("separated")
    first, body, hidden = rstdp.network_rewards(config, params, state, a_head, a_body)
    side = config.hidden_side
    np.testing.assert_allclose(hidden, np.asarray(body)[side], rtol=1e-6)  # Eq. (13) = Eq. (10): r of its output
    np.testing.assert_allclose(hidden, backprop_rewards(body, state.w_hidden, config.hidden_mask), rtol=0)
    printed = rstdp.NetworkConfig(topology="separated", eq13_sign="printed")
    _, _, hidden_p = rstdp.network_rewards(printed, params, state, a_head, a_body)
    w = jnp.sum(state.w_hidden, axis=1)
    np.testing.assert_allclose(hidden_p, separated_rewards(body, w, jnp.asarray(side), sign="printed"), rtol=0)
    assert np.allclose(hidden_p, body[1])  # the printed minus rewards both groups as the right output


def test_one_input_spike_travels_two_delays_and_moves_the_output_as_a_lone_lif():
    """Generator -> parrot (1 ms) -> LIF (1 ms): the LIF sees what a lone iaf_psc_alpha driven at step k + 2D sees."""
    config, params, state = _net("basic", learn=False)
    w = 900.0
    state = state._replace(w_first=jnp.zeros((10, 2)).at[3, 1].set(w))
    steps = 5 + 2 * config.delay + 8  # end while the PSP still rises steeply
    generated = jnp.zeros((steps, 16), jnp.int32).at[5, 3].set(2)  # two spikes in cell 3 at step 5
    out, counts = rstdp.network_run(config, params, state, generated, jnp.zeros(2), jnp.zeros(2))

    def lone(arrive):
        s = iaf_psc_alpha_init(2, params.neuron)
        for k in range(steps):
            ex = jnp.zeros(2).at[1].set(2 * w if k == arrive else 0.0)
            s, _ = iaf_psc_alpha_step(params.neuron, s, ex, jnp.zeros(2), config.dt)
        return np.asarray(s.V_m)

    v = np.asarray(out.neurons.V_m)
    np.testing.assert_allclose(v, lone(5 + 2 * config.delay), rtol=0, atol=1e-4)
    for late in (4 + 2 * config.delay, 6 + 2 * config.delay):  # one step either way is far off
        assert abs(v[1] - lone(late)[1]) > 1e-2
    assert v[1] > -70.0 + 0.5 and v[0] == -70.0
    np.testing.assert_array_equal(out.w_first, state.w_first)  # frozen


def test_zero_weights_never_fire_and_strong_input_does():
    config, params, state = _net("basic")
    generated = jax.random.poisson(jax.random.PRNGKey(1), 0.2, (config.substeps, 16)).astype(jnp.int32)
    silent, counts = rstdp.network_run(
        config, params, state._replace(w_first=jnp.zeros((10, 2))), generated, jnp.ones(2), jnp.ones(2)
    )
    assert counts.tolist() == [0, 0]
    np.testing.assert_array_equal(silent.w_first, 0.0)  # no post spike: the eligibility can only fall, w sits at Wmin
    _, counts = rstdp.network_run(config, params, state, generated, jnp.zeros(2), jnp.zeros(2))
    assert (np.asarray(counts) > 0).all()


def test_reward_on_the_right_potentiates_the_right_inputs_onto_the_right_neuron():
    """Eq. (6)-(9) in the network: right-side input, target on the right -> w(right cells -> O_R) grows."""
    from spikejax import coding

    config, params, state = _net("basic")
    rates = jnp.asarray([0, 0, 0, 300, 300] * 2 + [0] * 6, jnp.float32)
    run = jax.jit(lambda s, g, r: rstdp.network_run(config, params, s, g, r, r))
    key = jax.random.PRNGKey(2)
    w0 = np.asarray(state.w_first)
    for _ in range(25):
        key, sub = jax.random.split(key)
        generated = coding.poisson_counts(jnp.broadcast_to(rates, (config.substeps, 16)), 1e-4, key=sub)
        state, _ = run(state, generated, jnp.asarray(rstdp.network_rewards(config, params, state, 0.35, 0.35)[0]))
    dw = np.asarray(state.w_first) - w0
    right = [3, 4, 8, 9]
    assert (dw[right, 1] > 0).all() and (dw[right, 0] < 0).all()
    np.testing.assert_allclose(dw[[0, 1, 2, 5, 6, 7]], 0.0, atol=1e-3)  # silent inputs: no pre spikes, no pairs


def test_decode_eq4_eq5_per_pair():
    config, params, state = _net("basic-head")
    out = rstdp.network_decode(config, params, state, jnp.asarray([1, 3, 6, 2]))
    assert float(out.d_head) == pytest.approx(0.02 * (3 - 1) / 4)
    assert float(out.d_body) == pytest.approx(0.07 * (2 - 6) / 8)
    config, params, state = _net("basic")
    out = rstdp.network_decode(config, params, state._replace(d_body=jnp.float32(0.99)), jnp.asarray([0, 5]))
    assert float(out.d_body) == 1.0 and float(out.d_head) == 0.0  # clipped; no head controller
