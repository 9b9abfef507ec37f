"""The sweep engine's task kinds that ``policies`` owns (:mod:`onlinemap.sweeps.kinds`):
``explore`` (a planner chooses every action for ``steps`` steps).

The engine finds them through the ``onlinemap.task_kinds`` entry points (``pyproject.toml``),
so a spec with ``[planners.NAME]`` tables runs in any process, a dask worker included, without
the engine importing this package. A task's world, seed and floor plan are the engine's;
the loop is :func:`policies.explore.exploration`'s, unscored (the engine scores it once).

Imports: :mod:`onlinemap.sweeps.kinds`, :mod:`.explore`, :mod:`.planners`, :mod:`.worlds`.
"""

from __future__ import annotations

import numpy as np

from onlinemap.model import GridModel
from onlinemap.sweeps.kinds import Played, TaskKind
from onlinemap.sweeps.tasks import Task

from .explore import _exploration
from .planners import Planner, make_planner, planner_class, planner_options
from .worlds import with_floor_plan


def build_planner(model: GridModel, name: str, options: dict) -> Planner:
    """One planner configuration built on ``model`` (the spec's check; seed 0)."""
    return make_planner(name, model, seed=0, **options)


def play_exploration(model: GridModel, true_map: np.ndarray, task: Task) -> Played:
    """:func:`~policies.explore.exploration` of the task's planner and estimator, seeded by the
    task's seed, without its frame (the engine scores the run)."""
    found = _exploration(model, true_map, task.planner, task.estimator, task.steps, task.seed,
                         dict(task.options), dict(task.planner_options), progress=False, score=False)
    return Played(found.run, found.trajectory, {}, {})


EXPLORE = TaskKind("explore", "planners", planner_options, planner_class, build_planner, with_floor_plan,
                   play_exploration, ("floor_plan",))
