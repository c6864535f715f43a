"""Neuron models against hand-computed cases, closed forms and Brian2."""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from spikejax.neurons import (
    DiscreteLIFParams,
    LIFState,
    discrete_lif_init,
    discrete_lif_step,
    lif_first_spike_time,
    lif_init,
    lif_params,
    lif_rate,
    lif_step,
)

# Float32 rounding of times and potentials; far below one step (1e-4 s, ~1e-2 V per step).
FLOAT_SLACK = 1e-6


@functools.partial(jax.jit, static_argnames="n_steps")
def simulate(params, state, currents, n_steps, key=None):
    """Runs ``lif_step`` for ``n_steps``; ``currents`` is ``(n,)`` or ``(n_steps, n)``.

    Returns the final state, the potentials after each step and the spikes, both
    ``(n_steps, n)``.
    """
    currents = jnp.broadcast_to(currents, (n_steps,) + state.v.shape)
    keys = None if key is None else jax.random.split(key, n_steps)

    def body(s, xs):
        i, k = xs
        s, spikes = lif_step(params, s, i, key=k)
        return s, (s.v, spikes)

    state, (v, spikes) = jax.lax.scan(body, state, (currents, keys))
    return state, v, spikes


def spike_steps(spikes):
    """Per neuron, the step indices at which it spiked."""
    spikes = np.asarray(spikes)
    return [np.flatnonzero(spikes[:, j]) for j in range(spikes.shape[1])]


# ---------------------------------------------------------------- discrete LIF


def test_discrete_lif_hand_computed_sequence():
    # alpha = 2, V_th = 1, input 0.6: V = 0.6, 0.9, 1.05 > 1 -> spike and reset, repeat.
    p = DiscreteLIFParams(alpha=jnp.float32(2.0), v_th=jnp.float32(1.0))
    s = discrete_lif_init(1)
    vs, spikes = [], []
    for _ in range(7):
        s, out = discrete_lif_step(p, s, jnp.array([0.6], jnp.float32))
        vs.append(float(s.v[0]))
        spikes.append(float(out[0]))
    np.testing.assert_allclose(vs, [0.6, 0.9, 0.0, 0.6, 0.9, 0.0, 0.6], atol=FLOAT_SLACK)
    assert spikes == [0, 0, 1, 0, 0, 1, 0]


def test_discrete_lif_threshold_is_strict():
    # alpha = 1 integrates 0.5 exactly: V = 0.5, 1.0 (not > 1, no spike), 1.5 -> spike.
    p = DiscreteLIFParams(alpha=jnp.float32(1.0), v_th=jnp.float32(1.0))
    s = discrete_lif_init(1)
    out = []
    for _ in range(3):
        s, sp = discrete_lif_step(p, s, jnp.array([0.5], jnp.float32))
        out.append(float(sp[0]))
    assert out == [0, 0, 1]


# ---------------------------------------------------------------- LIF: exactness


def test_lif_init_is_at_rest_and_not_refractory():
    p = lif_params(v_rest=-0.2)
    s = lif_init(5, p)
    assert isinstance(s, LIFState)
    assert s.v.shape == s.refractory.shape == (5,)
    assert s.v.dtype == s.refractory.dtype == jnp.float32
    np.testing.assert_allclose(s.v, -0.2, atol=FLOAT_SLACK)
    assert not s.refractory.any()


def test_lif_subthreshold_trajectory_is_exact_for_any_dt():
    # The exact update gives the same v(t) from 100 steps of 0.1 ms as from one of 10 ms.
    current = jnp.array([0.3, 0.7, -0.4])
    v0 = jnp.array([0.5, -0.2, 0.1])
    fine = lif_params(v_th=10.0, v_rest=0.1, dt=1e-4)
    coarse = fine._replace(dt=jnp.float32(1e-2))
    _, v_fine, _ = simulate(fine, LIFState(v0, jnp.zeros(3)), current, 100)
    _, v_coarse, _ = simulate(coarse, LIFState(v0, jnp.zeros(3)), current, 1)
    v_inf = 0.1 + current
    closed = v_inf + (v0 - v_inf) * math.exp(-10e-3 / 20e-3)
    np.testing.assert_allclose(v_fine[-1], closed, atol=1e-5)
    np.testing.assert_allclose(v_coarse[-1], closed, atol=1e-6)


