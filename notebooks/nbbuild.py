"""Builds the notebooks: each ``build_NAME.py`` beside this file lists its cells and ends with
``write(build(), "NAME.ipynb")``; :func:`write` executes the notebook (nbclient, top to bottom, in
this directory, progress bars off) and stores it WITH its outputs, so that a reader on a code
host sees the figures.

Regenerate every notebook (after editing a generator or the library), from the repository root:

    python notebooks/nbbuild.py            # all of them; or: python notebooks/nbbuild.py NAME ...

``tests/test_notebooks.py`` checks that each stored notebook has its generator's cells and that
re-executing it gives the stored text outputs (figures may differ by pixels, numbers by 1e-6
relative), so nothing in a notebook may print timings or other values that change between runs.
"""

from __future__ import annotations

import importlib.util
import os
import re
import sys
from pathlib import Path

import nbformat
from nbformat.v4 import new_code_cell, new_markdown_cell, new_notebook

HERE = Path(__file__).resolve().parent
KERNELSPEC = {"name": "python3", "display_name": "Python 3", "language": "python"}


def cpu_flags() -> set[str]:
    """The CPU's feature flags from /proc/cpuinfo (``avx2``, ``fma``, ``avx512f``, ...); empty
    where there is no /proc/cpuinfo."""
    try:
        with open("/proc/cpuinfo") as info:
            return set(next((line for line in info if line.startswith("flags")), "").split()[2:])
    except OSError:
        return set()


def same_code_paths() -> dict[str, str]:
    """Environment variables that make numpy, its OpenBLAS and numba run the same floating-point
    code on every x86-64 machine with AVX2 and FMA (x86-64-v3), whatever else the CPU has.

    Why: the studies in the notebooks are chaotic in the last bit. numpy picks its exp/log/sum
    kernels by CPU (AVX-512 ones on x86-64-v4), OpenBLAS its matrix kernels, numba compiles for
    the host; one ulp of difference in a particle weight flips a resampling draw and the run
    diverges (seen here: an exploration table's 0.399 became 0.410 when the notebook written
    on one machine was re-run on another, an AMD EPYC with X86_V3 only). Pinning every machine
    to the v3 code paths makes the stored outputs reproducible. Elsewhere (no AVX2, not x86,
    no /proc/cpuinfo) nothing is pinned. Costs a few percent of speed on v4 machines."""
    if not {"avx2", "fma"} <= cpu_flags():
        return {}
    from importlib.metadata import version

    major, minor = (int(part) for part in version("numpy").split(".")[:2])
    avx512 = ("X86_V4 AVX512_ICL AVX512_SPR" if (major, minor) >= (2, 4) else
              "AVX512F AVX512CD AVX512_KNL AVX512_KNM AVX512_SKX AVX512_CLX AVX512_CNL AVX512_ICL AVX512_SPR")
    return {"NPY_DISABLE_CPU_FEATURES": avx512, "OPENBLAS_CORETYPE": "Haswell", "NUMBA_CPU_NAME": "haswell"}


# The kernel's environment: no progress bars, a fixed hash seed, figures without a display, the
# same floating-point code paths on every machine.
ENVIRONMENT = {"ONLINEMAP_PROGRESS": "0", "PYTHONHASHSEED": "0", "MPLBACKEND": "Agg", **same_code_paths()}
TIMEOUT = 600  # seconds per cell


def notebook(cells) -> nbformat.NotebookNode:
    """A notebook from cells given as nbformat cells or ``("md" | "code", source)`` pairs."""
    made = [cell if isinstance(cell, dict) else
            new_markdown_cell(cell[1]) if cell[0] == "md" else new_code_cell(cell[1]) for cell in cells]
    return new_notebook(cells=made, metadata={"kernelspec": KERNELSPEC})


def execute(nb: nbformat.NotebookNode, timeout: int = TIMEOUT) -> nbformat.NotebookNode:
    """Run ``nb`` top to bottom in a fresh kernel (in ``notebooks/``, with :data:`ENVIRONMENT`);
    outputs are stored in ``nb`` (no timing metadata). Raises on the first failing cell."""
    import tempfile

    from jupyter_client.manager import KernelManager
    from nbclient import NotebookClient

    saved = {key: os.environ.get(key) for key in ENVIRONMENT}
    os.environ.update(ENVIRONMENT)
    try:
        # The kernel talks over Unix sockets in a private directory, not TCP ports: ports chosen
        # free can be taken by another kernel starting at the same moment (parallel test workers)
        with tempfile.TemporaryDirectory(prefix="nb") as sockets:
            manager = KernelManager(kernel_name=KERNELSPEC["name"], transport="ipc",
                                    ip=os.path.join(sockets, "kernel"))
            NotebookClient(nb, km=manager, timeout=timeout, record_timing=False,
                           resources={"metadata": {"path": str(HERE)}}).execute()
    finally:
        for key, value in saved.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value
    return nb


def text_outputs(nb: nbformat.NotebookNode) -> list[list[str]]:
    """Per code cell, the text of its outputs (streams, ``text/plain`` results, errors), images
    and HTML left out: what a re-execution must reproduce."""
    cells = []
    for cell in nb.cells:
        if cell.cell_type != "code":
            continue
        texts = []
        for out in cell.get("outputs", []):
            if out.output_type == "stream":
                texts.append(f"{out.name}: {out.text}")
            elif out.output_type in ("execute_result", "display_data"):
                texts.append(out.get("data", {}).get("text/plain", ""))
            elif out.output_type == "error":
                texts.append(f"error: {out.ename}: {out.evalue}")
        cells.append(texts)
    return cells


NUMBER = re.compile(r"[-+]?(?:\d+\.\d*|\.\d+|\d+)(?:[eE][-+]?\d+)?")


def same_text(stored: str, fresh: str, rtol: float = 1e-6, atol: float = 1e-9) -> bool:
    """``stored`` and ``fresh`` are the same text, numbers compared with a tolerance (last digits
    of floats may differ between machines)."""
    if NUMBER.sub("#", stored) != NUMBER.sub("#", fresh):
        return False
    return all(abs(float(a) - float(b)) <= atol + rtol * abs(float(a))
               for a, b in zip(NUMBER.findall(stored), NUMBER.findall(fresh)))


def write(nb: nbformat.NotebookNode, name: str, execute_cells: bool = True) -> Path:
    """Execute ``nb`` (unless ``execute_cells`` is False) and write it as ``notebooks/NAME``; say so."""
    if execute_cells:
        execute(nb)
    path = HERE / name
    nbformat.write(nb, path)
    print(f"wrote {path}")
    return path


def generator(name: str):
    """The module ``notebooks/build_NAME.py`` (its ``build()`` returns the notebook's cells)."""
    spec = importlib.util.spec_from_file_location(f"build_{name}", HERE / f"build_{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.path.insert(0, str(HERE))
    try:
        spec.loader.exec_module(module)
    finally:
        sys.path.remove(str(HERE))
    return module


def names() -> list[str]:
    """Every notebook with a generator: ``build_NAME.py`` -> NAME."""
    return sorted(path.stem.removeprefix("build_") for path in HERE.glob("build_*.py"))


def build_all(selected: list[str] | None = None) -> list[Path]:
    """Build, execute and write the ``selected`` notebooks (default: all)."""
    return [write(generator(name).build(), f"{name}.ipynb") for name in selected or names()]


if __name__ == "__main__":
    unknown = sorted(set(sys.argv[1:]) - set(names()))
    if unknown:
        sys.exit(f"nbbuild: no generator for {', '.join(unknown)}; known: {', '.join(names())}")
    build_all(sys.argv[1:])
