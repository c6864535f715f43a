"""NaN and infinity alike, in float results and in the ``nonfinite`` flag, are reported with their trials."""

from __future__ import annotations

import json
import subprocess

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_sweep import TESTS, _cli_command, _cli_env, _write

from spikejax import cli
from spikejax.sweep import nonfinite, read_results

INF = """\
[sweep]
name = "inf"
trial = "_sweep_trials:inf_trial"
seeds = 2
chunk_size = 3

[grid]
a = [1.0, 3.0, 0.0, -3.0]
"""


@pytest.fixture(autouse=True)
def _trials_importable(monkeypatch):
    monkeypatch.syspath_prepend(str(TESTS))


def _metadata(out):
    return json.loads((out / "metadata.json").read_text())


def test_nonfinite_of_a_tree():
    assert not bool(nonfinite({"w": jnp.ones(3), "n": jnp.asarray(7)}))
    assert bool(nonfinite({"w": jnp.array([1.0, jnp.inf]), "n": jnp.asarray(7)}))
    assert bool(nonfinite((jnp.array([-jnp.inf]),)))
    assert bool(nonfinite([jnp.zeros(2), jnp.array(jnp.nan, jnp.float16)]))
    assert not bool(nonfinite({"n": jnp.arange(3)}))
    assert bool(jax.jit(nonfinite)(jnp.array([0.0, jnp.nan])))


def test_nan_and_infinity_are_reported_alike_from_the_command_line(tmp_path):
    out = tmp_path / "out"
    run = subprocess.run(
        _cli_command(_write(tmp_path, INF), out, "--no-progress"), env=_cli_env(), capture_output=True, text=True
    )

    assert run.returncode == 0, run.stderr
    table = read_results(out)
    assert table["value"][2:4].tolist() == [np.inf, np.inf] and table["value"][6:8].tolist() == [-np.inf, -np.inf]
    assert np.isnan(table["value"][4:6]).all()
    assert run.stderr == (
        "warning: sweep 'inf': non-finite values (NaN or inf) in 6 of 8 trials: 2, 3, 4, 5, 6, 7 "
        f"(all in {out / 'metadata.json'}, nonfinite_trials)\n"
    )
    assert _metadata(out)["nonfinite_trials"] == [2, 3, 4, 5, 6, 7]
    assert _metadata(out)["nan_trials"] == [4, 5]


def test_the_flag_reports_a_trial_whose_results_are_not_floats(tmp_path, capsys):
    path = _write(tmp_path, INF.replace("inf_trial", "flag_trial"))

    assert cli.main(["sweep", str(path), "--out", str(tmp_path / "out"), "--no-progress"]) == 0

    table = read_results(tmp_path / "out")
    assert table["nonfinite"].tolist() == [False, False, False, False, True, True, False, False]
    assert "non-finite values (NaN or inf) in 2 of 8 trials: 4, 5 " in capsys.readouterr().err
    assert _metadata(tmp_path / "out")["nonfinite_trials"] == [4, 5]


def test_the_flag_must_be_a_bool(tmp_path, capsys):
    path = _write(tmp_path, INF.replace("inf_trial", "int_flag_trial"))

    assert cli.main(["sweep", str(path), "--out", str(tmp_path / "out")]) == 2

    assert capsys.readouterr().err == (
        "spikejax sweep: error: result 'nonfinite' of the trial _sweep_trials:int_flag_trial must be a bool "
        "(spikejax.sweep.nonfinite of its state), got int32\n"
    )


HEXAPOD = """\
[sweep]
name = "gaits"
trial = "robots.hexapod.trial:convergence_trial"
seeds = 1

[fixed]
max_epochs = 2
eval_cycles = 1

[grid]
lr = [1.0, 3e38]
"""


def test_the_hexapod_trial_reports_a_state_gone_infinite(tmp_path, capsys):
    """``lr = 3e38`` overflows the weights: not an ordinary "did not converge" row."""
    out = tmp_path / "out"

    assert cli.main(["sweep", str(_write(tmp_path, HEXAPOD)), "--out", str(out), "--no-progress"]) == 0

    table = read_results(out)
    assert table["nonfinite"].tolist() == [False, True]
    assert "non-finite values (NaN or inf) in 1 of 2 trials: 1 " in capsys.readouterr().err


def test_the_hexapod_trial_flags_alpha_zero_and_nan():
    """Sweep files cannot give them (the ranges refuse them), the Python API can: the flag tells."""
    from robots.hexapod.trial import GaitTrialParams, convergence_trial

    def run(**values):
        params = GaitTrialParams(*(jnp.float32(v) for v in GaitTrialParams(**values)))
        return bool(convergence_trial(params, jax.random.key(0), max_epochs=1, eval_cycles=1).nonfinite)

    assert [run(), run(alpha=0.0), run(alpha=float("nan")), run(lr=3e38)] == [False, True, True, True]


def test_the_robobee_summary_reports_a_recording_gone_nonfinite():
    from robots.robobee.flight import Recording, flight_plan
    from robots.robobee.trial import summarize

    n = 10
    plan = flight_plan("waypoints")
    q = jnp.tile(plan.q0, (n, 1))
    zeros = jnp.zeros(n)
    rec = Recording(
        t=(jnp.arange(n) + 1) * 1e-3, q=q, target=q, y_hat=zeros, y_lqr=zeros, w_ih_mean=zeros, w_ho_mean=zeros
    )
    flags = [
        bool(summarize(r, plan, hold_steps=20, segment_steps=40, record_every=10).nonfinite)
        for r in (rec, rec._replace(w_ih_mean=zeros.at[3].set(jnp.inf)), rec._replace(q=q.at[5, 2].set(jnp.nan)))
    ]
    assert flags == [False, True, True]
