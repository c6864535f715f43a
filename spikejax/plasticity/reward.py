"""Rewards of output neurons and their assignment to hidden layers, as in the snake R-STDP paper.

The paper trains the synapses onto each neuron with R-STDP modulated by that
neuron's own reward: Eq. (9) rewards the output neuron on the target's side and
punishes the other, and Eq. (10) passes rewards back one layer at a time, each
hidden neuron getting the weighted vote of the rewards of the neurons it
projects to, normalised by its largest outgoing weight. Eq. (11) (a hidden
layer connected to both outputs) and Eq. (13) (each hidden neuron connected to
one output) are the two cases the paper uses.

All functions are for one network (no batch axis) and jit and vmap.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from spikejax.errors import UserError

__all__ = [
    "backprop_rewards",
    "pair_rewards",
    "separated_rewards",
    "unified_rewards",
]


def pair_rewards(a_target, c_reward) -> jax.Array:
    """Rewards of a left/right pair of output neurons, Eq. (9).

    ``r_right = -r_left = a_target * C_reward``: with the target to the right
    (``a_target > 0``) the right neuron is rewarded and the left one punished,
    and the other way round. Every synapse onto a neuron gets that neuron's
    reward.

    Args:
        a_target: angle between the robot's moving direction and the target,
            positive to the right (the paper's unit is degrees); scalar, may be traced.
        c_reward: gain, > 0 (0.0001 for the body, 0.0004 for the head in the paper).

    Returns:
        ``[r_left, r_right]``, shape ``(2,)``.

    Examples:
        >>> pair_rewards(10.0, 0.5).tolist()
        [-5.0, 5.0]
    """
    r = jnp.asarray(a_target) * c_reward
    return jnp.stack([-r, r])


def backprop_rewards(r_next: jax.Array, weights: jax.Array, mask: jax.Array | None = None) -> jax.Array:
    """Rewards of one layer from those of the layer one closer to the output, Eq. (10).

    For neuron ``j`` of this layer with outgoing synapses of weights ``w_jk`` to
    the neurons ``k`` of the next layer (rewards ``r_k``)::

        r_j = sum_k r_k w_jk / (max_k |w_jk| * Y_j),

    the sum, the max and the count ``Y_j`` running over the synapses that exist.
    The paper writes ``Y`` for the size of the next layer, which is the same for
    all-to-all connections; Eq. (13) shows that a neuron with one outgoing
    synapse has ``Y = 1``, hence the count of existing synapses. The result is a
    normalised weighted vote, ``|r_j| <= max_k |r_k|``. A neuron with no synapse,
    or whose weights are all 0, gets 0 (the paper leaves it undefined), without
    a NaN in the value or in its gradients.

    Each weight is normalised first, ``u_jk = w_jk / (max_k |w_jk| Y_j)``, then
    ``r_j = sum_k u_jk r_k``: the same quantity, but a lone synapse has
    ``u = sign(w)`` exactly, so Eq. (13) (`separated_rewards`) is this function
    with a one-synapse mask bit for bit, and tiny weights do not underflow.

    Args:
        r_next: rewards of the next layer, shape ``(Y,)``.
        weights: weights from this layer's ``N`` neurons to the next layer,
            shape ``(N, Y)`` (row ``j`` = neuron ``j``'s outgoing synapses).
        mask: bool ``(N, Y)``, the synapses that exist; ``None``: all of them.

    Returns:
        Rewards of this layer, shape ``(N,)``, the dtype of ``weights`` and ``r_next`` promoted.

    Raises:
        UserError: if the shapes do not fit together.

    Examples:
        >>> w = jnp.array([[1.0, 4.0], [2.0, 0.0], [2.0, 0.0]])
        >>> backprop_rewards(jnp.array([-1.0, 1.0]), w, mask=jnp.array([[1, 1], [1, 1], [1, 0]])).tolist()
        [0.375, -0.5, -1.0]
    """
    r_next = jnp.asarray(r_next)
    weights = jnp.asarray(weights)
    if weights.ndim != 2 or r_next.shape != weights.shape[1:]:
        raise UserError(
            f"weights must be (N, Y) and r_next (Y,), got weights {weights.shape} and r_next {r_next.shape}"
        )
    if mask is None:
        mask = jnp.ones(weights.shape, bool)
    else:
        mask = jnp.asarray(mask, bool)
        if mask.shape != weights.shape:
            raise UserError(f"mask must have the shape of weights {weights.shape}, got {mask.shape}")
    dtype = jnp.result_type(weights, r_next)
    if not jnp.issubdtype(dtype, jnp.floating):
        dtype = jnp.zeros(()).dtype
    weights = weights.astype(dtype)
    r_next = r_next.astype(dtype)
    zero = jnp.zeros((), dtype)
    w = jnp.where(mask, weights, zero)
    largest = jnp.max(jnp.abs(w), axis=1, initial=zero)
    n_synapses = jnp.sum(mask, axis=1).astype(dtype)
    defined = (largest > 0) & (n_synapses > 0)
    # XLA turns a division by a broadcast into a product with its reciprocal, which is off by an ulp; taking
    # sign(w) outright where |w| is the largest keeps a lone synapse at exactly sign(w).
    ratio = jnp.where(jnp.abs(w) == largest[:, None], jnp.sign(w), w / jnp.where(defined, largest, 1)[:, None])
    u = ratio / jnp.where(defined, n_synapses, 1)[:, None]
    votes = jnp.where(mask & defined[:, None], u * r_next[None, :], zero)
    return jnp.sum(votes, axis=1)


def unified_rewards(r_out: jax.Array, weights: jax.Array) -> jax.Array:
    """Rewards of a hidden layer connected to both output neurons, Eq. (11).

    ``r_h = (r_l w_l + r_r w_r) / (max(|w_l|, |w_r|) * 2)``, `backprop_rewards`
    with every hidden neuron projecting to both outputs. With Eq. (9)'s
    ``r_l = -r_r`` it is ``r_r (w_r - w_l) / (2 max(|w_l|, |w_r|))``: near 0 for a
    neuron connected about equally to both sides, the weakening the paper blames
    for the unified network's failure.

    Args:
        r_out: ``[r_left, r_right]``, shape ``(2,)``.
        weights: ``(N, 2)``, column 0 to the left output, column 1 to the right.

    Returns:
        Rewards of the ``N`` hidden neurons, shape ``(N,)``.

    Raises:
        UserError: if ``r_out`` is not ``(2,)`` or ``weights`` not ``(N, 2)``.
    """
    r_out = jnp.asarray(r_out)
    weights = jnp.asarray(weights)
    if r_out.shape != (2,) or weights.ndim != 2 or weights.shape[1] != 2:
        raise UserError(f"r_out must be (2,) and weights (N, 2), got {r_out.shape} and {weights.shape}")
    return backprop_rewards(r_out, weights)


def separated_rewards(r_out: jax.Array, weights: jax.Array, side: jax.Array, *, sign: str = "eq10") -> jax.Array:
    """Rewards of a hidden layer split into a left and a right group, Eq. (13).

    Each hidden neuron ``j`` has one outgoing synapse, of weight ``w_j``, to the
    output neuron ``side[j]`` (0 left, 1 right). The paper prints

        r_hr = r_or * w_r / |w_r|,    r_hl = -r_ol * w_l / |w_l|,

    and calls it the simplification of Eq. (10) for one outgoing synapse; but
    Eq. (10) gives ``r_hl = +r_ol * w_l / |w_l|``. With Eq. (9)'s ``r_ol = -r_or``
    and positive weights the printed minus rewards both groups alike (``r_hl =
    r_or = r_hr``), the left group for a target on the right. Both are offered:

    * ``sign="eq10"`` (default): ``r_j = r_out[side[j]] * sign(w_j)``, exactly
      `backprop_rewards` with a one-synapse mask;
    * ``sign="printed"``: the paper's equation as printed, the left group's
      reward negated.

    A zero weight gives 0.

    Args:
        r_out: ``[r_left, r_right]``, shape ``(2,)``.
        weights: ``(N,)``, weight of each hidden neuron's synapse to its output.
        side: ``(N,)`` int, 0 for the left group, 1 for the right (may be traced).
        sign: ``"eq10"`` or ``"printed"`` (static).

    Returns:
        Rewards of the ``N`` hidden neurons, shape ``(N,)``.

    Raises:
        UserError: if ``sign`` is unknown or the shapes do not fit.

    Examples:
        >>> r_out, w, side = jnp.array([-1.0, 1.0]), jnp.array([2.0, 2.0]), jnp.array([0, 1])
        >>> separated_rewards(r_out, w, side).tolist(), separated_rewards(r_out, w, side, sign="printed").tolist()
        ([-1.0, 1.0], [1.0, 1.0])
    """
    if sign not in ("eq10", "printed"):
        raise UserError(f'sign must be "eq10" or "printed", got {sign!r}')
    r_out = jnp.asarray(r_out)
    weights = jnp.asarray(weights)
    side = jnp.asarray(side)
    if r_out.shape != (2,) or weights.ndim != 1 or side.shape != weights.shape:
        raise UserError(
            f"r_out must be (2,), weights (N,) and side (N,), got {r_out.shape}, {weights.shape} and {side.shape}"
        )
    dtype = jnp.result_type(weights, r_out)
    if not jnp.issubdtype(dtype, jnp.floating):
        dtype = jnp.zeros(()).dtype
    r = r_out.astype(dtype)[side] * jnp.sign(weights.astype(dtype))
    if sign == "printed":
        r = jnp.where(side == 0, -r, r)
    return r
