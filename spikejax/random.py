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

`threefry_uniform` is ``jax.random.uniform`` itself, the same numbers bit for
bit, lowered so that a CPU draws them in one pass (for the DVS emulator's
per-pixel noise, whose results must not change).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["hash_seed", "hash_uniform", "threefry_uniform"]

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


_ROTATIONS = ((13, 15, 26, 6), (17, 29, 16, 24))


def _threefry2x32(k1: jax.Array, k2: jax.Array, x1: jax.Array, x2: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Threefry-2x32, 20 rounds (Salmon et al. 2011), written out: XLA fuses it into one pass."""
    ks = (k1, k2, k1 ^ k2 ^ jnp.uint32(0x1BD11BDA))
    x1, x2 = x1 + ks[0], x2 + ks[1]
    for i in range(5):
        for r in _ROTATIONS[i % 2]:
            x1 = x1 + x2
            x2 = x1 ^ ((x2 << jnp.uint32(r)) | (x2 >> jnp.uint32(32 - r)))
        x1, x2 = x1 + ks[(i + 1) % 3], x2 + ks[(i + 2) % 3] + jnp.uint32(i + 1)
    return x1, x2


def threefry_uniform(key: jax.Array, shape: tuple[int, ...], minval=0.0, maxval=1.0) -> jax.Array:
    """``jax.random.uniform(key, shape, jnp.float32, minval, maxval)``, bit for bit, in one pass on a CPU.

    On a CPU, JAX lowers its threefry2x32 generator as a loop of five steps,
    each a pass over the whole output (on accelerators, unrolled); written out
    here, XLA fuses the 20 rounds and the conversion to floats into one pass:
    the hexapod's render, DVS and visual SNN ran 1.4x faster with the DVS's
    per-pixel noise drawn so (docs/BENCHMARKS.md). The numbers are JAX's
    (``jax_threefry_partitionable``'s counter layout, tested against
    ``jax.random.uniform``); a key of another generator, or JAX configured
    otherwise, is passed to ``jax.random.uniform``.
    """
    typed = jax.dtypes.issubdtype(key.dtype, jax.dtypes.prng_key)
    impl = str(jax.random.key_impl(key)) if typed else jax.config.jax_default_prng_impl
    size = math.prod(shape)
    if "threefry2x32" not in impl or not jax.config.jax_threefry_partitionable or size >= 2**32:
        return jax.random.uniform(key, shape, jnp.float32, minval, maxval)
    words = jax.random.key_data(key) if typed else key
    count = jax.lax.iota(jnp.uint32, size).reshape(shape)
    b1, b2 = _threefry2x32(words[0], words[1], jnp.zeros_like(count), count)
    one = jnp.uint32(np.array(1.0, np.float32).view(np.uint32))
    floats = jax.lax.bitcast_convert_type(((b1 ^ b2) >> jnp.uint32(9)) | one, jnp.float32) - jnp.float32(1.0)
    minval, maxval = jnp.float32(minval), jnp.float32(maxval)
    return jnp.maximum(minval, floats * (maxval - minval) + minval)
