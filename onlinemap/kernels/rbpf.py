"""numba kernels of the Rao-Blackwellised particle filter (``estimators/rbpf.py``).

Particle maps are stored as shared, copy-on-write blocks of B consecutive cells:

- ``pool (R, B, K)``: block rows of per-cell label marginals; ``pool_stamps (R, B)``: the step
  at which each marginal was last brought up to date (dynamic worlds with lazy dynamics; a
  (R, 0) array otherwise, never read); ``row_block (R,)``: which block of the map a row holds;
  ``refcount (R,)``: how many particles use the row; ``free (R,)`` with ``free_top (1,)``: a
  stack of unused rows.
- ``table (P, n_blocks)``: the row holding block b of particle p's map, so cell i of particle p
  is ``pool[table[p, cell_block[i]], cell_slot[i]]``; ``block_members (n_blocks, B)`` lists
  each block's cells (-1 pads a partial block). Blocks are runs of a corridor or square tiles
  of a 2D grid, so a robot stays in one block for several steps.

With lazy dynamics the marginal of a cell at step t is ``row @ powers[t - stamp]``
(``powers[d] = C^d``). Resampling copies table rows (n_blocks ints per particle that replaces
a dropped one) instead of maps; a particle writing into a shared block first copies that one
block (B K floats). A step reads two cells per particle: O(P K^2).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from . import PREFETCH_AHEAD, loop_kernel, prefetch, thread_kernel
from .resampling import optimal_keep_into


@njit(cache=True, inline="always")
def _age(pool_stamps, dynamic, t, r, j):
    """Steps since slot j of block row r was last brought up to date (0 in a static world)."""
    d = 0
    if dynamic:
        d = t - pool_stamps[r, j]
    return d


@njit(cache=True, inline="always")
def _aged_label(pool, powers, d, r, j, b):
    """P(label b) of slot j of block row r, ``d`` steps after its stamp: ``(row @ C^d)[b]``.

    (The inlined helpers here have one ``return`` statement and loops without ``break``: numba then
    prunes the reference counting of their array arguments, which otherwise costs atomic
    operations on every call, several times the arithmetic. ``return a if c else b`` is two.)"""
    value = pool[r, j, b]
    if d != 0:
        value = 0.0
        for a in range(pool.shape[2]):
            value += pool[r, j, a] * powers[d, a, b]
    return value


@njit(cache=True, inline="always")
def _evidence(pool, powers, d, r, j, likelihood):
    """``P(z | cell) = sum_b current(b) likelihood[b]`` for slot j of block row r, ``d`` steps
    after its stamp (:func:`_age`; the callers compute it: an age read inside a looping helper
    defeats the pruning of reference counts)."""
    acc = 0.0
    for b in range(likelihood.shape[0]):
        acc += _aged_label(pool, powers, d, r, j, b) * likelihood[b]
    return acc


@njit(cache=True, inline="always")
def _observed_cell(pool, powers, d, r, j, likelihood, lam, out):
    """out (K,) <- the posterior of slot j of row r (``d`` steps after its stamp) after seeing a
    label of likelihood ``likelihood`` (``lam`` = its evidence, from :func:`_evidence`); the prior
    unchanged where ``lam`` is 0."""
    for b in range(likelihood.shape[0]):  # divide (1 / lam overflows for a subnormal lam)
        current = _aged_label(pool, powers, d, r, j, b)
        out[b] = current * likelihood[b] / lam if lam > 0.0 else current


@njit(cache=True, inline="always")
def _successor(l, n, p_move, s):
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
def _prefetch_cell(pool, pool_stamps, table, cell_block, cell_slot, dynamic, q, cell):
    """Ask for particle q's marginal of ``cell`` (and its stamp) ahead of its use (:func:`prefetch`)."""
    r = table[q, cell_block[cell]]
    prefetch(pool, (r, cell_slot[cell], 0))
    if dynamic:
        prefetch(pool_stamps, (r, cell_slot[cell]))


@njit(cache=True, inline="always")
def _prefetch_child(pool, pool_stamps, table, cell_block, cell_slot, dynamic, ancestors, slot_child, child_location,
                    ahead, stop):
    """Ask for the marginal of the cell slot ``ahead``'s child enters, from its parent's rows, if
    that slot (below ``stop``) has a child (:func:`_prefetch_cell`)."""
    if ahead < stop and slot_child[ahead] >= 0:
        _prefetch_cell(pool, pool_stamps, table, cell_block, cell_slot, dynamic, ancestors[ahead],
                       child_location[slot_child[ahead]])


@njit(cache=True, inline="always")
def _prefetch_footprint(pool, pool_stamps, table, cell_block, cell_slot, dynamic, footprint_cells, q, cell):
    """Ask for particle q's marginals of the cells a robot at ``cell`` reads."""
    for f in range(footprint_cells.shape[1]):
        if footprint_cells[cell, f] >= 0:
            _prefetch_cell(pool, pool_stamps, table, cell_block, cell_slot, dynamic, q, footprint_cells[cell, f])


@njit(cache=True, inline="always")
def _prefetch_parent(locations, pool, pool_stamps, table, cell_block, cell_slot, dynamic, neighbors, q):
    """Ask for the two cells particle q reads in a step (its own and the one its action points at)."""
    l = locations[q]
    _prefetch_cell(pool, pool_stamps, table, cell_block, cell_slot, dynamic, q, l)
    _prefetch_cell(pool, pool_stamps, table, cell_block, cell_slot, dynamic, q, neighbors[l])


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


def rbpf_enumerate(locations: np.ndarray, log_weights: np.ndarray, pool: np.ndarray, pool_stamps: np.ndarray,
                   table: np.ndarray, cell_block: np.ndarray, cell_slot: np.ndarray, powers: np.ndarray,
                   dynamic: bool, t: int, neighbors: np.ndarray, p_move: float, likelihood: np.ndarray,
                   child_parent: np.ndarray, child_location: np.ndarray, child_log_weight: np.ndarray) -> int:
    """Every successor of every live particle with its exact log weight; returns their number M.

    For parent q at l (``log_weights[q] > -inf``) and each successor j of l with motion probability
    ``T(l, j) > 0`` (:func:`_successor`; ``neighbors = arange(N)`` at step 0: stay only):
    ``log w_q + log T(l, j) + log P(z | j, map_q)``. Children with probability zero are left out.
    Writes the first M entries of ``child_parent``, ``child_location`` and ``child_log_weight``
    (each at least 2P long), grouped by parent in increasing order. A child's observed cell (the
    posterior of cell j given z) is not stored: :func:`rbpf_commit_children` computes it for the
    children kept. O(P K^2). (A Python function: its kernel, :func:`_enumerate` on every parent, is
    the one the threads run on runs of parents, compiled once for both.)"""
    return _enumerate(locations, log_weights, pool, pool_stamps, table, cell_block, cell_slot, powers, dynamic, t,
                      neighbors, p_move, likelihood, child_parent, child_location, child_log_weight, 0,
                      len(locations), 0, np.empty(1))


