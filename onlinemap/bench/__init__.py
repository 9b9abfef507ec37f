"""Benchmarks, reported as ratios against a reference measured in the same process.

A benchmark is a function ``(quick: bool) -> list[dict]`` registered with :func:`benchmark`;
each dict is one row with at least ``case``, ``ms`` (per step or per call), ``reference``
(what the ratio is against), ``reference_ms``, ``ratio`` and ``target`` (the largest ratio
that meets the goal, or NaN). ``onlinemap bench`` runs them and prints one table.
"""

from __future__ import annotations

import importlib
import time
from typing import Callable

import numpy as np
import pandas as pd

BENCHMARK_MODULES = ("exact",)
_BENCHMARKS: dict[str, Callable[[bool], list[dict]]] = {}


def benchmark(name: str):
    """Decorator registering a benchmark under ``name``."""

    def decorate(fn):
        _BENCHMARKS[name] = fn
        return fn

    return decorate


def available_benchmarks() -> tuple[str, ...]:
    for module in BENCHMARK_MODULES:
        importlib.import_module(f"{__name__}.{module}")
    return tuple(_BENCHMARKS)


def seconds_per_call(fn: Callable[[], object], min_seconds: float = 0.2, max_calls: int = 1000) -> float:
    """Median wall time of ``fn()`` over repeated calls (at least 3, about ``min_seconds`` in all)."""
    times = []
    start = time.perf_counter()
    while len(times) < 3 or (time.perf_counter() - start < min_seconds and len(times) < max_calls):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def copy_pass_ms(n_floats: int, dtype=np.float64) -> float:
    """Milliseconds for one read+write pass (``np.copyto``) over ``n_floats`` values."""
    source = np.random.default_rng(0).random(n_floats).astype(dtype)
    target = np.empty_like(source)
    return 1e3 * seconds_per_call(lambda: np.copyto(target, source))


def run_benchmarks(names: list[str] | None = None, quick: bool = False) -> pd.DataFrame:
    """Run the named benchmarks (all when None) and return one table."""
    known = available_benchmarks()
    names = list(names or known)
    unknown = [n for n in names if n not in known]
    if unknown:
        raise ValueError(f"unknown benchmark {', '.join(unknown)}; available: {', '.join(known)}")
    frames = []
    for name in names:
        rows = _BENCHMARKS[name](quick)
        frame = pd.DataFrame(rows)
        frame.insert(0, "benchmark", name)
        frames.append(frame)
    table = pd.concat(frames, ignore_index=True)
    table["meets_target"] = np.where(table["target"].isna(), None, table["ratio"] <= table["target"])
    return table
