"""Hindsight maps at building scale (issue 41, Burgard et al. 1999): flat EM against layered EM
on recorded runs in 32 x 32 floors, beside the RBPF's filtered map and the told-location map.

:func:`hindsight_study` records runs on the sweep engine (:func:`onlinemap.studies.exploration.planners_study`:
each planner of ``planners`` explores each world with the RBPF; ``random`` is a random walk)
and remaps every run after the fact (:mod:`onlinemap.hindsight`):

- ``flat_em``: Baum-Welch over the whole run, the model's (uniform) label prior;
- ``layered_em``: :func:`onlinemap.layered_em.fit_layered_map`, the model's prior;
- ``layered_em_learned``: the same with ``label_prior="learn"`` (the label frequencies and the
  adjacent labels' statistics learned in every M-step);
- ``layered_em_learned_alignment``: that fit's local maps where it placed them, the global map
  under the model's prior (aligned with the learned statistics, mapped like for like with flat EM);
- ``filter``: the recording RBPF's map at the last step (filtered, not smoothed);
- ``rbpf_filtered`` and ``rbpf_smoothed``: the run replayed through an RBPF of
  :data:`~onlinemap.hindsight.SMOOTHER_PARTICLES` particles (seed 0), its final map and its
  genealogy smoother (:func:`onlinemap.hindsight.smoothed_rbpf_map`; the rows add
  ``distinct_paths`` and ``common_steps``);
- ``told_location`` and ``told_location_learned``: the map of a robot told its true path, with
  the model's prior and with the learned frequencies: the references for the two priors.

World kinds (:data:`WORLD_KINDS`): ``building``, generated 32 x 32 buildings (blocking walls and
closed doors, a cross footprint) at ``p_move`` 0.95 and 0.8; ``floor``, 32 x 32 cells read from
the MovingAI and ROS map files in ``shared/maps`` (:data:`FLOOR_WORLDS`). Each row of
``per_run`` is one (world, planner, seed, method): ``final_map_error`` (mean over the N cells
of 1 - P(true label)) and ``confidently_wrong`` (cells with P(true label) < 0.1). The summary
has, per kind and method, the means with intervals at ``confidence`` (Student t), and
:func:`paired_tests` the Wilcoxon signed-rank test of "A's map error is lower than B's" on the
same runs. Cost: one RBPF exploration per (world, planner, seed) (O(steps particles F K)), then
flat EM (O(iterations T (N F + E))), layered EM twice (:mod:`onlinemap.layered_em`) and one
RBPF replay with its genealogy (:func:`onlinemap.hindsight.smoothed_rbpf_map`) per run.
"""

from __future__ import annotations

import os
import time
from typing import Mapping, NamedTuple, Sequence

import numpy as np
import pandas as pd

from ..hindsight import CONFIDENTLY_WRONG_BELOW, hindsight_map, smoothed_rbpf_map
from ..layered_em import fit_layered_map
from ..metrics import map_error
from ..progress import tqdm
from ..simulate import Run
from .base import Study, summary_of
from .exploration import planners_study

MAPS = os.path.join(os.path.dirname(__file__), "..", "..", "..", "shared", "maps")
BUILDING_WORLDS = tuple(f"building:32x32,seed={seed},p_move={p_move}" for p_move in (0.95, 0.8) for seed in range(4))
#: 32 x 32 cells of each map file (the regions with the most walls; the ROS maps at 0.25 m and 0.1 m cells)
FLOOR_FILES = ("movingai/arena.map,region=0:32x0:32", "movingai/random-32-32-20.map",
               "ros/nav2_depot/depot.yaml,cell_size=0.25,region=16:24x0:8",
               "ros/tb3_world/map.yaml,cell_size=0.1,region=-1.6:1.6x-1.6:1.6")
PLANNERS = ("random", "frontier", "info_gain")
METHODS = ("flat_em", "layered_em", "layered_em_learned", "layered_em_learned_alignment", "filter", "rbpf_filtered",
           "rbpf_smoothed", "told_location", "told_location_learned")
MEASURES = ("final_map_error", "confidently_wrong", "seconds")
STEPS = 200  # per run: the study records 48 runs; a few CPU minutes, RBPF and remapping alike
N_PARTICLES = 200
SEEDS = {"building": (0,), "floor": (0, 1)}  # 8 buildings x 3 planners x 1 seed, 4 floors x 3 planners x 2 seeds: 24 runs each