@thread_kernel
def _enumerate(locations, log_weights, pool, pool_stamps, table, cell_block, cell_slot, powers, dynamic, t, neighbors,
               p_move, likelihood, child_parent, child_location, child_log_weight, start, stop, out, lams):
    """:func:`rbpf_enumerate` of parents ``start..stop - 1``, their children written from index
    ``out`` on; returns their number. ``lams`` (1,) scratch."""
    m = max(out, 0)  # max(., 0): indices known nonnegative, no code for negative ones (5% faster, measured)
    for q in range(max(start, 0), stop):
        if q + PREFETCH_AHEAD < stop and log_weights[q + PREFETCH_AHEAD] != -np.inf:
            _prefetch_parent(locations, pool, pool_stamps, table, cell_block, cell_slot, dynamic, neighbors,
                             q + PREFETCH_AHEAD)
        live, l, n = _parent(locations, log_weights, neighbors, q)
        if not live:
            continue
        for s in range(2):
            j, probability = _successor(l, n, p_move, s)
            if probability <= 0.0:
                continue
            r = table[q, cell_block[j]]
            lam = _evidence(pool, powers, _age(pool_stamps, dynamic, t, r, cell_slot[j]), r, cell_slot[j], likelihood)
            if lam <= 0.0:
                continue
            lams[0] = lam
            child_log_weight[m] = _log_weight(log_weights[q], probability, lam, lams, 1)
            child_parent[m] = q
            child_location[m] = j
            m += 1
    return m - out


@njit(cache=True, inline="always")
def _passable_before(pool, pool_stamps, table_row, cell_block, cell_slot, powers, dynamic, t, blocking, n, before):
    """P(cell n passable) for the map whose block rows are ``table_row`` (n_blocks,), judged at
    step t - 1 (before this step's map change); ``before`` (K,) <- n's marginal at t - 1."""
    r = table_row[cell_block[n]]
    d = 0
    if dynamic:
        d = t - 1 - pool_stamps[r, cell_slot[n]]
    passable = 0.0
    for b in range(before.shape[0]):
        before[b] = _aged_label(pool, powers, d, r, cell_slot[n], b)
        if not blocking[b]:
            passable += before[b]
    return passable


@njit(cache=True, inline="always")
def _motion(l, n, p_move, s, gated, passable):
    """(cell, probability) of successor s (:func:`_successor`), a gated move's success scaled by
    P(n passable)."""
    j, probability = _successor(l, n, p_move, s)
    if gated:
        probability = probability * passable if s == 1 else 1.0 - p_move * passable
    return j, probability


@njit(cache=True, inline="always")
def _footprint_child(pool, pool_stamps, table_row, cell_block, cell_slot, powers, dynamic, t, j, n, s, gated, before,
                     p_move, blocking, change, footprint_cells, sensor, readings, given, ids, cells, lams, posteriors):
    """The map changes of a child (successor s, at cell j, of a parent whose action points at n
    and whose map has block rows ``table_row``), as :func:`rbpf_enumerate_cells` defines them:
    ``ids`` (W,) the changed cells (-1 pads), ``cells`` (W, K) their marginals at step t, ``lams``
    (F,) the likelihood of each on-grid reading in turn. ``before`` (K,): n's marginal at t - 1
    (:func:`_passable_before`, when ``gated``); ``given`` (K,) scratch. Without ``posteriors`` the
    read cells keep their prior in ``cells`` (the likelihood is the same: a footprint reads each
    cell once, after the move's evidence, and its divisions are most of the cost). Returns
    (n_reads, likelihood), ``n_reads = -1`` where the readings are impossible for this child.
    O(F (W + K))."""
    k = sensor.shape[0]
    used = 0
    if gated:  # n's marginal given the move's outcome (at t - 1), carried to step t by C
        total = 0.0
        for b in range(k):
            factor = (0.0 if blocking[b] else 1.0) if s == 1 else (1.0 - p_move) + (p_move if blocking[b] else 0.0)
            given[b] = before[b] * factor
            total += given[b]
        for b in range(k):
            given[b] /= total
        for b in range(k):
            if dynamic:
                acc = 0.0
                for a in range(k):
                    acc += given[a] * change[a, b]
                cells[0, b] = acc
            else:
                cells[0, b] = given[b]
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
            r = table_row[cell_block[c]]
            d = 0
            if dynamic:
                d = t - pool_stamps[r, cell_slot[c]]
            for b in range(k):
                cells[w, b] = _aged_label(pool, powers, d, r, cell_slot[c], b)
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


def rbpf_enumerate_cells(locations: np.ndarray, log_weights: np.ndarray, pool: np.ndarray, pool_stamps: np.ndarray,
                         table: np.ndarray, cell_block: np.ndarray, cell_slot: np.ndarray, powers: np.ndarray,
                         dynamic: bool, t: int, neighbors: np.ndarray, p_move: float, blocking: np.ndarray,
                         change: np.ndarray, footprint_cells: np.ndarray, sensor: np.ndarray, readings: np.ndarray,
                         child_parent: np.ndarray, child_location: np.ndarray, child_log_weight: np.ndarray,
                         child_log_motion: np.ndarray, child_ids: np.ndarray, child_cells: np.ndarray) -> int:
    """:func:`rbpf_enumerate` for blocking labels and sensor footprints; returns M.

    Blocking (``blocking`` (K,) bool, any True): from l the intended n != l is entered with
    ``p_move * P(m_n passable)``, judged on n's marginal at step t - 1 (before this step's map
    change); the move child's n is conditioned on passable, the stay child's on
    ``(1 - p_move) + p_move [m_n blocks]``, then carried to step t by ``change`` (C). Footprint
    (``footprint_cells`` (N, F), ``readings`` (F,), -1 off the grid): the likelihood is the product
    over the offsets of ``sum_k current(c_f)[k] sensor[k, z_f]`` (1 where both cell and reading
    are off the grid, 0 where only one is), and each read cell gets its posterior. Given the
    trajectory the cells stay independent, so a child's map differs from its parent's in at most
    W = F + 1 cells (:func:`_footprint_child`). With ``child_cells`` of 2P rows (the sampling
    schemes) it stores them: ``child_ids`` (2P, W) (-1: none) and ``child_cells`` (2P, W, K), at
    step t, and ``child_log_motion`` (2P,), each child's ``log T``; with 0 rows (Fearnhead-Clifford,
    which recomputes the kept children's in :func:`rbpf_commit_children_cells`) only the parents,
    locations and log weights. Cost O(P F K^2). (A Python function: its kernel,
    :func:`_enumerate_cells` on every parent, is the one the threads run on runs of parents,
    compiled once for both.)"""
    return _enumerate_cells(locations, log_weights, pool, pool_stamps, table, cell_block, cell_slot, powers, dynamic, t,
                            neighbors, p_move, blocking, change, footprint_cells, sensor, readings, child_parent,
                            child_location, child_log_weight, child_log_motion, child_ids, child_cells, 0,
                            len(locations), 0, *_footprint_scratch(sensor.shape[0], footprint_cells.shape[1],
                                                                 child_ids.shape[1]))


