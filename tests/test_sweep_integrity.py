"""Parts prove themselves (row count and checksum), damaged ones are recomputed; tables read back strictly."""

from __future__ import annotations

import json
import shutil
import subprocess

import numpy as np
import pytest
from test_sweep import TESTS, TOY, TOY_TRIALS, _cli_command, _cli_env, _run, _write

from spikejax import cli
from spikejax.errors import UserError
from spikejax.sweep import read_results


@pytest.fixture(autouse=True)
def _trials_importable(monkeypatch):
    monkeypatch.syspath_prepend(str(TESTS))


@pytest.fixture
def finished(tmp_path):
    """A finished toy sweep (chunks of 4: nine parts) and its uninterrupted table."""
    path = _write(tmp_path, TOY)
    reference = _run(path, tmp_path / "reference")
    out = tmp_path / "out"
    shutil.copytree(tmp_path / "reference", out)
    return path, out, reference


def _parts(out):
    return sorted((out / "parts").glob("rows-*.csv"))


def _computed(out):
    return json.loads((out / "metadata.json").read_text())["runs"][-1]["computed_trials"]


DAMAGES = {
    "fewer rows": (lambda data: data[: data.index(b"\n") + 1], "it holds 1 rows, its name says 4"),
    "empty": (lambda data: b"", "it is empty"),
    "cut mid-line": (lambda data: data[:-3], "it is cut mid-line"),
    "garbage": (lambda data: b"\x00\xffgarbage\n" * 4, "its checksum differs"),
    "changed cell": (
        lambda data: data.replace(b"true", b"TRUE", 1).replace(b"false", b"FALSE", 1),
        "its checksum differs",
    ),
}


@pytest.mark.parametrize("damage", list(DAMAGES))
def test_a_damaged_part_is_named_and_recomputed(finished, capsys, damage):
    path, out, reference = finished
    change, reason = DAMAGES[damage]
    part = _parts(out)[2]
    part.write_bytes(change(part.read_bytes()))

    assert cli.main(["sweep", str(path), "--out", str(out), "--no-progress"]) == 0

    warnings = [line for line in capsys.readouterr().err.splitlines() if line.startswith("warning:")]
    assert warnings == [
        f"warning: {part} is damaged ({reason}): moved to {part.name}.damaged, its trials 8..11 are computed again"
    ]
    assert (out / "results.csv").read_bytes() == reference
    assert _computed(out) == 4
    assert (part.parent / (part.name + ".damaged")).exists()


def test_several_damaged_parts_from_the_command_line(finished):
    """The real CLI: one warning line per damaged part on stderr, then the uninterrupted table."""
    path, out, reference = finished
    parts = _parts(out)
    for part, damage in zip(parts[1::2], DAMAGES.values()):
        part.write_bytes(damage[0](part.read_bytes()))
    (parts[0]).unlink()

    run = subprocess.run(
        _cli_command(path, out, "--no-progress"), cwd=path.parent, env=_cli_env(), capture_output=True, text=True
    )

    assert run.returncode == 0, run.stderr
    lines = run.stderr.splitlines()
    assert sorted(line.split(" is damaged")[0] for line in lines) == [f"warning: {p}" for p in parts[1::2][:4]]
    assert (out / "results.csv").read_bytes() == reference
    assert _computed(out) == 4 * 5


def test_results_csv_that_is_not_its_parts_is_rebuilt(finished):
    path, out, reference = finished
    damaged = reference.replace(b"true", b"TRUE", 1)
    (out / "results.csv").write_bytes(damaged)  # the same size: only its bytes tell

    assert _run(path, out) == reference
    assert _computed(out) == 0


def test_parts_of_an_older_table_without_checksums_are_kept(finished):
    path, out, reference = finished
    for part in _parts(out):
        part.rename(part.with_name(part.name.rsplit("-", 1)[0] + ".csv"))

    assert _run(path, out) == reference
    assert _computed(out) == 0


@pytest.mark.parametrize(
    "change",
    [
        lambda data: data.replace(b"true", b"TRUE", 1),
        lambda data: data[: data.index(b"\n") + 1],
        lambda data: data.replace(b"\n", b",1\n", 1),
        lambda data: data.replace(b"8,", b"9,", 1),
    ],
)
def test_older_parts_are_checked_cell_by_cell(finished, capsys, change):
    path, out, reference = finished
    for part in _parts(out):
        part.rename(part.with_name(part.name.rsplit("-", 1)[0] + ".csv"))
    part = _parts(out)[2]
    part.write_bytes(change(part.read_bytes()))

    assert _run(path, out) == reference
    assert _computed(out) == 4
    assert f"warning: {part} is damaged" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("old", "new", "line", "message"),
    [
        (b"true", b"TRUE", None, "column positive: 'TRUE' is not true or false"),
        (b",1,", b",1.0,", None, "is not an integer"),
        (b"\n0,", b"\n0,1,", 2, "cells, the table has 9 columns"),
    ],
)
def test_reading_a_table_accepts_only_what_the_engine_writes(finished, old, new, line, message):
    _, out, reference = finished
    (out / "results.csv").write_bytes(reference.replace(old, new, 1))
    expected_line = line or reference[: reference.index(old)].count(b"\n") + 1

    with pytest.raises(UserError) as err:
        read_results(out)

    assert str(err.value).startswith(f"{out / 'results.csv'}, line {expected_line}")
    assert message in str(err.value)


def test_the_engine_reads_its_own_numbers_back(finished):
    _, out, _ = finished
    table = read_results(out)

    assert len(table["trial"]) == TOY_TRIALS
    np.testing.assert_array_equal(table["trial"], np.arange(TOY_TRIALS))


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda data: data[: data.rindex(b"\n", 0, -1) + 1], "holds 35 rows and {out}/metadata.json says 36 trials"),
        (lambda data: data.replace(b"\n1,", b"\n0,", 1), "results.csv, line 3: the trials are not in order"),
    ],
)
def test_a_table_cut_at_a_row_or_out_of_order_is_refused(finished, change, message):
    _, out, reference = finished
    (out / "results.csv").write_bytes(change(reference))

    with pytest.raises(UserError, match=message.format(out=out).replace(".", r"\.")):
        read_results(out)
