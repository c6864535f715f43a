"""The predator-prey task's scenes and truth (`robots.hexapod.prey`)."""

import argparse
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from robots.hexapod import prey
from robots.hexapod import reproduce_decisions as rd
from robots.hexapod.vision import FORWARD, LEFT, RIGHT
from spikejax.errors import UserError

SCENE = """
[robot]
x = 0.0
y = 0.0
yaw_deg = 0.0

[[prey]]
x = 1.5
y = 0.4
size = 0.1

[[prey]]
x = 0.5
y = -0.2
size = 0.2
"""


def test_a_scene_file_loads_into_fixed_slots(tmp_path):
    path = tmp_path / "scene.toml"
    path.write_text(SCENE)
    s = prey.load_scene(path)
    np.testing.assert_allclose(np.asarray(s.prey[:2]), [[1.5, 0.4], [0.5, -0.2]])
    np.testing.assert_allclose(np.asarray(s.size[:2]), [0.1, 0.2])
    assert np.asarray(s.alive).tolist() == [True, True, False, False]
    slot, dist, bearing = prey.nearest(s, s.start)
    assert int(slot) == 1 and float(dist) == pytest.approx(math.hypot(0.5, 0.2))
    assert float(bearing) == pytest.approx(math.atan2(-0.2, 0.5))


@pytest.mark.parametrize(
    "text, words",
    [
        ("[robot]\nx = 0\ny = 0\n", "yaw_deg"),
        (SCENE.replace("size = 0.2", "size = -1"), "size"),
        (SCENE.replace("size = 0.2", 'size = "big"'), "finite number"),
        (SCENE.replace("[robot]", "[robots]"), "unknown section"),
        (SCENE.replace("x = 0.5", "x = 0.05").replace("y = -0.2", "y = 0.0"), "start"),
        (SCENE.replace("size = 0.1", "size = 0.1\ncolour = 1"), "only the keys"),
        ("[robot\n", "not a TOML"),
        (SCENE + "".join("\n[[prey]]\nx = 2.0\ny = %d\nsize = 0.1\n" % i for i in range(3)), "at most 4"),
    ],
)
def test_bad_scene_files_are_one_line_errors(tmp_path, text, words):
    path = tmp_path / "scene.toml"
    path.write_text(text)
    with pytest.raises(UserError, match=words) as info:
        prey.load_scene(path)
    assert "\n" not in str(info.value)


def test_sampled_scenes_keep_their_ranges_and_gaps_and_depend_only_on_the_key():
    keys = jax.random.split(jax.random.key(0), 512)
    n = jnp.asarray(np.arange(512) % 4 + 1)
    scenes = jax.jit(jax.vmap(prey.sample_scene))(keys, n)
    alive = np.asarray(scenes.alive)
    assert (alive.sum(1) == np.asarray(n)).all()
    xy = np.asarray(scenes.prey)
    d, b = np.hypot(xy[..., 0], xy[..., 1]), np.degrees(np.arctan2(xy[..., 1], xy[..., 0]))
    assert (d[alive] >= 0.8 - 1e-6).all() and (d[alive] <= 2.5 + 1e-6).all() and (np.abs(b[alive]) <= 20 + 1e-4).all()
    gaps = np.linalg.norm(xy[:, :, None] - xy[:, None], axis=-1)
    pair = alive[:, :, None] & alive[:, None] & ~np.eye(4, dtype=bool)
    assert (gaps[pair] >= 0.3 - 1e-6).mean() > 0.999
    again = prey.sample_scene(keys[7], n[7])
    for a, b_ in zip(jax.tree.leaves(again), jax.tree.leaves(jax.tree.map(lambda x: x[7], scenes))):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b_))


def test_near_distance_is_the_pinhole_boundary():
    """The reading notes' examples: 1.11 m, 0.37 m when tilted 10 deg, 0.96 m at 0.15 m and 90 deg."""
    assert prey.near_distance(0.10, 0, 60, 1280, 100) == pytest.approx(1.1085, abs=1e-4)
    assert prey.near_distance(0.10, 10, 60, 1280, 100) == pytest.approx(0.3692, abs=1e-4)
    assert prey.near_distance(0.15, 0, 90, 1280, 100) == pytest.approx(0.96, abs=1e-9)
    with pytest.raises(UserError, match="horizon"):
        prey.near_distance(0.1, -20, 60, 1280, 100)


def test_the_truth_rule_and_capture():
    s = prey.PreyScene(
        jnp.zeros(3),
        jnp.asarray([[2.0, 0.5], [0.6, -0.3], [0.5, 0.1], [9.0, 9.0]]),
        jnp.full(4, 0.1),
        jnp.asarray([True, True, False, False]),
    )
    pose = jnp.zeros(3)
    # The nearest living prey (slot 1, at 0.67 m, to the right) is near at d_near = 1 m, far at 0.5 m.
    assert int(prey.truth_gait(s, pose, 1.0)) == RIGHT
    assert int(prey.truth_gait(s, pose, 0.5)) == FORWARD
    # Facing it: captured; turned away by 30 deg: not.
    facing = jnp.asarray([0.0, 0.0, math.atan2(-0.3, 0.6)])
    assert bool(prey.captured(s, facing, 0.6)) and not bool(prey.captured(s, facing + jnp.asarray([0, 0, 0.52]), 0.6))
    # Removing it hands the choice to the next: far and to the left.
    gone = s._replace(alive=jnp.asarray([True, False, False, False]))
    assert int(prey.truth_gait(gone, pose, 1.0)) == FORWARD and int(prey.truth_gait(gone, pose, 2.5)) == LEFT
    none = s._replace(alive=jnp.zeros(4, bool))
    assert int(prey.nearest(none, pose)[0]) == -1 and int(prey.truth_gait(none, pose, 1.0)) == FORWARD


def test_the_reproduction_draws_empty_arenas_and_takes_the_prey_size():
    both = jax.jit(lambda i: (rd.scenes(0, i), rd.scenes(0, i, 0, 0.1)))
    default, empty = both(jnp.int32(5))
    assert np.asarray(default.alive).sum() == 2  # 1 + 5 % 4 prey by default
    np.testing.assert_allclose(np.asarray(default.size), prey.PREY_SIZE)
    assert not np.asarray(empty.alive).any()  # an empty arena: the truth keeps walking
    np.testing.assert_allclose(np.asarray(empty.size), 0.1)
    assert int(jax.jit(prey.truth_gait)(empty, jnp.zeros(3), 10.0)) == FORWARD
    parser = argparse.ArgumentParser()
    rd.command.add_arguments(parser)
    args = parser.parse_args(["--out", "x", "--empty", "0", "--full-check", "64", "--prey-size", "0.1"])
    assert (args.empty_n, args.full_check, args.prey_size, args.scenes_n) == (0, 64, 0.1, 2000)
    for bad in (["--empty", "-1"], ["--full-check", "x"], ["--prey-size", "0"], ["--prey-size", "2"]):
        with pytest.raises(SystemExit):
            parser.parse_args(["--out", "x", *bad])
