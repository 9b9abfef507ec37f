"""The location HMM of the EM estimators (DESIGN.md section 3, ``online_em`` and ``offline_em``).

EM treats the map as a parameter, the observation matrix ``B[i, k] = P(Z = k | L = i)`` (N, K);
only the location is hidden. Transitions are the model's known, sparse, action-dependent
motion ``T[a]`` (never a dense N x N matrix). This module holds the pieces both EM estimators
share: forward-backward over a stretch of steps (numba), expected sufficient statistics, the
M-step, the map read off ``B`` through the sensor channel, and posterior tempering
(deterministic annealing).

Costs: W steps, N cells, E motion edges (E <= 2 N for every grid here), K labels.
``forward_backward`` O(W (N + E)); ``expected_counts`` O(W N); ``emission_from_counts`` and
``map_from_emission`` O(N K^2).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from .errors import ImpossibleObservationError
from .model import GridModel


_TINY = 1e-280  # messages below this are set to 0: subnormal floats would make every pass ~10x slower


@njit(cache=True)
def _forward_backward(self_prob, predecessor, neighbors, p_move, prior, actions, observations, emission,
                      filtered, posterior, normalizers):
    """Scaled forward-backward on the sparse motion model.

    self_prob (A, N), predecessor (A, N), neighbors (N, A): the model's motion tables; prior (N,)
    the distribution of the first step's location before its observation; actions (W - 1,);
    observations (W,); emission (N, K) B. Writes filtered (W, N) ``P(L_tau | z_0..tau)``, posterior
    (W, N) ``P(L_tau | z_0..W-1)`` and normalizers (W,) ``P(z_tau | z_0..tau-1)``. Returns the
    index of the first step whose observation has probability zero, or -1. O(W (N + E)).
    Forward and backward messages below ``_TINY`` (relative to rows summing to 1) are set to 0.
    """
    w, n = filtered.shape
    for t in range(w):
        z = observations[t]
        total = 0.0
        if t == 0:
            for j in range(n):
                v = prior[j] * emission[j, z]
                filtered[0, j] = v
                total += v
        else:
            a = actions[t - 1]
            for j in range(n):
                v = self_prob[a, j] * filtered[t - 1, j]
                p = predecessor[a, j]
                if p >= 0:
                    v += p_move * filtered[t - 1, p]
                v *= emission[j, z]
                if v < _TINY:
                    v = 0.0
                filtered[t, j] = v
                total += v
        if not total > 0.0:
            return t
        normalizers[t] = total
        inverse = 1.0 / total
        for j in range(n):
            filtered[t, j] *= inverse
    beta = np.ones(n)
    scaled = np.empty(n)
    for j in range(n):
        posterior[w - 1, j] = filtered[w - 1, j]
    for t in range(w - 1, 0, -1):
        a = actions[t - 1]
        z = observations[t]
        inverse = 1.0 / normalizers[t]
        for j in range(n):
            scaled[j] = beta[j] * emission[j, z] * inverse
        total = 0.0
        for i in range(n):
            v = self_prob[a, i] * scaled[i]
            nb = neighbors[i, a]
            if nb != i:
                v += p_move * scaled[nb]
            if v < _TINY:
                v = 0.0
            beta[i] = v
            v *= filtered[t - 1, i]
            posterior[t - 1, i] = v
            total += v
        inverse = 1.0 / total
        for i in range(n):
            posterior[t - 1, i] *= inverse
    return -1


class HMMPosterior(NamedTuple):
    """Forward-backward over W steps with one observation matrix."""

    filtered: np.ndarray  # (W, N) P(L_tau | z_first..tau)
    posterior: np.ndarray  # (W, N) P(L_tau | z_first..last), smoothed
    log_normalizers: np.ndarray  # (W,) log P(z_tau | z_first..tau-1)

    @property
    def log_likelihood(self) -> float:
        """``log P(z_first..last | prior, a, B)``."""
        return float(self.log_normalizers.sum())


def forward_backward(model: GridModel, prior: np.ndarray, actions: np.ndarray, observations: np.ndarray,
                     emission: np.ndarray, first_step: int = 0, out: HMMPosterior | None = None) -> HMMPosterior:
    """Filter and smooth the location over W steps under observation matrix ``emission``.

    prior (N,): P(L) at the first step before its observation; actions (W - 1,) int, the moves
    between consecutive steps; observations (W,) int; emission (N, K). ``first_step`` only
    labels error messages. ``out``, a previous result of the same shape, has its arrays
    overwritten instead of allocating new ones (iterating EM over long runs: fresh large arrays
    cost a page fault per 4 kB on first touch). Raises :class:`ImpossibleObservationError` if an
    observation has probability zero. O(W (N + E)) time, 3 W N floats of memory.
    """
    actions = np.ascontiguousarray(actions, dtype=np.int64)
    observations = np.ascontiguousarray(observations, dtype=np.int64)
    w, n = len(observations), model.n_cells
    if out is not None and out.filtered.shape == (w, n):
        filtered, posterior, normalizers = out.filtered, out.posterior, out.log_normalizers
    else:
        filtered, posterior, normalizers = np.empty((w, n)), np.empty((w, n)), np.empty(w)
    bad = _forward_backward(model.self_prob, model.predecessor, model.neighbors, model.p_move,
                            np.ascontiguousarray(prior, dtype=np.float64), actions, observations,
                            np.ascontiguousarray(emission, dtype=np.float64), filtered, posterior, normalizers)
    if bad >= 0:
        label = model.label_names[observations[bad]]
        raise ImpossibleObservationError(
            f"observation {label!r} at step {first_step + bad} has probability zero under the observation "
            f"matrix B in use (B starts as label_prior @ O; a learned B has no zeros when pseudo_count > 0)")
    np.log(normalizers, out=normalizers)
    return HMMPosterior(filtered, posterior, normalizers)


@njit(cache=True)
def _accumulate_counts(posterior, observations, counts):
    for t in range(posterior.shape[0]):
        z = observations[t]
        for i in range(posterior.shape[1]):
            counts[i, z] += posterior[t, i]


def expected_counts(posterior: np.ndarray, observations: np.ndarray, n_labels: int) -> np.ndarray:
    """Expected sufficient statistics ``E[i, k] = sum_tau P(L_tau = i | z) [z_tau = k]``.
    posterior (W, N), observations (W,) -> (N, K). One pass over the posterior (numba): O(W N)."""
    counts = np.zeros((posterior.shape[1], n_labels))
    _accumulate_counts(np.ascontiguousarray(posterior), np.ascontiguousarray(observations, dtype=np.int64), counts)
    return counts


def emission_from_counts(counts: np.ndarray, pseudo_count: float, fallback: np.ndarray) -> np.ndarray:
    """M-step: ``B[i] = (S[i] + c) / (sum_k S[i, k] + K c)``, the MAP estimate under a symmetric
    Dirichlet(c + 1) prior per row. A row with no statistics at all (only possible when c = 0)
    takes the ``fallback`` row. counts, fallback (N, K) -> (N, K)."""
    smoothed = counts + pseudo_count
    totals = smoothed.sum(axis=1, keepdims=True)
    empty = totals[:, 0] <= 0
    totals[empty] = 1.0
    emission = smoothed / totals
    emission[empty] = fallback[empty]
    return emission


def prior_emission(model: GridModel) -> np.ndarray:
    """The observation matrix implied by the label prior: ``B0 = label_prior @ O``, (N, K)."""
    return model.label_prior @ model.sensor


def sensor_inverse(sensor: np.ndarray) -> np.ndarray:
    """(K, K) pseudo-inverse of the sensor O (its inverse when O is invertible; least squares
    when it is singular, e.g. p_obs = 1/K), for :func:`map_from_emission`. O(K^3)."""
    return np.linalg.pinv(sensor)


def map_from_emission(emission: np.ndarray, inverse: np.ndarray) -> np.ndarray:
    """Map marginals read off B by inverting the sensor channel: ``m = B O^+`` row by row
    (``inverse`` = :func:`sensor_inverse` of O), clipped to [0, 1], rows renormalised (a row
    clipped to all zeros becomes uniform). (N, K), (K, K) -> (N, K). O(N K^2)."""
    maps = np.clip(emission @ inverse, 0.0, 1.0)
    totals = maps.sum(axis=1, keepdims=True)
    empty = totals[:, 0] <= 0
    if empty.any():
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