def floor_worlds(maps: str | os.PathLike = MAPS) -> tuple[str, ...]:
    """The world specs of :data:`FLOOR_FILES` under the folder ``maps``."""
    return tuple(f"layout:{os.path.normpath(os.path.join(maps, name.split(',')[0]))}"
                 + "".join("," + part for part in name.split(",")[1:]) for name in FLOOR_FILES)


def world_kinds(maps: str | os.PathLike = MAPS) -> dict[str, tuple[str, ...]]:
    """``{"building": BUILDING_WORLDS, "floor": floor_worlds(maps)}``."""
    return {"building": BUILDING_WORLDS, "floor": floor_worlds(maps)}


def remap_rows(run, filter_map: np.ndarray | None, fit_options: Mapping[str, dict] | None = None,
               methods: Sequence[str] = METHODS) -> list[dict]:
    """The study's rows of one recorded run (:class:`~onlinemap.simulate.Run`): every method of
    ``methods`` (default :data:`METHODS`; ``layered_em_learned`` brings its alignment's row and
    ``rbpf_smoothed`` the row ``rbpf_filtered``; ``filter`` only when ``filter_map`` (N, K) is
    given) scored against the run's true map, with its CPU seconds (``layered_em_learned_alignment`` is the learned fit's map under
    the model's prior, :meth:`~onlinemap.layered_em.LayeredMap.map_with_prior`: the same fit's
    seconds; ``rbpf_filtered`` is the replay of ``rbpf_smoothed``, the same seconds).
    ``fit_options``: extra options per method. Cost: the fits."""
    fit_options = fit_options or {}
    options = {"flat_em": ("flat_em", {}), "layered_em": ("layered_em", {}),
               "told_location": ("told_location", {"label_prior": "model"}), "told_location_learned": ("told_location", {"label_prior": "learn"})}
    rows = []
    for method in methods:
        started = time.process_time()
        if method == "filter":
            if filter_map is not None:
                rows.append(score_map(method, np.asarray(filter_map), run.final_map, np.nan))
        elif method == "layered_em_learned":
            fit = fit_layered_map(run.model, run.actions, run.observations,
                                  **{"label_prior": "learn", **fit_options.get(method, {})})
            seconds = time.process_time() - started
            rows.append(score_map(method, fit.map, run.final_map, seconds))
            rows.append(score_map(f"{method}_alignment", fit.map_with_prior(run.model.label_prior), run.final_map,
                                  seconds))
        elif method == "rbpf_smoothed":
            smoothed = smoothed_rbpf_map(run.model, run.actions, run.observations, **fit_options.get(method, {}))
            seconds = time.process_time() - started
            genealogy = {"distinct_paths": smoothed.distinct_paths, "common_steps": smoothed.common_steps}
            rows.append({**score_map("rbpf_filtered", smoothed.filtered, run.final_map, seconds), **genealogy})
            rows.append({**score_map(method, smoothed.map, run.final_map, seconds), **genealogy})
        elif method not in ("layered_em_learned_alignment", "rbpf_filtered"):
            kind, extra = options[method]
            belief = hindsight_map(run.model, run, kind, **{**extra, **fit_options.get(method, {})}).map
            rows.append(score_map(method, belief, run.final_map, time.process_time() - started))
    return rows


def score_map(method: str, belief: np.ndarray, true_map: np.ndarray, seconds: float) -> dict:
    """One row: ``method``, ``final_map_error`` and ``confidently_wrong`` of ``belief`` (N, K)
    against the true labels (N,), and ``seconds``. O(N K)."""
    p_true = belief[np.arange(len(true_map)), true_map]
    return {"method": method, "final_map_error": float(map_error(belief, true_map)),
            "confidently_wrong": int(np.sum(p_true < CONFIDENTLY_WRONG_BELOW)), "seconds": seconds}


class Recorded(NamedTuple):
    """One recorded run of the study and the filter's final map."""

    kind: str
    world: str
    planner: str
    seed: int
    run: Run
    filter_map: np.ndarray  # (N, K) the RBPF's map at the last step


