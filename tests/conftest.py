import gc
import os
import sys
from collections import Counter

import pytest

sys.path.insert(0, os.path.dirname(__file__))
# the notebook generators import their shared helper, notebooks/nbbuild.py
sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "notebooks"))

import nbbuild  # noqa: E402  (reads /proc/cpuinfo; imports neither numpy nor numba)

# numba compiles for the CPU the notebooks' kernels are pinned to (nbbuild.ENVIRONMENT), so the
# tests and the re-executed notebooks share one on-disk cache: a fresh clone compiles each kernel
# once for both instead of once for the host CPU and again, inside the notebook tests, for the
# pinned one. numba is imported already (pyproject's filterwarnings names onlinemap's warning
# class), but it reads the CPU name when it first compiles, which has not happened yet.
if "NUMBA_CPU_NAME" in nbbuild.ENVIRONMENT and os.environ.get("NUMBA_CPU_NAME") is None:
    import numba

    os.environ["NUMBA_CPU_NAME"] = numba.config.CPU_NAME = nbbuild.ENVIRONMENT["NUMBA_CPU_NAME"]


# The cyclic collector's full passes walk every object a worker holds: 0.5-0.9 million once numpy,
# scipy, pandas, numba, the test modules and the compiled kernels are loaded, 0.3-0.5 s a pass, and a
# worker keeps nearly all of them to the end. With Python's default thresholds (700, 10, 10) a cold
# run made 31 full passes over both workers, 12-13 CPU s of the 14.7 s its collections took in all
# (measured with gc.callbacks); with a full pass only every 1000th middle one: one pass, 4 s in all,
# for 55-60 MB more peak memory per worker. The young generations are collected as by default.
gc.set_threshold(700, 10, 1_000)


def pytest_collection_modifyitems(session, config, items):
    """The slow tests first, the longest (re-executed notebooks) first of all, then the other units
    of work (:func:`work_unit`) from the largest: pytest-xdist hands them out in this order, so
    the long ones start at once and the many short ones fill the other worker, instead of one
    long test running alone at the end. Order within each class is kept."""
    sizes = Counter(work_unit(item.nodeid) for item in items)

    def rank(item):
        if item.get_closest_marker("slow") is not None:
            return 0 if item.nodeid.startswith(ALONE) else 1, 0
        return 2, -sizes[work_unit(item.nodeid)]  # then the larger units of work: the small ones fill in at the end

    items[:] = sorted(items, key=rank)


#: tests that are each a unit of work of their own: the re-executed notebooks share nothing (each
#: runs in its own kernel) and are the longest tests, so they go to whichever worker is free
ALONE = ("tests/test_notebooks.py::test_stored_outputs_are_current[",)


#: files that test the same kernels: one unit of work (the RBPF's serial and threaded kernels
#: take a minute to compile, once)
FAMILIES = ("tests/test_rbpf",)


def work_unit(nodeid: str) -> str:
    """The unit of work the scheduler below hands to one worker: the test's file (or the test,
    :data:`ALONE`; or its family of files, :data:`FAMILIES`). A file's tests share its module
    fixtures (a dask cluster, 128 explorations) and, mostly, its numba kernels, so each is built
    once instead of once per worker; and two workers on two different files rarely compile the
    same kernel at the same time."""
    if nodeid.startswith(ALONE):
        return nodeid
    path = nodeid.split("::", 1)[0]
    return next((family for family in FAMILIES if path.startswith(family)), path)


@pytest.hookimpl(optionalhook=True)  # pytest without pytest-xdist runs the tests too
def pytest_xdist_make_scheduler(config, log):
    """``--dist loadgroup`` (the README's command) hands out whole files (:func:`work_unit`), in
    the collection's order (the files with slow tests first, as sorted above). xdist's own
    loadgroup keys on the ``xdist_group`` mark through the test's node id, which pytest 9.2 no
    longer lets it change (pytest-dev/pytest-xdist#1386): the marks were silently ignored and
    a group's tests could each build its module fixture on both workers."""
    if config.getoption("dist") != "loadgroup":
        return None
    from xdist.scheduler import LoadScopeScheduling

    class FileScheduling(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            return work_unit(nodeid)

    config.option.loadscopereorder = False  # keep the order: the long files start first
    return FileScheduling(config, log)
