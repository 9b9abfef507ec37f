"""Navigation runs (DESIGN.md section 8): the exploration loop of :mod:`policies.explore` with a
goal planner, stopped when the true robot stands on the goal, and the true distance to the goal at
every step; and the omniscient oracle a navigation study compares against.

The true world of a navigation run (:class:`PairedWorld`) draws its map changes, its slips and its
sensor readings from three separate streams of the seed, so that every run with one seed,
whatever the robot does, meets the same doors and the same slips step by step: planners (and the
oracle) are compared on the same building history (paired runs). The dynamics are the model's
(:func:`onlinemap.simulate.world_step`); only the order of the random draws differs, so a
navigation run is not the exploration run of the same seed.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import pandas as pd
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra

from onlinemap import arguments
from onlinemap.belief import STALL_AFTER
from onlinemap.errors import InvalidOptionError
from onlinemap.estimators import Estimator, Trajectory
from onlinemap.model import GridModel
from onlinemap.rng import SeedLike
from onlinemap.simulate import Run, categorical, world_step
from onlinemap.validation import check_map

from .explore import COLUMNS, WorldState, closed_loop, loop_estimator, loop_planner, seed_streams
from .navigation import check_goal, plan_to_goal
from .planners import Planner
from .planners import planner_options as named_options

NAVIGATION_COLUMNS = COLUMNS + ("distance_to_goal",)


class PairedWorld:
    """The true world of navigation runs: the order of DESIGN.md section 1 (the action moves the
    robot, then the map changes, then the robot observes, :func:`onlinemap.simulate.world_step`'s
    rules), each kind of draw from its own stream of ``rng``: one uniform per step for the slip,
    whatever the action; N categorical draws per step for the map (a static world draws none);
    the readings through ``world_step``. Two worlds built from equal generators therefore have the
    same maps and slips at every step whatever their robots do. Cost per step O(N + F)."""

    def __init__(self, model: GridModel, true_map, rng: np.random.Generator):
        self.model = model
        self.location, self.labels = model.start, check_map(model, true_map)
        self._maps, self._slips, self._readings = rng.spawn(3)

    def reset(self) -> WorldState:
        """Step 0: the first observation."""
        return self._observe()

    def advance(self, action: int) -> WorldState:
        """One step with ``action``: ``(observation, location, labels)`` after it."""
        model = self.model
        moves = self._slips.random() < model.p_move
        target = int(model.neighbors[self.location, action])
        if moves and not model.blocking[self.labels[target]]:
            self.location = target
        if not model.is_static:
            self.labels = categorical(self._maps, model.change[self.labels])
        return self._observe()

    def _observe(self) -> WorldState:
        _, _, observation = world_step(self.model, self.location, self.labels, None, self._readings)
        return observation, self.location, self.labels


class Navigation(NamedTuple):
    """One navigation run: the per-step table, the step the goal was reached, the true run and
    the estimator's beliefs."""

    frame: pd.DataFrame  # one row per step: NAVIGATION_COLUMNS
    reached_at: int | None  # the first step at which the true robot stands on the goal (None: never)
    run: Run
    trajectory: Trajectory
    stalled_at: int | None = None  # the step at which the run stalled and ended (closed_loop), None if it did not

    def __repr__(self) -> str:
        """One line (the frame's rows are its own to print): the goal, when it was reached, the
        steps and the fields' sizes."""
        reached = "never reached" if self.reached_at is None else f"reached at step {self.reached_at}"
        if self.stalled_at is not None:
            reached += f", stalled at step {self.stalled_at}"
        rows, columns = self.frame.shape
        return (f"Navigation(goal cell {self.frame.attrs.get('goal')} {reached}; {self.run.n_steps} steps from "
                f"cell {self.run.locations[0]} to {self.run.locations[-1]}; frame {rows} rows x {columns} columns, "
                f"run, trajectory)")


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
             planner_options: dict | None = None, progress: bool | None = None,
             score: bool = True, stall_after: int | None = STALL_AFTER) -> Navigation:
    """Drive the robot towards ``goal`` (a cell index or ``(row, col)``) in closed loop: the loop
    of :func:`policies.explore.exploration` (planner chooses, world moves, estimator updates) in a
    :class:`PairedWorld`, ended when the true robot stands on the goal or after ``max_steps``
    actions. ``seed`` fixes the world, a named planner and a named estimator, as in ``explore``.

    ``planner``: a registered name (``goto``, ``static_goto``; a named planner that takes a goal
    is given this one, others, e.g. ``random``, run as they are) or a planner instance (whose
    ``goal``, if it has one, must be this goal). The goal is checked as the goal planners check it
    (:func:`~policies.navigation.check_goal`: InvalidOptionError naming it when off the grid, a wall under
    the prior or cut off from the start).

    Returns a :class:`Navigation`: ``frame`` has one row per step (at most ``max_steps + 1``),
    the columns of :data:`policies.explore.COLUMNS` plus ``distance_to_goal``, the fewest moves
    from the true location to the goal on the true map of that step (:func:`true_distances`; inf
    while the goal is cut off, 0 on the goal); ``reached_at`` the step at which the robot first
    stands on the goal, or None; with ``score`` False the frame holds only ``distance_to_goal``
    (the sweep engine scores the run itself); ``stalled_at`` the step at which the run stalled and
    ended (``stall_after`` presses in a row left the belief as it was,
    :func:`policies.explore.closed_loop`; None: never). Cost: the steps taken x (estimator step + planner choice), plus
    O(N A) per distinct true map for the distances.
    """
    max_steps = arguments.integer("max_steps", max_steps, minimum=0, error=InvalidOptionError)
    cell = check_goal(model, goal)
    if isinstance(planner, str):
        options = dict(planner_options or {})
        if "goal" in named_options(planner):
            if "goal" in options:
                raise InvalidOptionError("give the goal once, as navigate's goal, not in planner_options")
            options["goal"] = goal
        planner_options = options
    elif getattr(planner, "goal", cell) != cell:
        raise InvalidOptionError(f"the planner goes to cell {planner.goal}, not to the goal {goal!r} (cell {cell})")
    world_rng, planner_rng, estimator_seed = seed_streams(seed)
    world = PairedWorld(model, true_map, world_rng)
    est = loop_estimator(model, estimator, estimator_options, estimator_seed)
    chooser = loop_planner(model, planner, planner_options, planner_rng)
    found = closed_loop(model, world.reset, world.advance, chooser, est, max_steps + 1, progress,
                        until=lambda location: location == cell, score=score, stall_after=stall_after)
    frame = found.frame if score else pd.DataFrame(index=range(found.run.n_steps))
    frame["distance_to_goal"] = _distances_to_goal(model, found.run, cell)
    frame.attrs["goal"] = cell
    at_goal = np.flatnonzero(found.run.locations == cell)
    return Navigation(frame, int(at_goal[0]) if len(at_goal) else None, found.run, found.trajectory,
                      found.stalled_at)


