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

import pandas as pd

from ..estimators import Trajectory
from ..evaluate import run_metrics, step_metrics, timed_trajectory
from ..progress import show_progress, tqdm
from ..simulate import Run
from .base import summary_of

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

STUDY_OUTCOMES = ("astray_way_back", "ends_lost", "wrong_map", "ends_lost_or_wrong_map")
#: the corridor table's columns (from :func:`onlinemap.evaluate.run_metrics`, plus final_p_true)
CORRIDOR_COLUMNS = ("final_map_error", "wrong_visited", "min_p_true_way_back", "final_p_true", "astray_way_back",
                    "ends_lost", "ms_per_step")


def corridor_scores(run: Run, trajectory: Trajectory) -> dict[str, float]:
    """How one estimator did on one run (a static world): the :data:`CORRIDOR_COLUMNS` of
    :func:`onlinemap.evaluate.run_metrics` (final map error; ``wrong_visited``: visited cells whose
    most likely final label is wrong; the lowest P(true location) after the turn and whether it
    fell below :data:`~onlinemap.evaluate.ASTRAY_BELOW`; ``ends_lost``: final P(true location)
    below :data:`~onlinemap.evaluate.LOST_BELOW`) and ``final_p_true``, P(true location) at the end.
    """
    row = run_metrics(run, trajectory, trip=True)
    row["final_p_true"] = 1.0 - row["final_location_error"]
    return {name: row.get(name, math.nan) for name in CORRIDOR_COLUMNS}


def corridor_table(run: Run, estimators=None, progress: bool = True) -> tuple[pd.DataFrame, dict[str, Trajectory]]:
    """Run every (label, name, options) of ``estimators`` (default :data:`CORRIDOR_ESTIMATORS`)
    over ``run``. Returns one row of :func:`corridor_scores` per estimator, and the trajectories
    by label."""
    rows, trajectories = [], {}
    for label, name, options in tqdm(estimators or CORRIDOR_ESTIMATORS, desc="estimators",
                                     disable=not show_progress(progress), leave=False):
        trajectory = timed_trajectory(name, run.model, options, run)
        trajectories[label] = trajectory
        rows.append({"estimator": label, **corridor_scores(run, trajectory)})
    return pd.DataFrame(rows), trajectories


RANDOM_LENGTHS = tuple(range(6, 13))  # the study's corridor lengths, each run as often


def random_corridor_spec(n_runs: int, seed: int = 0, estimators=None) -> dict:
    """The random-corridor study as a sweep spec (:mod:`onlinemap.sweeps`): corridors of every
    length in :data:`RANDOM_LENGTHS` (p_obs 0.9, p_move 0.8), one scripted trip each
    (``walk = "scripted_trip"``: uniform binary labels, one slip at a random outward move,
    noise-free observations), ``ceil(n_runs / 7)`` seeds from ``seed`` per length, and every
    (label, name, options) of ``estimators`` (default :data:`CORRIDOR_ESTIMATORS`)."""
    per_length = max(1, math.ceil(int(n_runs) / len(RANDOM_LENGTHS)))
    tables: dict[str, list] = {}
    for label, name, options in estimators or CORRIDOR_ESTIMATORS:
        tables.setdefault(name, []).append({"label": label, **options})  # a tuple is one value, a list a grid
    return {"name": "random-corridors", "worlds": [f"corridor:{n}" for n in RANDOM_LENGTHS],
            "seeds": list(range(int(seed), int(seed) + per_length)), "steps": "trip", "walk": "scripted_trip",
            "estimators": tables}


def random_corridor_study(n_runs: int, seed: int = 0, estimators=None, confidence: float = 0.95,
                          progress: bool = True, *, workers: int | None = 0,
                          out=None) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Run every estimator on random corridors (:func:`random_corridor_spec`, on the sweep engine:
    ``workers`` as in :func:`onlinemap.sweeps.sweep`; ``out``: a folder of parts, so a rerun resumes).

    Returns (per-run table: the sweep's rows (:mod:`onlinemap.evaluate`) with ``estimator``
    relabelled as in :data:`CORRIDOR_ESTIMATORS`, ``run`` (the seed) and ``n_cells``; summary
    per estimator: the fraction of runs in :data:`STUDY_OUTCOMES` (astray on the way back, ends
    lost, wrong map, ends lost or with a wrong map), each with its Wilson interval at
    ``confidence`` (columns NAME, NAME_low, NAME_high), and the mean lowest P(true location)
    on the way back). Cost: about n_runs times the cost of :func:`corridor_table`.
    """
    from ..sweeps import sweep

    estimators = estimators or CORRIDOR_ESTIMATORS
    per_run = sweep(random_corridor_spec(n_runs, seed, estimators), workers=workers, results_dir=out,
                    progress=progress)
    per_run["estimator"] = per_run.pop("label")
    per_run.insert(0, "run", per_run["seed"])
    per_run.insert(1, "n_cells", per_run["world"].str.partition(":")[2].astype(int))
    per_run["wrong_map"] = per_run["wrong_visited"] > 0
    per_run["ends_lost_or_wrong_map"] = per_run["ends_lost"] | per_run["wrong_map"]
    order = {label: i for i, (label, _, _) in enumerate(estimators)}
    per_run = per_run.sort_values("estimator", key=lambda c: c.map(order), kind="stable")
    summary = summary_of(per_run, [*STUDY_OUTCOMES, "min_p_true_way_back"], ["estimator"], confidence)
    summary = summary.rename(columns={"min_p_true_way_back": "mean_min_p_true_way_back"})
    return per_run.reset_index(drop=True), summary[["estimator", "runs", *(
        f"{c}{end}" for c in STUDY_OUTCOMES for end in ("", "_low", "_high")), "mean_min_p_true_way_back"]]


def steps_table(run: Run, trajectories: dict[str, Trajectory]) -> pd.DataFrame:
    """One row per estimator and step of ``run``: ``estimator``, ``t``, ``true_location``,
    ``p_true_location`` (1 - the location error) and ``map_error``
    (:func:`onlinemap.evaluate.step_metrics`)."""
    frames = []
    for label, trajectory in trajectories.items():
        steps = step_metrics(run, trajectory)
        frames.append(pd.DataFrame({"estimator": label, "t": steps["t"], "true_location": steps["true_location"],
                                    "p_true_location": 1.0 - steps["location_error"],
                                    "map_error": steps["map_error"]}))
    return pd.concat(frames, ignore_index=True)


def with_intervals(summary: pd.DataFrame) -> pd.DataFrame:
    """The study summary with each outcome as one "fraction [low, high]" text column (for printing)."""
    table = summary[["estimator", "runs"]].copy()
    for column in STUDY_OUTCOMES:
        table[column] = [f"{p:.2f} [{lo:.2f}, {hi:.2f}]" for p, lo, hi in
                         summary[[column, f"{column}_low", f"{column}_high"]].itertuples(index=False)]
    table["mean_min_p_true_way_back"] = summary["mean_min_p_true_way_back"]
    return table

