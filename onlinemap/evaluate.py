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
  ``mean_read_map_claimed`` and ``map_calibration_gap``.
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
run the told-location map (:func:`told_location`) and a shortest-path search per distinct true cell
(:func:`floor_distances`).
"""

from __future__ import annotations

import functools
import logging
import math
import warnings
from typing import Mapping, NamedTuple

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike

from . import metrics
from .arrays import read_only
from .errors import MemoryLimitError, PerformanceWarning
from .estimators import estimator_options, make_estimator, run_estimator
from .estimators.base import Trajectory
from .model import GridModel, door_cells
from .progress import show_progress, tqdm
from .rng import ESTIMATOR_STREAM, derived_seed
from .simulate import Run

log = logging.getLogger(__name__)

LOST_BELOW = 0.5  # a robot whose P(true location) is below this is "lost"
ASTRAY_BELOW = 0.05  # ... and below this, confidently in the wrong place ("astray")
LATE_FROM = 1 / 3  # late_door_error: steps t >= LATE_FROM * (T - 1)
SECOND_HALF = 1 / 2  # late_location_distance: steps t >= SECOND_HALF * (T - 1)
CONFIDENT = 0.55  # the probability a most probable label needs to count as known (cell_counts)
KNOWN_ABOVE = 0.9  # known_cells: cells whose true label has at least this probability
SUCCESS_WITHIN = 4  # a navigation succeeds when it reaches the goal within this many times the oracle's steps
COVERAGE_THRESHOLDS = {"steps_to_map_error_20": 0.20, "steps_to_map_error_10": 0.10, "steps_to_map_error_05": 0.05}

STEP_METRICS = ("map_error", "location_error", "log_evidence", "location_entropy", "map_entropy",
                "wrong_cells", "known_cells", "observable_map_error", "door_error", "location_tv", "map_tv",
                "location_distance", "location_claimed", "read_map_p_true", "read_map_claimed",
                "told_location_map_error", "excess_map_error")
RUN_METRICS = ("final_map_error", "mean_map_error", "final_location_error", "mean_location_error",
               "max_location_error", "wrong_cells", "unsure_or_wrong", "confidently_wrong", "wrong_visited",
               "read_map_error", "read_wrong_cells", "ends_lost", "failed", "min_p_true_way_back",
               "astray_way_back", "told_location_map_error", "told_location_wrong", "told_location_unsure_or_wrong",
               "told_location_confidently_wrong", "excess_map_error", "mean_location_distance",
               "late_location_distance", "final_location_distance", "mean_location_p_true", "mean_location_claimed",
               "location_calibration_gap", "mean_read_map_p_true", "mean_read_map_claimed", "map_calibration_gap",
               "final_known_cells", "final_observable_map_error",
               "map_error_area", *COVERAGE_THRESHOLDS, "final_log_evidence", "final_location_tv", "mean_location_tv", "final_map_tv",
               "mean_map_tv", "final_map_entropy", "final_location_entropy", "final_door_error",
               "mean_door_error", "late_door_error", "ms_per_step")
UNIT_METRICS = ("error", "_tv", "entropy", "p_true", "claimed")  # names containing these lie in [0, 1]
#: yes/no outcomes per run: their means (shares of runs) lie in [0, 1]
PROPORTION_METRICS = ("reached", "oracle_reached", "stalled", "success", "ends_lost", "failed", "astray_way_back",
                      "any_wrong_cell", "wrong_map", "ends_lost_or_wrong_map", "local_maximum")
#: the honest metrics (issue 40), one sentence each, for the legend of a printed table
HONEST_METRICS = {
    "late_location_distance": "expected moves on the true floor between the location belief and the true cell, "
                              "mean over the second half of the run (off by one cell scores 1; lost scores far more)",
    "location_calibration_gap": "mean P(true cell) minus the mean P(true cell) the belief expects (sum_i P(i)^2): "
                                "0 when honest, negative when it claims to know where it is more than it does",
    "map_calibration_gap": "the same for the labels of the cells read so far (mean P(true label) minus mean "
                           "sum_k P(k)^2): negative when the map is overconfident",
    "told_location_map_error": "final map error of a robot told its true path, from the same readings and "
                               "moves (the best these data allow)",
    "excess_map_error": "final map error minus the told-location map's: what not knowing the location costs",
}
#: what each metric means, printed under the tables that show it (:func:`metric_legend`); ``final_X``
#: and ``mean_X`` are X at the last step and X averaged over the steps
METRIC_DEFINITIONS = {
    "map_error": "mean over cells of 1 - P(true label)",
    "location_error": "1 - P(true cell)",
    "log_evidence": "log P(all observations so far)",
    "location_entropy": "entropy of the location belief / log(cells), in [0, 1]",
    "map_entropy": "mean over cells of the label belief's entropy / log(labels), in [0, 1]",
    "wrong_cells": "cells whose most probable label is wrong at the end",
    "known_cells": f"cells whose true label has probability >= {KNOWN_ABOVE}",
    "observable_map_error": "map_error over the cells a robot could ever read",
    "door_error": "map_error over the door cells",
    "location_tv": "total variation distance to exact Bayes's location belief",
    "map_tv": "total variation distance to exact Bayes's label belief, mean over cells",
    "max_location_error": "the largest location_error over the steps",
    "unsure_or_wrong": f"cells whose most probable label is wrong or below probability {CONFIDENT} at the end",
    "confidently_wrong": f"cells whose most probable label is wrong with probability >= {CONFIDENT} at the end",
    "wrong_visited": "visited cells whose most probable label is wrong at the end",
    "read_map_error": "final map_error over the cells the sensor read",
    "read_wrong_cells": "wrong_cells among the cells the sensor read",
    "ends_lost": f"share of runs ending with P(true cell) < {LOST_BELOW}",
    "failed": f"share of runs that end lost (P(true cell) < {LOST_BELOW}) or with a visited cell's most probable "
              "label wrong",
    "min_p_true_way_back": "the lowest P(true cell) after the robot turns back",
    "astray_way_back": f"share of runs whose P(true cell) falls below {ASTRAY_BELOW} after the robot turns back",
    "map_error_area": "sum of map_error over the steps",
    "late_door_error": "mean door_error over the last two thirds of the run",
    "ms_per_step": "wall time per step, measured after a warm-up run (numba kernels compiled first)",
    "reached": "share of runs in which the robot reaches the goal",
    "stalled": "share of runs that stalled: the belief did not move for stall_after presses in a row (the run ends)",
    "steps_to_goal": "steps until the robot first stands on the goal",
    "oracle_steps": "steps of a robot that knows its cell and the true map, in the same world history",
    "steps_over_oracle": "steps_to_goal / oracle_steps, per run",
    "success": f"share of runs reaching the goal within {SUCCESS_WITHIN}x the oracle's steps",
    **HONEST_METRICS,
}
#: a footnote for printed tables: what ``ms_per_step`` includes
TIMING_NOTE = f"ms_per_step: {METRIC_DEFINITIONS['ms_per_step']}"


def metric_definition(name: str) -> str | None:
    """What the metric ``name`` means (:data:`METRIC_DEFINITIONS`; ``final_X``/``mean_X``: X at
    the last step / averaged over the steps; ``told_location_X``: X of a robot told its cell;
    ``steps_to_map_error_NN``: the first step with map_error <= 0.NN), or None for a name that is
    not a metric."""
    if name in METRIC_DEFINITIONS:
        return METRIC_DEFINITIONS[name]
    if name in COVERAGE_THRESHOLDS:
        return f"first step at which map_error <= {COVERAGE_THRESHOLDS[name]:.2f} (empty: never)"
    for prefix, meaning in (("final_", "{} at the last step"), ("mean_", "{} averaged over the steps"),
                            ("told_location_", "{} of a robot told its cell at every step (mapping alone)")):
        if name.startswith(prefix):
            base = name[len(prefix):]
            base = {"wrong": "wrong_cells", "map_error": "final_map_error"}.get(base, base) \
                if prefix == "told_location_" else base
            if metric_definition(base) is not None:
                return meaning.format(base)
    return None


def metric_legend(names) -> list[str]:
    """``NAME: definition`` for each metric among ``names`` (other names, e.g. configuration
    columns, skipped), in their order: the legend printed under a table of metrics."""
    return [f"{name}: {metric_definition(name)}" for name in dict.fromkeys(names) if metric_definition(name)]


def metric_bounds(name: str, n_cells: int | None = None) -> tuple[float, float]:
    """The range of a metric: [0, 1] for errors, entropies, probabilities and yes/no outcomes
    (:data:`PROPORTION_METRICS`), [0, N] for counts of cells in a world of ``n_cells`` = N
    (``wrong_cells``, ``unsure_or_wrong``, ``final_known_cells``, ...; [0, inf) when N is not
    known), [0, inf) for times, steps (``steps_to_map_error_10``, ``steps_to_goal``,
    ``oracle_steps``), ratios of steps (``steps_over_oracle``), expected distances in cells
    (``mean_location_distance``), gaps to a maximum (``objective_gap``) and areas under an error
    curve (``map_error_area``, error x steps), [-1, 1] for differences of two quantities in [0, 1]
    (``excess_map_error``, ``location_calibration_gap``), unbounded otherwise (log evidence,
    objectives)."""
    if name.startswith("excess_") or name.endswith("calibration_gap"):
        return -1.0, 1.0
    if name == "ms_per_step" or name.startswith("map_error_area") or "steps" in name or name.endswith("_gap") \
            or name.endswith("location_distance"):
        return 0.0, math.inf
    if name in PROPORTION_METRICS or any(part in name for part in UNIT_METRICS):
        return 0.0, 1.0
    if "wrong" in name or name.endswith("known_cells"):
        return 0.0, math.inf if n_cells is None else float(n_cells)
    return -math.inf, math.inf


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
        row.update(honest_metrics(run))
        if "told_location_map_error" in run:
            row.update(told_location_map_error=float(run["told_location_map_error"].iloc[-1]),
                       excess_map_error=float(run["excess_map_error"].iloc[-1]))
        if "ms_per_step" in run:
            row["ms_per_step"] = float(run["ms_per_step"].iloc[0])
        rows.append(row)
    return pd.DataFrame(rows)


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


def read_cells(run: Run) -> np.ndarray:
    """The cells the sensor read at least once during the run (sorted; with the paper's sensor,
    the visited cells). O(T F)."""
    cells = run.model.footprint_cells[run.locations]
    return np.unique(cells[cells >= 0])


class ToldLocation(NamedTuple):
    """The map of a robot told its true location at every step (:func:`told_location`)."""

    map: np.ndarray  # (N, K) its belief after the last step
    map_error: np.ndarray  # (T,) its map error at each step t, against the true map at t


def told_location_map(model: GridModel, run: Run) -> np.ndarray:
    """(N, K) the map belief of a robot told its true location at every step of ``run``, from the
    same observations: :func:`told_location`'s ``map``. What the data of a run could teach at
    best, the yardstick of the peer's "a robot told its location would get about 8 wrong"."""
    return told_location(model, run).map


