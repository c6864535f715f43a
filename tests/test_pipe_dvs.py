"""The pipe env's contrast-threshold DVS: sub-frame event times, the emulator's counts, jit and vmap.

The oracle is the contrast-threshold model itself on the env's own frames: in
the first step after a reset every pixel's reference is the reset frame's log
intensity, so it crosses ``floor(|log(I1 + eps) - log(I0 + eps)| / C)``
levels, the first at ``t0 + dt * C / |log(I1 + eps) - log(I0 + eps)|``.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from robots.snake import pipe_env, pipes
from spikejax.errors import UserError

STEPS = 3


@pytest.fixture(scope="module")
def run():
    env = pipe_env.PipeEnv(dvs="contrast")
    scene = pipes.sample(jax.random.key(0), pipes.STANDING, pipes.RIGHT)
    scene = scene._replace(xy=jnp.array([[1.4, -0.5]], jnp.float32))

    def episode(key):
        s = env.reset(key, scene)

        def body(s, _):
            t0, before = s.pipeline_state.time, s.info["frame"]
            s = env.step(s, jnp.zeros(2))
            return s, (t0, s.pipeline_state.time, before, s.info["frame"], s.info["events"], s.info["overflow"])

        return jax.lax.scan(body, s, None, length=STEPS)[1]

    return env, jax.jit(jax.vmap(episode))(jax.random.split(jax.random.key(3), 2))


@pytest.mark.slow  # the fixture compiles the env: 8 s at load 1.5 on 2 cores, 23 s at load 8
def test_contrast_events_carry_times_inside_their_step(run):
    _, (t0, t1, _, _, events, _) = run
    valid, t = np.asarray(events.valid), np.asarray(events.t)
    t0, t1 = np.asarray(t0)[..., None], np.asarray(t1)[..., None]
    assert valid.sum() > 1000
    assert np.all((t >= t0 - 1e-7) & (t <= t1 + 1e-7) | ~valid)
    strictly = valid & (t > t0 + 1e-6) & (t < t1 - 1e-6)
    assert strictly.sum() > 0.5 * valid.sum()  # not all at the step's end, as the frame difference stamps them
    for b in range(2):  # in time order, as the asynchronous grids need
        for k in range(STEPS):
            tk = t[b, k][valid[b, k]]
            assert np.all(np.diff(tk) >= 0)


@pytest.mark.slow  # shares the fixture above
def test_first_step_matches_the_contrast_threshold_model(run):
    env, (t0, t1, before, after, events, overflow) = run
    c, eps = float(env.dvs_params.pos_threshold), float(env.dvs_params.eps)
    for b in range(2):
        d = np.log(np.asarray(after[b, 0], np.float64) + eps) - np.log(np.asarray(before[b, 0], np.float64) + eps)
        crossings = np.floor(np.abs(d) / c + 1e-9).astype(int)
        valid = np.asarray(events.valid[b, 0])
        assert valid.sum() + int(overflow[b, 0]) == crossings.sum()
        x, y, t, p = (np.asarray(getattr(events, f)[b, 0])[valid] for f in "xytp")
        first = {}
        for xi, yi, ti, pi in zip(x, y, t, p):
            first.setdefault((yi, xi), (ti, pi))
        dt = float(t1[b, 0] - t0[b, 0])
        for (yi, xi), (ti, pi) in list(first.items())[:200]:
            assert pi == np.sign(d[yi, xi])
            assert ti == pytest.approx(float(t0[b, 0]) + dt * c / abs(d[yi, xi]), abs=1e-5)


def test_an_unknown_dvs_model_is_a_one_line_error():
    with pytest.raises(UserError, match="dvs"):
        pipe_env.PipeEnv(dvs="rgb")
    with pytest.raises(UserError, match="max_per_pixel"):
        pipe_env.PipeEnv(dvs="contrast", max_per_pixel=0)