def oracle_steps(model: GridModel, true_map, goal, *, max_steps: int, seed: SeedLike,
                 horizon: int | None = None) -> int | None:
    """The steps an omniscient robot needs to reach ``goal``, for comparison in a study (not a
    planner: it reads the true state). It moves in the :class:`PairedWorld` of ``seed`` (the
    doors and slips that :func:`navigate` with that seed meets, step by step); at every step it
    knows its true location and the true map of now and plans with
    :func:`~policies.navigation.plan_to_goal` on that map (certain marginals, the doors still
    changing by C on the way: it waits or goes round as :class:`~policies.navigation.GoTo`
    would, knowing what it knows), taking the cheapest action from its cell. Returns the step at
    which it first stands on the goal, or None after ``max_steps`` actions. Cost: one plan per
    distinct true map met, plus O(N + F) per step."""
    max_steps = arguments.integer("max_steps", max_steps, minimum=0, error=InvalidOptionError)
    cell = check_goal(model, goal)
    world = PairedWorld(model, true_map, seed_streams(seed)[0])
    _, location, labels = world.reset()
    plans: dict[bytes, np.ndarray] = {}
    for t in range(max_steps):
        if location == cell:
            return t
        key = labels.tobytes()
        if key not in plans:
            plans[key] = plan_to_goal(model, np.eye(model.n_labels)[labels], cell, horizon).q
        _, location, labels = world.advance(int(np.argmin(plans[key][location])))
    return max_steps if location == cell else None
