"""Hindsight maps (DESIGN.md section 9): the best map of a recorded run, made after the run with
all its data, compared in one table with the filter's last belief and the told-location map.

Methods (:data:`METHODS`):

- ``flat_em``: Baum-Welch over the whole run (:func:`onlinemap.estimators.offline_em.baum_welch`),
  the map read off the fitted observation matrix: one global map, each reading placed by its own
  step's location posterior;
- ``layered_em``: :func:`onlinemap.layered_em.fit_layered_map`, local maps from stretches of the
  run aligned by EM and assembled at the end;
- ``layered_em_learned_alignment`` (the default): layered EM with the label prior learned (the
  alignment), its map under the model's prior;
- ``rbpf_smoothed``: :func:`smoothed_rbpf_map`, the RBPF replayed over the run and the map given
  each final particle's ancestral path, mixed by the final weights (genealogy smoothing; in a
  static world the filter's own final map, but after a recovery from depletion);
- ``told_location``: the map of a robot told its true path (needs a :class:`~onlinemap.simulate.Run`):
  :func:`onlinemap.evaluate.told_location_map`, and with blocking labels in a static world the
  same with every press's outcome as evidence about the cell pressed into (:func:`told_location`).

Scores (:func:`hindsight_table`): ``final_map_error`` (mean over cells of 1 - P(true label)),
``wrong_cells`` (most probable label wrong) and ``confidently_wrong`` (P(wrong label) > 0.9, i.e.
P(true label) < :data:`CONFIDENTLY_WRONG_BELOW`).
"""

from __future__ import annotations

import math
import time
from typing import Mapping, NamedTuple

import numpy as np
import pandas as pd

from . import metrics
from .errors import InvalidOptionError, ModelError
from .estimators.offline_em import baum_welch
from .estimators.rbpf import RaoBlackwellisedPF
from .evaluate import told_location_map
from .label_prior import fixed_point_frequencies, resolve_label_prior
from .layered_em import fit_layered_map
from .model import GridModel
from .rng import SeedLike
from .simulate import Run

METHODS = ("flat_em", "layered_em", "layered_em_learned_alignment", "rbpf_smoothed", "told_location")
SMOOTHER_PARTICLES = 1000  # rbpf_smoothed's default particle count
IMPOSSIBLE = -1e300  # the log-likelihood of a reading a label cannot give (sums of T of them stay finite)
CONFIDENTLY_WRONG_BELOW = 0.1  # a cell whose true label has less probability is confidently wrong


class HindsightMap(NamedTuple):
    """One hindsight method's map of a run."""

    method: str
    map: np.ndarray  # (N, K) P(m_i = k | the whole run)
    seconds: float  # wall time of the fit
    filtered: np.ndarray | None = None  # (N, K) rbpf_smoothed: the replaying filter's own final map


class SmoothedMap(NamedTuple):
    """:func:`smoothed_rbpf_map`'s result."""

    map: np.ndarray  # (N, K) the mixture over the final particles' ancestral paths of the map given each
    filtered: np.ndarray  # (N, K) the same filter's final map (its belief after the last step)
    distinct_paths: int  # distinct ancestral paths among the final live particles (D)
    live_particles: int  # final particles with nonzero weight
    common_steps: int  # steps 0..common_steps - 1 on which every live path agrees (the genealogy's collapse)
    lineages: np.ndarray  # (T,) distinct ancestors of the final live particles at each step (1 where collapsed)
    recoveries: int  # the filter's steps that recovered from depletion


def _resolved(model: GridModel, label_prior, prior_strength):
    """The label prior a map of ``model`` is made under (:func:`~onlinemap.label_prior.resolve_label_prior`):
    ``label_prior=None`` follows the model, as the filters do: learned where the model says its
    label frequencies are unknown (generated buildings, read floors) and the world is static."""
    return resolve_label_prior(model.n_labels, label_prior, prior_strength,
                               model_learns=model.learns_label_frequencies)


def told_location(model: GridModel, run: Run, label_prior=None, prior_strength=None) -> np.ndarray:
    """(N, K) the told-location map of ``run``: :func:`~onlinemap.evaluate.told_location_map`,
    and with blocking labels or a learned prior (static worlds) :func:`path_map` of the true
    path; ``label_prior=None`` follows the model (learned on buildings and read floors). Raises
    ModelError for blocking labels or a learned prior in a dynamic world. O(T F K + iterations N K)."""
    prior = _resolved(model, label_prior, prior_strength)
    if prior.kind == "model" and not model.has_blocking:
        return told_location_map(model, run)
    return path_map(model, run.locations, run.actions, run.observations, label_prior, prior_strength)