def told_location(model: GridModel, run: Run) -> ToldLocation:
    """The map of a robot told its true path: given the path the cells are independent hidden
    Markov chains, each filtered exactly, and its map error at every step.

    Per cell i: prior ``label_prior[i]``; at step t >= 1, first the press (judged on the labels
    before this step's change, DESIGN.md section 7): with blocking labels, a press from ``L_{t-1}``
    towards an in-grid cell j that moved the robot says ``m_j`` is passable (likelihood
    ``p_move [m_j passable]``, the constant dropped), and one that left it where it was says
    ``P(stay | m_j) = 1`` if ``m_j`` blocks, ``1 - p_move`` otherwise; without blocking labels
    motion ignores the map and says nothing. Then the change C (dynamic worlds), then each cell
    the sensor read, weighed by its column of O. In a static world the evidence of a cell
    multiplies in any order (kept as log sums). Cost: O(T (F + 1) K + T N) in a static world,
    O(T N K^2) in a dynamic one; memory O(N K)."""
    cells = model.footprint_cells[run.locations]  # (T, F)
    readings = np.asarray(run.observations).reshape(cells.shape)
    read = (cells >= 0) & (readings >= 0)
    presses = _presses(model, run)
    n, every = model.n_cells, np.arange(model.n_cells)
    errors = np.empty(run.n_steps)
    belief = np.array(np.broadcast_to(model.label_prior, (n, model.n_labels)))
    if model.is_static:  # every reading of a cell multiplies its belief by a column of O, in any order
        truth = run.maps[0]
        with np.errstate(divide="ignore"):
            log_belief = np.log(belief)
            log_reading = np.log(model.sensor.T)  # row z: log O[:, z]
            log_press = np.log(presses.likelihood)
        p_true = belief[every, truth]
        for t in range(run.n_steps):
            touched = cells[t][read[t]]  # distinct: one footprint offset per cell
            if presses.cell[t] >= 0:
                log_belief[presses.cell[t]] += log_press[presses.kind[t]]
            log_belief[touched] += log_reading[readings[t][read[t]]]
            if presses.cell[t] >= 0:
                touched = np.append(touched, presses.cell[t])
            p_true[touched] = _normalised(log_belief[touched])[np.arange(len(touched)), truth[touched]]
            errors[t] = 1.0 - p_true.mean()
        return ToldLocation(_normalised(log_belief), errors)
    for t in range(run.n_steps):
        if t > 0:
            if presses.cell[t] >= 0:
                belief[presses.cell[t]] *= presses.likelihood[presses.kind[t]]
                belief[presses.cell[t]] /= belief[presses.cell[t]].sum()
            belief = belief @ model.change
        for cell, z in zip(cells[t][read[t]], readings[t][read[t]]):
            belief[cell] *= model.sensor[:, z]
            belief[cell] /= belief[cell].sum()
        errors[t] = 1.0 - belief[every, run.maps[t]].mean()
    return ToldLocation(belief, errors)


