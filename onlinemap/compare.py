"""Accuracy study: approximate estimators against exact Bayes on random runs (DESIGN.md
section 5, claim 2), used by ``onlinemap compare`` and ``notebooks/rbpf_vs_bk.ipynb``.

For every world and run (a random walk through a map drawn from the prior), every estimator
of :func:`compare_estimators` is run next to ``exact``; per step we record the total-variation
distance to exact of the location marginal (``location_tv``, over cells) and of the map
marginals (``map_tv``, the mean over cells of each cell's distance), and the map error against
the true (current) map. Worlds must be small enough for ``exact``.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
import pandas as pd
from matplotlib.figure import Figure
from .progress import tqdm

from . import metrics
from .estimators.rbpf import PROPOSALS
from .estimators import available_estimators, make_estimator, run_estimator
from .worlds import parse_world

DEFAULT_WORLDS = ("corridor:10", "corridor:10,p_change=0.02", "grid:3x3", "grid:3x3,p_change=0.02")
DEFAULT_PARTICLES = (10, 50, 100, 1000)


def compare_estimators(particles: Sequence[int] = DEFAULT_PARTICLES) -> list[tuple[str, str, dict]]:
    """(label, registry name, options) of the estimators compared with exact: bk, rbpf with each
    proposal and particle count, online_em (only if registered), dead_reckoning."""
    entries = [("bk", "bk", {})]
    entries += [(f"rbpf {proposal} P={n}", "rbpf", {"n_particles": int(n), "proposal": proposal})
                for proposal in PROPOSALS for n in particles]
    if "online_em" in available_estimators():
        entries.append(("online_em", "online_em", {}))
    entries.append(("dead_reckoning", "dead_reckoning", {}))
    return entries


def accuracy_study(worlds: Sequence[str] = DEFAULT_WORLDS, n_runs: int = 20, n_steps: int = 100,
                   particles: Sequence[int] = DEFAULT_PARTICLES, seed: int = 0,
                   progress: bool = True) -> pd.DataFrame:
    """Per-step distances to exact, one row per (world, run, estimator, t): columns world, run,
    estimator, particles (NaN unless rbpf), proposal, t, location_tv, map_tv, map_error and
    seconds (the estimator's mean wall time per step on that run). Particle filters are seeded
    from (seed, run). Cost: n_runs * n_steps steps of exact and of every estimator, per world.
    """
    entries = compare_estimators(particles)
    frames = []
    jobs = [(spec, r) for spec in worlds for r in range(n_runs)]
    for spec in worlds:  # load every numba kernel (resampling included) before anything is timed
        world = parse_world(spec)
        model, warm_up = world.model, world.simulate(5, 0)
        for name, options in [("exact", {})] + [(name, options) for _, name, options in entries]:
            options = {**options, "resample_threshold": 1.0} if name == "rbpf" else options
            run_estimator(make_estimator(name, model, **options), warm_up.actions, warm_up.observations)
    for spec, r in tqdm(jobs, desc="runs", disable=not progress, leave=False):
        world = parse_world(spec)
        run = world.simulate(n_steps, [seed, r])
        exact = run_estimator(make_estimator("exact", world.model), run.actions, run.observations)
        for label, name, options in [("exact", "exact", {})] + entries:
            if name == "rbpf":
                options = {**options, "seed": [seed, r]}
            trajectory = exact if name == "exact" else run_estimator(
                make_estimator(name, world.model, **options), run.actions, run.observations)
            frames.append(pd.DataFrame({
                "world": spec, "run": r, "estimator": label,
                "particles": options.get("n_particles", np.nan), "proposal": options.get("proposal"),
                "t": np.arange(run.n_steps),
                "location_tv": metrics.total_variation(trajectory.location, exact.location),
                "map_tv": metrics.total_variation(trajectory.map, exact.map).mean(axis=-1),
                "map_error": metrics.map_error(trajectory.map, run.maps),
                "seconds": trajectory.seconds_per_step}))
    return pd.concat(frames, ignore_index=True)


def summarise(per_step: pd.DataFrame) -> pd.DataFrame:
    """One row per (world, estimator): mean and worst (over runs and steps) location and map
    distances to exact, mean map error against the truth (over runs and steps) and at the last
    step, and ms per step."""
    grouped = per_step.groupby(["world", "estimator"], sort=False)
    last = per_step[per_step["t"] == per_step["t"].max()].groupby(["world", "estimator"], sort=False)
    return pd.DataFrame({
        "location_tv_mean": grouped["location_tv"].mean(),
        "location_tv_worst": grouped["location_tv"].max(),
        "map_tv_mean": grouped["map_tv"].mean(),
        "map_tv_worst": grouped["map_tv"].max(),
        "map_error_mean": grouped["map_error"].mean(),
        "map_error_final": last["map_error"].mean(),
        "ms_per_step": 1e3 * grouped["seconds"].mean(),
    }).reset_index()


def _world_axes(fig: Figure, worlds: list[str], rows: int = 1):
    axes = fig.subplots(rows, len(worlds), squeeze=False, sharey="row")
    for ax, world in zip(axes[0], worlds):
        ax.set_title(world, fontsize="small")
    return axes


def error_vs_particles_figure(summary: pd.DataFrame) -> Figure:
    """Per world: mean map (solid) and location (dotted) distance to exact against the number of
    particles for each proposal; horizontal lines for the estimators without particles."""
    worlds = list(dict.fromkeys(summary["world"]))
    fig = Figure(figsize=(3.6 * len(worlds), 3.4), layout="constrained")
    rbpf = summary["estimator"].str.startswith("rbpf ")
    for ax, world in zip(_world_axes(fig, worlds)[0], worlds):
        rows = summary[summary["world"] == world]
        for proposal, color in zip(PROPOSALS, ("C0", "C1")):
            sub = rows[rows["estimator"].str.startswith(f"rbpf {proposal} ")]
            n = sub["estimator"].str.extract(r"P=(\d+)")[0].astype(int)
            order = np.argsort(n.to_numpy())
            ax.plot(n.to_numpy()[order], sub["map_tv_mean"].to_numpy()[order], "o-", color=color,
                    label=f"rbpf {proposal}: map")
            ax.plot(n.to_numpy()[order], sub["location_tv_mean"].to_numpy()[order], "o:", color=color,
                    label=f"rbpf {proposal}: location")
        others = rows[~rbpf.loc[rows.index] & (rows["estimator"] != "exact")]
        for (label, value), color in zip(others[["estimator", "map_tv_mean"]].itertuples(index=False),
                                         ("C3", "C4", "C5", "C6")):
            ax.axhline(value, color=color, linestyle="--", linewidth=1, label=f"{label}: map")
        ax.set(xscale="log", yscale="log", xlabel="particles")
    fig.axes[0].set_ylabel("mean TV distance to exact")
    fig.axes[-1].legend(fontsize="x-small", loc="best")
    return fig


def error_over_time_figure(per_step: pd.DataFrame, estimators: Sequence[str] | None = None) -> Figure:
    """Per world: map (top) and location (bottom) distance to exact over time, mean over runs,
    for ``estimators`` (default: all but exact and the transition-proposal filters)."""
    worlds = list(dict.fromkeys(per_step["world"]))
    if estimators is None:
        names = dict.fromkeys(per_step["estimator"])
        estimators = [e for e in names if e != "exact" and not e.startswith("rbpf transition")]
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
