"""Every notebook in notebooks/ is stored executed, with its figures, exactly as its generator
(``notebooks/build_NAME.py``, run through ``notebooks/nbbuild.py``) writes it: the same cells,
and re-executing it gives the stored text outputs (numbers to 1e-6 relative; images are not
compared, they may differ by pixels). Each ends with its conclusion in words."""

import copy
import json
import os
import subprocess
import sys
from pathlib import Path

import nbformat
import pytest

NOTEBOOKS = Path(__file__).resolve().parents[1] / "notebooks"
sys.path.insert(0, str(NOTEBOOKS))
import nbbuild  # noqa: E402

STORED = sorted(path.stem for path in NOTEBOOKS.glob("*.ipynb"))


def test_every_notebook_has_a_generator_and_every_generator_a_notebook():
    assert STORED and STORED == nbbuild.names()


@pytest.mark.skipif(not nbbuild.same_code_paths(), reason="nothing is pinned on a CPU without AVX2 and FMA")
def test_the_kernel_runs_the_pinned_code_paths():
    """A process started with the notebooks' environment runs numpy without its AVX-512 kernels,
    OpenBLAS with its Haswell kernels and numba compiling for Haswell, whatever the CPU."""
    script = ("import json, numpy, numba; from numpy._core._multiarray_umath import __cpu_features__ as f; "
              "from threadpoolctl import threadpool_info as t; "
              "print(json.dumps([sorted(k for k, on in f.items() if on and 'AVX512' in k), "
              "[i.get('architecture') for i in t() if i['internal_api'] == 'openblas'], "
              "numba.config.CPU_NAME]))")
    environment = {**os.environ, **nbbuild.ENVIRONMENT}
    out = subprocess.run([sys.executable, "-c", script], env=environment, capture_output=True, text=True, check=True)
    avx512, openblas, numba_cpu = json.loads(out.stdout)
    assert avx512 == [] and set(openblas) <= {"Haswell"} and numba_cpu == "haswell"


def test_same_text_compares_words_exactly_and_numbers_with_a_tolerance():
    assert nbbuild.same_text("p = 0.1234567 after 16 steps", "p = 0.12345670001 after 16 steps")
    assert not nbbuild.same_text("p = 0.1234567", "p = 0.1234577")
    assert not nbbuild.same_text("16 steps", "17 steps")
    assert not nbbuild.same_text("exact 0.5", "bk 0.5")


@pytest.fixture(scope="module", params=STORED)
def stored(request):
    return request.param, nbformat.read(NOTEBOOKS / f"{request.param}.ipynb", as_version=4)


def test_notebook_has_its_generators_cells(stored):
    name, notebook = stored
    built = nbbuild.generator(name).build()
    assert [(c.cell_type, c.source) for c in notebook.cells] == [(c.cell_type, c.source) for c in built.cells]


def test_notebook_is_stored_executed_with_figures_and_a_conclusion(stored):
    name, notebook = stored
    code = [cell for cell in notebook.cells if cell.cell_type == "code"]
    assert all(cell.get("execution_count") for cell in code), f"{name} is stored without outputs: run nbbuild"
    outputs = [out for cell in code for out in cell.outputs]
    assert any("image/png" in out.get("data", {}) for out in outputs), "a reader should see figures"
    noise = [out.text for out in outputs if out.output_type == "stream" and out.name == "stderr"]
    assert not noise, f"warnings or progress bars in the stored outputs: {noise}"
    assert not [out for out in outputs if out.output_type == "error"]
    last = notebook.cells[-1]
    assert last.cell_type == "markdown" and len(last.source.split()) >= 30, "end with the conclusion in words"


@pytest.mark.slow  # re-executes every notebook
def test_stored_outputs_are_current(stored):
    name, notebook = stored
    fresh = copy.deepcopy(notebook)
    for cell in fresh.cells:
        if cell.cell_type == "code":
            cell.outputs, cell.execution_count = [], None
    nbbuild.execute(fresh)
    old, new = nbbuild.text_outputs(notebook), nbbuild.text_outputs(fresh)
    assert len(old) == len(new)
    for index, (before, after) in enumerate(zip(old, new)):
        assert len(before) == len(after) and all(map(nbbuild.same_text, before, after)), (
            f"{name}: code cell {index} prints something else now; regenerate with "
            f"`python notebooks/nbbuild.py {name}`\nstored: {before}\nfresh:  {after}")
