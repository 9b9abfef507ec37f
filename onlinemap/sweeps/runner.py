"""The task runner: simulate a task's run from its seed, run its estimator (and planner), score
it with :mod:`onlinemap.evaluate`, and return its rows with the task's description and typed
option columns (so a folder of parts assembles into the table without the spec). The engines
keep the rows as plain columns (:func:`task_rows`, :class:`~.tasks.TaskRows`) and build one
frame for all the tasks of a sweep; :func:`run_task` is one task's frame.

A task simulates its run exactly as ``onlinemap run --seed`` does (``default_rng(seed)`` draws
the map, then the walk, then the noise); estimators with a ``seed`` option get one derived from
the task's seed (unless the spec sets it). Each process parses a world string once
(:func:`world`) and memoises the last runs and reference trajectories, so the tasks sharing a
run (every estimator of a seed) simulate it once.

Tasks a planner plays (``explore``, ``navigate``) are run by their registered kind
(:mod:`.kinds`); the engine scores them like any other.

Imports: :mod:`.tasks`, :mod:`.kinds`, :mod:`onlinemap.evaluate`.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import NamedTuple

import numpy as np
import pandas as pd

from ..estimators import estimator_options
from ..estimators.base import Trajectory
from ..evaluate import RUN_METRICS, STEP_METRICS, WARM_UP_STEPS, run_metrics, step_columns, timed_trajectory
from ..model import GridModel
from ..progress import counting_steps
from ..rng import ESTIMATOR_STREAM, derived_seed
from ..scenarios import one_slip_corridor
from ..simulate import Run, random_walk, there_and_back
from ..worlds import WorldSpec, parse_world
from .kinds import Played, task_kind
from .tasks import OPTION_PREFIXES, Task, TaskRows, options_text


@functools.lru_cache(maxsize=64)
def world(spec: str) -> WorldSpec:
    """The parsed world spec (memoised: each process parses a world string once)."""
    return parse_world(spec)


def walk_actions(model: GridModel, walk: str, n_actions: int, rng: np.random.Generator) -> np.ndarray:
    """``random``: uniform actions; ``there_and_back``: right N - 1 times, left N - 1 times;
    ``repeat:NAME,...``: those actions; each repeated and cut to ``n_actions`` (only ``random``
    draws from ``rng``)."""
    if walk == "random":
        return random_walk(model, n_actions, rng)
    if walk.startswith("repeat:"):
        script = [model.action_names.index(name) for name in walk[len("repeat:"):].split(",")]
        return np.resize(np.array(script, dtype=np.int64), n_actions)
    return np.resize(there_and_back(model), n_actions)


def scripted_trip(model: GridModel, labels: np.ndarray, rng: np.random.Generator) -> Run:
    """The literature's corridor run (DESIGN.md section 5.1) on a static corridor ``model`` with
    the given labels: right N - 1 times, left N - 1 times, exactly one slip at an outward move
    drawn uniformly in 1..N-1, every observation the true label
    (:func:`onlinemap.scenarios.scripted_corridor`, with ``model`` as the robot's model)."""
    return one_slip_corridor(labels, rng, model=model)[0]


@functools.lru_cache(maxsize=16)
def simulated_run(world_spec: str, steps: int | str, walk: str, seed: int) -> Run:
    """The run of a task (memoised per process: every estimator of a sweep sees the same run):
    ``default_rng(seed)`` draws the map, then the walk (``steps`` - 1 actions, or one trip),
    then the noise (:meth:`WorldSpec.simulate`); ``scripted_trip`` draws its slip instead."""
    spec = world(world_spec)
    model = spec.model
    if walk == "scripted_trip":
        rng = np.random.default_rng(seed)
        return scripted_trip(model, spec.initial_map(rng), rng)
    n_steps = 2 * (model.n_cells - 1) + 1 if steps == "trip" else steps
    return spec.simulate(n_steps, seed, walk=lambda model, n_actions, rng: walk_actions(model, walk, n_actions, rng))


def _options(name: str, options: tuple, seed: int) -> dict:
    """The task's estimator options, with a seed derived from the task's if it takes one."""
    options = dict(options)
    if "seed" in estimator_options(name):
        options.setdefault("seed", derived_seed(seed, ESTIMATOR_STREAM))
    return options


@functools.lru_cache(maxsize=16)
def reference_trajectory(world_spec: str, steps: int | str, walk: str, seed: int, reference: str) -> Trajectory:
    """The reference estimator's trajectory on the task's run (memoised per process, so a
    sweep runs it once per run and process, not once per task)."""
    run = simulated_run(world_spec, steps, walk, seed)
    return timed_trajectory(reference, run.model, _options(reference, (), seed), run)


def run_task(task: Task) -> pd.DataFrame:
    """Simulate the task's run and return its metrics (:mod:`onlinemap.evaluate`): one row of
    :data:`~onlinemap.evaluate.RUN_METRICS`, or one row per step of
    :data:`~onlinemap.evaluate.STEP_METRICS` (``rows = "step"``); with a reference estimator,
    the total variation to its beliefs too; the task's description columns first
    (:func:`description`), one typed column per option last (:func:`option_columns`). Timing is
    measured after a warm-up run. Cost: that of :func:`task_rows`, plus one DataFrame (1-2 ms
    for one row)."""
    return task_rows(task).frame()


def task_rows(task: Task) -> TaskRows:
    """The rows of :func:`run_task` as plain columns (what the engines keep: a table of many tasks
    is built once, :func:`~.store.assemble_rows`). Cost: the estimator's run, plus (unless this
    process has just had them for another task) one simulation and the reference's run
    (:func:`simulated_run`, :func:`reference_trajectory`), plus O(T N K) to score it."""
    return played_rows(task)[1]


def played_rows(task: Task) -> tuple[Played, TaskRows]:
    """What the task played (its true run and the estimator's beliefs, :class:`~.kinds.Played`) and
    its :func:`task_rows`. Cost: that of :func:`task_rows`."""
    reference = None
    if task.kind != "estimate":
        played = _play(task)
    else:
        run = simulated_run(task.world, task.steps, task.walk, task.seed)
        trajectory = timed_trajectory(task.estimator, run.model, _options(task.estimator, task.options, task.seed),
                                      run)
        played = Played(run, trajectory, {}, {})
        if task.reference is not None:
            # the reference estimator itself, unconfigured: its own trajectory (distance 0)
            reference = trajectory if (task.estimator, task.options) == (task.reference, ()) else \
                reference_trajectory(task.world, task.steps, task.walk, task.seed, task.reference)
    run, trajectory = played.run, played.trajectory
    steps = step_columns(run, trajectory, reference)
    if task.per_step:
        names = ["t", "true_location", *(c for c in STEP_METRICS if c in steps)]
        metrics = {**{name: steps[name] for name in names},
                   **{name: np.asarray(values) for name, values in played.step_columns.items()},
                   "ms_per_step": np.full(run.n_steps, 1e3 * trajectory.seconds_per_step)}
    else:
        row = run_metrics(run, trajectory, reference, steps, trip=task.walk != "random")
        metrics = {**{name: row[name] for name in RUN_METRICS if name in row}, **played.run_columns}
    return played, TaskRows(run.n_steps if task.per_step else 1, {**description(task, run.n_steps), **metrics},
                            option_columns(task))


class Outcome(NamedTuple):
    """What running one task gave: its rows, or the error that ended it (``"Type: message"``);
    and what it played, if asked for."""

    rows: TaskRows | None
    error: str | None
    played: Played | None = None


def attempt(task: Task, keep: bool = False) -> Outcome:
    """:func:`task_rows`, with an exception returned as text instead of raised: a dask worker then
    never sees a failed task (so it logs no ``Compute Failed`` block and no traceback), and the
    engine reports every failure the same way, serial or not. ``keep``: what the task played too."""
    try:
        played, rows = played_rows(task)
        return Outcome(rows, None, played if keep else None)
    except Exception as error:  # any failure of a task is reported, never raised out of a worker
        return Outcome(None, f"{type(error).__name__}: {error}")


PLAYED_MAP_STREAM = 3  # the stream of a task's seed that draws a played task's true map


def played_map(world_spec: str, seed: int) -> np.ndarray:
    """The true map a played task (``explore``, ...) of ``world_spec`` and ``seed`` runs in: the
    world's fixed map, or one drawn from its prior with stream :data:`PLAYED_MAP_STREAM` of the
    seed (so a figure can show the map a run used). Cost O(N)."""
    return world(world_spec).initial_map(np.random.default_rng(derived_seed(seed, PLAYED_MAP_STREAM)))


_WARMED_PLAYS: set = set()


def _play(task: Task) -> Played:
    """A task of a played kind, in its world: the true map (:func:`played_map`), the robot's model
    given the floor plan, then the kind's ``play``. The first time in this process for a
    configuration (kind, planner, estimator, options, the model's shape and kernels), a shorter
    play of :data:`~onlinemap.evaluate.WARM_UP_STEPS` steps comes first, so that compiling the
    planner's and the estimator's numba kernels is not counted in ``ms_per_step``."""
    kind = task_kind(task.kind)
    spec = world(task.world)
    true_map = played_map(task.world, task.seed)
    model = spec.model if task.floor_plan is None else kind.prior(spec.model, true_map, task.floor_plan)
    warm = (task.kind, task.planner, task.planner_options, task.estimator,
            tuple(option for option in task.options if option[0] != "seed"), model.n_cells, model.n_labels,
            model.n_actions, model.is_static, model.has_blocking, model.n_readings)
    if warm not in _WARMED_PLAYS and isinstance(task.steps, int) and task.steps > 1:
        with counting_steps(False):  # no bar for the warm-up
            kind.play(model, true_map, dataclasses.replace(task, steps=min(task.steps, WARM_UP_STEPS)))
        _WARMED_PLAYS.add(warm)
    return kind.play(model, true_map, task)


def description(task: Task, n_steps: int) -> dict[str, object]:
    """The task's description columns, one value each: those of its kind, and its labels if the
    spec gave them (``steps``: the run's actual number of steps, ``n_steps``)."""
    described = {"task": task.key, "kind": task.kind, "world": task.world}
    if task.kind != "estimate":
        described["planner"] = task.planner
        if task.planner_label is not None:
            described["planner_label"] = task.planner_label
        described.update(planner_options=options_text(task.planner_options),
                         floor_plan=np.nan if task.floor_plan is None else task.floor_plan)
    if task.kind == "navigate":
        described["goal"] = task.goal
    described["estimator"] = task.estimator
    if task.label is not None:
        described["label"] = task.label
    described.update(options=options_text(task.options), steps=n_steps)
    if task.kind == "estimate":
        described.update(walk=task.walk, reference=task.reference or "")
    described["seed"] = task.seed
    return described


def option_columns(task: Task) -> dict[str, object]:
    """One ``opt_NAME`` (``planner_opt_NAME``) value per option of the task."""
    return {prefix + name: value for field, prefix in OPTION_PREFIXES.items() for name, value in getattr(task, field)}
