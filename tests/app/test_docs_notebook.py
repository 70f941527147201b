"""docs/notebook.ipynb runs top to bottom in a real Jupyter kernel (nbclient), with its checks."""

from __future__ import annotations

from pathlib import Path

import pytest

pytest.importorskip("moderngl")
pytest.importorskip("anywidget")
pytest.importorskip("nbclient")
pytest.importorskip("ipykernel")
pytest.importorskip("nibabel")

NOTEBOOK = Path(__file__).resolve().parents[2] / "docs" / "notebook.ipynb"


@pytest.mark.slow
def test_docs_notebook_runs(tmp_path):
    import nbformat
    from nbclient import NotebookClient

    nb = nbformat.read(NOTEBOOK, as_version=4)
    NotebookClient(nb, timeout=180, kernel_name="python3", resources={"metadata": {"path": str(tmp_path)}}).execute()
    text = []
    for cell in nb.cells:
        for out in cell.get("outputs", []):
            assert out.get("output_type") != "error", out
            text.append(out.get("text", "") or str(out.get("data", {}).get("text/plain", "")))
    joined = "\n".join(text)
    assert "bricks L" in joined  # the HUD printed
    assert "left R right L top S" in joined  # the phantom's frontal view is labelled (radiological)
    widget_outputs = [o for c in nb.cells for o in c.get("outputs", []) if "application/vnd.jupyter.widget-view+json" in o.get("data", {})]
    assert len(widget_outputs) == 2  # both views displayed as widgets
