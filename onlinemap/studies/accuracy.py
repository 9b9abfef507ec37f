"""Accuracy study: approximate estimators against exact Bayes on random runs (DESIGN.md
section 5, claim 2), used by ``onlinemap compare`` and ``notebooks/rbpf_vs_bk.ipynb``.

For every world and run (a random walk through a map drawn from the prior), every estimator
of :func:`compare_estimators` is run next to ``exact``, as a sweep (:func:`study_spec` on
:func:`onlinemap.sweeps.sweep`, so it runs on dask, resumes and writes parquet like any sweep);
per step it records (:mod:`onlinemap.evaluate`) the total-variation distance to exact of the
location marginal (``location_tv``, over cells) and of the map marginals (``map_tv``, the mean
over cells of each cell's distance), and the map error against the true (current) map. Worlds
must be small enough for ``exact``.
"""

from __future__ import annotations

from typing import Mapping, Sequence

import pandas as pd
from matplotlib.figure import Figure
from matplotlib.ticker import NullFormatter

from ..errors import ModelError
from ..estimators import available_estimators
from ..estimators.rbpf import SCHEMES

DEFAULT_WORLDS = ("corridor:10", "corridor:10,p_change=0.02", "grid:3x3", "grid:3x3,p_change=0.02")
DEFAULT_PARTICLES = (10, 50, 100, 1000)


def compare_estimators(particles: Sequence[int] = DEFAULT_PARTICLES) -> list[tuple[str, str, dict]]:
    """(label, registry name, options) of the estimators compared with exact: bk, rbpf with each
    scheme of :data:`onlinemap.estimators.rbpf.SCHEMES` and particle count (``rbpf FC P=100``),
    online_em (only if registered), dead_reckoning."""
    entries = [("bk", "bk", {})]
    entries += [(label("rbpf", scheme, n), "rbpf", {"n_particles": int(n), **options})
                for scheme, options in SCHEMES.items() for n in particles]
    if "online_em" in available_estimators():
        entries.append(("online_em", "online_em", {}))
    entries.append(("dead_reckoning", "dead_reckoning", {}))
    return entries


def study_spec(worlds: Sequence[str] = DEFAULT_WORLDS, n_runs: int = 20, n_steps: int = 100,
               particles: Sequence[int] = DEFAULT_PARTICLES, seed: int = 0,
               options: Mapping[str, Mapping[str, object]] | None = None) -> dict:
    """The accuracy study as a sweep spec (:mod:`onlinemap.sweeps`): every world, seeds
    ``seed .. seed + n_runs - 1``, ``n_steps`` steps of a random walk, one row per step, exact
    Bayes as the reference, and every estimator of :func:`compare_estimators`, each rbpf scheme
    labelled with its name. ``options``: extra options per registry name (e.g.
    ``{"rbpf": {"block_cells": 4}}``), added to each of that estimator's configurations; the
    rbpf's scheme keys (``n_particles``, ``proposal``, ``resampling``) are the study's own and
    cannot be overridden."""
    options = {name: dict(extra) for name, extra in (options or {}).items()}
    fixed = {"n_particles", "proposal", "resampling"} & set(options.get("rbpf", ()))
    if fixed:
        raise ModelError(f"compare sets the rbpf's {', '.join(sorted(fixed))} itself (its schemes and --particles)")
    estimators: dict[str, object] = {"exact": options.get("exact", {})}
    for _, name, _ in compare_estimators(particles):
        if name == "rbpf":  # one grid per scheme: the schemes are not a product of proposals and resamplers
            estimators["rbpf"] = [{"label": scheme, "n_particles": [int(n) for n in particles], **scheme_options,
                                   **options.get("rbpf", {})} for scheme, scheme_options in SCHEMES.items()]
        else:
            estimators[name] = options.get(name, {})
    return {"name": "compare", "worlds": list(worlds), "seeds": list(range(int(seed), int(seed) + int(n_runs))),
            "steps": int(n_steps), "rows": "step", "reference": "exact", "estimators": estimators}


def label(estimator: str, scheme: str | None = None, n_particles: int | None = None) -> str:
    """The study's display name of a configuration: ``rbpf FC P=100`` for an rbpf scheme
    (:data:`onlinemap.estimators.rbpf.SCHEMES`) and particle count, else the registry name."""
    return f"rbpf {scheme} P={int(n_particles)}" if estimator == "rbpf" else estimator


