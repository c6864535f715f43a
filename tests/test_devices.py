"""A batch split over two CPU devices gives the one-device results, padding and replicated arguments included."""

import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from spikejax import devices
from spikejax.errors import UserError

_TWO_DEVICES = textwrap.dedent(
    """
    import jax, jax.numpy as jnp, numpy as np
    from spikejax import devices
    from spikejax.vision import hough
    from spikejax.vision.events import Events
    devices.use_cpu_devices(2)
    assert len(jax.devices()) == 2
    grid = hough.LineGrid(width=32, height=32, n_theta=30, n_rho=48)
    params = hough.hough_params(3.0, 50.0)
    key = jax.random.key(0)
    x = jax.random.randint(key, (5, 3, 40), 0, 32)
    y = jax.random.randint(jax.random.fold_in(key, 1), (5, 3, 40), 0, 32)
    p = jnp.where(jax.random.bernoulli(jax.random.fold_in(key, 2), 0.5, (5, 3, 40)), 1, -1).astype(jnp.int32)
    t = jnp.broadcast_to(jnp.arange(3, dtype=jnp.float32)[None, :, None] * 0.01, (5, 3, 40))
    valid = jax.random.bernoulli(jax.random.fold_in(key, 3), 0.8, (5, 3, 40))
    events = Events(x.astype(jnp.int32), y.astype(jnp.int32), t, p, valid)
    times = jnp.arange(1, 4, dtype=jnp.float32) * 0.01
    run = jax.vmap(lambda e: hough.sync_run(params, grid, e, times)[1])
    one = jax.jit(run)(events)
    two = devices.shard_batch(run)(events)  # 5 streams over 2 devices: padded to 6
    assert two.shape == one.shape == (5, 3) + grid.shape, two.shape
    assert np.array_equal(np.asarray(one), np.asarray(two))
    assert np.count_nonzero(np.asarray(one)) > 0
    print("ok")
    """
)


_REPLICATED = textwrap.dedent(
    """
    from typing import NamedTuple
    import jax, jax.numpy as jnp, numpy as np
    from spikejax import devices
    devices.use_cpu_devices(2)
    assert len(jax.devices()) == 2

    class Params(NamedTuple):
        a: object
        b: object

    axes = (Params(a=0, b=None), 0)
    run = jax.vmap(lambda p, s: jnp.sin(p.a * p.b) + s * p.b, in_axes=axes)
    params = Params(a=np.linspace(0.0, 1.0, 5, dtype=np.float32), b=np.float32(3.0))
    seeds = np.arange(5, dtype=np.int32)
    one = np.asarray(jax.jit(run)(params, seeds))
    split = devices.shard_batch(run, in_axes=axes)  # 5 members over 2 devices: padded to 6, b whole on both
    assert split.padded_size(5) == 6
    assert np.array_equal(np.asarray(split(params, seeds)), one)
    compiled = split.compile(params, seeds)
    assert np.array_equal(np.asarray(compiled(params, seeds)), one)
    assert np.array_equal(np.asarray(compiled(params._replace(b=np.float32(2.0)), seeds)),
                          np.asarray(jax.jit(run)(params._replace(b=np.float32(2.0)), seeds)))
    print("ok")
    """
)


def test_two_cpu_devices_give_the_one_device_spikes():
    run = subprocess.run([sys.executable, "-c", _TWO_DEVICES], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-3000:]
    assert run.stdout.strip().endswith("ok")


def test_one_device_is_plain_jit():
    f = devices.shard_batch(lambda a: a * 2, devices=jax.devices()[:1])
    np.testing.assert_array_equal(f(jnp.arange(3)), [0, 2, 4])


def test_mismatched_batch_axes_are_rejected():
    f = devices.shard_batch(lambda a, b: a + b, devices=[jax.devices()[0]] * 2)
    with pytest.raises(UserError, match="same leading batch axis"):
        f(jnp.zeros(2), jnp.zeros(3))


def test_a_device_count_below_one_is_rejected():
    with pytest.raises(UserError, match=">= 1"):
        devices.use_cpu_devices(0)


def test_unbatched_arguments_go_whole_to_every_device():
    run = subprocess.run([sys.executable, "-c", _REPLICATED], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-3000:]
    assert run.stdout.strip().endswith("ok")


def test_compiled_ahead_on_one_device_is_the_jitted_function():
    f = devices.shard_batch(lambda a, b: a * b, devices=jax.devices()[:1], in_axes=(0, None))
    compiled = f.compile(jnp.arange(3.0), jnp.float32(2.0))
    np.testing.assert_array_equal(compiled(jnp.arange(3.0), jnp.float32(3.0)), [0.0, 3.0, 6.0])


def test_only_the_leading_axis_is_split():
    with pytest.raises(UserError, match="leading axis"):
        devices.shard_batch(lambda a: a, in_axes=(1,))
