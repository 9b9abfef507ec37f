"""numba kernels of the RBPF's recovery from particle depletion (``estimators/rbpf_recovery.py``):
the relocated children's weights and maps, and their placement into the slots. The math is in
the class docstring of :class:`~onlinemap.estimators.rbpf.RaoBlackwellisedPF`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .rbpf import age, carried
from .rbpf_commit import children_by_location, copy_child, place_children


@njit(cache=True)
def _landing(l, world, readings, ids, factors):
    """What a robot put down at ``l`` sees: returns the number U of cells it touches, or -1 when the
    readings' off-grid pattern does not fit ``l`` (an offset off the grid reads -1 exactly). Writes
    ``ids[:U]`` the cells (``l`` first with blocking labels: it must be passable) and ``factors[:U]``
    (U, K) the likelihood of each label of each: ``[label passable]`` for ``l`` with blocking labels,
    times ``sensor[label, z_f]`` for every offset f reading the cell. O(F K)."""
    footprint_cells, sensor, blocking = world.footprint_cells, world.sensor, world.blocking
    k = sensor.shape[0]
    used = 0
    if world.has_blocking:
        ids[0] = l
        for b in range(k):
            factors[0, b] = 0.0 if blocking[b] else 1.0
        used = 1
    for f in range(footprint_cells.shape[1]):
        c = footprint_cells[l, f]
        z = readings[f]
        if c < 0 or z < 0:
            if c < 0 and z < 0:
                continue
            return -1
        w = used
        for v in range(used):
            if ids[v] == c:
                w = v
        if w == used:
            ids[w] = c
            for b in range(k):
                factors[w, b] = 1.0
            used += 1
        for b in range(k):
            factors[w, b] *= sensor[b, z]
    return used


@njit(cache=True, inline="always")
def _landing_cell(rows, stamps, powers, dynamic, t, r, j, prior_cell, factor, q):
    """``q`` (K,) <- the current marginal of slot j of row r, or ``prior_cell`` (a reset) when that
    marginal gives what the child sees of the cell (``factor`` (K,)) probability 0. Returns
    ``(q @ factor, reset)``. O(K^2)."""
    k = factor.shape[0]
    d = age(stamps, dynamic, t, r, j)
    lam = 0.0
    for b in range(k):
        q[b] = carried(rows, powers, d, r, j, b)
        lam += q[b] * factor[b]
    if lam > 0.0:
        return lam, False
    lam = 0.0
    for b in range(k):
        q[b] = prior_cell[b]
        lam += q[b] * factor[b]
    return lam, True


@njit(cache=True)
def _grid_distances(moves, source, dist, queue):
    """``dist`` (N,) <- the fewest moves from ``source`` to every cell, labels ignored (-1 where no
    path). Breadth-first search over ``moves`` (A, N); ``queue`` (N,) scratch. O(N A)."""
    dist[:] = -1
    dist[source] = 0
    queue[0] = source
    head, tail = 0, 1
    while head < tail:
        c = queue[head]
        head += 1
        for a in range(moves.shape[0]):
            n = moves[a, c]
            if dist[n] < 0:
                dist[n] = dist[c] + 1
                queue[tail] = n
                tail += 1


@njit(cache=True)
def rbpf_relocation_weights(locations, log_weights, pool, world, t, scale, readings, prior, child_log_weight):
    """Log weights of the recovery children (l, p) of the live particles; returns the fewest resets
    R of a possible child, or -1 when no child is possible (nothing explains the readings).

    Child (l, p) is particle p relocated to cell l by the kernel ``K(l | l_p) = exp(-d / scale) / Z``
    (d the fewest moves from ``l_p``, labels ignored; Z the sum over the cells reachable from
    ``l_p``), seeing what :func:`_landing` says a robot at l sees. Each touched cell keeps p's
    marginal at step t unless that marginal gives what is seen of it probability 0; then it is
    redrawn from ``prior`` (N, K) (a reset; if that too gives 0 the child is impossible).
    ``child_log_weight`` (N, P) <- ``log w_p + log K(l | l_p) + sum log (q @ factor)`` for the
    children with R resets, -inf for the others. The particles are visited in order of location
    (a counting sort), one search per distinct location; any order within a location gives the
    same output. O(P N U K^2 + min(P, N) N A) time, N P bytes besides the output."""
    rows, stamps, table, cell_block, cell_slot, powers = (pool.rows, pool.stamps, pool.table, pool.cell_block,
                                                          pool.cell_slot, pool.powers)  # locals: kernels/rbpf.py
    dynamic, moves = pool.stamped, world.moves
    n_cells, n_particles = child_log_weight.shape
    ids, factors, used = _landings(world, readings)
    resets = np.zeros((n_cells, n_particles), dtype=np.int8)
    child_log_weight[:] = -np.inf
    dist = np.empty(n_cells, dtype=np.int64)
    queue = np.empty(n_cells, dtype=np.int64)
    q = np.empty(world.sensor.shape[0])
    fewest = -1
    source = -1
    log_z = 0.0
    order = np.empty(n_particles, dtype=np.int64)  # by location (a counting sort; the result needs no other order)
    children_by_location(locations, np.zeros(n_cells + 1, dtype=np.int64), order)
    for p in order:
        if log_weights[p] == -np.inf:
            continue
        if locations[p] != source:
            source = locations[p]
            _grid_distances(moves, source, dist, queue)
            log_z = _log_normaliser(dist, scale)
        for l in range(n_cells):
            if dist[l] < 0 or used[l] < 0:
                continue
            total = log_weights[p] - dist[l] / scale - log_z
            count = 0
            for w in range(used[l]):
                c = ids[l, w]
                lam, reset = _landing_cell(rows, stamps, powers, dynamic, t, table[p, cell_block[c]],
                                           cell_slot[c], prior[c], factors[l, w], q)
                if lam <= 0.0:
                    total = -np.inf
                    break
                total += math.log(lam)
                if reset:
                    count += 1
            if total == -np.inf or (fewest >= 0 and count > fewest):
                continue
            child_log_weight[l, p] = total
            resets[l, p] = count
            if fewest < 0 or count < fewest:
                fewest = count
    _drop_more_resets(child_log_weight, resets, fewest)
    return fewest


@njit(cache=True)
def _landings(world, readings):
    """(ids (N, W), factors (N, W, K), used (N,)): :func:`_landing` of every cell."""
    n_cells, width = world.footprint_cells.shape[0], world.footprint_cells.shape[1] + 1
    ids = np.empty((n_cells, width), dtype=np.int64)
    factors = np.empty((n_cells, width, world.sensor.shape[0]))
    used = np.empty(n_cells, dtype=np.int64)
    for l in range(n_cells):
        used[l] = _landing(l, world, readings, ids[l], factors[l])
    return ids, factors, used


@njit(cache=True)
def _log_normaliser(dist, scale):
    """``log Z``, Z the sum of the relocation kernel's ``exp(-d / scale)`` over the cells a search
    reached (``dist`` (N,) >= 0), in cell order."""
    z_sum = 0.0
    for l in range(dist.shape[0]):
        if dist[l] >= 0:
            z_sum += math.exp(-dist[l] / scale)
    return math.log(z_sum)


@njit(cache=True)
def _drop_more_resets(child_log_weight, resets, fewest):
    """``child_log_weight[l, p] <- -inf`` where child (l, p) took more than ``fewest`` resets."""
    for l in range(resets.shape[0]):
        for p in range(resets.shape[1]):
            if resets[l, p] > fewest:
                child_log_weight[l, p] = -np.inf


@njit(cache=True)
def rbpf_relocated_children(child_parent, child_location, pool, world, t, readings, prior, child_ids, child_cells):
    """The maps of recovery children (:func:`rbpf_relocation_weights`; kept ones, M of them): parent
    ``child_parent[i]`` relocated to ``child_location[i]``. ``child_ids`` (M, W) <- the cells the
    child touches (-1 pads), ``child_cells`` (M, W, K) <- their marginals at step t given what it
    sees (``q * factor / (q @ factor)``, q the parent's marginal or, where that gives 0, the
    prior: the same rule as the weights). O(M U K^2)."""
    rows, stamps, table, cell_block, cell_slot, powers = (pool.rows, pool.stamps, pool.table, pool.cell_block,
                                                          pool.cell_slot, pool.powers)  # locals: kernels/rbpf.py
    dynamic = pool.stamped
    k = world.sensor.shape[0]
    width = child_ids.shape[1]
    ids = np.empty(width, dtype=np.int64)
    factors = np.empty((width, k))
    q = np.empty(k)
    child_ids[:] = -1
    child_cells[:] = 0.0
    for i in range(child_parent.shape[0]):
        p, l = child_parent[i], child_location[i]
        used = _landing(l, world, readings, ids, factors)
        for w in range(used):
            c = ids[w]
            lam, _ = _landing_cell(rows, stamps, powers, dynamic, t, table[p, cell_block[c]], cell_slot[c],
                                   prior[c], factors[w], q)
            child_ids[i, w] = c
            for b in range(k):
                child_cells[i, w, b] = q[b] * factors[w, b] / lam


@njit(cache=True)
def rbpf_place_children(child_parent, child_location, child_ids, child_cells, kept, kept_weights, ancestors,
                        new_locations, new_ids, new_cells, new_log_weights):
    """Put kept children that carry their own changed cells (the recovery's relocated ones,
    :func:`rbpf_relocated_children`: their cells do not follow from the parent's map at the
    child's location, so :func:`rbpf_commit_children` cannot recompute them) into the P slots as
    :func:`place_children` places Fearnhead-Clifford's, for :func:`rbpf_commit_cells`. A child's
    ``child_ids`` (M, W) and ``child_cells`` (M, W, K) go with it. Slots left without a child
    (fewer children than P) get ``new_locations = -1`` (no write) and weight 0. Outputs (P,)
    ancestors, (P,), (P, W), (P, W, K), (P,). O(P W K)."""
    n_particles = ancestors.shape[0]
    slot_child = np.empty(n_particles, dtype=np.int64)
    place_children(child_parent, kept, kept_weights, ancestors, slot_child, new_log_weights,
                   np.zeros(n_particles, dtype=np.bool_), np.zeros(n_particles, dtype=np.bool_))
    new_ids[:] = -1
    new_cells[:] = 0.0
    for p in range(n_particles):
        c = slot_child[p]
        new_locations[p] = -1
        if c >= 0:
            new_locations[p] = child_location[c]
            copy_child(child_ids, child_cells, c, new_ids, new_cells, p)
