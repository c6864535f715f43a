"""The Hough notebook runs from top to bottom on a small size."""

from pathlib import Path

import pytest

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")

NOTEBOOKS = Path(__file__).resolve().parents[1] / "notebooks"


@pytest.mark.slow  # 30 s (kernel, imports, both grids compiled): the fast suite is at its 15-minute limit; the gaits notebook stays in it
def test_hough_notebook_executes(monkeypatch):
    monkeypatch.setenv("SPIKEJAX_NB_HOUGH_FRAMES", "11")
    nb = nbformat.read(NOTEBOOKS / "hough.ipynb", as_version=4)
    nbclient.NotebookClient(
        nb, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(NOTEBOOKS)}}
    ).execute()
    outputs = [o for cell in nb.cells if cell.cell_type == "code" for o in cell.get("outputs", [])]
    assert not [o for o in outputs if o.output_type == "error"]
    assert sum(o.output_type == "display_data" for o in outputs) >= 5  # frame, accumulators, overlay, modes, distance
    text = "".join(o.get("text", "") for o in outputs)
    assert "strongest line: theta 90 deg" in text
    assert "body" in text and "Eq. (9):" in text
