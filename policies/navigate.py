"""Navigation runs (DESIGN.md section 8): the exploration loop of :mod:`policies.explore` with a
goal planner, stopped when the true robot stands on the goal, and the true distance to the goal at
every step; and the omniscient oracle a navigation study compares against.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import pandas as pd
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra

from onlinemap import arguments
from onlinemap.errors import ModelError
from onlinemap.estimators import Estimator, Trajectory
from onlinemap.model import GridModel
from onlinemap.rng import SeedLike
from onlinemap.simulate import Run, world_step
from onlinemap.validation import check_map

from .explore import COLUMNS, _seeds, exploration
from .navigation import check_goal, plan_to_goal
from .planners import Planner
from .planners import planner_options as named_options

NAVIGATION_COLUMNS = COLUMNS + ("distance_to_goal",)


class Navigation(NamedTuple):
    """One navigation run: the per-step table, the step the goal was reached, the true run and
    the estimator's beliefs."""

    frame: pd.DataFrame  # one row per step: NAVIGATION_COLUMNS
    reached_at: int | None  # the first step at which the true robot stands on the goal (None: never)
    run: Run
    trajectory: Trajectory


def true_distances(model: GridModel, labels: np.ndarray, goal: int) -> np.ndarray:
    """(N,) the fewest moves from each cell to ``goal`` on the map ``labels`` (N,): a move may
    enter a cell whose label does not block; slips are not counted. inf where no path exists
    (e.g. behind a closed door). O(N A)."""
    n = model.n_cells
    cells = np.repeat(np.arange(n), model.n_actions)
    targets = model.neighbors.ravel()
    keep = (targets != cells) & ~model.blocking[np.asarray(labels)[targets]]
    reverse = sp.csr_array((np.ones(keep.sum()), (targets[keep], cells[keep])), shape=(n, n))
    return dijkstra(reverse, directed=True, indices=goal, unweighted=True)


def _distances_to_goal(model: GridModel, run: Run, goal: int) -> np.ndarray:
    """(T,) :func:`true_distances` from the true location on the true map of each step (one
    search per distinct map)."""
    found: dict[bytes, np.ndarray] = {}
    out = np.empty(run.n_steps)
    for t, (labels, location) in enumerate(zip(run.maps, run.locations)):
        key = labels.tobytes()
        if key not in found:
            found[key] = true_distances(model, labels, goal)
        out[t] = found[key][location]
    return out


def navigate(model: GridModel, true_map, goal, planner: str | Planner = "goto", estimator: str | Estimator = "rbpf",
             *, max_steps: int, seed: SeedLike, estimator_options: dict | None = None,
             planner_options: dict | None = None, progress: bool | None = None) -> Navigation:
    """Drive the robot towards ``goal`` (a cell index or ``(row, col)``) in closed loop: the loop
    of :func:`policies.explore.exploration` (the same world, estimator and planner streams from
    ``seed``), ended when the true robot stands on the goal or after ``max_steps`` actions.

    ``planner``: a registered name (``goto``, ``static_goto``; a named planner that takes a goal
    is given this one, others, e.g. ``random``, run as they are) or a planner instance (whose
    ``goal``, if it has one, must be this goal). The goal is checked as the goal planners check it
    (:func:`~policies.navigation.check_goal`: ModelError naming it when off the grid, a wall under
    the prior or cut off from the start).

    Returns a :class:`Navigation`: ``frame`` has one row per step (at most ``max_steps + 1``),
    the columns of :data:`policies.explore.COLUMNS` plus ``distance_to_goal``, the fewest moves
    from the true location to the goal on the true map of that step (:func:`true_distances`; inf
    while the goal is cut off, 0 on the goal); ``reached_at`` the step at which the robot first
    stands on the goal, or None. Cost: the steps taken x (estimator step + planner choice), plus
    O(N A) per distinct true map for the distances.
    """
    max_steps = arguments.integer("max_steps", max_steps, minimum=0)
    cell = check_goal(model, goal)
    if isinstance(planner, str):
        options = dict(planner_options or {})
        if "goal" in named_options(planner):
            if "goal" in options:
                raise ModelError("give the goal once, as navigate's goal, not in planner_options")
            options["goal"] = goal
        planner_options = options
    elif getattr(planner, "goal", cell) != cell:
        raise ModelError(f"the planner goes to cell {planner.goal}, not to the goal {goal!r} (cell {cell})")
    found = exploration(model, true_map, planner, estimator, max_steps + 1, seed, estimator_options=estimator_options,
                        planner_options=planner_options, progress=progress, until=lambda location: location == cell)
    frame = found.frame
    frame["distance_to_goal"] = _distances_to_goal(model, found.run, cell)
    frame.attrs["goal"] = cell
    at_goal = np.flatnonzero(found.run.locations == cell)
    return Navigation(frame, int(at_goal[0]) if len(at_goal) else None, found.run, found.trajectory)


def oracle_steps(model: GridModel, true_map, goal, *, max_steps: int, seed: SeedLike,
                 horizon: int | None = None) -> int | None:
    """The steps an omniscient robot needs to reach ``goal``, for comparison in a study (not a
    planner: it reads the true state). At every step it knows its true location and the true map
    of now, plans with :func:`~policies.navigation.plan_to_goal` on that map (certain marginals;
    doors may still change by C on the way, so it waits or detours as :class:`GoTo` would with
    perfect knowledge) and takes the cheapest action from its cell; the world moves by
    :func:`onlinemap.simulate.world_step` from the world stream of ``seed``, as in
    :func:`navigate` (the same draws while the two robots' sensors read the same number of cells).
    Returns the step at which it first stands on the goal, or None after ``max_steps`` actions.
    Cost: one plan per distinct true map met, O(max_steps (N + F)) for the world."""
    max_steps = arguments.integer("max_steps", max_steps, minimum=0)
    cell = check_goal(model, goal)
    labels = check_map(model, true_map)
    rng = _seeds(seed)[0]
    location, labels, _ = world_step(model, model.start, labels, None, rng)
    plans: dict[bytes, np.ndarray] = {}
    for t in range(max_steps):
        if location == cell:
            return t
        key = labels.tobytes()
        if key not in plans:
            plans[key] = plan_to_goal(model, np.eye(model.n_labels)[labels], cell, horizon).q
        location, labels, _ = world_step(model, location, labels, int(np.argmin(plans[key][location])), rng)
    return max_steps if location == cell else None
