"""Task kinds: what a sweep task runs besides simulate-and-filter, registered with the engine by
the package that owns it, so that the engine never imports that package.

The engine runs one kind itself, ``estimate``: simulate a run, filter it, score it. A kind
whose tasks are *played* (a planner chooses the actions: ``explore``, and ``navigate``, which
also has a goal) belongs to ``policies``, above the engine. It describes itself with a
:class:`TaskKind` (how to list, type and build its configurations, and how to play one task),
and it is found in one of two ways:

- :func:`register_kind` (a package registers its kinds when it is imported);
- the ``onlinemap.task_kinds`` entry-point group (``pyproject.toml``), loaded on the first
  lookup of a name nobody registered, so a spec file with ``[planners]`` runs in a process
  that never imported ``policies``, a dask worker included.

The engine scores what a kind plays (:mod:`onlinemap.evaluate`, once per task); a kind may add
columns of its own (``distance_to_goal`` per step, ``reached_at`` per run).

Imports: :mod:`.tasks`; the model, simulation and beliefs types only.
"""

from __future__ import annotations

import importlib.metadata
from typing import Callable, NamedTuple

import numpy as np

from ..errors import OnlineMapError
from ..estimators.base import Trajectory
from ..model import GridModel
from ..simulate import Run
from .tasks import Task

ENTRY_POINTS = "onlinemap.task_kinds"


class Played(NamedTuple):
    """What a kind's :attr:`TaskKind.play` returns for one task: the true run and the
    estimator's beliefs (scored by the engine), and the kind's own columns."""

    run: Run
    trajectory: Trajectory
    step_columns: dict[str, np.ndarray]  # extra per-step columns, (T,) each
    run_columns: dict[str, float | int | None]  # extra per-run metrics


class TaskKind(NamedTuple):
    """A kind of task whose configurations live in a spec section (``[planners.NAME]``).

    ``options(name)``: the configuration's options and defaults (raises OnlineMapError for an
    unknown name); ``option_class(name)``: the class whose ``__init__`` annotates them (the spec
    checks value types against it); ``build(model, name, options)``: build one configuration on a
    model (the spec builds each once, so refused values show before any task runs);
    ``prior(model, true_map, confidence)``: the robot's model given a floor plan of that
    confidence (``floor_plan`` in a spec); ``play(model, true_map, task)``: run one task in
    its world. Every function must be importable by name (module level), so a dask worker can
    unpickle it."""

    name: str
    section: str
    options: Callable[[str], dict]
    option_class: Callable[[str], type]
    build: Callable[[GridModel, str, dict], object]
    prior: Callable[[GridModel, np.ndarray, float], GridModel]
    play: Callable[[GridModel, np.ndarray, Task], Played]
    keys: tuple[str, ...] = ()  # the top-level spec keys of this kind (e.g. "floor_plan", "goals")


_KINDS: dict[str, TaskKind] = {}


def register_kind(kind: TaskKind) -> TaskKind:
    """Make ``kind`` known to the engine (idempotent for the same kind; a different kind under a
    registered name raises OnlineMapError)."""
    known = _KINDS.get(kind.name)
    if known is not None and known != kind:
        raise OnlineMapError(f"a different task kind {kind.name!r} is already registered")
    _KINDS[kind.name] = kind
    return kind


def task_kind(name: str) -> TaskKind:
    """The registered kind ``name``, loading the ``onlinemap.task_kinds`` entry points of that
    name first if nobody registered it. Raises OnlineMapError if none provides it."""
    if name not in _KINDS:
        for point in importlib.metadata.entry_points(group=ENTRY_POINTS, name=name):
            register_kind(point.load())
    if name not in _KINDS:
        raise OnlineMapError(f"no task kind {name!r} is registered (tasks of this kind are provided by the "
                             f"package that owns them, e.g. policies for explore and navigate; is onlinemap "
                             f"installed with its entry points?)")
    return _KINDS[name]
