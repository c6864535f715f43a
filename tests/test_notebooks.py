"""The notebooks run from top to bottom on a small size."""

from pathlib import Path

import pytest

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")

NOTEBOOKS = Path(__file__).resolve().parents[1] / "notebooks"


def _execute(name: str, *, timeout: int = 300) -> tuple[list, str]:
    """Run ``notebooks/name`` top to bottom; its outputs and their printed text, after checking none is an error."""
    nb = nbformat.read(NOTEBOOKS / name, as_version=4)
    nbclient.NotebookClient(
        nb, timeout=timeout, kernel_name="python3", resources={"metadata": {"path": str(NOTEBOOKS)}}
    ).execute()
    outputs = [o for cell in nb.cells if cell.cell_type == "code" for o in cell.get("outputs", [])]
    assert not [o for o in outputs if o.output_type == "error"]
    return outputs, "".join(o.get("text", "") for o in outputs)


def _figures(outputs: list) -> int:
    return sum(o.output_type == "display_data" for o in outputs)


@pytest.mark.slow  # 27 s; the command it calls is test_reproduce_gaits.py's, in the fast suite
def test_gaits_notebook_executes(tmp_path, monkeypatch):
    monkeypatch.setenv("SPIKEJAX_RESULTS", str(tmp_path / "gaits"))
    monkeypatch.setenv("SPIKEJAX_NB_TRIALS", "40")
    outputs, _ = _execute("gaits.ipynb")
    assert _figures(outputs) >= 3  # rasters, weights, errors
    assert (tmp_path / "gaits" / "gait_convergence.csv").exists()


@pytest.mark.slow  # 22-31 s: the fast suite is at its 15-minute limit
def test_robobee_notebook_executes(monkeypatch):
    monkeypatch.setenv("SPIKEJAX_NB_FLIGHTS", "4")
    outputs, text = _execute("robobee.ipynb", timeout=600)
    assert _figures(outputs) >= 2
    assert "of 4 randomised robots reached both waypoints" in text


@pytest.mark.slow  # 22-31 s: the fast suite is at its 15-minute limit
def test_snake_rstdp_notebook_executes(monkeypatch):
    monkeypatch.setenv("SPIKEJAX_NB_SEEDS", "2")
    monkeypatch.setenv("SPIKEJAX_NB_STEPS", "100")
    outputs, text = _execute("snake_rstdp.ipynb", timeout=600)
    assert _figures(outputs) >= 2  # weights and angles, test traces
    assert "failures per seed during training" in text and "mean |MA a_head| deg" in text


@pytest.mark.slow  # 37 s at load 8 on 2 cores (kernel, imports, the env's step compiled), above the 20 s of a fast one
def test_snake_pipe_notebook_executes(monkeypatch):
    monkeypatch.setenv("SPIKEJAX_NB_PIPE_STEPS", "40")
    outputs, text = _execute("snake_pipe.ipynb")
    assert _figures(outputs) >= 2  # path and estimates, events and grid
    assert "40 control steps (0.8 s simulated)" in text and "slots with a detection:" in text


@pytest.mark.slow  # 22 s on an idle 2-core machine (kernel, the env's step compiled twice), above a fast test's 20 s
def test_hexapod_prey_notebook_executes(monkeypatch):
    monkeypatch.setenv("SPIKEJAX_NB_HEX_STEPS", "8")
    outputs, text = _execute("hexapod_prey.ipynb", timeout=600)
    assert _figures(outputs) >= 3  # paths, spikes and CPG raster, one decision inside
    assert "oracle: 8 decisions" in text and "Fig. 8 gaits FFFRR" in text  # the oracle's first capture, as in the paper
    assert "gait neurons' spikes over the step" in text