def path_map(model: GridModel, locations, actions, observations, label_prior=None,
             prior_strength=None) -> np.ndarray:
    """(N, K) the exact map of a static world given the path ``locations`` (T,), the ``actions``
    (T - 1,) and ``observations`` (T,) or (T, F): the cells are independent given the path, each
    ``prior x prod O(k, z)`` over its readings times, with blocking labels, every press's outcome,
    ``P(moved | m_j) = p_move [m_j passable]`` and ``P(stayed | m_j) = 1 - p_move [m_j
    passable]`` for the cell j pressed into (a known failed press is evidence about the cell not
    entered; a step that neither stays nor reaches the cell pressed into, a relocation of the
    RBPF's recovery from depletion, says nothing). ``label_prior="learn"``
    (:mod:`onlinemap.label_prior`): the cells' prior is the label frequencies theta, the fixed
    point of theta = the Dirichlet posterior mean given the expected labels of the cells read
    (iterated until it moves less than 1e-12), as layered EM learns them. Raises ModelError in a
    dynamic world. O(T F K + iterations N K)."""
    prior = _resolved(model, label_prior, prior_strength)
    if not model.is_static:
        raise ModelError("the map given a path (the told-location map with blocking labels or a learned prior, the "
                         "smoothed RBPF map) is computed for static worlds only")
    with np.errstate(divide="ignore"):
        start = 0.0 if prior.kind == "learn" else \
            np.log(model.label_prior if prior.kind == "model" else prior.frequencies)
    counts, log_evidence = _path_evidence(model, _path_steps(model, locations, actions, observations), start)
    if prior.kind != "learn":
        return _normalised_rows(log_evidence)
    theta = fixed_point_frequencies(prior.alpha, log_evidence, np.minimum(counts.sum(axis=1), 1.0))
    return _normalised_rows(np.log(theta) + log_evidence)


def smoothed_rbpf_map(model: GridModel, actions, observations, *, n_particles: int = SMOOTHER_PARTICLES,
                      seed: SeedLike = 0, label_prior=None, prior_strength=None, **rbpf_options) -> SmoothedMap:
    """The RBPF's genealogy smoother: replay ``actions`` (T - 1,) and ``observations`` (T,) or
    (T, F) through :class:`~onlinemap.estimators.rbpf.RaoBlackwellisedPF` (``n_particles``,
    ``seed``, ``label_prior``, ``prior_strength`` and ``rbpf_options``; recording every step's
    locations and :meth:`~onlinemap.estimators.rbpf.RaoBlackwellisedPF.update_with_ancestors`),
    follow each final live particle's ancestors back to step 0, and mix the exact map given each
    distinct path x^d (:func:`path_map`, the same prior) by the summed final weights W_d::

        P(m_i = k | z_{0:T})  ~=  sum_d W_d P(m_i = k | x^d_{0:T}, a, z_{0:T})

    In a static world each particle's filtered map already is the exact map given its path, so
    with the model's or a fixed prior and no recovery from depletion this equals the filter's
    final map (up to rounding): the genealogy adds no path the filter did not weigh. It differs
    where the filter's map is not the map given the path: a recovery reset read cells to their
    prior (here every reading counts), and ``label_prior="learn"`` (the filter's plug-in
    frequencies learned along the run, here each path's own fixed point). ``distinct_paths``,
    ``common_steps`` and ``lineages`` measure the genealogy's degeneracy. Raises ModelError in a
    dynamic world and InvalidOptionError for ``move_window`` (a move redraws past locations the
    genealogy does not record) or ``label_prior="context"`` (the filter's alone: a path's map has
    no population to learn contexts from), before the replay. Cost: the replay O(T P F K^2), the
    genealogy O(T P log P) time and 16 T P bytes, the distinct paths O(T P log P), the maps
    O(D (T F K + iterations N K)) for D distinct paths."""
    if not model.is_static:
        raise ModelError("rbpf_smoothed needs a static world: in a dynamic one the final map is the filter's own "
                         "(the cells' chains end at the last step)")
    if rbpf_options.get("move_window") is not None:
        raise InvalidOptionError("rbpf_smoothed does not take move_window: the resample-move step redraws past "
                                 "locations, which the genealogy (each step's ancestors) does not record")
    _resolved(model, label_prior, prior_strength)  # the paths' maps take the filter's prior: refuse before the replay
    observations = np.asarray(observations)
    steps = len(observations)
    filter_ = RaoBlackwellisedPF(model, n_particles=n_particles, seed=seed, label_prior=label_prior,
                                 prior_strength=prior_strength, **rbpf_options)
    locations = np.empty((steps, n_particles), dtype=np.int32)
    ancestors = np.empty((steps, n_particles), dtype=np.int32)
    for t in range(steps):
        ancestors[t] = filter_.update_with_ancestors(None if t == 0 else actions[t - 1], observations[t])
        locations[t] = filter_.particles
    weights = filter_.weights
    slots = np.flatnonzero(weights > 0)
    paths = np.empty((len(slots), steps), dtype=np.int64)
    lineages = np.empty(steps, dtype=np.int64)
    for t in range(steps - 1, -1, -1):
        paths[:, t] = locations[t, slots]
        lineages[t] = len(np.unique(slots))
        slots = ancestors[t, slots]
    distinct, which = np.unique(paths, axis=0, return_inverse=True)
    path_weights = np.bincount(which.ravel(), weights=weights[weights > 0], minlength=len(distinct))
    belief = np.zeros((model.n_cells, model.n_labels))
    for path, weight in zip(distinct, path_weights):
        belief += weight * path_map(model, path, actions, observations, label_prior, prior_strength)
    agree = np.all(paths == paths[0], axis=0)
    common = steps if agree.all() else int(np.argmin(agree))
    return SmoothedMap(belief / belief.sum(axis=1, keepdims=True), filter_.belief.map, len(distinct), len(paths),
                       common, lineages, filter_.recoveries)