def _footprint_scratch(k: int, f: int, width: int) -> tuple:
    """Fresh scratch arrays of :func:`_enumerate_cells`: ``before``, ``given`` (K,), ``lams`` (F,),
    ``ids`` (W,), ``cells`` (W, K) (the first three those of :func:`_stage_children_cells`)."""
    return np.empty(k), np.empty(k), np.empty(f), np.empty(width, dtype=np.int64), np.empty((width, k))


@njit(cache=True, inline="always")
def _any(flags):
    """Whether any of ``flags`` (K,) is True."""
    found = False
    for b in range(flags.shape[0]):
        found = found or flags[b]
    return found


@thread_kernel
def _enumerate_cells(locations, log_weights, pool, pool_stamps, table, cell_block, cell_slot, powers, dynamic, t,
                     neighbors, p_move, blocking, change, footprint_cells, sensor, readings, child_parent,
                     child_location, child_log_weight, child_log_motion, child_ids, child_cells, start, stop, out,
                     before, given, lams, ids, cells):
    """:func:`rbpf_enumerate_cells` of parents ``start..stop - 1``, their children written from
    index ``out`` on; returns their number. ``before``, ``given`` (K,), ``lams`` (F,), ``ids`` (W,)
    and ``cells`` (W, K) scratch."""
    store = child_cells.shape[0] > 0
    has_blocking = _any(blocking)
    m = max(out, 0)  # as in _enumerate
    for q in range(max(start, 0), stop):
        ahead = q + PREFETCH_AHEAD
        if ahead < stop and log_weights[ahead] != -np.inf:
            _prefetch_parent(locations, pool, pool_stamps, table, cell_block, cell_slot, dynamic, neighbors, ahead)
            _prefetch_footprint(pool, pool_stamps, table, cell_block, cell_slot, dynamic, footprint_cells, ahead,
                                locations[ahead])
            _prefetch_footprint(pool, pool_stamps, table, cell_block, cell_slot, dynamic, footprint_cells, ahead,
                                neighbors[locations[ahead]])
        live, l, n = _parent(locations, log_weights, neighbors, q)
        if not live:
            continue
        gated = has_blocking and n != l  # the move's success tells about cell n
        passable = 1.0
        if gated:
            passable = _passable_before(pool, pool_stamps, table[q], cell_block, cell_slot, powers, dynamic, t,
                                        blocking, n, before)
        for s in range(2):
            j, probability = _motion(l, n, p_move, s, gated, passable)
            if probability <= 0.0:
                continue
            n_reads, likelihood = _footprint_child(pool, pool_stamps, table[q], cell_block, cell_slot, powers, dynamic,
                                                   t, j, n, s, gated, before, p_move, blocking, change,
                                                   footprint_cells, sensor, readings, given, ids, cells, lams, store)
            if n_reads < 0:
                continue
            if store:
                for w in range(ids.shape[0]):
                    child_ids[m, w] = ids[w]
                    for b in range(cells.shape[1]):
                        child_cells[m, w, b] = cells[w, b]
                child_log_motion[m] = math.log(probability)
            child_log_weight[m] = _log_weight(log_weights[q], probability, likelihood, lams, n_reads)
            child_parent[m] = q
            child_location[m] = j
            m += 1
    return m - out


@njit(cache=True, inline="always")
def _copy_child(child_ids, child_cells, c, new_ids, new_cells, p):
    """``new_ids[p], new_cells[p] <- child_ids[c], child_cells[c]`` ((W,), (W, K)), element by
    element: a whole-row assignment compiles numba's shape-mismatch message (string formatting,
    seconds of compilation per kernel) for a check these shapes never fail."""
    for w in range(new_ids.shape[1]):
        new_ids[p, w] = child_ids[c, w]
        for b in range(new_cells.shape[2]):
            new_cells[p, w, b] = child_cells[c, w, b]


@njit(cache=True)
def rbpf_pick_children(ancestors, child_parent, child_location, child_log_weight, child_log_motion, child_ids,
                       child_cells, m, optimal, uniforms, new_locations, new_ids, new_cells, log_increments):
    """The sampling schemes on enumerated children (:func:`rbpf_enumerate_cells` with every
    parent's log weight 0): slot p draws one child of its ancestor ``ancestors[p]`` with
    ``uniforms[p]``. Optimal proposal: in proportion to ``T P(z | child)``, increment ``log sum``
    of those; transition proposal: in proportion to ``T`` over every successor (one the
    observation rules out, left out of the children, gives weight 0), increment ``log P(z |
    child)``. A slot with weight 0 gets ``new_locations = -1`` (no write). O(P W K)."""
    n_particles = ancestors.shape[0]
    start = np.zeros(n_particles + 1, dtype=np.int64)
    for c in range(m):
        start[child_parent[c] + 1] += 1
    for q in range(n_particles):
        start[q + 1] += start[q]
    new_locations[:] = -1
    new_ids[:] = -1
    new_cells[:] = 0.0
    for p in range(n_particles):
        q = ancestors[p]
        log_increments[p] = -np.inf
        chosen = -1
        if optimal and start[q + 1] > start[q]:
            top = -np.inf
            for c in range(start[q], start[q + 1]):
                top = max(top, child_log_weight[c])
            total = 0.0
            for c in range(start[q], start[q + 1]):
                total += math.exp(child_log_weight[c] - top)
            target = uniforms[p] * total
            chosen = start[q + 1] - 1
            for c in range(start[q], start[q + 1]):
                target -= math.exp(child_log_weight[c] - top)
                if target < 0.0:
                    chosen = c
                    break
            log_increments[p] = top + math.log(total)
        elif not optimal:
            acc = 0.0
            for c in range(start[q], start[q + 1]):
                acc += math.exp(child_log_motion[c])
                if uniforms[p] < acc:
                    chosen = c
                    log_increments[p] = child_log_weight[c] - child_log_motion[c]
                    break
        if chosen >= 0:
            new_locations[p] = child_location[chosen]
            _copy_child(child_ids, child_cells, chosen, new_ids, new_cells, p)


@njit(cache=True)
def rbpf_keep_children(child_parent, child_location, weights, n_cells, uniform, order, kept, kept_weights, ancestors,
                       slot_child, new_log_weights):
    """Fearnhead-Clifford's selection of P of the M children (``weights`` (M,), normalised; the
    first M entries of ``child_parent`` and ``child_location``): order them by location
    (:func:`_children_by_location`, into ``order``), keep P by optimal resampling with ``uniform``
    (:func:`~onlinemap.kernels.resampling.optimal_keep_into`, into ``kept`` and ``kept_weights``)
    and place them in the slots (:func:`_place_children`). Returns c (0 when every child was
    kept). O(M + N)."""
    m = weights.shape[0]
    n_particles = ancestors.shape[0]
    _children_by_location(child_location[:m], np.zeros(n_cells + 1, dtype=np.int64), order[:m])
    n_kept, c = optimal_keep_into(weights, n_particles, uniform, order[:m], kept, kept_weights)
    _place_children(child_parent, kept[:n_kept], kept_weights[:n_kept], ancestors, slot_child, new_log_weights,
                    np.zeros(n_particles, dtype=np.bool_), np.zeros(n_particles, dtype=np.bool_))
    return c


