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
  Bayesian robot is often below 0.5 on the way back without being astray); the three readings
  of wrong cells at the end (:func:`cell_counts`: ``wrong_cells``, ``unsure_or_wrong``,
  ``confidently_wrong``); the map error and wrong cells over the cells the sensor read
  (``read_map_error``, ``read_wrong_cells``: :func:`read_cells`); and the yardstick of a robot
  told its location (:func:`told_location_map`: ``told_location_map_error`` and its three
  counts; with blocking labels the moves are evidence too) and ``excess_map_error``, the final
  map error less the told-location map's.
- honest (issue 40; :data:`HONEST_METRICS` says each in one sentence for printed tables): per step
  ``location_distance`` (the expected moves on the true floor between the location belief and
  the true cell: :func:`floor_distances`), ``location_claimed`` (``sum_i P(L_t = i)^2``, the
  P(true cell) the belief expects), ``read_map_p_true`` and ``read_map_claimed`` (the same for the
  labels of the cells read so far), ``told_location_map_error`` and ``excess_map_error``; per run
  (:func:`honest_metrics`) ``mean_``, ``late_`` (second half) and ``final_location_distance``,
  ``mean_location_p_true``, ``mean_location_claimed`` and ``location_calibration_gap`` (their
  difference: negative when the filter is overconfident), ``mean_read_map_p_true``,
  ``mean_read_map_claimed`` and ``map_calibration_gap``; and the location anchor of a robot told
  the true map (:func:`told_map_location`): per step ``told_map_location_error`` (its 1 - P(true
  cell)) and ``told_map_location_distance``, per run (:func:`told_map_metrics`) their means over
  the second half and ``excess_location_distance`` (``late_location_distance`` less the anchor's).
- coverage (how fast an explorer maps): ``known_cells`` per step (cells whose true label has
  probability >= :data:`KNOWN_ABOVE`), ``observable_map_error`` per step (the map error over the
  cells a robot could ever read: :func:`observable_cells`; with blocking walls some walls are
  read from no reachable cell); per run ``map_error_area`` (the area under the map-error curve:
  the sum over steps), ``steps_to_map_error_20`` / ``_10`` / ``_05`` (the first step at which the
  map error is at most 0.20 / 0.10 / 0.05, NaN if never: :func:`coverage`), ``final_known_cells``
  and ``final_observable_map_error``.
- navigation (:func:`navigation_metrics`, per run): ``reached`` the goal, ``steps_to_goal``,
  ``oracle_steps`` (an omniscient robot's, in the same world history), ``steps_over_oracle`` and
  ``success`` (reached within :data:`SUCCESS_WITHIN` times the oracle's steps; counted over the
  runs where the oracle reaches the goal, ``oracle_reached``).

Cost: O(T N K) for T steps, N cells, K labels (one pass over the stacked beliefs), plus once per
run the told-location map (:func:`told_location`), the told-map location (:func:`told_map_location`)
and a shortest-path search per distinct true cell
(:func:`floor_distances`).
"""

from __future__ import annotations

import logging
import math
import warnings
from typing import Mapping

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike

from . import metrics
from .errors import MemoryLimitError, PerformanceWarning
from .estimators import estimator_options, make_estimator, run_estimator
from .estimators.base import Trajectory
from .model import door_cells
from .progress import show_progress, tqdm
from .rng import ESTIMATOR_STREAM, derived_seed
from .simulate import Run
# The vocabulary and the run facts live in their own modules; callers import them from here too.
from .metric_names import (ASTRAY_BELOW, CONFIDENT, COVERAGE_THRESHOLDS, HONEST_METRICS, KNOWN_ABOVE,  # noqa: F401
                           LATE_FROM, LOST_BELOW, METRIC_DEFINITIONS, PROPORTION_METRICS, RUN_METRICS, SECOND_HALF,
                           STEP_METRICS, SUCCESS_WITHIN, TIMING_NOTE, UNIT_METRICS, metric_bounds, metric_definition,
                           metric_legend)
from .run_facts import (CellCounts, RunFacts, ToldLocation, cell_counts, first_read, floor_distances,  # noqa: F401
                        observable_cells, read_cells, run_facts, told_location, told_location_map,
                        told_map_location, way_back)

log = logging.getLogger(__name__)


def skipna_mean(values: ArrayLike) -> float:
    """The mean of the values that are not NaN (NaN if none is), bit for bit as pandas'
    ``Series.mean`` computes it (NaNs as zeros in one sum, then one division), without a Series.
    O(T)."""
    values = np.asarray(values, dtype=np.float64)
    missing = np.isnan(values)
    count = values.size - np.count_nonzero(missing)
    return float(np.where(missing, 0.0, values).sum() / count) if count else math.nan


def late_mean(t: ArrayLike, values: ArrayLike, start: float = LATE_FROM) -> float:
    """Mean of ``values`` over the steps ``t >= start * last t`` (by default :data:`LATE_FROM`:
    after the first visits), NaNs skipped (:func:`skipna_mean`). O(T)."""
    t = np.asarray(t)
    return skipna_mean(np.asarray(values, dtype=np.float64)[t >= start * t[-1]])


def honest_metrics(column: Mapping[str, ArrayLike]) -> dict[str, float]:
    """Per run, from its per-step columns (``t``, ``location_error``, ``location_distance``,
    ``location_claimed``, ``read_map_p_true``, ``read_map_claimed``; none if the table lacks
    ``location_distance``, a table written before they existed): ``mean_location_distance``,
    ``late_location_distance`` (over the second half, :data:`SECOND_HALF`),
    ``final_location_distance``; ``mean_location_p_true`` and ``mean_location_claimed`` (means over
    steps of P(true cell) and of what the belief expects it to be) and their difference
    ``location_calibration_gap`` (negative: overconfident); the same over the cells read so far,
    ``mean_read_map_p_true``, ``mean_read_map_claimed``, ``map_calibration_gap`` (NaN steps
    skipped). O(T)."""
    if "location_distance" not in column:
        return {}
    t = np.asarray(column["t"])
    distance = np.asarray(column["location_distance"], dtype=np.float64)
    p_true = 1.0 - np.asarray(column["location_error"], dtype=np.float64)
    claimed = np.asarray(column["location_claimed"], dtype=np.float64)
    read_true = np.asarray(column["read_map_p_true"], dtype=np.float64)
    read_claimed = np.asarray(column["read_map_claimed"], dtype=np.float64)
    return {"mean_location_distance": float(distance.mean()),
            "late_location_distance": late_mean(t, distance, SECOND_HALF),
            "final_location_distance": float(distance[-1]),
            "mean_location_p_true": float(p_true.mean()), "mean_location_claimed": float(claimed.mean()),
            "location_calibration_gap": float((p_true - claimed).mean()),
            "mean_read_map_p_true": skipna_mean(read_true), "mean_read_map_claimed": skipna_mean(read_claimed),
            "map_calibration_gap": skipna_mean(read_true - read_claimed)}


def told_map_metrics(column: Mapping[str, ArrayLike], honest: Mapping[str, float]) -> dict[str, float]:
    """Per run, from its per-step columns (``t``, ``told_map_location_error``,
    ``told_map_location_distance``; none if the table lacks them, a table written before they
    existed) and its :func:`honest_metrics` ``honest`` (none if they lack
    ``late_location_distance``): the location anchor of a robot told the true map
    (:func:`~onlinemap.run_facts.told_map_location`) over the window of ``late_location_distance``
    (the second half, :data:`SECOND_HALF`): ``told_map_location_error`` and
    ``told_map_location_distance``, and ``excess_location_distance``, the filter's
    ``late_location_distance`` less the anchor's. O(T)."""
    if "told_map_location_error" not in column or "late_location_distance" not in honest:
        return {}
    t = np.asarray(column["t"])
    told_distance = late_mean(t, column["told_map_location_distance"], SECOND_HALF)
    return {"told_map_location_error": late_mean(t, column["told_map_location_error"], SECOND_HALF),
            "told_map_location_distance": told_distance,
            "excess_location_distance": honest["late_location_distance"] - told_distance}


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
        row.update(coverage(run["map_error"]))
        if "door_error" in run and run["door_error"].notna().any():
            row["late_door_error"] = late_mean(run["t"], run["door_error"])
        honest = honest_metrics(run)
        row.update(honest)
        if "told_location_map_error" in run:
            row.update(told_location_map_error=float(run["told_location_map_error"].iloc[-1]),
                       excess_map_error=float(run["excess_map_error"].iloc[-1]))
        row.update(told_map_metrics(run, honest))
        if "ms_per_step" in run:
            row["ms_per_step"] = float(run["ms_per_step"].iloc[0])
        rows.append(row)
    return pd.DataFrame(rows)


def coverage(map_error: np.ndarray) -> dict[str, float]:
    """Per run from its (T,) map errors: ``map_error_area`` (their sum: the area under the
    map-error curve, in steps) and ``steps_to_map_error_XX`` (the first step t at which the map
    error is at most each of :data:`COVERAGE_THRESHOLDS`, NaN if never). O(T)."""
    map_error = np.asarray(map_error, dtype=np.float64)
    row = {"map_error_area": float(map_error.sum())}
    for name, threshold in COVERAGE_THRESHOLDS.items():
        below = np.flatnonzero(map_error <= threshold)
        row[name] = float(below[0]) if len(below) else math.nan
    return row


def navigation_metrics(reached_at: int | None, oracle: int | None,
                       stalled_at: int | None = None) -> dict[str, float | bool]:
    """A navigation run's metrics from the step it first stood on the goal (None: never), the
    oracle's (None: the oracle never got there either) and the step at which the run stalled
    (None: it did not; ``stalled``). O(1)."""
    reached, oracle_reached = reached_at is not None, oracle is not None
    both = reached and oracle_reached
    return {"reached": reached, "steps_to_goal": float(reached_at) if reached else math.nan,
            "oracle_reached": oracle_reached, "oracle_steps": float(oracle) if oracle_reached else math.nan,
            "steps_over_oracle": reached_at / max(oracle, 1) if both else math.nan,
            "success": bool(both and reached_at <= SUCCESS_WITHIN * max(oracle, 1)), "stalled": stalled_at is not None}


def _honest_columns(run: Run, trajectory: Trajectory, p_true: np.ndarray) -> dict[str, np.ndarray]:
    """The per-step columns that say how far off and how honest the belief is, (T,) each:
    ``location_distance`` (the expected moves between the location belief and the true cell on
    the true floor: :func:`floor_distances`), ``location_claimed`` (``sum_i P(L_t = i)^2``, the
    P(true cell) the belief expects), and over the cells the sensor has read by step t,
    ``read_map_p_true`` (their mean P(true label): ``p_true`` (T, N), every cell's) and
    ``read_map_claimed`` (their mean ``sum_k P(m_i = k)^2``; both NaN before a first reading).
    O(T N K)."""
    facts = run_facts(run)
    read = facts.first_read[None, :] <= np.arange(run.n_steps)[:, None]  # (T, N): read by step t
    count = read.sum(axis=1)
    claimed = metrics.belief_expected_p_true(trajectory.map)
    with np.errstate(invalid="ignore", divide="ignore"):  # NaN at steps before a first reading
        return {"location_distance": metrics.location_distance(trajectory.location, run.locations, facts.distances),
                "location_claimed": metrics.belief_expected_p_true(trajectory.location),
                "read_map_p_true": np.where(read, p_true, 0.0).sum(axis=1) / count,
                "read_map_claimed": np.where(read, claimed, 0.0).sum(axis=1) / count}


def step_metrics(run: Run, trajectory: Trajectory, reference: Trajectory | None = None) -> pd.DataFrame:
    """One row per step of ``run``: ``t`` and the per-step metrics (module docstring) of
    ``trajectory`` (location (T, N), map (T, N, K)); ``door_error`` if the true initial map has
    doors, ``location_tv`` / ``map_tv`` if a ``reference`` trajectory is given. The frame of
    :func:`step_columns`."""
    return pd.DataFrame(step_columns(run, trajectory, reference))


def step_columns(run: Run, trajectory: Trajectory, reference: Trajectory | None = None) -> dict[str, np.ndarray]:
    """The columns of :func:`step_metrics`, (T,) arrays by name, without building a frame.
    O(T N K)."""
    p_true = np.take_along_axis(trajectory.map, run.maps[..., None], axis=-1)[..., 0]  # (T, N)
    facts = run_facts(run)
    seen = facts.observable
    columns = {
        "t": np.arange(run.n_steps),
        "map_error": 1.0 - p_true.mean(axis=-1),
        "location_error": metrics.location_error(trajectory.location, run.locations),
        "log_evidence": np.asarray(trajectory.log_evidence, dtype=np.float64),
        "location_entropy": metrics.normalized_entropy(trajectory.location),
        "map_entropy": metrics.map_entropy(trajectory.map),
        "wrong_cells": (np.argmax(trajectory.map, axis=-1) != run.maps).sum(axis=-1),
        "known_cells": (p_true >= KNOWN_ABOVE).sum(axis=-1),
        "observable_map_error": 1.0 - p_true[:, seen].mean(axis=-1),
        "true_location": run.locations,
        **_honest_columns(run, trajectory, p_true),
    }
    doors = door_cells(run.model, run.initial_map)
    if len(doors):
        columns["door_error"] = metrics.map_error(trajectory.map[:, doors], run.maps[:, doors])
    columns["told_location_map_error"] = facts.told_map_error
    columns["excess_map_error"] = columns["map_error"] - facts.told_map_error
    columns["told_map_location_error"] = facts.told_map_location_error
    columns["told_map_location_distance"] = facts.told_map_location_distance
    if reference is not None:
        columns["location_tv"] = metrics.total_variation(trajectory.location, reference.location)
        columns["map_tv"] = metrics.total_variation(trajectory.map, reference.map).mean(axis=-1)
    return columns


def run_metrics(run: Run, trajectory: Trajectory, reference: Trajectory | None = None,
                steps: pd.DataFrame | Mapping[str, ArrayLike] | None = None, *,
                trip: bool = False) -> dict[str, float | int | bool]:
    """The per-run metrics (module docstring) of ``trajectory`` on ``run``, in
    :data:`RUN_METRICS` order (those that apply; the way-back ones only for a there-and-back
    ``trip``). ``steps``: its :func:`step_metrics` (or :func:`step_columns`), if already
    computed. Cost: O(N K) on top of the steps (O(T N K) without them), and the yardstick of
    :func:`told_location_map` (once per run for the last few runs: :func:`run_facts`)."""
    steps = step_columns(run, trajectory, reference) if steps is None else steps
    column = {name: np.asarray(steps[name]) for name in steps}
    final = {name: values[-1] for name, values in column.items()}
    location_error = column["location_error"]
    final_map = trajectory.map[-1]
    facts = run_facts(run)
    wrong = metrics.wrong_cells(final_map, run.final_map, facts.visited)
    counts = cell_counts(final_map, run.final_map)
    seen = facts.read
    row: dict[str, float | int | bool] = {
        "final_map_error": float(final["map_error"]), "mean_map_error": skipna_mean(column["map_error"]),
        "final_location_error": float(location_error[-1]), "mean_location_error": float(location_error.mean()),
        "max_location_error": float(location_error.max()), "wrong_cells": int(final["wrong_cells"]),
        "unsure_or_wrong": counts.unsure_or_wrong, "confidently_wrong": counts.confidently_wrong,
        "wrong_visited": wrong, "read_map_error": float(metrics.map_error(final_map[seen], run.final_map[seen])),
        "read_wrong_cells": metrics.wrong_cells(final_map[seen], run.final_map[seen])}
    row["ends_lost"] = bool(1.0 - location_error[-1] < LOST_BELOW)
    row["failed"] = row["ends_lost"] or wrong > 0
    back = way_back(run) if trip else np.zeros(run.n_steps, dtype=bool)
    if back.any():
        lowest = float(1.0 - location_error[back].max())
        row.update(min_p_true_way_back=lowest, astray_way_back=bool(lowest < ASTRAY_BELOW))
    row.update(facts.told)
    row["excess_map_error"] = row["final_map_error"] - row["told_location_map_error"]
    honest = honest_metrics(column)
    row.update(honest)
    row.update(told_map_metrics(column, honest))
    row.update(final_known_cells=int(final["known_cells"]),
               final_observable_map_error=float(final["observable_map_error"]), **coverage(column["map_error"]))
    row["final_log_evidence"] = float(final["log_evidence"])
    if "location_tv" in column:
        row.update(final_location_tv=float(final["location_tv"]),
                   mean_location_tv=skipna_mean(column["location_tv"]),
                   final_map_tv=float(final["map_tv"]), mean_map_tv=skipna_mean(column["map_tv"]))
    row.update(final_map_entropy=float(final["map_entropy"]), final_location_entropy=float(final["location_entropy"]))
    if "door_error" in column:
        row.update(final_door_error=float(final["door_error"]), mean_door_error=skipna_mean(column["door_error"]),
                   late_door_error=late_mean(column["t"], column["door_error"]))
    row["ms_per_step"] = 1e3 * trajectory.seconds_per_step
    return row


_WARMED: set = set()
WARM_UP_STEPS = 20


def timed_trajectory(name: str, model, options: dict, run: Run) -> Trajectory:
    """Run estimator ``name`` (built with ``options``) over ``run``. The first time in this
    process for (name, options, the model's shape and the kind of kernels it needs: grid size,
    static or not, blocking, footprint), it first takes up to :data:`WARM_UP_STEPS` steps of
    ``run`` on a throwaway copy, so compiling or loading numba kernels is not counted in
    ``seconds_per_step``. Steps every estimator on purpose, offline EM included: no
    :class:`~onlinemap.errors.PerformanceWarning`. Cost: the run's T steps (plus the warm-up once)."""
    warm = (name, repr(sorted((k, v) for k, v in options.items() if k != "seed")), model.n_cells,
            model.n_labels, model.n_actions, model.is_static, model.has_blocking, model.n_readings)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PerformanceWarning)
        if warm not in _WARMED and run.n_steps > 1:
            steps = min(run.n_steps, WARM_UP_STEPS)
            run_estimator(make_estimator(name, model, **options), run.actions[:steps - 1], run.observations[:steps])
            _WARMED.add(warm)
        return run_estimator(make_estimator(name, model, **options), run.actions, run.observations)


def compare_on_run(run: Run, names: list[str], options: dict[str, dict] | None = None,
                   progress: bool = True, seed: int | None = None) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Run each estimator over ``run`` (``onlinemap run``); returns (summary: one row per
    estimator with ``final_map_error``, ``mean_location_error``, ``final_location_error``;
    per-step table: ``estimator``, ``t``, ``map_error``, ``location_error``, ``log_evidence``), the
    metrics of :func:`step_metrics` and :func:`run_metrics`. Both depend only on the run and the
    seeds; the time per step (after a warm-up, :func:`timed_trajectory`), which does not, is
    ``summary.attrs["ms_per_step"]``.

    An estimator with a ``seed`` option that ``options`` leaves unset gets
    ``derived_seed(seed, ESTIMATOR_STREAM)`` when ``seed`` is given (as in a sweep task with that
    seed), so the tables are reproducible. Estimators that would exceed their memory limit are
    skipped (logged as a warning). Cost: T steps of each estimator (plus its warm-up once per
    process); memory O(T N K) per estimator.
    """
    options = options or {}
    rows, steps, times = [], [], {}
    for name in tqdm(names, desc="estimators", disable=not show_progress(progress), leave=False):
        chosen = dict(options.get(name, {}))
        if seed is not None and "seed" in estimator_options(name) and chosen.get("seed") is None:
            chosen["seed"] = derived_seed(seed, ESTIMATOR_STREAM)
        try:
            trajectory = timed_trajectory(name, run.model, chosen, run)
        except MemoryLimitError as error:
            log.warning("%s: skipped: %s", name, error)
            continue
        scores = step_metrics(run, trajectory)
        row = run_metrics(run, trajectory, steps=scores)
        rows.append({"estimator": name, **{m: row[m] for m in ("final_map_error", "mean_location_error",
                                                                 "final_location_error")}})
        times[name] = 1e3 * trajectory.seconds_per_step
        steps.append(scores[["t", "map_error", "location_error", "log_evidence"]].assign(estimator=name)[
            ["estimator", "t", "map_error", "location_error", "log_evidence"]])
    summary = pd.DataFrame(rows)
    summary.attrs["ms_per_step"] = times
    return summary, pd.concat(steps, ignore_index=True) if steps else pd.DataFrame()
