import os
import sys

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


def pytest_collection_modifyitems(session, config, items):
    """The slow tests first, the longest (re-executed notebooks) first of all: pytest-xdist hands
    out tests in this order, so the long ones start at once and the many short ones fill the
    other worker, instead of one long test running alone at the end. Order within each class is
    kept."""
    def rank(item):
        if item.get_closest_marker("slow") is None:
            return 2
        return 0 if "test_stored_outputs_are_current" in item.nodeid else 1

    items[:] = sorted(items, key=rank)
