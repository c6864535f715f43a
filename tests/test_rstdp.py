"""R-STDP, Eq. (6)-(8) of the snake R-STDP paper: closed forms, and NEST 3.10's stdp_dopamine_synapse live."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from spikejax.errors import UserError
from spikejax.plasticity import RSTDPNestState, RSTDPParams, replay, rstdp_params, set_dopamine
from spikejax.plasticity.rstdp import rstdp

H = 0.1  # ms, NEST's default resolution
D = 1.0  # ms, every delay of the NEST networks below
RTOL = 1e-6


@pytest.fixture
def x64():
    jax.config.update("jax_enable_x64", True)
    yield
    jax.config.update("jax_enable_x64", False)


def drive(
    params,
    pre_steps,
    post_steps,
    n_steps,
    *,
    n_pre=1,
    n_post=1,
    w0=10.0,
    dopa_steps=(),
    n_set=None,
    schedule="exact",
    deliver_interval=1,
):
    """Runs the time-driven rule in a scan; spikes as {step: counts}; returns w, c, n after every step.

    ``n_set`` maps a step ``k`` to the dopamine set (`set_dopamine`) after step ``k``.
    """
    dtype = jnp.float64 if jax.config.jax_enable_x64 else jnp.float32
    rule = rstdp(n_pre, n_post, delay_steps=10, schedule=schedule, deliver_interval=deliver_interval)
    pre = np.zeros((n_steps + 1, n_pre))
    post = np.zeros((n_steps + 1, n_post))
    for k, v in pre_steps.items():
        pre[k] += v
    for k, v in post_steps.items():
        post[k] += v
    dopa = np.bincount(np.asarray(dopa_steps, int), minlength=n_steps + 1)[: n_steps + 1]
    mask = np.zeros(n_steps + 1, bool)
    value = np.zeros(n_steps + 1)
    for k, v in (n_set or {}).items():
        mask[k], value[k] = True, v

    def body(carry, x):
        w, s = carry
        pre_k, post_k, dopa_k, m_prev, v_prev = x
        s = jax.tree.map(lambda a, b: jnp.where(m_prev, a, b), set_dopamine(s, v_prev), s)
        dw, s = rule.update(params, s, w, pre_k, post_k, dopa_k, H)
        w = w + dw
        return (w, s), (w, s.c, s.n)

    w = jnp.full((n_pre, n_post), w0, dtype)
    xs = tuple(jnp.asarray(a, dtype) for a in (pre[1:], post[1:], dopa[1:])) + (
        jnp.asarray(mask[:-1]),
        jnp.asarray(value[:-1], dtype),
    )
    _, (ws, cs, ns) = jax.jit(lambda c, x: jax.lax.scan(body, c, x))((w, rule.init(w)), xs)
    return np.asarray(ws), np.asarray(cs), np.asarray(ns)


# --------------------------------------------------------------------------------------------
# closed forms


def test_single_causal_pair_jump_and_weight_integral(x64):
    # pre at 1.0 ms, post at 3.0 ms (arrives 4.0 ms), dopamine n set to 0.5 at 5.0 ms.
    p = rstdp_params(dtype=jnp.float64)
    n_steps = 300
    ws, cs, ns = drive(p, {10: [1]}, {30: [1]}, n_steps, n_set={50: 0.5})
    jump = math.exp(-(4.0 - 1.0) / 20.0)
    assert cs[39, 0, 0] == pytest.approx(jump, rel=1e-12)
    assert cs[38, 0, 0] == pytest.approx(0.0, abs=1e-15)
    # Eq. (8) in closed form from 5 ms to 30 ms, b = 0: c0 n0 tau_s (1 - exp(-T / tau_s)).
    c0, n0, t = jump * math.exp(-1.0 / 1000.0), 0.5, 25.0
    tau_s = 1.0 / (1.0 / 1000.0 + 1.0 / 200.0)
    assert ws[n_steps - 1, 0, 0] - 10.0 == pytest.approx(c0 * n0 * tau_s * (1 - math.exp(-t / tau_s)), rel=1e-10)
    assert ns[n_steps - 1, 0] == pytest.approx(0.5 * math.exp(-t / 200.0), rel=1e-12)


def test_anticausal_pair_and_baseline_closed_form(x64):
    # post at 1.0 ms, pre at 2.5 ms: the post spike is seen at 2.0 ms, before the pre spike.
    b, tau_c = 0.02, 500.0
    p = rstdp_params(b=b, tau_c=tau_c, A_minus=1.2, tau_minus=15.0, dtype=jnp.float64)
    ws, cs, _ = drive(p, {25: [1]}, {10: [1]}, 225)
    c0 = -1.2 * math.exp(-(2.5 - 2.0) / 15.0)
    assert cs[24, 0, 0] == pytest.approx(c0, rel=1e-12)
    # n = 0: dw/dt = -b c, so Delta w = -b c0 tau_c (1 - exp(-T / tau_c)) over the 20 ms after the pre spike.
    assert ws[-1, 0, 0] - 10.0 == pytest.approx(-b * c0 * tau_c * (1 - math.exp(-20.0 / tau_c)), rel=1e-10)


def test_dopamine_spike_adds_one_over_tau_n_and_multiplicities_add(x64):
    p = rstdp_params(tau_n=50.0, dtype=jnp.float64)
    _, _, ns = drive(p, {}, {}, 30, dopa_steps=[5, 20, 20])
    assert ns[4, 0] == pytest.approx(1 / 50.0, rel=1e-12)
    assert ns[19, 0] == pytest.approx(math.exp(-1.5 / 50.0) / 50.0 + 2 / 50.0, rel=1e-12)
    # Two pre spikes in one step depress twice, with the same K_minus.
    ws, cs, _ = drive(rstdp_params(dtype=jnp.float64), {30: [2]}, {5: [1]}, 30)
    assert cs[-1, 0, 0] == pytest.approx(-2 * 1.5 * math.exp(-(3.0 - 1.5) / 20.0), rel=1e-12)


def test_simultaneous_pre_and_arrival_do_not_pair(x64):
    # post at 1.0 ms arrives at 2.0 ms, exactly when the pre spike comes: neither jump.
    _, cs, _ = drive(rstdp_params(dtype=jnp.float64), {20: [1]}, {10: [1]}, 40)
    assert np.all(cs == 0.0)


@pytest.mark.parametrize("schedule", ["exact", "nest"])
def test_dw_keeps_weights_in_bounds_and_every_parameter_is_traced(schedule):
    rule = rstdp(3, 2, delay_steps=2, schedule="exact")
    w = jnp.full((3, 2), 5.0)
    p = rstdp_params(Wmax=5.2, Wmin=4.9)
    s = rule.init(w)._replace(c=jnp.array([[1.0, -1.0]] * 3), n=jnp.array([100.0, 100.0]))
    dw, _ = rule.update(p, s, w, jnp.zeros(3), jnp.zeros(2), 0.0, 0.1)
    np.testing.assert_allclose(np.asarray(w + dw), [[5.2, 4.9]] * 3, rtol=1e-6)

    rule = rstdp(3, 2, delay_steps=2, schedule=schedule)
    s = rule.init(w)
    traces = []

    def run(params):
        traces.append(1)
        dw, st = rule.update(params, s, w, jnp.array([1.0, 0.0, 2.0]), jnp.array([1.0, 1.0]), 1.0, 0.1)
        return dw, st.c

    batch = jax.tree.map(
        lambda *x: jnp.stack(x), *[rstdp_params(tau_c=100.0 * (i + 1), b=0.01 * i, Wmax=5.0 + i) for i in range(4)]
    )
    f = jax.jit(jax.vmap(run))
    f(batch)
    f(jax.tree.map(lambda x: x * 1.1, batch))
    assert len(traces) == 1
    dws, _ = f(batch)
    assert dws.shape == (4, 3, 2)
    assert isinstance(batch, RSTDPParams)


def test_nest_schedule_with_an_unbatched_step_counter_matches_batched():
    rule = rstdp(3, 2, schedule="nest", deliver_interval=2)
    p = rstdp_params(tau_n=30.0)
    batch = 4
    w = jnp.full((batch, 3, 2), 10.0)
    key = jax.random.key(0)
    pre = (jax.random.uniform(key, (60, batch, 3)) < 0.2).astype(jnp.float32)
    post = (jax.random.uniform(jax.random.fold_in(key, 1), (60, batch, 2)) < 0.2).astype(jnp.float32)
    dopa = jnp.zeros((60, batch)).at[25].set(2.0)
    axes = RSTDPNestState(*[0] * len(RSTDPNestState._fields))._replace(step=None, t_trig=None)
    s0 = jax.vmap(rule.init)(w)
    runs = {}
    for name, in_axes, state in (
        ("batched", 0, s0),
        ("shared", axes, s0._replace(step=s0.step[0], t_trig=s0.t_trig[0])),
    ):
        step = jax.vmap(rule.update, in_axes=(None, in_axes, 0, 0, 0, 0, None), out_axes=(0, in_axes))

        def body(carry, x, step=step):
            w, s = carry
            dw, s = step(p, s, w, *x, 0.1)
            return (w + dw, s), s.c

        (_, _), cs = jax.lax.scan(body, (w, state), (pre, post, dopa))
        runs[name] = np.asarray(cs)
    np.testing.assert_allclose(runs["shared"], runs["batched"], rtol=1e-6, atol=1e-6)
    assert np.any(runs["shared"] != 0.0)


def test_bad_input():
    with pytest.raises(UserError):
        rstdp(0, 2)
    with pytest.raises(UserError):
        rstdp(2, 2, delay_steps=0)
    with pytest.raises(UserError):
        rstdp_params(tau_c=0.0)
    with pytest.raises(UserError):
        rstdp_params(Wmin=3.0, Wmax=1.0)
    with pytest.raises(UserError):
        rstdp(2, 2).init(jnp.zeros((3, 2)))
    with pytest.raises(UserError):
        rstdp(2, 2, schedule="lazy")
    with pytest.raises(UserError):
        rstdp(2, 2, delay_steps=5, min_delay_steps=6)
    with pytest.raises(UserError):
        replay({}, [0.05], [], [], w0=1.0, t_sim_ms=10.0)
    with pytest.raises(UserError):
        replay({"tau": 1.0}, [], [], [], w0=1.0, t_sim_ms=10.0)


# --------------------------------------------------------------------------------------------
# NEST 3.10 live


def nest_run(params, pre, post, dopa, *, w0, t_sim, tau_minus=20.0, n_set=(), record=None, deliver_interval=1):
    """The replayed network in NEST: spike_generator -> parrot for pre, post and dopamine; returns t, w, c, n.

    Parrot spike times are the generator times plus one delay; the generators get the
    wanted parrot times minus ``D``. ``record`` lists the steps after which ``GetStatus``
    is read (default: every step); ``n_set`` are ``(t, n)`` set after ``Simulate`` to ``t``.
    """
    nest = pytest.importorskip("nest")
    if hasattr(nest, "VerbosityLevel"):
        nest.verbosity = nest.VerbosityLevel.ERROR
    else:
        nest.set_verbosity("M_ERROR")
    nest.ResetKernel()
    nest.resolution = H
    gens = [
        nest.Create("spike_generator", params={"spike_times": [round(t - D, 4) for t in x]}) for x in (pre, post, dopa)
    ]
    parrots = [nest.Create("parrot_neuron") for _ in range(3)]
    for g, par in zip(gens, parrots):
        nest.Connect(g, par, syn_spec={"delay": D})
    parrots[1].set(tau_minus=tau_minus)
    vt = nest.Create("volume_transmitter", params={"deliver_interval": deliver_interval})
    nest.Connect(parrots[2], vt, syn_spec={"delay": D})
    nest.CopyModel("stdp_dopamine_synapse", "rstdp_test", {"volume_transmitter": vt, **params})
    # Receptor 1 of a parrot takes the spikes without repeating them.
    nest.Connect(
        parrots[0], parrots[1], syn_spec={"synapse_model": "rstdp_test", "weight": w0, "delay": D, "receptor_type": 1}
    )
    conn = nest.GetConnections(parrots[0], parrots[1], synapse_model="rstdp_test")
    recorders = [nest.Create("spike_recorder") for _ in range(3)]
    for par, r in zip(parrots, recorders):
        nest.Connect(par, r)
    n_steps = int(round(t_sim / H))
    record = range(1, n_steps + 1) if record is None else record
    sets = {int(round(t / H)): v for t, v in n_set}
    stops = sorted(set(record) | set(sets))
    out = {}
    for s in stops:
        nest.Simulate(round((s - round(nest.biological_time / H)) * H, 4))
        if s in record:
            st = conn.get(["weight", "c", "n"])
            out[s] = (st["weight"], st["c"], st["n"])
        if s in sets:
            conn.set(n=sets[s])
    times = [np.sort(r.get("events")["times"]) for r in recorders]
    for want, got in zip((pre, post, dopa), times):
        np.testing.assert_allclose(got, np.sort(want), atol=1e-9)
    steps = np.array(sorted(out))
    vals = np.array([out[s] for s in steps])
    return steps, vals[:, 0], vals[:, 1], vals[:, 2]


def compare(a, b, what):
    a, b = np.asarray(a), np.asarray(b)
    scale = np.maximum(np.abs(b), 1e-3 * max(np.max(np.abs(b)), 1e-12))
    err = np.max(np.abs(a - b) / scale)
    assert err < RTOL, f"{what}: relative error {err:.3g}"


def check_replay(params, pre, post, dopa, *, w0=10.0, t_sim, tau_minus=20.0, n_set=(), deliver_interval=1):
    steps, w, c, n = nest_run(
        params, pre, post, dopa, w0=w0, t_sim=t_sim, tau_minus=tau_minus, n_set=n_set, deliver_interval=deliver_interval
    )
    t, rw, rc, rn = replay(
        params,
        pre,
        post,
        dopa,
        w0=w0,
        t_sim_ms=t_sim,
        tau_minus_ms=tau_minus,
        n_set=n_set,
        deliver_interval=deliver_interval,
    )
    np.testing.assert_allclose(t[steps - 1], steps * H)
    for got, want, what in ((rw, w, "w"), (rc, c, "c"), (rn, n, "n")):
        compare(got[steps - 1], want, what)
    return w, c, n


def grid(times):
    return [round(t, 1) for t in times]


def test_replay_causal_pairs_then_dopamine_burst():
    pre = grid([5.3, 15.0, 25.7, 37.2, 44.4])
    post = grid([8.1, 17.5, 27.0, 39.9, 46.2])
    dopa = grid([60.0, 60.0, 61.3, 62.6, 64.1, 66.0])
    w, c, n = check_replay({"tau_c": 200.0, "tau_n": 20.0}, pre, post, dopa, t_sim=120.0)
    assert w[-1] > 10.0 and c.max() > 0


def test_replay_anticausal_pairs_then_burst_and_dopamine_before_pairs():
    pre = grid([9.5, 19.9, 31.3, 55.0, 58.2])
    post = grid([8.0, 17.2, 30.0, 52.1, 57.7])
    dopa = grid([2.0, 3.1, 4.4, 65.0, 65.5, 70.2])
    w, c, _ = check_replay(
        {"tau_c": 150.0, "tau_n": 30.0, "A_minus": 1.3}, pre, post, dopa, t_sim=110.0, tau_minus=12.0
    )
    assert w[-1] < 10.0 and c.min() < 0


def test_replay_baseline_and_clipping_at_wmax_and_wmin():
    pre = grid([3.0, 7.4, 11.1, 14.9, 40.0, 43.3, 47.7])
    post = grid([5.0, 9.2, 12.5, 16.6, 38.1, 41.2, 45.0])
    dopa = grid([2.0, 4.0, 6.0, 8.0, 10.0, 12.0, 20.0, 50.0, 52.2])
    check_replay({"b": 0.05, "tau_n": 25.0, "tau_c": 100.0}, pre, post, dopa, t_sim=80.0)
    w, _, _ = check_replay({"Wmax": 10.3, "tau_n": 10.0, "tau_c": 80.0}, pre[:4], post[:4], dopa, t_sim=60.0)
    assert np.isclose(w.max(), 10.3)
    anti = grid([6.0, 10.0, 13.9, 17.8])
    w, _, _ = check_replay({"Wmin": 9.8, "tau_n": 10.0, "tau_c": 80.0}, anti, pre[:4], dopa, t_sim=60.0)
    assert np.isclose(w.min(), 9.8)


def test_replay_dense_spikes_deliver_interval_and_multiplicity():
    rng = np.random.default_rng(3)
    pre = grid(sorted(rng.choice(np.arange(11, 800) * 0.1, 40, replace=False))) + [30.0]
    post = grid(sorted(rng.choice(np.arange(11, 800) * 0.1, 40, replace=False))) + [30.0]
    dopa = grid(sorted(rng.choice(np.arange(11, 800) * 0.1, 25, replace=True)))
    check_replay({"tau_c": 300.0, "tau_n": 40.0, "b": 0.01}, sorted(pre), sorted(post), dopa, t_sim=90.0)
    check_replay({"tau_c": 300.0, "tau_n": 40.0}, sorted(pre), sorted(post), dopa, t_sim=90.0, deliver_interval=3)


def test_exact_schedule_equals_nest_for_pre_spikes_on_slice_ends_with_n_set(x64):
    # The authors' mode: SetStatus({"n": r}) on the connection every 20 ms, 60 control steps.
    # Pre spikes on whole milliseconds, where NEST's schedule is exact (see the module docstring);
    # post spikes anywhere.
    rng = np.random.default_rng(7)
    n_ctrl, ctrl = 60, 20.0
    t_sim = n_ctrl * ctrl
    pre = sorted({float(t) for t in rng.integers(2, int(t_sim), 120)})
    post = sorted({round(float(t), 1) for t in rng.uniform(1.1, t_sim, 120)})
    rewards = rng.normal(0.0, 0.3, n_ctrl)
    n_set = [(k * ctrl, rewards[k]) for k in range(n_ctrl)]
    params = {"tau_c": 400.0, "tau_n": 200.0, "A_plus": 0.8, "A_minus": 1.1}
    per = int(round(ctrl / H))
    ends = [k * per for k in range(1, n_ctrl + 1)]  # at T = 20 k ms, before SetStatus
    after = [k * per + 1 for k in range(1, n_ctrl)]  # one step later, the pre spike of T delivered
    steps, w, c, n = nest_run(params, pre, post, [], w0=50.0, t_sim=t_sim, n_set=n_set, record=ends + after)

    p = rstdp_params(**params, dtype=jnp.float64)
    n_steps = int(round(t_sim / H))
    ws, cs, ns = drive(
        p,
        {int(round(t / H)): [1.0] for t in pre},
        {int(round(t / H)): [1.0] for t in post},
        n_steps,
        w0=50.0,
        n_set={int(round(t / H)): r for t, r in n_set},
    )
    end = steps % per == 0
    # At T NEST has brought the synapse to T (the trigger) but not yet seen a pre spike at T: w and n
    # agree; one step later NEST has processed that pre spike at T and stored c, w at T.
    compare(ws[steps[end] - 1, 0, 0], w[end], "w")
    compare(ns[steps[end] - 1, 0], n[end], "n")
    compare(ws[steps[~end] - 2, 0, 0], w[~end], "w")
    compare(cs[steps[~end] - 2, 0, 0], c[~end], "c")
    assert np.ptp(w) > 1.0
    # And replay, at every 20 ms.
    t, rw, rc, rn = replay(params, pre, post, [], w0=50.0, t_sim_ms=t_sim, n_set=n_set)
    for got, want, what in ((rw, w, "w"), (rc, c, "c"), (rn, n, "n")):
        compare(got[steps - 1], want, what)


def test_exact_schedule_equals_nest_for_pre_spikes_on_slice_ends_with_dopamine(x64):
    # Dopamine through the volume transmitter (arriving one delay after the dopamine parrot), b > 0,
    # two postsynaptic neurons sharing the rule's n: compared after every whole millisecond.
    rng = np.random.default_rng(11)
    t_sim = 300.0
    pre = sorted({float(t) for t in rng.integers(2, int(t_sim), 40)})
    post = sorted({round(float(t), 1) for t in rng.uniform(1.1, t_sim, 40)})
    dopa = sorted(round(float(t), 1) for t in rng.uniform(1.1, t_sim - 2, 30))
    params = {"tau_c": 250.0, "tau_n": 50.0, "b": 0.002, "Wmax": 12.0}
    n_steps = int(round(t_sim / H))
    record = list(range(11, n_steps, 10))
    steps, w, c, n = nest_run(params, pre, post, dopa, w0=10.0, t_sim=t_sim, record=record)
    p = rstdp_params(**params, dtype=jnp.float64)
    dopa_steps = [int(round((t + D) / H)) for t in dopa]
    ws, cs, ns = drive(
        p,
        {int(round(t / H)): [1.0] for t in pre},
        {int(round(t / H)): [1.0, 0.0] for t in post},
        n_steps,
        n_post=2,
        dopa_steps=dopa_steps,
    )
    compare(ws[steps - 2, 0, 0], w, "w")
    compare(cs[steps - 2, 0, 0], c, "c")
    compare(ns[steps - 2, 0], n, "n")
    assert np.all(cs[:, 0, 1] <= 0.0)  # no post spikes: depression only


def dense(rng, t_sim, n, lo=1.1):
    """``n`` spike times on the 0.1 ms grid in ``[lo, t_sim)``, repeats allowed (multiplicities)."""
    return sorted(round(float(t), 1) for t in rng.choice(np.arange(int(lo / H), int(t_sim / H)) * H, n))


def test_nest_schedule_equals_nest_with_n_set_each_control_step(x64):
    # The authors' mode, dense spikes anywhere (repeats are multiplicities): SetStatus({"n": r}) every
    # 20 ms for 60 control steps; NEST read every millisecond (at x.5 ms), the rule after every step.
    rng = np.random.default_rng(5)
    n_ctrl, per = 60, 200
    t_sim = n_ctrl * per * H
    pre, post = dense(rng, t_sim, 400), dense(rng, t_sim, 300)
    rewards = rng.normal(0.0, 0.2, n_ctrl)
    n_set = [(k * per * H, rewards[k]) for k in range(n_ctrl)]
    params = {"tau_c": 400.0, "tau_n": 200.0, "A_plus": 0.1, "A_minus": 0.12, "Wmax": 60.0, "Wmin": 40.0}
    n_steps = n_ctrl * per
    record = list(range(5, n_steps + 1, 10))
    steps, w, c, n = nest_run(params, pre, post, [], w0=50.0, t_sim=t_sim, n_set=n_set, record=record)
    counts = lambda ts: {
        k: [float(v)] for k, v in zip(*np.unique(np.rint(np.array(ts) / H).astype(int), return_counts=True))
    }  # noqa: E731
    ws, cs, ns = drive(
        rstdp_params(**params, dtype=jnp.float64),
        counts(pre),
        counts(post),
        n_steps,
        w0=50.0,
        n_set={int(round(t / H)): r for t, r in n_set},
        schedule="nest",
    )
    compare(ws[steps - 1, 0, 0], w, "w")
    compare(cs[steps - 1, 0, 0], c, "c")
    assert np.ptp(w) > 1.0
    # The exact-time rule tells another story here: NEST's schedule matters for dense spikes.
    wx, _, _ = drive(
        rstdp_params(**params, dtype=jnp.float64),
        counts(pre),
        counts(post),
        n_steps,
        w0=50.0,
        n_set={int(round(t / H)): r for t, r in n_set},
    )
    assert np.max(np.abs(wx[steps - 1, 0, 0] - w)) > 1e-3


def nest_group(params, pres, posts, dopa, *, w0, t_sim, record, deliver_interval=1):
    """A dense group in NEST: len(pres) pre parrots all-to-all onto len(posts) post parrots; w, c per record."""
    nest = pytest.importorskip("nest")
    nest.ResetKernel()
    nest.resolution = H
    par = []
    for times in list(pres) + list(posts) + [dopa]:
        g = nest.Create("spike_generator", params={"spike_times": [round(t - D, 4) for t in times]})
        p = nest.Create("parrot_neuron")
        nest.Connect(g, p, syn_spec={"delay": D})
        par.append(p)
    pre = sum(par[1 : len(pres)], par[0])
    post = sum(par[len(pres) + 1 : len(pres) + len(posts)], par[len(pres)])
    vt = nest.Create("volume_transmitter", params={"deliver_interval": deliver_interval})
    nest.Connect(par[-1], vt, syn_spec={"delay": D})
    nest.CopyModel("stdp_dopamine_synapse", "rstdp_group", {"volume_transmitter": vt, **params})
    nest.Connect(pre, post, syn_spec={"synapse_model": "rstdp_group", "weight": w0, "delay": D, "receptor_type": 1})
    conns = nest.GetConnections(pre, post, synapse_model="rstdp_group")
    row = {p.global_id: i for i, p in enumerate(par[: len(pres)])}
    col = {p.global_id: j for j, p in enumerate(par[len(pres) : len(pres) + len(posts)])}
    src = np.array([row[x] for x in np.atleast_1d(conns.get("source"))])
    tgt = np.array([col[x] for x in np.atleast_1d(conns.get("target"))])
    ws, cs = [], []
    for step in record:
        nest.Simulate(round((step - round(nest.biological_time / H)) * H, 4))
        st = conns.get(["weight", "c"])
        w = np.zeros((len(pres), len(posts)))
        c = np.zeros_like(w)
        w[src, tgt], c[src, tgt] = st["weight"], st["c"]
        ws.append(w)
        cs.append(c)
    return np.array(ws), np.array(cs)


@pytest.mark.parametrize("n_pre, n_post, deliver_interval", [(4, 2, 1), (4, 2, 2), (1, 1, 2)])
def test_nest_schedule_group_equals_nest_with_dopamine_spikes(x64, n_pre, n_post, deliver_interval):
    # A group, dopamine through the volume transmitter, b > 0, clipping, dense spikes anywhere, NEST's
    # GetStatus of every connection every 0.5 ms.
    rng = np.random.default_rng(13)
    t_sim = 150.0
    pres = [dense(rng, t_sim, 40) for _ in range(n_pre)]
    posts = [dense(rng, t_sim, 30) for _ in range(n_post)]
    dopa = dense(rng, t_sim - 2, 20)
    params = {"tau_c": 200.0, "tau_n": 30.0, "b": 0.01, "Wmax": 11.0, "Wmin": 9.5}
    n_steps = int(round(t_sim / H))
    record = list(range(3, n_steps + 1, 5))
    w, c = nest_group(params, pres, posts, dopa, w0=10.0, t_sim=t_sim, record=record, deliver_interval=deliver_interval)
    pre_steps, post_steps = {}, {}
    for i, ts in enumerate(pres):
        for t in ts:
            pre_steps.setdefault(int(round(t / H)), np.zeros(n_pre))[i] += 1
    for j, ts in enumerate(posts):
        for t in ts:
            post_steps.setdefault(int(round(t / H)), np.zeros(n_post))[j] += 1
    ws, cs, _ = drive(
        rstdp_params(**params, dtype=jnp.float64),
        pre_steps,
        post_steps,
        n_steps,
        n_pre=n_pre,
        n_post=n_post,
        dopa_steps=[int(round((t + D) / H)) for t in dopa],
        schedule="nest",
        deliver_interval=deliver_interval,
    )
    at = np.array(record) - 1
    compare(ws[at], w, "w")
    compare(cs[at], c, "c")
    assert np.any(w == 11.0) or np.any(w == 9.5)


def test_pruned_post_history_is_not_read_twice(x64):
    # deliver_interval 2: triggers at 22 and 24 ms. The pre spike of 21.2 ms is delivered after the trigger
    # at 22 ms, so the trigger at 24 ms reads the post spikes of 20.3 and 20.5 ms (arriving at 21.3, 21.5)
    # again; but the post spike at 23.3 ms has pruned 20.3 ms from the history (read once, and 20.5 ms is
    # more than max_delay + min_delay older), so only 20.5 ms is paired a second time.
    pre, post = [15.0, 21.2], [20.3, 20.5, 23.3]
    steps, w, c, n = nest_run({}, pre, post, [], w0=10.0, t_sim=30.0, deliver_interval=2)
    _, rw, rc, _ = replay({}, pre, post, [], w0=10.0, t_sim_ms=30.0, deliver_interval=2)
    compare(rc[steps - 1], c, "c")
    # No post spike before 21.2 - 1 ms: the pre spike of 21.2 ms does not depress.
    k_21_3, k_21_5 = math.exp(-(21.3 - 15.0) / 20.0), math.exp(-(21.5 - 15.0) / 20.0)  # at the trigger of 22 ms
    again = (math.exp(-(21.2 - 15.0) / 20.0) + 1.0) * math.exp(-(21.5 - 21.2) / 20.0)  # 20.5 ms, with 21.2 ms
    # c of the trigger at 22 ms, integrated back to 21.2 ms, then forward to 24 ms with the second pairing.
    expected = (k_21_3 * math.exp(-0.2 / 1000.0) + k_21_5 + again) * math.exp(-(24.0 - 21.5) / 1000.0)
    assert c[int(round(24.0 / H)) - 1] == pytest.approx(expected, rel=1e-9)
    ws, cs, _ = drive(
        rstdp_params(dtype=jnp.float64),
        {150: [1.0], 212: [1.0]},
        {203: [1.0], 205: [1.0], 233: [1.0]},
        300,
        schedule="nest",
        deliver_interval=2,
    )
    compare(cs[steps - 1, 0, 0], c, "c")
