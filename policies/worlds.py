"""Worlds for exploration experiments: a door world whose floor plan the robot roughly knows.

With the default uniform label prior the robot must build the map from nothing while it is
localised only by what it has already mapped; at ``p_move = 0.8`` in the 10 x 10 door world it
is then lost most of the time, whatever it does (location error about 0.6-0.9 with RBPF, for
every planner). A robot given the building's floor plan (free space and walls, believed with
``confidence``; door cells known to be doors, open or closed unknown) can localise on the walls
and spend its effort on what changes: the doors.
"""

from __future__ import annotations

import numpy as np

from onlinemap.model import GridModel, door_world
from onlinemap.worlds import floor_plan_prior, with_floor_plan  # the floor plan lives with the world specs

__all__ = ["exploration_world", "floor_plan_prior", "with_floor_plan"]


def exploration_world(p_door: float = 0.01, p_move: float = 0.9, floor_plan: float | None = 0.8, *,
                      layout: str | None = None, p_obs: float = 0.9) -> tuple[GridModel, np.ndarray]:
    """The door world used to compare planners: ``door_world(layout, ...)`` (default the 10 x 10
    layout) with the :func:`floor_plan_prior` of confidence ``floor_plan`` (None: uniform
    prior). Returns ``(model, true_map)``."""
    model, true_map = door_world(layout, p_obs=p_obs, p_move=p_move, p_door=p_door)
    if floor_plan is not None:
        model = with_floor_plan(model, true_map, floor_plan)
    return model, true_map
