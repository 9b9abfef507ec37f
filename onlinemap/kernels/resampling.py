"""numba kernels of resampling (``onlinemap/resampling.py``): Fearnhead and Clifford's optimal
resampling, its threshold c and its stratified walk, into arrays the caller owns; and the draw of
labels from marginals by inversion (``onlinemap.estimators.base.draw_labels``)."""

from __future__ import annotations

import numpy as np
from numba import njit

from . import loop_kernel


@njit(cache=True)
def _sift_down(a, root, end):
    """Restore the max-heap ``a[root:end]`` below ``root``. O(log end)."""
    while True:
        child = 2 * root + 1
        if child >= end:
            return
        if child + 1 < end and a[child] < a[child + 1]:
            child += 1
        if not a[root] < a[child]:
            return
        a[root], a[child] = a[child], a[root]
        root = child


@njit(cache=True)
def _heapsort(a):
    """Sort ``a`` (M,) ascending in place, O(M log M): the same array as ``np.sort`` (equal values
    are indistinguishable), at a fraction of the compile cost of numba's ``np.sort``."""
    m = a.shape[0]
    for root in range(m // 2 - 1, -1, -1):
        _sift_down(a, root, m)
    for end in range(m - 1, 0, -1):
        a[0], a[end] = a[end], a[0]
        _sift_down(a, np.int64(0), end)  # not a literal 0: one compile


@njit(cache=True, _nrt=True)  # it allocates: compiled with reference counting even when called from a loop_kernel
def _sorted_threshold(w, n):
    """(c, n_large) by sorting, O(M log M): keeping the k largest, c_k = (sum of the rest) / (n - k);
    the first k with the (k+1)-th largest below c_k is the solution (the k-th is then >= c_k)."""
    m = w.shape[0]
    ascending = w.copy()
    _heapsort(ascending)
    below = np.empty(m)  # below[i] = sum of the i + 1 smallest, added in order: tails without cancellation
    acc = 0.0
    for i in range(m):
        acc += ascending[i]
        below[i] = acc
    for k in range(n):
        c = below[m - 1 - k] / (n - k)
        if ascending[m - 1 - k] < c:
            return c, k
    return ascending[m - n], n  # the n - 1 smallest weigh less than the rounding of the rest


@loop_kernel
def _optimal_threshold(w, n, max_rounds=8):
    """(c, n_large) for M > n positive weights ``w`` summing to 1: c solves
    ``sum_i min(1, w_i / c) = n``, and exactly ``n_large < n`` weights are >= c.

    Fixed point, O(M) a round: from c = 1/n, c <- (sum of the w < c) / (n - #{w >= c}) until no
    weight crosses c. With f(c) = sum min(1, w / c) decreasing and c >= c* (f(c) <= n), the
    update stays >= c* (the weights set aside are all >= c*) and is <= c (f(c) <= n), so c
    decreases to c*, adding weights to the large set each round; once none is added, c solves the
    equation. Rarely more than 3 rounds; after ``max_rounds`` it sorts instead (O(M log M))."""
    c = 1.0 / n
    n_large = -1
    for _ in range(max_rounds):
        count = 0
        rest = 0.0
        for i in range(w.shape[0]):
            if w[i] >= c:
                count += 1
            else:
                rest += w[i]
        if count == n_large or count >= n:
            break
        n_large = count
        c = rest / (n - count)
    else:
        return _sorted_threshold(w, n)
    if count >= n:  # rounding pushed c below c*: sort
        return _sorted_threshold(w, n)
    return c, n_large


@loop_kernel
def optimal_keep_into(w, n, uniform, order, indices, weights):
    """Kernel of :func:`optimal_resampling` for callers whose input is already valid: ``w`` (M,)
    non-negative, summing to 1, ``n >= 1``, ``uniform`` in [0, 1), ``order`` (M,) a permutation:
    the order in which the strata walk the children (any order fixed before the uniform is drawn
    keeps the scheme unbiased; children of similar states next to each other spread the draws
    over the states). Writes the kept children's indices (in walk order) and weights into the
    first ``kept`` entries of ``indices`` and ``weights`` (each at least ``n`` long) and returns
    ``(kept, c)``. O(M), no allocation."""
    m = w.shape[0]
    positive = 0
    for i in range(m):
        if w[i] > 0.0:
            positive += 1
    if positive <= n:
        j = 0
        for i in order:
            if w[i] > 0.0:
                indices[j] = i
                weights[j] = w[i]
                j += 1
        return positive, 0.0
    c, n_large = _optimal_threshold(w, n)
    small_total = 0.0  # summed in the order the strata are walked, so the last stratum fits
    for i in order:
        if w[i] < c:
            small_total += w[i]
    n_small = n - n_large  # 0 only when the children below c weigh less than the rounding of the rest
    step = small_total / n_small if n_small > 0 else 0.0
    position = uniform * step  # the strata are [j step, (j + 1) step), one point in each
    drawn = 0
    cumulative = 0.0
    kept = 0
    for i in order:
        if w[i] >= c:
            if kept < n:  # more than n at c only through ties after rounding: keep the first n
                indices[kept] = i
                weights[kept] = w[i]
                kept += 1
            continue
        cumulative += w[i]
        if drawn < n_small and position < cumulative and kept < n:  # w[i] < step: at most one point falls in it
            indices[kept] = i
            weights[kept] = step
            kept += 1
            drawn += 1
            position += step
    return kept, c


@loop_kernel
def draw_by_inversion(marginals, uniforms, labels):
    """``labels[s, i]`` <- the count of b with ``uniforms[s, i] * T >= F_b``, at most K - 1, for
    ``F`` the running sums of ``marginals[s, i]`` (S, N, K) and ``T`` their total: label b drawn
    with probability ``marginals[s, i, b] / T`` by one uniform (``uniforms`` (S, N) in [0, 1)). The
    sums are numpy's ``cumsum`` (left to right), so the labels are those of the numpy expression.
    O(S N K)."""
    k = marginals.shape[2]
    for s in range(marginals.shape[0]):
        for i in range(marginals.shape[1]):
            total = 0.0
            for b in range(k):
                total += marginals[s, i, b]
            u = uniforms[s, i] * total
            running = 0.0
            count = 0
            for b in range(k):
                running += marginals[s, i, b]
                if u >= running:
                    count += 1
            labels[s, i] = min(count, k - 1)
