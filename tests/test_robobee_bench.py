"""The closed-loop RoboBee benchmark: Brian2 (runtime, NumPy target) and spikejax fly the same algorithm.

Nothing here is timed; the benchmark itself is `robots.robobee.bench.run`; the peer is `robots.robobee.peers`.
"""

from __future__ import annotations

import csv
import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from robots.robobee import bench, peers
from robots.robobee.controller import controller_init, controller_step
from robots.robobee.dynamics import clip_controls, rhs
from robots.robobee.params import robobee_params
from spikejax.coding import antagonist_currents, shift_scale

b2 = pytest.importorskip("brian2")

SEED = 0
DURATION = 0.05  # s: 500 steps, hold 100, two segments of 200


@pytest.fixture(autouse=True)
def numpy_target():
    """Brian2's NumPy target: no Cython build in the tests."""
    old = b2.prefs.codegen.target
    b2.prefs.codegen.target = "numpy"
    yield
    b2.prefs.codegen.target = old


@functools.cache
def brian2_flight() -> dict:
    b2.prefs.codegen.target = "numpy"
    return bench.run_brian2_closed_loop(DURATION, SEED, "numpy")


@functools.cache
def spikejax_flight() -> dict:
    return bench.run_spikejax_flights(2, DURATION, SEED)


def test_flight_plan_scales_with_the_duration():
    assert bench.flight_steps(2.5) == (5000, 10000)  # the paper's 0.5 s hold and 1 s legs
    assert bench.flight_steps(DURATION) == (100, 200)
    with pytest.raises(ValueError):
        bench.flight_steps(1e-3)


def test_brian2_simulates_spikejax_flight_0_network():
    setup = bench.flight_setup(1, SEED)
    flight = peers.Brian2Flight(setup.keys[0], 100, 200)
    state = flight.state0
    for syn, mask, w in zip(flight.synapses, (state.mask_ih, state.mask_ho), (state.w_ih, state.w_ho)):
        i, j = np.nonzero(mask)
        np.testing.assert_array_equal(np.asarray(syn.i[:]), i)
        np.testing.assert_array_equal(np.asarray(syn.j[:]), j)
        np.testing.assert_array_equal(np.asarray(syn.w[:]), w[i, j])
    for g, v_th in zip(flight.groups, (state.v_th_input, state.v_th_hidden, state.v_th_output)):
        np.testing.assert_array_equal(np.asarray(g.v_th[:]), v_th)
    # About 30 % connectivity, as in the paper.
    assert 0.25 < len(flight.synapses[0]) / (200 * 100) < 0.35
    flight.run(10)
    assert flight.k == 10 and len(flight.recording()["t"]) == 1


def test_brian2_encoder_is_the_antagonist_encoder_of_the_library():
    # The peer keeps the encoder as float64 slopes and offsets; they are spikejax.coding's encoder.
    setup = bench.flight_setup(1, SEED)
    flight = peers.Brian2Flight(setup.keys[0], 0, 10)
    cp, n_per = setup.cparams, setup.config.n_per_input
    for e in (np.zeros(4), np.array([0.3, -0.2, 0.05, -0.01])):
        ours = antagonist_currents(shift_scale(jnp.asarray(e, jnp.float32), cp.a, cp.b), n_per, cp.input_gain)
        np.testing.assert_allclose(flight.offset + flight.slope * e[flight.group], ours, rtol=1e-6, atol=1e-6)


def test_brian2_physics_is_the_semi_implicit_euler_step_of_rhs():
    # MuJoCo's integrator; tests/test_robobee_robot.py checks the MJX model against rhs.
    setup = bench.flight_setup(1, SEED)
    flight = peers.Brian2Flight(setup.keys[0], 0, 10)
    robot = jax.tree.map(np.float64, robobee_params())
    for q, lift, torque in (
        ((0.3, -2.0, 0.01, 0.05, 0.2, -0.1), 9e-4, 5e-7),
        ((-0.6, 0.0, 0.0, 0.02, 0.0, 0.0), 2e-3, -3e-6),  # both commands clipped
        ((0.0, 0.0, 0.0, 1e-6, 0.0, -0.5), 0.0, 0.0),
    ):  # onto the floor
        flight.q = q
        flight._physics(lift, torque)
        f_lift, tau_c = clip_controls(robot, lift, torque)
        qd = rhs(np.asarray(q), robot, f_lift, tau_c)
        vel = np.asarray(q)[[1, 4, 5]] + flight.dt * qd[[1, 4, 5]]
        pos = np.asarray(q)[[0, 2, 3]] + flight.dt * vel
        expected = np.array([pos[0], vel[0], pos[1], pos[2], vel[1], vel[2]])
        if expected[3] < 0:
            expected[3], expected[5] = 0.0, max(expected[5], 0.0)
        np.testing.assert_allclose(flight.q, expected, rtol=1e-12, atol=1e-15)
    flight.run(10)


