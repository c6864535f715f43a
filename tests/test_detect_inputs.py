"""`detect pipe` flags are checked where they enter, against ranges declared beside the parameters.

Each bad flag is one error line naming the flag, in the user's unit (degrees for
``--fov``), before the recording is read or anything compiles, and without an
output directory left behind.
"""

import contextlib
import math
import subprocess
import sys

import numpy as np
import pytest

from spikejax import cli
from spikejax.errors import UserError
from spikejax.ranges import ranges_of
from spikejax.vision import hough, io, pipe
from spikejax.vision.detect import detect

PREFIX = "spikejax detect pipe: error: "


def _recording(path):
    a = np.zeros(50, io.EVENT_DTYPE)
    a["x"], a["y"], a["t"], a["p"] = np.arange(50) % 16, 3, np.arange(50) * 100, 1
    return io.save(path, a, (16, 16))


BAD_FLAGS = [
    (["--fov", "500"], "--fov must be in (0, 180), got 500"),
    (["--fov", "0"], "--fov must be in (0, 180), got 0"),
    (["--fov", "180"], "--fov must be in (0, 180), got 180"),
    (["--fov", "inf"], "--fov must be a finite number, got inf"),
    (["--v-th", "-1"], "--v-th must be > 0, got -1"),
    (["--v-th", "0"], "--v-th must be > 0, got 0"),
    (["--decay", "-50"], "--decay must be >= 0, got -50"),
    (["--decay", "nan"], "--decay must be a finite number, got nan"),
    (["--pipe-size", "nan"], "--pipe-size must be a finite number, got nan"),
    (["--pipe-size", "-0.25"], "--pipe-size must be >= 0, got -0.25"),
    (["--speed", "-1"], "--speed must be >= 0, got -1"),
    (["--slot", "0"], "--slot must be > 0, got 0"),
    (["--slot", "-0.02"], "--slot must be > 0, got -0.02"),
    (["--sub-slots", "0"], "argument --sub-slots: must be at least 1, got 0"),
    (["--capacity", "-3"], "argument --capacity: must be at least 1, got -3"),
    (["--sensor-size", "0", "16"], "argument --sensor-size: must be at least 1, got 0"),
    (["--sensor-size", "16"], "argument --sensor-size: expected 2 arguments"),
    (["--sensor-size", "1.5", "16"], "argument --sensor-size: expected a whole number, got '1.5'"),
]


@pytest.mark.parametrize("flags, message", BAD_FLAGS, ids=[" ".join(f) for f, _ in BAD_FLAGS])
def test_bad_flag_is_one_line_naming_it_and_nothing_is_made(flags, message, tmp_path, capsys, monkeypatch):
    path = _recording(tmp_path / "rec.npz")
    read = []
    monkeypatch.setattr(io, "read", lambda *a, **k: read.append(a))  # nothing may be read
    with (
        pytest.raises(SystemExit)
        if flags[0] in ("--sub-slots", "--capacity", "--sensor-size")
        else contextlib.nullcontext()
    ):
        assert cli.main(["detect", "pipe", str(path), *flags, "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.splitlines() == [err.strip()] and err.startswith(PREFIX) and message in err
    assert not read and not (tmp_path / "out").exists()


def test_the_real_cli_refuses_fov_500_before_reading(tmp_path):
    # The file does not even exist: the flag is refused first, in the user's unit.
    run = subprocess.run(
        [sys.executable, "-m", "spikejax.cli", "detect", "pipe", str(tmp_path / "none.npz"), "--fov", "500"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert run.returncode == 2 and run.stdout == ""
    assert run.stderr == PREFIX + "--fov must be in (0, 180), got 500\n"


def test_ranges_are_declared_beside_the_parameters():
    assert set(ranges_of(hough.HoughParams)) == {"v_th", "decay"}
    assert {"size", "speed"} <= set(ranges_of(pipe.TrackParams))
    fov = ranges_of(pipe.track_params)["fov"]
    assert not fov.contains(0) and fov.contains(math.radians(60)) and not fov.contains(math.pi)
    assert {"slot", "sub_slots", "capacity"} <= set(ranges_of(detect))


def test_the_library_refuses_a_bad_slot_with_the_argument_named():
    a = np.zeros(3, io.EVENT_DTYPE)
    a["t"] = [0, 1, 2]
    with pytest.raises(UserError, match=r"^sub_slots must be a whole number >= 1, got 2.5$"):
        detect(a, (16, 16), sub_slots=2.5)
    with pytest.raises(UserError, match=r"^slot must be > 0, got -1$"):
        detect(a, (16, 16), slot=-1)
