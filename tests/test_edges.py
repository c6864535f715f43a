"""The hexapod paper's visual SNN (`spikejax.vision.edges`): its arithmetic (Sec. IV-B), its leak, and its two modes."""

import itertools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from spikejax.errors import UserError
from spikejax.vision import edges
from spikejax.vision.events import Events

SMALL = edges.EdgeConfig(height=24, width=36, window=6, n_out=3)


def _readout(config, value=0.0):
    return jnp.full((config.n_out, config.n_rows, config.n_cols, 2), value, jnp.float32)


def _events(xs, ys, ts):
    n = len(xs)
    return Events(
        jnp.asarray(xs, jnp.int32),
        jnp.asarray(ys, jnp.int32),
        jnp.asarray(ts, jnp.float32),
        jnp.ones(n, jnp.int32),
        jnp.ones(n, bool),
    )


_sync_step = jax.jit(edges.sync_step, static_argnums=0)


def _slot(config, params, xs, ys, t=0.01):
    """One sync slot holding the given events, from rest."""
    image = edges.count_image(config, _events(xs, ys, np.full(len(xs), t)))
    return _sync_step(config, params, edges.init(config), image, t)


def _same_network(a: edges.EdgeState, b: edges.EdgeState):
    """Equal spikes, counts and update times; potentials to float32 rounding.

    How the compiler fuses the leak's product and sum (one multiply-add or two
    roundings) depends on the program around it: batched or not, one event or a
    slot; it moves the last bit of a potential, never a spike here.
    """
    for x, y in zip(jax.tree.leaves(a.counts), jax.tree.leaves(b.counts)):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    for x, y in zip(a[:5], b[:5]):
        np.testing.assert_array_equal(np.asarray(x.t_last), np.asarray(y.t_last))
        np.testing.assert_allclose(np.asarray(x.v), np.asarray(y.v), rtol=1e-6, atol=1e-7)


def test_the_filter_fires_exactly_when_the_kernel_sum_exceeds_one_for_every_set_of_neighbours():
    """All 512 sets of events in a 3 x 3 neighbourhood, one each, at one time: the centre fires iff its sum > 1.

    Sec. IV-B's kernel 0.5 / 0.18 / 0.06: one event never fires (0.5); the centre and three
    four-neighbours do (1.04); the centre, two four-neighbours and two diagonals do not (0.98);
    no set without the centre does (0.96 at most).
    """
    params = edges.edge_params(_readout(SMALL))
    k = np.array([[0.06, 0.18, 0.06], [0.18, 0.5, 0.18], [0.06, 0.18, 0.06]], np.float32)
    sets = np.array(list(itertools.product([0, 1], repeat=9)), np.int32).reshape(-1, 3, 3)
    images = np.zeros((len(sets), SMALL.height, SMALL.width), np.int32)
    images[:, 10:13, 10:13] = sets

    def centre_fires(image):
        _, spikes = edges.sync_step(SMALL, params, edges.init(SMALL), image, 0.01)
        return spikes.filter[11, 11]

    fired = np.asarray(jax.jit(jax.vmap(centre_fires))(images))
    expected = np.einsum("nij,ij->n", sets.astype(np.float32), k) > 1.0
    np.testing.assert_array_equal(fired, expected)
    assert not fired[sets.reshape(-1, 9)[:, 4] == 0].any()
    assert expected.sum() > 0 and (~expected).sum() > 0
    # The worked cases.
    by_set = {tuple(s.ravel()): f for s, f in zip(sets, fired)}
    assert not by_set[(0, 0, 0, 0, 1, 0, 0, 0, 0)]
    assert by_set[(0, 1, 0, 1, 1, 1, 0, 0, 0)]
    assert not by_set[(1, 1, 0, 0, 1, 0, 0, 1, 1)]


