"""The exploration studies of issue 11, rerunnable: planners compared on the same seeds
(paired), with confidence intervals over seeds.

- :func:`paper_world_study`: the built-in 10 x 10 door world at the paper's settings (uniform
  label prior, ``p_move`` 0.8, ``p_obs`` 0.9; static or with doors flipping at ``p_door``),
  RBPF with 1000 particles, 1000 steps.
- :func:`binary_task_study`: the binary 10 x 10 task of the C++ belief-tracking peer (2 labels,
  ``p_move`` 0.9, ``p_obs`` 0.8, 300 steps, 100 particles), a fresh random map per seed.

Both return a :class:`Study`: one row per run and one summary row per planner (mean and a 95%
t-interval over seeds of every metric). Cost: ``len(planners) * len(seeds)`` exploration runs.
"""

from __future__ import annotations

from typing import Callable, NamedTuple, Sequence

import numpy as np
import pandas as pd
from onlinemap.progress import tqdm

from onlinemap.evaluate import metric_bounds
from onlinemap.model import GridModel, door_cells, grid_model
from onlinemap.simulate import sample_map
from onlinemap.stats import mean_interval

from .explore import explore
from .worlds import exploration_world

METRICS = ("final_map_error", "wrong_cells", "mean_location_error", "late_door_error")
CONFIDENT = 0.55  # a cell counts as right only if its true label is the most probable, with at least this


class Study(NamedTuple):
    """A paired comparison of planners over seeds."""

    runs: pd.DataFrame  # one row per (planner, seed): the METRICS, ms_per_step
    summary: pd.DataFrame  # one row per planner: runs, then mean, ci_low, ci_high of each metric


def wrong_cells(map_belief: np.ndarray, true_map: np.ndarray, confident: float = CONFIDENT) -> int:
    """Cells whose true label is not the most probable one with probability >= ``confident``
    (a cell left at an uninformed 1/2 counts as wrong). (N, K), (N,) -> int."""
    p_true = map_belief[np.arange(len(true_map)), true_map]
    return int(np.sum(~((np.argmax(map_belief, axis=1) == true_map) & (p_true >= confident))))


def run_metrics(frame: pd.DataFrame, final_map: np.ndarray, model: GridModel, true_map: np.ndarray) -> dict:
    """The study's metrics of one :func:`~policies.explore` run whose final map marginals are
    ``final_map`` (N, K): final map error, wrong cells (against ``true_map``, the initial map:
    exact in a static world), mean location error and the mean door error over the last two
    thirds of the run (NaN without doors)."""
    late = frame["t"] >= frame["t"].max() / 3
    return {"final_map_error": float(frame["map_error"].iloc[-1]),
            "wrong_cells": wrong_cells(final_map, np.asarray(true_map)),
            "mean_location_error": float(frame["location_error"].mean()),
            "late_door_error": float(frame.loc[late, "door_error"].mean()) if len(door_cells(model, true_map))
            else float("nan"),
            "ms_per_step": 1e3 * frame.attrs["seconds_per_step"]}


def summarize_study(runs: pd.DataFrame) -> pd.DataFrame:
    """Mean and 95% t-interval over seeds of each metric (cut to the metric's range), per planner
    (in order of appearance)."""
    rows = []
    for planner, group in runs.groupby("planner", sort=False):
        row = {"planner": planner, "runs": len(group)}
        for metric in (*METRICS, "ms_per_step"):
            interval = mean_interval(group[metric].to_numpy(dtype=float), 0.95, bounds=metric_bounds(metric))
            row.update({metric: interval.mean, f"{metric}_ci_low": interval.low, f"{metric}_ci_high": interval.high})
        rows.append(row)
    return pd.DataFrame(rows)


def compare(world: Callable[[int], tuple[GridModel, np.ndarray]], planners: Sequence[str], seeds: Sequence[int],
            steps: int, estimator_options: dict, planner_options: dict | None = None,
            progress: bool = True) -> Study:
    """Run every planner on every seed's world (``world(seed) -> (model, true_map)``), paired:
    the same seed gives the same world, and the same world random stream to every planner."""
    planner_options = planner_options or {}
    rows = []
    jobs = [(planner, seed) for seed in seeds for planner in planners]
    for planner, seed in tqdm(jobs, desc="exploration study", disable=not progress):
        model, true_map = world(seed)
        frame = _explore(model, true_map, planner, steps, seed, estimator_options, planner_options.get(planner))
        rows.append({"planner": planner, "seed": seed, **frame})
    runs = pd.DataFrame(rows)
    runs["planner"] = pd.Categorical(runs["planner"], categories=list(planners), ordered=True)
    runs = runs.sort_values(["planner", "seed"]).reset_index(drop=True)
    runs["planner"] = runs["planner"].astype(str)
    return Study(runs, summarize_study(runs))


def _explore(model, true_map, planner, steps, seed, estimator_options, planner_options) -> dict:
    from onlinemap.estimators import make_estimator

    est = make_estimator("rbpf", model, seed=int(np.random.SeedSequence(seed).generate_state(1)[0]),
                         **estimator_options)
    frame = explore(model, true_map, planner, est, steps, seed, planner_options=planner_options, progress=False)
    return run_metrics(frame, est.belief.map, model, true_map)


def paper_world_study(planners: Sequence[str] = ("info_gain", "entropy", "random", "sweep"), *,
                      seeds: Sequence[int] = range(20), steps: int = 1000, n_particles: int = 1000,
                      p_door: float = 0.0, planner_options: dict | None = None, progress: bool = True) -> Study:
    """Issue 11's main study: the 10 x 10 door world, uniform prior, ``p_move`` 0.8, ``p_obs`` 0.9."""
    model, true_map = exploration_world(p_door=p_door, p_move=0.8, floor_plan=None)
    return compare(lambda seed: (model, true_map), planners, seeds, steps, {"n_particles": n_particles},
                   planner_options, progress)


def binary_task_study(planners: Sequence[str] = ("info_gain", "random"), *, seeds: Sequence[int] = range(50),
                      steps: int = 300, n_particles: int = 100, planner_options: dict | None = None,
                      progress: bool = True) -> Study:
    """The peer's binary 10 x 10 task: 2 labels, ``p_move`` 0.9, ``p_obs`` 0.8, a uniform random map
    per seed (:func:`onlinemap.simulate.sample_map`)."""
    model = grid_model(10, 10, 2, p_obs=0.8, p_move=0.9)
    return compare(lambda seed: (model, sample_map(model, 10_000 + seed)), planners, seeds, steps,
                   {"n_particles": n_particles}, planner_options, progress)
