"""notebooks/corridor_em_failure.ipynb executes top to bottom (a short random study), and is
what its generator script writes."""

from pathlib import Path

import nbformat

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOK = ROOT / "notebooks" / "corridor_em_failure.ipynb"


def test_notebook_is_up_to_date_with_its_generator():
    import importlib.util

    spec = importlib.util.spec_from_file_location("build_nb", ROOT / "notebooks" / "build_corridor_em_failure.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    stored = nbformat.read(NOTEBOOK, as_version=4)
    assert [c.source for c in stored.cells] == [c.source for c in module.build().cells]


def test_notebook_runs(monkeypatch):
    from nbclient import NotebookClient

    monkeypatch.setenv("ONLINEMAP_NOTEBOOK_RUNS", "3")
    monkeypatch.setenv("MPLBACKEND", "Agg")
    notebook = nbformat.read(NOTEBOOK, as_version=4)
    NotebookClient(notebook, timeout=300, kernel_name="python3", cwd=str(ROOT)).execute()
    images = [o for c in notebook.cells if c.cell_type == "code" for o in c.get("outputs", [])
              if "image/png" in o.get("data", {})]
    assert len(images) >= 4, "the notebook should show its figures"  # a failing cell has raised already
