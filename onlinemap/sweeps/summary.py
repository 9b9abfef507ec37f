"""Summaries of a sweep table: means over seeds with confidence intervals per configuration,
a readable pivot, and plots against an option.

Intervals (:func:`onlinemap.stats.mean_interval`): Wilson for yes/no outcomes, Student t for
the rest, intersected with the metric's range (:func:`onlinemap.evaluate.metric_bounds`: errors,
distances and entropies lie in [0, 1], counts of cells in [0, N] for the configuration's world of
N cells), which keeps the interval's coverage (the true mean lies in the range) and never prints
an impossible bound.

Imports: :mod:`.tasks`, :mod:`.runner` (the parsed worlds), :mod:`onlinemap.evaluate`,
:mod:`onlinemap.stats`; matplotlib lazily.
"""

from __future__ import annotations

import itertools
import math
import os
import textwrap
from typing import Iterable

import numpy as np
import pandas as pd

from ..errors import OnlineMapError
from ..evaluate import RUN_METRICS, STEP_METRICS, metric_bounds
from ..stats import mean_interval
from .runner import world
from .tasks import CONFIG_COLUMNS


def _interval(column: pd.Series, metric: str, confidence: float, n_cells: int | None = None):
    return mean_interval(column.to_numpy(dtype=np.float64, na_value=np.nan), confidence,
                         proportion=pd.api.types.is_bool_dtype(column), bounds=metric_bounds(metric, n_cells))


def cell_count(group: pd.DataFrame) -> int | None:
    """The number of cells of the world(s) of a group of rows (the largest, if several), read from
    its ``world`` column; None when there is none or a world no longer parses (a layout file
    gone)."""
    if "world" not in group:
        return None
    try:
        return max(world(spec).model.n_cells for spec in group["world"].dropna().unique())
    except (OnlineMapError, ValueError):  # an empty column, or a world that does not parse here
        return None


def last_steps(table: pd.DataFrame) -> pd.DataFrame:
    """A per-step table (with a ``t`` column) cut to each task's last step; others unchanged."""
    if "t" in table.columns:
        table = table.sort_values("t").groupby("task", sort=False).tail(1)
    return table


def summarize(table: pd.DataFrame, metrics_: Iterable[str] | None = None, confidence: float = 0.95, *,
              by: Iterable[str] | None = None) -> pd.DataFrame:
    """Per configuration (the columns ``by``; default every task column that varies but the
    seed; with one configuration, its estimator or planner), for each metric: n, mean and a
    ``confidence`` interval over seeds (see :func:`mean_interval`; Wilson for boolean columns).
    A per-step table is summarised at each task's last step. One row per configuration and
    metric, configurations in order of appearance. Every study's summary is this one
    (:func:`summary_wide` and :func:`summary_table` are views of it)."""
    table = last_steps(table)
    known = tuple(dict.fromkeys(RUN_METRICS + STEP_METRICS))
    chosen = [m for m in dict.fromkeys(metrics_ or known) if m in table.columns]
    missing = [m for m in (metrics_ or ()) if m not in table.columns]
    if missing:
        raise OnlineMapError(f"no metric {', '.join(missing)} in the table; it has: "
                             f"{', '.join(m for m in known if m in table.columns)}")
    if by is not None:
        config = list(by)
    else:
        config = [c for c in CONFIG_COLUMNS if c in table.columns and table[c].nunique(dropna=False) > 1] or \
            [c for c in ("estimator", "planner") if c in table.columns][:1]  # one configuration: name it
    rows = []
    groups = table.groupby(config, sort=False, dropna=False) if config else [((), table)]
    for keys, group in groups:
        keys = keys if isinstance(keys, tuple) else (keys,)
        n_cells = cell_count(group) if any("wrong" in m or m.endswith("known_cells") for m in chosen) else None
        for metric in chosen:
            interval = _interval(group[metric], metric, confidence, n_cells)
            if math.isnan(interval.mean):
                continue
            rows.append({**dict(zip(config, keys)), "metric": metric, "n": len(group),
                         "mean": interval.mean, "low": interval.low, "high": interval.high})
    return pd.DataFrame(rows, columns=[*config, "metric", "n", "mean", "low", "high"])


