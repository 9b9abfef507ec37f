"""Resampling schemes for particle filters: ``(weights (P,), rng) -> indices (P,)``.

Each function draws ``P = len(weights)`` ancestor indices so that particle ``i`` is copied
``P * w_i`` times on average (``w`` = weights normalised), from an explicit
``numpy.random.Generator``; the global random state is never used. The returned indices are
sorted. Cost O(P) (multinomial O(P log P)); one or P uniforms per call.

- ``multinomial``: P independent draws; copies ~ Multinomial(P, w) (the most variance).
- ``stratified``: one uniform in each stratum ``[j/P, (j+1)/P)``.
- ``systematic``: one uniform shifted over all strata (least variance in practice, but the
  copies of neighbouring particles are correlated).
- ``residual`` (Liu and Chen 1998): ``floor(P w_i)`` copies deterministically, the remaining
  ``R = P - sum floor(P w_i)`` drawn multinomially from the residuals ``P w_i - floor(P w_i)``.

(filterpy 2.0.0's ``residual_resample`` is biased and uses numpy's global random state;
these are written from the definitions and tested for unbiasedness.)
"""

from __future__ import annotations

from typing import Callable

import numpy as np
from numba import njit

Resampler = Callable[[np.ndarray, np.random.Generator], np.ndarray]


def _normalised(weights) -> np.ndarray:
    w = np.asarray(weights, dtype=np.float64)
    if w.ndim != 1 or w.size == 0:
        raise ValueError(f"weights must be a non-empty 1-D array, got shape {w.shape}")
    if not np.all(np.isfinite(w)) or np.any(w < 0):
        raise ValueError("weights must be finite and non-negative")
    total = w.sum()
    if not total > 0:
        raise ValueError("weights sum to zero")
    return w / total


@njit(cache=True)
def _sorted_positions_to_indices(cumulative, positions):
    """indices[j] = first i with positions[j] < cumulative[i], for sorted positions; O(P)."""
    n = positions.shape[0]
    last = cumulative.shape[0] - 1
    out = np.empty(n, dtype=np.int64)
    i = 0
    for j in range(n):
        while i < last and positions[j] >= cumulative[i]:
            i += 1
        out[j] = i
    return out


def _from_sorted_positions(w: np.ndarray, positions: np.ndarray) -> np.ndarray:
    cumulative = np.cumsum(w)
    cumulative[-1] = 1.0  # rounding must not leave the last position uncovered
    return _sorted_positions_to_indices(cumulative, positions)


def _sorted_uniforms(n: int, rng: np.random.Generator) -> np.ndarray:
    """n sorted i.i.d. uniforms in O(n): normalised cumulative exponential spacings."""
    spacings = rng.standard_exponential(n + 1)
    return np.cumsum(spacings[:-1]) / spacings.sum()


def multinomial(weights, rng: np.random.Generator) -> np.ndarray:
    """P independent draws from ``w``."""
    w = _normalised(weights)
    return _from_sorted_positions(w, _sorted_uniforms(w.size, rng))


def stratified(weights, rng: np.random.Generator) -> np.ndarray:
    """One uniform in each of the P strata: positions ``(j + U_j) / P``."""
    w = _normalised(weights)
    n = w.size
    return _from_sorted_positions(w, (np.arange(n) + rng.random(n)) / n)


def systematic(weights, rng: np.random.Generator) -> np.ndarray:
    """One uniform for all strata: positions ``(j + U) / P``."""
    w = _normalised(weights)
    n = w.size
    return _from_sorted_positions(w, (np.arange(n) + rng.random()) / n)


def residual(weights, rng: np.random.Generator) -> np.ndarray:
    """``floor(P w_i)`` copies of each particle, the rest multinomially from the residuals."""
    w = _normalised(weights)
    n = w.size
    expected = n * w
    copies = np.floor(expected).astype(np.int64)
    rest = n - int(copies.sum())
    if rest > 0:
        copies += rng.multinomial(rest, _normalised(np.maximum(expected - copies, 0.0)))
    return np.repeat(np.arange(n), copies)


RESAMPLERS: dict[str, Resampler] = {
    "residual": residual,
    "systematic": systematic,
    "stratified": stratified,
    "multinomial": multinomial,
}


def effective_sample_size(weights) -> float:
    """``(sum w)^2 / sum w^2`` of non-negative weights (P for equal weights, 1 for one survivor)."""
    w = np.asarray(weights, dtype=np.float64)
    return float(w.sum() ** 2 / np.dot(w, w))


__all__ = ["multinomial", "stratified", "systematic", "residual", "RESAMPLERS", "Resampler",
           "effective_sample_size"]
