"""Reproductions of the literature's claims (DESIGN.md section 5), used by ``onlinemap
reproduce`` and the notebooks.

Claim 1, the 1D corridor: on Murphy's scripted run, exact Bayes ends with the right map and
knows where it is; online EM (any window, any decay) locks onto a wrong map and gets lost on
the way back; offline EM, with hindsight, does well; dead reckoning blurs.
:func:`corridor_table` measures this on one run, :func:`random_corridor_study` on many random
ones (random labels, lengths and slip times) with Wilson confidence intervals.

The estimators compared are the entries of :data:`CORRIDOR_ESTIMATORS`; adding an estimator to
every table, figure and study is adding one entry there.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import pandas as pd
from .progress import tqdm

from . import metrics
from .estimators import Trajectory, make_estimator, run_estimator
from .scenarios import one_slip_corridor
from .rng import SeedLike, as_generator
from .simulate import Run
from .stats import wilson_interval

CORRIDOR_WINDOWS = (1, 2, 4, 8, "max")
CORRIDOR_DECAYS = (0.8, 0.9, 0.95, 1.0)

#: (label, registry name, options) of every estimator in the corridor reproduction.
CORRIDOR_ESTIMATORS: list[tuple[str, str, dict]] = [
    ("exact", "exact", {}),
    ("dead_reckoning", "dead_reckoning", {}),
    *((f"online_em W={w} decay={d}", "online_em", {"window": w, "decay": d})
      for w in CORRIDOR_WINDOWS for d in CORRIDOR_DECAYS),
    ("offline_em", "offline_em", {}),
    ("bk", "bk", {}),
    ("rbpf P=100", "rbpf", {"n_particles": 100, "seed": 0}),
]

LOST_BELOW = 0.5  # a robot whose P(true location) is below this is "lost"
ASTRAY_BELOW = 0.05  # ... and below this, confidently in the wrong place ("astray")
STUDY_OUTCOMES = ("astray_way_back", "ends_lost", "wrong_map", "ends_lost_or_wrong_map")


def way_back(run: Run) -> np.ndarray:
    """(T,) True at the steps after the robot turned (after its first action that differs
    from the first action); all False if it never turns."""
    turns = np.flatnonzero(run.actions != run.actions[0])
    mask = np.zeros(run.n_steps, dtype=bool)
    if len(turns):
        mask[turns[0] + 1:] = True
    return mask


def corridor_scores(run: Run, trajectory: Trajectory) -> dict[str, float]:
    """How one estimator did on one run (a static world).

    final_map_error: mean over all cells of 1 - P(true label) at the end; wrong_visited: visited
    cells whose most likely label is wrong at the end; min_p_true_way_back / final_p_true:
    P(true location) at its lowest after the turn / at the last step; lost_way_back /
    ends_lost: those below :data:`LOST_BELOW`; astray_way_back: the lowest below
    :data:`ASTRAY_BELOW` (an uncertain Bayesian robot is often "lost" at 0.5 on the way back, a
    robot with a wrong map is confidently wrong).
    """
    p_true = trajectory.location[np.arange(run.n_steps), run.locations]
    back = way_back(run)
    visited = np.unique(run.locations)
    lowest_back = float(p_true[back].min()) if back.any() else math.nan
    return {
        "final_map_error": float(metrics.map_error(trajectory.map[-1], run.final_map)),
        "wrong_visited": metrics.wrong_cells(trajectory.map[-1], run.final_map, visited),
        "min_p_true_way_back": lowest_back,
        "final_p_true": float(p_true[-1]),
        "lost_way_back": bool(lowest_back < LOST_BELOW),
        "astray_way_back": bool(lowest_back < ASTRAY_BELOW),
        "ends_lost": bool(p_true[-1] < LOST_BELOW),
        "ms_per_step": 1e3 * trajectory.seconds_per_step,
    }


def corridor_table(run: Run, estimators=None, progress: bool = True) -> tuple[pd.DataFrame, dict[str, Trajectory]]:
    """Run every (label, name, options) of ``estimators`` (default :data:`CORRIDOR_ESTIMATORS`)
    over ``run``. Returns one row of :func:`corridor_scores` per estimator, and the trajectories
    by label."""
    rows, trajectories = [], {}
    for label, name, options in tqdm(estimators or CORRIDOR_ESTIMATORS, desc="estimators",
                                     disable=not progress, leave=False):
        trajectory = run_estimator(make_estimator(name, run.model, **options), run.actions, run.observations)
        trajectories[label] = trajectory
        rows.append({"estimator": label, **corridor_scores(run, trajectory)})
    return pd.DataFrame(rows), trajectories


class CorridorDraw(NamedTuple):
    """One random corridor run of the study and how it was drawn."""

    run: Run
    labels: np.ndarray  # (N,) the true labels
    slip: int  # the outward move (1-based step) that fails


def random_corridor(seed: SeedLike = None, n_cells: tuple[int, int] = (6, 12), p_obs: float = 0.9,
                    p_move: float = 0.8) -> CorridorDraw:
    """A scripted there-and-back run (:func:`onlinemap.scenarios.scripted_corridor`) with N drawn
    uniformly in ``n_cells`` (inclusive), i.i.d. uniform binary labels and one slip at a move
    of the way out drawn uniformly in 1..N-1."""
    rng = as_generator(seed)
    n = int(rng.integers(n_cells[0], n_cells[1] + 1))
    labels = rng.integers(0, 2, size=n)
    run, slip = one_slip_corridor(labels, rng, p_obs=p_obs, p_move=p_move)
    return CorridorDraw(run, labels, slip)


def random_corridor_study(n_runs: int, seed: SeedLike = 0, estimators=None, confidence: float = 0.95,
                          progress: bool = True) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Run every estimator on ``n_runs`` random corridors (:func:`random_corridor`).

    Returns (per-run table: run, n_cells, slip, estimator and :func:`corridor_scores`; summary
    per estimator: the fraction of runs in :data:`STUDY_OUTCOMES` (astray on the way back, ends
    lost, wrong map, ends lost or with a wrong map), each with its Wilson interval at
    ``confidence`` (columns NAME, NAME_low, NAME_high), and the mean lowest P(true location)
    on the way back). Cost: n_runs times the cost of :func:`corridor_table`.
    """
    rng = as_generator(seed)
    frames = []
    for index in tqdm(range(int(n_runs)), desc="random corridors", disable=not progress):
        draw = random_corridor(rng)
        table, _ = corridor_table(draw.run, estimators, progress=False)
        table.insert(0, "run", index)
        table.insert(1, "n_cells", len(draw.labels))
        table.insert(2, "slip", draw.slip)
        frames.append(table)
    per_run = pd.concat(frames, ignore_index=True)
    per_run["wrong_map"] = per_run["wrong_visited"] > 0
    per_run["ends_lost_or_wrong_map"] = per_run["ends_lost"] | per_run["wrong_map"]
    grouped = per_run.groupby("estimator", sort=False)
    summary = pd.DataFrame({"runs": grouped.size()})
    for column in STUDY_OUTCOMES:
        hits = grouped[column].sum()
        low, high = wilson_interval(hits, summary["runs"], confidence)
        summary[column] = hits / summary["runs"]
        summary[f"{column}_low"], summary[f"{column}_high"] = low, high
    summary["mean_min_p_true_way_back"] = grouped["min_p_true_way_back"].mean()
    return per_run, summary.reset_index()


def with_intervals(summary: pd.DataFrame) -> pd.DataFrame:
    """The study summary with each outcome as one "fraction [low, high]" text column (for printing)."""
    table = summary[["estimator", "runs"]].copy()
    for column in STUDY_OUTCOMES:
        table[column] = [f"{p:.2f} [{lo:.2f}, {hi:.2f}]" for p, lo, hi in
                         summary[[column, f"{column}_low", f"{column}_high"]].itertuples(index=False)]
    table["mean_min_p_true_way_back"] = summary["mean_min_p_true_way_back"]
    return table

