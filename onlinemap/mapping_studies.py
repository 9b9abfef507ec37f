"""The other papers' EM-mapping claims (issue 13), each a study over many seeded random runs
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

Maps are scored over the cells the footprint read at least once (:func:`read_cells`). Each
returns ``(per_run, summary)`` frames; the summary has, per estimator (and policy), each
measure's mean and its interval at ``confidence`` (columns NAME, NAME_low, NAME_high: Student-t
for errors, Wilson for 0/1 outcomes). An estimator that refuses a model (e.g. an RBPF without
footprint support) is reported in the ``error`` column, not dropped silently.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import numpy as np
import pandas as pd

from . import metrics
from .estimators import make_estimator, run_estimator
from .estimators.offline_em import baum_welch
from .evaluate import metric_bounds
from .hmm import log_dirichlet_prior
from .model import GridModel, door_world, grid_model
from .progress import tqdm
from .rng import SeedLike, as_generator
from .simulate import Run, simulate
from .stats import mean_interval

LOST_BELOW = 0.5  # P(true location) below this at the end: lost
RING_ACTIONS = (1, 1, 2, 2, 3, 3, 0, 0)  # east, east, south, south, west, west, north, north: one lap


class StudyResult(NamedTuple):
    per_run: pd.DataFrame  # one row per run and estimator (and policy)
    summary: pd.DataFrame  # one row per estimator (and policy): means and intervals


def summarize(per_run: pd.DataFrame, by: list[str], measures: dict[str, bool],
              confidence: float = 0.95) -> pd.DataFrame:
    """Per group: ``runs`` and, for each measure, the mean with its interval (Wilson when the
    measure is a 0/1 ``proportion``, Student-t otherwise). ``measures``: name -> proportion."""
    rows = []
    for key, group in per_run.groupby(by, sort=False):
        row = dict(zip(by, key if isinstance(key, tuple) else (key,)))
        row["runs"] = int(group[measures and next(iter(measures))].notna().sum()) if measures else len(group)
        for name, proportion in measures.items():
            interval = mean_interval(group[name].to_numpy(dtype=np.float64), confidence, proportion=proportion,
                                     bounds=metric_bounds(name))
            row[name], row[f"{name}_low"], row[f"{name}_high"] = interval
        if "error" in group:  # failed runs: how many, and the kinds of error (details in per_run)
            failed = group["error"].dropna()
            kinds = failed.str.split(":").str[0].value_counts()
            row["error"] = "; ".join(f"{n} runs: {kind}" for kind, n in kinds.items())
        rows.append(row)
    return pd.DataFrame(rows)


def with_intervals(summary: pd.DataFrame, measures) -> pd.DataFrame:
    """The summary with each measure as one "mean [low, high]" text column (for printing)."""
    keep = [c for c in summary.columns if c not in measures and not c.endswith(("_low", "_high"))]
    table = summary[keep].copy()
    for name in measures:
        table[name] = [f"{m:.3f} [{lo:.3f}, {hi:.3f}]" if np.isfinite(m) else "-" for m, lo, hi in
                       summary[[name, f"{name}_low", f"{name}_high"]].itertuples(index=False)]
    return table


# --- the loop world -------------------------------------------------------------------------
def loop_world(p_obs: float = 0.8, p_move: float = 0.8, footprint="cross", size: int = 5) -> GridModel:
    """A ``size`` x ``size`` binary world (uniform label prior, static) whose robot walks the
    ring of 8 cells around the central cell (the block), starting at the ring's top-left
    corner, cell (size // 2 - 1, size // 2 - 1). With ``size`` = 5 the ring lies inside the grid,
    so a cross footprint never reads off the grid: the -1 readings give away no location (on a
    3 x 3 grid every cell's off-grid pattern is unique and the loop is trivial)."""
    corner = size // 2 - 1
    return grid_model(size, size, 2, p_obs=p_obs, p_move=p_move, start=corner * size + corner,
                      footprint=footprint)


def loop_run(model: GridModel, laps: int, seed: SeedLike) -> Run:
    """``laps`` scripted laps of the ring (:data:`RING_ACTIONS`) in a map drawn from the prior;
    slips (1 - p_move) put the robot out of phase with the script."""
    return simulate(model, None, np.tile(RING_ACTIONS, int(laps)), seed)


def read_cells(run: Run) -> np.ndarray:
    """The cells the footprint read at least once during the run (sorted)."""
    cells = run.model.footprint_cells[run.locations]
    return np.unique(cells[cells >= 0])


def _final_scores(run: Run, location: np.ndarray, maps: np.ndarray) -> dict[str, float]:
    """At the last step, over the cells ever read: map error, wrong cells; location error, lost."""
    p_true = float(location[run.locations[-1]])
    seen = read_cells(run)
    return {"map_error": float(metrics.map_error(maps[seen], run.final_map[seen])),
            "wrong_cells": metrics.wrong_cells(maps[seen], run.final_map[seen]),
            "location_error": 1.0 - p_true, "lost": float(p_true < LOST_BELOW)}


LOOP_ESTIMATORS: list[tuple[str, str, dict]] = [
    ("exact", "exact", {}),
    ("offline grid EM", "offline_em", {}),
    ("online_em W=16", "online_em", {}),
    ("online_em W=max", "online_em", {"window": "max"}),
    ("bk", "bk", {}),
    ("rbpf P=500", "rbpf", {"n_particles": 500}),
    ("dead_reckoning", "dead_reckoning", {}),
]
LOOP_MEASURES = {"map_error": False, "wrong_cells": False, "location_error": False, "lost": True,
                 "any_wrong_cell": True}


def _final_belief(model: GridModel, name: str, options: dict, run: Run, seed: int):
    """(location (N,), map (N, K)) at the last step; offline EM fits once on the whole run."""
    if name == "offline_em":
        fit = baum_welch(model, run.actions, run.observations, **options)
        return fit.location[-1], fit.map
    if name == "rbpf":
        options = {**options, "seed": seed}
    trajectory = run_estimator(make_estimator(name, model, **options), run.actions, run.observations)
    return trajectory.location[-1], trajectory.map[-1]


def _short_error(error: Exception) -> str:
    first = str(error).strip().splitlines()[0] if str(error).strip() else ""
    return f"{type(error).__name__}: {first[:120]}"


def _score_estimators(model: GridModel, run: Run, estimators, seed: int) -> list[dict]:
    rows = []
    for label, name, options in estimators:
        try:
            location, maps = _final_belief(model, name, options, run, seed)
            row = _final_scores(run, location, maps)
            row["any_wrong_cell"] = float(row["wrong_cells"] > 0)
            row["error"] = None
        except Exception as error:  # noqa: BLE001 - an estimator that refuses (or fails on) the model: reported
            row = {measure: np.nan for measure in LOOP_MEASURES} | {"error": _short_error(error)}
        rows.append({"estimator": label, **row})
    return rows


def _loop_runs(model: GridModel, n_runs: int, seed: SeedLike, laps: int, desc: str, progress: bool):
    """Yield ``(index, run seed, run)`` for ``n_runs`` :func:`loop_run` runs, each seeded from ``seed``."""
    rng = as_generator(seed)
    for index in tqdm(range(int(n_runs)), desc=desc, disable=not progress):
        run_seed = int(rng.integers(2**31))
        yield index, run_seed, loop_run(model, laps, run_seed)


def loop_study(n_runs: int = 200, seed: SeedLike = 0, *, laps: int = 3, p_obs: float = 0.8,
               p_move: float = 0.8, footprint="cross", size: int = 5, estimators=None,
               confidence: float = 0.95, progress: bool = True) -> StudyResult:
    """Grid EM with a footprint sensor on the loop world (:func:`loop_world`), ``n_runs`` random
    maps and slip patterns of ``laps`` laps each; every estimator of ``estimators`` (default
    :data:`LOOP_ESTIMATORS`) on the same runs, scored at the last step: map error, wrong cells,
    location error, lost (P(true location) < 0.5) and any wrong cell. Cost: n_runs x (exact's
    O(T F N 2^N) + offline EM's O(iterations T N F) + the others)."""
    rows = []
    for index, run_seed, run in _loop_runs(loop_world(p_obs, p_move, footprint, size), n_runs, seed, laps,
                                           "loop world", progress):
        model = run.model
        for row in _score_estimators(model, run, estimators or LOOP_ESTIMATORS, run_seed):
            rows.append({"run": index, "seed": run_seed, "slips": int(run.slipped.sum()), **row})
    per_run = pd.DataFrame(rows)
    return StudyResult(per_run, summarize(per_run, ["estimator"], LOOP_MEASURES, confidence))


# --- annealing --------------------------------------------------------------------------------
ANNEAL = (8.0, 0.85, 1.0)  # tau0, rate, tau_min: the posterior tempered by 1/tau, tau from 8 down to 1
ANNEAL_MEASURES = {"local_maximum": True, "objective_gap": False, "map_error": False}


def anneal_study(n_runs: int = 200, seed: SeedLike = 0, *, laps: int = 3, restarts: int = 10,
                 anneal=ANNEAL, pseudo_count: float = 0.1, tol: float = 1e-3, p_obs: float = 0.8,
                 p_move: float = 0.8, footprint="cross", size: int = 5, confidence: float = 0.95,
                 progress: bool = True) -> StudyResult:
    """Plain against annealed offline EM on the loop world's runs. For each run the best
    objective (log likelihood + the pseudo-count prior) over plain EM, annealed EM and
    ``restarts`` plain EM runs from random B (rows Dirichlet(1)) is the reference; a method
    ends at a local maximum when its objective is more than ``tol`` below it. Reports, per
    method, the fraction of runs at a local maximum (Wilson), the mean gap to the best, the
    final map error, and the paired comparison on the same runs: ``stuck_alone`` (runs where
    only this method is at a local maximum) and the exact McNemar p-value of the two counts.
    Cost: n_runs x (restarts + 2) Baum-Welch fits."""
    model = loop_world(p_obs, p_move, footprint, size)
    rows = []
    for index, run_seed, run in _loop_runs(model, n_runs, seed, laps, "annealing", progress):
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
            rows.append({"run": index, "seed": run_seed, "estimator": label, "objective": objective(fit),
                         "best_objective": best, "objective_gap": gap, "local_maximum": float(gap > tol),
                         "map_error": _final_scores(run, fit.location[-1], fit.map)["map_error"]})
    per_run = pd.DataFrame(rows)
    summary = summarize(per_run, ["estimator"], ANNEAL_MEASURES, confidence)
    stuck = per_run.pivot(index="run", columns="estimator", values="local_maximum")[list(fits)]
    alone = [int(((stuck[m] == 1) & (stuck.drop(columns=m) == 0).all(axis=1)).sum()) for m in fits]
    summary["stuck_alone"] = alone  # runs where only this method ends at a local maximum
    summary["mcnemar_p"] = _mcnemar(*alone)
    return StudyResult(per_run, summary)


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
BLOCKING_MEASURES = {"map_error": False, "wrong_cells": False, "location_error": False, "lost": True}


def blocking_world(p_obs: float = 0.9, p_move: float = 0.8, footprint="cross") -> tuple[GridModel, np.ndarray]:
    """The 10 x 10 door world, walls and closed doors blocking, a cross footprint, a uniform
    label prior over the four labels (the robot knows nothing of the layout)."""
    return door_world(p_obs=p_obs, p_move=p_move, blocking=True, footprint=footprint,
                      label_prior=np.full(4, 0.25))


def blocking_study(n_runs: int = 200, seed: SeedLike = 0, *, steps: int = 150, policies=("random walk",),
                   estimators=None, planner_estimators=None, planner_options: dict | None = None,
                   p_obs: float = 0.9, p_move: float = 0.8, footprint="cross",
                   confidence: float = 0.95, progress: bool = True) -> StudyResult:
    """Map and location error in :func:`blocking_world` over ``n_runs`` seeded runs of ``steps``
    steps per policy: ``"random walk"`` (the same runs for every estimator of ``estimators``,
    default :data:`BLOCKING_ESTIMATORS`) or a planner name of ``policies.explore`` (the loop
    closed on each estimator of ``planner_estimators``, default :data:`PLANNER_ESTIMATORS`,
    the planner built with ``planner_options[name]``; the same run seeds as the random walk).
    Scored alike at the last step over the cells read: map error, wrong cells, location error,
    lost. An estimator or planner that refuses the model is reported in ``error``.
    Cost: n_runs x policies x estimators x steps x one step (BK O(N F^2), online EM
    O(W N F), offline EM one fit of O(iterations T N F)), plus each planner's choices
    (info_gain: ~S C H estimator steps per plan on forks, S hypotheses, C candidates, H horizon)."""
    model, true_map = blocking_world(p_obs, p_move, footprint)
    rng = as_generator(seed)
    rows = []
    seeds = [int(s) for s in rng.integers(2**31, size=int(n_runs))]
    total = len(seeds) * len(policies)
    with tqdm(total=total, desc="door world, blocking", disable=not progress) as bar:
        for policy in policies:
            for index, run_seed in enumerate(seeds):
                if policy == "random walk":
                    run = simulate(model, true_map, steps=steps, seed=run_seed)
                    scored = _score_estimators(model, run, estimators or BLOCKING_ESTIMATORS, run_seed)
                else:
                    scored = _explore_scores(model, true_map, policy, planner_estimators or PLANNER_ESTIMATORS,
                                             steps, run_seed, (planner_options or {}).get(policy))
                for row in scored:
                    rows.append({"policy": policy, "run": index, "seed": run_seed, **row})
                bar.update()
    per_run = pd.DataFrame(rows)
    return StudyResult(per_run, summarize(per_run, ["policy", "estimator"], BLOCKING_MEASURES, confidence))


def _explore_scores(model, true_map, planner: str, estimators, steps: int, seed: int,
                    planner_options: dict | None = None) -> list[dict]:
    """Close the loop with ``policies.exploration``: the planner acts on each (online) estimator;
    scored like the random walk (:func:`_final_scores`, over the cells read)."""
    from policies.explore import exploration

    rows = []
    for label, name, options in estimators:
        if name == "offline_em":  # refits from scratch every step: O(T^2) in a closed loop
            continue
        try:
            found = exploration(model, true_map, planner, name, steps, seed, estimator_options=options or None,
                                planner_options=planner_options, progress=False)
            row = _final_scores(found.run, found.trajectory.location[-1], found.trajectory.map[-1])
            row["error"] = None
        except Exception as error:  # noqa: BLE001 - a planner or estimator that fails on the model: reported
            row = {measure: np.nan for measure in BLOCKING_MEASURES} | {"error": _short_error(error)}
        rows.append({"estimator": label, **row})
    return rows


class Study(NamedTuple):
    run: Callable[..., StudyResult]
    measures: dict[str, bool]  # measure -> is a 0/1 proportion
    description: str


STUDIES: dict[str, Study] = {
    "loop": Study(loop_study, LOOP_MEASURES,
                  "grid EM with a cross footprint on a ring of 8 cells around a block (5 x 5 grid, 3 laps, "
                  "p_obs 0.8, p_move 0.8); scored at the last step over the cells read"),
    "anneal": Study(anneal_study, ANNEAL_MEASURES,
                    f"plain vs annealed offline EM {ANNEAL} on the loop world; local maximum: objective more "
                    "than 1e-3 below the best of both and 10 random restarts"),
    "blocking": Study(blocking_study, BLOCKING_MEASURES,
                      "10 x 10 door world, walls and closed doors blocking, cross footprint, uniform label "
                      "prior; random walk (every estimator) and the --planners closed on rbpf P=200; scored at the "
                      "last step over the cells read"),
}
