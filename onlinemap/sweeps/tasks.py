"""Sweep tasks: one cell of the product (world, estimator configuration[, planner
configuration, floor plan, goal], steps, walk, seed), its stable key, the expansion of a
validated spec into tasks (counted before any is built, against a cap), and the rows a task
gives (:class:`TaskRows`: plain columns, made a frame once for many tasks by :func:`stacked`).

Imports: nothing of the sweeps package (every other module of it imports this one).
"""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
import json
import math
from dataclasses import dataclass
from functools import cached_property
from typing import Mapping, NamedTuple, Sequence

import numpy as np
import pandas as pd

from ..errors import OnlineMapError

#: default cap on the tasks of one sweep (raise it with ``max_tasks`` / ``--max-tasks``)
MAX_TASKS = 100_000
# Columns describing a task (the configuration and the seed); everything else is a metric.
TASK_COLUMNS = ("task", "kind", "world", "estimator", "label", "options", "planner", "planner_label",
                "planner_options", "floor_plan", "goal", "steps", "walk", "reference", "seed")
CONFIG_COLUMNS = tuple(c for c in TASK_COLUMNS if c not in ("task", "seed"))
OPTION_PREFIXES = {"options": "opt_", "planner_options": "planner_opt_"}
UNHASHED = ("label", "planner_label")


@dataclass(frozen=True)
class Task:
    """One cell of a sweep. ``options`` and ``planner_options`` are sorted (name, value) pairs.
    Its kind: ``estimate`` (simulate and filter), ``explore`` (a planner chooses the actions) or
    ``navigate`` (a planner takes the robot to ``goal``); see :mod:`.kinds`."""

    world: str
    estimator: str
    options: tuple
    seed: int
    steps: int | str  # "trip": one there-and-back trip, 2 (N - 1) + 1 steps
    walk: str = "random"
    reference: str | None = None
    per_step: bool = False
    planner: str | None = None
    planner_options: tuple = ()
    floor_plan: float | None = None
    goal: int | None = None
    played: str | None = None  # the kind that plays the task when the fields above do not say it
    label: str | None = None  # the spec's name for the estimator configuration (not hashed)
    planner_label: str | None = None  # ... and for the planner configuration (not hashed)

    @property
    def kind(self) -> str:
        if self.played is not None:
            return self.played
        if self.goal is not None:
            return "navigate"
        return "explore" if self.planner else "estimate"

    @cached_property
    def key(self) -> str:
        """A stable hash of everything that determines the task's result (16 hex digits); fields
        left at None are not hashed, so adding an optional field keeps existing keys; labels
        name a result and do not change it, so they are not hashed either. Computed once per
        task (about 50 us; a sweep asks several times per task)."""
        values = {field.name: getattr(self, field.name) for field in dataclasses.fields(self)}
        fields = {k: v for k, v in values.items() if v is not None and k not in UNHASHED}
        return hashlib.sha256(json.dumps(plain(fields), sort_keys=True).encode()).hexdigest()[:16]


class SweepSpec(NamedTuple):
    """A validated spec: its tasks in order (seeds innermost), where it came from and its text
    (recorded in the results table's provenance)."""

    name: str
    tasks: tuple[Task, ...]
    source: str
    text: str = ""


def plain(value):
    """Tuples to lists, recursively (JSON and the hash see the same structure)."""
    if isinstance(value, dict):
        return {k: plain(v) for k, v in value.items()}
    if isinstance(value, (tuple, list)):
        return [plain(v) for v in value]
    return value


def frozen(value):
    """Lists to tuples, recursively (hashable option values)."""
    return tuple(frozen(v) for v in value) if isinstance(value, (list, tuple)) else value


def options_text(options: tuple) -> str:
    """``(("n_particles", 10), ("proposal", "optimal"))`` -> ``n_particles=10, proposal="optimal"``."""
    return ", ".join(f"{k}={json.dumps(plain(v))}" for k, v in options)


def count_tasks(*axes: Sequence) -> int:
    """The size of the product of ``axes`` (before duplicates are merged), without building it."""
    return math.prod(len(axis) for axis in axes)


def expand(worlds: Sequence[str], estimators: Sequence[tuple], planners: Sequence[tuple],
           floor_plans: Sequence, steps: Sequence, walks: Sequence[str], seeds: Sequence[int],
           reference: str | None, per_step: bool, max_tasks: int = MAX_TASKS,
           goals: Sequence = (None,), played: str | None = None) -> tuple[Task, ...]:
    """Every task of the product, seeds innermost, each distinct task once (a repeated world or
    grid value runs once). ``estimators`` / ``planners``: (name, options, label) triples. Raises
    OnlineMapError, before building anything, if the product exceeds ``max_tasks``.
    Cost: O(number of tasks)."""
    total = count_tasks(worlds, estimators, planners, floor_plans, goals, steps, walks, seeds)
    if total > max_tasks:
        raise OnlineMapError(f"{total:,} tasks exceed the cap of {max_tasks:,} (max_tasks / --max-tasks "
                             f"raises it); fewer seeds or a smaller grid?")
    tasks, seen = [], set()
    for world, (est, options, label), (planner, planner_opts, planner_label), plan, goal, n_steps, walk, seed in \
            itertools.product(worlds, estimators, planners, floor_plans, goals, steps, walks, seeds):
        task = Task(world, est, options, int(seed), n_steps, walk, reference, per_step, planner, planner_opts, plan,
                    goal, played, label, planner_label)
        if task.key not in seen:
            seen.add(task.key)
            tasks.append(task)
    return tuple(tasks)



class TaskRows(NamedTuple):
    """What one task gave, before it is a frame: ``n`` rows of ``columns`` (by name, in order;
    each a (n,) array, or one value for every row) and its ``options`` (``opt_NAME`` /
    ``planner_opt_NAME`` -> value). Plain values, so that a table of many tasks is one frame
    built once (:func:`stacked`), not one frame per task."""

    n: int
    columns: dict[str, object]
    options: dict[str, object]

    def frame(self) -> pd.DataFrame:
        """The task's frame: its columns, then one column per option. Cost: one DataFrame
        (about 1-2 ms for one row)."""
        return stacked([{**self.columns, **self.options}], [self.n])


def stacked(columns: Sequence[Mapping[str, object]], lengths: Sequence[int]) -> pd.DataFrame:
    """One frame of the rows of several tasks' ``columns`` (:class:`TaskRows`; ``lengths`` rows
    each; the same names in the same order, and in each column arrays of one dtype or values of
    one Python type): arrays concatenated, values repeated over their task's rows, and each
    column's type inferred once by pandas, as it is for each task alone. Cost: one DataFrame,
    O(rows x columns)."""
    data: dict[str, np.ndarray | list] = {}
    for name, first in columns[0].items():
        if isinstance(first, np.ndarray):
            data[name] = np.concatenate([task[name] for task in columns])
        else:
            data[name] = [task[name] for task, n in zip(columns, lengths) for _ in range(n)]
    return pd.DataFrame(data)
