"""Bad values of a sweep file name their key; errors of the user's trial and module point at the user's line."""

from __future__ import annotations

import subprocess

import pytest
from test_sweep import TESTS, _assert_one_line_error, _cli_command, _cli_env, _write

from spikejax import cli
from spikejax.sweep import read_results

RANGED = """\
[sweep]
name = "ranged"
trial = "_sweep_trials:ranged_trial"
seeds = 2

[fixed]
{fixed}

[grid]
{grid}
"""

HEXAPOD = """\
[sweep]
name = "gaits"
trial = "robots.hexapod.trial:convergence_trial"
seeds = 2

[fixed]
{fixed}

[grid]
{grid}
"""


@pytest.fixture(autouse=True)
def _trials_importable(monkeypatch):
    monkeypatch.syspath_prepend(str(TESTS))


def _line_of(marker: str) -> int:
    lines = (TESTS / "_sweep_trials.py").read_text().splitlines()
    return next(i for i, line in enumerate(lines, start=1) if marker in line)


CASES = {
    # traced fields, against the ranges declared beside the params NamedTuple
    "grid n_gaits": (HEXAPOD, "", "n_gaits = [1, 2, 7]", "[grid] n_gaits must be a whole number in [1, 3], got 7"),
    "fixed alpha zero": (HEXAPOD, "alpha = 0.0", "n_gaits = [1]", "[fixed] alpha must be > 0, got 0"),
    "fixed alpha nan": (HEXAPOD, "alpha = nan", "n_gaits = [1]", "[fixed] alpha must be a finite number, got nan"),
    "grid v_th": (HEXAPOD, "", "v_th = [1.0, -1.0]", "[grid] v_th must be > 0, got -1"),
    "fixed lr inf": (HEXAPOD, "lr = -inf", "n_gaits = [1]", "[fixed] lr must be a finite number, got -inf"),
    "toy grid": (RANGED, "", "a = [1.0, -0.5]", "[grid] a must be > 0, got -0.5"),
    "toy fixed": (RANGED, "n = 4", "a = [1.0]", "[fixed] n must be a whole number in [1, 3], got 4"),
    # static keywords: their annotation and the ranges declared on the trial function
    "max_epochs zero": (
        HEXAPOD,
        "max_epochs = 0",
        "n_gaits = [1]",
        "[fixed] max_epochs must be a whole number >= 1, got 0",
    ),
    "max_epochs list": (
        HEXAPOD,
        "max_epochs = [1, 2]",
        "n_gaits = [1]",
        "[fixed] max_epochs must be an integer (the trial's keyword 'max_epochs: int'), got [1, 2]",
    ),
    "max_epochs float": (
        HEXAPOD,
        "max_epochs = 2.5",
        "n_gaits = [1]",
        "[fixed] max_epochs must be an integer (the trial's keyword 'max_epochs: int'), got 2.5",
    ),
    "static grid": (RANGED, "", "steps = [2, 0]", "[grid] steps must be a whole number >= 1, got 0"),
    "static string": (
        RANGED,
        'gain = "big"',
        "a = [1.0]",
        "[fixed] gain must be a number (the trial's keyword 'gain: float'), got 'big'",
    ),
}


@pytest.mark.parametrize("case", list(CASES))
def test_a_bad_value_is_one_line_naming_its_key(tmp_path, capsys, case):
    template, fixed, grid, expected = CASES[case]
    path = _write(tmp_path, template.format(fixed=fixed, grid=grid))
    out = tmp_path / "out"

    rc = cli.main(["sweep", str(path), "--out", str(out)])

    err = capsys.readouterr().err
    _assert_one_line_error(rc, err, expected)
    assert err == f"spikejax sweep: error: {path}: {expected}\n"
    assert not out.exists()


def test_a_bad_grid_value_from_the_command_line(tmp_path):
    path = _write(tmp_path, HEXAPOD.format(fixed="", grid="n_gaits = [1, 2, 7]"))

    run = subprocess.run(_cli_command(path, tmp_path / "out"), env=_cli_env(), capture_output=True, text=True)

    _assert_one_line_error(run.returncode, run.stderr, "[grid] n_gaits must be a whole number in [1, 3], got 7")
    assert not (tmp_path / "out").exists()


