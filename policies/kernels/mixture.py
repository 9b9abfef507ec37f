"""numba kernel of the rollouts' uncertainty (:mod:`policies.kernels.footprint`): ``U =
location_weight * H(L) + sum_i H(M_i)`` of a thinned particle belief whose particles keep their
changed cells in overlays, recomputed only where the particles' maps differ (the disputed cells)
or some particle wrote (the touched cells); every other cell's term is summed once per step count
by the caller. Marginals are carried by ``C^d`` by the RBPF's rule (``onlinemap.kernels.rbpf.carried``).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from onlinemap.kernels import aligned, inner_kernel
from onlinemap.kernels.rbpf import carried

from .planning import entropy


class Mixture(NamedTuple):
    """Scratch of :func:`mixture_uncertainty`: the disputed cells' base marginals ``maps`` (R, D
    K) (a particle's row contiguous for the sums), their mixture ``mixed`` (1, D, K), ``mask`` (N,)
    marking them; ``location`` (N,) and ``cells`` (N, K) zero between calls; ``weights`` (R,)."""

    maps: np.ndarray
    mixed: np.ndarray
    mask: np.ndarray
    location: np.ndarray
    cells: np.ndarray
    weights: np.ndarray


@njit(cache=True)
def disputed_cells(maps):
    """(D,) sorted: the cells c whose rows ``maps[p, c]`` (``maps`` (R, N, K)) are not all equal to
    particle 0's (``!=`` entry by entry, particle 0's own row included: a NaN is disputed). One pass
    over the maps, particle by particle (each row read in order). O(R N K) time, O(N) memory."""
    r_count, n_cells, k = maps.shape
    flags = np.zeros(n_cells, dtype=np.bool_)
    for p in range(r_count):
        for c in range(n_cells):
            if not flags[c]:
                for b in range(k):
                    if maps[p, c, b] != maps[0, c, b]:
                        flags[c] = True
    return np.flatnonzero(flags)


def mixture_scratch(maps, disputed):
    """:func:`mixture_uncertainty`'s scratch (:class:`Mixture`) for the particles' ``maps`` (R, N,
    K) and the ``disputed`` cells (D,). O(R D K + N K)."""
    r_count, n_cells, k = maps.shape
    mask = aligned(n_cells, np.bool_, 0)
    mask[disputed] = True
    disputed_maps = aligned((r_count, disputed.shape[0] * k))
    disputed_maps.reshape(r_count, disputed.shape[0], k)[:] = maps[:, disputed, :]
    return Mixture(disputed_maps, aligned((1, disputed.shape[0], k)), mask, aligned(n_cells, fill=0.0),
                   aligned((n_cells, k), fill=0.0), aligned(r_count))


@njit(cache=True, inline="always")
def _location_entropy(loc, lw, mixture):
    """H(L) of the particles at ``loc`` (R,) weighted by ``exp(lw)`` (into ``mixture.weights``);
    ``mixture.location`` zero on entry and on exit. O(R)."""
    location, weights = mixture.location, mixture.weights
    for p in range(loc.shape[0]):
        location[loc[p]] = 0.0
        weights[p] = math.exp(lw[p])
    for p in range(loc.shape[0]):
        location[loc[p]] += weights[p]
    h_location = 0.0
    for p in range(loc.shape[0]):
        x = location[loc[p]]
        if x > 0.0:
            h_location -= x * math.log(x)
            location[loc[p]] = 0.0  # each cell once
    return h_location


@njit(cache=True, inline="always")
def _add_entropies(total, disputed, mask, touched_list, n_touched, cells):
    """``total`` plus the entropy of every disputed and touched row of ``cells`` (N, K) (negative
    rounding clipped), each once, in that order; those rows are zeroed. O((D + T) K)."""
    for pass_ in range(2):
        count = disputed.shape[0] if pass_ == 0 else n_touched
        for index in range(count):
            c = disputed[index] if pass_ == 0 else touched_list[index]
            if pass_ == 1 and mask[c]:
                continue
            for b in range(cells.shape[1]):
                if cells[c, b] < 0.0:  # rounding: keep every term a probability
                    cells[c, b] = 0.0
            total += entropy(cells[c])
            cells[c] = 0.0
    return total


@inner_kernel
def mixture_uncertainty(loc, lw, maps, ov, tables, h, location_weight, n_touched, agreed, disputed, mixture):
    """``location_weight * H(L) + sum_i H(M_i)`` of the weighted particles at step h. The mixture
    ``M_i = sum_p w_p m_p(i)`` is recomputed on the ``disputed`` cells (D,) and the touched ones:
    the base part by a weighted sum (into ``mixture.mixed``, particle by particle: one long
    contiguous loop per particle instead of a K-long one per cell and particle, the same sums in
    the same order), then each particle's overlay slots add ``w_p (overlay - base)``. Every other
    cell's term is the same for any weights: ``agreed`` holds their sum at step h (a touched
    agreed cell's term is taken out and recomputed). O(R D K + R H F K + (D + T) K) (K^2 instead
    of K with map dynamics)."""
    k = maps.shape[2]
    powers, base = tables.powers, h if tables.dynamic else 0
    cells, weights = mixture.cells, mixture.weights
    total = location_weight * _location_entropy(loc, lw, mixture) + agreed
    flat = mixture.mixed.reshape(disputed.shape[0] * k)
    for j in range(flat.shape[0]):
        flat[j] = 0.0
    for p in range(loc.shape[0]):
        w = weights[p]
        if w > 0.0:
            for j in range(flat.shape[0]):
                flat[j] += w * mixture.maps[p, j]
    for d in range(disputed.shape[0]):
        for b in range(k):
            cells[disputed[d], b] = carried(mixture.mixed, powers, base, 0, d, b)
    for index in range(n_touched):
        c = ov.touched_list[index]
        if not mixture.mask[c]:  # an agreed cell a particle changed: its base term leaves the sum
            for b in range(k):
                cells[c, b] = carried(maps, powers, base, 0, c, b)
            total -= entropy(cells[c])
    for p in range(loc.shape[0]):
        w = weights[p]
        if w == 0.0:
            continue
        for j in range(ov.n[p]):
            c = ov.cell[p, j]
            d = h - ov.stamp[p, j] if tables.dynamic else 0
            for b in range(k):
                cells[c, b] += w * (carried(ov.val, powers, d, p, j, b) - carried(maps, powers, base, p, c, b))
    return _add_entropies(total, disputed, mixture.mask, ov.touched_list, n_touched, cells)
