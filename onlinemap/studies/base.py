"""What every study shares: one row per run (a sweep task), and one summary with intervals over
seeds (:func:`onlinemap.sweeps.summarize`, Student t intersected with the
metric's range, Wilson for yes/no outcomes).

Imports: :mod:`onlinemap.sweeps`, :mod:`onlinemap.evaluate`.
"""

from __future__ import annotations

from types import MappingProxyType
from typing import Mapping, NamedTuple, Sequence

import numpy as np
import pandas as pd

from ..sweeps import summarize, summary_wide
from ..sweeps.kinds import Played


class _Pair(NamedTuple):
    runs: pd.DataFrame  # one row per run (a sweep task): its configuration, seed and metrics
    summary: pd.DataFrame  # one row per group: runs, then NAME, NAME_low, NAME_high per metric


class Study(_Pair):
    """A study's result: the pair ``runs, summary = study``; and ``played``, the true run and the
    beliefs (:class:`~onlinemap.sweeps.kinds.Played`) of the runs it was asked to keep, by
    ``(world, planner, seed)`` (empty unless asked: ``planners_study(..., keep=...)``)."""

    played: Mapping[tuple, Played] = MappingProxyType({})

    def __new__(cls, runs: pd.DataFrame, summary: pd.DataFrame, played: Mapping[tuple, Played] | None = None):
        study = super().__new__(cls, runs, summary)
        if played:
            study.played = MappingProxyType(dict(played))
        return study


def summary_of(runs: pd.DataFrame, metrics: Sequence[str], by: Sequence[str], confidence: float = 0.95,
               bounds: dict[str, tuple[float, float]] | None = None) -> pd.DataFrame:
    """One row per group of ``runs`` (the columns ``by``, in order of appearance): ``runs`` and
    each metric's mean with its interval at ``confidence`` (NAME, NAME_low, NAME_high).
    ``bounds``: ranges tighter than the metric's own (e.g. a count of cells lies in [0, N]).
    A metric of ``runs`` with no value in any run (steps to a map error no run reached) keeps
    its columns, NaN."""
    present = [m for m in metrics if m in runs]
    long = summarize(runs, present, confidence, by=list(by))
    for metric, (low, high) in (bounds or {}).items():
        rows = long["metric"] == metric
        long.loc[rows, "low"] = long.loc[rows, "low"].clip(lower=low)
        long.loc[rows, "high"] = long.loc[rows, "high"].clip(upper=high)
    wide = summary_wide(long)
    for metric in present:
        for name in (metric, f"{metric}_low", f"{metric}_high"):
            if name not in wide:
                wide[name] = np.nan
    return wide


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
