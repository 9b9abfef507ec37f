"""Long runs: beliefs stay valid distributions and memory does not grow with t.

Every cheap estimator that is registered (dead_reckoning, bk, rbpf with 100 particles,
online_em with a window of 4), on a static corridor and a dynamic door world, fed by a
streaming simulation (no O(T) record). At EVERY step the belief must be finite, non-negative
and sum to 1 within 1e-9 (and an effective sample size, if any, lie in [1, P]). Memory: the
state (``state_dict``: every array and scalar the estimator keeps) has the same size after 10^3
steps as at the end, and the Python heap (tracemalloc) does not grow over the second half of
the default run.

By default 6000 steps per case (about 30 s for the whole file on a loaded 2-core machine).
The 10^6-step versions are marked ``million`` (and ``slow``) and deselected by default
(``addopts`` in pyproject.toml); run them with ``pytest -m million tests/test_long_runs.py``.
They take about 25 minutes in all on a loaded 2-core machine (times per case on the docs site's development page).
"""

from __future__ import annotations

import time
import tracemalloc

import numpy as np
import pytest

import onlinemap as om
from estimator_cases import CHEAP, CHEAP_NAMES, assert_valid_belief, stream

SMALL_DOOR_WORLD = """\
..#...
..o...
#c##o#
......
.#....
"""


def world(kind: str) -> tuple[om.GridModel, np.ndarray]:
    if kind == "static":
        model = om.corridor(16, p_obs=0.9, p_move=0.8)
        return model, om.sample_map(model, 0)
    return om.door_world(SMALL_DOOR_WORLD, p_door=0.02)


def state_size(est) -> tuple[int, int]:
    """(bytes of the state's arrays, number of other values in it, containers' items included):
    what grows if an estimator keeps more with time. Values themselves (t, log evidence) may change.
    Also checks that no float in the state is NaN or +inf (-inf is a log of 0, e.g. a log weight)."""
    arrays, leaves = 0, 0

    def walk(node):
        nonlocal arrays, leaves
        if isinstance(node, np.ndarray):
            arrays += node.nbytes
            if node.dtype.kind in "fc":
                assert not np.isnan(node).any() and not (node == np.inf).any(), f"NaN or +inf in the state of {est.name}"
        elif isinstance(node, (list, dict)):
            for value in (node if isinstance(node, list) else node.values()):
                walk(value)
        else:
            assert not (isinstance(node, float) and (np.isnan(node) or node == np.inf)) or \
                (est.name == "dead_reckoning" and np.isnan(node)), f"{node} in the state of {est.name}"
            leaves += 1

    walk(est.state_dict()["attributes"])
    return arrays, leaves


class BufferedCheck:
    """Copy every step's belief into a buffer and check ``size`` steps at once (vectorised), so
    checking costs about a microsecond per step. Same checks as ``assert_valid_belief``."""

    def __init__(self, model: om.GridModel, particles: int | None, size: int = 1000):
        self.model, self.particles, self.size = model, particles, size
        self.location = np.empty((size, model.n_cells))
        self.map = np.empty((size, model.n_cells, model.n_labels))
        self.ess = np.full(size, np.nan)
        self.t = np.empty(size, dtype=np.int64)
        self.filled = 0

    def add(self, belief: om.Belief) -> None:
        i = self.filled
        self.location[i], self.map[i], self.t[i] = belief.location, belief.map, belief.t
        if belief.effective_sample_size is not None:
            self.ess[i] = belief.effective_sample_size
        self.filled += 1
        if self.filled == self.size:
            self.check()

    def check(self) -> None:
        n = self.filled
        if n == 0:
            return
        ts = self.t[:n]
        assert np.array_equal(ts, ts[0] + np.arange(n)), "beliefs out of step"
        for what, p in (("location", self.location[:n]), ("map", self.map[:n])):
            bad = ~np.isfinite(p) | (p < 0)
            bad = bad.reshape(n, -1).any(axis=1) | (np.abs(p.sum(axis=-1) - 1) > 1e-9).reshape(n, -1).any(axis=1)
            assert not bad.any(), f"invalid {what} at t={ts[np.argmax(bad)]}: {p[np.argmax(bad)]}"
        if self.particles:
            ess = self.ess[:n]
            assert np.all((ess >= 1 - 1e-9) & (ess <= self.particles + 1e-9)), f"effective sample size {ess}"
        self.filled = 0


def long_run(name: str, kind: str, n_steps: int, heap_from: int | None = None) -> dict[str, float]:
    """Run ``n_steps``, checking every belief. Returns state sizes, heap growth and time per step."""
    model, true_map = world(kind)
    est = om.make_estimator(name, model, **CHEAP[name])
    check = BufferedCheck(model, est.options.get("n_particles"))
    sizes, heap = {}, None
    start = time.perf_counter()
    for t, action, z in stream(model, true_map, n_steps, seed=7):
        check.add(est.step(action, z))
        if t == 0:
            assert_valid_belief(est.belief, model, 0)  # the same checks, one by one
        if t + 1 in (1000, n_steps):
            sizes[t + 1] = state_size(est)
        if heap_from is not None and t + 1 == heap_from:
            tracemalloc.start()
            heap = tracemalloc.get_traced_memory()[0]
    check.check()
    seconds = (time.perf_counter() - start) / n_steps
    growth = None
    if heap is not None:
        growth = tracemalloc.get_traced_memory()[0] - heap
        tracemalloc.stop()
    print(f"\n{name} {kind}: {n_steps} steps, {1e6 * seconds:.0f} us/step, state (bytes, values) {sizes}, "
          f"heap growth {growth} bytes")
    return {"sizes": sizes, "heap_growth": growth, "seconds_per_step": seconds}


CASES = [pytest.param(name, kind, id=f"{name}-{kind}") for name in CHEAP_NAMES for kind in ("static", "dynamic")]


@pytest.mark.parametrize("name,kind", CASES)
def test_six_thousand_steps_valid_and_bounded(name, kind):
    result = long_run(name, kind, 6_000, heap_from=3_000)
    sizes = result["sizes"]
    assert sizes[6_000] == sizes[1000], f"state grew from {sizes[1000]} to {sizes[6_000]} (bytes, values)"
    # 3000 more steps: a list growing by one small object per step would add about 100 kB
    assert result["heap_growth"] < 32_000, f"the heap grew by {result['heap_growth']} bytes in 3000 steps"


@pytest.mark.slow
@pytest.mark.million
@pytest.mark.parametrize("name,kind", CASES)
def test_million_steps_valid_and_bounded(name, kind):
    result = long_run(name, kind, 1_000_000)
    sizes = result["sizes"]
    assert sizes[1_000_000] == sizes[1000], f"state grew from {sizes[1000]} to {sizes[1_000_000]} (bytes, values)"
