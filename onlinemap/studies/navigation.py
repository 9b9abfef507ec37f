"""Navigation studies (DESIGN.md section 8): goal planners taking the robot through a
building whose doors open and close, against the omniscient oracle of the same world history
and the floor-plan baseline ``static_goto``, on the sweep engine (``navigate`` tasks, played by
:mod:`policies`).

- :func:`navigation_study`: planners x worlds x seeds, each world with its far goal(s)
  (:func:`far_goals`); one row per run, a summary per planner over the runs where the oracle
  reaches the goal (success: within 4x the oracle's steps,
  :func:`onlinemap.evaluate.navigation_metrics`).
- :func:`door_world_study`: the 10 x 10 door world with blocking, a cross footprint and the floor
  plan known with confidence 0.95, doors flipping at ``p_door``.
- :func:`building_navigation_study`: the same in generated buildings, one per seed.
- figures: :func:`route_figure` (one run's path drawn on the map, the goal and where it waited)
  and :func:`oracle_figure` (each run's steps against the oracle's).

Cost: planners x runs navigation runs of at most ``max_steps`` steps (estimator step + plan each),
plus one oracle run per (world, goal, seed).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from policies.navigate import true_distances

from .. import plots
from ..errors import InvalidOptionError
from ..model import GridModel
from ..simulate import Run
from ..sweeps import sweep
from ..worlds import WorldSpec, parse_world
from .base import Study, ordered, summary_of

DOOR_WORLD = "door,blocking=1,footprint=cross"  # the 10 x 10 door world with blocking and a cross footprint
FLOOR_PLAN = 0.95  # the confidence of the floor plan the robot is given
METRICS = ("success", "reached", "steps_to_goal", "oracle_steps", "steps_over_oracle", "mean_location_error",
           "mean_location_distance", "location_calibration_gap", "map_calibration_gap", "ms_per_step")


def far_goals(model: GridModel, true_map: np.ndarray, count: int = 1) -> list[int]:
    """The ``count`` free cells farthest from the start by the fewest moves with every door open
    (ties: the lowest cell), the goals a navigation study sends the robot to; in a world without a
    ``free`` label (``corridor``, ``grid``), the cells whose label does not block. Fewer than
    ``count`` (none) when fewer are reachable. O(N A)."""
    labels = np.asarray(true_map).copy()
    names = np.asarray(model.label_names)
    doors = np.isin(names[labels], ("open_door", "closed_door"))
    labels[doors] = model.label_names.index("open_door") if "open_door" in model.label_names else labels[doors]
    distance = true_distances(model, labels, model.start)  # symmetric moves: from the start = to it
    free = names[np.asarray(true_map)] == "free" if "free" in model.label_names else ~model.blocking[labels]
    free = np.flatnonzero(free & np.isfinite(distance))
    order = free[np.lexsort((free, -distance[free]))]
    return [int(cell) for cell in order[:count]]


def fixed_map(world: WorldSpec) -> np.ndarray:
    """(N,) the world's own map, on which a navigation study chooses the goals every seed shares
    (:func:`far_goals`): door worlds, buildings and layouts have one; a world that draws its map
    from its prior, one per seed, has none (InvalidOptionError: give the goals)."""
    if world.true_map is None:
        raise InvalidOptionError(f"{world.spec} draws its map from its prior, one per seed: give the goals")
    return world.true_map


def navigation_spec(world: str, planners: Sequence[str], goals: Sequence[int], seeds: Sequence[int], *,
                    max_steps: int = 400, estimator_options: dict | None = None, floor_plan: float | None = FLOOR_PLAN,
                    planner_options: dict | None = None, name: str = "navigate") -> dict:
    """The sweep spec of planners taking the robot to each goal of ``world`` on the same seeds."""
    spec = {"name": name, "worlds": [world], "goals": [int(goal) for goal in goals],
            "seeds": [int(seed) for seed in seeds], "steps": int(max_steps) + 1,
            "planners": {planner: dict((planner_options or {}).get(planner, {})) for planner in planners},
            "estimators": {"rbpf": dict(estimator_options or {"n_particles": 500})}}
    if floor_plan is not None:
        spec["floor_plan"] = float(floor_plan)
    return spec


def navigation_study(worlds: str | Sequence[str], planners: Sequence[str] = ("goto", "static_goto"), *,
                     goals: Sequence[int] | None = None, seeds: Sequence[int] = range(20), max_steps: int = 400,
                     n_particles: int = 500, floor_plan: float | None = FLOOR_PLAN,
                     planner_options: dict | None = None, confidence: float = 0.95, workers: int | None = 0,
                     progress: bool = True) -> Study:
    """Every planner to every goal of every world (``goals``, or each world's :func:`far_goals`),
    on the same seeds (paired: the same doors and slips step by step, and the same oracle). The
    summary, per planner, is over the runs where the oracle reaches the goal: success, reached,
    mean steps, the oracle's, their ratio per run (``steps_over_oracle``), location error, ms per
    step; and ``mean_steps_over_mean_oracle``, the ratio of the mean steps to the oracle's mean
    over the runs where both reach it."""
    frames = []
    for world in [worlds] if isinstance(worlds, str) else worlds:
        spec = parse_world(world)
        chosen = goals if goals is not None else far_goals(spec.model, fixed_map(spec))
        frames.append(sweep(navigation_spec(world, planners, chosen, seeds, max_steps=max_steps,
                                            estimator_options={"n_particles": n_particles}, floor_plan=floor_plan,
                                            planner_options=planner_options),
                            workers=workers, progress=progress))
    runs = ordered(pd.concat(frames, ignore_index=True), "planner", list(planners))
    judged = runs[runs["oracle_reached"].astype(bool)]
    summary = summary_of(judged, METRICS, ["planner"], confidence, {"steps_over_oracle": (0.0, np.inf)})
    both = judged[judged["reached"].astype(bool)].groupby("planner", sort=False)
    ratio = both["steps_to_goal"].mean() / both["oracle_steps"].mean()
    summary["mean_steps_over_mean_oracle"] = summary["planner"].map(ratio)
    return Study(runs, summary)


def door_world_study(p_door: float = 0.05, planners: Sequence[str] = ("goto", "static_goto"), *,
                     seeds: Sequence[int] = range(20), max_steps: int = 400, n_particles: int = 500,
                     workers: int | None = 0, progress: bool = True) -> Study:
    """The navigation study's main setting: the door world with blocking and a cross footprint, the floor plan
    known with confidence 0.95, doors flipping at ``p_door``, the far goal."""
    return navigation_study(f"{DOOR_WORLD},p_door={p_door}", planners, seeds=seeds, max_steps=max_steps,
                            n_particles=n_particles, workers=workers, progress=progress)


def building_navigation_study(p_door: float = 0.05, planners: Sequence[str] = ("goto", "static_goto"), *,
                              rows: int = 32, cols: int = 32, seeds: Sequence[int] = range(20),
                              max_steps: int = 600, n_particles: int = 500, workers: int | None = 0,
                              progress: bool = True) -> Study:
    """Generated buildings (one per seed, ``building:RxC,seed=S,p_door=...``; blocking, a cross
    footprint), the floor plan known with confidence 0.95, each building's far goal."""
    worlds = [f"building:{rows}x{cols},seed={int(seed)},p_door={p_door}" for seed in seeds]
    return navigation_study(worlds, planners, seeds=[0], max_steps=max_steps, n_particles=n_particles,
                            workers=workers, progress=progress)


# --- figures -----------------------------------------------------------------------------------
def route_figure(model: GridModel, run: Run, goal: int, title: str = "") -> Figure:
    """One navigation run drawn on the map it started in (:func:`onlinemap.plots.plot_building`):
    the true path (a line through the cells visited, darker later), the goal, and the cells where
    the robot spent several steps in a row (waiting or pressing into a door). O(T + N)."""
    fig = plots.plot_building(model, run.maps[0], title=title)
    ax = fig.axes[0]
    rows, cols = np.divmod(run.locations, model.cols)
    ax.plot(cols, rows, "-", color="tab:blue", linewidth=2, alpha=0.7, label="path")
    stays = np.flatnonzero(np.diff(run.locations) == 0)
    if len(stays):
        cells, counts = np.unique(run.locations[stays], return_counts=True)
        waits = cells[counts >= 3]
        if len(waits):
            r, c = np.divmod(waits, model.cols)
            ax.plot(c, r, "o", color="tab:orange", markersize=9, markerfacecolor="none", markeredgewidth=2,
                    linestyle="none", label="stayed 3+ steps")
    row, col = divmod(int(goal), model.cols)
    ax.plot(col, row, marker="X", color="tab:purple", markersize=13, linestyle="none", label="goal")
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1), fontsize="small")
    return fig


def oracle_figure(runs: pd.DataFrame) -> Figure:
    """Each run's steps to the goal against the oracle's, one colour per planner (runs that did not
    get there at the top, at the step limit), with the lines y = x and y = 1.3 x."""
    fig = Figure(figsize=(5.2, 4.4), layout="constrained")
    ax = fig.subplots()
    limit = float(runs["steps"].max())
    for planner, group in runs[runs["oracle_reached"].astype(bool)].groupby("planner", sort=False):
        steps = group["steps_to_goal"].fillna(limit)
        ax.plot(group["oracle_steps"], steps, "o", alpha=0.7, label=planner)
    top = float(np.nanmax(runs["oracle_steps"])) if runs["oracle_steps"].notna().any() else limit
    ax.plot([0, top], [0, top], "k-", linewidth=1, label="oracle")
    ax.plot([0, top], [0, 1.3 * top], "k:", linewidth=1, label="1.3 x oracle")
    ax.set(xlabel="oracle's steps", ylabel="steps to the goal", title="steps to the goal, per run")
    ax.legend(fontsize="small")
    return fig