class _PathSteps(NamedTuple):
    """A path's steps as :func:`_path_evidence` and :func:`path_log_likelihood` read them."""

    cells: np.ndarray  # (T, F) the cells read at each step (-1 off the grid)
    readings: np.ndarray  # (T, F) the readings
    here: np.ndarray  # (T - 1,) the cell each action starts from
    there: np.ndarray  # (T - 1,) the cell it ends in
    target: np.ndarray  # (T - 1,) the cell it presses into (``here`` at the grid's edge)


def _path_steps(model: GridModel, locations, actions, observations) -> _PathSteps:
    """The footprint cells, readings and presses of a path: locations (T,), actions (T - 1,),
    observations (T,) or (T, F). O(T F)."""
    locations = np.asarray(locations)
    cells = model.footprint_cells[locations]
    here = locations[:-1]
    return _PathSteps(cells, np.asarray(observations).reshape(cells.shape), here, locations[1:],
                      model.neighbors[here, actions])


def _path_evidence(model: GridModel, steps: _PathSteps, start) -> tuple[np.ndarray, np.ndarray]:
    """(counts (N, K) of each cell's readings, log evidence (N, K)) of a path (:func:`_path_steps`):
    ``start`` (a log prior, (N, K), (K,) or 0.0) plus, per cell and label k, ``sum_z count(z) log O(k, z)``
    (a reading a label cannot give: the finite penalty ``IMPOSSIBLE``) and, with blocking labels,
    every press's outcome, ``log(p_move [k passable])`` entered and ``log(1 - p_move [k passable])``
    stayed (``GridModel.press_likelihood``). O(T F K)."""
    n, k = model.n_cells, model.n_labels
    cells, readings, here, there, target = steps
    read = (cells >= 0) & (readings >= 0)
    counts = np.bincount((cells * k + readings)[read], minlength=n * k).reshape(n, k)
    presses = target != here
    entered = np.bincount(target[presses & (there == target)], minlength=n) if model.has_blocking \
        else np.zeros(n)
    bumped = np.bincount(target[presses & (there == here)], minlength=n) if model.has_blocking \
        else np.zeros(n)
    with np.errstate(divide="ignore", invalid="ignore"):
        # a reading a label cannot give: a huge finite penalty (not -inf, which 0 counts would turn into NaN)
        log_evidence = start + counts @ np.maximum(np.log(model.sensor), IMPOSSIBLE).T
        # 0 * log 0 is no evidence, not NaN: a count of zero leaves the label alone
        # P(entered | m_j) with the constant p_move the table leaves out: a cell's map normalises it away, and
        # with it the maps keep their bits (those of the stored notebooks)
        log_entered = np.log(model.p_move * model.press_likelihood[0])
        log_stayed = np.log(model.press_likelihood[1])
        log_evidence += np.where(entered[:, None] > 0, entered[:, None] * log_entered, 0.0)
        log_evidence += np.where(bumped[:, None] > 0, bumped[:, None] * log_stayed, 0.0)
    return counts, log_evidence


