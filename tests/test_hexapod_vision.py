"""The hexapod's window-to-gait wiring (`robots.hexapod.vision`, Sec. IV-C and V-A of the hexapod paper)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from robots.hexapod import vision
from spikejax.errors import UserError
from spikejax.vision import edges


def test_the_paper_map_is_60_forward_18_left_18_right():
    region = vision.regions(vision.PAPER_SENSOR)
    assert region.shape == (8, 12)
    assert [(region == g).sum() for g in (vision.FORWARD, vision.LEFT, vision.RIGHT)] == [60, 18, 18]
    assert (region[:5] == vision.FORWARD).all()
    assert (region[5:, :6] == vision.LEFT).all() and (region[5:, 6:] == vision.RIGHT).all()
    w = np.asarray(vision.readout(vision.PAPER_SENSOR))
    assert set(np.unique(w[vision.FORWARD])) == {0.0, np.float32(0.4)}
    assert set(np.unique(w[vision.LEFT])) == {0.0, np.float32(0.7)}
    # Both branches, the same map.
    np.testing.assert_array_equal(w[..., 0], w[..., 1])


@pytest.mark.parametrize("window, layer2, layer3", [(100, 17, 4), (20, 4, 1), (50, 9, 2)])
def test_scaled_weights_keep_the_papers_fractions(window, layer2, layer3):
    """``k`` coincident spikes fire a layer and ``k - 1`` do not; at 100 pixels the paper's 17 and 4."""
    p = vision.vision_params(vision.scaled_config(8 * window, 12 * window, window))
    for weight, k in ((p.column, layer2), (p.window, layer3)):
        assert k * float(weight) > 1.0 and (k - 1) * float(weight) < 1.0


def _bar_image(config, rows, cols):
    """One event per pixel in the given window rows and pixel columns (a vertical edge's band)."""
    image = np.zeros((config.height, config.width), np.int32)
    w = config.window
    image[rows[0] * w : (rows[-1] + 1) * w, cols[0] : cols[1]] = 1
    return jnp.asarray(image)


@pytest.mark.parametrize(
    "rows, cols, gait",
    [
        ((0, 2), (5, 75), vision.FORWARD),  # far: window rows 0-2, window columns 0-3
        ((6, 7), (5, 35), vision.LEFT),
        ((6, 7), (205, 235), vision.RIGHT),
    ],
)
def test_an_edge_band_in_a_region_makes_its_gait_win(rows, cols, gait):
    """On a 160 x 240 sensor of 20-pixel windows, a band of edge events in one region fires that gait's neuron only."""
    config = vision.scaled_config(160, 240, 20)
    params = vision.vision_params(config)
    image = _bar_image(config, rows, cols)
    step = jax.jit(lambda s, t: edges.sync_step(config, params, s, image, t))
    state = edges.init(config)
    for k in range(3):
        state, spikes = step(state, 0.01 * (k + 1))
    counts = np.asarray(state.counts["out"])
    assert counts[gait] > 0 and counts.sum() == counts[gait]
    assert int(edges.winner(state.counts["out"], jnp.int32(vision.FORWARD))) == gait


def test_a_near_object_outvotes_a_far_one_at_equal_evidence():
    """Window spikes arriving one at a time: 0.7 fires a turn every 2, 0.4 fires G1 every 3, so the near side wins.

    The paper's wiring: the near windows' veto on G1 is the next test.
    """
    config = vision.scaled_config(160, 240, 20)
    params = vision.vision_params(config, "paper", tau_out=10.0)
    region = vision.regions(config)
    far = np.argwhere(region == vision.FORWARD)[:6]
    near = np.argwhere(region == vision.RIGHT)[:6]
    state = edges.init(config)
    out = state.out
    fired = np.zeros(3, int)
    for i, (f, n) in enumerate(zip(far, near)):
        for cell in (f, n):
            s = np.zeros((config.n_rows, config.n_cols, 2), bool)
            s[cell[0], cell[1], 0] = True
            out, spikes = edges._update(
                out,
                jnp.bool_(True),
                edges._readout_drive(params, jnp.asarray(s)),
                0.01 * i,
                params.tau_out,
                params.v_th,
            )
            fired += np.asarray(spikes, int)
    assert fired[vision.RIGHT] == 3 and fired[vision.FORWARD] == 2
    assert int(edges.winner(jnp.asarray(fired), jnp.int32(vision.FORWARD))) == vision.RIGHT


