"""The snake notebook runs from top to bottom on a small size."""

from pathlib import Path

import pytest

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")

NOTEBOOKS = Path(__file__).resolve().parents[1] / "notebooks"


@pytest.mark.slow  # 21 s (kernel, the env and its camera compiled): the fast suite is at its 15-minute limit; the gaits notebook stays in it
def test_snake_notebook_executes(monkeypatch):
    monkeypatch.setenv("SPIKEJAX_NB_SNAKE_STEPS", "40")
    monkeypatch.setenv("SPIKEJAX_NB_SNAKE_PERIODS", "3")
    nb = nbformat.read(NOTEBOOKS / "snake.ipynb", as_version=4)
    nbclient.NotebookClient(
        nb, timeout=300, kernel_name="python3", resources={"metadata": {"path": str(NOTEBOOKS)}}
    ).execute()
    outputs = [o for cell in nb.cells if cell.cell_type == "code" for o in cell.get("outputs", [])]
    assert not [o for o in outputs if o.output_type == "error"]
    assert sum(o.output_type == "display_data" for o in outputs) >= 4  # path, frames + events, counts, the batch
    text = "".join(o.get("text", "") for o in outputs)
    assert "forward progress" in text and text.count("C_o ") >= 9
