"""Forward-backward kernels of the EM estimators' location HMM (``onlinemap/hmm.py``).

Shapes: W steps, N cells, A actions, K labels. The motion model is the model's sparse tables
(``self_prob (A, N)``, ``predecessor (A, N)``, ``neighbors (N, A)``), never a dense N x N matrix.
"""

from __future__ import annotations

import numpy as np
from numba import njit

_TINY = 1e-280  # messages below this are set to 0: subnormal floats would make every pass ~10x slower


@njit(cache=True)
def forward_backward_pass(self_prob, predecessor, neighbors, enter, prior, actions, observations, emission,
                          filtered, posterior, normalizers):
    """Scaled forward-backward on the sparse motion model.

    self_prob (A, N), predecessor (A, N), neighbors (N, A): the model's motion tables; enter (N,)
    the probability that a move into cell j succeeds (``p_move`` everywhere for the paper's
    motion, ``p_move P(m_j passable)`` with blocking labels); prior (N,)
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
                    v += enter[j] * filtered[t - 1, p]
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
    return -1


@njit(cache=True)
def accumulate_counts(posterior, observations, counts):
    """counts (N, K) += sum_tau posterior[tau, i] [observations[tau] = k]: posterior (W, N). O(W N)."""
    for t in range(posterior.shape[0]):
        z = observations[t]
        for i in range(posterior.shape[1]):
            counts[i, z] += posterior[t, i]
