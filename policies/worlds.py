"""Worlds for exploration experiments: a door world whose floor plan the robot roughly knows.

With the default uniform label prior the robot must build the map from nothing while it is
localised only by what it has already mapped; at ``p_move = 0.8`` in the 10 x 10 door world it
is then lost most of the time, whatever it does (location error about 0.6-0.9 with RBPF, for
every planner). A robot given the building's floor plan (free space and walls, believed with
``confidence``; door cells known to be doors, open or closed unknown) can localise on the walls
and spend its effort on what changes: the doors.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from onlinemap.errors import ModelError
from onlinemap.model import CLOSED_DOOR, OPEN_DOOR, GridModel, door_cells, door_world
from onlinemap.validation import check_map


def floor_plan_prior(model: GridModel, true_map, confidence: float = 0.8) -> np.ndarray:
    """(N, K) label prior from a floor plan: ``confidence`` on each cell's true label, the rest
    spread uniformly over the other labels. In a door world, door cells get 1/2 open, 1/2
    closed (the plan shows the door, not its state)."""
    labels = check_map(model, true_map)
    k = model.n_labels
    if not 1.0 / k <= float(confidence) <= 1.0:
        raise ModelError(f"confidence must be in [1/K, 1] = [{1 / k:.3g}, 1], got {confidence!r}")
    prior = np.full((model.n_cells, k), (1.0 - confidence) / (k - 1))
    prior[np.arange(model.n_cells), labels] = confidence
    doors = door_cells(model, labels)
    if len(doors):
        prior[doors] = 0.0
        prior[np.ix_(doors, [OPEN_DOOR, CLOSED_DOOR])] = 0.5
    return prior


def with_floor_plan(model: GridModel, true_map, confidence: float = 0.8) -> GridModel:
    """``model`` with the :func:`floor_plan_prior` of ``true_map`` as its label prior."""
    return dataclasses.replace(model, label_prior=floor_plan_prior(model, true_map, confidence))


def exploration_world(p_door: float = 0.01, p_move: float = 0.9, floor_plan: float | None = 0.8, *,
                      layout: str | None = None, p_obs: float = 0.9) -> tuple[GridModel, np.ndarray]:
    """The door world used to compare planners: ``door_world(layout, ...)`` (default the 10 x 10
    layout) with the :func:`floor_plan_prior` of confidence ``floor_plan`` (None: uniform
    prior). Returns ``(model, true_map)``."""
    model, true_map = door_world(layout, p_obs=p_obs, p_move=p_move, p_door=p_door)
    if floor_plan is not None:
        model = with_floor_plan(model, true_map, floor_plan)
    return model, true_map
