"""numba kernels of the Rao-Blackwellised particle filter (``estimators/rbpf.py``).

Particle state: ``locations (P,)`` int64, ``maps (P, N, K)`` float64 per-cell label marginals,
``stamps (P, N)`` int64, the step at which each (particle, cell) marginal was last brought up
to date. With lazy dynamics the marginal of cell i at step t is
``maps[p, i] @ powers[t - stamps[p, i]]`` (``powers[d] = C^d``); a static world passes
``dynamic=False`` and the stamps are never read (a (P, 0) array will do).

A step reads and writes only the cells a particle may be in (its cell and the intended
neighbour): O(P K^2), independent of N. Resampling copies the rows of the particles that
replace dropped ones: O(P_dropped N K).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True)
def _current(maps, stamps, powers, dynamic, t, p, cell, out):
    """out (K,) <- marginal of ``cell`` for particle ``p`` at step ``t``."""
    k = out.shape[0]
    if dynamic and stamps[p, cell] != t:
        c = powers[t - stamps[p, cell]]
        for b in range(k):
            acc = 0.0
            for a in range(k):
                acc += maps[p, cell, a] * c[a, b]
            out[b] = acc
    else:
        for b in range(k):
            out[b] = maps[p, cell, b]


@njit(cache=True)
def _dot(x, y):
    acc = 0.0
    for b in range(x.shape[0]):
        acc += x[b] * y[b]
    return acc


@njit(cache=True)
def rbpf_propose(locations, maps, stamps, powers, dynamic, t, ancestors, neighbors, p_move, likelihood,
                 optimal, uniforms, new_locations, new_cells, log_increments):
    """Propose every particle's step-t location and weight it; writes nothing to the state.

    Particle ``p`` descends from ``ancestors[p]``. ``neighbors`` (N,) is ``neighbors[:, a]``
    (pass ``locations``-independent ``arange(N)`` for step 0: no motion). Candidates are the
    ancestor's cell ``l`` (probability ``1 - p_move``, or 1 where the move is impossible) and
    ``n = neighbors[l]`` (``p_move``). Transition proposal: draw from the motion model,
    increment = ``P(z | l_t, map_p)``. Optimal proposal: draw from ``P(l_t | l, a, z, map_p)``,
    increment = ``sum_l' T[a, l, l'] P(z | l', map_p)``. Outputs: ``new_locations`` (P,),
    ``new_cells`` (P, K) the observed cell's updated marginal, ``log_increments`` (P,)
    (-inf where z is impossible). One uniform per particle. O(P K^2).
    """
    n_particles = ancestors.shape[0]
    k = likelihood.shape[0]
    here = np.empty(k)
    there = np.empty(k)
    for p in range(n_particles):
        q = ancestors[p]
        l = locations[q]
        n = neighbors[l]
        _current(maps, stamps, powers, dynamic, t, q, l, here)
        lam_here = _dot(here, likelihood)
        target = l
        lam = lam_here
        weight = lam_here
        if n != l:
            _current(maps, stamps, powers, dynamic, t, q, n, there)
            lam_there = _dot(there, likelihood)
            if optimal:
                move = p_move * lam_there
                weight = move + (1.0 - p_move) * lam_here
                if uniforms[p] * weight < move:
                    target, lam = n, lam_there
            elif uniforms[p] < p_move:
                target, lam, weight = n, lam_there, lam_there
        new_locations[p] = target
        source = there if target != l else here
        if lam > 0.0:
            for b in range(k):
                new_cells[p, b] = source[b] * likelihood[b] / lam
            log_increments[p] = math.log(weight)
        else:
            for b in range(k):
                new_cells[p, b] = source[b]
            log_increments[p] = -np.inf


@njit(cache=True)
def rbpf_commit(locations, maps, stamps, dynamic, t, ancestors, new_locations, new_cells):
    """Apply a proposal in place: copy the rows of ancestors into the slots that take them
    (``ancestors[p] != p``; such ancestors keep their own slot, so sources are never
    overwritten), then set each particle's location and observed cell (stamped ``t``).
    Cost O(N K) per copied row + O(P K)."""
    n_particles = ancestors.shape[0]
    for p in range(n_particles):
        q = ancestors[p]
        if q != p:
            maps[p] = maps[q]
            if dynamic:
                stamps[p] = stamps[q]
    for p in range(n_particles):
        cell = new_locations[p]
        locations[p] = cell
        maps[p, cell] = new_cells[p]
        if dynamic:
            stamps[p, cell] = t


@njit(cache=True)
def in_place_ancestors(counts):
    """Ancestor of every slot given the copy counts (P,) of a resampling: a particle with at
    least one copy keeps its slot, its extra copies fill the slots of dropped particles. O(P)."""
    n = counts.shape[0]
    ancestors = np.arange(n)
    free = 0
    for q in range(n):
        for _ in range(counts[q] - 1):
            while counts[free] > 0:
                free += 1
            ancestors[free] = q
            free += 1
    return ancestors


@njit(cache=True)
def rbpf_map_mixture(maps, stamps, powers, dynamic, t, weights, out):
    """out (N, K) <- ``sum_p weights[p] * current marginals of particle p``. One read of
    ``maps``; with lazy dynamics K^2 flops per out-of-date (particle, cell). O(P N K^2)."""
    n_particles, n_cells, k = maps.shape
    out[:] = 0.0
    tmp = np.empty(k)
    for p in range(n_particles):
        w = weights[p]
        if w == 0.0:
            continue
        for i in range(n_cells):
            if dynamic and stamps[p, i] != t:
                c = powers[t - stamps[p, i]]
                for b in range(k):
                    acc = 0.0
                    for a in range(k):
                        acc += maps[p, i, a] * c[a, b]
                    tmp[b] = acc
                for b in range(k):
                    out[i, b] += w * tmp[b]
            else:
                for b in range(k):
                    out[i, b] += w * maps[p, i, b]
