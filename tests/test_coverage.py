"""Coverage metrics (onlinemap.evaluate) against hand computations: the steps to a map error, the
area under the map-error curve, the cells a robot could ever read, the known cells."""

import math

import numpy as np
import pandas as pd
import pytest

import onlinemap as om
from onlinemap.estimators.base import Trajectory
from onlinemap.evaluate import (KNOWN_ABOVE, coverage, from_steps, observable_cells, run_metrics,
                                step_metrics)


def test_coverage_of_a_map_error_curve():
    row = coverage([0.5, 0.3, 0.1, 0.2, 0.04])
    assert row["map_error_area"] == pytest.approx(1.14)
    assert row["steps_to_map_error_20"] == 2.0  # 0.1 at t = 2 is the first at most 0.2
    assert row["steps_to_map_error_10"] == 2.0  # at most: 0.1 itself counts
    assert row["steps_to_map_error_05"] == 4.0
    assert math.isnan(coverage([0.5, 0.3])["steps_to_map_error_10"])  # never reached


def test_observable_cells_of_a_walled_in_start():
    """From the top-left corner, walls east and south: the robot never leaves it, and its cross
    footprint reads itself and the two walls (cells 0, 1, 3); the rest is unobservable."""
    model, true_map = om.door_world(".#.\n##.\n...\n", blocking=True, footprint="cross")
    assert model.start == 0
    assert observable_cells(model, true_map).tolist() == [0, 1, 3]
    # without blocking the robot walks anywhere: every cell is observable
    free, labels = om.door_world(".#.\n##.\n...\n", footprint="cross")
    assert observable_cells(free, labels).tolist() == list(range(9))
    # a one-cell sensor reads only where the robot can stand
    cell, labels = om.door_world(".#.\n##.\n...\n", blocking=True)
    assert observable_cells(cell, labels).tolist() == [0]


def test_step_and_run_metrics_count_known_cells_and_the_observable_error():
    model, true_map = om.door_world(".#.\n##.\n...\n", blocking=True, footprint="cross")
    run = om.simulate(model, true_map, [1, 2, 1], seed=0)  # bumps: the robot stays in cell 0
    maps = np.full((run.n_steps, 9, 4), 0.25)
    maps[2:, 0] = [0.95, 0.05 / 3, 0.05 / 3, 0.05 / 3]  # cell 0 (free) known from t = 2
    maps[3, 1] = [0.05, 0.91, 0.02, 0.02]  # cell 1 (wall) known at t = 3
    location = np.zeros((run.n_steps, 9))
    location[:, 0] = 1.0
    trajectory = Trajectory(location, maps, np.zeros(run.n_steps), 0.0)
    steps = step_metrics(run, trajectory)
    assert steps["known_cells"].tolist() == [0, 0, 1, 2]
    # over the observable cells 0, 1, 3: 1 - mean P(true label)
    expected = [0.75, 0.75, 1 - (0.95 + 0.25 + 0.25) / 3, 1 - (0.95 + 0.91 + 0.25) / 3]
    assert steps["observable_map_error"].to_numpy() == pytest.approx(expected)
    assert steps["map_error"].iloc[3] == pytest.approx(1 - (0.95 + 0.91 + 7 * 0.25) / 9)
    row = run_metrics(run, trajectory, steps=steps)
    assert row["final_known_cells"] == 2 and row["final_observable_map_error"] == pytest.approx(expected[-1])
    assert row["map_error_area"] == pytest.approx(steps["map_error"].sum())
    assert math.isnan(row["steps_to_map_error_20"])
    assert KNOWN_ABOVE == 0.9


def test_per_step_tables_give_the_same_coverage_per_run():
    steps = pd.DataFrame({"planner": ["a"] * 3 + ["b"] * 3, "seed": 0, "t": [0, 1, 2] * 2,
                          "map_error": [0.5, 0.15, 0.04, 0.6, 0.5, 0.4], "location_error": 0.0})
    runs = from_steps(steps, ["planner", "seed"])
    assert runs["steps_to_map_error_20"].tolist()[0] == 1.0 and math.isnan(runs["steps_to_map_error_20"].iloc[1])
    assert runs["map_error_area"].tolist() == pytest.approx([0.69, 1.5])