def test_same_spikes_with_learning_off_and_the_robot_held():
    """Learning off, the robot held at q0 for 50 ms: Brian2 and `controller_step` fire the same spikes."""
    setup = bench.flight_setup(1, SEED)
    n_steps = 500
    flight = peers.Brian2Flight(setup.keys[0], hold_steps=n_steps, segment_steps=10, learn=False)
    flight.run(n_steps)
    cp = setup.cparams
    n_ref = round(float(cp.t_ref) / float(cp.dt))

    @jax.jit
    def counts():
        state = controller_init(setup.config, cp, key=setup.keys[0])
        # Held at q0 with target q0: zero lateral error, the teacher's output 0.
        e = jnp.zeros(4)

        def step(state, _):
            state, _ = controller_step(setup.config, cp, state, e, jnp.float32(0.0), jnp.float32(0.0))
            # A neuron that fires starts its refractory count at n_ref - 1.
            fired = [s.refractory == n_ref - 1 for s in (state.input, state.hidden, state.output)]
            return state, jnp.concatenate(fired).astype(jnp.int32)

        _, fired = jax.lax.scan(step, state, None, length=n_steps)
        return fired.sum(0)

    spikejax_counts = np.asarray(counts())
    brian2_counts = flight.counts
    for sl in (slice(0, 200), slice(200, 300), slice(300, 350)):
        assert brian2_counts[sl].sum() > 0
    np.testing.assert_array_equal(brian2_counts, spikejax_counts)


@pytest.mark.slow  # about 25 s; Brian2's network against ours stays in the suite (flight 0 above)
def test_brian2_and_spikejax_fly_the_same_closed_loop():
    """Hold, then toward q1 and q2, learning online: the same outputs, teacher and robot state."""
    brian2, jx = brian2_flight(), spikejax_flight()
    rec_b, rec_j = brian2["recording"], jx["recording"]
    np.testing.assert_allclose(rec_b["t"], rec_j.t[0], rtol=1e-6)
    np.testing.assert_allclose(rec_b["target"], rec_j.target[0], atol=1e-7)
    # float64 against float32: the spike trains are the same, the numbers agree to float32 precision.
    np.testing.assert_allclose(rec_b["y_hat"], rec_j.y_hat[0], atol=1e-4)
    np.testing.assert_allclose(rec_b["y_lqr"], rec_j.y_lqr[0], atol=1e-4)
    scale = np.abs(rec_b["q"]).max(axis=0) + 1e-9
    np.testing.assert_allclose(rec_b["q"] / scale, rec_j.q[0] / scale, atol=1e-4)
    # The robot moved (the teacher asked for torque and the SNN gave it), and learning changed the weights.
    assert np.abs(rec_b["y_hat"]).max() > 0.5
    assert np.ptp(rec_b["q"][:, 0]) > 0.05
    setup = bench.flight_setup(1, SEED)
    state0 = controller_init(setup.config, setup.cparams, key=setup.keys[0])
    w0, mask = np.asarray(state0.w_ih), np.asarray(state0.mask_ih)
    assert np.abs(brian2["w_ih"] - w0).max() > 1e-3
    assert np.all(brian2["w_ih"][mask == 0] == 0)


@pytest.mark.slow  # 22 s, a flight's compile: the bench's rows; its peer checks stay in the fast suite
def test_rows_report_throughput_for_the_full_flight():
    brian2, jx = brian2_flight(), spikejax_flight()
    # Brian2 is timed on 0.05 s and extrapolated to a 2.5 s flight; spikejax flew whole 0.05 s flights.
    for row, batch, flight_s in ((brian2, 1, bench.FLIGHT_S), (jx, 2, DURATION)):
        assert set(bench.ROW_FIELDS) <= set(row)
        assert row["batch"] == batch and row["flight_s"] == flight_s
        assert row["timed_s"] == pytest.approx(DURATION)
        assert row["sim_s_per_wall_s"] == pytest.approx(row["flights_per_s"] * flight_s)
        assert row["neuron_updates_per_s"] == pytest.approx(row["flights_per_s"] * 350 * round(flight_s / 1e-4))
    # The second flight has its own network.
    assert not np.allclose(jx["recording"].y_hat[0], jx["recording"].y_hat[1])
    # Whole flights fly within 5 mm of both waypoints or not: a fraction.
    assert 0.0 <= jx["reached_q1"] <= 1.0 and 0.0 <= jx["reached_q2"] <= 1.0


