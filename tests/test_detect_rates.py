"""False positives and detection rates of the pipe detector on scenes with known truth (fixed seeds).

`spikejax.vision.scenes.detection_rates` runs both grids on snake-view scenes
(a bobbing horizon, pixel noise, the gait's sideways swing) that hold a
standing pipe only, an entry only, or nothing; per slot, it counts what the
detector reports. The sizes are small (48 x 48 pixels, 6 scenes of 5 slots per
kind) to keep the suite fast; docs/BENCHMARKS.md has the 128-pixel figures.
"""

import numpy as np
import pytest

from spikejax.vision import detect, scenes
from spikejax.vision import pipe as pp

KW = dict(n_scenes=6, size=48, n_frames=26, seed=0)


@pytest.fixture(scope="module")
def rates():
    return scenes.detection_rates(**KW)


def test_standing_pipe_is_a_body_never_an_entry(rates):
    r = rates["standing"]
    assert r["in_view"] >= 6
    assert r["entry"] <= 0.05  # no entry on >= 95 % of the slots
    assert r["body_in_view"] >= 0.8


def test_entry_is_never_a_body(rates):
    r = rates["lying"]
    assert r["in_view"] >= 6
    assert r["body"] <= 0.05
    assert r["entry_in_view"] >= 0.6


def test_horizon_and_noise_alone_are_nothing(rates):
    r = rates["empty"]
    assert r["body"] <= 0.05 and r["entry"] <= 0.05


@pytest.mark.slow
def test_the_paper_conditions_alone_report_entries_on_a_standing_pipe():
    """The guard: without the ring test, a standing pipe's edges make circle neurons fire as entries (~10 s)."""
    paper = detect.detector_params(v_th=24.0, body=pp.BodyParams(), entry=pp.EntryParams())
    r = scenes.detection_rates(("standing",), params=paper, **KW)["standing"]
    assert r["entry"] >= 0.08


def test_snake_view_truth_matches_its_frames():
    view = scenes.View("standing", centre=40.0, swing=10.0, period=40.0, phase=0.0, size=12.0, horizon=30.0,
                       bob=0.0, base=3.0)  # fmt: skip
    scene = scenes.snake_view(view, n_frames=3, height=64, width=64)
    frame = np.asarray(scene.frames[0])
    # Frame 0: the pipe spans columns 34-46 (centre 40, width 12) from the top down to row 33 (base 3 below row 30).
    assert frame[10, 40] == pytest.approx(scenes.PIPE) and frame[10, 30] == pytest.approx(scenes.SKY)
    assert frame[50, 40] == pytest.approx(scenes.FLOOR) and frame[50, 30] == pytest.approx(scenes.FLOOR)
    np.testing.assert_allclose(scene.truth.pos[0], 40.0)
    assert frame[10, 35] == pytest.approx(scenes.PIPE) and frame[10, 33] == pytest.approx(scenes.SKY)
    lying = scenes.snake_view(view._replace(kind="lying", size=10.0, base=0.0), n_frames=2, height=64, width=64)
    f = np.asarray(lying.frames[0])
    assert f[30, 40] == pytest.approx(scenes.BORE) and f[30, 49] == pytest.approx(scenes.WALL)
    assert (
        scenes.in_view(lying, 64).all()
        and not scenes.in_view(lying._replace(truth=lying.truth._replace(a=lying.truth.a + 20)), 64).any()
    )
    assert scenes.snake_view(view._replace(kind="empty"), n_frames=2, height=64, width=64).truth is None
    with pytest.raises(scenes.UserError, match="unknown view kind 'pipe'"):
        scenes.snake_view(view._replace(kind="pipe"))
