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

from .errors import ImpossibleObservationError
from .kernels.forward_backward import accumulate_counts, forward_backward_pass
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
    log_scales = np.empty(w)  # 0 but where a step was rescaled against underflow
    bad = forward_backward_pass(model.self_prob, model.predecessor, model.neighbors, model.p_move,
                            np.ascontiguousarray(prior, dtype=np.float64), actions, observations,
                            np.ascontiguousarray(emission, dtype=np.float64), filtered, posterior, normalizers,
                            log_scales)
    if bad >= 0:
        label = model.label_names[observations[bad]]
        raise ImpossibleObservationError(
            f"observation {label!r} at step {first_step + bad} has probability zero under the observation "
            f"matrix B in use (B starts as label_prior @ O; a learned B has no zeros when pseudo_count > 0)")
    np.log(normalizers, out=normalizers)
    normalizers += log_scales
    return HMMPosterior(filtered, posterior, normalizers)


def expected_counts(posterior: np.ndarray, observations: np.ndarray, n_labels: int) -> np.ndarray:
    """Expected sufficient statistics ``E[i, k] = sum_tau P(L_tau = i | z) [z_tau = k]``.
    posterior (W, N), observations (W,) -> (N, K). One pass over the posterior (numba): O(W N)."""
    counts = np.zeros((posterior.shape[1], n_labels))
    accumulate_counts(np.ascontiguousarray(posterior), np.ascontiguousarray(observations, dtype=np.int64), counts)
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

