"""The metrics' vocabulary: the thresholds that define them, the names of the per-step and per-run
metrics in table order, one sentence per metric for the legend printed under a table, and each
metric's range (:func:`metric_bounds`). Every scorer, table and figure reads its names and
thresholds here, so a metric is defined once. Imports nothing but the standard library: the CLI
prints a legend without loading numpy or pandas.
"""

from __future__ import annotations

import math

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
                "told_location_map_error", "excess_map_error", "told_map_location_error", "told_map_location_distance")
RUN_METRICS = ("final_map_error", "mean_map_error", "final_location_error", "mean_location_error",
               "max_location_error", "wrong_cells", "unsure_or_wrong", "confidently_wrong", "wrong_visited",
               "read_map_error", "read_wrong_cells", "ends_lost", "failed", "min_p_true_way_back",
               "astray_way_back", "told_location_map_error", "told_location_wrong", "told_location_unsure_or_wrong",
               "told_location_confidently_wrong", "excess_map_error", "mean_location_distance",
               "late_location_distance", "told_map_location_error", "told_map_location_distance",
               "excess_location_distance", "final_location_distance", "mean_location_p_true", "mean_location_claimed",
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
    "told_map_location_error": "1 - P(true cell) of a robot told the true map at every step, from the same moves "
                               "and readings (exact; what these readings allow), mean over the second half of the "
                               "run (per step: at that step)",
    "told_map_location_distance": "the same robot's expected moves on the true floor to the true cell, mean over "
                                  "the second half of the run (per step: at that step)",
    "excess_location_distance": "late_location_distance minus told_map_location_distance: what not knowing the "
                                "map costs the location",
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
    "steps_to_goal": "steps until the robot first stands on the goal",
    "oracle_steps": "steps of a robot that knows its cell and the true map, in the same world history",
    "steps_over_oracle": "steps_to_goal / oracle_steps, per run",
    "success": f"share of runs reaching the goal within {SUCCESS_WITHIN}x the oracle's steps",
    "stalled": "share of runs that stalled: the belief did not move for stall_after presses in a row (the run ends)",
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
    objectives, the difference of two distances ``excess_location_distance``)."""
    if name == "excess_location_distance":
        return -math.inf, math.inf
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