def accuracy_study(worlds: Sequence[str] = DEFAULT_WORLDS, n_runs: int = 20, n_steps: int = 100,
                   particles: Sequence[int] = DEFAULT_PARTICLES, seed: int = 0, progress: bool = True, *,
                   workers: int | None = 0, out=None,
                   options: Mapping[str, Mapping[str, object]] | None = None) -> pd.DataFrame:
    """Per-step distances to exact, run on the sweep engine (:func:`study_spec`; ``workers`` as in
    :func:`onlinemap.sweeps.sweep`: 0 runs serially here; ``out``: a folder of parts, so a rerun
    resumes; ``options`` as in :func:`study_spec`). One row per (world, run, estimator, t): the sweep's per-step columns
    (:mod:`onlinemap.evaluate`: ``location_tv``, ``map_tv``, ``map_error``, ``ms_per_step``, ...)
    plus ``run`` (the seed), ``particles`` (NaN unless rbpf), ``proposal``, ``resampling`` (in
    place of the sweep's ``opt_n_particles``, ``opt_proposal``, ``opt_resampling``) and
    ``estimator`` relabelled by :func:`label`. Cost: n_runs * n_steps steps of exact and of every estimator,
    per world."""
    from ..sweeps import sweep

    table = sweep(study_spec(worlds, n_runs, n_steps, particles, seed, options), workers=workers, results_dir=out,
                  progress=progress)
    rbpf = table["estimator"] == "rbpf"
    count = table["opt_n_particles"] if "opt_n_particles" in table else pd.Series(pd.NA, index=table.index)
    table["scheme"] = table["label"].where(rbpf) if "label" in table else None
    table["particles"] = count.astype("Float64").where(rbpf)
    table["estimator"] = [label(e, s, n) for e, s, n in zip(table["estimator"], table["scheme"], count)]
    table["run"] = table["seed"]
    for column in ("proposal", "resampling"):
        table[column] = table[f"opt_{column}"] if f"opt_{column}" in table else None
    # the scheme's options are the columns above now: their opt_ copies would repeat them
    return table.drop(columns=["opt_n_particles", "opt_proposal", "opt_resampling"], errors="ignore")


def summarise(per_step: pd.DataFrame) -> pd.DataFrame:
    """One row per (world, estimator): mean and worst (over runs and steps) location and map
    distances to exact, mean map error against the truth (over runs and steps) and at the last
    step, the honest metrics (:data:`onlinemap.evaluate.HONEST_METRICS`; over runs and steps: the
    expected location distance and the calibration gaps; at the last step: the excess map error
    over the told-location map), and ms per step (after a warm-up run)."""
    grouped = per_step.groupby(["world", "estimator"], sort=False)
    last = per_step[per_step["t"] == per_step["t"].max()].groupby(["world", "estimator"], sort=False)
    honest = {}
    if "location_distance" in per_step:  # tables written before the honest metrics lack them
        honest = {"mean_location_distance": grouped["location_distance"].mean(),
                  "location_calibration_gap": (1.0 - grouped["location_error"].mean())
                  - grouped["location_claimed"].mean(),
                  "map_calibration_gap": grouped["read_map_p_true"].mean() - grouped["read_map_claimed"].mean(),
                  "excess_map_error": last["excess_map_error"].mean()}
    return pd.DataFrame({
        "scheme": grouped["scheme"].first(),
        "particles": grouped["particles"].first(),
        "mean_location_tv": grouped["location_tv"].mean(),
        "worst_location_tv": grouped["location_tv"].max(),
        "mean_map_tv": grouped["map_tv"].mean(),
        "worst_map_tv": grouped["map_tv"].max(),
        "mean_map_error": grouped["map_error"].mean(),
        "final_map_error": last["map_error"].mean(),
        **honest,
        "ms_per_step": grouped["ms_per_step"].mean(),
    }).reset_index()


def _world_axes(fig: Figure, worlds: list[str], rows: int = 1):
    axes = fig.subplots(rows, len(worlds), squeeze=False, sharey="row")
    for ax, world in zip(axes[0], worlds):
        ax.set_title(world, fontsize="small")
    return axes


def _world_panels(summary: pd.DataFrame) -> tuple[Figure, list[tuple[object, pd.DataFrame]]]:
    """A figure with one panel per world of a :func:`summarise` table, and (axis, rows) per panel."""
    worlds = list(dict.fromkeys(summary["world"]))
    fig = Figure(figsize=(3.6 * len(worlds), 3.4), layout="constrained")
    return fig, [(ax, summary[summary["world"] == world]) for ax, world in zip(_world_axes(fig, worlds)[0], worlds)]


