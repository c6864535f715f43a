"""A cheap counter-based uniform generator for inner loops that draw many numbers.

JAX's default generator (threefry2x32, 20 rounds) costs about a hundred integer
operations per 32 random bits. A learning rule that draws a few numbers per
neuron and step for a tiny network (the hexapod SCPG: 6 neurons) spends most of
its time there. `hash_uniform` instead hashes a counter with a per-trial
seed through two rounds of the ``lowbias32`` integer mixer (Wellons' hash
prospector; bias 0.17 for one round), about 15 operations per number. The seed
comes from a regular JAX key, so randomness stays explicit, and a draw depends
only on its key and counter: the same trial gets the same numbers whatever the
batch size or chunking.

It is not a cryptographic generator, nor a substitute for ``jax.random`` where
statistical quality matters more than speed; its uniformity and lack of serial
correlation are checked by the tests at the level a stochastic update rule needs.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

__all__ = ["hash_seed", "hash_uniform"]

_GOLDEN = 0x9E3779B9


def _lowbias32(x: jax.Array) -> jax.Array:
    x = x ^ (x >> 16)
    x = x * jnp.uint32(0x7FEB352D)
    x = x ^ (x >> 15)
    x = x * jnp.uint32(0x846CA68B)
    return x ^ (x >> 16)


def hash_seed(*, key: jax.Array) -> jax.Array:
    """Two 32-bit words of seed from a JAX PRNG key, shape (2,), dtype uint32."""
    return jax.random.bits(key, (2,), jnp.uint32)


def hash_uniform(seed: jax.Array, counter: jax.Array) -> jax.Array:
    """Uniform float32 numbers in [0, 1), one per counter value.

    Args:
        seed: two uint32 words from `hash_seed`.
        counter: uint32 (or int) array of distinct counter values; the output has its shape.

    Returns:
        ``float32`` array of the counter's shape: the top 24 bits of the hash over ``2**24``.
    """
    x = counter.astype(jnp.uint32) * jnp.uint32(_GOLDEN) + seed[0]
    x = _lowbias32(_lowbias32(x) ^ seed[1])
    return (x >> 8).astype(jnp.float32) * jnp.float32(1.0 / (1 << 24))
