"""The exploration studies of issue 11, rerunnable: planners compared on the same seeds
(paired), with confidence intervals over seeds.

- :func:`paper_world_study`: the built-in 10 x 10 door world at the paper's settings (uniform
  label prior, ``p_move`` 0.8, ``p_obs`` 0.9; static or with doors flipping at ``p_door``),
  RBPF with 1000 particles, 1000 steps.
- :func:`replay_study`: how much of a planner's map error is the particle filter's: its runs
  replayed (same actions and observations) through filters with more particles.
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
from onlinemap.errors import ModelError
from onlinemap.simulate import Run, sample_map
from onlinemap.stats import mean_interval

from .explore import Exploration, exploration
from .worlds import exploration_world

METRICS = ("final_map_error", "wrong_cells", "unsure_or_wrong", "confidently_wrong", "mean_location_error",
           "late_door_error", "told_location_map_error", "told_location_wrong", "told_location_unsure_or_wrong",
           "told_location_confidently_wrong")
CONFIDENT = 0.55  # the probability a most probable label needs to count as known (the peer's rule)


class Study(NamedTuple):
    """A paired comparison of planners over seeds."""

    runs: pd.DataFrame  # one row per (planner, seed): the METRICS, ms_per_step
    summary: pd.DataFrame  # one row per planner: runs, then mean, ci_low, ci_high of each metric


class CellCounts(NamedTuple):
    """Three readings of "wrong cells" of a map belief (N, K) against the true labels (N,)."""

    wrong: int  # the most probable label is not the true one (ties: the lowest label wins)
    unsure_or_wrong: int  # not (the true label is the most probable, with probability >= confident)
    confidently_wrong: int  # the most probable label is wrong and has probability >= confident


def cell_counts(map_belief: np.ndarray, true_map: np.ndarray, confident: float = CONFIDENT) -> CellCounts:
    """The peer's rule ("count a cell wrong when its most probable label, with probability >=
    0.55, is wrong") read both ways: ``confidently_wrong`` leaves an unsure cell out, so a robot
    that learns nothing scores 0; ``unsure_or_wrong`` counts it, so a cell never seen counts
    as wrong. O(N K)."""
    true_map = np.asarray(true_map)
    guess = np.argmax(map_belief, axis=1)
    sure = map_belief[np.arange(len(true_map)), guess] >= confident
    wrong = guess != true_map
    return CellCounts(int(wrong.sum()), int(np.sum(wrong | ~sure)), int(np.sum(wrong & sure)))


def told_location_map(model: GridModel, run: Run) -> np.ndarray:
    """(N, K) the map belief of a robot told its true location at every step of ``run``, from the
    same observations: given the trajectory the cells are independent hidden Markov chains
    (motion ignores the map), each filtered exactly (predict by C, weigh the cells read by the
    sensor). What the data of a run could teach at best, the yardstick of the peer's "a robot
    told its location would get about 8 wrong". O(T N K^2)."""
    if model.has_blocking:
        raise ModelError("told_location_map needs motion that ignores the map (no blocking labels): with "
                         "blocking labels the trajectory itself depends on the map")
    belief = np.array(np.broadcast_to(model.label_prior, (model.n_cells, model.n_labels)))
    for t, (location, observation) in enumerate(zip(run.locations, run.observations)):
        if t > 0 and not model.is_static:
            belief = belief @ model.change
        if model.n_readings == 1 and model.footprint == ((0, 0),):
            cells, readings = np.array([location]), np.array([observation])
        else:
            cells = model.footprint_cells[location]
            readings = np.atleast_1d(observation)
            cells, readings = cells[readings >= 0], readings[readings >= 0]
        for cell, z in zip(cells, readings):
            belief[cell] *= model.sensor[:, z]
            belief[cell] /= belief[cell].sum()
    return belief


def run_metrics(found: Exploration, final_map: np.ndarray, model: GridModel, true_map: np.ndarray) -> dict:
    """The study's metrics of one :func:`~policies.exploration` run whose final map marginals are
    ``final_map`` (N, K): final map error, the :func:`cell_counts` (against the final true map),
    mean location error, the mean door error over the last two thirds of the run (NaN without
    doors), and the map error and wrong cells of :func:`told_location_map` on the same run."""
    frame, final_truth = found.frame, found.run.maps[-1]
    late = frame["t"] >= frame["t"].max() / 3
    told = told_location_map(model, found.run)
    counts, told_counts = cell_counts(final_map, final_truth), cell_counts(told, final_truth)
    return {"final_map_error": float(frame["map_error"].iloc[-1]),
            "wrong_cells": counts.wrong, "unsure_or_wrong": counts.unsure_or_wrong,
            "confidently_wrong": counts.confidently_wrong,
            "mean_location_error": float(frame["location_error"].mean()),
            "late_door_error": float(frame.loc[late, "door_error"].mean()) if len(door_cells(model, true_map))
            else float("nan"),
            "told_location_map_error": float(1.0 - told[np.arange(model.n_cells), final_truth].mean()),
            "told_location_wrong": told_counts.wrong, "told_location_unsure_or_wrong": told_counts.unsure_or_wrong,
            "told_location_confidently_wrong": told_counts.confidently_wrong,
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
    found = exploration(model, true_map, planner, est, steps, seed, planner_options=planner_options, progress=False)
    return run_metrics(found, est.belief.map, model, true_map)


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


def replay_study(planner: str = "info_gain", *, seeds: Sequence[int] = range(5), steps: int = 1000,
                 n_particles: int = 1000, replay_particles: Sequence[int] = (1000, 5000, 20000), replays: int = 2,
                 p_door: float = 0.0, progress: bool = True) -> pd.DataFrame:
    """The paper's world explored by ``planner`` with an RBPF of ``n_particles`` (one run per seed),
    then each run's actions and observations fed to fresh RBPFs of every size in
    ``replay_particles`` (``replays`` estimator seeds each) and to :func:`told_location_map`.
    One row per (seed, filter): ``seed``, ``filter`` ("live", "rbpf P", "told location"),
    ``final_map_error`` (mean over replays). The data are the same in a row group, so the
    differences are the filters': what a better filter would make of the planner's data.
    Cost: ``len(seeds)`` runs plus ``len(seeds) * replays * sum(replay_particles) * steps`` particle
    steps (about 40 s a seed at the defaults)."""
    from onlinemap.estimators import make_estimator, run_estimator

    model, true_map = exploration_world(p_door=p_door, p_move=0.8, floor_plan=None)
    rows = []
    for seed in tqdm(list(seeds), desc="replay study", disable=not progress):
        est = make_estimator("rbpf", model, seed=seed, n_particles=n_particles)
        found = exploration(model, true_map, planner, est, steps, seed, progress=False)
        truth = found.run.maps[-1]
        rows.append({"seed": seed, "filter": "live", "final_map_error": float(found.frame["map_error"].iloc[-1])})
        for size in replay_particles:
            errors = []
            for replay in range(replays):
                replayed = make_estimator("rbpf", model, seed=10_000 + replay, n_particles=int(size),
                                          max_bytes=2**36)
                final = run_estimator(replayed, found.run.actions, found.run.observations).map[-1]
                errors.append(1.0 - final[np.arange(model.n_cells), truth].mean())
            rows.append({"seed": seed, "filter": f"rbpf {int(size)}", "final_map_error": float(np.mean(errors))})
        told = told_location_map(model, found.run)
        rows.append({"seed": seed, "filter": "told location",
                     "final_map_error": float(1.0 - told[np.arange(model.n_cells), truth].mean())})
    return pd.DataFrame(rows)
