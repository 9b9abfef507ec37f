"""Every notebook in notebooks/ is what its generator script writes, and executes top to
bottom with a short setting, showing its figures."""

import importlib.util
from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOKS = ROOT / "notebooks"

# name -> (environment for a short run, replacement of the cell tagged "parameters", figures expected)
SHORT_RUNS = {
    "corridor_em_failure": ({"ONLINEMAP_NOTEBOOK_RUNS": "3"}, None, 4),
    "rbpf_vs_bk": ({"ONLINEMAP_NOTEBOOK_RUNS": "2", "ONLINEMAP_NOTEBOOK_STEPS": "15",
                    "ONLINEMAP_NOTEBOOK_SEEDS": "1"}, None, 5),
    "active_exploration": ({}, "STEPS = 40\nSEEDS = [0, 1]\nN_PARTICLES = 30", 1),
}


def test_every_notebook_has_a_generator_and_a_short_run():
    names = {path.stem for path in NOTEBOOKS.glob("*.ipynb")}
    assert names == set(SHORT_RUNS)
    assert all((NOTEBOOKS / f"build_{name}.py").exists() for name in names)


@pytest.mark.parametrize("name", sorted(SHORT_RUNS))
def test_notebook_is_up_to_date_with_its_generator(name):
    spec = importlib.util.spec_from_file_location(f"build_{name}", NOTEBOOKS / f"build_{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    stored = nbformat.read(NOTEBOOKS / f"{name}.ipynb", as_version=4)
    assert [c.source for c in stored.cells] == [c.source for c in module.build().cells]


@pytest.mark.parametrize("name", sorted(SHORT_RUNS))
def test_notebook_runs(name, monkeypatch, tmp_path):
    environment, parameters, n_figures = SHORT_RUNS[name]
    for key, value in {**environment, "MPLBACKEND": "Agg"}.items():
        monkeypatch.setenv(key, value)
    notebook = nbformat.read(NOTEBOOKS / f"{name}.ipynb", as_version=4)
    if parameters is not None:
        tagged = [cell for cell in notebook.cells if "parameters" in cell.get("metadata", {}).get("tags", [])]
        assert len(tagged) == 1
        tagged[0].source = parameters
    NotebookClient(notebook, timeout=300, kernel_name="python3",
                   resources={"metadata": {"path": str(tmp_path)}}).execute()
    outputs = [out for cell in notebook.cells if cell.cell_type == "code" for out in cell.get("outputs", [])]
    figures = [out for out in outputs if "image/png" in out.get("data", {})]
    assert len(figures) >= n_figures, "the notebook should show its figures"
