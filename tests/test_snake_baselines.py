"""``reproduce snake-baselines``: the scripted controller through the common test, and the whole command at small size."""

from __future__ import annotations

import csv

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from robots.snake import env as snake_env
from robots.snake import steering, training
from robots.snake.reproduce_baselines import HEADER, run, scripted_controller
from spikejax.errors import UserError


def test_the_scripted_controller_in_the_common_test_steers_on_the_angle_it_saw():
    """Each step's action is `steering.step` of the body angle the last step left (the trace's own record).

    Against `robots.snake.env.rollout` driving the same controller, the head
    angles agree bit for bit for the first seven steps, then part by float
    rounding (the two programs round an action's last bit differently, and
    the closed loop amplifies it): the head within 3 cm over 3 s.
    """
    env = training.env_for("zigzag")
    states = jax.tree.map(lambda x: jnp.stack([x]), steering.init())
    trace = training.run_test(scripted_controller(env), None, states, "zigzag", 150, seeds=np.arange(1))
    gains = steering.for_max_steer(training.MAX_STEER, env.compensate_from)
    assert float(steering.for_max_steer(training.MAX_STEER, "joints").gain) == pytest.approx(4.0)  # 2 at 0.25 rad
    assert float(steering.for_max_steer(training.MAX_STEER).gain) == pytest.approx(2.0)  # from the targets: 1 at 0.25
    seen = trace.a_body[0, :-1]
    np.testing.assert_allclose(trace.d_body[0, 1:], np.clip(gains.gain * seen, -1, 1), atol=1e-6)
    np.testing.assert_allclose(trace.d_head[0, 1:], np.clip(gains.head_gain * seen, -1, 1), atol=1e-6)
    assert not trace.failed.any()

    def policy(state, obs, _):
        return steering.step(gains, state, obs, env.dt)

    record, _ = jax.jit(lambda: snake_env.rollout(env, policy, steering.init(), 150))()
    head = np.asarray(record.pipeline_state.head_pos[:, :2])
    assert np.abs(trace.head_xy[0] - head).max() < 0.03


def test_the_rescaled_gain_takes_the_first_turn_that_the_default_gain_loses():
    """The zigzag's first turn, ~65 s in, with the training env's 0.125 rad steering range.

    At gain 1 the snake turns only once the body's angle to the target nears
    37 degrees (this gait does not turn for ``|C_o|`` below
    `robots.snake.env.TURN_THRESHOLD`), and the body-angle rule fires first;
    at the rescaled gain 2 it follows. With the head compensated from the
    joint targets and without the head-swing correction, not `training.env_for`'s
    defaults (with the correction, measured, gain 1 gets round this turn too).
    """
    env = training.env_for("zigzag", camera=False, compensate_from="targets", head_swing=(0.0, 0.0))
    initial = env.reset(jax.random.PRNGKey(0))

    def run(gain):
        params = steering.SteeringParams(gain=gain)

        def body(carry, _):
            state, cstate = carry
            cstate, action = steering.step(params, cstate, state.obs, env.dt)
            state = env.step(state, action)
            return (state, cstate), state.done > 0

        return jax.lax.scan(body, (initial, steering.init()), None, length=4000)[1]

    failed = np.asarray(
        jax.jit(jax.vmap(run))(jnp.array([1.0, float(steering.for_max_steer(training.MAX_STEER).gain)]))
    )
    first = np.argmax(failed[0])
    assert failed[0].any() and 3000 < first < 4000, first  # lost in the turn, not on the straight lead-in
    assert not failed[1].any()


def test_a_head_gain_of_2_oscillates_with_the_compensation_from_the_joints_and_the_tuned_gain_does_not():
    """60 s of the ladder's straight lead-in, the head compensated from the measured joints.

    Turning the head bends the neck joints the compensation reads, a loop
    back through the body: the gains tuned for the compensation from the
    targets (head gain 2) swing the head by about 19 degrees and lose the
    target; `steering.for_max_steer`'s gains for the joints (head 1.25) hold
    it within a few degrees.
    """
    env = training.env_for("ladder", camera=False, compensate_from="joints")
    initial = env.reset(jax.random.PRNGKey(0))

    def run(gain, head_gain):
        params = steering.SteeringParams(gain=gain, head_gain=head_gain)

        def body(carry, _):
            state, cstate = carry
            cstate, action = steering.step(params, cstate, state.obs, env.dt)
            state = env.step(state, action)
            return (state, cstate), (state.metrics["a_head"], state.done > 0)

        return jax.lax.scan(body, (initial, steering.init()), None, length=3000)[1]

    tuned = steering.for_max_steer(training.MAX_STEER, "joints")
    old = steering.for_max_steer(training.MAX_STEER, "targets")
    a_head, failed = jax.jit(jax.vmap(run))(
        jnp.array([old.gain, tuned.gain]), jnp.array([old.head_gain, tuned.head_gain])
    )
    swing = np.degrees(np.abs(np.asarray(a_head))).mean(axis=1)
    assert swing[0] > 10.0 and np.asarray(failed)[0].any()
    assert swing[1] < 5.0 and not np.asarray(failed)[1].any()


def test_bad_compensate_from_for_the_gains_is_one_line_error():
    with pytest.raises(UserError, match="compensate_from"):
        steering.for_max_steer(0.125, "servos")


@pytest.mark.slow  # ~3 min
def test_reproduce_snake_baselines_small(tmp_path):
    rows = run(tmp_path, seeds=2, ppo_steps=2_560, train_laps=0.01, test_steps=100, progress=False)
    with open(tmp_path / "snake_baselines.csv", newline="") as f:
        table = list(csv.DictReader(f))
    assert list(table[0]) == HEADER and len(table) == len(rows)
    controllers = {r["topology"] for r in table}
    assert controllers == {"scripted", "ppo-grid", "ppo-angles", "basic", "basic-head", "unified", "separated"}
    assert {r["seeds"] for r in table if r["topology"] != "scripted"} == {"2"}
    assert (tmp_path / "snake_baselines.png").exists()


def test_a_test_pass_is_long_enough_for_a_snake_at_its_tracking_speed():
    from robots.snake import tracks

    env = training.env_for("ladder", camera=False)
    straight = float(tracks.drawn_length("ladder")) / snake_env.SNAKE_SPEED / env.dt
    steps = training.pass_steps(env)
    assert steps % training.BLOCK == 0 and 0 <= steps - 2.0 * straight < training.BLOCK
    # The scripted steering covers the test tracks at 0.062-0.064 m/s: a pass must fit at 0.062.
    assert steps * env.dt * 0.062 > float(tracks.drawn_length("ladder"))