def record_runs(kinds: Mapping[str, Sequence[str]] | None = None, *, planners: Sequence[str] = PLANNERS,
                seeds: Mapping[str, Sequence[int]] | Sequence[int] | None = None, steps: int = STEPS,
                n_particles: int = N_PARTICLES, progress: bool = True) -> list[Recorded]:
    """Every planner of ``planners`` on every world of every kind (``kinds``: name -> world specs,
    default :func:`world_kinds`) and seed (``seeds``: one sequence, or one per kind; default
    :data:`SEEDS`), ``steps`` steps with the RBPF of ``n_particles`` particles, played on the
    sweep engine (:func:`~onlinemap.studies.exploration.planners_study`). Cost: the runs."""
    kinds = world_kinds() if kinds is None else kinds
    seeds = SEEDS if seeds is None else seeds
    recorded = []
    for kind, worlds in kinds.items():
        kind_seeds = [int(seed) for seed in (seeds[kind] if isinstance(seeds, Mapping) else seeds)]
        for world in worlds:
            keep = [(world, planner, seed) for planner in planners for seed in kind_seeds]
            played = planners_study(world, planners, seeds=kind_seeds, steps=steps,
                                    estimator_options={"n_particles": n_particles}, workers=0, progress=progress,
                                    keep=keep).played
            recorded += [Recorded(kind, world, planner, seed, played[world, planner, seed].run,
                                  played[world, planner, seed].trajectory.map[-1]) for _, planner, seed in keep]
    return recorded


def remap_study(recorded: Sequence[Recorded], *, fit_options: Mapping[str, dict] | None = None,
                confidence: float = 0.95, progress: bool = True, methods: Sequence[str] = METHODS) -> Study:
    """Each recorded run remapped by :func:`remap_rows` (``methods``): ``Study(per_run, summary)``, per_run
    one row per (kind, world, planner, seed, method), the summary per (kind, method) with
    intervals. Cost: the fits, per run."""
    rows = []
    for item in tqdm(recorded, desc="remap", disable=not progress):
        for row in remap_rows(item.run, item.filter_map, fit_options, methods):
            rows.append({"kind": item.kind, "world": item.world, "planner": item.planner, "seed": item.seed, **row})
    per_run = pd.DataFrame(rows)
    summary = summary_of(per_run, list(MEASURES), ["kind", "method"], confidence,
                         {"final_map_error": (0.0, 1.0), "confidently_wrong": (0, np.inf), "seconds": (0, np.inf)})
    return Study(per_run, summary)


def hindsight_study(kinds: Mapping[str, Sequence[str]] | None = None, *, planners: Sequence[str] = PLANNERS,
                    seeds: Mapping[str, Sequence[int]] | Sequence[int] | None = None, steps: int = STEPS,
                    n_particles: int = N_PARTICLES, fit_options: Mapping[str, dict] | None = None,
                    confidence: float = 0.95, progress: bool = True) -> Study:
    """:func:`record_runs` then :func:`remap_study` (the arguments theirs). Cost: the module
    docstring's, per run."""
    recorded = record_runs(kinds, planners=planners, seeds=seeds, steps=steps, n_particles=n_particles,
                           progress=progress)
    return remap_study(recorded, fit_options=fit_options, confidence=confidence, progress=progress)


def paired_tests(per_run: pd.DataFrame, pairs: Sequence[tuple[str, str]] = (("layered_em", "flat_em"),
                                                                           ("layered_em_learned", "flat_em"))
                 ) -> pd.DataFrame:
    """For each kind and each ``(a, b)`` of ``pairs``: the runs, the runs where a's map error is
    lower, the mean difference ``a - b`` of final map error, and the one-sided Wilcoxon
    signed-rank p-value of "a's error is lower than b's" on the same runs (scipy.stats), and a's
    mean excess over the told-location map of its prior. O(runs log runs)."""
    from scipy.stats import wilcoxon

    wide = per_run.pivot_table(index=["kind", "world", "planner", "seed"], columns="method",
                               values="final_map_error")
    rows = []
    for kind, table in wide.groupby(level="kind"):
        for a, b in pairs:
            difference = (table[a] - table[b]).to_numpy()
            told = "told_location_learned" if a.endswith("_learned") else "told_location"
            rows.append({"kind": kind, "a": a, "b": b, "runs": len(difference),
                         "a_lower": int(np.sum(difference < 0)), "mean_difference": float(difference.mean()),
                         "wilcoxon_p": float(wilcoxon(difference, alternative="less").pvalue),
                         "excess_over_told": float((table[a] - table[told]).mean())})
    return pd.DataFrame(rows)
