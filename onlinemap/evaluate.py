"""One place that scores an estimator against a run: (run, beliefs, optional reference) -> metrics.

Every study (sweeps, ``compare``, ``reproduce``, ``policies.explore``, the notebooks) computes
its numbers here, with the same names and thresholds:

- per step (:func:`step_metrics`, one row per step t): ``true_location``, ``map_error`` (mean
  over cells of 1 - P(true label)), ``location_error`` (1 - P(true cell)), ``log_evidence``, the
  normalised entropies ``location_entropy`` and ``map_entropy`` (in [0, 1]), ``wrong_cells``
  (cells whose most probable label is not the true one), ``door_error`` (``map_error``
  over the door cells; only when the world has doors) and, with a reference trajectory (exact
  Bayes on the same run), the total variation to it: ``location_tv`` (over cells) and
  ``map_tv`` (per cell, averaged over cells).
- per run (:func:`run_metrics`): the last step's and the mean over steps of those
  (``final_map_error``, ``mean_map_error``, ...), ``max_location_error``, ``wrong_cells`` (at
  the end), ``wrong_visited`` (visited cells whose most probable final label is wrong),
  ``ends_lost`` (final P(true cell) < :data:`LOST_BELOW`), ``failed`` (ends lost or a wrong
  visited cell), ``late_door_error`` (mean door
  error over the last two thirds of the run, after the first visits) and, when the run turns
  back (:func:`way_back`), ``min_p_true_way_back`` and ``astray_way_back`` (it fell below
  :data:`ASTRAY_BELOW`: confidently in the wrong place, the online-EM failure; an uncertain
  Bayesian robot is often below 0.5 on the way back without being astray).

Cost: O(T N K) for T steps, N cells, K labels (one pass over the stacked beliefs).
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pandas as pd

from . import metrics
from .errors import PerformanceWarning
from .estimators import make_estimator, run_estimator
from .estimators.base import Trajectory
from .model import door_cells
from .simulate import Run

LOST_BELOW = 0.5  # a robot whose P(true location) is below this is "lost"
ASTRAY_BELOW = 0.05  # ... and below this, confidently in the wrong place ("astray")
LATE_FROM = 1 / 3  # late_door_error: steps t >= LATE_FROM * (T - 1)

STEP_METRICS = ("map_error", "location_error", "log_evidence", "location_entropy", "map_entropy",
                "wrong_cells", "door_error", "location_tv", "map_tv")
RUN_METRICS = ("final_map_error", "mean_map_error", "final_location_error", "mean_location_error",
               "max_location_error", "wrong_cells", "wrong_visited", "ends_lost", "failed", "min_p_true_way_back",
               "astray_way_back", "final_log_evidence", "final_location_tv", "mean_location_tv", "final_map_tv",
               "mean_map_tv", "final_map_entropy", "final_location_entropy", "final_door_error",
               "mean_door_error", "late_door_error", "ms_per_step")
UNIT_METRICS = ("error", "_tv", "entropy", "p_true")  # names containing these lie in [0, 1]
#: a footnote for printed tables: what ``ms_per_step`` includes
TIMING_NOTE = "ms_per_step: wall time per step, measured after a warm-up run (numba kernels compiled first)"


def metric_bounds(name: str) -> tuple[float, float]:
    """The range of a metric: [0, 1] for errors, distances, entropies and probabilities, [0, inf)
    for counts and times, unbounded otherwise (log evidence)."""
    if any(part in name for part in UNIT_METRICS):
        return 0.0, 1.0
    if "wrong" in name or name == "ms_per_step":
        return 0.0, math.inf
    return -math.inf, math.inf


def late_mean(t: pd.Series, values: pd.Series) -> float:
    """Mean of ``values`` over the steps ``t >= LATE_FROM * last t`` (after the first visits)."""
    return float(values[t >= LATE_FROM * t.iloc[-1]].mean())


def from_steps(steps: pd.DataFrame, by: list[str]) -> pd.DataFrame:
    """Per-run metrics from a per-step table (one group of rows per run, ``by`` its columns,
    ``t`` ascending): final map error, final wrong cells (if the table has them), mean location
    error, the late door error (if it has door errors) and ``ms_per_step``: the same
    definitions as :func:`run_metrics`. Cost: O(rows)."""
    rows = []
    for keys, run in steps.groupby(by, sort=False):
        row = dict(zip(by, keys if isinstance(keys, tuple) else (keys,)))
        row["final_map_error"] = float(run["map_error"].iloc[-1])
        if "wrong_cells" in run:
            row["wrong_cells"] = int(run["wrong_cells"].iloc[-1])
        row["mean_location_error"] = float(run["location_error"].mean())
        if "door_error" in run and run["door_error"].notna().any():
            row["late_door_error"] = late_mean(run["t"].reset_index(drop=True),
                                               run["door_error"].reset_index(drop=True))
        if "ms_per_step" in run:
            row["ms_per_step"] = float(run["ms_per_step"].iloc[0])
        rows.append(row)
    return pd.DataFrame(rows)


def way_back(run: Run) -> np.ndarray:
    """(T,) True at the steps after the robot turned (after its first action that differs
    from the first action); all False if it never turns."""
    turns = np.flatnonzero(run.actions != run.actions[0])
    mask = np.zeros(run.n_steps, dtype=bool)
    if len(turns):
        mask[turns[0] + 1:] = True
    return mask


def step_metrics(run: Run, trajectory: Trajectory, reference: Trajectory | None = None) -> pd.DataFrame:
    """One row per step of ``run``: ``t`` and the per-step metrics (module docstring) of
    ``trajectory`` (location (T, N), map (T, N, K)); ``door_error`` if the true initial map has
    doors, ``location_tv`` / ``map_tv`` if a ``reference`` trajectory is given."""
    columns = {
        "t": np.arange(run.n_steps),
        "map_error": metrics.map_error(trajectory.map, run.maps),
        "location_error": metrics.location_error(trajectory.location, run.locations),
        "log_evidence": np.asarray(trajectory.log_evidence, dtype=np.float64),
        "location_entropy": metrics.normalized_entropy(trajectory.location),
        "map_entropy": metrics.map_entropy(trajectory.map),
        "wrong_cells": (np.argmax(trajectory.map, axis=-1) != run.maps).sum(axis=-1),
        "true_location": run.locations,
    }
    doors = door_cells(run.model, run.initial_map)
    if len(doors):
        columns["door_error"] = metrics.map_error(trajectory.map[:, doors], run.maps[:, doors])
    if reference is not None:
        columns["location_tv"] = metrics.total_variation(trajectory.location, reference.location)
        columns["map_tv"] = metrics.total_variation(trajectory.map, reference.map).mean(axis=-1)
    return pd.DataFrame(columns)


def run_metrics(run: Run, trajectory: Trajectory, reference: Trajectory | None = None,
                steps: pd.DataFrame | None = None, *, trip: bool = False) -> dict[str, float | int | bool]:
    """The per-run metrics (module docstring) of ``trajectory`` on ``run``, in
    :data:`RUN_METRICS` order (those that apply; the way-back ones only for a there-and-back
    ``trip``). ``steps``: its :func:`step_metrics`, if already computed."""
    steps = step_metrics(run, trajectory, reference) if steps is None else steps
    final, location_error = steps.iloc[-1], steps["location_error"].to_numpy()
    wrong = metrics.wrong_cells(trajectory.map[-1], run.final_map, np.unique(run.locations))
    row: dict[str, float | int | bool] = {
        "final_map_error": float(final["map_error"]), "mean_map_error": float(steps["map_error"].mean()),
        "final_location_error": float(location_error[-1]), "mean_location_error": float(location_error.mean()),
        "max_location_error": float(location_error.max()), "wrong_cells": int(final["wrong_cells"]),
        "wrong_visited": wrong}
    row["ends_lost"] = bool(1.0 - location_error[-1] < LOST_BELOW)
    row["failed"] = row["ends_lost"] or wrong > 0
    back = way_back(run) if trip else np.zeros(run.n_steps, dtype=bool)
    if back.any():
        lowest = float(1.0 - location_error[back].max())
        row.update(min_p_true_way_back=lowest, astray_way_back=bool(lowest < ASTRAY_BELOW))
    row["final_log_evidence"] = float(final["log_evidence"])
    if "location_tv" in steps:
        row.update(final_location_tv=float(final["location_tv"]), mean_location_tv=float(steps["location_tv"].mean()),
                   final_map_tv=float(final["map_tv"]), mean_map_tv=float(steps["map_tv"].mean()))
    row.update(final_map_entropy=float(final["map_entropy"]), final_location_entropy=float(final["location_entropy"]))
    if "door_error" in steps:
        row.update(final_door_error=float(final["door_error"]), mean_door_error=float(steps["door_error"].mean()),
                   late_door_error=late_mean(steps["t"], steps["door_error"]))
    row["ms_per_step"] = 1e3 * trajectory.seconds_per_step
    return row


_WARMED: set = set()
WARM_UP_STEPS = 20


def timed_trajectory(name: str, model, options: dict, run: Run) -> Trajectory:
    """Run estimator ``name`` (built with ``options``) over ``run``. The first time in this
    process for (name, options, grid size), it first takes up to :data:`WARM_UP_STEPS` steps of
    ``run`` on a throwaway copy, so compiling or loading numba kernels is not counted in
    ``seconds_per_step``. Steps every estimator on purpose, offline EM included: no
    :class:`~onlinemap.errors.PerformanceWarning`. Cost: the run's T steps (plus the warm-up once)."""
    warm = (name, repr(sorted((k, v) for k, v in options.items() if k != "seed")), model.n_cells,
            model.n_labels, model.n_actions, model.is_static)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PerformanceWarning)
        if warm not in _WARMED and run.n_steps > 1:
            steps = min(run.n_steps, WARM_UP_STEPS)
            run_estimator(make_estimator(name, model, **options), run.actions[:steps - 1], run.observations[:steps])
            _WARMED.add(warm)
        return run_estimator(make_estimator(name, model, **options), run.actions, run.observations)
