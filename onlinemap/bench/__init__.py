"""Benchmarks, reported as ratios against a reference measured in the same process.

A benchmark is a function ``(quick: bool) -> list[dict]`` registered with :func:`benchmark`;
each dict is one row with at least ``case``, ``ms`` (per step or per call), ``reference``
(what the ratio is against), ``reference_ms`` and ``target`` (the largest ratio that meets the
goal, or NaN). :func:`run_benchmarks` adds ``ratio`` = ``ms / reference_ms`` and
``meets_target``; ``onlinemap bench`` runs them and prints one table.
"""

from __future__ import annotations

import importlib
import time
from typing import Callable

import numpy as np
import pandas as pd
from ..progress import tqdm

BENCHMARK_MODULES = ("exact", "peers", "rbpf", "em", "planning", "checkpoint")
_BENCHMARKS: dict[str, Callable[[bool], list[dict]]] = {}
_FIGURES: dict[str, Callable[[pd.DataFrame], dict]] = {}


def benchmark(name: str):
    """Decorator registering a benchmark under ``name``."""

    def decorate(fn):
        _BENCHMARKS[name] = fn
        return fn

    return decorate


def figure(name: str):
    """Decorator registering the figures of benchmark ``name``: a function (its rows of a
    :func:`run_benchmarks` table) -> ``{file stem: matplotlib Figure}``."""

    def decorate(fn):
        _FIGURES[name] = fn
        return fn

    return decorate


def benchmark_figures(table: pd.DataFrame) -> dict:
    """``{file stem: Figure}`` of every benchmark in ``table`` that draws figures."""
    figures = {}
    for name, rows in table.groupby("benchmark", sort=False):
        if name in _FIGURES:
            figures.update(_FIGURES[name](rows.reset_index(drop=True)))
    return figures


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


def run_benchmarks(names: list[str] | None = None, quick: bool = False, progress: bool = False) -> pd.DataFrame:
    """Run the named benchmarks (all when None) and return one table.

    With ``names=None`` a benchmark whose optional peer library is missing is skipped (listed
    in ``table.attrs["skipped"]`` with the reason); one asked for by name raises instead.
    """
    from ..peers import PeerMissingError

    known = available_benchmarks()
    run_all = not names
    names = list(names or known)
    unknown = [n for n in names if n not in known]
    if unknown:
        raise ValueError(f"unknown benchmark {', '.join(unknown)}; available: {', '.join(known)}")
    frames, skipped = [], {}
    for name in tqdm(names, desc="benchmarks", disable=not progress, leave=False):
        try:
            rows = _BENCHMARKS[name](quick)
        except PeerMissingError as error:
            if not run_all:
                raise
            skipped[name] = str(error)
            continue
        frame = pd.DataFrame(rows)
        frame.insert(0, "benchmark", name)
        frames.append(frame)
    table = pd.concat(frames, ignore_index=True) if frames else pd.DataFrame(columns=COLUMNS)
    table["ratio"] = table["ms"] / table["reference_ms"]
    table["meets_target"] = np.where(table["target"].isna(), None, table["ratio"] <= table["target"])
    first = [c for c in COLUMNS if c in table.columns]
    table = table[first + [c for c in table.columns if c not in first]]
    table.attrs["skipped"] = skipped
    return table


#: the columns every benchmark table leads with; the CLI prints any other column as notes
COLUMNS = ("benchmark", "case", "ms", "reference", "reference_ms", "ratio", "target", "meets_target")


def machine_info() -> dict:
    """What a benchmark number depends on: versions, CPU, platform, time and git commit."""
    import datetime
    import os
    import platform
    import subprocess

    import numba

    from .._version import __version__

    try:
        commit = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, timeout=5,
                                cwd=os.path.dirname(__file__)).stdout.strip() or None
    except (OSError, subprocess.SubprocessError):
        commit = None
    return {"onlinemap": __version__, "git_commit": commit,
            "time_utc": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
            "python": platform.python_version(), "numpy": np.__version__, "numba": numba.__version__,
            "pandas": pd.__version__, "platform": platform.platform(), "machine": platform.machine(),
            "processor": platform.processor() or None, "cpu_count": os.cpu_count(),
            "hostname": platform.node()}


def benchmark_record(table: pd.DataFrame, quick: bool) -> dict:
    """A JSON-ready record of one ``onlinemap bench`` run: machine info, options, the rows
    (NaN as null) and the benchmarks skipped, for tracking numbers over time."""
    rows = [{key: (None if isinstance(value, float) and not np.isfinite(value) else
                   value.item() if isinstance(value, np.generic) else value)
             for key, value in row.items()} for row in table.to_dict(orient="records")]
    return {"machine": machine_info(), "quick": quick, "skipped": table.attrs.get("skipped", {}), "rows": rows}
