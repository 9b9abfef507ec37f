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
    """Number b of innermost axes in a block of K**b <= 2048 entries: at least 1, at most
    N - 3 when N > 3, so that the (b, K**b) block pattern costs at most 1/8 of a pass."""
    limit = n - 3 if n > 3 else n
    b = 1
    while b < limit and k ** (b + 1) <= _BLOCK_TARGET:
        b += 1
    return b


@njit(cache=True, fastmath=True)
def motion_observe(x, out, self_prob, predecessor, p_move, scale, likelihood, joint_map, location):
    """One fused pass: ``out[j, m] = scale (self_prob[j] x[j, m] + p_move x[pred[j], m]) lik[m_j]``.

    x, out: (N, M) (may be the same array when every predecessor is -1); self_prob, predecessor:
    (N,); likelihood: (K,) ``O[:, z]``; writes ``joint_map`` (M,) = sum over locations of out and
    ``location`` (N,) = sum over maps. ``scale`` folds the previous step's normalisation in.
    Cost: one read and one write of (N, M), plus O(N * 2048) to build the block pattern.
    """
    n, m_total = x.shape
    k = likelihood.shape[0]
    b = _block_axes(n, k)
    block = k**b
    inner = n - b  # axes j >= inner vary within a block
    pattern = np.empty((n, block))  # rows inner..n-1 used
    for j in range(inner, n):
        stride = k ** (n - 1 - j)
        for run in range(block // stride):
            f = likelihood[run % k]
            for m in range(run * stride, (run + 1) * stride):
                pattern[j, m] = f
    joint_map[:] = 0.0
    location[:] = 0.0
    ones = np.ones(block)
    for start in range(0, m_total, block):
        stop = start + block
        q = joint_map[start:stop]
        for j in range(n):
            a = self_prob[j] * scale
            p = predecessor[j]
            if j < inner:
                f = likelihood[(start // k ** (n - 1 - j)) % k]
                a *= f
                factor = ones
                pm = p_move * scale * f
            else:
                factor = pattern[j]
                pm = p_move * scale
            here = x[j, start:stop]
            target = out[j, start:stop]
            acc = 0.0
            if p >= 0:
                there = x[p, start:stop]
                for m in range(block):
                    v = (a * here[m] + pm * there[m]) * factor[m]
                    target[m] = v
                    acc += v
                    q[m] += v
            else:
                for m in range(block):
                    v = a * here[m] * factor[m]
                    target[m] = v
                    acc += v
                    q[m] += v
            location[j] += acc


@njit(cache=True, fastmath=True)
def _change_axis(x, row, base, stride, span, change, k, tmp):
    """Apply C along the axis of the given stride to ``x[row, base:base+span]``, in place
    (``tmp`` (K,) scratch)."""
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
def _binary_change(v, stride, stop, c00, c01, c10, c11):
    """Binary C along the axis of ``stride`` of the 1-D ``v`` and, when ``4 stride <= stop``,
    along the axis of ``2 stride`` too, in one sweep (radix 4: half the memory traffic).
    Contiguous slices keep the inner loops vectorisable."""
    m = v.shape[0]
    if 4 * stride > stop:
        for g in range(0, m, 2 * stride):
            lo = v[g:g + stride]
            hi = v[g + stride:g + 2 * stride]
            for i in range(stride):
                u = lo[i]
                w = hi[i]
                lo[i] = u * c00 + w * c10
                hi[i] = u * c01 + w * c11
        return
    for g in range(0, m, 4 * stride):
        va = v[g:g + stride]
        vb = v[g + stride:g + 2 * stride]
        vc = v[g + 2 * stride:g + 3 * stride]
        vd = v[g + 3 * stride:g + 4 * stride]
        for i in range(stride):
            a = va[i]
            b = vb[i]
            c = vc[i]
            d = vd[i]
            a1 = a * c00 + b * c10
            b1 = a * c01 + b * c11
            c1 = c * c00 + d * c10
            d1 = c * c01 + d * c11
            va[i] = a1 * c00 + c1 * c10
            vc[i] = a1 * c01 + c1 * c11
            vb[i] = b1 * c00 + d1 * c10
            vd[i] = b1 * c01 + d1 * c11


@njit(cache=True, fastmath=True)
def _binary_change_every_axis(x, change):
    """K = 2 case of :func:`change_every_axis`: the innermost axes block by block in cache
    (the stride-1 axis on interleaved pairs, then two axes per sweep), the outer axes two per
    memory pass."""
    n, m_total = x.shape
    block = 2 ** _block_axes(n, np.int64(2))  # int64, not a literal 2: one compile for both callers
    c00, c01, c10, c11 = change[0, 0], change[0, 1], change[1, 0], change[1, 1]
    flat = x.reshape(-1)
    for start in range(0, flat.shape[0], block):
        blk = flat[start:start + block]
        for i in range(block // 2):
            u = blk[2 * i]
            w = blk[2 * i + 1]
            blk[2 * i] = u * c00 + w * c10
            blk[2 * i + 1] = u * c01 + w * c11
        stride = np.int64(2)  # not a literal: _binary_change compiles once
        while stride < block:
            _binary_change(blk, stride, block, c00, c01, c10, c11)
            stride *= 4
    for row in range(n):
        stride = block
        while stride < m_total:
            _binary_change(x[row], stride, m_total, c00, c01, c10, c11)
            stride *= 4


@njit(cache=True, fastmath=True)
def change_every_axis(x, change):
    """In place on (N, M): apply ``C`` (K, K) along every one of the N map axes,
    ``x[.., m_i = k', ..] <- sum_k C[k, k'] x[.., m_i = k, ..]``.

    Cost: the b innermost axes are applied block by block in cache (one memory pass); the
    N - b outer axes cost one read+write pass each (K > 2) or one per two axes (K = 2).
    """
    n, m_total = x.shape
    k = change.shape[0]
    if k == 2:
        _binary_change_every_axis(x, change)
        return
    b = _block_axes(n, k)
    block = k**b
    tmp = np.empty(k)
    for row in range(n):
        for start in range(0, m_total, block):
            for axis in range(n - b, n):
                _change_axis(x, row, start, k ** (n - 1 - axis), block, change, k, tmp)
        for axis in range(n - b):
            _change_axis(x, row, np.int64(0), k ** (n - 1 - axis), m_total, change, k, tmp)  # one compile


@njit(cache=True)
def map_marginals(joint_map, n, k, out):
    """(N, K) marginals of a (K**N,) joint over maps into ``out``, by peeling the leading axis.
    ``joint_map`` is scratch: it is overwritten (the rest after each peel is summed in place
    into its head). Cost: about 2 K / (K - 1) reads of the joint, no allocation."""
    size = joint_map.shape[0]
    for i in range(n):
        size //= k
        acc = 0.0
        for s in range(size):
            acc += joint_map[s]
        out[i, 0] = acc
        for a in range(1, k):
            acc = 0.0
            base = a * size
            for s in range(size):
                v = joint_map[base + s]
                acc += v
                joint_map[s] += v
            out[i, a] = acc
