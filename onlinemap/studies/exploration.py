"""Exploration studies: planners compared on the same seeds (paired), run on the sweep engine
(``explore`` tasks, played by :mod:`policies`), with intervals over seeds.

- :func:`compare_planners`: any world spec and planners, one row per (planner, seed, step), and
  :func:`summarize_planners` (final map error, late door error, time at doors, cells visited).
- :func:`planners_study`: the same, one row per run, summarised per planner (every metric of
  :data:`METRICS`, :mod:`onlinemap.evaluate`).
- :func:`paper_world_study`: the built-in 10 x 10 door world at the paper's settings (uniform
  label prior, ``p_move`` 0.8, ``p_obs`` 0.9; static or with doors flipping at ``p_door``),
  RBPF with 1000 particles, 1000 steps.
- :func:`binary_task_study`: the binary 10 x 10 task of the C++ belief-tracking peer (2 labels,
  ``p_move`` 0.9, ``p_obs`` 0.8, 300 steps, 100 particles), a fresh random map per seed.
- :func:`replay_study`: how much of a planner's map error is the particle filter's: its runs
  replayed (same actions and observations) through filters with more particles (``replay``
  tasks, :data:`REPLAY`, a task kind of this module).

Cost: ``len(planners) * len(seeds)`` exploration runs (plus the replays).
"""

from __future__ import annotations

import dataclasses
import functools
import os
from typing import Sequence

import numpy as np
import pandas as pd

import policies
from policies.explore import Exploration, exploration
from policies.tasks import EXPLORE, build_planner

from .. import metrics as metric_functions
from ..estimators import make_estimator, run_estimator
from ..evaluate import COVERAGE_THRESHOLDS, HONEST_METRICS, from_steps
from ..errors import InvalidOptionError, ModelError
from ..model import GridModel, door_cells
from ..rng import ESTIMATOR_STREAM, derived_seed
from ..sweeps import sweep
from ..sweeps.kinds import Played, TaskKind
from ..sweeps.tasks import Task
from ..worlds import parse_world
from .base import Study, ordered, summary_of

METRICS = ("final_map_error", "wrong_cells", "unsure_or_wrong", "confidently_wrong", "mean_location_error",
           "late_door_error", "mean_location_distance", "late_location_distance", "told_map_location_error",
           "told_map_location_distance", "excess_location_distance", "location_calibration_gap",
           "map_calibration_gap", "excess_map_error", "told_location_map_error", "told_location_wrong",
           "told_location_unsure_or_wrong", "told_location_confidently_wrong", "final_observable_map_error", "final_known_cells", "map_error_area",
           "steps_to_map_error_20", "steps_to_map_error_10", "steps_to_map_error_05", "reached_map_error_20",
           "reached_map_error_10", "reached_map_error_05", "ms_per_step")
PAPER_WORLD = "door,p_move=0.8"  # the built-in 10 x 10 door world, uniform label prior
BINARY_WORLD = "grid:10x10,n_labels=2,p_obs=0.8,p_move=0.9"  # the peer's binary task
BLOCKING_WORLD = "door,blocking=1,footprint=cross"  # the door world a robot would recognise, uniform prior


def exploration_spec(world: str | Sequence[str], planners: Sequence[str], steps: int, seeds: Sequence[int], *,
                     estimator: str = "rbpf", estimator_options: dict | None = None,
                     planner_options: dict | None = None, floor_plan: float | None = None,
                     rows: str = "task", name: str = "explore") -> dict:
    """The sweep spec of planners exploring ``world`` (a world spec, or several) on the same
    ``seeds``: ``planner_options`` per planner name, ``estimator_options`` for the one estimator
    (a tuple is one value; a list is a grid). InvalidOptionError if ``planner_options`` names a
    planner not in ``planners`` (e.g. options given flat instead of per planner)."""
    stray = sorted(set(planner_options or {}) - set(planners))
    if stray:
        raise InvalidOptionError(f"planner_options is per planner name ({{planner: {{option: value}}}}); "
                                 f"{stray} is not among the planners {list(planners)}")
    spec = {"name": name, "worlds": [world] if isinstance(world, str) else list(world), "seeds": [int(seed) for seed in seeds], "steps": int(steps),
            "rows": rows, "planners": {planner: dict((planner_options or {}).get(planner, {}))
                                       for planner in planners},
            "estimators": {estimator: dict(estimator_options or {})}}
    if floor_plan is not None:
        spec["floor_plan"] = float(floor_plan)
    return spec