def test_large_batches_time_shorter_flights():
    assert bench.timed_duration(16, 2.5) == pytest.approx(2.5)
    assert bench.timed_duration(1024, 2.5) == pytest.approx(0.625)  # 256 x 2.5 s of flight-steps
    assert bench.timed_duration(1024, 2.5, step_budget=1000) == pytest.approx(0.05)  # the floor


@pytest.mark.slow  # ~15 s: the bench end to end; its peer checks stay in the fast suite
def test_main_writes_the_closed_loop_table(tmp_path, capsys):
    assert (
        bench.run(
            trials=1,
            out=str(tmp_path),
            duration=DURATION,
            brian2_target="numpy",
            network=False,
            cpu_devices=1,
            repeats=1,
            no_progress=True,
        )
        == 0
    )
    out = capsys.readouterr().out
    assert "| Brian2 runtime (numpy) + network_operation | 1 |" in out
    with open(tmp_path / "bench_robobee.csv") as file:
        rows = list(csv.DictReader(file))
    assert [(r["impl"].split()[0], int(r["batch"])) for r in rows] == [("Brian2", 1), ("spikejax", 1)]
    assert float(rows[0]["x_brian2"]) == 1.0
    assert [(r["cores"], r["parallel"]) for r in rows] == [("1", "1 process"), ("1", "1 device, held to 1 core")]
    assert all(float(r["flights_per_s"]) > 0 for r in rows)


_TWO_DEVICES = """
import csv, sys
import numpy as np
from spikejax.devices import use_cpu_devices
use_cpu_devices(2)
from robots.robobee import bench
one = bench.run_spikejax_flights(3, {duration}, {seed}, devices=1)
two = bench.run_spikejax_flights(3, {duration}, {seed}, devices=2)  # 3 flights over 2 devices: padded to 4
assert two["devices"] == 2 and two["impl"].endswith(", 2 devices"), two["impl"]
for a, b in zip(one["recording"], two["recording"]):
    np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-7)
out = sys.argv[1]
bench.run(trials=2, out=out, duration={duration}, brian2_target="numpy", network=False, repeats=1, no_progress=True)
with open(out + "/bench_robobee.csv") as f:
    rows = list(csv.DictReader(f))
held = "1 device, held to 1 core"
assert [(r["cores"], r["parallel"]) for r in rows] == [("1", "1 process"), ("2", "2 processes"), ("1", held),
                                                      ("1", held), ("2", "2 devices")]
print([(r["impl"], r["batch"], r["devices"], r["x_brian2"], r["x_brian2_all_cores"]) for r in rows])
"""


@pytest.mark.slow  # ~70 s: two fresh processes; device equality of flights is also in tests/test_devices.py
def test_two_cpu_devices_fly_the_same_flights_and_brian2_runs_on_both_cores(tmp_path):
    """Flights split over 2 CPU devices equal those on one; the table adds Brian2 on both cores and split rows."""
    import ast
    import subprocess
    import sys

    script = _TWO_DEVICES.format(duration=DURATION, seed=SEED)
    run = subprocess.run([sys.executable, "-c", script, str(tmp_path)], capture_output=True, text=True, timeout=900)
    assert run.returncode == 0, run.stderr[-3000:]
    rows = ast.literal_eval(run.stdout.strip().splitlines()[-1])
    assert [(impl.split()[0], batch, devices) for impl, batch, devices, _, _ in rows] == [
        ("Brian2", "1", "1"),
        ("Brian2", "2", "1"),
        ("spikejax", "1", "1"),
        ("spikejax", "2", "1"),
        ("spikejax", "2", "2"),
    ]
    assert rows[1][0].endswith("2 processes at once") and rows[4][0].endswith(", 2 devices")
    # Each row against one Brian2 flight and against two side by side.
    assert float(rows[0][3]) == 1.0 and float(rows[1][4]) == 1.0
    for _, _, _, x_one, x_all in rows:
        assert float(x_all) == pytest.approx(float(x_one) * float(rows[0][4]))
