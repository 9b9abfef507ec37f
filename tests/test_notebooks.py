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


CODE_PATHS = ("import json, numpy, numba; "
              "from numpy._core._multiarray_umath import __cpu_features__ as f, __cpu_dispatch__ as d; "
              "from threadpoolctl import threadpool_info as t; "
              "print(json.dumps([[k for k in d if f.get(k) and ('AVX512' in k or k == 'X86_V4')], "
              "[i.get('architecture') for i in t() if i['internal_api'] == 'openblas'], "
              "numba.config.CPU_NAME]))")


def code_paths(environment: dict) -> tuple[list, list, str | None]:
    """(numpy's AVX-512 dispatch targets that are switched on, OpenBLAS's kernel architectures,
    numba's CPU name) in a fresh Python process started with ``environment``."""
    out = subprocess.run([sys.executable, "-c", CODE_PATHS], env=environment, capture_output=True, text=True,
                         check=True)
    return tuple(json.loads(out.stdout))


@pytest.mark.skipif(not nbbuild.same_code_paths(), reason="nothing is pinned on a CPU without AVX2 and FMA")
def test_the_kernel_runs_the_pinned_code_paths():
    """A process started with the notebooks' environment runs numpy without its AVX-512 kernels,
    OpenBLAS with its Haswell kernels and numba compiling for Haswell, whatever the CPU. numpy
    picks its kernels among its dispatch targets (``X86_V4``, ``AVX512_ICL``, ... from numpy 2.4;
    ``AVX512F``, ``AVX512_SKX``, ... before), so those are what must be off; a single CPU feature
    such as ``AVX512F`` stays reported as present (numpy 2.4 disables targets, not features)."""
    avx512, openblas, numba_cpu = code_paths({**os.environ, **nbbuild.ENVIRONMENT})
    assert avx512 == [] and set(openblas) <= {"Haswell"} and numba_cpu == "haswell"


@pytest.mark.skipif("avx512f" not in nbbuild.cpu_flags(), reason="the CPU has no AVX-512 to switch off")
def test_without_the_pinning_an_avx512_cpu_runs_avx512_kernels():
    """The check above can fail: on this CPU, a process without the notebooks' environment
    dispatches to AVX-512 kernels."""
    unpinned = {k: v for k, v in os.environ.items() if k not in nbbuild.ENVIRONMENT}
    avx512, _, _ = code_paths(unpinned)
    assert avx512


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