@loop_kernel
def _children_by_location(child_location, starts, order):
    """order (M,) <- the children's indices ordered by location (stable: by parent within a
    location), the order in which Fearnhead-Clifford's strata walk them, so that the draws spread
    over the cells in proportion to their weight. Counting sort, O(M + N); ``starts`` (N + 1,)
    zeros."""
    for c in range(child_location.shape[0]):
        starts[child_location[c] + 1] += 1
    for i in range(starts.shape[0] - 1):
        starts[i + 1] += starts[i]
    for c in range(child_location.shape[0]):
        i = child_location[c]
        order[starts[i]] = c
        starts[i] += 1


@loop_kernel
def _place_children(child_parent, kept, kept_weights, ancestors, slot_child, new_log_weights, has_child, filled):
    """Put the kept children (``kept`` distinct indices into the children, any order;
    ``kept_weights`` their weights) into the P particle slots: a parent's first kept child takes
    the parent's slot, a second one the next slot whose particle has no kept child
    (``ancestors[slot]`` = the parent; ``ancestors[p] = p`` elsewhere, so a parent with a kept
    child keeps its slot and no source is overwritten). Outputs (P,): ``ancestors``,
    ``slot_child`` (the child in each slot, -1 for none: fewer children than P) and
    ``new_log_weights`` (``log`` of the kept weight, -inf for none). ``has_child``, ``filled``
    (P,) False. O(P)."""
    n_particles = ancestors.shape[0]
    for i in range(kept.shape[0]):
        has_child[child_parent[kept[i]]] = True
    for p in range(n_particles):
        ancestors[p] = p
        slot_child[p] = -1
        new_log_weights[p] = -np.inf
    extra = 0  # the next slot without a child of its own, for a second child
    for i in range(kept.shape[0]):
        if i + PREFETCH_AHEAD < kept.shape[0]:
            prefetch(child_parent, (kept[i + PREFETCH_AHEAD],))
        c = kept[i]
        q = child_parent[c]
        if not filled[q]:
            slot = q
        else:
            while has_child[extra]:
                extra += 1
            slot = extra
            extra += 1
            ancestors[slot] = q
        filled[slot] = True
        slot_child[slot] = c
        new_log_weights[slot] = math.log(kept_weights[i])


@loop_kernel
def rbpf_propose(locations, pool, pool_stamps, table, cell_block, cell_slot, powers, dynamic, t, ancestors,
                 neighbors, p_move, likelihood, optimal, uniforms, new_locations, new_cells, log_increments):
    """Propose every particle's step-t location and weight it; writes nothing to the state.

    Particle ``p`` descends from ``ancestors[p]``. ``neighbors`` (N,) is ``neighbors[:, a]``
    (``arange(N)`` at step 0: no motion). Candidates are the ancestor's cell ``l`` (probability
    ``1 - p_move``, or 1 where the move is impossible) and ``n = neighbors[l]`` (``p_move``).
    Transition proposal: draw from the motion model, increment = ``P(z | l_t, map_p)``.
    Optimal proposal: draw from ``P(l_t | l, a, z, map_p)``, increment =
    ``sum_l' T[a, l, l'] P(z | l', map_p)``. Outputs: ``new_locations`` (P,), ``new_cells``
    (P, K) the observed cell's updated marginal, ``log_increments`` (P,) (-inf where z is
    impossible). One uniform per particle. O(P K^2).
    """
    _propose(locations, pool, pool_stamps, table, cell_block, cell_slot, powers, dynamic, t, ancestors, neighbors,
             p_move, likelihood, optimal, uniforms, new_locations, new_cells, log_increments, np.int64(0),
             ancestors.shape[0])  # np.int64(0), not 0: one compile shared with the threads' calls


@thread_kernel
def _propose(locations, pool, pool_stamps, table, cell_block, cell_slot, powers, dynamic, t, ancestors, neighbors,
             p_move, likelihood, optimal, uniforms, new_locations, new_cells, log_increments, start, stop):
    """:func:`rbpf_propose` of particles ``start..stop - 1``."""
    for p in range(start, stop):
        if p + PREFETCH_AHEAD < stop:
            _prefetch_parent(locations, pool, pool_stamps, table, cell_block, cell_slot, dynamic, neighbors,
                             ancestors[p + PREFETCH_AHEAD])
        q = ancestors[p]
        l = locations[q]
        n = neighbors[l]
        here = table[q, cell_block[l]]
        lam_here = _evidence(pool, powers, _age(pool_stamps, dynamic, t, here, cell_slot[l]), here, cell_slot[l],
                             likelihood)
        target = l
        lam = lam_here
        weight = lam_here
        if n != l:
            there = table[q, cell_block[n]]
            lam_there = _evidence(pool, powers, _age(pool_stamps, dynamic, t, there, cell_slot[n]), there,
                                  cell_slot[n], likelihood)
            if optimal:
                move = p_move * lam_there
                weight = move + (1.0 - p_move) * lam_here
                if uniforms[p] * weight < move:
                    target, lam = n, lam_there
            elif uniforms[p] < p_move:
                target, lam, weight = n, lam_there, lam_there
        new_locations[p] = target
        r = table[q, cell_block[target]]
        _observed_cell(pool, powers, _age(pool_stamps, dynamic, t, r, cell_slot[target]), r, cell_slot[target],
                       likelihood, lam, new_cells[p])
        log_increments[p] = math.log(weight) if lam > 0.0 else -np.inf


@loop_kernel
def _take_over_slots(refcount, free, free_top, table, ancestors):
    """Slots taken over by a copy (``ancestors[p] != p``; such ancestors keep their own slot, so
    sources are never overwritten) release their rows and share the ancestor's: O(n_blocks) per
    copied particle, reference counts touched only where the two rows differ (a row both share
    keeps its count: it is named by both, so it never drops to 0 on the way)."""
    n_particles, n_blocks = table.shape
    for p in range(n_particles):
        ahead = p + PREFETCH_AHEAD
        if ahead < n_particles and ancestors[ahead] != ahead:
            for b in range(0, n_blocks, 8):  # the two table rows, a cache line (8 entries) at a time
                prefetch(table, (ancestors[ahead], b))
                prefetch(table, (ahead, b))
        q = ancestors[p]
        if q == p:
            continue
        for b in range(n_blocks):
            r = table[p, b]
            s = table[q, b]
            if r == s:
                continue
            refcount[r] -= 1
            if refcount[r] == 0:
                free[free_top[0]] = r
                free_top[0] += 1
            table[p, b] = s
            refcount[s] += 1


