"""Rules of the navigation and coverage metrics (onlinemap.evaluate), each on a run small enough to
work out by hand (issue 43 section 3): success at exactly four times the oracle's steps, the oracle
reaching the goal on its last allowed step, and the observable cells taken from the map the run
started with (a door that closes during the run does not hide what lay behind it).

Every expected value is written here, never read from the module under test."""

from __future__ import annotations

import math

import numpy as np
import pytest

import onlinemap as om
from onlinemap.estimators.base import Trajectory
from onlinemap.evaluate import navigation_metrics, run_metrics, step_metrics
from onlinemap.simulate import Run
from policies import navigate
from policies.navigate import oracle_steps


# --- navigation success ------------------------------------------------------------------------
@pytest.mark.parametrize("oracle, reached_at, success", [
    (10, 40, True),   # exactly 4 x the oracle's steps: still a success ("within")
    (10, 41, False),  # one step more: a failure
    (3, 12, True), (3, 13, False),
    (1, 4, True), (1, 5, False),
    (0, 4, True), (0, 5, False),  # the robot starts on the goal: the oracle's 0 counts as one step
])
def test_success_is_reaching_the_goal_within_four_times_the_oracles_steps(oracle, reached_at, success):
    row = navigation_metrics(reached_at, oracle)
    assert row["success"] is success
    assert row["reached"] and row["oracle_reached"]
    assert row["steps_over_oracle"] == pytest.approx(reached_at / max(oracle, 1))


def test_no_success_without_the_goal_or_without_an_oracle():
    assert navigation_metrics(None, 5)["success"] is False
    assert navigation_metrics(3, None)["success"] is False  # counted over runs where the oracle got there
    assert math.isnan(navigation_metrics(None, 5)["steps_to_goal"])


class Dawdler:
    """Presses ``left`` (into the corridor's end at cell 0) ``wait`` times, then ``right`` for ever."""

    def __init__(self, model, wait):
        self.model, self.wait, self.calls = model, wait, 0

    def choose(self, belief):
        self.calls += 1
        return 0 if self.calls <= self.wait else 1


@pytest.mark.parametrize("wait, success", [(6, True), (7, False)])
def test_a_hand_built_navigation_run_at_four_times_the_oracle_succeeds(wait, success):
    """A 5-cell corridor with perfect wheels, the goal 2 cells right of the start: the oracle needs
    2 steps. A robot that first presses into the wall 6 times arrives at step 8 = 4 x 2 (success),
    after 7 presses at step 9 (failure)."""
    model = om.corridor(5, 2, p_obs=0.9, p_move=1.0)
    true_map = np.zeros(5, dtype=np.int64)
    oracle = oracle_steps(model, true_map, 2, max_steps=20, seed=0)
    assert oracle == 2
    found = navigate(model, true_map, 2, Dawdler(model, wait), "exact", max_steps=20, seed=0)
    assert found.reached_at == wait + 2
    assert found.run.locations.tolist()[-3:] == [0, 1, 2]
    assert navigation_metrics(found.reached_at, oracle)["success"] is success


@pytest.mark.parametrize("max_steps, expected", [(4, 4), (3, None), (5, 4), (0, None)])
def test_the_oracle_counts_a_goal_reached_on_its_last_allowed_step(max_steps, expected):
    """Corridor of 5 cells, perfect wheels, goal at the far end (4 moves): with exactly 4 actions
    allowed the oracle stands on the goal after its last one."""
    model = om.corridor(5, 2, p_move=1.0)
    assert oracle_steps(model, np.zeros(5, dtype=np.int64), 4, max_steps=max_steps, seed=0) == expected


def test_the_oracle_on_the_start_takes_zero_steps():
    model = om.corridor(5, 2, p_move=1.0)
    assert oracle_steps(model, np.zeros(5, dtype=np.int64), 0, max_steps=0, seed=0) == 0


# --- observable cells come from the initial map ------------------------------------------------
def door_closing_run():
    """A 2 x 3 door world ``. o .`` over a wall row, blocking, one-cell sensor; the robot in cell 0
    presses north (the grid's edge) twice; the door (cell 1) is open at t = 0, 1 and closed at t = 2.
    From the start, through the open door, cells 0, 1, 2 are reachable (and read by a one-cell
    sensor); with the final map only cell 0 would be."""
    model, true_map = om.door_world(".o.\n###\n", blocking=True, p_door=0.1)
    assert model.start == 0 and true_map.tolist() == [0, 2, 0, 1, 1, 1]
    north = model.action_names.index("north")
    closed = true_map.copy()
    closed[1] = 3
    maps = np.stack([true_map, true_map, closed])
    run = Run(model, np.array([north, north]), np.array([0, 0, 0]), maps, np.array([0, 0, 0]))
    return model, run


def test_the_observable_map_error_is_over_the_cells_reachable_in_the_initial_map():
    """Belief: cell 0 known free (P = 1) at every step, every other cell uniform (1/4 each label).
    Over the observable cells 0, 1, 2: 1 - (1 + 1/4 + 1/4) / 3 = 1/2 at every step (the closed door
    is still unknown at 1/4). Over cell 0 alone (the final map's reachable cells) it would be 0."""
    model, run = door_closing_run()
    maps = np.full((3, 6, 4), 0.25)
    maps[:, 0] = [1.0, 0.0, 0.0, 0.0]
    location = np.zeros((3, 6))
    location[:, 0] = 1.0
    trajectory = Trajectory(location, maps, np.zeros(3), 0.0)
    steps = step_metrics(run, trajectory)
    np.testing.assert_allclose(steps["observable_map_error"].to_numpy(), [0.5, 0.5, 0.5], atol=1e-15)
    np.testing.assert_allclose(steps["map_error"].to_numpy(), [1 - (1 + 5 * 0.25) / 6] * 3, atol=1e-15)
    row = run_metrics(run, trajectory, steps=steps)
    assert row["final_observable_map_error"] == pytest.approx(0.5, abs=1e-15)
