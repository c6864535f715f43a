"""NEST's iaf_psc_alpha (`spikejax.neurons.iaf_psc_alpha_step`) against NEST 3.10 live and closed forms.

Float64 throughout: with the same propagators and the same order of operations
the two agree to rounding, so spike trains must be identical and potentials
agree far below 1e-9 mV.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from spikejax.neurons import (
    IafPscAlphaParams,
    iaf_psc_alpha_init,
    iaf_psc_alpha_params,
    iaf_psc_alpha_step,
    iaf_refractory_steps,
    parrot_step,
)
from spikejax.synapses import delay_init, delay_read, delay_step

DT = 0.1  # ms, NEST's default resolution


@pytest.fixture
def x64():
    previous = jax.config.jax_enable_x64
    jax.config.update("jax_enable_x64", True)
    yield
    jax.config.update("jax_enable_x64", previous)


def _nest():
    nest = pytest.importorskip("nest")
    nest.ResetKernel()
    nest.verbosity = nest.VerbosityLevel.ERROR
    nest.resolution = DT
    return nest


def _nest_params(p: IafPscAlphaParams, n: int) -> dict:
    """``p`` as NEST's status dictionary, with ``V_m = E_L`` as `iaf_psc_alpha_init` starts.

    NEST keeps ``V_m`` where it was (-70 mV) when ``E_L`` is set, so it is set too.
    """
    d = {name: np.broadcast_to(np.asarray(v, float), (n,)).tolist() for name, v in p._asdict().items()}
    return d | {"V_m": d["E_L"]}


@functools.partial(jax.jit, static_argnames=("d_gen", "d_syn"))
def _network(params, gen_counts, w, *, d_gen, d_syn):
    """generators -(d_gen)-> parrots -(d_syn, weights w)-> iaf_psc_alpha, as NEST wires it.

    ``gen_counts[k]``: the generators' spikes emitted by step ``k`` (stamped
    ``(k + 1) DT``). Returns ``V_m`` after every step and the spikes, ``(steps, n)``.
    """
    n_src, n = w.shape
    w_ex, w_in = jnp.maximum(w, 0.0), jnp.minimum(w, 0.0)

    def body(carry, g):
        state, to_parrot, to_neuron = carry
        parrots = parrot_step(delay_read(to_parrot))
        to_parrot, _ = delay_step(to_parrot, g)
        arriving = delay_read(to_neuron)
        state, spikes = iaf_psc_alpha_step(params, state, arriving @ w_ex, arriving @ w_in, DT)
        to_neuron, _ = delay_step(to_neuron, parrots)
        return (state, to_parrot, to_neuron), (state.V_m, spikes)

    carry = (
        iaf_psc_alpha_init(n, params),
        delay_init(n_src, d_gen, w.dtype),
        delay_init(n_src, d_syn, w.dtype),
    )
    _, (v, spikes) = jax.lax.scan(body, carry, gen_counts.astype(w.dtype))
    return v, spikes


def _nest_run(nest, p, gen_counts, w, t_sim, record_v=True):
    """The same network in NEST; returns per-neuron spike steps and V_m ``(steps, n)``."""
    steps, n_src = gen_counts.shape
    n = w.shape[1]
    gens = nest.Create("spike_generator", n_src)
    for i in range(n_src):
        k = np.flatnonzero(gen_counts[:, i])
        if len(k) == 0:
            continue
        gens[i].set(
            spike_times=np.round((k + 1) * DT, 10).tolist(),
            spike_multiplicities=gen_counts[k, i].astype(int).tolist(),
        )
    parrots = nest.Create("parrot_neuron", n_src)
    neurons = nest.Create("iaf_psc_alpha", n)
    neurons.set(_nest_params(p, n))
    nest.Connect(gens, parrots, "one_to_one", syn_spec={"delay": 1.0})
    nest.Connect(parrots, neurons, "all_to_all", syn_spec={"weight": np.asarray(w).T, "delay": 1.0})
    rec = nest.Create("spike_recorder")
    nest.Connect(neurons, rec)
    if record_v:
        mm = nest.Create("multimeter", params={"interval": DT, "record_from": ["V_m"]})
        nest.Connect(mm, neurons)
    # A multimeter hands over its last min_delay of data one slice late: run past the end.
    nest.Simulate(t_sim + 2.0)
    ev = rec.get("events")
    first = neurons[0].global_id
    spikes = [np.sort(np.round(ev["times"][ev["senders"] == first + j] / DT).astype(int) - 1) for j in range(n)]
    spikes = [s[s < steps] for s in spikes]
    if not record_v:
        return spikes, None
    m = mm.get("events")
    k = np.round(m["times"] / DT).astype(int) - 1  # the record at (k + 1) DT follows step k
    keep = k < steps
    v = np.full((steps, n), np.nan)
    v[k[keep], m["senders"][keep] - first] = m["V_m"][keep]
    return spikes, v


def _spike_steps(spikes):
    spikes = np.asarray(spikes)
    return [np.flatnonzero(spikes[:, j]) for j in range(spikes.shape[1])]


def test_poisson_driven_population_matches_nest_spike_for_spike(x64):
    nest = _nest()
    rng = np.random.default_rng(7)
    n, n_src, t_sim = 20, 24, 10_000.0
    steps = int(round(t_sim / DT))
    rates = rng.uniform(5.0, 60.0, n_src)
    rates[:3] = 1500.0  # several spikes in one step: multiplicities > 1
    gen_counts = rng.poisson(rates * DT * 1e-3, (steps, n_src))
    # The generators' first spike can be at DT at the earliest (stamp of step 0).
    w = rng.uniform(20.0, 160.0, (n_src, n)) * np.where(rng.random((n_src, n)) < 0.3, -1.0, 1.0)
    w[:3] *= 0.3
    cyc = lambda *v: np.resize(np.asarray(v, float), n)  # noqa: E731
    p = iaf_psc_alpha_params(
        C_m=cyc(250.0, 200.0, 300.0),
        tau_m=cyc(10.0, 10.0, 15.0, 8.0),
        t_ref=cyc(2.0, 0.25, 0.0, 3.3, 2.0),
        E_L=cyc(-70.0, -65.0),
        V_reset=cyc(-70.0, -72.0, -68.0),
        V_th=cyc(-55.0, -52.0, -56.0, -54.0, -55.0, -50.0, -57.0),
        tau_syn_ex=cyc(2.0, 0.5, 10.0, 3.0, 1.0),  # 10 = tau_m for some: NEST's singular propagators
        tau_syn_in=cyc(2.0, 5.0, 1.5),
        I_e=cyc(0.0, 100.0, 250.0, 0.0, 50.0),
        dtype=jnp.float64,
    )
    assert np.any(np.asarray(p.tau_syn_ex) == np.asarray(p.tau_m))
    # Scale each neuron's excitation so that its mean drive sits at threshold: fluctuation-driven firing.
    a = {f: np.asarray(x) for f, x in p._asdict().items()}
    charge = rates[:, None] * 1e-3 * np.e * np.where(w > 0, a["tau_syn_ex"], a["tau_syn_in"])  # pA per pA of weight
    needed = 1.02 * (a["V_th"] - a["E_L"]) * a["C_m"] / a["tau_m"] - a["I_e"]
    w_in = np.minimum(w, 0.0)
    w = np.where(w > 0, w * (needed - (charge * w_in).sum(0)) / (charge * np.maximum(w, 0.0)).sum(0), w)

    v, spikes = _network(p, jnp.asarray(gen_counts), jnp.asarray(w), d_gen=10, d_syn=10)
    assert v.dtype == jnp.float64
    nest_spikes, nest_v = _nest_run(nest, p, gen_counts, w, t_sim)

    ours = _spike_steps(spikes)
    n_spikes = sum(len(s) for s in nest_spikes)
    assert n_spikes > 20 * n  # every neuron is driven to fire, several Hz on average
    assert min(len(s) for s in nest_spikes) > 10
    differing = sum(len(np.setxor1d(a, b)) for a, b in zip(ours, nest_spikes, strict=True))
    assert differing == 0
    assert not np.isnan(nest_v).any()
    np.testing.assert_allclose(np.asarray(v), nest_v, rtol=0, atol=1e-9)


def _isi_closed_form(p, j, n, dt):
    """Steps to the first spike from E_L and between spikes, under I_e alone (None: never)."""
    p = IafPscAlphaParams(*(np.broadcast_to(np.asarray(x, float), (n,)) for x in p))
    v_inf = float(p.I_e[j]) * float(p.tau_m[j]) / float(p.C_m[j])  # relative to E_L
    theta = float(p.V_th[j]) - float(p.E_L[j])
    reset = float(p.V_reset[j]) - float(p.E_L[j])
    if v_inf <= theta:
        return None
    t_first = float(p.tau_m[j]) * math.log(v_inf / (v_inf - theta))
    t_free = float(p.tau_m[j]) * math.log((v_inf - reset) / (v_inf - theta))
    n_ref = math.ceil(round(float(p.t_ref[j]) * 1000) / round(dt * 1000))
    for t in (t_first, t_free):  # away from a tie, so that ceil is safe
        assert abs(t / dt - round(t / dt)) > 1e-6
    return math.ceil(t_first / dt) - 1, n_ref + math.ceil(t_free / dt), t_free + float(p.t_ref[j])


def test_constant_current_matches_nest_and_closed_form_interval(x64):
    nest = _nest()
    n, t_sim = 6, 500.0
    steps = int(round(t_sim / DT))
    p = iaf_psc_alpha_params(
        I_e=[300.0, 376.0, 450.0, 600.0, 1000.0, 2500.0],  # the first is below rheobase (375 pA)
        t_ref=[2.0, 2.0, 0.25, 0.0, 2.0, 3.3],
        V_reset=[-70.0, -70.0, -65.0, -70.0, -60.0, -70.0],
        dtype=jnp.float64,
    )
    w = jnp.zeros((1, n), jnp.float64)
    v, spikes = _network(p, jnp.zeros((steps, 1)), w, d_gen=1, d_syn=1)
    ours = _spike_steps(spikes)
    nest_spikes, _ = _nest_run(nest, p, np.zeros((steps, 1), int), np.zeros((1, n)), t_sim, record_v=False)

    for j in range(n):
        np.testing.assert_array_equal(ours[j], nest_spikes[j])
        form = _isi_closed_form(p, j, n, DT)
        if form is None:
            assert len(ours[j]) == 0
            continue
        first, isi, isi_continuous = form
        assert len(ours[j]) > 5
        assert ours[j][0] == first
        np.testing.assert_array_equal(np.diff(ours[j]), isi)
        assert abs(isi * DT - isi_continuous) < DT + 1e-12  # within one step of the continuous interval


def test_refractory_steps_follow_nest_tics():
    # NEST: t_ref rounded to 1 us tics, then rounded up to steps.
    got = iaf_refractory_steps(jnp.array([0.0, 0.1, 2.0, 0.25, 3.3, 0.0004, 0.0006]), 0.1)
    np.testing.assert_array_equal(np.asarray(got), [0, 1, 20, 3, 33, 0, 1])


def test_alpha_kernel_closed_form(x64):
    # One excitatory spike of weight w into a neuron at rest: I_ex(t) = w (t / tau) e^(1 - t / tau),
    # V(t) - E_L the closed-form convolution with the membrane kernel (tau_syn != tau_m).
    tau_s, tau_m, c_m, w, k0 = 2.0, 10.0, 250.0, 300.0, 5
    p = iaf_psc_alpha_params(tau_syn_ex=tau_s, tau_m=tau_m, C_m=c_m, dtype=jnp.float64)
    s = iaf_psc_alpha_init(1, p)
    vs, currents = [], []
    for k in range(200):
        ex = jnp.full((1,), w if k == k0 else 0.0)
        s, _ = iaf_psc_alpha_step(p, s, ex, jnp.zeros(1), DT)
        vs.append(float(s.V_m[0]))
        currents.append(float(s.I_ex[0]))
    t = (np.arange(200) - k0) * DT  # the spike enters at the end of step k0
    i_ref = np.where(t > 0, w * t / tau_s * np.exp(1 - t / tau_s), 0.0)
    a, b = 1 / tau_s, 1 / tau_m
    # V = (w e / (tau_s C)) * integral_0^t u e^{-a u} e^{-b (t - u)} du
    d = a - b
    conv = np.exp(-b * t) * (1 - np.exp(-d * t) * (1 + d * t)) / d**2
    v_ref = np.where(t > 0, w * math.e / (tau_s * c_m) * conv, 0.0) - 70.0
    np.testing.assert_allclose(currents, i_ref, rtol=0, atol=1e-10)
    np.testing.assert_allclose(vs, v_ref, rtol=0, atol=1e-11)


def test_float32_by_default_and_dtype_follows_params():
    p = iaf_psc_alpha_params()
    s = iaf_psc_alpha_init(3, p)
    s, spikes = iaf_psc_alpha_step(p, s, jnp.ones(3), -jnp.ones(3), DT)
    assert s.V_m.dtype == jnp.float32 and s.dI_in.dtype == jnp.float32
    assert spikes.dtype == jnp.bool_ and spikes.shape == (3,)
    assert s.refractory.dtype == jnp.int32


def test_vmap_over_params_compiles_once_and_equals_the_loop(x64):
    traces = []
    n, steps = 5, 3000
    rng = np.random.default_rng(3)
    drive = jnp.asarray(rng.poisson(0.08, (steps, n)) * 120.0)
    inhib = jnp.asarray(rng.poisson(0.03, (steps, n)) * -90.0)

    def run(params):
        traces.append(1)

        def body(state, x):
            state, spikes = iaf_psc_alpha_step(params, state, x[0], x[1], DT)
            return state, (state.V_m, spikes)

        _, out = jax.lax.scan(body, iaf_psc_alpha_init(n, params), (drive, inhib))
        return out

    batch = IafPscAlphaParams(
        *(
            jnp.stack(
                [
                    getattr(iaf_psc_alpha_params(I_e=i_e, tau_m=tau, tau_syn_in=ts, dtype=jnp.float64), f)
                    for i_e, tau, ts in [(0.0, 10.0, 2.0), (200.0, 12.0, 5.0), (350.0, 8.0, 1.0), (50.0, 10.0, 10.0)]
                ]
            )
            for f in IafPscAlphaParams._fields
        )
    )
    v_batch, s_batch = jax.jit(jax.vmap(run))(batch)
    assert len(traces) == 1
    single = jax.jit(run)
    for b in range(4):
        member = IafPscAlphaParams(*(x[b] for x in batch))
        v, s = single(member)
        np.testing.assert_array_equal(np.asarray(s_batch[b]), np.asarray(s))
        np.testing.assert_allclose(np.asarray(v_batch[b]), np.asarray(v), rtol=0, atol=1e-12)
    assert np.asarray(s_batch).sum() > 10