def compare_planners(world: str = "door,p_door=0.01,p_move=0.9", planners=("entropy", "random", "sweep"),
                     estimator: str = "rbpf", steps: int = 500, seeds=(0,), *, floor_plan: float | None = None,
                     estimator_options: dict | None = None, planner_options: dict | None = None,
                     workers: int | None = 0, out: str | os.PathLike | None = None,
                     progress: bool = True) -> pd.DataFrame:
    """:func:`policies.explore` for every planner name and seed (the same seeds for every planner,
    so the runs are paired), run as a sweep on :func:`onlinemap.sweeps.sweep` (``workers``: 0 in
    this process, None or N on a local dask cluster; ``out``: a folder of parts, to resume).
    ``world``: a world spec (:func:`onlinemap.worlds.parse_world`); ``floor_plan``: the confidence
    of :func:`policies.with_floor_plan` (None: the world's own prior).
    One row per (planner, seed, step): ``planner``, ``seed``, ``t``, ``true_location`` and the
    per-step metrics of :func:`onlinemap.evaluate.step_metrics`, and ``seconds_per_step``.
    Cost: ``len(planners) * len(seeds)`` runs of ``steps`` steps."""
    spec = exploration_spec(world, planners, steps, seeds, estimator=estimator, estimator_options=estimator_options,
                            planner_options=planner_options, floor_plan=floor_plan, rows="step",
                            name="compare-planners")
    table = sweep(spec, workers=workers, results_dir=out, progress=progress)
    table["seconds_per_step"] = table["ms_per_step"] / 1e3
    position = {name: i for i, name in enumerate(planners)}
    return table.sort_values(["planner", "seed", "t"], key=lambda c: c.map(position) if c.name == "planner" else c,
                             kind="stable").reset_index(drop=True)


def _with_ms_per_step(table: pd.DataFrame) -> pd.DataFrame:
    """``table`` with ``ms_per_step``: the engine's own column where it has one (a
    :func:`compare_planners` table), else from ``seconds_per_step`` (a table built by hand)."""
    return table if "ms_per_step" in table else table.assign(ms_per_step=1e3 * table["seconds_per_step"])


def summarize_planners(table: pd.DataFrame, model: GridModel, true_map) -> pd.DataFrame:
    """One row per planner from a :func:`compare_planners` table, averaged over seeds: the
    per-run metrics of :func:`onlinemap.evaluate.from_steps` (final map error, mean door error
    over the last two thirds of the run, mean location error, the honest metrics of
    :data:`onlinemap.evaluate.HONEST_METRICS`), the share of steps spent on door cells, distinct
    cells visited, and milliseconds per step (estimator + planner)."""
    doors = door_cells(model, true_map)
    table = _with_ms_per_step(table)
    per_run = from_steps(table, ["planner", "seed"])
    visits = table.groupby(["planner", "seed"], sort=False)["true_location"]
    per_run["time_at_doors"] = visits.apply(lambda cells: np.isin(cells, doors).mean()).to_numpy()
    per_run["cells_visited"] = visits.nunique().to_numpy()
    columns = ["planner", "final_map_error", "late_door_error", "mean_location_error", *HONEST_METRICS,
               "time_at_doors", "cells_visited", "ms_per_step"]
    summary = per_run[[c for c in columns if c in per_run]].groupby("planner", sort=False).mean().reset_index()
    summary.insert(1, "runs", per_run.groupby("planner", sort=False).size().to_numpy())
    return summary


