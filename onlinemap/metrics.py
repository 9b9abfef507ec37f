"""Metrics on beliefs. All are pure and vectorised over leading axes (e.g. time)."""

from __future__ import annotations

import numpy as np


def map_error(map_belief: np.ndarray, true_map: np.ndarray) -> np.ndarray | float:
    """Expected map error: mean over cells of ``1 - P(true label)``.
    map_belief (..., N, K), true_map (..., N) -> (...)."""
    map_belief = np.asarray(map_belief)
    true_map = np.asarray(true_map)
    p_true = np.take_along_axis(map_belief, true_map[..., None], axis=-1)[..., 0]
    return 1.0 - p_true.mean(axis=-1)


def location_error(location: np.ndarray, true_location) -> np.ndarray | float:
    """``1 - P(true location)``. location (..., N), true_location (...) -> (...)."""
    location = np.asarray(location)
    true_location = np.asarray(true_location)
    return 1.0 - np.take_along_axis(location, true_location[..., None], axis=-1)[..., 0]


def total_variation(p: np.ndarray, q: np.ndarray) -> np.ndarray | float:
    """``0.5 * sum |p - q|`` over the last axis. (..., K) -> (...). For map beliefs (N, K) take
    ``.mean(-1)`` of the result to get the mean per-cell distance."""
    return 0.5 * np.abs(np.asarray(p) - np.asarray(q)).sum(axis=-1)


def normalized_entropy(p: np.ndarray) -> np.ndarray | float:
    """Entropy over the last axis divided by ``log(size)``, in [0, 1]. (..., K) -> (...)."""
    p = np.asarray(p, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        terms = np.where(p > 0, -p * np.log(p), 0.0)
    return terms.sum(axis=-1) / np.log(p.shape[-1])


def map_entropy(map_belief: np.ndarray) -> np.ndarray | float:
    """Mean normalised label entropy over cells. (..., N, K) -> (...)."""
    return normalized_entropy(map_belief).mean(axis=-1)


def wrong_cells(map_belief: np.ndarray, true_map: np.ndarray, cells=None) -> int:
    """Number of cells (optionally among ``cells``) whose most likely label is not the true one."""
    wrong = np.argmax(np.asarray(map_belief), axis=-1) != np.asarray(true_map)
    return int(wrong[..., cells].sum() if cells is not None else wrong.sum())
