"""The snake pipe notebook runs from top to bottom on a small size."""

from pathlib import Path

import pytest

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")

NOTEBOOKS = Path(__file__).resolve().parents[1] / "notebooks"


@pytest.mark.slow  # 37 s at load 8 on 2 cores (kernel, imports, the env's step compiled), above the 20 s of a fast one
def test_snake_pipe_notebook_executes(monkeypatch):
    monkeypatch.setenv("SPIKEJAX_NB_PIPE_STEPS", "40")
    nb = nbformat.read(NOTEBOOKS / "snake_pipe.ipynb", as_version=4)
    nbclient.NotebookClient(
        nb, timeout=300, kernel_name="python3", resources={"metadata": {"path": str(NOTEBOOKS)}}
    ).execute()
    outputs = [o for cell in nb.cells if cell.cell_type == "code" for o in cell.get("outputs", [])]
    assert not [o for o in outputs if o.output_type == "error"]
    assert sum(o.output_type == "display_data" for o in outputs) >= 2  # path and estimates, events and grid
    text = "".join(o.get("text", "") for o in outputs)
    assert "40 control steps (0.8 s simulated)" in text and "slots with a detection:" in text