@njit(cache=True, inline="always")
def _row_for_write(row_block, refcount, free, free_top, table, p, b):
    """(row, source): the row particle p writes block b into, and the row to copy into it first
    (-1: none). A row p shares (count > 1) is replaced by a free one, which takes over p's
    reference: the bookkeeping of copy-on-write, without touching the rows."""
    r = table[p, b]
    source = -1
    if refcount[r] > 1:
        free_top[0] -= 1
        fresh = free[free_top[0]]
        row_block[fresh] = b
        refcount[r] -= 1
        refcount[fresh] = 1
        table[p, b] = fresh
        source = r
        r = fresh
    return r, source


@njit(cache=True, inline="always")
def _copy_row(pool, pool_stamps, dynamic, powers, max_age, t, source, row):
    """Block row ``row`` <- a copy of ``source`` (O(B K)); slots older than ``max_age`` steps are
    brought up to date (stamped t), so a copy never extends a row's age."""
    for slot in range(pool.shape[1]):
        for label in range(pool.shape[2]):
            pool[row, slot, label] = pool[source, slot, label]
    if dynamic:
        for slot in range(pool.shape[1]):
            pool_stamps[row, slot] = pool_stamps[source, slot]
            if t - pool_stamps[row, slot] > max_age:
                for label in range(pool.shape[2]):
                    pool[row, slot, label] = _aged_label(pool, powers, t - pool_stamps[source, slot], source, slot,
                                                         label)
                pool_stamps[row, slot] = t


@njit(cache=True, inline="always")
def _set_slot(pool, pool_stamps, dynamic, t, row, slot, values):
    """Slot ``slot`` of block row ``row`` <- ``values`` (K,), stamped t."""
    for label in range(pool.shape[2]):
        pool[row, slot, label] = values[label]
    if dynamic:
        pool_stamps[row, slot] = t


@njit(cache=True, inline="always")
def _write_cell(pool, pool_stamps, row_block, refcount, free, free_top, table, cell_block, cell_slot, dynamic,
                powers, max_age, t, p, cell, values):
    """Particle p's marginal of ``cell`` <- ``values`` (K,), stamped t; the block is first copied if
    shared (:func:`_row_for_write`, :func:`_copy_row`: O(B K)). Takes a free row when it copies."""
    r, source = _row_for_write(row_block, refcount, free, free_top, table, p, cell_block[cell])
    if source >= 0:
        _copy_row(pool, pool_stamps, dynamic, powers, max_age, t, source, r)
    _set_slot(pool, pool_stamps, dynamic, t, r, cell_slot[cell], values)


@loop_kernel
def rbpf_commit(locations, pool, pool_stamps, row_block, refcount, free, free_top, table, cell_block, cell_slot,
                dynamic, powers, max_age, t, ancestors, new_locations, new_cells):
    """Apply a validated proposal in place: :func:`_take_over_slots`, then each particle writes
    its observed cell ``new_cells[p]`` at ``new_locations[p]`` (:func:`_write_cell`; needs
    ``free_top[0] >= P``). ``new_locations[p] = -1`` leaves slot p as it is."""
    _take_over_slots(refcount, free, free_top, table, ancestors)
    for p in range(table.shape[0]):
        cell = new_locations[p]
        if cell < 0:
            continue
        _write_cell(pool, pool_stamps, row_block, refcount, free, free_top, table, cell_block, cell_slot, dynamic,
                    powers, max_age, t, p, cell, new_cells[p])
        locations[p] = cell


@loop_kernel
def rbpf_commit_cells(locations, pool, pool_stamps, row_block, refcount, free, free_top, table, cell_block,
                      cell_slot, dynamic, powers, max_age, t, ancestors, new_locations, new_ids, new_cells):
    """:func:`rbpf_commit` with up to W cells written per particle: ``new_ids`` (P, W) the cells
    (-1: none), ``new_cells`` (P, W, K) their marginals at step t. Needs ``free_top[0] >= W P``."""
    _take_over_slots(refcount, free, free_top, table, ancestors)
    for p in range(table.shape[0]):
        if new_locations[p] < 0:
            continue
        for w in range(new_ids.shape[1]):
            if new_ids[p, w] >= 0:
                _write_cell(pool, pool_stamps, row_block, refcount, free, free_top, table, cell_block, cell_slot,
                            dynamic, powers, max_age, t, p, new_ids[p, w], new_cells[p, w])
        locations[p] = new_locations[p]


@njit(cache=True)
def rbpf_commit_children(locations, pool, pool_stamps, row_block, refcount, free, free_top, table, cell_block,
                         cell_slot, dynamic, powers, max_age, t, ancestors, slot_child, child_location, likelihood):
    """Fearnhead-Clifford's commit (:func:`rbpf_keep_children` placed the kept children): each
    slot p takes over its ancestor's table row (:func:`_take_over_slots`), then its child's
    observed cell, the posterior given z (likelihood (K,)) of cell ``child_location[c]`` of the
    parent's map, is computed as :func:`rbpf_enumerate` defines it and written (:func:`_write_cell`;
    needs ``free_top[0] >= P``); the locations follow. ``slot_child[p] = -1`` leaves slot p as it
    is. O(P B K) at most, O(P K^2) for the posteriors."""
    _take_over_slots(refcount, free, free_top, table, ancestors)
    _write_children(locations, pool, pool_stamps, row_block, refcount, free, free_top, table, cell_block, cell_slot,
                    dynamic, powers, max_age, t, slot_child, child_location, likelihood, np.empty(likelihood.shape[0]))


@loop_kernel
def _write_children(locations, pool, pool_stamps, row_block, refcount, free, free_top, table, cell_block, cell_slot,
                    dynamic, powers, max_age, t, slot_child, child_location, likelihood, values):
    """The writes of :func:`rbpf_commit_children` once the slots are taken over; ``values`` (K,)
    scratch."""
    for p in range(table.shape[0]):
        ahead = p + PREFETCH_AHEAD
        if ahead < table.shape[0] and slot_child[ahead] >= 0:
            _prefetch_write(pool, pool_stamps, row_block, refcount, free, free_top, table, cell_block, cell_slot,
                            dynamic, ahead, child_location[slot_child[ahead]])
        c = slot_child[p]
        if c < 0:
            continue
        j = child_location[c]
        r = table[p, cell_block[j]]  # the parent's row (only its sole user writes a row in place)
        d = _age(pool_stamps, dynamic, t, r, cell_slot[j])
        lam = _evidence(pool, powers, d, r, cell_slot[j], likelihood)
        _observed_cell(pool, powers, d, r, cell_slot[j], likelihood, lam, values)
        _write_cell(pool, pool_stamps, row_block, refcount, free, free_top, table, cell_block, cell_slot, dynamic,
                    powers, max_age, t, p, j, values)
    _move_to_children(locations, slot_child, child_location)


