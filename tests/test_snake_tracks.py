"""Target tracks: closed-form geometry, mirror images, the 8's alternation, the target's motion rule, Eq. (12)."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from robots.snake import tracks
from spikejax.errors import UserError


def _points(track, s):
    return np.asarray(jax.vmap(lambda v: tracks.point(track, v))(jnp.asarray(s, jnp.float32)))


@pytest.mark.parametrize("name", tracks.TRACKS)
def test_tracks_start_at_spawn_point_and_have_unit_speed(name):
    track = tracks.get(name)
    np.testing.assert_allclose(tracks.point(track, 0.0), [tracks.START[0] + tracks.SPAWN_DISTANCE, 0.0], atol=1e-6)
    assert float(tracks.heading(track, 0.0)) == 0.0
    s = np.linspace(0.0, 150.0, 3001)
    p = _points(track, s)
    step = np.linalg.norm(np.diff(p, axis=0), axis=1)
    # Chords of a unit-speed curve: at most ds, and no jumps at segment joints.
    np.testing.assert_allclose(step, s[1] - s[0], rtol=2e-3, atol=2e-5)
    # The heading is the direction of motion.
    mid = 0.5 * (s[1:] + s[:-1])
    th = np.asarray(jax.vmap(lambda v: tracks.heading(track, v))(jnp.asarray(mid, jnp.float32)))
    direction = np.diff(p, axis=0) / step[:, None]
    np.testing.assert_allclose(direction, np.stack([np.cos(th), np.sin(th)], 1), atol=5e-3)  # float32 arc length


def test_eight_lobes_are_circles_through_the_origin():
    r = tracks.TURN_RADIUS
    track = tracks.eight()
    lobe = 2 * math.pi * r
    s1 = tracks.LEAD_IN + np.linspace(0.0, lobe, 50)
    s2 = tracks.LEAD_IN + lobe + np.linspace(0.0, lobe, 50)
    np.testing.assert_allclose(np.linalg.norm(_points(track, s1) - [0.0, r], axis=1), r, atol=1e-4)
    np.testing.assert_allclose(np.linalg.norm(_points(track, s2) - [0.0, -r], axis=1), r, atol=1e-4)
    # Top of the first lobe after half a turn; back through the origin after each lobe.
    np.testing.assert_allclose(tracks.point(track, tracks.LEAD_IN + 0.5 * lobe), [0.0, 2 * r], atol=1e-4)
    for k in range(1, 6):
        np.testing.assert_allclose(tracks.point(track, tracks.LEAD_IN + k * lobe), [0.0, 0.0], atol=2e-3)


@pytest.mark.parametrize("base", ["eight", "ladder", "zigzag"])
def test_mirror_image_is_the_reflection_about_the_x_axis(base):
    s = np.linspace(0.0, 80.0, 400)
    p, q = _points(tracks.get(base), s), _points(tracks.get(base + "-mirror"), s)
    np.testing.assert_allclose(q, p * [1.0, -1.0], atol=1e-5)
    assert p[:, 1].max() > 2.0  # the curve does leave the axis


def test_training_track_alternates_direction_each_episode():
    first_lobe = tracks.LEAD_IN + 0.25 * 2 * math.pi * tracks.TURN_RADIUS  # a quarter round the first lobe
    ys = [float(tracks.point(tracks.training_track(e), first_lobe)[1]) for e in range(4)]
    assert ys[0] == pytest.approx(tracks.TURN_RADIUS, abs=1e-4)  # counter-clockwise: goes left first
    assert ys[1] == pytest.approx(-tracks.TURN_RADIUS, abs=1e-4)  # clockwise: goes right first
    assert ys[2] == ys[0] and ys[3] == ys[1]


def test_ladder_steps_and_zigzag_legs():
    r = tracks.TURN_RADIUS
    ladder = tracks.ladder(rung=2.0, run=3.0)
    unit = math.pi * r + 5.0
    for k in range(1, 4):  # after k steps: heading +x again, k * (2r + rung) higher, k * (2r + run) further
        s = tracks.LEAD_IN + k * unit
        np.testing.assert_allclose(tracks.point(ladder, s), [k * (2 * r + 3.0), k * (2 * r + 2.0)], atol=2e-3)
        assert float(tracks.heading(ladder, s)) == pytest.approx(0.0, abs=1e-5)
    zig = tracks.zigzag(leg=4.0)
    eighth = 0.25 * math.pi * r
    assert float(tracks.heading(zig, tracks.LEAD_IN + eighth + 2.0)) == pytest.approx(math.pi / 4, abs=1e-5)
    assert float(tracks.heading(zig, tracks.LEAD_IN + 3 * eighth + 6.0)) == pytest.approx(-math.pi / 4, abs=1e-5)
    ys = _points(zig, np.linspace(tracks.LEAD_IN, 300.0, 2000))[:, 1]
    peak = 2 * r * (1 - math.cos(math.pi / 4)) + 4.0 * math.sin(math.pi / 4)
    assert ys.max() == pytest.approx(peak, abs=1e-2) and ys.min() > -1e-3  # bounded, never drifts


def test_target_never_moves_farther_than_the_initial_distance():
    track = tracks.get("eight")

    # A snake that follows the track 1.6 m behind at first, more slowly than the target, then stops.
    def step(s_target, i):
        s_snake = -tracks.SPAWN_DISTANCE + 0.2 * 0.02 * jnp.minimum(i, 2000)
        behind = jnp.array([tracks.START[0], 0.0]) + jnp.array([s_snake + tracks.SPAWN_DISTANCE, 0.0])
        head = jnp.where(s_snake > 0, tracks.point(track, s_snake), behind)
        new = tracks.advance(track, s_target, head, 0.3, 0.02)
        return new, (new > s_target, jnp.linalg.norm(tracks.point(track, new) - head))

    _, (moved, distance) = jax.lax.scan(step, jnp.float32(0.0), jnp.arange(1, 3001))
    assert float(distance.max()) <= tracks.SPAWN_DISTANCE + 1e-6
    assert 0.2 * 2000 / 0.3 < int(moved.sum()) < 2000  # it moved at its own speed, and waited for the snake


def test_target_waits_for_a_snake_that_does_not_move():
    track = tracks.get("ladder")
    head = jnp.asarray(tracks.START)
    s = 0.0
    for _ in range(50):
        s = tracks.advance(track, s, head, 0.3, 0.02)
    assert float(s) == 0.0


def test_target_angles_by_hand():
    head, forward = jnp.zeros(2), jnp.array([1.0, 0.0])
    a_head, a_body = tracks.target_angles(head, forward, jnp.array([2.0, 0.0]), 0.0)
    assert float(a_head) == 0.0 and float(a_body) == 0.0
    a_head, _ = tracks.target_angles(head, forward, jnp.array([1.0, -1.0]), 0.0)  # ahead and to the right
    assert float(a_head) == pytest.approx(math.pi / 4)
    a_head, _ = tracks.target_angles(head, forward, jnp.array([-1.0, 1.0]), 0.0)  # behind, to the left
    assert float(a_head) == pytest.approx(-3 * math.pi / 4)
    # The head turned 0.3 rad left: a target straight ahead of the body is 0.3 rad right of the head (Eq. 12).
    turned = jnp.array([math.cos(0.3), math.sin(0.3)])
    a_head, a_body = tracks.target_angles(head, turned, jnp.array([2.0, 0.0]), 0.3)
    assert float(a_head) == pytest.approx(0.3, abs=1e-6) and float(a_body) == pytest.approx(0.0, abs=1e-6)


def test_unknown_track_is_a_user_error():
    with pytest.raises(UserError, match="unknown track 'spiral'"):
        tracks.get("spiral")


@pytest.mark.parametrize("base", ["eight", "ladder", "zigzag"])
def test_drawn_tracks_end_where_their_units_do(base):
    r = tracks.TURN_RADIUS
    units = {
        "eight": 4 * math.pi * r,
        "ladder": tracks.LADDER_STEPS * (math.pi * r + 2.0 + 3.0),
        "zigzag": tracks.ZIGZAG_PERIODS * (math.pi * r + 8.0),
    }
    assert tracks.drawn_length(base) == pytest.approx(tracks.LEAD_IN + units[base], rel=1e-5)
    assert tracks.drawn_length(base + "-mirror") == pytest.approx(tracks.drawn_length(base), rel=1e-6)
    # the drawn 8 closes on itself: its end is the crossing at the origin
    if base == "eight":
        np.testing.assert_allclose(tracks.point(tracks.get("eight", drawn=True), 1e6), [0.0, 0.0], atol=2e-3)


def test_waypoints_are_placed_ahead_of_the_snake_along_their_first_segment():
    # first segment along +y, then a right turn along +x: placed along +x, then turning right (to -y)
    track = tracks.from_waypoints([[1.0, 1.0], [1.0, 3.0], [3.0, 3.0]])
    spawn = np.array([tracks.START[0] + tracks.SPAWN_DISTANCE, 0.0])
    np.testing.assert_allclose(tracks.point(track, 0.0), spawn, atol=1e-6)
    np.testing.assert_allclose(tracks.point(track, 2.0), spawn + [2.0, 0.0], atol=1e-5)
    np.testing.assert_allclose(tracks.point(track, 3.0), spawn + [2.0, -1.0], atol=1e-5)
    assert float(track.length) == pytest.approx(4.0)
    assert float(tracks.heading(track, 3.0)) == pytest.approx(-math.pi / 2, abs=1e-6)


def test_waypoint_files_read_and_bad_ones_get_one_line_errors(tmp_path):
    good = tmp_path / "t.csv"
    good.write_text("x,y\n0,0\n2,0\n2,2\n")
    assert float(tracks.load_waypoints(good).length) == pytest.approx(4.0)
    cases = {
        "x,y\n0,0\n": "at least two",
        "x,y\n0,0\n1,a\n": "line 3",
        "0,0,1\n1,1,1\n": "two columns",
        "0,0\n0,0\n1,1\n": "coincide",
        "0,0\nnan,1\n": "finite",
    }
    for i, (text, words) in enumerate(cases.items()):
        bad = tmp_path / f"bad{i}.csv"
        bad.write_text(text)
        with pytest.raises(UserError, match=words) as e:
            tracks.load_waypoints(bad)
        assert "\n" not in str(e.value) and str(bad) in str(e.value)
    with pytest.raises(UserError, match="cannot read"):
        tracks.load_waypoints(tmp_path / "missing.csv")
