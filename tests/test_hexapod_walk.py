"""The hexapod walking on CPG spikes: the step primitive (`robots.hexapod.legs`) and MuJoCo C walks (`robots.hexapod.physics`)."""

import jax.numpy as jnp
import numpy as np
import pytest

from robots.hexapod import physics
from robots.hexapod.gaits import PATTERNS, PERIOD
from robots.hexapod.legs import servo_targets, step_params
from spikejax.errors import UserError


def test_the_step_primitive_gives_the_hand_computed_servo_targets():
    p = step_params(amplitude=0.3, lift=0.5, dt_cpg=0.2)
    a, lift, dt = 0.3, 0.5, 0.2
    raster = np.zeros((4, 6), np.float32)
    raster[[0, 2], 0] = 1  # L1 fires at steps 0 and 2
    raster[[0, 1], 4] = 1  # R2 fires at steps 0 and 1 (the second spike comes at the start of its stance)
    t = jnp.asarray([0.5, 1.0, 1.5, 2.0, 2.5, 3.5, 5.0]) * dt
    ctrl = np.asarray(servo_targets(p, jnp.asarray(raster), t)).reshape(len(t), 6, 2)
    hip_l1, lift_l1 = ctrl[:, 0, 0], ctrl[:, 0, 1]
    # Swing from rest (0 -> +A, raised cosine: A/2 halfway), the foot at L at mid-swing; stance +A -> -A; hold -A;
    # the second swing from -A (0 halfway), then stance again, then hold.
    np.testing.assert_allclose(hip_l1, [a / 2, a, 0.0, -a, 0.0, 0.0, -a], atol=1e-6)
    np.testing.assert_allclose(lift_l1, [lift, 0.0, 0.0, 0.0, lift, 0.0, 0.0], atol=1e-6)
    # R2's second swing starts at +A, where its stance would have begun, and stays there.
    np.testing.assert_allclose(ctrl[:3, 4, 0], [a / 2, a, a], atol=1e-6)
    np.testing.assert_allclose(ctrl[2, 4, 1], lift, atol=1e-6)
    # Legs that never fire stay planted at neutral.
    assert np.all(ctrl[:, [1, 2, 3, 5]] == 0.0)


@pytest.fixture(scope="module")
def walks():
    """Each gait for 10 cycles on 8 robots randomised in friction (+-30 %), mass and servo gain (+-20 %)."""
    models = [physics.load_model(*d) for d in physics.randomised(8, seed=1)]
    p = step_params()
    n_cycles = 10
    t = jnp.arange(int(round(n_cycles * PERIOD * float(p.dt_cpg) / 0.002))) * 0.002
    out = []
    for g in range(3):
        raster = jnp.asarray(PATTERNS[g][np.arange(n_cycles * PERIOD) % PERIOD])
        out.append(physics.walk(models, np.asarray(servo_targets(p, raster, t)), nthread=2))
    return out


def test_the_gaits_walk_as_named(walks):
    """G1 forward without turning; G2 turns left (counter-clockwise), G3 right, mirror images of each other."""
    g1, g2, g3 = walks
    d1 = g1.xy[:, -1] - g1.xy[:, 0]
    assert np.all(d1[:, 0] > 0.5)
    assert np.all(np.abs(np.degrees(g1.yaw[:, -1] - g1.yaw[:, 0])) / np.hypot(*d1.T) < 5.0)
    yaw2, yaw3 = (np.degrees(g.yaw[:, -1] - g.yaw[:, 0]) for g in (g2, g3))
    assert np.all(yaw2 > 45) and np.all(yaw3 < -45)
    np.testing.assert_allclose(np.abs(yaw2), np.abs(yaw3), rtol=0.05)
    for g in walks:
        assert np.degrees(np.abs(g.roll).max()) < 20 and np.degrees(np.abs(g.pitch).max()) < 20
        assert g.height.min() > 0.04  # the torso (half-height 0.02 m) never touches the floor


def test_bad_robots_are_one_line_errors():
    with pytest.raises(UserError, match="friction"):
        physics.load_model(friction=0.0)
    with pytest.raises(UserError, match="controls"):
        physics.walk([physics.load_model()], np.zeros((10, 5)))


def test_the_walk_command_writes_a_gait_table_from_trained_networks(tmp_path, capsys):
    import csv

    from robots.hexapod.reproduce_walk import HEADER, run, trained_rasters

    # A converged network's rasters are the gaits' patterns (Fig. 2), step for step.
    rasters = trained_rasters(3, 6, seed=2)
    for g in range(3):
        np.testing.assert_array_equal(rasters[:, g], np.broadcast_to(PATTERNS[g][np.arange(6) % PERIOD], (3, 6, 6)))
    assert run(out=tmp_path, robots=3, cycles=3, seed=2) == 0
    with open(tmp_path / "gait_table.csv") as f:
        rows = list(csv.reader(f))
    assert rows[0] == HEADER
    table = {(r[0], r[2]): float(r[3]) for r in rows[1:]}
    assert table[("G1 tripod", "speed_m_per_s")] > 0.1
    assert table[("G2 left turn", "turn_deg_per_s")] > 10 > -10 > table[("G3 right turn", "turn_deg_per_s")]
    for r in rows[1:]:
        if r[4]:
            assert float(r[4]) <= float(r[3]) <= float(r[5])
    assert (tmp_path / "walk_trajectories.png").stat().st_size > 10_000


def test_mjx_walks_as_mujoco_c():
    """Two cycles of G1 and G2 on MJX and on MuJoCo C: the torso within 1 cm and 2 deg (it compiles in seconds)."""
    model = physics.load_model()
    p = step_params()
    t = jnp.arange(320) * 0.002
    ctrl = np.stack([np.asarray(servo_targets(p, jnp.asarray(PATTERNS[g][np.arange(8) % PERIOD]), t)) for g in (0, 1)])
    ours = physics.mjx_walk(model, ctrl)
    c = physics.walk([model, model], ctrl, nthread=1)
    assert np.abs(ours.xy - c.xy).max() < 0.01
    assert np.degrees(np.abs(ours.yaw - c.yaw).max()) < 2.0
    assert c.xy[0, -1, 0] > 0.1 and np.degrees(c.yaw[1, -1]) > 10