@njit(cache=True, inline="always")
def _prefetch_write(pool, pool_stamps, row_block, refcount, free, free_top, table, cell_block, cell_slot, dynamic, p,
                    cell):
    """Ask for what particle p's write of ``cell`` reads: the cell's marginal and its row's count;
    and for a free row a copy will soon take (the second on the stack), its first slot and its
    bookkeeping."""
    _prefetch_cell(pool, pool_stamps, table, cell_block, cell_slot, dynamic, p, cell)
    prefetch(refcount, (table[p, cell_block[cell]],))
    if free_top[0] > 1:
        fresh = free[free_top[0] - 2]
        prefetch(pool, (fresh, 0, 0))
        prefetch(refcount, (fresh,))
        prefetch(row_block, (fresh,))


@njit(cache=True, inline="always")
def _move_to_children(locations, slot_child, child_location):
    """locations[p] <- the location of slot p's child (unchanged where it has none)."""
    for p in range(locations.shape[0]):
        if slot_child[p] >= 0:
            locations[p] = child_location[slot_child[p]]


@njit(cache=True)
def rbpf_commit_children_cells(locations, pool, pool_stamps, row_block, refcount, free, free_top, table, cell_block,
                               cell_slot, dynamic, powers, max_age, t, ancestors, slot_child, child_location,
                               neighbors, p_move, blocking, change, footprint_cells, sensor, readings):
    """:func:`rbpf_commit_children` for blocking labels and sensor footprints: each kept child's
    W changed cells are computed from its parent's map as :func:`rbpf_enumerate_cells` defines
    them (:func:`_footprint_child`; the parent's location is read before any slot moves) and
    written. Needs ``free_top[0] >= W P``. O(P F K^2 + P W B K)."""
    k = sensor.shape[0]
    width = footprint_cells.shape[1] + int(_any(blocking))
    _take_over_slots(refcount, free, free_top, table, ancestors)
    _write_children_cells(locations, pool, pool_stamps, row_block, refcount, free, free_top, table, cell_block,
                          cell_slot, dynamic, powers, max_age, t, ancestors, slot_child, child_location, neighbors,
                          p_move, blocking, change, footprint_cells, sensor, readings, np.empty(k), np.empty(k),
                          np.empty(footprint_cells.shape[1]), np.empty(width, dtype=np.int64), np.empty((width, k)))


@loop_kernel
def _write_children_cells(locations, pool, pool_stamps, row_block, refcount, free, free_top, table, cell_block,
                          cell_slot, dynamic, powers, max_age, t, ancestors, slot_child, child_location, neighbors,
                          p_move, blocking, change, footprint_cells, sensor, readings, before, given, lams, ids, cells):
    """The writes of :func:`rbpf_commit_children_cells` once the slots are taken over; ``before``,
    ``given`` (K,), ``lams`` (F,), ``ids`` (W,), ``cells`` (W, K) scratch."""
    has_blocking = _any(blocking)
    for p in range(table.shape[0]):
        ahead = p + PREFETCH_AHEAD
        if ahead < table.shape[0] and slot_child[ahead] >= 0:
            _prefetch_write(pool, pool_stamps, row_block, refcount, free, free_top, table, cell_block, cell_slot,
                            dynamic, ahead, child_location[slot_child[ahead]])
            _prefetch_footprint(pool, pool_stamps, table, cell_block, cell_slot, dynamic, footprint_cells, ahead,
                                child_location[slot_child[ahead]])
        c = slot_child[p]
        if c < 0:
            continue
        l = locations[ancestors[p]]
        n = neighbors[l]
        j = child_location[c]
        s = 0 if j == l else 1  # the move's cell differs from l (a move to l has probability 0)
        gated = has_blocking and n != l
        if gated:
            _passable_before(pool, pool_stamps, table[p], cell_block, cell_slot, powers, dynamic, t, blocking, n,
                             before)
        _footprint_child(pool, pool_stamps, table[p], cell_block, cell_slot, powers, dynamic, t, j, n, s, gated,
                         before, p_move, blocking, change, footprint_cells, sensor, readings, given, ids, cells, lams,
                         True)
        for w in range(ids.shape[0]):  # computed from the parent's rows before any of them is copied
            if ids[w] >= 0:
                _write_cell(pool, pool_stamps, row_block, refcount, free, free_top, table, cell_block, cell_slot,
                            dynamic, powers, max_age, t, p, ids[w], cells[w])
    _move_to_children(locations, slot_child, child_location)


@thread_kernel
def _stage_children(pool, pool_stamps, table, cell_block, cell_slot, powers, dynamic, t, ancestors, slot_child,
                    child_location, likelihood, new_locations, new_ids, new_cells, start, stop):
    """The writes :func:`_write_children` makes, staged for slots ``start..stop - 1`` before the
    commit (from the parents' rows, ``table[ancestors[p]]``, which the take-over gives slot p):
    ``new_locations`` (P,) the child's cell (-1: no child), ``new_ids`` (P, 1) the same,
    ``new_cells`` (P, 1, K) its observed cell's posterior."""
    for p in range(start, stop):
        _prefetch_child(pool, pool_stamps, table, cell_block, cell_slot, dynamic, ancestors, slot_child,
                        child_location, p + PREFETCH_AHEAD, stop)
        c = slot_child[p]
        new_locations[p] = -1
        new_ids[p, 0] = -1
        if c >= 0:
            j = child_location[c]
            r = table[ancestors[p], cell_block[j]]
            d = _age(pool_stamps, dynamic, t, r, cell_slot[j])
            lam = _evidence(pool, powers, d, r, cell_slot[j], likelihood)
            _observed_cell(pool, powers, d, r, cell_slot[j], likelihood, lam, new_cells[p, 0])
            new_locations[p] = j
            new_ids[p, 0] = j


@thread_kernel
def _stage_children_cells(locations, pool, pool_stamps, table, cell_block, cell_slot, powers, dynamic, t, ancestors,
                          slot_child, child_location, neighbors, p_move, blocking, change, footprint_cells, sensor,
                          readings, new_locations, new_ids, new_cells, start, stop, before, given, lams):
    """The writes :func:`_write_children_cells` makes, staged for slots ``start..stop - 1`` before
    the commit (as :func:`_stage_children`): ``new_locations`` (P,), ``new_ids`` (P, W),
    ``new_cells`` (P, W, K); ``before``, ``given`` (K,), ``lams`` (F,) scratch."""
    has_blocking = _any(blocking)
    for p in range(start, stop):
        _prefetch_child(pool, pool_stamps, table, cell_block, cell_slot, dynamic, ancestors, slot_child,
                        child_location, p + PREFETCH_AHEAD, stop)
        c = slot_child[p]
        new_locations[p] = -1
        if c < 0:
            for w in range(new_ids.shape[1]):
                new_ids[p, w] = -1
            continue
        q = ancestors[p]
        l = locations[q]
        n = neighbors[l]
        j = child_location[c]
        gated = has_blocking and n != l
        if gated:
            _passable_before(pool, pool_stamps, table[q], cell_block, cell_slot, powers, dynamic, t, blocking, n,
                             before)
        _footprint_child(pool, pool_stamps, table[q], cell_block, cell_slot, powers, dynamic, t, j, n,
                         0 if j == l else 1, gated, before, p_move, blocking, change, footprint_cells, sensor,
                         readings, given, new_ids[p], new_cells[p], lams, True)
        new_locations[p] = j