@pytest.mark.parametrize("v0", [-0.5, 0.0, 0.6])
def test_lif_first_spike_time_matches_closed_form(v0):
    currents = jnp.array([1.01, 1.1, 1.5, 2.0, 4.0, 20.0])
    p = lif_params(v_rest=0.0, t_ref=0.0)
    n_steps = 2000
    _, _, spikes = simulate(p, LIFState(jnp.full(6, v0), jnp.zeros(6)), currents, n_steps)
    t_closed = np.asarray(lif_first_spike_time(p, currents, v0))
    dt = float(p.dt)
    for j, steps in enumerate(spike_steps(spikes)):
        # The crossing lies in (k dt, (k + 1) dt] and is stamped k dt.
        t_sim = steps[0] * dt
        assert t_sim <= t_closed[j] + FLOAT_SLACK
        assert t_closed[j] - t_sim <= dt + FLOAT_SLACK


def test_lif_first_spike_time_edge_cases():
    p = lif_params()
    t = lif_first_spike_time(p, jnp.array([0.5, 1.0, 2.0, 0.0]), jnp.array([0.0, 0.0, 1.2, 1.0]))
    assert np.isinf(t[0]) and np.isinf(t[1])
    assert t[2] == 0.0 and t[3] == 0.0


# ---------------------------------------------------------------- LIF: f-I curve


def test_lif_f_i_curve_matches_closed_form():
    currents = jnp.array([1.05, 1.2, 1.5, 2.0, 3.0, 5.0, 10.0])
    p = lif_params(tau=20e-3, r=1.0, v_th=1.0, v_reset=0.0, t_ref=2e-3, dt=1e-4)
    duration, dt = 2.0, float(p.dt)
    n_steps = round(duration / dt)
    _, _, spikes = simulate(p, lif_init(7, p), currents, n_steps)
    rate = np.asarray(lif_rate(p, currents), np.float64)
    np.testing.assert_allclose(
        rate,
        1.0 / (2e-3 + 20e-3 * np.log(np.asarray(currents) / (np.asarray(currents) - 1.0))),
        rtol=1e-5,
    )
    for j, steps in enumerate(spike_steps(spikes)):
        period = 1.0 / rate[j]
        # Each interspike interval is a whole number of steps within dt of the period.
        isi = np.diff(steps) * dt
        assert len(isi) > 10
        assert np.all(isi <= period + FLOAT_SLACK)
        assert np.all(isi > period - dt - FLOAT_SLACK)
        # So the count over the run is within one spike of duration / isi.
        f_sim = len(steps) / duration
        assert rate[j] - 1.0 / duration - FLOAT_SLACK <= f_sim
        assert f_sim <= 1.0 / (period - dt) + 1.0 / duration


def test_lif_below_rheobase_never_spikes():
    # v_inf = v_rest + R I = 0.1 + I stays below v_th = 1 (the exact rheobase is left out:
    # there v creeps up to v_th until rounding puts it on the threshold).
    currents = jnp.array([-1.0, 0.0, 0.5, 0.85, 0.899])
    p = lif_params(v_rest=0.1, v_reset=0.1)
    _, v, spikes = simulate(p, lif_init(5, p), currents, 10_000)
    assert not spikes.any()
    assert float(v.max()) < 1.0
    np.testing.assert_array_equal(lif_rate(p, currents), 0.0)


def test_lif_rate_gradient_is_finite_below_and_above_rheobase():
    p = lif_params()
    g = jax.vmap(jax.grad(lambda i: lif_rate(p, i)))(jnp.array([0.5, 1.0, 1.5]))
    assert np.all(np.isfinite(g))
    assert g[0] == 0.0 and g[2] > 0.0


# ---------------------------------------------------------------- LIF: refractoriness


@pytest.mark.parametrize("t_ref", [0.0, 1e-3, 2e-3, 5e-3])
def test_lif_refractory_period_is_respected(t_ref):
    currents = jnp.array([1.2, 3.0, 30.0, 1e4])
    p = lif_params(t_ref=t_ref)
    n_ref = round(t_ref / float(p.dt))
    _, v, spikes = simulate(p, lif_init(4, p), currents, 3000)
    v = np.asarray(v)
    for j, steps in enumerate(spike_steps(spikes)):
        assert len(steps) > 2
        assert np.all(np.diff(steps) >= max(n_ref, 1))
        # The spiking step and the n_ref - 1 after it leave v at v_reset whatever the input.
        for k in steps[:-1]:
            np.testing.assert_array_equal(v[k : k + max(n_ref, 1), j], 0.0)
    # A current that crosses the threshold in one step fires once every max(n_ref, 1) steps.
    np.testing.assert_array_equal(np.diff(spike_steps(spikes)[3]), max(n_ref, 1))


