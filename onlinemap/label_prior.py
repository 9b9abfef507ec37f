"""What maps look like: the label prior of cells the robot has not read (DESIGN.md section 9).

The model's prior makes the cells independent with fixed frequencies (uniform by default). A
building is not a draw from that prior (about 56% free, 39% wall, 5% doors), and a uniform prior
says that half of every unseen cell blocks. The hierarchical model this module serves puts the
frequencies theta themselves under a Dirichlet,

    theta ~ Dirichlet(alpha),    m_i | theta ~ Categorical(theta) i.i.d.,

so that, integrated over theta, the map prior is the Dirichlet-multinomial

    P(m) = Gamma(A) / Gamma(A + N) prod_k Gamma(alpha_k + n_k(m)) / Gamma(alpha_k),

with ``A = sum_k alpha_k`` and ``n_k(m)`` the cells of label k: cells are exchangeable, no longer
independent, and what the robot reads of some cells tells it about the others. The predictive of
a cell given the labels of n others is ``(alpha + counts) / (A + n)``. Estimators take the
option ``label_prior``:

- ``None``: the model's own prior (the default; every result as without the option);
- a (K,) frequency vector: that fixed prior for every cell;
- ``"learn"``: the hierarchical prior above with ``alpha = prior_strength / K`` per label
  (``prior_strength`` defaults to K: Laplace's uniform Dirichlet). The exact filter computes its
  posterior exactly (the Dirichlet-multinomial joint); approximate filters plug in the posterior
  mean of theta given the expected label counts of the cells they have read (empirical Bayes).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from scipy.special import gammaln

from .errors import InvalidOptionError

LEARN = "learn"


class LabelPrior(NamedTuple):
    """A resolved ``label_prior`` option: ``kind`` is ``"model"`` (the model's own prior),
    ``"fixed"`` (``frequencies`` (K,) for every cell) or ``"learn"`` (a Dirichlet with
    concentrations ``alpha`` (K,) over the label frequencies)."""

    kind: str
    frequencies: np.ndarray | None
    alpha: np.ndarray | None


def resolve_label_prior(n_labels: int, label_prior, prior_strength=None) -> LabelPrior:
    """Check and resolve the ``label_prior`` / ``prior_strength`` options of an estimator for K =
    ``n_labels`` labels. Raises :class:`~onlinemap.errors.InvalidOptionError` naming the problem:
    an unknown string, a vector of the wrong length or not a probability vector (entries in
    [0, 1] summing to 1), a ``prior_strength`` that is not a positive finite number or given
    without ``"learn"``. O(K)."""
    if prior_strength is not None and not (isinstance(label_prior, str) and label_prior == LEARN):
        raise InvalidOptionError("prior_strength is the Dirichlet's total pseudo-count of label_prior='learn'; "
                                 f"it means nothing with label_prior={label_prior!r}")
    if label_prior is None:
        return LabelPrior("model", None, None)
    if isinstance(label_prior, str):
        if label_prior != LEARN:
            raise InvalidOptionError(f"label_prior must be None (the model's prior), 'learn' or a vector of "
                                     f"{n_labels} label frequencies, got {label_prior!r}")
        strength = float(n_labels) if prior_strength is None else prior_strength
        if isinstance(strength, bool) or not isinstance(strength, (int, float, np.integer, np.floating)) \
                or not 0 < float(strength) < math.inf:
            raise InvalidOptionError(f"prior_strength must be a positive finite number, got {prior_strength!r}")
        return LabelPrior(LEARN, None, np.full(n_labels, float(strength) / n_labels))
    try:
        freq = np.array(label_prior, dtype=np.float64)
    except (TypeError, ValueError):
        raise InvalidOptionError(f"label_prior must be None, 'learn' or a vector of {n_labels} label "
                                 f"frequencies, got {label_prior!r}") from None
    if freq.shape != (n_labels,):
        raise InvalidOptionError(f"label_prior must have one frequency per label ({n_labels}), got shape "
                                 f"{freq.shape}")
    if not np.all(np.isfinite(freq)) or np.any(freq < 0) or np.any(freq > 1) or abs(freq.sum() - 1) > 1e-9:
        raise InvalidOptionError(f"label_prior must be label frequencies in [0, 1] summing to 1, got "
                                 f"{freq.tolist()}")
    freq.setflags(write=False)
    return LabelPrior("fixed", freq, None)


def map_counts(n_cells: int, n_labels: int) -> np.ndarray:
    """(K**N, K) the number of cells of each label in every map, maps in the exact filter's order
    (row-major over the cells: cell 0 the slowest digit). O(K**N N)."""
    maps = np.arange(n_labels ** n_cells)
    counts = np.zeros((maps.size, n_labels), dtype=np.int64)
    for _ in range(n_cells):
        maps, digit = np.divmod(maps, n_labels)
        counts[np.arange(counts.shape[0]), digit] += 1
    return counts


def dirichlet_multinomial_prior(n_cells: int, alpha: np.ndarray) -> np.ndarray:
    """(K**N,) the joint prior of every map under the Dirichlet-multinomial with concentrations
    ``alpha`` (K,), maps in the exact filter's order (:func:`map_counts`). Sums to 1.
    O(K**N (N + K)) time, 8 K**N (K + 1) bytes."""
    alpha = np.asarray(alpha, dtype=np.float64)
    counts = map_counts(n_cells, len(alpha))
    total = alpha.sum()
    log_p = (gammaln(total) - gammaln(total + n_cells)
             + (gammaln(alpha + counts) - gammaln(alpha)).sum(axis=1))
    return np.exp(log_p)


def posterior_frequencies(alpha: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """(K,) the posterior mean of the label frequencies, ``(alpha + counts) / (A + sum counts)``,
    given the (expected) label counts (K,) of the cells read. O(K)."""
    post = np.asarray(alpha, dtype=np.float64) + np.asarray(counts, dtype=np.float64)
    return post / post.sum()