@loop_kernel
def _plan_writes(row_block, refcount, free, free_top, table, cell_block, new_locations, new_ids, target, source):
    """The bookkeeping of copy-on-write for staged writes, in the order the serial commit makes
    them (slots in order, then their cells): ``target`` (P, W) <- the row each write goes to,
    ``source`` (P, W) <- the row to copy into it first (-1: none; :func:`_row_for_write`).
    Slots with ``new_locations[p] < 0`` and cells -1 write nothing. O(P W)."""
    for p in range(new_ids.shape[0]):
        for w in range(new_ids.shape[1]):
            target[p, w] = -1
            source[p, w] = -1
            if new_locations[p] >= 0 and new_ids[p, w] >= 0:
                target[p, w], source[p, w] = _row_for_write(row_block, refcount, free, free_top, table, p,
                                                           cell_block[new_ids[p, w]])


@thread_kernel
def _copy_planned(pool, pool_stamps, dynamic, powers, max_age, t, target, source, start, stop):
    """The copies :func:`_plan_writes` planned, for slots ``start..stop - 1`` (each reads a row
    no write of this step changes before every copy is made, and fills a row only its slot uses)."""
    for p in range(start, stop):
        for w in range(target.shape[1]):
            if source[p, w] >= 0:
                _copy_row(pool, pool_stamps, dynamic, powers, max_age, t, source[p, w], target[p, w])


@thread_kernel
def _write_planned(pool, pool_stamps, dynamic, t, cell_slot, new_ids, new_cells, target, locations, new_locations,
                   start, stop):
    """The staged writes of slots ``start..stop - 1`` into their planned rows (rows only their
    slot uses, once the copies are made), then their locations (``new_locations[p] < 0``: kept)."""
    for p in range(start, stop):
        for w in range(target.shape[1]):
            if target[p, w] >= 0:
                _set_slot(pool, pool_stamps, dynamic, t, target[p, w], cell_slot[new_ids[p, w]], new_cells[p, w])
        if new_locations[p] >= 0:
            locations[p] = new_locations[p]


@njit(cache=True)
def rbpf_refresh(pool, pool_stamps, refcount, powers, t, start, count):
    """Bring rows ``start, start + 1, ...`` (``count`` of them, cyclically) up to date at step t:
    ``row <- row @ C^(t - stamp)``, stamp ``t``. Same values, bounded ages: called every step
    with ``count = ceil(R / h)``, every row is refreshed at least every h steps; with copies
    refreshed beyond age h (``rbpf_commit``), no stamp is older than 2 h + 1 steps, so a table of
    powers up to a few h suffices however long the run. O(count B K^2)."""
    n_rows, block, k = pool.shape
    tmp = np.empty(k)
    for step in range(count):
        r = (start + step) % n_rows
        if refcount[r] == 0:
            continue
        for j in range(block):
            d = t - pool_stamps[r, j]
            if d == 0:
                continue
            for b in range(k):
                acc = 0.0
                for a in range(k):
                    acc += pool[r, j, a] * powers[d, a, b]
                tmp[b] = acc
            for b in range(k):
                pool[r, j, b] = tmp[b]
            pool_stamps[r, j] = t


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
def rbpf_map_mixture(pool, pool_stamps, row_block, refcount, table, block_members, powers, dynamic, t, weights, out):
    """out (N, K) <- ``sum_p weights[p] * current marginals of particle p``.

    First the weight of every row (:func:`_row_weights`), O(P n_blocks) at most; then one pass over
    the rows in use, in row order, O(R_used B K), with K^2 flops per out-of-date cell in a dynamic
    world (:func:`_mixture`). R_used <= P n_blocks, and much less when particles share blocks.
    """
    n_blocks = table.shape[1]
    row_weight = np.zeros(pool.shape[0])
    _row_weights(table, refcount, weights, _sum(weights), row_weight, np.int64(0), n_blocks,  # int64: one compile
                 np.empty(n_blocks, dtype=np.int64), np.empty(n_blocks, dtype=np.int64), np.empty(n_blocks))
    out[:] = 0.0
    _mixture(pool, pool_stamps, row_block, block_members, powers, dynamic, t, row_weight, out)


@loop_kernel
def _sum(values):
    """``sum(values)``, added in order from 0.0."""
    total = 0.0
    for i in range(values.shape[0]):
        total += values[i]
    return total


@thread_kernel
def _row_weights(table, refcount, weights, total, out, first, last, split, current, acc):
    """out[r] <- the weight of every row r holding one of the blocks ``first..last - 1``: the sum
    of ``weights`` (P,) over the particles whose table names it, in increasing particle order
    (``out`` zero on entry; rows nobody names stay 0). A block every particle shares (its row's
    count is P) gets ``total``, the plain sum (:func:`_sum`); elsewhere a run of particles naming
    the same row adds up in a register. The same additions in the same order as
    ``out[table[p, b]] += weights[p]`` over p, then b. ``split``, ``current``, ``acc`` (at least
    ``last - first``,) scratch. O(P n_split + last - first), n_split the blocks the particles do
    not all share."""
    n_particles = table.shape[0]
    n_split = 0
    for b in range(first, last):
        r = table[0, b]
        if refcount[r] == n_particles:
            out[r] = total
        else:
            split[n_split] = b
            current[n_split] = -1
            n_split += 1
    for p in range(n_particles):
        w = weights[p]
        for i in range(n_split):
            r = table[p, split[i]]
            if r == current[i]:
                acc[i] += w
            else:
                if current[i] >= 0:
                    out[current[i]] = acc[i]
                current[i] = r
                acc[i] = out[r] + w
    for i in range(n_split):
        if current[i] >= 0:
            out[current[i]] = acc[i]


@njit(cache=True, inline="always")
def _add_row(pool, pool_stamps, powers, dynamic, t, members, r, w, out):
    """out[members] += ``w`` times the current marginals of block row r (its block's cells
    ``members`` (B,), -1 padding)."""
    for j in range(members.shape[0]):
        i = members[j]
        if i >= 0:
            d = _age(pool_stamps, dynamic, t, r, j)
            for b in range(out.shape[1]):
                out[i, b] += w * _aged_label(pool, powers, d, r, j, b)


@loop_kernel
def _mixture(pool, pool_stamps, row_block, block_members, powers, dynamic, t, row_weight, out):
    """out (N, K) += ``sum_r row_weight[r] * current marginals of block row r``, rows in order."""
    for r in range(pool.shape[0]):
        if row_weight[r] != 0.0:
            _add_row(pool, pool_stamps, powers, dynamic, t, block_members[row_block[r]], r, row_weight[r], out)


@thread_kernel
def _mixture_blocks(pool, pool_stamps, row_block, block_members, powers, dynamic, t, row_weight, first, last, out):
    """:func:`_mixture` of the rows holding blocks ``first..last - 1`` (into those blocks' cells):
    O(R) to scan the rows, plus O(B K) per row of nonzero weight among them."""
    for r in range(pool.shape[0]):
        if row_weight[r] != 0.0 and first <= row_block[r] < last:
            _add_row(pool, pool_stamps, powers, dynamic, t, block_members[row_block[r]], r, row_weight[r], out)


