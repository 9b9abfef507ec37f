"""Shared by the notebook generators (``build_*.py``): cells in, notebook out, written beside
the generator. Run a generator (``python notebooks/build_NAME.py``) after editing it; the test
suite checks that every stored notebook is what its generator writes."""

from __future__ import annotations

from pathlib import Path

import nbformat
from nbformat.v4 import new_code_cell, new_markdown_cell, new_notebook

KERNELSPEC = {"name": "python3", "display_name": "Python 3", "language": "python"}


def notebook(cells) -> nbformat.NotebookNode:
    """A notebook from cells given as nbformat cells or ``("md" | "code", source)`` pairs."""
    made = [cell if isinstance(cell, dict) else
            new_markdown_cell(cell[1]) if cell[0] == "md" else new_code_cell(cell[1]) for cell in cells]
    return new_notebook(cells=made, metadata={"kernelspec": KERNELSPEC})


def write(nb: nbformat.NotebookNode, name: str) -> Path:
    """Write ``nb`` as ``notebooks/NAME`` and say so."""
    path = Path(__file__).with_name(name)
    nbformat.write(nb, path)
    print(f"wrote {path}")
    return path