def test_the_filter_leaks_by_the_event_times():
    """The centre's event at 0, three four-neighbours at ``t``: it fires iff ``0.5 exp(-t / tau) + 0.54 > 1``."""
    tau = 10e-3
    params = edges.edge_params(_readout(SMALL), tau_filter=tau)
    t_star = tau * math.log(0.5 / 0.46)

    def fires(t):
        events = _events([11, 10, 12, 11], [11, 11, 11, 10], [0.0, t, t, t])
        state = edges.async_step(SMALL, params, edges.init(SMALL), events)
        return int(state.counts["filter"])

    assert fires(0.98 * t_star) == 1
    assert fires(1.02 * t_star) == 0


def test_layer_2_needs_17_coincident_spikes_in_a_column_and_layer_3_needs_4():
    """With a filter that passes every event, a window column of n events fires layer 2 iff 0.06 n > 1 (n >= 17).

    The paper says "at least 16"; 16 x 0.06 = 0.96 does not reach the threshold of 1.
    """
    config = edges.EdgeConfig(height=40, width=40, window=20, n_out=1)
    passing = edges.edge_params(_readout(config), centre=1.5, edge=0.0, corner=0.0)
    for n, fires in ((16, False), (17, True)):
        _, spikes = _slot(config, passing, [5] * n, list(range(n)))
        assert bool(spikes.vertical[0, 5]) is fires
        assert int(spikes.vertical.sum()) == int(fires) and not spikes.horizontal.any()
    # Layer 3 with layer 2 passing every filter spike: n events on a diagonal fire n vertical
    # and n horizontal layer-2 neurons, and each branch's window neuron iff 0.3 n > 1 (n >= 4).
    both = passing._replace(column=jnp.float32(1.5))
    for n, fires in ((3, False), (4, True)):
        _, spikes = _slot(config, both, list(range(n)), list(range(n)))
        assert int(spikes.vertical.sum()) == n and int(spikes.horizontal.sum()) == n
        np.testing.assert_array_equal(np.asarray(spikes.windows[0, 0]), [fires, fires])
        assert int(spikes.windows.sum()) == 2 * int(fires)


def test_readout_weights_04_and_07_need_three_and_two_windows():
    """Sec. IV-C's gait-selection weights: at 0.4 three coincident window spikes fire, at 0.7 two do."""
    config = edges.EdgeConfig(height=20, width=40, window=10, n_out=2)
    readout = np.zeros((2, config.n_rows, config.n_cols, 2), np.float32)
    readout[0, ..., 0], readout[1, ..., 0] = 0.4, 0.7
    params = edges.edge_params(readout, centre=1.5, edge=0.0, corner=0.0, column=1.5, window=1.5)
    for n_windows, expected in ((1, [0, 0]), (2, [0, 1]), (3, [1, 1])):
        xs = [10 * i + 2 for i in range(n_windows)]
        _, spikes = _slot(config, params, xs, [3] * n_windows)
        assert int(spikes.windows[..., 0].sum()) == n_windows
        np.testing.assert_array_equal(np.asarray(spikes.out, np.int32), expected)


def _edge_stream(key, n_steps=40, noise=0.3):
    """A vertical edge sweeping right over the small sensor, one event per pixel per step, plus noise events."""
    xs, ys, ts = [], [], []
    rng = np.random.default_rng(int(jax.random.randint(key, (), 0, 2**30)))
    for k in range(n_steps):
        col = 4 + k // 2
        rows = rng.permutation(SMALL.height)
        for i, y in enumerate(rows):
            t = k * 2e-3 + i * 2e-3 / SMALL.height
            xs.append(col + (rng.random() < 0.3))
            ys.append(y)
            ts.append(t)
            if rng.random() < noise:
                xs.append(rng.integers(SMALL.width))
                ys.append(rng.integers(SMALL.height))
                ts.append(t + 1e-5)
    order = np.argsort(ts, kind="stable")
    return _events(np.asarray(xs)[order], np.asarray(ys)[order], np.asarray(ts)[order])