def summary_wide(summary: pd.DataFrame) -> pd.DataFrame:
    """The long summary with one row per configuration: ``runs`` (the largest n) and, per
    metric, columns ``NAME``, ``NAME_low``, ``NAME_high``."""
    config = [c for c in summary.columns if c not in ("metric", "n", "mean", "low", "high")]
    rows = []
    if summary.empty:  # no run to summarise (e.g. none where the oracle reached the goal)
        return pd.DataFrame(columns=[*config, "runs"])
    for keys, group in summary.groupby(config, sort=False, dropna=False) if config else [((), summary)]:
        keys = keys if isinstance(keys, tuple) else (keys,)
        row = {**dict(zip(config, keys)), "runs": int(group["n"].max())}
        for metric, mean, low, high in group[["metric", "mean", "low", "high"]].itertuples(index=False):
            row.update({metric: mean, f"{metric}_low": low, f"{metric}_high": high})
        rows.append(row)
    return pd.DataFrame(rows)


def summary_table(summary: pd.DataFrame) -> pd.DataFrame:
    """The long summary pivoted for reading: one row per configuration, one column per metric
    holding ``mean [low, high]``."""
    if summary.empty:
        return summary
    config = [c for c in summary.columns if c not in ("metric", "n", "mean", "low", "high")]

    def cell(row) -> str:
        if np.isnan(row["low"]):
            return f"{row['mean']:.4g}"
        return f"{row['mean']:.4g} [{row['low']:.4g}, {row['high']:.4g}]"

    summary = summary.assign(cell=summary.apply(cell, axis=1))
    wide = summary.pivot_table(index=config + ["n"], columns="metric", values="cell", aggfunc="first", sort=False)
    order = [m for m in dict.fromkeys(summary["metric"]) if m in wide.columns]
    return wide[order].reset_index().rename_axis(columns=None)


LEGEND_CHAR_INCHES = 0.075  # the width of a character of the 7-point legend, with room to spare


def plot_sweep(table: pd.DataFrame, x: str, metrics_: Iterable[str], path: str | os.PathLike | None = None,
               confidence: float = 0.95):
    """One panel per metric: its mean over seeds against ``x`` (an option name, e.g.
    ``n_particles``, or a task column such as ``world`` or ``steps``) with ``confidence``
    intervals as error bars, one line per remaining configuration; a positive ``x`` spanning more
    than a doubling (particle counts) on a log axis; the legend below the panels. A per-step table is read at
    each task's last step. Saves to ``path`` if given; returns the matplotlib figure."""
    import matplotlib.pyplot as plt

    table = last_steps(table)
    column = x if x in table.columns else f"opt_{x}"
    if column not in table.columns:
        options = sorted(c[4:] for c in table.columns if c.startswith("opt_"))
        raise OnlineMapError(f"--x {x!r}: not an option or column of the table; options: {', '.join(options)}")
    metrics_ = [m for m in metrics_ if m in table.columns] or ["final_map_error"]
    table = _with_line_labels(table, column)
    flat = table[table[column].isna()]  # configurations without that option: horizontal lines
    table = table[table[column].notna()]
    numeric = pd.api.types.is_numeric_dtype(table[column])
    positions = None if numeric else {v: i for i, v in enumerate(dict.fromkeys(table[column]))}
    figure, axes = plt.subplots(1, len(metrics_), figsize=(5 * len(metrics_), 3.8), squeeze=False,
                                layout="constrained")
    for axis, metric in zip(axes[0], metrics_):
        _draw_panel(axis, table, flat, x, column, metric, confidence, positions)
    _legend_below(figure, *axes[0][0].get_legend_handles_labels())
    figure.suptitle(f"mean over seeds with {confidence:.0%} intervals")
    if path is not None:
        from .. import plots

        plots.save(figure, path, dpi=120)
    return figure


