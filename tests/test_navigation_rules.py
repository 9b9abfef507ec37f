"""Rules of the navigation loop worked out by hand on worlds small enough to read (issue 43,
section 3): each test fails for a realistic slip of the code it checks."""

from __future__ import annotations

import numpy as np
import pytest

import onlinemap as om
import policies
from onlinemap.belief import Belief


@pytest.fixture
def perfect_corridor():
    """Six free cells, perfect wheels: from cell 0 the goal 3 is exactly three presses right."""
    return om.corridor(6, p_move=1.0, blocking=[1]), np.zeros(6, dtype=np.int64)


def test_the_oracle_reaching_the_goal_on_its_last_allowed_step_counts(perfect_corridor):
    model, true_map = perfect_corridor
    assert policies.oracle_steps(model, true_map, 3, max_steps=3, seed=0) == 3
    assert policies.oracle_steps(model, true_map, 3, max_steps=2, seed=0) is None
    assert policies.oracle_steps(model, true_map, 3, max_steps=50, seed=0) == 3


def certain_belief(model, cell, walls) -> Belief:
    """The robot certainly in ``cell``, the cells in ``walls`` certainly label 1, the rest label 0."""
    location = np.zeros(model.n_cells)
    location[cell] = 1.0
    labels = np.tile([1.0, 0.0], (model.n_cells, 1))
    labels[list(walls)] = [0.0, 1.0]
    return Belief(0, location, labels, 0.0)


def test_unblocked_actions_falls_back_to_every_action_when_all_block():
    model = om.grid_model(3, 3, 2, blocking=[1])
    boxed_in = certain_belief(model, 4, walls=(1, 3, 5, 7))  # centre, walls N, W, E, S
    np.testing.assert_array_equal(policies.blocked_probability(model, boxed_in), [1, 1, 1, 1])
    np.testing.assert_array_equal(policies.unblocked_actions(model, boxed_in), [True, True, True, True])
    east_open = certain_belief(model, 4, walls=(1, 3, 7))  # actions north, east, south, west
    np.testing.assert_array_equal(policies.unblocked_actions(model, east_open), [False, True, False, False])