def _busy_params(config):
    readout = np.zeros((config.n_out, config.n_rows, config.n_cols, 2), np.float32)
    readout[0, : config.n_rows // 2], readout[1, config.n_rows // 2 :, : config.n_cols // 2] = 0.4, 0.7
    readout[2, config.n_rows // 2 :, config.n_cols // 2 :] = 0.7
    return edges.edge_params(readout, column=0.3, window=0.4)


def test_sync_with_one_event_per_slot_gives_the_spikes_of_async():
    """Both modes keep each neuron's last update time and decay lazily, so one-event slots give the same network.

    Spikes, counts and update times are equal; potentials to float32 rounding (one
    multiply-add fused in one mode and not in the other moves the last bit).
    """
    params = _busy_params(SMALL)
    events = _edge_stream(jax.random.key(0))
    asy = jax.jit(lambda e: edges.async_step(SMALL, params, edges.init(SMALL), e))(events)

    def slot(state, e):
        one = jax.tree.map(lambda a: a[None], e)
        state, _ = edges.sync_step(SMALL, params, state, edges.count_image(SMALL, one), e.t)
        return state, None

    syn = jax.jit(lambda e: jax.lax.scan(slot, edges.init(SMALL), e)[0])(events)
    _same_network(asy, syn)
    # The stream exercised every layer.
    assert int(asy.counts["filter"]) > 100 and int(asy.counts["layer2"]) > 10
    assert int(asy.counts["windows"].sum()) > 3 and int(asy.counts["out"].sum()) > 0
    # Isolated noise events never pass the filter on their own: far fewer filter spikes than events.
    assert int(asy.counts["filter"]) < int(asy.counts["events"])


def test_vmap_over_cameras_equals_each_camera_alone():
    params = _busy_params(SMALL)
    streams = [_edge_stream(jax.random.key(i), n_steps=12) for i in range(3)]
    n = min(s.capacity for s in streams)
    batch = jax.tree.map(lambda *a: jnp.stack([x[:n] for x in a]), *streams)
    run = jax.jit(lambda e: edges.async_step(SMALL, params, edges.init(SMALL), e))
    together = jax.vmap(run)(batch)
    for i in range(3):
        _same_network(jax.tree.map(lambda a: a[i], together), run(jax.tree.map(lambda a: a[i], batch)))


def test_invalid_event_slots_change_nothing():
    params = _busy_params(SMALL)
    events = _edge_stream(jax.random.key(1), n_steps=6)
    padded = jax.tree.map(lambda a: jnp.concatenate([a, jnp.zeros(50, a.dtype)]), events)
    run = jax.jit(lambda e: edges.async_step(SMALL, params, edges.init(SMALL), e))
    for a, b in zip(jax.tree.leaves(run(events)), jax.tree.leaves(run(padded))):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_the_paper_sensor_has_96_windows_and_ignores_the_rightmost_80_columns():
    config = edges.EdgeConfig()
    assert (config.n_rows, config.n_cols) == (8, 12)
    assert config.used == (800, 1200)
    state = edges.init(config)
    assert state.vertical.v.shape == (8, 1200) and state.horizontal.v.shape == (800, 12)
    # A bright column in the ignored strip fires the filter but nothing beyond it.
    params = edges.edge_params(_readout(config, 0.4), centre=1.5, edge=0.0, corner=0.0)
    image = jnp.zeros((800, 1280), jnp.int32).at[:, 1250].set(1)
    _, spikes = _sync_step(config, params, state, image, 0.01)
    assert int(spikes.filter.sum()) == 800
    assert not spikes.vertical.any() and not spikes.horizontal.any()


@pytest.mark.parametrize(
    "counts, previous, expected",
    [([0, 0, 0], 2, 2), ([3, 5, 1], 0, 1), ([4, 4, 0], 1, 1), ([4, 4, 0], 2, 0), ([0, 2, 2], 0, 1)],
)
def test_winner_takes_the_most_spikes_and_keeps_the_gait_on_silence_or_a_tie(counts, previous, expected):
    assert int(edges.winner(jnp.asarray(counts), jnp.int32(previous))) == expected


def test_bad_sizes_are_one_line_errors():
    with pytest.raises(UserError, match="window"):
        edges.EdgeConfig(height=10, width=10, window=20)
    with pytest.raises(UserError, match="height"):
        edges.EdgeConfig(height=0)