def _with_line_labels(table: pd.DataFrame, column: str) -> pd.DataFrame:
    """``table`` with a column ``_line``: the label of each row's configuration, the columns
    besides ``column`` that vary across the table ("all" if none does)."""
    varying = [c for c in ("world", "estimator", "planner", "walk", "steps", "reference")
               if c in table.columns and c != column and table[c].nunique() > 1]
    varying += [c for c in table.columns if c.startswith(("opt_", "planner_opt_")) and c != column
                and table[c].nunique() > 1]

    def label(row) -> str:
        parts = [f"{c.removeprefix('planner_opt_').removeprefix('opt_')}={row[c]}" if c.startswith(("opt_", "planner_opt_"))
                 else str(row[c]) for c in varying if pd.notna(row[c]) and row[c] != ""]
        return ", ".join(parts) or "all"

    return table.assign(_line=table.apply(label, axis=1) if len(table) else [])


def _draw_panel(axis, table: pd.DataFrame, flat: pd.DataFrame, x: str, column: str, metric: str, confidence: float,
                positions: dict | None) -> None:
    """One panel: ``metric``'s mean and interval against ``column`` per line of ``table``, a
    horizontal line per configuration of ``flat`` (without the option); a positive numeric
    ``column`` spanning more than a doubling on a log axis, categories (``positions``) in order."""
    numeric = positions is None
    for line, group in table.groupby("_line", sort=False):
        points = [(value, _interval(g[metric], metric, confidence, cell_count(g)))
                  for value, g in group.groupby(column, sort=True)]
        xs = np.array([v if numeric else positions[v] for v, _ in points], dtype=np.float64)
        means = np.array([i.mean for _, i in points])
        errors = np.array([[i.mean - i.low, i.high - i.mean] for _, i in points]).T
        # bounds can round a hair past the mean (a Wilson bound at 0 or 1 successes): never negative
        axis.errorbar(xs, means, yerr=np.maximum(np.nan_to_num(errors), 0.0), marker="o", capsize=3, label=line)
    for style, (line, group) in zip(itertools.cycle(("--", ":", "-.")), flat.groupby("_line", sort=False)):
        level = _interval(group[metric], metric, confidence, cell_count(group))
        axis.axhline(level.mean, linestyle=style, color="gray", label=f"{line} (no {x})")
    if numeric and table[column].min() > 0 and table[column].max() / table[column].min() > 2:
        axis.set_xscale("log")  # particle counts and the like: a grid of doublings or decades
        axis.set_xticks(sorted(set(table[column])), [f"{v:g}" for v in sorted(set(table[column]))])
    if positions is not None:
        axis.set_xticks(range(len(positions)), list(positions), rotation=20)
    axis.set_xlabel(x)
    axis.set_ylabel(metric)
    axis.grid(alpha=0.3)


def _legend_below(figure, handles: list, labels: list[str]) -> None:
    """The legend below the panels, the figure made taller to hold it: as many columns (at most 3)
    as the labels fit across the figure, long labels wrapped to fit one ("outside": the
    constrained layout makes room below the panels, so nothing is cut)."""
    width = figure.get_figwidth() / LEGEND_CHAR_INCHES  # characters across the figure
    longest = max((len(label) for label in labels), default=1) + 6  # with the marker
    columns = max(1, min(3, len(labels), int(width // longest)))
    labels = [textwrap.fill(label, int(width / columns) - 6) for label in labels]
    lines = sum(label.count("\n") + 1 for label in labels[::columns])  # one row of the legend per line
    figure.set_figheight(3.8 + 0.15 * lines)
    figure.legend(handles, labels, loc="outside lower center", ncol=columns, fontsize=7, frameon=False)
