"""What every study shares: a spec run on the sweep engine, one row per run, and one summary
with intervals over seeds (:func:`onlinemap.sweeps.summarize`, Student t intersected with the
metric's range, Wilson for yes/no outcomes).

Imports: :mod:`onlinemap.sweeps`, :mod:`onlinemap.evaluate`.
"""

from __future__ import annotations

import os
from typing import NamedTuple, Sequence

import numpy as np
import pandas as pd

from ..sweeps import summarize, summary_wide, sweep


class Study(NamedTuple):
    """A study's result."""

    runs: pd.DataFrame  # one row per run (a sweep task): its configuration, seed and metrics
    summary: pd.DataFrame  # one row per group: runs, then NAME, NAME_low, NAME_high per metric


def summary_of(runs: pd.DataFrame, metrics: Sequence[str], by: Sequence[str], confidence: float = 0.95,
               bounds: dict[str, tuple[float, float]] | None = None) -> pd.DataFrame:
    """One row per group of ``runs`` (the columns ``by``, in order of appearance): ``runs`` and
    each metric's mean with its interval at ``confidence`` (NAME, NAME_low, NAME_high).
    ``bounds``: ranges tighter than the metric's own (e.g. a count of cells lies in [0, N])."""
    long = summarize(runs, [m for m in metrics if m in runs], confidence, by=list(by))
    for metric, (low, high) in (bounds or {}).items():
        rows = long["metric"] == metric
        long.loc[rows, "low"] = long.loc[rows, "low"].clip(lower=low)
        long.loc[rows, "high"] = long.loc[rows, "high"].clip(upper=high)
    return summary_wide(long)


def run_study(spec: dict, metrics: Sequence[str], by: Sequence[str], *, confidence: float = 0.95,
              workers: int | None = 0, out: str | os.PathLike | None = None, progress: bool = True,
              bounds: dict[str, tuple[float, float]] | None = None) -> Study:
    """Run ``spec`` on the sweep engine (``workers`` 0: in this process; N: on a local dask cluster
    of N processes; None: the engine picks; ``out``: a folder of parts, so a rerun resumes) and
    summarise it by ``by``."""
    runs = sweep(spec, workers=workers, results_dir=out, progress=progress)
    return Study(runs, summary_of(runs, metrics, by, confidence, bounds))


def with_intervals(summary: pd.DataFrame, metrics: Sequence[str], digits: int = 3) -> pd.DataFrame:
    """A summary with each metric as one ``mean [low, high]`` text column (for printing); the
    other columns (groups, runs) as they are."""
    metrics = [m for m in metrics if m in summary]
    keep = [c for c in summary.columns if c not in metrics and not c.endswith(("_low", "_high"))]
    table = summary[keep].copy()
    for name in metrics:
        table[name] = [f"{m:.{digits}f} [{lo:.{digits}f}, {hi:.{digits}f}]" if np.isfinite(lo) else
                       (f"{m:.{digits}f}" if np.isfinite(m) else "-")
                       for m, lo, hi in summary[[name, f"{name}_low", f"{name}_high"]].itertuples(index=False)]
    return table


def ordered(runs: pd.DataFrame, column: str, order: Sequence) -> pd.DataFrame:
    """``runs`` sorted by ``column`` in the given ``order`` (then by seed), stable."""
    position = {value: i for i, value in enumerate(order)}
    return runs.sort_values([column, "seed"], key=lambda c: c.map(position) if c.name == column else c,
                            kind="stable").reset_index(drop=True)