def _scheme_rows(rows: pd.DataFrame) -> dict[str, pd.DataFrame]:
    """The rbpf rows of a :func:`summarise` table per scheme, by increasing particle count."""
    return {scheme: group.sort_values("particles") for scheme, group in
            rows[rows["scheme"].notna()].groupby("scheme", sort=False)}


def _others(rows: pd.DataFrame) -> pd.DataFrame:
    """The estimators of a :func:`summarise` table without particles, exact left out."""
    return rows[rows["scheme"].isna() & (rows["estimator"] != "exact")]


def error_vs_particles_figure(summary: pd.DataFrame) -> Figure:
    """Per world: mean map (solid) and location (dotted) distance to exact against the number of
    particles for each rbpf scheme (:data:`onlinemap.estimators.rbpf.SCHEMES`); horizontal lines
    for the estimators without particles."""
    fig, panels = _world_panels(summary)
    for ax, rows in panels:
        for (scheme, sub), color in zip(_scheme_rows(rows).items(), ("C0", "C1", "C2")):
            ax.plot(sub["particles"], sub["mean_map_tv"], "o-", color=color, label=f"rbpf {scheme}: map")
            ax.plot(sub["particles"], sub["mean_location_tv"], "o:", color=color, label=f"rbpf {scheme}: location")
        for (name, value), color in zip(_others(rows)[["estimator", "mean_map_tv"]].itertuples(index=False),
                                        ("C3", "C4", "C5", "C6")):
            ax.axhline(value, color=color, linestyle="--", linewidth=1, label=f"{name}: map")
        ax.set(xscale="log", yscale="log", xlabel="particles")
    fig.axes[0].set_ylabel("mean TV distance to exact")
    fig.axes[-1].legend(fontsize="x-small", loc="best")
    return fig


def error_vs_time_figure(summary: pd.DataFrame) -> Figure:
    """Per world: mean map distance to exact against milliseconds per step, one line per rbpf
    scheme through its particle counts (annotated), one point per estimator without particles:
    which scheme buys accuracy cheapest."""
    fig, panels = _world_panels(summary)
    for ax, rows in panels:
        for (scheme, sub), color in zip(_scheme_rows(rows).items(), ("C0", "C1", "C2")):
            ax.plot(sub["ms_per_step"], sub["mean_map_tv"], "o-", color=color, label=f"rbpf {scheme}")
            for x, y, n in zip(sub["ms_per_step"], sub["mean_map_tv"], sub["particles"]):
                ax.annotate(f"{n}", (x, y), fontsize="xx-small", color=color, xytext=(2, 2),
                            textcoords="offset points")
        for (name, ms, value), color in zip(
                _others(rows)[["estimator", "ms_per_step", "mean_map_tv"]].itertuples(index=False),
                ("C3", "C4", "C5", "C6")):
            ax.plot([ms], [value], "s", color=color, label=name)
        ax.set(xscale="log", yscale="log", xlabel="ms per step")
        ax.xaxis.set_minor_formatter(NullFormatter())  # a span under a decade labels every minor tick
    fig.axes[0].set_ylabel("mean map TV distance to exact")
    fig.axes[-1].legend(fontsize="x-small", loc="best")
    return fig


def error_over_time_figure(per_step: pd.DataFrame, estimators: Sequence[str] | None = None) -> Figure:
    """Per world: map (top) and location (bottom) distance to exact over time, mean over runs,
    for ``estimators`` (default: all but exact and the transition+residual filters)."""
    worlds = list(dict.fromkeys(per_step["world"]))
    if estimators is None:
        shown = (per_step["estimator"] != "exact") & (per_step["scheme"] != "transition+residual")
        estimators = list(dict.fromkeys(per_step.loc[shown, "estimator"]))
    mean = per_step.groupby(["world", "estimator", "t"], sort=False)[["map_tv", "location_tv"]].mean()
    fig = Figure(figsize=(3.6 * len(worlds), 6), layout="constrained")
    axes = _world_axes(fig, worlds, rows=2)
    for what, row in zip(worlds, axes.T):
        for label in estimators:
            series = mean.loc[(what, label)]
            row[0].plot(series.index, series["map_tv"].to_numpy(), label=label, linewidth=1)
            row[1].plot(series.index, series["location_tv"].to_numpy(), label=label, linewidth=1)
        for ax in row:
            ax.set(xlabel="step t", yscale="log", ylim=(1e-4, 1.5))
    axes[0, 0].set_ylabel("map TV to exact (mean over runs)")
    axes[1, 0].set_ylabel("location TV to exact")
    axes[0, -1].legend(fontsize="x-small", loc="lower right")
    return fig