def test_lif_parrot_neuron_repeats_its_input_spikes():
    # t_ref = 0 and v_th close to v_rest: each input pulse gives a spike in the same step.
    p = lif_params(v_th=0.01, t_ref=0.0)
    pattern = np.zeros((200, 3), bool)
    pattern[[3, 4, 5, 50, 51, 120], 0] = True
    pattern[::7, 1] = True
    pattern[199, 2] = True
    # R I (1 - exp(-dt / tau)) = 10 (1 - exp(-5e-3)) ~ 0.05 V >= v_th in the pulse's step.
    currents = jnp.asarray(pattern, jnp.float32) * 10.0
    _, _, spikes = simulate(p, lif_init(3, p), currents, 200)
    np.testing.assert_array_equal(np.asarray(spikes), pattern)


# ---------------------------------------------------------------- LIF: noise


def test_lif_ou_noise_has_stationary_std_sigma():
    # dt / tau = 0.1 is coarse on purpose: an Euler-Maruyama noise term would give a std
    # about 5 % too large here, the exact OU update gives sigma for any dt.
    n, n_steps, burn_in = 2000, 1000, 100
    sigma, mean = 0.3, 0.5
    p = lif_params(tau=20e-3, dt=2e-3, v_th=1e6, sigma=sigma)
    _, v, spikes = simulate(p, lif_init(n, p), jnp.full(n, mean), n_steps, jax.random.key(7))
    assert not spikes.any()
    v = np.asarray(v[burn_in:], np.float64)
    # Roughly n * n_steps * dt / (2 tau) = 5e4 independent samples: the std is known to ~0.3 %.
    assert abs(v.std() / sigma - 1.0) < 0.015
    assert abs(v.mean() - mean) < 0.01
    lag1 = np.mean((v[1:] - mean) * (v[:-1] - mean)) / v.var()
    assert abs(lag1 - math.exp(-0.1)) < 0.01


def test_lif_noise_is_reproducible_and_keyed():
    p = lif_params(sigma=0.2)
    s0 = lif_init(4, p)
    current = jnp.full(4, 1.1)
    _, v_a, sp_a = simulate(p, s0, current, 500, jax.random.key(3))
    _, v_b, sp_b = simulate(p, s0, current, 500, jax.random.key(3))
    _, v_c, _ = simulate(p, s0, current, 500, jax.random.key(4))
    np.testing.assert_array_equal(v_a, v_b)
    np.testing.assert_array_equal(sp_a, sp_b)
    assert not np.allclose(v_a, v_c)
    # Without a key the step is deterministic even though sigma > 0.
    _, v_none, _ = simulate(p, s0, current, 500)
    p_zero = p._replace(sigma=jnp.float32(0.0))
    _, v_zero, _ = simulate(p_zero, s0, current, 500, jax.random.key(3))
    np.testing.assert_allclose(v_none, v_zero, atol=FLOAT_SLACK)


def test_lif_step_uses_its_key_once():
    p = lif_params(sigma=0.1)
    with jax.debug_key_reuse(True):
        simulate(p, lif_init(3, p), jnp.full(3, 1.2), 50, jax.random.key(0))


# ---------------------------------------------------------------- LIF: jit, vmap


def test_lif_jit_equals_eager():
    p = lif_params(sigma=0.1)
    s = lif_init(5, p)
    current = jnp.linspace(0.8, 3.0, 5)
    keys = jax.random.split(jax.random.key(11), 150)
    eager_v, eager_spikes = [], []
    for k in keys:
        s, spikes = lif_step(p, s, current, key=k)
        eager_v.append(s.v)
        eager_spikes.append(spikes)
    _, v, spikes = simulate(p, lif_init(5, p), current, 150, jax.random.key(11))
    # Op-by-op and fused float32 arithmetic differ by a few ulps per step, which add up.
    np.testing.assert_allclose(np.stack(eager_v), v, rtol=1e-5, atol=1e-6)
    np.testing.assert_array_equal(np.stack(eager_spikes), spikes)
    assert np.asarray(spikes).any()