def path_log_likelihood(model: GridModel, locations, actions, observations, frequencies=None) -> float:
    """``log P(x_{0:T}, z_{0:T} | a_{1:T})`` of a static world, the map summed out: how well the
    path ``locations`` (T,) explains the ``actions`` (T - 1,) and ``observations`` (T,) or (T, F)
    under the model with independent labels, each cell's prior ``frequencies`` (K,) (None: the
    model's ``label_prior``)::

        log P(x_0) + sum_t log T0(x_t | x_{t-1}, a_t) + sum_c log sum_k prior(k) prod_{e at c} f_e(k)

    over the events e of cell c (its readings ``O(k, z)``; with blocking labels, the presses into it,
    ``p_move [k passable]`` entered and ``1 - p_move [k passable]`` stayed); ``T0`` is the motion
    where it does not depend on the map (``p_move`` / ``1 - p_move`` for a move that could go, 1 at
    the grid's edge). -inf for a path the model rules out: a step that is neither the cell pressed
    into nor a stay, readings off the grid that do not fit the cell. Compares paths: the true path
    against a filter's (a filter that lost a path the model prefers, or a model that prefers a
    wrong one). Raises ModelError in a dynamic world. O(T F K + N K)."""
    if not model.is_static:
        raise ModelError("path_log_likelihood sums the map out of a static world only")
    locations = np.asarray(locations)
    if frequencies is None:
        theta = np.asarray(model.label_prior, dtype=float)
    else:
        theta = np.asarray(frequencies, dtype=float)
        if theta.shape != (model.n_labels,) or not np.isfinite(theta).all() or (theta < 0).any() or theta.sum() <= 0:
            raise InvalidOptionError(f"frequencies must be {model.n_labels} finite non-negative numbers with a positive "
                                     f"sum (one per label), got {frequencies!r}")
    theta = theta / theta.sum(axis=-1, keepdims=True)
    steps = _path_steps(model, locations, actions, observations)
    cells, readings, here, there, target = steps
    if np.any((there != here) & (there != target)) or np.any((cells < 0) != (readings < 0)):
        return -math.inf
    with np.errstate(divide="ignore"):
        _, log_evidence = _path_evidence(model, steps, np.log(theta))
        log_start = math.log(model.location_prior()[locations[0]])
    pressed = target != here
    motion = 0.0 if model.has_blocking else \
        int((pressed & (there == target)).sum()) * math.log(model.p_move) + \
        int((pressed & (there == here)).sum()) * math.log1p(-model.p_move)
    top = log_evidence.max(axis=1, keepdims=True)  # log sum_k exp, row by row
    return log_start + motion + float((top[:, 0] + np.log(np.exp(log_evidence - top).sum(axis=1))).sum())


def _normalised_rows(log_belief: np.ndarray) -> np.ndarray:
    """Rows of exp(log_belief) normalised. (N, K) -> (N, K)."""
    log_belief = log_belief - log_belief.max(axis=1, keepdims=True)
    belief = np.exp(log_belief)
    return belief / belief.sum(axis=1, keepdims=True)


def _data(run_or_data) -> tuple[np.ndarray, np.ndarray, Run | None]:
    if isinstance(run_or_data, Run):
        return run_or_data.actions, run_or_data.observations, run_or_data
    if isinstance(run_or_data, tuple) and len(run_or_data) == 2:
        return run_or_data[0], run_or_data[1], None
    raise InvalidOptionError(f"run_or_data must be a Run or (actions, observations), got {type(run_or_data).__name__}")


