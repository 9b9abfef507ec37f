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


@njit(cache=True)
def _forward_backward(self_prob, predecessor, neighbors, p_move, prior, actions, likelihood,
                      filtered, posterior, normalizers):
    """Scaled forward-backward on the sparse motion model.

    self_prob (A, N), predecessor (A, N), neighbors (N, A): the model's motion tables; prior (N,)
    the distribution of the first step's location before its observation; actions (W - 1,);
    likelihood (W, N) ``B[:, z_tau]``. Writes filtered (W, N) ``P(L_tau | z_0..tau)``, posterior
    (W, N) ``P(L_tau | z_0..W-1)`` and normalizers (W,) ``P(z_tau | z_0..tau-1)``. Returns the
    index of the first step whose observation has probability zero, or -1. O(W (N + E)).
    """
    w, n = likelihood.shape
    for t in range(w):
        total = 0.0
        if t == 0:
            for j in range(n):
                v = prior[j] * likelihood[0, j]
                filtered[0, j] = v
                total += v
        else:
            a = actions[t - 1]
            for j in range(n):
                v = self_prob[a, j] * filtered[t - 1, j]
                p = predecessor[a, j]
                if p >= 0:
                    v += p_move * filtered[t - 1, p]
                v *= likelihood[t, j]
                filtered[t, j] = v
                total += v
        if not total > 0.0:
            return t
        normalizers[t] = total
        for j in range(n):
            filtered[t, j] /= total
    beta = np.ones(n)
    scaled = np.empty(n)
    for j in range(n):
        posterior[w - 1, j] = filtered[w - 1, j]
    for t in range(w - 1, 0, -1):
        a = actions[t - 1]
        for j in range(n):
            scaled[j] = beta[j] * likelihood[t, j] / normalizers[t]
        total = 0.0
        for i in range(n):
            v = self_prob[a, i] * scaled[i]
            nb = neighbors[i, a]
            if nb != i:
                v += p_move * scaled[nb]
            beta[i] = v
            v *= filtered[t - 1, i]
            posterior[t - 1, i] = v
            total += v
        for i in range(n):
            posterior[t - 1, i] /= total
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
                     emission: np.ndarray, first_step: int = 0) -> HMMPosterior:
    """Filter and smooth the location over W steps under observation matrix ``emission``.

    prior (N,): P(L) at the first step before its observation; actions (W - 1,) int, the moves
    between consecutive steps; observations (W,) int; emission (N, K). ``first_step`` only
    labels error messages. Raises :class:`ImpossibleObservationError` if an observation has
    probability zero. O(W (N + E)) time, 3 W N floats of memory.
    """
    actions = np.ascontiguousarray(actions, dtype=np.int64)
    observations = np.asarray(observations, dtype=np.int64)
    likelihood = np.ascontiguousarray(emission[:, observations].T)
    w, n = likelihood.shape
    filtered, posterior, normalizers = np.empty((w, n)), np.empty((w, n)), np.empty(w)
    bad = _forward_backward(model.self_prob, model.predecessor, model.neighbors, model.p_move,
                            np.ascontiguousarray(prior, dtype=np.float64), actions, likelihood,
                            filtered, posterior, normalizers)
    if bad >= 0:
        label = model.label_names[observations[bad]]
        raise ImpossibleObservationError(
            f"observation {label!r} at step {first_step + bad} has probability zero under the "
            f"current observation matrix B (use pseudo_count > 0 to keep every observation possible)")
    return HMMPosterior(filtered, posterior, np.log(normalizers))


def expected_counts(posterior: np.ndarray, observations: np.ndarray, n_labels: int) -> np.ndarray:
    """Expected sufficient statistics ``E[i, k] = sum_tau P(L_tau = i | z) [z_tau = k]``.
    posterior (W, N), observations (W,) -> (N, K). O(W N)."""
    counts = np.zeros((posterior.shape[1], n_labels))
    np.add.at(counts.T, np.asarray(observations), posterior)
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


def map_from_emission(emission: np.ndarray, sensor: np.ndarray) -> np.ndarray:
    """Map marginals read off B by inverting the sensor channel: solve ``m O = B`` row by row
    (least squares, so a singular O still gives an answer), clip to [0, 1], renormalise rows
    (a row clipped to all zeros becomes uniform). (N, K), (K, K) -> (N, K). O(N K^2 + K^3)."""
    maps = np.clip(emission @ np.linalg.pinv(sensor), 0.0, 1.0)
    totals = maps.sum(axis=1, keepdims=True)
    uniform = np.full(maps.shape[1], 1.0 / maps.shape[1])
    return np.where(totals > 0, maps / np.where(totals > 0, totals, 1.0), uniform)


def temper(posterior: np.ndarray, tau: float) -> np.ndarray:
    """Deterministic annealing of per-step posteriors: ``p^(1/tau)`` renormalised over the last
    axis (tau = 1: unchanged; tau -> 0: the one-hot argmax). (..., N) -> (..., N)."""
    if tau == 1.0:
        return posterior
    scaled = posterior / posterior.max(axis=-1, keepdims=True)
    powered = scaled ** (1.0 / tau)
    return powered / powered.sum(axis=-1, keepdims=True)


def log_dirichlet_prior(emission: np.ndarray, pseudo_count: float) -> float:
    """The pseudo-count prior's log density up to a constant, ``c sum_ik log B[i, k]`` (0 when c = 0)."""
    if pseudo_count == 0:
        return 0.0
    return float(pseudo_count * np.log(emission).sum())

