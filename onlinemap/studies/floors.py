"""Real floors in the studies (issue 40, item 4): planners exploring floors read from files
(MovingAI benchmark maps and cropped ROS maps, shipped in ``tests/data/floors`` with their
sources and licences) and generated buildings of 32 x 32 and 64 x 64, on the sweep engine, one
row per run with the honest metrics and the told-location anchor.

- :data:`REAL_FLOORS`: the shipped floors by name, each a world spec relative to the floors
  folder (:func:`real_floor_specs` makes them absolute);
- :func:`floor_worlds`: the world specs of a study (real floors by name or any world spec, plus
  generated buildings), with extra world keys (``label_prior=floor``, ``p_move=0.95``);
  floors and buildings leave their label frequencies unknown, so the RBPF learns them unless a
  world key states the prior (``label_prior=uniform``: the fixed uniform baseline) or the
  estimator options ask for the model's table (``{"label_prior": "model"}``);
- :func:`floor_study`: every planner on every world and seed, RBPF with any estimator options
  (``n_particles``, and whatever else the estimator takes: a list is a grid), one row per run
  (:data:`COLUMNS`), the summary per (floor, planner, estimator options) with intervals over seeds;
- :func:`run_extras`: the per-run columns this study adds to :func:`onlinemap.evaluate.from_steps`
  (late location error, cells visited, stalled, died).

Every run is an ``explore`` task of the sweep engine with per-step rows (``rows = "step"``), so
``out`` makes a study resumable and :func:`floor_study` reads the same parts again.
Cost: ``len(worlds) * len(planners) * len(configurations) * len(seeds)`` runs of ``steps`` steps,
each an RBPF step plus a planner decision per step (about 0.1-0.3 s a step at 32 x 32 and 1000
particles with ``info_gain`` on a loaded 2-core machine), then O(T N K) to score.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
import pandas as pd

from ..errors import ModelError
from ..evaluate import SECOND_HALF, from_steps, late_mean
from ..sweeps import sweep
from ..worlds import parse_world
from .base import Study, ordered, summary_of
from .exploration import exploration_spec

#: the shipped floors: name -> world spec relative to the floors folder (tests/data/floors/SOURCES.md)
REAL_FLOORS = {
    "maze": "maze-32-32-2.map",
    "room": "room-32-32-4.map",
    "random": "random-32-32-20.map,doorways=0",
    "arena": "arena.map,cell_size=2",
    "tb3_world": "tb3_world/map.yaml,cell_size=0.2",
    "nav2_depot": "nav2_depot/depot.yaml,cell_size=0.25,doorways=0",
}
#: where the floors are in a clone of the project (an installed wheel does not ship tests/)
FLOORS_DIR = Path(__file__).resolve().parents[2] / "tests" / "data" / "floors"
PLANNERS = ("info_gain", "frontier", "random")
BUILDINGS = ("32x32", "64x64")
STALL_STEPS = 50  # a run stalls when the robot's true cell has not changed over its last max(50, T/10) steps
#: the per-run columns of a floor study's table, in order (after floor, world, planner, options, seed)
COLUMNS = ("final_map_error", "late_location_error", "late_location_distance", "told_map_location_error",
           "told_map_location_distance", "excess_location_distance", "location_calibration_gap",
           "map_calibration_gap", "told_location_map_error", "excess_map_error", "mean_location_error",
           "mean_location_distance", "cells_visited", "stalled", "died", "steps_to_map_error_20",
           "steps_to_map_error_10", "steps_to_map_error_05", "ms_per_step")
#: the columns the summary averages (``stalled`` and ``died`` as counts: their sums)
SUMMARY = tuple(c for c in COLUMNS if c not in ("stalled", "died") and not c.startswith("steps_to"))


def real_floor_specs(directory: str | os.PathLike | None = None, names: Sequence[str] | None = None) \
        -> dict[str, str]:
    """{name: world spec} of the shipped floors ``names`` (default all of :data:`REAL_FLOORS`)
    in ``directory`` (default :data:`FLOORS_DIR`), with absolute paths (a dask worker or another
    working directory reads the same file). ModelError for an unknown name."""
    names = list(REAL_FLOORS) if names is None else list(names)
    unknown = [name for name in names if name not in REAL_FLOORS]
    if unknown:
        raise ModelError(f"unknown real floors {unknown}; known: {', '.join(REAL_FLOORS)}")
    root = Path(FLOORS_DIR if directory is None else directory).resolve()
    specs = {}
    for name in names:
        path, _, keys = REAL_FLOORS[name].partition(",")
        where = str(root / path)
        where = f'"{where}"' if "," in where else where
        specs[name] = f"layout:{where}" + (f",{keys}" if keys else "")
    return specs


def floor_worlds(floors: Sequence[str] = tuple(REAL_FLOORS), *, buildings: Sequence[str] = BUILDINGS,
                 building_seeds: Sequence[int] = (0,), world_keys: str = "",
                 directory: str | os.PathLike | None = None) -> dict[str, str]:
    """{floor name: world spec} of a study: each of ``floors`` (a name of :data:`REAL_FLOORS`, or
    any world spec, named by itself), then a generated building per size in ``buildings``
    (``"32x32"``) and seed in ``building_seeds`` (named ``building:32x32,seed=S``); ``world_keys``
    (``"label_prior=floor"``, ``"label_prior=uniform"``, ``"p_move=0.95"``) appended to every spec. Each spec is parsed once
    here, so a bad one fails before any run (ModelError naming it). Cost: reading each floor."""
    known = real_floor_specs(directory, [f for f in floors if f in REAL_FLOORS])
    worlds = {floor: known.get(floor, floor) for floor in floors}
    for size in buildings:
        for seed in building_seeds:
            worlds[f"building:{size},seed={int(seed)}"] = f"building:{size},seed={int(seed)}"
    keys = world_keys.strip().strip(",")
    if keys:
        worlds = {name: f"{spec},{keys}" for name, spec in worlds.items()}
    if len(set(worlds.values())) < len(worlds):
        raise ModelError(f"floor_worlds: a world is named twice: {list(worlds.values())}")
    for name, spec in worlds.items():
        try:
            parse_world(spec)
        except ModelError as error:
            if name in REAL_FLOORS or name.startswith("building:"):
                raise
            raise type(error)(f"{name!r} is neither a real floor ({', '.join(REAL_FLOORS)}) nor a world spec: "
                              f"{error}") from None
    return worlds


def run_extras(run: pd.DataFrame) -> dict[str, float | int | bool]:
    """The columns of one run's per-step rows (``t`` ascending; ``location_error``,
    ``true_location``, ``map_error``, ``log_evidence``) that :func:`onlinemap.evaluate.from_steps`
    lacks: ``late_location_error`` (mean 1 - P(true cell) over the second half,
    :data:`~onlinemap.evaluate.SECOND_HALF`), ``cells_visited`` (distinct true cells),
    ``stalled`` (the true cell did not change over the last ``max(STALL_STEPS, T // 10)`` steps:
    the planner stopped moving the robot, or keeps pressing into a wall) and ``died`` (some step's
    belief is not a number: a NaN map or location error, or a log evidence that is NaN or
    -inf, i.e. the filter gave the readings probability 0). O(T)."""
    t = run["t"].to_numpy()
    cells = run["true_location"].to_numpy()
    tail = max(STALL_STEPS, len(cells) // 10)
    evidence = run["log_evidence"].to_numpy(dtype=np.float64)
    died = (np.isnan(run["location_error"].to_numpy(dtype=np.float64)).any()
            or np.isnan(run["map_error"].to_numpy(dtype=np.float64)).any()
            or not np.all(np.isfinite(evidence) | (evidence == np.inf)))
    return {"late_location_error": late_mean(t, run["location_error"], SECOND_HALF),
            "cells_visited": int(len(np.unique(cells))),
            "stalled": bool(len(cells) > tail and np.all(cells[-tail:] == cells[-tail])),
            "died": bool(died)}


def floor_runs(steps: pd.DataFrame, names: Mapping[str, str]) -> pd.DataFrame:
    """One row per run of a per-step explore table (the sweep's ``rows = "step"``): ``floor``
    (the name of its world in ``names``, {name: world spec}), ``world``, ``planner``,
    ``planner_options``, ``options`` (the estimator's), the ``opt_*`` columns, ``seed``, then
    :data:`COLUMNS`. O(rows)."""
    options = [c for c in steps.columns if c.startswith("opt_")]
    by = ["world", "planner", "planner_options", "options", *options, "seed"]
    table = steps.sort_values([*by, "t"], kind="stable")
    runs = from_steps(table, by)
    extras = pd.DataFrame([run_extras(run) for _, run in table.groupby(by, sort=False)])
    runs = pd.concat([runs.reset_index(drop=True), extras], axis=1)
    floor_of = {spec: name for name, spec in names.items()}
    runs.insert(0, "floor", runs["world"].map(floor_of))
    return runs[["floor", *by, *(c for c in COLUMNS if c in runs)]]


def floor_study(floors: Sequence[str] = tuple(REAL_FLOORS), *, buildings: Sequence[str] = BUILDINGS,
                building_seeds: Sequence[int] = (0,), planners: Sequence[str] = PLANNERS,
                seeds: Sequence[int] = range(3), steps: int = 1000, n_particles: int | Sequence[int] = 1000,
                estimator_options: dict | None = None, planner_options: dict | None = None,
                world_keys: str = "", directory: str | os.PathLike | None = None, confidence: float = 0.95,
                workers: int | None = 0, out: str | os.PathLike | None = None, progress: bool = True) -> Study:
    """Every planner on every world of :func:`floor_worlds` (``floors``, ``buildings`` x
    ``building_seeds``, ``world_keys``) and run seed (paired: the same seeds for every planner),
    closed on an RBPF with ``n_particles`` (a list: a grid) and ``estimator_options`` (any option
    the estimator takes, passed through; a list is a grid, a tuple one value), on the sweep
    engine (``workers``; ``out``: a folder of parts, to resume). ``runs``: one row per run
    (:func:`floor_runs`); ``summary``: per (floor, planner, estimator options) the mean and
    interval at ``confidence`` of :data:`SUMMARY`, and the counts ``stalled`` and ``died``.
    Cost: see the module docstring."""
    worlds = floor_worlds(floors, buildings=buildings, building_seeds=building_seeds, world_keys=world_keys,
                          directory=directory)
    particles = [int(p) for p in n_particles] if isinstance(n_particles, (list, tuple, range)) else int(n_particles)
    options = {"n_particles": particles, **(estimator_options or {})}
    spec = exploration_spec(list(worlds.values()), planners, steps, seeds, estimator_options=options,
                            planner_options=planner_options, rows="step", name="floors")
    table = sweep(spec, workers=workers, results_dir=out, progress=progress)
    runs = floor_runs(table, worlds)
    runs = ordered(runs.assign(_floor=runs["floor"].map({name: i for i, name in enumerate(worlds)})),
                   "planner", list(planners)).sort_values(["_floor", "seed"], kind="stable")
    runs = runs.drop(columns="_floor").reset_index(drop=True)
    return Study(runs, floor_summary(runs, confidence))


def floor_summary(runs: pd.DataFrame, confidence: float = 0.95) -> pd.DataFrame:
    """Per (floor, planner, planner options, estimator options) of a :func:`floor_study` table:
    ``runs``, the mean and interval of :data:`SUMMARY`, and the runs that ``stalled`` and
    ``died`` (counts). O(rows)."""
    by = ["floor", "planner", "planner_options", "options"]
    summary = summary_of(runs, SUMMARY, by, confidence, {"cells_visited": (0, np.inf)})
    counts = runs.groupby(by, sort=False)[["stalled", "died"]].sum().astype(int).reset_index()
    return summary.merge(counts, on=by, how="left")
