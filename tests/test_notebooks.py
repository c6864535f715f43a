"""The notebooks run from top to bottom on a small size."""

from pathlib import Path

import pytest

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")

NOTEBOOKS = Path(__file__).resolve().parents[1] / "notebooks"


def test_gaits_notebook_executes(tmp_path, monkeypatch):
    monkeypatch.setenv("SPIKEJAX_RESULTS", str(tmp_path / "gaits"))
    monkeypatch.setenv("SPIKEJAX_NB_TRIALS", "40")
    nb = nbformat.read(NOTEBOOKS / "gaits.ipynb", as_version=4)
    nbclient.NotebookClient(
        nb, timeout=300, kernel_name="python3", resources={"metadata": {"path": str(NOTEBOOKS)}}
    ).execute()
    outputs = [o for cell in nb.cells if cell.cell_type == "code" for o in cell.get("outputs", [])]
    assert not [o for o in outputs if o.output_type == "error"]
    assert sum(o.output_type == "display_data" for o in outputs) >= 3  # rasters, weights, errors
    assert (tmp_path / "gaits" / "gait_convergence.csv").exists()


@pytest.mark.slow  # 22-31 s: the fast suite is at its 15-minute limit
def test_robobee_notebook_executes(monkeypatch):
    monkeypatch.setenv("SPIKEJAX_NB_FLIGHTS", "4")
    nb = nbformat.read(NOTEBOOKS / "robobee.ipynb", as_version=4)
    nbclient.NotebookClient(
        nb, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(NOTEBOOKS)}}
    ).execute()
    outputs = [o for cell in nb.cells if cell.cell_type == "code" for o in cell.get("outputs", [])]
    assert not [o for o in outputs if o.output_type == "error"]
    assert sum(o.output_type == "display_data" for o in outputs) >= 2
    text = "".join(o.get("text", "") for o in outputs)
    assert "of 4 randomised robots reached both waypoints" in text


@pytest.mark.slow  # 22-31 s: the fast suite is at its 15-minute limit
def test_snake_rstdp_notebook_executes(monkeypatch):
    monkeypatch.setenv("SPIKEJAX_NB_SEEDS", "2")
    monkeypatch.setenv("SPIKEJAX_NB_STEPS", "100")
    nb = nbformat.read(NOTEBOOKS / "snake_rstdp.ipynb", as_version=4)
    nbclient.NotebookClient(
        nb, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(NOTEBOOKS)}}
    ).execute()
    outputs = [o for cell in nb.cells if cell.cell_type == "code" for o in cell.get("outputs", [])]
    assert not [o for o in outputs if o.output_type == "error"]
    assert sum(o.output_type == "display_data" for o in outputs) >= 2  # weights and angles, test traces
    text = "".join(o.get("text", "") for o in outputs)
    assert "failures per seed during training" in text and "mean |MA a_head| deg" in text