def planners_study(world: str | Sequence[str], planners: Sequence[str], *, seeds: Sequence[int] = range(20),
                   steps: int = 1000, estimator_options: dict | None = None, planner_options: dict | None = None,
                   floor_plan: float | None = None, confidence: float = 0.95, workers: int | None = 0,
                   out: str | os.PathLike | None = None, progress: bool = True,
                   keep: Sequence[tuple[str, str, int]] = ()) -> Study:
    """Every planner on every seed of ``world`` (a world spec, or several of one size: every
    planner runs in each, paired), one row per run; the summary per planner (and planner
    options) holds the mean and interval of every metric of :data:`METRICS`. ``keep``: runs
    named ``(world, planner, seed)`` whose true run and beliefs the study returns too
    (``Study.played``, to plot one without running it again; ``workers=0``, no ``out``)."""
    spec = exploration_spec(world, planners, steps, seeds, estimator_options=estimator_options,
                            planner_options=planner_options, floor_plan=floor_plan)
    wanted = _kept_runs(spec, keep, workers, out)
    played: dict[tuple, Played] = {}

    def on_played(task: Task, what: Played) -> None:
        if (task.world, task.planner, task.seed) in wanted:
            played[task.world, task.planner, task.seed] = what

    runs = sweep(spec, workers=workers, results_dir=out, progress=progress, on_played=on_played if wanted else None)
    return Study(*_planners_summary(runs, list(planners), confidence), played)


def _kept_runs(spec: dict, keep: Sequence[tuple[str, str, int]], workers: int | None, out) -> set[tuple]:
    """The ``(world, planner, seed)`` runs of ``spec`` to keep; ModelError for a run the study
    does not have, or with ``workers`` other than 0 or an ``out`` folder (a resumed task is not
    run again)."""
    wanted = {(str(world), str(planner), int(seed)) for world, planner, seed in keep}
    have = {(world, planner, seed) for world in spec["worlds"] for planner in spec["planners"] for seed in spec["seeds"]}
    if wanted - have:
        raise ModelError(f"keep names runs the study does not have: {sorted(wanted - have)}; it has "
                         f"(world, planner, seed) for worlds {spec['worlds']}, planners {list(spec['planners'])}, "
                         f"seeds {spec['seeds']}")
    if wanted and (workers != 0 or out is not None):
        raise ModelError("keep needs workers=0 and no out folder: the kept runs live in this process")
    return wanted


def steps_study(table: pd.DataFrame, planners: Sequence[str] | None = None, confidence: float = 0.95) -> Study:
    """:func:`planners_study` read off a per-step table of :func:`compare_planners` instead of
    running the tasks again: one row per run (planner, planner options, world, seed) with the
    metrics a per-step table holds (:func:`onlinemap.evaluate.from_steps`: final map error and
    wrong cells, mean location error, late door error, the coverage metrics, ms per step), the
    same values :func:`planners_study` gives for those runs; ``planners``: their order (default:
    the table's). Cost O(rows)."""
    by = ["planner", "planner_options", "world", "seed"]
    runs = from_steps(_with_ms_per_step(table), by)
    order = list(dict.fromkeys(table["planner"])) if planners is None else list(planners)
    return _planners_summary(runs, order, confidence)


def _planners_summary(runs: pd.DataFrame, planners: list[str], confidence: float) -> Study:
    """The study of one row per run: ``reached_*`` (did the run get there at all; the mean
    ``steps_to_*`` counts only those), runs in the order of ``planners``, and the summary per
    planner (and planner options) of :data:`METRICS`, cell counts bounded by the world's cells."""
    n_cells = parse_world(runs["world"].iloc[0]).model.n_cells
    counts = {m: (0, n_cells) for m in METRICS if "wrong" in m or "known" in m}
    for name in COVERAGE_THRESHOLDS:
        runs[name.replace("steps_to", "reached")] = runs[name].notna()
    runs = ordered(runs, "planner", planners)
    return Study(runs, summary_of(runs, METRICS, ["planner", "planner_options"], confidence, counts))


def paper_world_study(planners: Sequence[str] = ("info_gain", "entropy", "random", "sweep"), *,
                      seeds: Sequence[int] = range(20), steps: int = 1000, n_particles: int = 1000,
                      p_door: float = 0.0, planner_options: dict | None = None, workers: int | None = 0,
                      progress: bool = True) -> Study:
    """The planners' main study: the 10 x 10 door world, uniform prior, ``p_move`` 0.8, ``p_obs`` 0.9."""
    world = PAPER_WORLD + (f",p_door={p_door}" if p_door else "")
    return planners_study(world, planners, seeds=seeds, steps=steps, estimator_options={"n_particles": n_particles},
                          planner_options=planner_options, workers=workers, progress=progress)