def _normalised(log_belief: np.ndarray) -> np.ndarray:
    """Rows of log-probabilities (up to a constant each) -> probabilities. O(size)."""
    log_belief = log_belief - log_belief.max(axis=1, keepdims=True)
    belief = np.exp(log_belief)
    return belief / belief.sum(axis=1, keepdims=True)


class _Presses(NamedTuple):
    """What the moves of a run say about the cells pressed towards (:func:`_presses`)."""

    cell: np.ndarray  # (T,) the in-grid cell pressed towards at step t, or -1 (t = 0, an edge, no blocking labels)
    kind: np.ndarray  # (T,) 0: the robot entered it, 1: it stayed
    likelihood: np.ndarray  # (2, K) P(outcome | label of the cell), up to a constant per row


def _presses(model: GridModel, run: Run) -> _Presses:
    """The moves' evidence about the map: with blocking labels, step t >= 1 pressed from
    ``L_{t-1}`` towards ``j = neighbors[L_{t-1}, a_t]``; if j is another cell, the robot entered it
    (``[m_j passable]``) or stayed (1 if ``m_j`` blocks, else ``1 - p_move``). O(T)."""
    cell = np.full(run.n_steps, -1, dtype=np.int64)
    kind = np.zeros(run.n_steps, dtype=np.int64)
    if model.has_blocking and run.n_steps > 1:
        before = run.locations[:-1]
        target = model.neighbors[before, run.actions]
        pressed = target != before
        cell[1:] = np.where(pressed, target, -1)
        kind[1:] = run.locations[1:] == before
    likelihood = np.stack([(~model.blocking).astype(np.float64), np.where(model.blocking, 1.0, 1.0 - model.p_move)])
    return _Presses(cell, kind, likelihood)


