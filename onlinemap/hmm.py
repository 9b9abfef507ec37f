"""The location HMM of the EM estimators (DESIGN.md section 3, ``online_em`` and ``offline_em``).

EM treats the map as a parameter, the observation matrix ``B[i, k] = P(Z = k | L = i)`` (N, K);
only the location is hidden. Transitions are the model's known, sparse, action-dependent
motion ``T[a]`` (never a dense N x N matrix). This module holds the pieces both EM estimators
share: forward-backward over a stretch of steps (numba; its forward pass alone for
:func:`onlinemap.run_facts.told_map_location`), expected sufficient statistics, the
M-step, the map read off ``B`` through the sensor channel, and posterior tempering
(deterministic annealing).

A sensor footprint (DESIGN.md section 7, the textbook's grid EM): ``B[c, k]`` is the probability
of reading k when cell c is read, an observation is F readings and its probability at location
l is ``prod_f B[c_f(l), z_f]`` (0 where the -1 readings do not fit l); the M-step stays a count
per cell (:func:`expected_cell_counts`). Blocking labels: the E-step moves into cell j with
``p_move P(m_j passable)`` under the map read off the current B (``passable``), a generalised
EM step: the objective is no longer guaranteed to rise, and bumps teach the M-step nothing.

Costs: W steps, N cells, E motion edges (E <= 2 N for every grid here), K labels, F readings.
``forward_backward`` and ``forward_filter`` (its forward pass alone) O(W (N F + E));
``expected_counts`` O(W N F); ``emission_from_counts`` and ``map_from_emission`` O(N K^2).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .arrays import cached_by_content, frozen
from .errors import ImpossibleObservationError
from .kernels.forward_backward import accumulate_counts, forward_backward_pass, forward_pass
from .model import GridModel


class HMMPosterior(NamedTuple):
    """Forward-backward over W steps with one observation matrix."""

    filtered: np.ndarray  # (W, N) P(L_tau | z_first..tau)
    posterior: np.ndarray  # (W, N) P(L_tau | z_first..last), smoothed
    log_normalizers: np.ndarray  # (W,) log P(z_tau | z_first..tau-1)

    @property
    def log_likelihood(self) -> float:
        """``log P(z_first..last | prior, a, B)``."""
        return float(self.log_normalizers.sum())


class HMMFilter(NamedTuple):
    """The forward pass alone over W steps with one observation matrix (:func:`forward_filter`):
    :class:`HMMPosterior` without the smoothed rows, the same bits."""

    filtered: np.ndarray  # (W, N) P(L_tau | z_first..tau)
    log_normalizers: np.ndarray  # (W,) log P(z_tau | z_first..tau-1); their sum is log P(z_first..last)


class _PassInputs(NamedTuple):
    """The kernels' inputs in one form (:func:`~onlinemap.arrays.frozen`, no copy where already
    C-contiguous), whatever the caller passed (the model's read-only tables, a transposed or
    learned matrix): numba compiles each pass once."""

    self_prob: np.ndarray  # (A, N) P(stay | a, j)
    predecessor: np.ndarray  # (A, N)
    neighbors: np.ndarray  # (N, A)
    enter: np.ndarray  # (N,) P(a move into j succeeds)
    prior: np.ndarray  # (N,)
    actions: np.ndarray  # (W - 1,)
    observations: np.ndarray  # (W,) the column of ``emission`` each step reads
    emission: np.ndarray  # (N, K), or (N, W) with a footprint


def _pass_inputs(model: GridModel, prior: np.ndarray, actions: np.ndarray, observations: np.ndarray,
                 emission: np.ndarray, passable: np.ndarray | None) -> _PassInputs:
    """The motion tables under ``passable`` and the emission in the kernels' form (observations
    (W,) or (W, F) int64). O(N A), plus O(W N F) with a footprint."""
    n = model.n_cells
    if passable is None:
        self_prob, enter = model.self_prob, np.full(n, model.p_move)
    else:
        enter = model.p_move * np.asarray(passable, dtype=np.float64)
        movers = model.neighbors != np.arange(n)[:, None]  # (N, A)
        self_prob = np.ascontiguousarray(np.where(movers, 1.0 - enter[model.neighbors], 1.0).T)
    if not model.reads_own_cell:  # the kernel reads emission[j, observations[t]]: give it (N, W) and 0..W-1
        kernel_emission = np.ascontiguousarray(footprint_emission(model, emission, observations).T)
        kernel_observations = np.arange(len(observations), dtype=np.int64)
    else:
        kernel_emission = np.asarray(emission, dtype=np.float64)
        kernel_observations = observations
    return _PassInputs(*map(frozen, (self_prob, model.predecessor, model.neighbors, enter,
                                     np.asarray(prior, dtype=np.float64), np.asarray(actions, dtype=np.int64),
                                     kernel_observations, kernel_emission)))


def _log_normalizers(model: GridModel, observations: np.ndarray, first_step: int, bad: int,
                     normalizers: np.ndarray, log_scales: np.ndarray) -> None:
    """After a pass: raise :class:`ImpossibleObservationError` if step ``bad`` >= 0 has
    probability zero, else turn ``normalizers`` into ``log P(z_tau | z_first..tau-1)`` in place. O(W)."""
    if bad >= 0:
        label = model.label_names[observations[bad]] if model.reads_own_cell else observations[bad].tolist()
        raise ImpossibleObservationError(
            f"observation {label!r} at step {first_step + bad} has probability zero under the observation "
            f"matrix B in use (B starts as label_prior @ O; a learned B has no zeros when pseudo_count > 0)")
    np.log(normalizers, out=normalizers)
    normalizers += log_scales


def forward_filter(model: GridModel, prior: np.ndarray, actions: np.ndarray, observations: np.ndarray,
                   emission: np.ndarray, first_step: int = 0, passable: np.ndarray | None = None) -> HMMFilter:
    """Filter the location over W steps under observation matrix ``emission``: the forward half
    of :func:`forward_backward` (the same arguments but ``out``, the same bits in ``filtered`` and
    ``log_normalizers``), without the backward pass and its (W, N) array. Raises
    :class:`ImpossibleObservationError` if an observation has probability zero. O(W (N F + E))
    time, W N floats of memory (2 W N with a footprint)."""
    observations = np.asarray(observations, dtype=np.int64)
    w = len(observations)
    inputs = _pass_inputs(model, prior, actions, observations, emission, passable)
    filtered, normalizers, log_scales = np.empty((w, model.n_cells)), np.empty(w), np.empty(w)
    bad = forward_pass(inputs.self_prob, inputs.predecessor, inputs.enter, inputs.prior, inputs.actions,
                       inputs.observations, inputs.emission, filtered, normalizers, log_scales)
    _log_normalizers(model, observations, first_step, bad, normalizers, log_scales)
    return HMMFilter(filtered, normalizers)


def forward_backward(model: GridModel, prior: np.ndarray, actions: np.ndarray, observations: np.ndarray,
                     emission: np.ndarray, first_step: int = 0, out: HMMPosterior | None = None,
                     passable: np.ndarray | None = None) -> HMMPosterior:
    """Filter and smooth the location over W steps under observation matrix ``emission``.

    prior (N,): P(L) at the first step before its observation; actions (W - 1,) int, the moves
    between consecutive steps; observations (W,) int; emission (N, K). ``first_step`` only
    labels error messages. ``out``, a previous result of the same shape, has its arrays
    overwritten instead of allocating new ones (iterating EM over long runs: fresh large arrays
    cost a page fault per 4 kB on first touch). Raises :class:`ImpossibleObservationError` if an
    observation has probability zero. With a footprint, observations are (W, F) readings; with
    blocking labels, ``passable`` (N,) is the probability that each cell can be entered (None:
    every cell). One kernel runs :func:`forward_filter`'s forward pass, then the backward pass.
    O(W (N F + E)) time, 3 W N floats of memory (4 W N with a footprint).
    """
    observations = np.asarray(observations, dtype=np.int64)
    w, n = len(observations), model.n_cells
    inputs = _pass_inputs(model, prior, actions, observations, emission, passable)
    if out is not None and out.filtered.shape == (w, n):
        filtered, posterior, normalizers = out.filtered, out.posterior, out.log_normalizers
    else:
        filtered, posterior, normalizers = np.empty((w, n)), np.empty((w, n)), np.empty(w)
    log_scales = np.empty(w)  # 0 but where a step was rescaled against underflow
    bad = forward_backward_pass(*inputs, filtered, posterior, normalizers, log_scales)
    _log_normalizers(model, observations, first_step, bad, normalizers, log_scales)
    return HMMPosterior(filtered, posterior, normalizers)


def expected_counts(posterior: np.ndarray, observations: np.ndarray, n_labels: int) -> np.ndarray:
    """Expected sufficient statistics ``E[i, k] = sum_tau P(L_tau = i | z) [z_tau = k]``.
    posterior (W, N), observations (W,) -> (N, K). One pass over the posterior (numba): O(W N)."""
    counts = np.zeros((posterior.shape[1], n_labels))
    accumulate_counts(np.ascontiguousarray(posterior), np.ascontiguousarray(observations, dtype=np.int64), counts)
    return counts


def footprint_emission(model: GridModel, emission: np.ndarray, observations: np.ndarray) -> np.ndarray:
    """(W, N) ``P(z_t | L = l; B) = prod_f B[c_f(l), z_tf]``, 0 where the -1 readings of z_t are
    not exactly l's off-grid offsets. emission (N, K), observations (W, F) or (W,). O(W N F).

    Fast on long stretches (a 2000-step told-map anchor on 32 x 32): the off-grid masks of the
    steps and of the locations are compared as one id each, and each offset gathers whole rows of
    ``B.T`` with a column of ones for the cells off the grid (times 1: the same bits)."""
    readings = np.asarray(observations, dtype=np.int64).reshape(len(observations), -1)
    cells = model.footprint_cells
    n = len(cells)
    _, mask_id = np.unique(np.concatenate([cells < 0, readings < 0]), axis=0, return_inverse=True)
    mask_id = mask_id.ravel()
    out = (mask_id[n:, None] == mask_id[None, :n]).astype(np.float64)  # (W, N): the masks fit
    table = np.ones((emission.shape[1], n + 1))  # (K, N + 1) row z: B[:, z], then 1 for an off-grid offset
    table[:, :n] = emission.T
    for f in range(cells.shape[1]):
        column = np.where(cells[:, f] >= 0, cells[:, f], n)
        z = np.where(readings[:, f] < 0, 0, readings[:, f])
        out *= table[:, column][z]
    return out


def expected_cell_counts(model: GridModel, posterior: np.ndarray, observations: np.ndarray) -> np.ndarray:
    """The M-step's statistics per cell, ``E[c, k] = sum_t sum_{l, f: c_f(l) = c} P(L_t = l | z)
    [z_tf = k]`` (N, K): :func:`expected_counts` for the paper's sensor, a count over every
    footprint reading otherwise. posterior (W, N), observations (W,) or (W, F). O(W N F)."""
    if model.reads_own_cell:
        return expected_counts(posterior, observations, model.n_labels)
    n, k = model.n_cells, model.n_labels
    readings = np.asarray(observations, dtype=np.int64).reshape(len(observations), -1)
    counts = np.zeros(n * k)
    for f in range(model.n_readings):
        cells = model.footprint_cells[:, f]
        on = cells >= 0
        z = readings[:, f]
        seen = z >= 0
        index = cells[on][None, :] * k + z[seen][:, None]  # (W', N') flat (cell, label)
        counts += np.bincount(index.ravel(), weights=posterior[np.ix_(seen, on)].ravel(), minlength=n * k)
    return counts.reshape(n, k)


def append_observation(observations: np.ndarray, z) -> np.ndarray:
    """A fresh (W + 1,) or (W + 1, F) int64 array: the stored observations and z appended."""
    if observations.ndim == 1:
        return np.append(observations, z)
    return np.concatenate([observations, np.asarray(z, dtype=np.int64)[None]])


PASSABLE_FLOOR = 1e-3  # the least passability the EM E-step gives a cell (see map_passability)


def map_passability(model: GridModel, emission: np.ndarray, inverse: np.ndarray) -> np.ndarray | None:
    """(N,) P(cell passable) under the map read off B (:func:`map_from_emission`), at least
    :data:`PASSABLE_FLOOR`: the clipped channel inversion can put a cell's passability at exactly
    0, and a run that then enters the cell would have probability zero. None without blocking
    labels. O(N K^2)."""
    if not model.has_blocking:
        return None
    passable = map_from_emission(emission, inverse) @ (~model.blocking).astype(np.float64)
    return np.maximum(passable, PASSABLE_FLOOR)


def emission_from_counts(counts: np.ndarray, pseudo_count: float, fallback: np.ndarray) -> np.ndarray:
    """M-step: ``B[i] = (S[i] + c) / (sum_k S[i, k] + K c)``, the MAP estimate under a symmetric
    Dirichlet(c + 1) prior per row. A row with no statistics at all (only possible when c = 0)
    takes the ``fallback`` row. counts, fallback (N, K) -> (N, K). Every EM step and iteration
    calls it on small tables: when every row has statistics (always when c > 0), one reduction
    says so and the rows are divided at once (a third of the cost of masking empty rows)."""
    smoothed = counts + pseudo_count
    totals = smoothed.sum(axis=1, keepdims=True)
    if totals.min() > 0:  # no empty row (False for a NaN: the masks below then leave the row as it is)
        return smoothed / totals
    empty = totals[:, 0] <= 0
    totals[empty] = 1.0
    emission = smoothed / totals
    emission[empty] = fallback[empty]
    return emission


def prior_emission(model: GridModel) -> np.ndarray:
    """The observation matrix implied by the label prior: ``B0 = label_prior @ O``, (N, K)."""
    return model.label_prior @ model.sensor


@cached_by_content
def sensor_inverse(sensor: np.ndarray) -> np.ndarray:
    """(K, K) pseudo-inverse of the sensor O (its inverse when O is invertible; least squares
    when it is singular, e.g. p_obs = 1/K), for :func:`map_from_emission`; read-only, computed
    once per distinct O (bit for bit: an SVD, about 0.2 ms, that every EM estimator built needs)
    and shared (:func:`~onlinemap.arrays.cached_by_content`). O(K^3) the first time."""
    return np.linalg.pinv(sensor)


def map_from_emission(emission: np.ndarray, inverse: np.ndarray) -> np.ndarray:
    """Map marginals read off B by inverting the sensor channel: ``m = B O^+`` row by row
    (``inverse`` = :func:`sensor_inverse` of O), clipped to [0, 1], rows renormalised (a row
    clipped to all zeros becomes uniform). (N, K), (K, K) -> (N, K). O(N K^2). Every EM step
    calls it on small tables, so the usual case (no row clipped to zeros) takes one reduction
    to check, not a mask."""
    maps = (emission @ inverse).clip(0.0, 1.0)
    totals = maps.sum(axis=1, keepdims=True)
    if not totals.min() > 0:  # some row clipped to all zeros (or a NaN, which the mask leaves as it is)
        empty = totals[:, 0] <= 0
        maps[empty], totals[empty] = 1.0, maps.shape[1]
    return maps / totals


def temper(posterior: np.ndarray, tau: float) -> np.ndarray:
    """Deterministic annealing of per-step posteriors: ``p^(1/tau)`` renormalised over the last
    axis (tau = 1: unchanged; tau -> 0: the one-hot argmax). (..., N) -> (..., N)."""
    if tau == 1.0:
        return posterior
    scaled = posterior / posterior.max(axis=-1, keepdims=True)
    powered = scaled ** (1.0 / tau)
    return powered / powered.sum(axis=-1, keepdims=True)


def log_dirichlet_prior(emission: np.ndarray, pseudo_count: float) -> float:
    """The pseudo-count prior's log density up to a constant, ``c sum_ik log B[i, k]`` (0 when
    c = 0; -inf when c > 0 and B has a zero, e.g. a starting B from a prior with zeros)."""
    if pseudo_count == 0:
        return 0.0
    with np.errstate(divide="ignore"):
        return float(pseudo_count * np.log(emission).sum())