@njit(cache=True)
def particle_maps(pool, pool_stamps, table, cell_block, cell_slot, powers, dynamic, t, which, out):
    """out (M, N, K) <- the current map marginals of particles ``which`` (M,) (the planners'
    hypotheses, inspection and tests). O(M N K^2)."""
    n_cells, k = out.shape[1], out.shape[2]
    for m in range(which.shape[0]):
        p = which[m]
        for i in range(n_cells):
            r = table[p, cell_block[i]]
            for b in range(k):
                d = _age(pool_stamps, dynamic, t, r, cell_slot[i])
                out[m, i, b] = _aged_label(pool, powers, d, r, cell_slot[i], b)


# --- recovery from depletion (estimators/rbpf.py, RaoBlackwellisedPF._recover) -----------------------
@njit(cache=True)
def _landing(l, footprint_cells, readings, sensor, blocking, has_blocking, ids, factors):
    """What a robot put down at ``l`` sees: returns the number U of cells it touches, or -1 when the
    readings' off-grid pattern does not fit ``l`` (an offset off the grid reads -1 exactly). Writes
    ``ids[:U]`` the cells (``l`` first with blocking labels: it must be passable) and ``factors[:U]``
    (U, K) the likelihood of each label of each: ``[label passable]`` for ``l`` with blocking labels,
    times ``sensor[label, z_f]`` for every offset f reading the cell. O(F K)."""
    k = sensor.shape[0]
    used = 0
    if has_blocking:
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
def _landing_cell(pool, pool_stamps, powers, dynamic, t, r, j, prior_cell, factor, q):
    """``q`` (K,) <- the current marginal of slot j of row r, or ``prior_cell`` (a reset) when that
    marginal gives what the child sees of the cell (``factor`` (K,)) probability 0. Returns
    ``(q @ factor, reset)``. O(K^2)."""
    k = factor.shape[0]
    d = _age(pool_stamps, dynamic, t, r, j)
    lam = 0.0
    for b in range(k):
        q[b] = _aged_label(pool, powers, d, r, j, b)
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
def rbpf_relocation_weights(locations, log_weights, pool, pool_stamps, table, cell_block, cell_slot, powers, dynamic,
                            t, moves, scale, blocking, footprint_cells, sensor, readings, prior, child_log_weight):
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
    n_cells, n_particles = child_log_weight.shape
    k = sensor.shape[0]
    width = footprint_cells.shape[1] + 1
    has_blocking = np.bool_(False)  # not a literal False: _landing compiles once, for bool
    for b in range(k):
        has_blocking = has_blocking or blocking[b]
    ids = np.empty((n_cells, width), dtype=np.int64)
    factors = np.empty((n_cells, width, k))
    used = np.empty(n_cells, dtype=np.int64)
    for l in range(n_cells):
        used[l] = _landing(l, footprint_cells, readings, sensor, blocking, has_blocking, ids[l], factors[l])
    resets = np.zeros((n_cells, n_particles), dtype=np.int8)
    child_log_weight[:] = -np.inf
    dist = np.empty(n_cells, dtype=np.int64)
    queue = np.empty(n_cells, dtype=np.int64)
    q = np.empty(k)
    fewest = -1
    source = -1
    log_z = 0.0
    order = np.empty(n_particles, dtype=np.int64)  # by location (a counting sort; the result needs no other order)
    _children_by_location(locations, np.zeros(n_cells + 1, dtype=np.int64), order)
    for p in order:
        if log_weights[p] == -np.inf:
            continue
        if locations[p] != source:
            source = locations[p]
            _grid_distances(moves, source, dist, queue)
            z_sum = 0.0
            for l in range(n_cells):
                if dist[l] >= 0:
                    z_sum += math.exp(-dist[l] / scale)
            log_z = math.log(z_sum)
        for l in range(n_cells):
            if dist[l] < 0 or used[l] < 0:
                continue
            total = log_weights[p] - dist[l] / scale - log_z
            count = 0
            for w in range(used[l]):
                c = ids[l, w]
                lam, reset = _landing_cell(pool, pool_stamps, powers, dynamic, t, table[p, cell_block[c]],
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
    for l in range(n_cells):
        for p in range(n_particles):
            if resets[l, p] > fewest:
                child_log_weight[l, p] = -np.inf
    return fewest


@njit(cache=True)
def rbpf_relocated_children(child_parent, child_location, pool, pool_stamps, table, cell_block, cell_slot, powers,
                            dynamic, t, blocking, footprint_cells, sensor, readings, prior, child_ids, child_cells):
    """The maps of recovery children (:func:`rbpf_relocation_weights`; kept ones, M of them): parent
    ``child_parent[i]`` relocated to ``child_location[i]``. ``child_ids`` (M, W) <- the cells the
    child touches (-1 pads), ``child_cells`` (M, W, K) <- their marginals at step t given what it
    sees (``q * factor / (q @ factor)``, q the parent's marginal or, where that gives 0, the
    prior: the same rule as the weights). O(M U K^2)."""
    k = sensor.shape[0]
    has_blocking = np.bool_(False)  # not a literal False: _landing compiles once, for bool
    for b in range(k):
        has_blocking = has_blocking or blocking[b]
    width = child_ids.shape[1]
    ids = np.empty(width, dtype=np.int64)
    factors = np.empty((width, k))
    q = np.empty(k)
    child_ids[:] = -1
    child_cells[:] = 0.0
    for i in range(child_parent.shape[0]):
        p, l = child_parent[i], child_location[i]
        used = _landing(l, footprint_cells, readings, sensor, blocking, has_blocking, ids, factors)
        for w in range(used):
            c = ids[w]
            lam, _ = _landing_cell(pool, pool_stamps, powers, dynamic, t, table[p, cell_block[c]], cell_slot[c],
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
    :func:`_place_children` places Fearnhead-Clifford's, for :func:`rbpf_commit_cells`. A child's
    ``child_ids`` (M, W) and ``child_cells`` (M, W, K) go with it. Slots left without a child
    (fewer children than P) get ``new_locations = -1`` (no write) and weight 0. Outputs (P,)
    ancestors, (P,), (P, W), (P, W, K), (P,). O(P W K)."""
    n_particles = ancestors.shape[0]
    slot_child = np.empty(n_particles, dtype=np.int64)
    _place_children(child_parent, kept, kept_weights, ancestors, slot_child, new_log_weights,
                    np.zeros(n_particles, dtype=np.bool_), np.zeros(n_particles, dtype=np.bool_))
    new_ids[:] = -1
    new_cells[:] = 0.0
    for p in range(n_particles):
        c = slot_child[p]
        new_locations[p] = -1
        if c >= 0:
            new_locations[p] = child_location[c]
            _copy_child(child_ids, child_cells, c, new_ids, new_cells, p)
