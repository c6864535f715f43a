"""The snake R-STDP sweep trial: its file loads, a trial is deterministic and independent of its batch."""

import jax
import jax.numpy as jnp
import numpy as np

from robots.snake.trial import RSTDPTrialParams, rstdp_trial
from spikejax.sweep.spec import load_sweep


def test_the_choices_sweep_file_loads_and_names_the_trial():
    spec = load_sweep("sweeps/snake_rstdp_choices.toml")
    assert spec.name == "snake_rstdp_choices"


def test_a_trial_is_deterministic_batch_independent_and_learning_changes_it():
    run = jax.jit(jax.vmap(lambda p, k: rstdp_trial(p, k, train_steps=100, test_steps=100)))
    keys = jnp.stack([jax.random.PRNGKey(0)] * 3)  # one seed: the members differ only by their reward scale
    base = RSTDPTrialParams()
    p = RSTDPTrialParams(*[jnp.full((3,), v, jnp.float32) for v in base])
    p = p._replace(c_reward_scale=jnp.asarray([1.0, 1.0, 1e3], jnp.float32))
    out = run(p, keys)  # members 0 and 1 are the same trial
    again = run(jax.tree.map(lambda x: x[:2], p), keys[:2])
    for field in out._fields:
        a, b = np.asarray(getattr(out, field)), np.asarray(getattr(again, field))
        assert a[0] == a[1] and a[0] == b[0], field
    assert not bool(np.asarray(out.nonfinite).any())
    assert (
        np.asarray(out.test_abs_head_deg)[2] != np.asarray(out.test_abs_head_deg)[0]
    )  # a 1000x reward moves the weights