def test_one_near_window_spike_holds_g1_back_for_eleven_far_ones():
    """The "near-veto" wiring: G1 at -3.2 from a near window, so after it G1 needs -3.2 + 0.4 k > 1, k = 11 far spikes."""
    config = vision.scaled_config(160, 240, 20)
    params = vision.vision_params(config, tau_out=1e6)  # no leak over the test
    region = vision.regions(config)
    far, near = np.argwhere(region == vision.FORWARD)[0], np.argwhere(region == vision.LEFT)[0]

    def one(cell):
        s = np.zeros((config.n_rows, config.n_cols, 2), bool)
        s[cell[0], cell[1], 1] = True  # the horizontal branch, wired as the vertical one
        return edges._readout_drive(params, jnp.asarray(s))

    out = edges.init(config).out
    out, spikes = edges._update(out, jnp.bool_(True), one(near), 0.0, params.tau_out, params.v_th)
    assert np.asarray(spikes).tolist() == [False, False, False]
    g1 = []
    for k in range(12):
        out, spikes = edges._update(out, jnp.bool_(True), one(far), 0.001 * (k + 1), params.tau_out, params.v_th)
        g1.append(bool(spikes[vision.FORWARD]))
    assert g1 == [False] * 10 + [True, False]
    paper = np.asarray(vision.vision_params(config, "paper").readout)
    assert np.all(paper[vision.FORWARD][region != vision.FORWARD] == 0)
    np.testing.assert_array_equal(np.asarray(params.readout)[1:], paper[1:])  # the turns' synapses are the paper's


def test_bad_maps_are_one_line_errors():
    with pytest.raises(UserError, match="2 x 2"):
        vision.regions(edges.EdgeConfig(height=20, width=40, window=20, n_out=3))
    with pytest.raises(UserError, match="3 gait"):
        vision.readout(edges.EdgeConfig(height=40, width=40, window=20, n_out=2))
    with pytest.raises(UserError, match="unknown wiring 'nearest'; expected one of near-veto, paper"):
        vision.vision_params(vision.scaled_config(160, 240, 20), "nearest")


def test_the_network_counts_the_spikes_of_plain_numpy_loops():
    """`edges.async_step` against `robots.hexapod.reference.reference_vision` on a moving bar with noise."""
    from robots.hexapod.reference import reference_vision
    from spikejax.vision.events import Events

    config = vision.scaled_config(40, 60, 10)
    params = vision.vision_params(config, tau_out=0.05)
    rng = np.random.default_rng(3)
    xs, ys, ts = [], [], []
    for k in range(30):  # a 3-pixel-wide band of edge events sweeping right, low and left, then noise
        for y in rng.permutation(np.arange(18, 40)):
            for x in (3 + k // 3, 4 + k // 3, 5 + k // 3):
                xs.append(x), ys.append(y), ts.append(k * 1e-3 + rng.random() * 1e-3)
        for _ in range(10):
            xs.append(rng.integers(60)), ys.append(rng.integers(40)), ts.append(k * 1e-3 + rng.random() * 1e-3)
    order = np.argsort(ts, kind="stable")
    xs, ys, ts = (np.asarray(a)[order] for a in (xs, ys, ts))
    n = len(xs)
    events = Events(
        jnp.asarray(xs, jnp.int32), jnp.asarray(ys, jnp.int32), jnp.asarray(ts, jnp.float32),
        jnp.ones(n, jnp.int32), jnp.ones(n, bool),
    )  # fmt: skip
    ours = jax.jit(lambda e: edges.async_step(config, params, edges.init(config), e))(events).counts
    ref = reference_vision(config, params, xs, ys, np.asarray(events.t))
    assert int(ours["filter"]) == ref["filter"] and int(ours["layer2"]) == ref["layer2"]
    np.testing.assert_array_equal(np.asarray(ours["windows"]), ref["windows"])
    np.testing.assert_array_equal(np.asarray(ours["out"]), ref["out"])
    assert ref["filter"] > 500 and ref["layer2"] > 20 and ref["windows"].sum() > 5
    assert ref["out"][vision.LEFT] > 0


def test_shot_noise_at_one_hertz_a_pixel_dies_in_the_filter():
    """Sec. IV-A: isolated noise events never reach the edge layers. 1 s of 1 Hz/pixel shot noise on the
    160 x 240 sensor (38,477 events): measured 14 filter spikes (0.04 %) and nothing beyond."""
    from spikejax.vision.events import Events

    config = vision.scaled_config(160, 240, 20)
    params = vision.vision_params(config)
    rng = np.random.default_rng(0)
    n = rng.poisson(config.height * config.width)
    ts = np.sort(rng.random(n))
    xs, ys = rng.integers(0, config.width, n), rng.integers(0, config.height, n)
    events = Events(
        jnp.asarray(xs, jnp.int32), jnp.asarray(ys, jnp.int32), jnp.asarray(ts, jnp.float32),
        jnp.ones(n, jnp.int32), jnp.ones(n, bool),
    )  # fmt: skip
    counts = jax.jit(lambda e: edges.async_step(config, params, edges.init(config), e))(events).counts
    assert int(counts["events"]) == n
    assert int(counts["filter"]) < 0.01 * n
    assert int(counts["layer2"]) == 0 and int(counts["windows"].sum()) == 0 and int(counts["out"].sum()) == 0
