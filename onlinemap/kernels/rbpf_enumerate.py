"""numba kernels of the RBPF's children (``estimators/rbpf.py``): every successor of every particle
with its exact weight (Fearnhead-Clifford's enumeration), the changed cells of a child (blocking
labels, sensor footprints), and the sampling schemes' proposal. They read the particle maps
(:class:`~onlinemap.kernels.rbpf.Pool`) and write only the arrays they are given.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from . import PREFETCH_AHEAD, loop_kernel, thread_kernel
from .rbpf import Pool, World, age, carried, evidence, observed_cell, prefetch_cell


class Children(NamedTuple):
    """A step's children, M of them in the first M entries (2P long): ``parent``, ``location``,
    ``log_weight``; with a footprint or blocking labels and when stored (the sampling schemes; 0
    rows otherwise), ``log_motion`` (each child's ``log T``), ``ids (2P, W)`` the cells its map
    changes (-1: none) and ``cells (2P, W, K)`` their marginals at step t."""

    parent: np.ndarray
    location: np.ndarray
    log_weight: np.ndarray
    log_motion: np.ndarray
    ids: np.ndarray
    cells: np.ndarray


class FootprintScratch(NamedTuple):
    """Scratch of the footprint kernels (:func:`footprint_child`): ``before``, ``given`` (K,),
    ``lams`` (F,), ``ids`` (W,), ``cells`` (W, K)."""

    before: np.ndarray
    given: np.ndarray
    lams: np.ndarray
    ids: np.ndarray
    cells: np.ndarray


#: where each bundle's fields end in the ``*fields`` of :func:`enumerate_cells_run` (children, scratch, world, pool)
_CHILDREN_END = len(Children._fields)
_SCRATCH_END = _CHILDREN_END + len(FootprintScratch._fields)
_WORLD_END = _SCRATCH_END + len(World._fields)


def footprint_scratch(k: int, f: int, width: int) -> FootprintScratch:
    """Fresh :class:`FootprintScratch` for K labels, F readings and W written cells."""
    return FootprintScratch(np.empty(k), np.empty(k), np.empty(f), np.empty(width, dtype=np.int64),
                            np.empty((width, k)))


class Proposed(NamedTuple):
    """The sampling proposal's outputs (P,): each slot's new ``locations`` (-1: no write), its
    observed cell's marginal ``cells`` (P, K), its ``log_increments``."""

    locations: np.ndarray
    cells: np.ndarray
    log_increments: np.ndarray


@njit(cache=True, inline="always")
def successor(l, n, p_move, s):
    """(cell, probability) of successor s in {0, 1} of a robot at ``l`` whose action points at ``n``:
    0 = stay (``1 - p_move``, or 1 where there is no move), 1 = the move (``p_move``; none where
    ``n == l``). The one place the FC enumeration learns the motion model's successors."""
    if s == 0:
        return l, (1.0 if n == l else 1.0 - p_move)
    return n, (0.0 if n == l else p_move)


@njit(cache=True, inline="always")
def _parent(locations, log_weights, neighbors, q):
    """(live, l, n) of particle q: whether it has weight, its cell, the cell its action points at."""
    l = locations[q]
    return log_weights[q] != -np.inf, l, neighbors[l]


@njit(cache=True, inline="always")
def prefetch_footprint(pool, footprint_cells, q, cell):
    """Ask for particle q's marginals of the cells a robot at ``cell`` reads."""
    for f in range(footprint_cells.shape[1]):
        if footprint_cells[cell, f] >= 0:
            prefetch_cell(pool, q, footprint_cells[cell, f])


@njit(cache=True, inline="always")
def _prefetch_parent(locations, pool, neighbors, q):
    """Ask for the two cells particle q reads in a step (its own and the one its action points at)."""
    l = locations[q]
    prefetch_cell(pool, q, l)
    prefetch_cell(pool, q, neighbors[l])


@njit(cache=True)
def _sum_of_logs(values, n):
    """``sum_i log(values[i])`` over the first n, in order (not inlined: it is the rare path, and
    an inlined loop over an array in a branch costs reference counting on every call)."""
    total = 0.0
    for i in range(n):
        total += math.log(values[i])
    return total


@njit(cache=True, inline="always")
def _log_weight(log_weight, probability, likelihood, lams, n_reads):
    """``log_weight + log(probability * likelihood)``: one log per child; where the product
    underflows, ``log(probability)`` plus the sum of the logs of the ``n_reads`` factors ``lams``
    of ``likelihood`` (in their order)."""
    joint = probability * likelihood
    return log_weight + (math.log(joint) if joint > 0.0 else math.log(probability) + _sum_of_logs(lams, n_reads))


def rbpf_enumerate(locations: np.ndarray, log_weights: np.ndarray, pool, world, t: int, neighbors: np.ndarray,
                   likelihood: np.ndarray, children: Children) -> int:
    """Every successor of every live particle with its exact log weight; returns their number M.

    For parent q at l (``log_weights[q] > -inf``) and each successor j of l with motion probability
    ``T(l, j) > 0`` (:func:`successor`; ``neighbors = arange(N)`` at step 0: stay only):
    ``log w_q + log T(l, j) + log P(z | j, map_q)``, ``likelihood (K,)`` the reading's. Children
    with probability zero are left out. Writes the first M entries of ``children``'s parent,
    location and log weight, grouped by parent in increasing order. A child's observed cell (the
    posterior of cell j given z) is not stored: ``rbpf_commit_children`` computes it for the
    children kept. O(P K^2). (A Python function: its kernel, :func:`enumerate_run` on every parent, is
    the one the threads run on runs of parents, compiled once for both.)"""
    return enumerate_run(locations, log_weights, world.p_move, t, neighbors, likelihood, 0, len(locations), 0,
                         np.empty(1), *children[:3], *pool)


@thread_kernel
def enumerate_run(locations, log_weights, p_move, t, neighbors, likelihood, start, stop, out, lams, *fields):
    """:func:`rbpf_enumerate` of parents ``start..stop - 1``, their children written from index
    ``out`` on; returns their number. ``lams`` (1,) scratch; ``*fields``: the children's
    ``parent``, ``location`` and ``log_weight`` (the first three fields of :class:`Children`),
    then the pool's fields; ``p_move``, not the model's :class:`~onlinemap.kernels.rbpf.World`
    (``kernels/rbpf.py``: bundles and dispatch)."""
    child_parent, child_location, child_log_weight = fields[0], fields[1], fields[2]
    pool = Pool(*fields[3:])
    rows, powers, table, cell_block, cell_slot = pool.rows, pool.powers, pool.table, pool.cell_block, pool.cell_slot
    m = max(out, 0)  # max(., 0): indices known nonnegative, no code for negative ones (5% faster, measured)
    for q in range(max(start, 0), stop):
        if q + PREFETCH_AHEAD < stop and log_weights[q + PREFETCH_AHEAD] != -np.inf:
            _prefetch_parent(locations, pool, neighbors, q + PREFETCH_AHEAD)
        live, l, n = _parent(locations, log_weights, neighbors, q)
        if not live:
            continue
        for s in range(2):
            j, probability = successor(l, n, p_move, s)
            if probability <= 0.0:
                continue
            r = table[q, cell_block[j]]
            lam = evidence(rows, powers, age(pool.stamps, pool.stamped, t, r, cell_slot[j]), r, cell_slot[j],
                           likelihood)
            if lam <= 0.0:
                continue
            lams[0] = lam
            child_log_weight[m] = _log_weight(log_weights[q], probability, lam, lams, 1)
            child_parent[m] = q
            child_location[m] = j
            m += 1
    return m - out


@njit(cache=True, inline="always")
def passable_before(pool, table_row, world, t, n, before):
    """P(cell n passable) for the map whose block rows are ``table_row`` (n_blocks,), judged at
    step t - 1 (before this step's map change); ``before`` (K,) <- n's marginal at t - 1."""
    r = table_row[pool.cell_block[n]]
    d = 0
    if pool.stamped:
        d = t - 1 - pool.stamps[r, pool.cell_slot[n]]
    passable = 0.0
    for b in range(before.shape[0]):
        before[b] = carried(pool.rows, pool.powers, d, r, pool.cell_slot[n], b)
        if not world.blocking[b]:
            passable += before[b]
    return passable


@njit(cache=True, inline="always")
def gated_successor(l, n, p_move, s, gated, passable):
    """(cell, probability) of successor s (:func:`successor`), a gated move's success scaled by
    P(n passable)."""
    j, probability = successor(l, n, p_move, s)
    if gated:
        probability = probability * passable if s == 1 else 1.0 - p_move * passable
    return j, probability


@njit(cache=True, inline="always")
def _gated_cell(world, dynamic, moved, scratch, cells):
    """``cells[0]`` <- the intended cell's marginal given the move's outcome (``moved``), judged
    at t - 1 (``scratch.before``, :func:`passable_before`), times the press's factor
    (``world.press``, row 0 entered, row 1 stayed), and carried to step t by C."""
    k = cells.shape[1]
    given, before, press = scratch.given, scratch.before, world.press
    row = 0 if moved else 1
    total = 0.0
    for b in range(k):
        given[b] = before[b] * press[row, b]
        total += given[b]
    if total > 0.0:  # else the outcome is impossible (p_move = 1 and the cell surely passable, or the
        for b in range(k):  # cell surely blocks): the child has probability 0, so its cell is never used
            given[b] /= total
    for b in range(k):
        if dynamic:
            acc = 0.0
            for a in range(k):
                acc += given[a] * world.change[a, b]
            cells[0, b] = acc
        else:
            cells[0, b] = given[b]


@njit(cache=True, inline="always")
def footprint_child(pool, table_row, world, t, j, n, gated, readings, scratch, ids, cells, posteriors):
    """The map changes of a child at cell j of a parent whose action points at n (a move when
    ``j == n``) and whose map has block rows ``table_row``, as :func:`rbpf_enumerate_cells` defines
    them: ``ids`` (W,) the changed cells (-1 pads), ``cells`` (W, K) their marginals at step t,
    ``scratch.lams`` (F,) the likelihood of each on-grid reading in turn. ``scratch.before``: n's
    marginal at t - 1 (:func:`passable_before`, when ``gated``). Without ``posteriors`` the read
    cells keep their prior in ``cells`` (the likelihood is the same: a footprint reads each cell
    once, after the move's evidence, and its divisions are most of the cost). Returns (n_reads,
    likelihood), ``n_reads = -1`` where the readings are impossible for this child. O(F (W + K))."""
    k = world.sensor.shape[0]
    footprint_cells, sensor, lams = world.footprint_cells, world.sensor, scratch.lams
    used = 0
    if gated:
        _gated_cell(world, pool.stamped, j == n, scratch, cells)
        ids[0] = n
        used = 1
    likelihood = 1.0
    n_reads = 0
    possible = True
    f = 0
    while possible and f < footprint_cells.shape[1]:
        c = footprint_cells[j, f]
        z = readings[f]
        f += 1
        if c < 0 or z < 0:  # off the grid reads -1 with probability 1, a cell never does
            possible = c < 0 and z < 0
            continue
        w = used
        for v in range(used):  # a cell this child already changed (the move's evidence)
            if ids[v] == c:
                w = v
        if w == used:
            r = table_row[pool.cell_block[c]]
            d = age(pool.stamps, pool.stamped, t, r, pool.cell_slot[c])
            for b in range(k):
                cells[w, b] = carried(pool.rows, pool.powers, d, r, pool.cell_slot[c], b)
            ids[w] = c
            used += 1
        lam = 0.0
        for b in range(k):
            lam += cells[w, b] * sensor[b, z]
        possible = lam > 0.0
        if possible:
            if posteriors:
                for b in range(k):
                    cells[w, b] = cells[w, b] * sensor[b, z] / lam
            likelihood *= lam
            lams[n_reads] = lam
            n_reads += 1
    for v in range(used, ids.shape[0]):
        ids[v] = -1
    result = n_reads if possible else -1
    return result, likelihood


def rbpf_enumerate_cells(locations: np.ndarray, log_weights: np.ndarray, pool, world, t: int, neighbors: np.ndarray,
                         readings: np.ndarray, children: Children) -> int:
    """:func:`rbpf_enumerate` for blocking labels and sensor footprints; returns M.

    Blocking (``world.blocking`` (K,) bool, any True): from l the intended n != l is entered with
    ``p_move * P(m_n passable)``, judged on n's marginal at step t - 1 (before this step's map
    change); the move child's n is conditioned on passable, the stay child's on
    ``1 - p_move [m_n passable]`` (``world.press``), then carried to step t by C. Footprint
    (``world.footprint_cells`` (N, F), ``readings`` (F,), -1 off the grid): the likelihood is the
    product over the offsets of ``sum_k current(c_f)[k] sensor[k, z_f]`` (1 where both cell and
    reading are off the grid, 0 where only one is), and each read cell gets its posterior. Given
    the trajectory the cells stay independent, so a child's map differs from its parent's in at
    most W = F + 1 cells (:func:`footprint_child`). With ``children.cells`` of 2P rows (the
    sampling schemes) it stores them (:class:`Children`); with 0 rows (Fearnhead-Clifford, which
    recomputes the kept children's in ``rbpf_commit_children_cells``) only the parents, locations
    and log weights. Cost O(P F K^2). (A Python function: its kernel, :func:`enumerate_cells_run` on
    every parent, is the one the threads run on runs of parents, compiled once for both.)"""
    scratch = footprint_scratch(world.sensor.shape[0], world.footprint_cells.shape[1], children.ids.shape[1])
    return enumerate_cells_run(locations, log_weights, t, neighbors, readings, 0, len(locations), 0, *children,
                               *scratch, *world, *pool)


@njit(cache=True, inline="always")
def _store_child(children, m, ids, cells, probability):
    """Child m's changed cells ``ids`` (W,), ``cells`` (W, K) and log motion into ``children``."""
    for w in range(ids.shape[0]):
        children.ids[m, w] = ids[w]
        for b in range(cells.shape[1]):
            children.cells[m, w, b] = cells[w, b]
    children.log_motion[m] = math.log(probability)


@thread_kernel
def enumerate_cells_run(locations, log_weights, t, neighbors, readings, start, stop, out, *fields):
    """:func:`rbpf_enumerate_cells` of parents ``start..stop - 1``, their children written from
    index ``out`` on; returns their number. ``*fields``: the fields of the :class:`Children`, a
    :class:`FootprintScratch`, the :class:`~onlinemap.kernels.rbpf.World` and the pool, in that
    order (``kernels/rbpf.py``: bundles and dispatch)."""
    children, scratch = Children(*fields[:_CHILDREN_END]), FootprintScratch(*fields[_CHILDREN_END:_SCRATCH_END])
    world, pool = World(*fields[_SCRATCH_END:_WORLD_END]), Pool(*fields[_WORLD_END:])
    store = children.cells.shape[0] > 0
    m = max(out, 0)  # as in enumerate_run
    for q in range(max(start, 0), stop):
        ahead = q + PREFETCH_AHEAD
        if ahead < stop and log_weights[ahead] != -np.inf:
            _prefetch_parent(locations, pool, neighbors, ahead)
            prefetch_footprint(pool, world.footprint_cells, ahead, locations[ahead])
            prefetch_footprint(pool, world.footprint_cells, ahead, neighbors[locations[ahead]])
        live, l, n = _parent(locations, log_weights, neighbors, q)
        if not live:
            continue
        gated = world.has_blocking and n != l  # the move's success tells about cell n
        passable = 1.0
        if gated:
            passable = passable_before(pool, pool.table[q], world, t, n, scratch.before)
        for s in range(2):
            j, probability = gated_successor(l, n, world.p_move, s, gated, passable)
            if probability <= 0.0:
                continue
            n_reads, likelihood = footprint_child(pool, pool.table[q], world, t, j, n, gated, readings, scratch,
                                                  scratch.ids, scratch.cells, store)
            if n_reads < 0:
                continue
            if store:
                _store_child(children, m, scratch.ids, scratch.cells, probability)
            children.log_weight[m] = _log_weight(log_weights[q], probability, likelihood, scratch.lams, n_reads)
            children.parent[m] = q
            children.location[m] = j
            m += 1
    return m - out


@loop_kernel
def rbpf_propose(locations, p_move, t, ancestors, neighbors, likelihood, optimal, uniforms, *fields):
    """Propose every particle's step-t location and weight it; writes nothing to the state.

    Particle ``p`` descends from ``ancestors[p]``. ``neighbors`` (N,) is ``moves[a]`` (``arange(N)``
    at step 0: no motion). Candidates are the ancestor's cell ``l`` (probability ``1 - p_move``,
    or 1 where the move is impossible) and ``n = neighbors[l]`` (``p_move``). Transition proposal:
    draw from the motion model, increment = ``P(z | l_t, map_p)``. Optimal proposal: draw from
    ``P(l_t | l, a, z, map_p)``, increment = ``sum_l' T[a, l, l'] P(z | l', map_p)``. Outputs
    (:class:`Proposed`): the new locations (P,), the observed cell's updated marginal (P, K), the
    log increments (P,) (-inf where z is impossible). One uniform per particle. O(P K^2).
    ``*fields``: the :class:`Proposed` arrays, then the pool's fields (``kernels/rbpf.py``: bundles
    and dispatch).
    """
    proposed, pool = Proposed(fields[0], fields[1], fields[2]), Pool(*fields[3:])
    propose_run(locations, pool, p_move, t, ancestors, neighbors, likelihood, optimal, uniforms, proposed, np.int64(0),
                ancestors.shape[0])  # np.int64(0), not 0: one compile shared with the threads' calls


@njit(cache=True, inline="always")
def _lam(pool, q, t, cell, likelihood):
    """``P(z | cell, map_q)``: :func:`evidence` of particle q's marginal of ``cell``."""
    r = pool.table[q, pool.cell_block[cell]]
    return evidence(pool.rows, pool.powers, age(pool.stamps, pool.stamped, t, r, pool.cell_slot[cell]), r,
                    pool.cell_slot[cell], likelihood)


@thread_kernel
def propose_run(locations, pool, p_move, t, ancestors, neighbors, likelihood, optimal, uniforms, proposed, start, stop):
    """:func:`rbpf_propose` of particles ``start..stop - 1``."""
    for p in range(start, stop):
        if p + PREFETCH_AHEAD < stop:
            _prefetch_parent(locations, pool, neighbors, ancestors[p + PREFETCH_AHEAD])
        q = ancestors[p]
        l = locations[q]
        n = neighbors[l]
        lam_here = _lam(pool, q, t, l, likelihood)
        target = l
        lam = lam_here
        weight = lam_here
        if n != l:
            lam_there = _lam(pool, q, t, n, likelihood)
            if optimal:
                move = p_move * lam_there
                weight = move + (1.0 - p_move) * lam_here
                if uniforms[p] * weight < move:
                    target, lam = n, lam_there
            elif uniforms[p] < p_move:
                target, lam, weight = n, lam_there, lam_there
        proposed.locations[p] = target
        r = pool.table[q, pool.cell_block[target]]
        observed_cell(pool.rows, pool.powers, age(pool.stamps, pool.stamped, t, r, pool.cell_slot[target]), r,
                      pool.cell_slot[target], likelihood, lam, proposed.cells[p])
        proposed.log_increments[p] = math.log(weight) if lam > 0.0 else -np.inf
