"""The sweep engine's task kinds that ``policies`` owns (:mod:`onlinemap.sweeps.kinds`):
``explore`` (a planner chooses every action for ``steps`` steps) and ``navigate`` (a planner takes
the robot to the task's goal, at most ``steps - 1`` actions; the run stops there, and records the
true distance to the goal per step and :func:`onlinemap.evaluate.navigation_metrics` against the
omniscient :func:`~policies.navigate.oracle_steps` of the same world history).

The engine finds them through the ``onlinemap.task_kinds`` entry points (``pyproject.toml``),
so a spec with ``[planners.NAME]`` tables runs in any process, a dask worker included, without
the engine importing this package. A task's world, seed and floor plan are the engine's;
the loop is :func:`policies.explore.exploration`'s, unscored (the engine scores it once).

Imports: :mod:`onlinemap.sweeps.kinds`, :mod:`.explore`, :mod:`.planners`, :mod:`.worlds`.
"""

from __future__ import annotations

import numpy as np

from onlinemap.evaluate import navigation_metrics
from onlinemap.model import GridModel
from onlinemap.progress import step_bars
from onlinemap.sweeps.kinds import Played, TaskKind
from onlinemap.sweeps.tasks import Task

from .explore import exploration
from .navigate import navigate, oracle_steps
from .planners import Planner, make_planner, planner_class, planner_options
from .worlds import with_floor_plan


def build_planner(model: GridModel, name: str, options: dict) -> Planner:
    """One planner configuration built on ``model`` (the spec's check; seed 0)."""
    return make_planner(name, model, seed=0, **options)


def play_exploration(model: GridModel, true_map: np.ndarray, task: Task) -> Played:
    """:func:`~policies.explore.exploration` of the task's planner and estimator, seeded by the
    task's seed, without its frame (the engine scores the run)."""
    found = exploration(model, true_map, task.planner, task.estimator, task.steps, task.seed,
                        estimator_options=dict(task.options), planner_options=dict(task.planner_options),
                        progress=step_bars(), score=False)
    return Played(found.run, found.trajectory, {}, {})


EXPLORE = TaskKind("explore", "planners", planner_options, planner_class, build_planner, with_floor_plan,
                   play_exploration, ("floor_plan",))


def build_goal_planner(model: GridModel, name: str, options: dict) -> Planner:
    """A navigation configuration built on ``model``: the goal goes to planners that take one."""
    if "goal" not in planner_options(name):
        options = {key: value for key, value in options.items() if key != "goal"}
    return build_planner(model, name, options)


_ORACLES: dict[tuple, int | None] = {}  # the oracle of a (world, goal, steps, seed): every planner's task shares it


def play_navigation(model: GridModel, true_map: np.ndarray, task: Task) -> Played:
    """:func:`~policies.navigate.navigate` of the task's planner to its goal, unscored, with the
    true distance to the goal per step and the navigation metrics against the oracle."""
    found = navigate(model, true_map, task.goal, task.planner, task.estimator, max_steps=task.steps - 1,
                     seed=task.seed, estimator_options=dict(task.options),
                     planner_options=dict(task.planner_options), progress=step_bars(), score=False)
    key = (task.world, task.floor_plan, task.goal, task.steps, task.seed)
    if key not in _ORACLES:
        if len(_ORACLES) >= 256:  # bounded: a process keeps the oracles of its recent tasks
            _ORACLES.clear()
        _ORACLES[key] = oracle_steps(model, true_map, task.goal, max_steps=task.steps - 1, seed=task.seed)
    return Played(found.run, found.trajectory, {"distance_to_goal": found.frame["distance_to_goal"].to_numpy()},
                  navigation_metrics(found.reached_at, _ORACLES[key], found.stalled_at))


NAVIGATE = TaskKind("navigate", "planners", planner_options, planner_class, build_goal_planner, with_floor_plan,
                    play_navigation, ("floor_plan", "goals"))
