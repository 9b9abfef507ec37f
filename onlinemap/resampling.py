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

:func:`optimal_resampling` (Fearnhead and Clifford 2003) is of another kind: it keeps at most
``n`` of M weighted children, no child twice, and returns new weights besides the indices.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import numpy as np
from numba import njit

from .kernels.resampling import optimal_keep_into

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


class Kept(NamedTuple):
    """The children :func:`optimal_resampling` keeps: ``indices`` (n',) in walk order, no repeat;
    ``weights`` (n',) their new weights (summing to the input's total, up to rounding);
    ``threshold`` c (0 when every positive child is kept)."""

    indices: np.ndarray
    weights: np.ndarray
    threshold: float


@njit(cache=True)
def optimal_keep(w, n, uniform, order):
    """:func:`optimal_keep_into` into fresh arrays: returns (indices in walk order, weights, c). O(M)."""
    indices = np.empty(n, dtype=np.int64)
    weights = np.empty(n)
    kept, c = optimal_keep_into(w, n, uniform, order, indices, weights)
    return indices[:kept].copy(), weights[:kept].copy(), c


def optimal_resampling(weights, n: int, rng: np.random.Generator, order=None) -> Kept:
    """Keep at most ``n`` of the M children ``weights`` (M,), none twice (Fearnhead and Clifford
    2003): if at most ``n`` are positive, keep those with their weights; otherwise find c with
    ``sum_i min(1, w_i / c) = n``, keep every child with ``w_i >= c`` with its weight, and draw
    the others by stratified sampling (one uniform) with weight c. Each child's expected new
    weight is its old one (unbiased: ``P(kept) = w_i / c`` for ``w_i < c``), and the new weights
    sum to the old total. ``order`` (M,), a permutation (default: index order), is the order in
    which the strata walk the children (the returned indices follow it). One uniform; O(M) (a few
    passes to find c; a sort, O(M log M), in the rare case they do not settle)."""
    w = _normalised(weights)
    if isinstance(n, bool) or int(n) != n or n < 1:
        raise ValueError(f"n must be a positive integer, got {n!r}")
    order = np.arange(w.size) if order is None else np.asarray(order)
    if order.shape != w.shape or order.dtype.kind not in "iu" or not np.array_equal(np.sort(order), np.arange(w.size)):
        raise ValueError(f"order must be a permutation of 0..{w.size - 1}")
    total = float(np.sum(np.asarray(weights, dtype=np.float64)))
    indices, kept, c = optimal_keep(w, int(n), rng.random(), order.astype(np.int64))
    return Kept(indices, kept * total, c * total)


def effective_sample_size(weights) -> float:
    """``(sum w)^2 / sum w^2`` of non-negative weights (P for equal weights, 1 for one survivor)."""
    w = np.asarray(weights, dtype=np.float64)
    return float(w.sum() ** 2 / np.dot(w, w))


__all__ = ["multinomial", "stratified", "systematic", "residual", "RESAMPLERS", "Resampler",
           "effective_sample_size", "optimal_resampling", "optimal_keep", "optimal_keep_into", "Kept"]
