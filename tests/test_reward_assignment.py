"""Reward assignment of the snake R-STDP paper: Eq. 9, Eq. 10 by hand, Eq. 11 and 13 as its cases, safety, vmap."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from spikejax.errors import UserError
from spikejax.plasticity.reward import backprop_rewards, pair_rewards, separated_rewards, unified_rewards


def test_pair_rewards_eq9():
    assert pair_rewards(10.0, 0.5).tolist() == [-5.0, 5.0]
    r_l, r_r = pair_rewards(-4.0, 0.25).tolist()
    assert r_l == 1.0 and r_r == -1.0  # target on the left: the left neuron is rewarded
    r = jax.jit(jax.vmap(pair_rewards, in_axes=(0, None)))(jnp.array([1.0, -2.0, 0.0]), 1e-4)
    np.testing.assert_allclose(r, [[-1e-4, 1e-4], [2e-4, -2e-4], [0.0, 0.0]], rtol=1e-6)


def test_eq10_three_layers_by_hand():
    # Output rewards (left, right) from Eq. 9.
    r_out = pair_rewards(20.0, 0.1)  # [-2, 2]
    # Hidden layer 2 (3 neurons) -> output, all-to-all.
    w2 = jnp.array([[1.0, 3.0], [2.0, -2.0], [0.0, 0.0]])
    r2 = backprop_rewards(r_out, w2)
    # n0: (-2*1 + 2*3) / (3 * 2) = 2/3; n1: (-2*2 + 2*-2) / (2 * 2) = -2; n2: all weights 0 -> 0.
    np.testing.assert_allclose(r2, [2 / 3, -2.0, 0.0], rtol=1e-6)
    # Hidden layer 1 (2 neurons) -> hidden layer 2; neuron 1 has no synapse to neuron 1 of layer 2.
    w1 = jnp.array([[1.0, 1.0, 1.0], [4.0, 100.0, -2.0]])
    mask = jnp.array([[True, True, True], [True, False, True]])
    r1 = backprop_rewards(r2, w1, mask)
    # n0: (2/3 - 2 + 0) / (1 * 3) = -4/9; n1 (Y = 2, max |w| = 4, the 100 does not exist):
    # (2/3 * 4 + 0 * -2) / (4 * 2) = 1/3.
    np.testing.assert_allclose(r1, [-4 / 9, 1 / 3], rtol=1e-6)
    # |r_j| <= max_k |r_k| (a normalised vote).
    assert np.all(np.abs(r1) <= np.abs(r2).max() + 1e-7)


def _random_case(seed, n=64, y=2):
    rng = np.random.default_rng(seed)
    w = rng.normal(0.0, 100.0, (n, y)).astype(np.float32)
    w[rng.uniform(size=(n, y)) < 0.1] = 0.0
    w[0] = 0.0
    r = rng.normal(0.0, 1.0, y).astype(np.float32)
    return jnp.asarray(r), jnp.asarray(w)


def test_eq11_is_eq10_with_both_columns():
    r_out, w = _random_case(1)
    r_h = unified_rewards(r_out, w)
    np.testing.assert_array_equal(r_h, backprop_rewards(r_out, w, jnp.ones(w.shape, bool)))
    np.testing.assert_array_equal(r_h, backprop_rewards(r_out, w))
    # The printed formula of Eq. 11, in float64.
    r_l, r_r = np.asarray(r_out, np.float64)
    w_l, w_r = np.asarray(w, np.float64).T
    m = np.maximum(np.abs(w_l), np.abs(w_r))
    printed = np.divide(r_l * w_l + r_r * w_r, m * 2, out=np.zeros_like(m), where=m > 0)
    np.testing.assert_allclose(r_h, printed, rtol=1e-6, atol=1e-7)
    # With Eq. 9 (r_l = -r_r): r_h = r_r (w_r - w_l) / (2 max |w|); equal weights cancel.
    r_h = unified_rewards(pair_rewards(3.0, 1.0), jnp.array([[5.0, 5.0], [1.0, 3.0]]))
    assert r_h.tolist() == [0.0, 1.0]


def test_eq13_is_eq10_with_one_synapse_each():
    r_out, w2 = _random_case(2)
    rng = np.random.default_rng(3)
    side = jnp.asarray(rng.integers(0, 2, w2.shape[0]))
    w = w2[:, 0]
    one_hot = jax.nn.one_hot(side, 2, dtype=bool)
    # The other column holds junk that must not count.
    w_full = jnp.where(one_hot, w[:, None], w2[:, 1:] * 1e3)
    r_h = separated_rewards(r_out, w, side)
    np.testing.assert_array_equal(r_h, backprop_rewards(r_out, w_full, one_hot))
    np.testing.assert_array_equal(
        jax.jit(separated_rewards)(r_out, w, side), jax.jit(backprop_rewards)(r_out, w_full, one_hot)
    )
    np.testing.assert_array_equal(r_h, np.asarray(r_out)[np.asarray(side)] * np.sign(np.asarray(w)))
    assert np.all(np.asarray(r_h)[np.asarray(w) == 0] == 0)


def test_printed_sign_rewards_both_groups_alike():
    r_out = pair_rewards(5.0, 0.2)  # target on the right: r_l = -1, r_r = 1
    w = jnp.array([0.5, 2.0, 300.0, 1.0, 7.0, 0.1])  # positive (excitatory) weights
    side = jnp.array([0, 0, 0, 1, 1, 1])  # three left, three right
    eq10 = separated_rewards(r_out, w, side)
    printed = separated_rewards(r_out, w, side, sign="printed")
    assert eq10.tolist() == [-1.0, -1.0, -1.0, 1.0, 1.0, 1.0]  # the left group punished, the right rewarded
    assert printed.tolist() == [1.0] * 6  # the left group rewarded for a target on the right too
    np.testing.assert_array_equal(printed[3:], eq10[3:])
    np.testing.assert_array_equal(printed[:3], -eq10[:3])
    # The printed sign agrees with Eq. 10 when the left group's weights are negative.
    w_neg = jnp.where(side == 0, -w, w)
    np.testing.assert_array_equal(separated_rewards(r_out, w_neg, side, sign="printed"), eq10)


def test_zero_weights_and_missing_synapses_give_zero_without_nan():
    r = jnp.array([1.0, -3.0])
    w = jnp.array([[0.0, 0.0], [2.0, 1.0], [5.0, 0.0], [1e-30, -1e-30]])
    mask = jnp.array([[True, True], [False, False], [True, True], [True, True]])
    f = jax.jit(backprop_rewards)
    out = f(r, w, mask)
    assert np.all(np.isfinite(out))
    assert out[0] == 0.0 and out[1] == 0.0
    assert float(out[2]) == pytest.approx(0.5)  # (1 * 5 + 0) / (5 * 2)
    assert float(out[3]) == pytest.approx(2.0)  # tiny weights: (1 + 3) / 2, no underflow
    # Gradients stay finite at zero weights and missing synapses (not at weights whose square underflows).
    grads = jax.grad(lambda r, w: jnp.sum(backprop_rewards(r, w[:3], mask[:3])), argnums=(0, 1))(r, w)
    assert all(np.all(np.isfinite(g)) for g in grads)
    np.testing.assert_allclose(grads[1][2], [0.0, -0.3], rtol=1e-6)  # d/dw of (w_0 - 3 w_1) / (2 max |w|) at (5, 0)
    sep = jax.jit(separated_rewards, static_argnames="sign")(r, jnp.array([0.0, -2.0]), jnp.array([0, 1]))
    assert sep.tolist() == [0.0, 3.0]


def test_mask_hides_weights():
    r, w = _random_case(4, n=16, y=3)
    rng = np.random.default_rng(5)
    mask = jnp.asarray(rng.uniform(size=w.shape) < 0.6)
    base = backprop_rewards(r, w, mask)
    changed = jnp.where(mask, w, 1e6)  # huge weights where no synapse exists change nothing
    np.testing.assert_array_equal(backprop_rewards(r, changed, mask), base)
    # Removing a neuron's synapse changes Y_j and the max: by hand for row 0.
    for j in range(1, 16):
        w_j, m_j = np.asarray(w[j], np.float64)[np.asarray(mask[j])], np.asarray(r, np.float64)[np.asarray(mask[j])]
        largest = np.abs(w_j).max(initial=0.0)
        expected = (m_j * w_j).sum() / (largest * len(w_j)) if largest > 0 else 0.0
        assert float(base[j]) == pytest.approx(expected, rel=1e-5, abs=1e-7)


def test_jit_vmap_over_networks():
    cases = [_random_case(10 + i, n=8, y=3) for i in range(5)]
    r = jnp.stack([c[0] for c in cases])
    w = jnp.stack([c[1] for c in cases])
    batched = jax.jit(jax.vmap(backprop_rewards))(r, w)
    for i in range(5):
        np.testing.assert_allclose(batched[i], backprop_rewards(r[i], w[i]), rtol=1e-6, atol=1e-7)
    sides = jnp.array([[0, 1, 0, 1, 0, 1, 0, 1], [1, 1, 1, 1, 0, 0, 0, 0]])
    sep = jax.jit(jax.vmap(lambda s: separated_rewards(r[0, :2], w[0, :, 0], s, sign="printed")))(sides)
    np.testing.assert_array_equal(sep[1], separated_rewards(r[0, :2], w[0, :, 0], sides[1], sign="printed"))


def test_dtype_follows_inputs():
    with jax.enable_x64(True):
        out = backprop_rewards(jnp.array([1.0, -1.0], jnp.float64), jnp.array([[1.0, 3.0]], jnp.float64))
        assert out.dtype == jnp.float64 and float(out[0]) == pytest.approx(-1 / 3, rel=1e-15)


@pytest.mark.parametrize(
    "call",
    [
        lambda: backprop_rewards(jnp.ones(3), jnp.ones((4, 2))),
        lambda: backprop_rewards(jnp.ones(2), jnp.ones(2)),
        lambda: backprop_rewards(jnp.ones(2), jnp.ones((4, 2)), jnp.ones((4, 3), bool)),
        lambda: unified_rewards(jnp.ones(2), jnp.ones((4, 3))),
        lambda: separated_rewards(jnp.ones(2), jnp.ones(4), jnp.zeros(3, int)),
        lambda: separated_rewards(jnp.ones(2), jnp.ones(4), jnp.zeros(4, int), sign="minus"),
    ],
)
def test_bad_shapes_and_signs_are_user_errors(call):
    with pytest.raises(UserError):
        call()
