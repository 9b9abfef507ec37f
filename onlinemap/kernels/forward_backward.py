"""Forward-backward kernels of the EM estimators' location HMM (``onlinemap/hmm.py``).

Shapes: W steps, N cells, A actions, K labels. The motion model is the model's sparse tables
(``self_prob (A, N)``, ``predecessor (A, N)``, ``neighbors (N, A)``), never a dense N x N matrix.
"""

from __future__ import annotations

import numpy as np
from numba import njit

_TINY = 1e-280  # messages below this are set to 0: subnormal floats would make every pass ~10x slower
_RESCALE_BELOW = 1e-250  # a step whose normaliser falls below this is redone with its column of B rescaled


@njit(cache=True, inline="always")
def _forward_row(self_prob, predecessor, enter, prior, filtered, actions, emission, t, z, scale):
    """Unnormalised filtered row t into ``filtered[t]`` with the column ``emission[:, z] / scale``;
    returns its total. Entries below ``_TINY`` are set to 0 after the first step. O(N + E)."""
    n = filtered.shape[1]
    total = 0.0
    if t == 0:
        for j in range(n):
            v = prior[j] * (emission[j, z] / scale)
            filtered[0, j] = v
            total += v
        return total
    a = actions[t - 1]
    for j in range(n):
        v = self_prob[a, j] * filtered[t - 1, j]
        p = predecessor[a, j]
        if p >= 0:
            v += enter[j] * filtered[t - 1, p]
        v *= emission[j, z] / scale
        if v < _TINY:
            v = 0.0
        filtered[t, j] = v
        total += v
    return total


@njit(cache=True)
def forward_backward_pass(self_prob, predecessor, neighbors, enter, prior, actions, observations, emission,
                          filtered, posterior, normalizers, log_scales):
    """Scaled forward-backward on the sparse motion model.

    self_prob (A, N), predecessor (A, N), neighbors (N, A): the model's motion tables; enter (N,)
    the probability that a move into cell j succeeds (``p_move`` everywhere for the paper's
    motion, ``p_move P(m_j passable)`` with blocking labels); prior (N,)
    the distribution of the first step's location before its observation; actions (W - 1,);
    observations (W,); emission (N, K) B. Writes filtered (W, N) ``P(L_tau | z_0..tau)``, posterior
    (W, N) ``P(L_tau | z_0..W-1)``, normalizers (W,) and log_scales (W,) with
    ``P(z_tau | z_0..tau-1) = normalizers[tau] exp(log_scales[tau])``. Returns the index of the
    first step whose observation has probability zero (or too small for float64 even after
    rescaling), or -1. O(W (N + E)).

    Underflow: a step whose normaliser falls below ``_RESCALE_BELOW`` (observations B gives
    probabilities near 1e-300) is redone with its column ``B[:, z]`` divided by the column's
    maximum ``s`` (``log_scales = log s``, 0 for every other step), so its messages stay normal
    floats. Forward and backward messages below ``_TINY`` (relative to rows summing to 1) are set to 0.
    """
    scales = np.ones(filtered.shape[0])
    bad = _forward_pass(self_prob, predecessor, enter, prior, actions, observations, emission, filtered,
                        normalizers, log_scales, scales)
    if bad < 0:
        _backward_pass(self_prob, neighbors, enter, actions, observations, emission, filtered, posterior,
                       normalizers, scales)
    return bad


@njit(cache=True)
def forward_pass(self_prob, predecessor, enter, prior, actions, observations, emission, filtered, normalizers,
                 log_scales):
    """The forward half of :func:`forward_backward_pass` alone (the same arguments but
    ``neighbors`` and ``posterior``, the same bits in ``filtered``, ``normalizers`` and
    ``log_scales``), for callers that need only the filtered rows. Returns the first step whose
    observation has probability zero, or -1. O(W (N + E))."""
    return _forward_pass(self_prob, predecessor, enter, prior, actions, observations, emission, filtered,
                         normalizers, log_scales, np.ones(filtered.shape[0]))


@njit(cache=True, inline="always")
def _forward_pass(self_prob, predecessor, enter, prior, actions, observations, emission, filtered, normalizers,
                  log_scales, scales):
    """The filtered rows, each normalised, their normalisers, and the scales of the steps redone
    with their column of B rescaled (``scales`` (W,) of ones on entry). Returns the first step
    whose observation has probability zero, or -1 (rows after it are left unwritten). O(W (N + E))."""
    n = filtered.shape[1]
    bad = -1
    for t in range(filtered.shape[0]):
        z = observations[t]
        total = _forward_row(self_prob, predecessor, enter, prior, filtered, actions, emission, t, z, 1.0)
        log_scales[t] = 0.0
        if not total >= _RESCALE_BELOW:
            top = 0.0
            for j in range(n):
                top = max(top, emission[j, z])
            if top > 0.0:
                total = _forward_row(self_prob, predecessor, enter, prior, filtered, actions, emission, t, z, top)
                scales[t] = top
                log_scales[t] = np.log(top)
            if not total >= _TINY:
                bad = t
                break
        normalizers[t] = total
        inverse = 1.0 / total
        for j in range(n):
            filtered[t, j] *= inverse
    return bad


@njit(cache=True, inline="always")
def _backward_pass(self_prob, neighbors, enter, actions, observations, emission, filtered, posterior, normalizers,
                   scales):
    """The posterior rows from the filtered ones, by the scaled backward messages (the forward
    pass's normalisers and scales). O(W (N + E))."""
    w, n = filtered.shape
    beta = np.ones(n)
    scaled = np.empty(n)
    for j in range(n):
        posterior[w - 1, j] = filtered[w - 1, j]
    for t in range(w - 1, 0, -1):
        a = actions[t - 1]
        z = observations[t]
        inverse = 1.0 / normalizers[t]
        for j in range(n):
            scaled[j] = beta[j] * (emission[j, z] / scales[t]) * inverse
        total = 0.0
        for i in range(n):
            v = self_prob[a, i] * scaled[i]
            nb = neighbors[i, a]
            if nb != i:
                v += enter[nb] * scaled[nb]
            if v < _TINY:
                v = 0.0
            beta[i] = v
            v *= filtered[t - 1, i]
            posterior[t - 1, i] = v
            total += v
        inverse = 1.0 / total
        for i in range(n):
            posterior[t - 1, i] *= inverse


@njit(cache=True)
def accumulate_counts(posterior, observations, counts):
    """``counts[i, k] += sum_tau posterior[tau, i] [observations[tau] = k]``: counts (N, K), posterior (W, N).
    O(W N)."""
    for t in range(posterior.shape[0]):
        z = observations[t]
        for i in range(posterior.shape[1]):
            counts[i, z] += posterior[t, i]