def observable_cells(model: GridModel, true_map: np.ndarray) -> np.ndarray:
    """The cells a robot could ever read (sorted): those its footprint covers from some cell
    reachable from the start through cells ``true_map`` does not block (every cell without
    blocking labels). A wall read from no reachable cell stays at its prior whatever the
    explorer does. O(N A + N F)."""
    passable = ~model.blocking[np.asarray(true_map)]
    reached = np.zeros(model.n_cells, dtype=bool)
    reached[model.start] = True
    frontier = [model.start]
    while frontier:
        cell = frontier.pop()
        for target in model.neighbors[cell]:
            if passable[target] and not reached[target]:
                reached[target] = True
                frontier.append(int(target))
    cells = model.footprint_cells[reached]
    return np.unique(cells[cells >= 0])


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


def way_back(run: Run) -> np.ndarray:
    """(T,) True at the steps after the robot turned (after its first action that differs
    from the first action); all False if it never turns."""
    turns = np.flatnonzero(run.actions != run.actions[0])
    mask = np.zeros(run.n_steps, dtype=bool)
    if len(turns):
        mask[turns[0] + 1:] = True
    return mask


class _RunFacts(NamedTuple):
    """What the metrics need of a run alone, whatever the beliefs scored on it (:func:`_run_facts`)."""

    visited: np.ndarray  # the cells the robot stood on, sorted
    read: np.ndarray  # the cells the sensor read (read_cells)
    observable: np.ndarray  # the cells a robot could ever read in the initial map (observable_cells)
    first_read: np.ndarray  # (N,) the first step at which the sensor read each cell (T if never)
    distances: metrics.FloorDistances  # moves on the true floor (floor_distances)
    told_map_error: np.ndarray  # (T,) the told-location map's error at each step (told_location)
    told: tuple[tuple[str, float | int], ...]  # the told_location_* metrics by name


