"""The other papers' EM-mapping claims, each a study over many seeded random runs
with confidence intervals (``onlinemap reproduce loop|anneal|blocking``, notebook
``notebooks/em_mapping.ipynb``).

- :func:`loop_study`: grid EM with a footprint sensor (the textbook chapter, Thrun et al. 1998:
  offline Baum-Welch, forward-backward E-step, per-cell M-step) learns a world with a loop (a
  ring of 8 cells around a central block inside a 5 x 5 grid, walked round several times with
  noisy motion), where online EM with the same sensor goes astray; BK and the RBPF on the same
  runs. Exact Bayes needs 25 x 2^25 floats here: it is reported as refused (MemoryLimitError);
  ``loop_study(size=3)`` runs it on the 3 x 3 version, where the off-grid readings give the
  location away.
- :func:`anneal_study`: Burgard et al. (1999)'s annealed softmax M-step
  (``offline_em(anneal=...)``) against plain EM: how often each ends at a lower objective than
  the best of many random restarts (a local maximum).
- :func:`blocking_study`: the 10 x 10 door world with blocking walls and a cross footprint,
  from a uniform label prior: map and location error of each estimator under a random walk and
  under the exploration planners (``policies.explore``).

Runs and online estimators go through the sweep engine (seeds ``seed .. seed + n_runs - 1``,
the walk of the loop world as ``walk = "repeat:east,..."``); offline grid EM and the annealing
fits are fitted once per run, on the engine's own runs (stepping offline EM re-fits every prefix,
O(T^2)). Maps are scored over the cells the footprint read at least once
(:func:`onlinemap.evaluate.read_cells`), and every measure has the engine's name
(:data:`MEASURED`: ``read_map_error``, ``read_wrong_cells``, ``final_location_error``,
``ends_lost``), as in every other table.
Each returns a :class:`~onlinemap.studies.base.Study` ``(per_run, summary)``; the summary has,
per estimator (and policy), each measure's mean and its interval at ``confidence`` (columns
NAME, NAME_low, NAME_high: Student-t for errors, Wilson for 0/1 outcomes). An estimator that
refuses a model (exact Bayes on 25 cells) is a summary row with its ``error``, not dropped
silently.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import numpy as np
import pandas as pd

from .. import metrics
from ..estimators import make_estimator
from ..estimators.offline_em import baum_welch
from ..evaluate import HONEST_METRICS, LOST_BELOW, read_cells
from ..hmm import log_dirichlet_prior
from ..model import GridModel, door_world, grid_model
from ..progress import tqdm
from ..rng import SeedLike
from ..simulate import Run, simulate
from ..sweeps import sweep
from ..sweeps.runner import simulated_run
from .base import Study, summary_of, with_intervals

RING_ACTIONS = (1, 1, 2, 2, 3, 3, 0, 0)  # east, east, south, south, west, west, north, north: one lap
RING_WALK = "repeat:east,east,south,south,west,west,north,north"  # the same, as a sweep walk
#: the engine's per-run metrics the studies report: the last step, maps over the cells read
MEASURED = ("read_map_error", "read_wrong_cells", "final_location_error", "ends_lost")


def _scored(runs: pd.DataFrame, groups: list[str]) -> pd.DataFrame:
    """A sweep's runs as the study's rows: ``run`` (the seed), ``seed``, the groups, the measures and
    the honest metrics (:data:`onlinemap.evaluate.HONEST_METRICS`: in the rows, not in the printed
    summaries)."""
    table = runs.drop(columns="estimator").rename(columns={"label": "estimator"})
    table.insert(0, "run", table["seed"])
    return table[["run", "seed", *groups, *MEASURED, *HONEST_METRICS]]


def _refused(model: GridModel, estimators) -> tuple[list, list[dict]]:
    """The (label, name, options) of ``estimators`` that build on ``model``, and one row per
    estimator that refuses it (``estimator``, ``runs`` 0, ``error``: the exception, one line)."""
    kept, refused = [], []
    for label, name, options in estimators:
        try:
            make_estimator(name, model, **options)
        except Exception as error:  # noqa: BLE001 - an estimator that refuses the model: reported
            refused.append({"estimator": label, "runs": 0, "error": _short_error(error)})
        else:
            kept.append((label, name, options))
    return kept, refused


def _spec_estimators(estimators) -> dict:
    """The ``estimators`` section of a spec: one labelled table per (label, name, options)."""
    tables: dict[str, list] = {}
    for label, name, options in estimators:
        tables.setdefault(name, []).append({"label": label, **options})
    return tables


def _offline_rows(world: str, steps: int, walk: str, seeds, estimators, fit_options) -> list[dict]:
    """Offline grid EM fitted once on each run of the sweep (the engine's own runs,
    :func:`onlinemap.sweeps.runner.simulated_run`), scored like the sweep's rows: stepping it
    re-fits on every prefix (O(T^2)); the last step's belief is this one fit's."""
    rows = []
    for label, _, options in estimators:
        for seed in seeds:
            run = simulated_run(world, steps, walk, int(seed))
            fit = baum_welch(run.model, run.actions, run.observations, **{**fit_options, **options})
            rows.append({"run": int(seed), "seed": int(seed), "estimator": label,
                         **_final_scores(run, fit.location[-1], fit.map)})
    return rows


def _summary(per_run: pd.DataFrame, by: list[str], measures, confidence: float, refused: list[dict],
             n_cells: int) -> pd.DataFrame:
    """The one summary (:func:`onlinemap.studies.base.summary_of`) with the refused estimators
    appended, each with its error (an empty ``error`` where every run went through)."""
    summary = summary_of(per_run, list(measures), by, confidence, {"read_wrong_cells": (0, n_cells)})
    summary["error"] = ""
    return pd.concat([summary, pd.DataFrame(refused)], ignore_index=True) if refused else summary


# --- the loop world -------------------------------------------------------------------------
def loop_world(p_obs: float = 0.8, p_move: float = 0.8, footprint: str = "cross", size: int = 5) -> GridModel:
    """A ``size`` x ``size`` binary world (uniform label prior, static) whose robot walks the
    ring of 8 cells around the central cell (the block), starting at the ring's top-left
    corner, cell (size // 2 - 1, size // 2 - 1). With ``size`` = 5 the ring lies inside the grid,
    so a cross footprint never reads off the grid: the -1 readings give away no location (on a
    3 x 3 grid every cell's off-grid pattern is unique and the loop is trivial)."""
    corner = size // 2 - 1
    return grid_model(size, size, 2, p_obs=p_obs, p_move=p_move, start=corner * size + corner,
                      footprint=footprint)


def loop_world_spec(p_obs: float = 0.8, p_move: float = 0.8, footprint: str = "cross", size: int = 5) -> str:
    """:func:`loop_world` as a world spec (what the sweep engine reads)."""
    corner = size // 2 - 1
    return (f"grid:{size}x{size},n_labels=2,p_obs={p_obs},p_move={p_move},start={corner * size + corner},"
            f"footprint={footprint}")


def loop_run(model: GridModel, laps: int, seed: SeedLike) -> Run:
    """``laps`` scripted laps of the ring (:data:`RING_ACTIONS`) in a map drawn from the prior;
    slips (1 - p_move) put the robot out of phase with the script."""
    return simulate(model, None, np.tile(RING_ACTIONS, int(laps)), seed)


def _final_scores(run: Run, location: np.ndarray, maps: np.ndarray) -> dict[str, float]:
    """At the last step, over the cells ever read: map error, wrong cells; location error, lost
    (:data:`MEASURED`, as the engine computes them for a filter's run)."""
    p_true = float(location[run.locations[-1]])
    seen = read_cells(run)
    return {"read_map_error": float(metrics.map_error(maps[seen], run.final_map[seen])),
            "read_wrong_cells": metrics.wrong_cells(maps[seen], run.final_map[seen]),
            "final_location_error": 1.0 - p_true, "ends_lost": p_true < LOST_BELOW}


LOOP_ESTIMATORS: list[tuple[str, str, dict]] = [
    ("exact", "exact", {}),
    ("offline grid EM", "offline_em", {}),
    ("online_em W=16", "online_em", {}),
    ("online_em W=max", "online_em", {"window": "max"}),
    ("bk", "bk", {}),
    ("rbpf P=500", "rbpf", {"n_particles": 500}),
    ("dead_reckoning", "dead_reckoning", {}),
]
LOOP_MEASURES = {"read_map_error": False, "read_wrong_cells": False, "final_location_error": False,
                 "ends_lost": True, "any_wrong_cell": True}


def _short_error(error: Exception) -> str:
    first = str(error).strip().splitlines()[0] if str(error).strip() else ""
    return f"{type(error).__name__}: {first[:120]}"


def _estimate_study(world: str, steps: int, walk: str, seeds, estimators, name: str, progress: bool,
                    workers: int | None) -> tuple[list[dict], list[dict]]:
    """The study's rows of every estimator on the same runs, and the refused estimators' rows:
    online estimators on the sweep engine, offline grid EM fitted once per run beside it."""
    from ..worlds import parse_world

    model = parse_world(world).model
    kept, refused = _refused(model, estimators)
    online = [e for e in kept if e[1] != "offline_em"]
    rows = []
    if online:
        spec = {"name": name, "worlds": [world], "seeds": list(seeds), "steps": steps, "walk": walk,
                "estimators": _spec_estimators(online)}
        rows += _scored(sweep(spec, workers=workers, progress=progress), ["estimator"]).to_dict("records")
    rows += _offline_rows(world, steps, walk, seeds, [e for e in kept if e[1] == "offline_em"], {})
    order = {label: i for i, (label, _, _) in enumerate(estimators)}
    rows.sort(key=lambda row: (order[row["estimator"]], row["seed"]))
    return rows, refused


def loop_study(n_runs: int = 200, seed: int = 0, *, laps: int = 3, p_obs: float = 0.8,
               p_move: float = 0.8, footprint: str = "cross", size: int = 5, estimators=None,
               confidence: float = 0.95, workers: int | None = 0, progress: bool = True) -> Study:
    """Grid EM with a footprint sensor on the loop world (:func:`loop_world`), ``n_runs`` random
    maps and slip patterns of ``laps`` laps each (seeds ``seed .. seed + n_runs - 1``, on the sweep
    engine); every estimator of ``estimators`` (default :data:`LOOP_ESTIMATORS`) on the same runs,
    scored at the last step: map error, wrong cells, location error, lost (P(true location) < 0.5)
    and any wrong cell. An estimator that refuses the model (exact Bayes on 25 cells) is a
    summary row with its error. Cost: n_runs x (offline EM's O(iterations T N F) + the others)."""
    world = loop_world_spec(p_obs, p_move, footprint, size)
    rows, refused = _estimate_study(world, len(RING_ACTIONS) * int(laps) + 1, RING_WALK,
                                    range(int(seed), int(seed) + int(n_runs)), estimators or LOOP_ESTIMATORS,
                                    "loop", progress, workers)
    per_run = pd.DataFrame(rows)
    per_run["any_wrong_cell"] = per_run["read_wrong_cells"] > 0
    return Study(per_run, _summary(per_run, ["estimator"], LOOP_MEASURES, confidence, refused, size * size))


# --- annealing --------------------------------------------------------------------------------
ANNEAL = (8.0, 0.85, 1.0)  # tau0, rate, tau_min: the posterior tempered by 1/tau, tau from 8 down to 1
ANNEAL_MEASURES = {"local_maximum": True, "objective_gap": False, "read_map_error": False}


def anneal_study(n_runs: int = 200, seed: int = 0, *, laps: int = 3, restarts: int = 10,
                 anneal=ANNEAL, pseudo_count: float = 0.1, tol: float = 1e-3, p_obs: float = 0.8,
                 p_move: float = 0.8, footprint: str = "cross", size: int = 5, confidence: float = 0.95,
                 progress: bool = True) -> Study:
    """Plain against annealed offline EM on the loop world's runs (the sweep engine's runs of
    :func:`loop_study`, seeds ``seed .. seed + n_runs - 1``). For each run the best objective
    (log likelihood + the pseudo-count prior) over plain EM, annealed EM and ``restarts`` plain EM
    runs from random B (rows Dirichlet(1)) is the reference; a method ends at a local maximum
    when its objective is more than ``tol`` below it. Reports, per method, the fraction of runs
    at a local maximum (Wilson), the mean gap to the best, the final map error, and the paired
    comparison on the same runs: ``stuck_alone`` (runs where only this method is at a local
    maximum) and the exact McNemar p-value of the two counts. The fits are the study (restarts
    of one Baum-Welch per run, not a filter stepped through a run), so they run here, on the
    engine's runs. Cost: n_runs x (restarts + 2) Baum-Welch fits."""
    world = loop_world_spec(p_obs, p_move, footprint, size)
    steps = len(RING_ACTIONS) * int(laps) + 1
    rows = []
    seeds = range(int(seed), int(seed) + int(n_runs))
    for run_seed in tqdm(seeds, desc="annealing", disable=not progress):
        run = simulated_run(world, steps, RING_WALK, run_seed)
        model = run.model
        fits = {"plain EM": baum_welch(model, run.actions, run.observations, pseudo_count=pseudo_count),
                f"annealed EM {tuple(anneal)}": baum_welch(model, run.actions, run.observations,
                                                           pseudo_count=pseudo_count, anneal=anneal)}
        starts = np.random.default_rng(run_seed).dirichlet(np.ones(model.n_labels), size=(restarts, model.n_cells))
        restart_fits = [baum_welch(model, run.actions, run.observations, pseudo_count=pseudo_count, initial=b)
                        for b in starts]

        def objective(fit) -> float:
            return fit.log_likelihood + log_dirichlet_prior(fit.observation_matrix, pseudo_count)

        best = max(objective(fit) for fit in [*fits.values(), *restart_fits])
        for label, fit in fits.items():
            gap = best - objective(fit)
            rows.append({"run": run_seed, "seed": run_seed, "estimator": label, "objective": objective(fit),
                         "best_objective": best, "objective_gap": gap, "local_maximum": bool(gap > tol),
                         "read_map_error": _final_scores(run, fit.location[-1], fit.map)["read_map_error"]})
    per_run = pd.DataFrame(rows)
    summary = summary_of(per_run, list(ANNEAL_MEASURES), ["estimator"], confidence)
    stuck = per_run.pivot(index="run", columns="estimator", values="local_maximum")[list(fits)]
    alone = [int(((stuck[m] == 1) & (stuck.drop(columns=m) == 0).all(axis=1)).sum()) for m in fits]
    summary["stuck_alone"] = alone  # runs where only this method ends at a local maximum
    summary["mcnemar_p"] = _mcnemar(*alone)
    return Study(per_run, summary)


def _mcnemar(a: int, b: int) -> float:
    """Exact two-sided McNemar p-value of ``a`` against ``b`` discordant pairs (binomial, 1/2)."""
    from scipy.stats import binomtest

    return float(binomtest(a, a + b).pvalue) if a + b else 1.0


# --- blocking walls in the door world -------------------------------------------------------
BLOCKING_ESTIMATORS: list[tuple[str, str, dict]] = [
    ("bk", "bk", {}),
    ("online_em W=16", "online_em", {}),
    ("offline grid EM", "offline_em", {}),
    ("rbpf P=200", "rbpf", {"n_particles": 200}),
    ("dead_reckoning", "dead_reckoning", {}),
]
# the estimators a planner's loop is closed on (the planners read its belief each step; info_gain
# rolls hypotheses out on forks of it)
PLANNER_ESTIMATORS: list[tuple[str, str, dict]] = [("rbpf P=200", "rbpf", {"n_particles": 200})]
BLOCKING_MEASURES = {"read_map_error": False, "read_wrong_cells": False, "final_location_error": False,
                     "ends_lost": True}


def blocking_world(p_obs: float = 0.9, p_move: float = 0.8, footprint="cross") -> tuple[GridModel, np.ndarray]:
    """The 10 x 10 door world, walls and closed doors blocking, a cross footprint, a uniform
    label prior over the four labels (the robot knows nothing of the layout)."""
    return door_world(p_obs=p_obs, p_move=p_move, blocking=True, footprint=footprint,
                      label_prior=np.full(4, 0.25))


def blocking_world_spec(p_obs: float = 0.9, p_move: float = 0.8, footprint: str = "cross") -> str:
    """:func:`blocking_world` as a world spec (the door world's prior is uniform)."""
    return f"door,blocking=1,footprint={footprint},p_obs={p_obs},p_move={p_move}"


def blocking_study(n_runs: int = 200, seed: int = 0, *, steps: int = 150, policies=("random walk",),
                   estimators=None, planner_estimators=None, planner_options: dict | None = None,
                   p_obs: float = 0.9, p_move: float = 0.8, footprint: str = "cross",
                   confidence: float = 0.95, workers: int | None = 0, progress: bool = True) -> Study:
    """Map and location error in :func:`blocking_world` over ``n_runs`` seeded runs of ``steps``
    steps per policy (seeds ``seed .. seed + n_runs - 1``, on the sweep engine): ``"random walk"``
    (the same runs for every estimator of ``estimators``, default :data:`BLOCKING_ESTIMATORS`) or
    a planner name of ``policies`` (exploration tasks: the loop closed on each estimator of
    ``planner_estimators``, default :data:`PLANNER_ESTIMATORS`, the planner built with
    ``planner_options[name]``; the same seeds). Scored alike at the last step over the cells read:
    map error, wrong cells, location error, lost. An estimator that refuses the model is a
    summary row with its error. Cost: n_runs x policies x estimators x steps x one step (BK
    O(N F^2), online EM O(W N F), offline EM one fit of O(iterations T N F)), plus each
    planner's choices."""
    world = blocking_world_spec(p_obs, p_move, footprint)
    seeds = range(int(seed), int(seed) + int(n_runs))
    rows, refused = [], []
    if "random walk" in policies:
        walked, refused = _estimate_study(world, steps, "random", seeds, estimators or BLOCKING_ESTIMATORS,
                                          "blocking", progress, workers)
        rows += [{"policy": "random walk", **row} for row in walked]
    planners = [p for p in policies if p != "random walk"]
    if planners:  # offline EM refits from scratch every step: O(T^2) in a closed loop, left out
        closed = [e for e in planner_estimators or PLANNER_ESTIMATORS if e[1] != "offline_em"]
        spec = {"name": "blocking-planners", "worlds": [world], "seeds": list(seeds), "steps": steps,
                "planners": {p: dict((planner_options or {}).get(p, {})) for p in planners},
                "estimators": _spec_estimators(closed)}
        played = _scored(sweep(spec, workers=workers, progress=progress), ["planner", "estimator"])
        rows += played.rename(columns={"planner": "policy"}).to_dict("records")
    order = {policy: i for i, policy in enumerate(policies)}
    per_run = pd.DataFrame(rows).sort_values("policy", key=lambda c: c.map(order), kind="stable")
    summary = _summary(per_run.reset_index(drop=True), ["policy", "estimator"], BLOCKING_MEASURES, confidence,
                       [{"policy": "random walk", **row} for row in refused], 100)
    return Study(per_run.reset_index(drop=True), summary)


class MappingStudy(NamedTuple):
    """A study of this module as the CLI runs it (``onlinemap reproduce NAME``)."""

    run: Callable[..., Study]
    measures: dict[str, bool]  # measure -> is a 0/1 proportion
    description: str


STUDIES: dict[str, MappingStudy] = {
    "loop": MappingStudy(loop_study, LOOP_MEASURES,
                  "grid EM with a cross footprint on a ring of 8 cells around a block (5 x 5 grid, 3 laps, "
                  "p_obs 0.8, p_move 0.8); scored at the last step over the cells read"),
    "anneal": MappingStudy(anneal_study, ANNEAL_MEASURES,
                    f"plain vs annealed offline EM {ANNEAL} on the loop world; local maximum: objective more "
                    "than 1e-3 below the best of both and 10 random restarts"),
    "blocking": MappingStudy(blocking_study, BLOCKING_MEASURES,
                      "10 x 10 door world, walls and closed doors blocking, cross footprint, uniform label "
                      "prior; random walk (every estimator) and the --planners closed on rbpf P=200; scored at the "
                      "last step over the cells read"),
}