def test_lif_vmap_equals_loop():
    # A batch of currents, and a batch of parameters (tau, t_ref swept), each run vmapped.
    p = lif_params(sigma=0.05)
    n, n_steps = 3, 400
    currents = jnp.linspace(0.9, 4.0, 4 * n).reshape(4, n)
    keys = jax.random.split(jax.random.key(5), 4)
    swept = p._replace(tau=jnp.array([10e-3, 20e-3, 30e-3, 40e-3]), t_ref=jnp.array([0.0, 1e-3, 2e-3, 3e-3]))
    run = lambda params, i, k: simulate(params, lif_init(n, params), i, n_steps, k)[1:]
    in_axes_p = type(p)(0, None, None, None, None, 0, None, None)
    v_batch, sp_batch = jax.vmap(run, in_axes=(in_axes_p, 0, 0))(swept, currents, keys)
    for b in range(4):
        pb = p._replace(tau=swept.tau[b], t_ref=swept.t_ref[b])
        v_one, sp_one = run(pb, currents[b], keys[b])
        np.testing.assert_allclose(v_batch[b], v_one, atol=1e-6)
        np.testing.assert_array_equal(sp_batch[b], sp_one)


# ---------------------------------------------------------------- LIF: Brian2


def _brian2_spike_steps(currents, duration, segment=None, **kw):
    """Spike steps of Brian2's exact LIF; ``currents`` (n,) or, with ``segment`` s, (m, n)."""
    b2 = pytest.importorskip("brian2")
    from brian2 import NeuronGroup, SpikeMonitor, TimedArray, amp, ohm, second, volt

    b2.prefs.codegen.target = "numpy"
    b2.start_scope()
    dt = kw["dt"]
    b2.defaultclock.dt = dt * second
    namespace = {
        "tau": kw["tau"] * second,
        "R": kw["r"] * ohm,
        "v_th": kw["v_th"] * volt,
        "v_reset": kw["v_reset"] * volt,
        "v_rest": kw["v_rest"] * volt,
    }
    if segment is None:
        current_eq = "I : amp"
    else:
        namespace["I_t"] = TimedArray(np.asarray(currents) * amp, dt=segment * second)
        current_eq = "I = I_t(t, i) : amp"
    eqs = f"dv/dt = (v_rest + R*I - v)/tau : volt (unless refractory)\n{current_eq}"
    n = np.asarray(currents).shape[-1]
    group = NeuronGroup(
        n,
        eqs,
        threshold="v >= v_th",
        reset="v = v_reset",
        refractory=kw["t_ref"] * second,
        method="exact",
        namespace=namespace,
    )
    group.v = kw["v_rest"] * volt
    if segment is None:
        group.I = np.asarray(currents) * amp
    monitor = SpikeMonitor(group)
    b2.run(duration * second, namespace=namespace)
    # Brian2 stamps a spike with the start time of the step whose update crossed v_th.
    steps = np.round(np.asarray(monitor.t / second) / dt).astype(int)
    idx = np.asarray(monitor.i)
    return [steps[idx == j] for j in range(n)]


def _compare_with_brian2(ours, theirs):
    max_diff = 0
    for j, (a, b) in enumerate(zip(ours, theirs)):
        assert len(a) == len(b), f"neuron {j}: {len(a)} spikes here, {len(b)} in Brian2"
        assert len(a) > 0
        max_diff = max(max_diff, int(np.abs(a - b).max()))
    assert max_diff <= 1, f"spike times differ by {max_diff} steps"
    return max_diff


BRIAN2_KW = dict(tau=20e-3, r=1.0, v_th=1.0, v_reset=-0.1, v_rest=0.05, t_ref=2e-3, dt=1e-4)


def test_lif_matches_brian2_constant_currents():
    currents = np.array([1.0, 1.1, 1.3, 1.7, 2.5, 4.0, 12.0, 1e3])
    duration = 0.3
    theirs = _brian2_spike_steps(currents, duration, **BRIAN2_KW)
    p = lif_params(**BRIAN2_KW)
    n_steps = round(duration / BRIAN2_KW["dt"])
    _, _, spikes = simulate(p, lif_init(len(currents), p), jnp.asarray(currents), n_steps)
    _compare_with_brian2(spike_steps(spikes), theirs)


def test_lif_matches_brian2_piecewise_constant_current():
    rng = np.random.default_rng(0)
    segment, duration, dt = 20e-3, 0.4, BRIAN2_KW["dt"]
    n_seg, n = round(duration / segment), 4
    seg_currents = rng.uniform(0.5, 3.0, size=(n_seg, n))
    theirs = _brian2_spike_steps(seg_currents, duration, segment=segment, **BRIAN2_KW)
    n_steps = round(duration / dt)
    per_step = np.repeat(seg_currents, round(segment / dt), axis=0)[:n_steps]
    p = lif_params(**BRIAN2_KW)
    _, _, spikes = simulate(p, lif_init(n, p), jnp.asarray(per_step, jnp.float32), n_steps)
    _compare_with_brian2(spike_steps(spikes), theirs)