def floor_distances(run: Run) -> metrics.FloorDistances:
    """The distances of :func:`onlinemap.metrics.location_distance` for ``run``: the fewest moves
    on the true floor, the cells whose label does not block at some step of the run (a door that
    is open at some step is a passage; every cell without blocking labels); a cell no such path
    reaches (a wall, a closed-off room) gets its grid distance, labels ignored
    (:class:`~onlinemap.metrics.FloorDistances`). O(T N) here, then O(N A log N) per distinct
    true cell asked for."""
    model = run.model
    passable = (~model.blocking[run.maps]).any(axis=0) if model.has_blocking else np.ones(model.n_cells, bool)
    return metrics.FloorDistances(model.neighbors, passable)


def first_read(run: Run) -> np.ndarray:
    """(N,) the first step at which the sensor read each cell (T where never). O(T F + N)."""
    cells = run.model.footprint_cells[run.locations]  # (T, F)
    steps = np.broadcast_to(np.arange(run.n_steps)[:, None], cells.shape)
    first = np.full(run.model.n_cells, run.n_steps, dtype=np.int64)
    np.minimum.at(first, cells[cells >= 0], steps[cells >= 0])
    return first


@functools.lru_cache(maxsize=4)
def _run_facts(run: Run) -> _RunFacts:
    """The :class:`_RunFacts` of ``run``, read-only, computed once per run (a Run is immutable and
    hashed by identity) for the last few runs: a sweep scores every estimator of a run one after
    the other (25 in the corridor study), each then at the cost of its beliefs only. Cost, the
    first time: that of :func:`told_location` and :func:`observable_cells` (about 0.15 ms
    on a corridor of 12 cells, 0.3 s for 2000 steps on 32 x 32 or 64 x 64 cells); then O(1)
    (the floor distances are computed as they are asked for)."""
    model = run.model
    told_map, told_error = told_location(model, run)
    counts = cell_counts(told_map, run.final_map)
    told = (("told_location_map_error", float(metrics.map_error(told_map, run.final_map))),
            ("told_location_wrong", counts.wrong), ("told_location_unsure_or_wrong", counts.unsure_or_wrong),
            ("told_location_confidently_wrong", counts.confidently_wrong))
    return _RunFacts(read_only(np.unique(run.locations)), read_only(read_cells(run)),
                     read_only(observable_cells(model, run.initial_map)), read_only(first_read(run)),
                     floor_distances(run), read_only(told_error), told)


def _honest_columns(run: Run, trajectory: Trajectory, p_true: np.ndarray) -> dict[str, np.ndarray]:
    """The per-step columns that say how far off and how honest the belief is, (T,) each:
    ``location_distance`` (the expected moves between the location belief and the true cell on
    the true floor: :func:`floor_distances`), ``location_claimed`` (``sum_i P(L_t = i)^2``, the
    P(true cell) the belief expects), and over the cells the sensor has read by step t,
    ``read_map_p_true`` (their mean P(true label): ``p_true`` (T, N), every cell's) and
    ``read_map_claimed`` (their mean ``sum_k P(m_i = k)^2``; both NaN before a first reading).
    O(T N K)."""
    facts = _run_facts(run)
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
    facts = _run_facts(run)
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
    :func:`told_location_map` (once per run for the last few runs: :func:`_run_facts`)."""
    steps = step_columns(run, trajectory, reference) if steps is None else steps
    column = {name: np.asarray(steps[name]) for name in steps}
    final = {name: values[-1] for name, values in column.items()}
    location_error = column["location_error"]
    final_map = trajectory.map[-1]
    facts = _run_facts(run)
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
    row.update(honest_metrics(column))
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