TOY = """\
[sweep]
name = "toy"
trial = "_sweep_trials:{trial}"
seeds = 2

[grid]
a = [1.0]
"""


def test_an_exception_in_the_trial_points_at_the_users_line(tmp_path, capsys):
    path = _write(tmp_path, TOY.format(trial="raising_trial"))

    rc = cli.main(["sweep", str(path), "--out", str(tmp_path / "out")])

    expected = (
        f"the trial _sweep_trials:raising_trial raised ZeroDivisionError at "
        f"{TESTS / '_sweep_trials.py'}:{_line_of('# RAISING_LINE')}: the user's own mistake"
    )
    _assert_one_line_error(rc, capsys.readouterr().err, expected)
    assert not (tmp_path / "out").exists()


def test_a_jax_error_in_the_trial_points_at_the_users_line(tmp_path, capsys):
    path = _write(tmp_path, TOY.format(trial="shape_error_trial"))

    rc = cli.main(["sweep", str(path), "--out", str(tmp_path / "out")])

    err = capsys.readouterr().err
    _assert_one_line_error(rc, err, "the trial _sweep_trials:shape_error_trial rejects the sweep's values: ")
    assert err.endswith(f"(at {TESTS / '_sweep_trials.py'}:{_line_of('# SHAPE_LINE')})\n")


MODULES = {
    "syntax": ("x = 1\ndef trial(:\n    pass\n", "has a syntax error at {file}:2: "),
    "raises": ("import math\n\nvalue = 1 / 0\n", "failed at {file}:3: ZeroDivisionError: division by zero"),
    "missing import": (
        "import no_such_dependency_xyz\n",
        "failed at {file}:1: No module named 'no_such_dependency_xyz'",
    ),
}


@pytest.mark.parametrize("case", list(MODULES))
def test_an_error_importing_the_trials_module_is_one_line_with_its_place(tmp_path, case):
    """The real CLI: the module's own error, where it is, not a traceback."""
    source, expected = MODULES[case]
    module = tmp_path / f"user_trials_{case.replace(' ', '_')}.py"
    module.write_text(source)
    path = _write(tmp_path, TOY.format(trial="x").replace("_sweep_trials:x", f"{module.stem}:trial"))

    run = subprocess.run(
        _cli_command(path, tmp_path / "out"),
        cwd=tmp_path,
        env=_cli_env(PYTHONPATH=str(tmp_path) + ":" + _cli_env()["PYTHONPATH"]),
        capture_output=True,
        text=True,
    )

    _assert_one_line_error(run.returncode, run.stderr, "[sweep] trial: ")
    assert expected.format(file=module) in run.stderr
    assert not (tmp_path / "out").exists()


def test_a_later_static_value_the_trial_rejects_is_one_line(tmp_path, capsys):
    """A static axis's second value is traced only when its chunks come: the trials before it are kept."""
    path = _write(tmp_path, TOY.format(trial="picky_trial") + "size = [1, 3]\n")

    rc = cli.main(["sweep", str(path), "--out", str(tmp_path / "out"), "--no-progress"])

    err = capsys.readouterr().err
    _assert_one_line_error(rc, err, "the trial _sweep_trials:picky_trial failed for size = 3 at ")
    assert err.endswith(
        f"{TESTS / '_sweep_trials.py'}:{_line_of('# PICKY_LINE')}: ValueError: size 3 is too large for this toy "
        "(the trials done so far are kept)\n"
    )
    assert len(read_results(tmp_path / "out")["trial"]) == 2


def test_ranges_are_declared_on_a_trial_functions_keywords():
    from _sweep_trials import ranged_trial

    from spikejax.ranges import Range, ranged, ranges_of

    assert ranges_of(ranged_trial) == {"steps": Range(1, integer=True)}
    with pytest.raises(TypeError, match="has no field nope to declare a range for"):
        ranged(nope=Range(0))(ranged_trial)