def blocking_world_study(planners: Sequence[str] = ("info_gain", "frontier", "random", "sweep", "entropy"), *,
                         seeds: Sequence[int] = range(20), steps: int = 300, n_particles: int = 1000,
                         p_door: float = 0.0, planner_options: dict | None = None, workers: int | None = 0,
                         progress: bool = True) -> Study:
    """The 10 x 10 door world as a robot would meet it: walls and closed doors block, a cross
    footprint, a uniform label prior, ``p_move`` 0.8, ``p_obs`` 0.9 (doors flipping at ``p_door``)."""
    world = BLOCKING_WORLD + (f",p_door={p_door}" if p_door else "")
    return planners_study(world, planners, seeds=seeds, steps=steps, estimator_options={"n_particles": n_particles},
                          planner_options=planner_options, workers=workers, progress=progress)


def building_study(planners: Sequence[str] = ("info_gain", "frontier", "random", "sweep"), *, rows: int = 32,
                   cols: int = 32, seeds: Sequence[int] = range(20), steps: int = 2000, n_particles: int = 1000,
                   estimator_options: dict | None = None, planner_options: dict | None = None,
                   workers: int | None = 0, progress: bool = True,
                   keep: Sequence[tuple[str, str, int]] = ()) -> Study:
    """Generated buildings (:func:`onlinemap.buildings.building`, blocking walls and closed doors,
    a cross footprint, label frequencies unknown: the RBPF learns them, :mod:`onlinemap.label_prior`):
    one building per seed (``building:RxC,seed=S``), every planner in each, with run seed 0
    (``keep``: ``("building:RxC,seed=S", planner, 0)``, see :func:`planners_study`).
    ``estimator_options``: more RBPF options, e.g. ``{"label_prior": "model"}`` for the fixed
    uniform prior (the baseline without learning)."""
    worlds = [f"building:{rows}x{cols},seed={int(seed)}" for seed in seeds]
    return planners_study(worlds, planners, seeds=[0], steps=steps,
                          estimator_options={"n_particles": n_particles, **(estimator_options or {})},
                          planner_options=planner_options, workers=workers, progress=progress, keep=keep)


def binary_task_study(planners: Sequence[str] = ("info_gain", "random"), *, seeds: Sequence[int] = range(50),
                      steps: int = 300, n_particles: int = 100, planner_options: dict | None = None,
                      workers: int | None = 0, progress: bool = True) -> Study:
    """The peer's binary 10 x 10 task: 2 labels, ``p_move`` 0.9, ``p_obs`` 0.8, a map drawn from the
    uniform prior per seed."""
    return planners_study(BINARY_WORLD, planners, seeds=seeds, steps=steps,
                          estimator_options={"n_particles": n_particles}, planner_options=planner_options,
                          workers=workers, progress=progress)


# --- replays: the data of a live run through other filters -----------------------------------
LIVE_PARTICLES = 1000  # the live filter's particles unless a replay task's planner says otherwise
REPLAY_SEED = 10_000  # replay r of a run uses filter seed REPLAY_SEED + r (replay_study, bench rbpf)


def replay_options(name: str) -> dict:
    """A replayed planner's options: its own, and ``live_particles`` (the live filter's size)."""
    return {**policies.planner_options(name), "live_particles": LIVE_PARTICLES}


def _planner_part(options: dict) -> dict:
    return {key: value for key, value in options.items() if key != "live_particles"}


def build_replayed(model: GridModel, name: str, options: dict):
    """The spec's check of a replay configuration: the planner without ``live_particles``."""
    return build_planner(model, name, _planner_part(options))


