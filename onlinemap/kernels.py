"""numba kernels for the hot loops (compiled once, cached on disk).

Shapes: N cells, K labels, M = K**N joint maps. The exact belief is an (N, M) array whose row
``l`` holds ``P(L = l, m)`` with the map index ``m`` in C order (``m_0`` most significant), so
map axis ``j`` has stride ``K**(N-1-j)``. Work is blocked over ``K**b`` consecutive map
entries (about 2048): within a block the ``b`` innermost axes follow one fixed pattern and the
outer ones are constant, so every inner loop is a plain contiguous loop.
"""

from __future__ import annotations

import numpy as np
from numba import njit

_BLOCK_TARGET = 2048  # map entries per block: N rows of one block stay in L2


@njit(cache=True)
def _block_axes(n, k):
    """Number b of innermost axes in a block of K**b <= 2048 entries (at least 1, at most N)."""
    b = 1
    while b < n and k ** (b + 1) <= _BLOCK_TARGET:
        b += 1
    return b


@njit(cache=True, fastmath=True)
def motion_observe(x, out, self_prob, predecessor, p_move, likelihood, joint_map, location):
    """One fused pass: ``out[j, m] = (self_prob[j] x[j, m] + p_move x[pred[j], m]) * lik[m_j]``.

    x, out: (N, M) (may be the same array when every predecessor is -1); self_prob, predecessor:
    (N,); likelihood: (K,) ``O[:, z]``; writes ``joint_map`` (M,) = sum over locations of out and
    ``location`` (N,) = sum over maps. Scaling (normalisation) is folded into the coefficients.
    Cost: one read and one write of (N, M), plus O(N * 2048) to build the block pattern.
    """
    n, m_total = x.shape
    k = likelihood.shape[0]
    b = _block_axes(n, k)
    block = k**b
    inner = n - b  # axes j >= inner vary within a block
    pattern = np.empty((n, block))
    for j in range(inner, n):
        stride = k ** (n - 1 - j)
        for run in range(block // stride):
            f = likelihood[run % k]
            for m in range(run * stride, (run + 1) * stride):
                pattern[j, m] = f
    joint_map[:] = 0.0
    location[:] = 0.0
    for start in range(0, m_total, block):
        for j in range(n):
            a = self_prob[j]
            p = predecessor[j]
            acc = 0.0
            if j < inner:
                f = likelihood[(start // k ** (n - 1 - j)) % k]
                if p >= 0:
                    for m in range(block):
                        v = (a * x[j, start + m] + p_move * x[p, start + m]) * f
                        out[j, start + m] = v
                        acc += v
                        joint_map[start + m] += v
                else:
                    for m in range(block):
                        v = a * x[j, start + m] * f
                        out[j, start + m] = v
                        acc += v
                        joint_map[start + m] += v
            else:
                if p >= 0:
                    for m in range(block):
                        v = (a * x[j, start + m] + p_move * x[p, start + m]) * pattern[j, m]
                        out[j, start + m] = v
                        acc += v
                        joint_map[start + m] += v
                else:
                    for m in range(block):
                        v = a * x[j, start + m] * pattern[j, m]
                        out[j, start + m] = v
                        acc += v
                        joint_map[start + m] += v
            location[j] += acc


@njit(cache=True, fastmath=True)
def _change_axis(x, row, base, stride, span, change, k):
    """Apply C along the axis of the given stride to ``x[row, base:base+span]``, in place."""
    if k == 2:
        c00, c01, c10, c11 = change[0, 0], change[0, 1], change[1, 0], change[1, 1]
        for g in range(base, base + span, 2 * stride):
            for s in range(g, g + stride):
                u = x[row, s]
                w = x[row, s + stride]
                x[row, s] = u * c00 + w * c10
                x[row, s + stride] = u * c01 + w * c11
        return
    tmp = np.empty(k)
    for g in range(base, base + span, k * stride):
        for s in range(g, g + stride):
            for a in range(k):
                tmp[a] = x[row, s + a * stride]
            for c in range(k):
                acc = 0.0
                for a in range(k):
                    acc += tmp[a] * change[a, c]
                x[row, s + c * stride] = acc


@njit(cache=True, fastmath=True)
def change_every_axis(x, change):
    """In place on (N, M): apply ``C`` (K, K) along every one of the N map axes,
    ``x[.., m_i = k', ..] <- sum_k C[k, k'] x[.., m_i = k, ..]``.

    Cost: the b innermost axes are applied block by block in cache (one memory pass); each of
    the N - b outer axes is one more read+write pass: N - b + 1 passes in all.
    """
    n, m_total = x.shape
    k = change.shape[0]
    b = _block_axes(n, k)
    block = k**b
    for row in range(n):
        for start in range(0, m_total, block):
            for axis in range(n - b, n):
                _change_axis(x, row, start, k ** (n - 1 - axis), block, change, k)
        for axis in range(n - b):
            _change_axis(x, row, 0, k ** (n - 1 - axis), m_total, change, k)


@njit(cache=True)
def map_marginals(joint_map, n, k, out):
    """(N, K) marginals of a (K**N,) joint over maps into ``out``, by peeling the leading axis.
    Cost: about 2 K / (K - 1) reads of the joint."""
    rest = joint_map
    size = joint_map.shape[0]
    for i in range(n):
        size //= k
        nxt = np.zeros(size)
        for a in range(k):
            acc = 0.0
            base = a * size
            for s in range(size):
                v = rest[base + s]
                acc += v
                nxt[s] += v
            out[i, a] = acc
        rest = nxt