def hindsight_map(model: GridModel, run_or_data, method: str = "layered_em_learned_alignment",
                  **options) -> HindsightMap:
    """The map of a recorded run by ``method`` (:data:`METHODS`), ``run_or_data`` a
    :class:`~onlinemap.simulate.Run` or ``(actions (T - 1,), observations (T,) or (T, F))``;
    ``options`` go to the fitter (``baum_welch`` for flat_em, ``fit_layered_map`` for layered_em
    and layered_em_learned_alignment, :func:`smoothed_rbpf_map` for rbpf_smoothed).
    ``layered_em_learned_alignment`` (the default): layered EM with ``label_prior="learn"`` (the
    robot aligned with the learned label statistics), its map under the model's prior
    (:meth:`~onlinemap.layered_em.LayeredMap.map_with_prior`): measured lower final map error
    than ``layered_em`` on 18 of 20 400-step runs in 32 x 32 buildings (Wilcoxon one-sided p =
    0.001) and 16 of 20 on the real floors of ``tests/data/floors`` (p = 0.0004), with the study
    :mod:`onlinemap.studies.hindsight`. ``rbpf_smoothed``: the result's
    ``filtered`` is the replaying filter's final map. Raises InvalidOptionError for an unknown
    method, or told_location without a Run. Cost: the method's (flat EM O(iterations T (N F +
    E)), layered EM its module's, rbpf_smoothed :func:`smoothed_rbpf_map`'s, told-location O(T F K))."""
    actions, observations, run = _data(run_or_data)
    if method not in METHODS:
        raise InvalidOptionError(f"unknown hindsight method {method!r}; expected one of {METHODS}")
    started = time.perf_counter()
    filtered = None
    if method == "flat_em":
        belief = baum_welch(model, actions, observations, **options).map
    elif method == "layered_em":
        belief = fit_layered_map(model, actions, observations, **options).map
    elif method == "layered_em_learned_alignment":
        if "label_prior" in options:
            raise InvalidOptionError("layered_em_learned_alignment learns the label prior: it takes no label_prior")
        fit = fit_layered_map(model, actions, observations, label_prior="learn", **options)
        belief = fit.map_with_prior(model.label_prior)
    elif method == "rbpf_smoothed":
        smoothed = smoothed_rbpf_map(model, actions, observations, **options)
        belief, filtered = smoothed.map, smoothed.filtered
    else:
        if run is None:
            raise InvalidOptionError("told_location needs the true path: pass a Run, not (actions, observations)")
        unknown = set(options) - {"label_prior", "prior_strength"}
        if unknown:
            raise InvalidOptionError(f"told_location takes label_prior and prior_strength only, got {sorted(unknown)}")
        belief = told_location(model, run, **options)
    return HindsightMap(method, belief, time.perf_counter() - started, filtered)


def hindsight_table(true_map: np.ndarray, maps: Mapping[str, np.ndarray],
                    seconds: Mapping[str, float] | None = None) -> pd.DataFrame:
    """One row per map (name -> (N, K) belief) scored against the true labels (N,): ``method``,
    ``final_map_error``, ``wrong_cells``, ``confidently_wrong`` and, where given, ``seconds``.
    O(N K) per map."""
    true_map = np.asarray(true_map)
    rows = []
    for name, belief in maps.items():
        p_true = np.asarray(belief)[np.arange(len(true_map)), true_map]
        rows.append({"method": name, "final_map_error": float(metrics.map_error(belief, true_map)),
                     "wrong_cells": int(np.sum(np.argmax(belief, axis=1) != true_map)),
                     "confidently_wrong": int(np.sum(p_true < CONFIDENTLY_WRONG_BELOW)),
                     "seconds": float((seconds or {}).get(name, np.nan))})
    return pd.DataFrame(rows)


def compare_hindsight(run: Run, filter_map: np.ndarray | None = None, methods=("flat_em", "layered_em"),
                      options: Mapping[str, dict] | None = None) -> pd.DataFrame:
    """Remap ``run`` by each of ``methods`` and score them with the filter's final map
    (``filter_map`` (N, K), row ``filter``, if given) and the told-location map (row
    ``told_location``; left out where it is not defined, blocking labels in a dynamic world):
    :func:`hindsight_table` against the run's final true labels; ``rbpf_smoothed`` adds the row
    ``rbpf_filtered``, its replaying filter's final map. Cost: the methods' fits."""
    options = options or {}
    maps, seconds = {}, {}
    if filter_map is not None:
        maps["filter"] = np.asarray(filter_map)
    for method in methods:
        fit = hindsight_map(run.model, run, method, **options.get(method, {}))
        if fit.filtered is not None:
            maps["rbpf_filtered"] = fit.filtered
        maps[method], seconds[method] = fit.map, fit.seconds
    if "told_location" not in maps and (run.model.is_static or not run.model.has_blocking):
        fit = hindsight_map(run.model, run, "told_location")
        maps["told_location"], seconds["told_location"] = fit.map, fit.seconds
    return hindsight_table(run.final_map, maps, seconds)