def live_exploration(model: GridModel, true_map: np.ndarray, planner: str, steps: int, seed: int, *,
                     planner_options: dict | None = None, live_particles: int = LIVE_PARTICLES) -> Exploration:
    """The run a replay replays: ``planner`` (built with ``planner_options``, default its own
    defaults) closed on an RBPF of ``live_particles`` in ``model`` whose true map is ``true_map``
    (N,), ``steps`` steps, the world, the planner and the live filter seeded from ``seed`` (as
    :func:`policies.exploration`); unscored (its ``frame`` is None). Cost: ``steps`` x (an RBPF
    step of ``live_particles`` + a planner decision)."""
    return exploration(model, true_map, planner, "rbpf", steps, seed,
                       estimator_options={"n_particles": int(live_particles)}, planner_options=planner_options,
                       progress=False, score=False)


@functools.lru_cache(maxsize=4)
def _live(model: GridModel, true_map: bytes, task: Task) -> Exploration:
    """The live exploration of a replay task (memoised per process: the replays of one seed
    share it): :func:`live_exploration` of the task's planner and ``live_particles``."""
    options = dict(task.planner_options)
    return live_exploration(model, np.frombuffer(true_map, dtype=np.int64), task.planner, task.steps, task.seed,
                            planner_options=_planner_part(options),
                            live_particles=int(options.get("live_particles", LIVE_PARTICLES)))


def play_replay(model: GridModel, true_map: np.ndarray, task: Task) -> Played:
    """A replay task: the live exploration (:func:`_live`), then the task's estimator fed the same
    actions and observations (seeded from the task's seed unless its options set one). The live
    filter's final map error is the extra column ``live_map_error``."""
    found = _live(model, np.asarray(true_map, dtype=np.int64).tobytes(),
                  dataclasses.replace(task, estimator="rbpf", options=()))
    options = dict(task.options)
    options.setdefault("seed", derived_seed(task.seed, ESTIMATOR_STREAM))
    trajectory = run_estimator(make_estimator(task.estimator, model, **options), found.run.actions,
                               found.run.observations)
    live_error = float(metric_functions.map_error(found.trajectory.map[-1], found.run.final_map))
    return Played(found.run, trajectory, {}, {"live_map_error": live_error})


REPLAY = TaskKind("replay", "planners", replay_options, policies.planner_class, build_replayed, EXPLORE.prior,
                  play_replay, ("floor_plan",))


def replay_study(planner: str = "info_gain", *, seeds: Sequence[int] = range(5), steps: int = 1000,
                 n_particles: int = 1000, replay_particles: Sequence[int] = (1000, 5000, 20000), replays: int = 2,
                 p_door: float = 0.0, workers: int | None = 0, progress: bool = True) -> pd.DataFrame:
    """The paper's world explored by ``planner`` with an RBPF of ``n_particles`` (one run per seed),
    then each run's actions and observations fed to fresh RBPFs of every size in
    ``replay_particles`` (``replays`` estimator seeds each) and to the told-location yardstick
    (:func:`onlinemap.evaluate.told_location_map`). One row per (seed, filter): ``seed``,
    ``filter`` ("live", "rbpf P", "told location"), ``final_map_error`` (mean over replays). The
    data are the same in a row group, so the differences are the filters': what a better filter
    would make of the planner's data. Cost: ``len(seeds)`` runs plus
    ``len(seeds) * replays * sum(replay_particles) * steps`` particle steps."""
    world = PAPER_WORLD + (f",p_door={p_door}" if p_door else "")
    spec = {"name": "replay", "kind": "replay", "worlds": [world], "seeds": [int(s) for s in seeds],
            "steps": int(steps), "planners": {planner: {"live_particles": int(n_particles)}},
            "estimators": {"rbpf": {"n_particles": [int(p) for p in replay_particles],
                                    "seed": [REPLAY_SEED + r for r in range(int(replays))], "max_bytes": 2**36}}}
    runs = sweep(spec, workers=workers, progress=progress)
    rows = []
    for seed, group in runs.groupby("seed", sort=True):
        rows.append({"seed": seed, "filter": "live", "final_map_error": float(group["live_map_error"].iloc[0])})
        for size, replayed in group.groupby("opt_n_particles", sort=False):
            rows.append({"seed": seed, "filter": f"rbpf {int(size)}",
                         "final_map_error": float(replayed["final_map_error"].mean())})
        rows.append({"seed": seed, "filter": "told location",
                     "final_map_error": float(group["told_location_map_error"].iloc[0])})
    return pd.DataFrame(rows)
