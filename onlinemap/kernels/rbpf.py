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


@njit(cache=True, inline="always")
def _age(pool_stamps, dynamic, t, r, j):
    """Steps since slot j of block row r was last brought up to date (0 in a static world)."""
    return t - pool_stamps[r, j] if dynamic else 0


@njit(cache=True, inline="always")
def _aged_label(pool, powers, d, r, j, b):
    """P(label b) of slot j of block row r, ``d`` steps after its stamp: ``(row @ C^d)[b]``."""
    if d == 0:
        return pool[r, j, b]
    acc = 0.0
    for a in range(pool.shape[2]):
        acc += pool[r, j, a] * powers[d, a, b]
    return acc


@njit(cache=True, inline="always")
def _label(pool, pool_stamps, powers, dynamic, t, r, j, b):
    """Current P(label b) of slot j of block row r at step t (C^dt applied on the fly)."""
    return _aged_label(pool, powers, _age(pool_stamps, dynamic, t, r, j), r, j, b)


@njit(cache=True, inline="always")
def _evidence(pool, pool_stamps, powers, dynamic, t, r, j, likelihood):
    """``P(z | cell) = sum_b current(b) likelihood[b]`` for slot j of block row r."""
    d = _age(pool_stamps, dynamic, t, r, j)
    acc = 0.0
    for b in range(likelihood.shape[0]):
        acc += _aged_label(pool, powers, d, r, j, b) * likelihood[b]
    return acc


@njit(cache=True, inline="always")
def _observed_cell(pool, pool_stamps, powers, dynamic, t, r, j, likelihood, lam, out):
    """out (K,) <- the posterior of slot j of row r after seeing a label of likelihood ``likelihood``
    (``lam`` = its evidence, from :func:`_evidence`); the prior unchanged where ``lam`` is 0."""
    d = _age(pool_stamps, dynamic, t, r, j)
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


@njit(cache=True)
def rbpf_enumerate(locations, log_weights, pool, pool_stamps, table, cell_block, cell_slot, powers, dynamic, t,
                   neighbors, p_move, likelihood, child_parent, child_location, child_log_weight, child_cells):
    """Every successor of every live particle with its exact log weight; returns their number M.

    For parent q at l (``log_weights[q] > -inf``) and each successor j of l with motion probability
    ``T(l, j) > 0`` (:func:`_successor`; ``neighbors = arange(N)`` at step 0: stay only):
    ``log w_q + log T(l, j) + log P(z | j, map_q)``, and the child's observed cell, the posterior
    of cell j given z. Children with probability zero are left out. Writes the first M entries of
    ``child_parent``, ``child_location``, ``child_log_weight`` and ``child_cells`` (M, K) (each at
    least 2P long), grouped by parent in increasing order. O(P K^2)."""
    k = likelihood.shape[0]
    m = 0
    for q in range(locations.shape[0]):
        live, l, n = _parent(locations, log_weights, neighbors, q)
        if not live:
            continue
        for s in range(2):
            j, probability = _successor(l, n, p_move, s)
            if probability <= 0.0:
                continue
            r = table[q, cell_block[j]]
            slot = cell_slot[j]
            d = _age(pool_stamps, dynamic, t, r, slot)
            lam = 0.0  # P(z | cell j of map q), as _evidence sums it
            for b in range(k):
                current = _aged_label(pool, powers, d, r, slot, b)
                child_cells[m, b] = current
                lam += current * likelihood[b]
            if lam <= 0.0:
                continue
            for b in range(k):  # as _observed_cell: divide (1 / lam overflows for a subnormal lam)
                child_cells[m, b] = child_cells[m, b] * likelihood[b] / lam
            joint = probability * lam  # one log per child; two where the product underflows
            child_log_weight[m] = log_weights[q] + (math.log(joint) if joint > 0.0 else
                                                    math.log(probability) + math.log(lam))
            child_parent[m] = q
            child_location[m] = j
            m += 1
    return m


@njit(cache=True)
def rbpf_enumerate_cells(locations, log_weights, pool, pool_stamps, table, cell_block, cell_slot, powers, dynamic,
                         t, neighbors, p_move, blocking, change, footprint_cells, sensor, readings, child_parent,
                         child_location, child_log_weight, child_log_motion, child_ids, child_cells):
    """:func:`rbpf_enumerate` for blocking labels and sensor footprints; returns M.

    Blocking (``blocking`` (K,) bool, any True): from l the intended n != l is entered with
    ``p_move * P(m_n passable)``, judged on n's marginal at step t - 1 (before this step's map
    change); the move child's n is conditioned on passable, the stay child's on
    ``(1 - p_move) + p_move [m_n blocks]``, then carried to step t by ``change`` (C). Footprint
    (``footprint_cells`` (N, F), ``readings`` (F,), -1 off the grid): the likelihood is the product
    over the offsets of ``sum_k current(c_f)[k] sensor[k, z_f]`` (1 where both cell and reading
    are off the grid, 0 where only one is), and each read cell gets its posterior. Given the
    trajectory the cells stay independent, so a child's map differs from its parent's in at most
    W = F + 1 cells: ``child_ids`` (2P, W) (-1: none) and ``child_cells`` (2P, W, K), at step t;
    ``child_log_motion`` (2P,) is each child's ``log T``. Cost O(P F K^2)."""
    k = sensor.shape[0]
    n_reads = footprint_cells.shape[1]
    width = child_ids.shape[1]
    has_blocking = False
    for b in range(k):
        has_blocking = has_blocking or blocking[b]
    before = np.empty(k)
    given = np.empty(k)
    m = 0
    for q in range(locations.shape[0]):
        live, l, n = _parent(locations, log_weights, neighbors, q)
        if not live:
            continue
        gated = has_blocking and n != l  # the move's success tells about cell n
        passable = 1.0
        if gated:
            r = table[q, cell_block[n]]
            d = t - 1 - pool_stamps[r, cell_slot[n]] if dynamic else 0
            passable = 0.0
            for b in range(k):
                before[b] = _aged_label(pool, powers, d, r, cell_slot[n], b)
                if not blocking[b]:
                    passable += before[b]
        for s in range(2):
            j, probability = _successor(l, n, p_move, s)
            if gated:
                probability = probability * passable if s == 1 else 1.0 - p_move * passable
            if probability <= 0.0:
                continue
            used = 0
            if gated:  # n's marginal given the move's outcome (at t - 1), carried to step t by C
                total = 0.0
                for b in range(k):
                    factor = (0.0 if blocking[b] else 1.0) if s == 1 else \
                        (1.0 - p_move) + (p_move if blocking[b] else 0.0)
                    given[b] = before[b] * factor
                    total += given[b]
                for b in range(k):
                    given[b] /= total
                for b in range(k):
                    if dynamic:
                        acc = 0.0
                        for a in range(k):
                            acc += given[a] * change[a, b]
                        child_cells[m, 0, b] = acc
                    else:
                        child_cells[m, 0, b] = given[b]
                child_ids[m, 0] = n
                used = 1
            likelihood = 1.0
            log_likelihood = 0.0
            possible = True
            for f in range(n_reads):
                c = footprint_cells[j, f]
                z = readings[f]
                if c < 0 or z < 0:  # off the grid reads -1 with probability 1, a cell never does
                    if c < 0 and z < 0:
                        continue
                    possible = False
                    break
                w = used
                for v in range(used):  # a cell this child already changed (the move's evidence)
                    if child_ids[m, v] == c:
                        w = v
                if w == used:
                    r = table[q, cell_block[c]]
                    d = _age(pool_stamps, dynamic, t, r, cell_slot[c])
                    for b in range(k):
                        child_cells[m, w, b] = _aged_label(pool, powers, d, r, cell_slot[c], b)
                    child_ids[m, w] = c
                    used += 1
                lam = 0.0
                for b in range(k):
                    lam += child_cells[m, w, b] * sensor[b, z]
                if lam <= 0.0:
                    possible = False
                    break
                for b in range(k):
                    child_cells[m, w, b] = child_cells[m, w, b] * sensor[b, z] / lam
                likelihood *= lam
                log_likelihood += math.log(lam)
            if not possible:
                continue
            for v in range(used, width):
                child_ids[m, v] = -1
            joint = probability * likelihood
            child_log_weight[m] = log_weights[q] + (math.log(joint) if joint > 0.0 else
                                                    math.log(probability) + log_likelihood)
            child_log_motion[m] = math.log(probability)
            child_parent[m] = q
            child_location[m] = j
            m += 1
    return m


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
            new_ids[p] = child_ids[chosen]
            new_cells[p] = child_cells[chosen]


@njit(cache=True)
def children_by_location(child_location, n_cells):
    """(M,) the children's indices ordered by location (stable: by parent within a location), the
    order in which Fearnhead-Clifford's strata walk them, so that the draws spread over the cells
    in proportion to their weight. Counting sort, O(M + N)."""
    starts = np.zeros(n_cells + 1, dtype=np.int64)
    for c in range(child_location.shape[0]):
        starts[child_location[c] + 1] += 1
    for i in range(n_cells):
        starts[i + 1] += starts[i]
    order = np.empty(child_location.shape[0], dtype=np.int64)
    for c in range(child_location.shape[0]):
        i = child_location[c]
        order[starts[i]] = c
        starts[i] += 1
    return order


@njit(cache=True)
def rbpf_place_children(child_parent, child_location, child_ids, child_cells, kept, kept_weights, ancestors,
                        new_locations, new_ids, new_cells, new_log_weights):
    """Put the kept children (``kept`` distinct indices into the children, any order;
    ``kept_weights`` their weights) into the P particle slots, for :func:`rbpf_commit_cells`: a
    parent's first kept child takes the parent's slot, a second one the next slot whose particle
    has no kept child (``ancestors[slot]`` = the parent; ``ancestors[p] = p`` elsewhere). A
    child's changed cells ``child_ids`` (M, W) and their marginals ``child_cells`` (M, W, K) go
    with it. Slots left without a child (fewer children than P) get ``new_locations = -1`` (no
    write) and weight 0. Outputs (P,) ancestors, (P,), (P, W), (P, W, K), (P,). O(P W K)."""
    n_particles = ancestors.shape[0]
    has_child = np.zeros(n_particles, dtype=np.bool_)
    for i in range(kept.shape[0]):
        has_child[child_parent[kept[i]]] = True
    for p in range(n_particles):
        ancestors[p] = p
    new_locations[:] = -1
    new_ids[:] = -1
    new_log_weights[:] = -np.inf
    new_cells[:] = 0.0
    filled = np.zeros(n_particles, dtype=np.bool_)
    extra = 0  # the next slot without a child of its own, for a second child
    for i in range(kept.shape[0]):
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
        new_locations[slot] = child_location[c]
        new_ids[slot] = child_ids[c]
        new_cells[slot] = child_cells[c]
        new_log_weights[slot] = math.log(kept_weights[i])


@njit(cache=True)
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
    n_particles = ancestors.shape[0]
    for p in range(n_particles):
        q = ancestors[p]
        l = locations[q]
        n = neighbors[l]
        lam_here = _evidence(pool, pool_stamps, powers, dynamic, t, table[q, cell_block[l]], cell_slot[l],
                             likelihood)
        target = l
        lam = lam_here
        weight = lam_here
        if n != l:
            lam_there = _evidence(pool, pool_stamps, powers, dynamic, t, table[q, cell_block[n]], cell_slot[n],
                                  likelihood)
            if optimal:
                move = p_move * lam_there
                weight = move + (1.0 - p_move) * lam_here
                if uniforms[p] * weight < move:
                    target, lam = n, lam_there
            elif uniforms[p] < p_move:
                target, lam, weight = n, lam_there, lam_there
        new_locations[p] = target
        _observed_cell(pool, pool_stamps, powers, dynamic, t, table[q, cell_block[target]], cell_slot[target],
                       likelihood, lam, new_cells[p])
        log_increments[p] = math.log(weight) if lam > 0.0 else -np.inf


@njit(cache=True)
def _take_over_slots(refcount, free, free_top, table, ancestors):
    """Slots taken over by a copy (``ancestors[p] != p``; such ancestors keep their own slot, so
    sources are never overwritten) release their rows and share the ancestor's: O(n_blocks) per
    copied particle."""
    n_particles, n_blocks = table.shape
    for p in range(n_particles):
        q = ancestors[p]
        if q == p:
            continue
        for b in range(n_blocks):
            r = table[p, b]
            refcount[r] -= 1
            if refcount[r] == 0:
                free[free_top[0]] = r
                free_top[0] += 1
            r = table[q, b]
            table[p, b] = r
            refcount[r] += 1


@njit(cache=True, inline="always")
def _write_cell(pool, pool_stamps, row_block, refcount, free, free_top, table, cell_block, cell_slot, dynamic,
                powers, max_age, t, p, cell, values):
    """Particle p's marginal of ``cell`` <- ``values`` (K,), stamped t; the block is first copied if
    shared: O(B K) (cells of the copy older than ``max_age`` steps are brought up to date, so a copy
    never extends a row's age). Takes a free row when it copies."""
    b = cell_block[cell]
    r = table[p, b]
    if refcount[r] > 1:
        free_top[0] -= 1
        fresh = free[free_top[0]]
        pool[fresh] = pool[r]
        if dynamic:
            pool_stamps[fresh] = pool_stamps[r]
            for slot in range(pool.shape[1]):
                if t - pool_stamps[fresh, slot] > max_age:
                    for label in range(pool.shape[2]):
                        pool[fresh, slot, label] = _label(pool, pool_stamps, powers, dynamic, t, r, slot, label)
                    pool_stamps[fresh, slot] = t
        row_block[fresh] = b
        refcount[r] -= 1
        refcount[fresh] = 1
        table[p, b] = fresh
        r = fresh
    j = cell_slot[cell]
    pool[r, j] = values
    if dynamic:
        pool_stamps[r, j] = t


@njit(cache=True)
def rbpf_commit(locations, pool, pool_stamps, row_block, refcount, free, free_top, table, cell_block, cell_slot,
                dynamic, powers, max_age, t, ancestors, new_locations, new_cells):
    """Apply a validated proposal in place: :func:`_take_over_slots`, then each particle writes
    its observed cell ``new_cells[p]`` at ``new_locations[p]`` (:func:`_write_cell`; needs
    ``free_top[0] >= P``). ``new_locations[p] = -1`` leaves slot p as it is (an empty slot)."""
    _take_over_slots(refcount, free, free_top, table, ancestors)
    for p in range(table.shape[0]):
        cell = new_locations[p]
        if cell < 0:  # an empty slot (Fearnhead-Clifford kept fewer children than P): no write
            continue
        _write_cell(pool, pool_stamps, row_block, refcount, free, free_top, table, cell_block, cell_slot, dynamic,
                    powers, max_age, t, p, cell, new_cells[p])
        locations[p] = cell


@njit(cache=True)
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
def rbpf_map_mixture(pool, pool_stamps, row_block, table, block_members, powers, dynamic, t, weights, out):
    """out (N, K) <- ``sum_p weights[p] * current marginals of particle p``.

    First the weight of every row (the sum over the particles sharing it), O(P n_blocks); then
    one pass over the rows in use, O(R_used B K), with K^2 flops per out-of-date cell in a
    dynamic world. R_used <= P n_blocks, and much less when particles share blocks.
    """
    k = out.shape[1]
    n_particles, n_blocks = table.shape
    row_weight = np.zeros(pool.shape[0])
    for p in range(n_particles):
        w = weights[p]
        for b in range(n_blocks):
            row_weight[table[p, b]] += w
    out[:] = 0.0
    for r in range(pool.shape[0]):
        w = row_weight[r]
        if w == 0.0:
            continue
        members = block_members[row_block[r]]
        for j in range(members.shape[0]):
            i = members[j]
            if i < 0:
                continue
            d = _age(pool_stamps, dynamic, t, r, j)
            for b in range(k):
                out[i, b] += w * _aged_label(pool, powers, d, r, j, b)


@njit(cache=True)
def particle_maps(pool, pool_stamps, table, cell_block, cell_slot, powers, dynamic, t, out):
    """out (P, N, K) <- every particle's current map marginals (for inspection and tests).
    O(P N K^2)."""
    n_particles, n_cells, k = out.shape
    for p in range(n_particles):
        for i in range(n_cells):
            r = table[p, cell_block[i]]
            for b in range(k):
                out[p, i, b] = _label(pool, pool_stamps, powers, dynamic, t, r, cell_slot[i], b)


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
    children with R resets, -inf for the others. The particles are visited in order of location,
    one search per distinct location. O(P N U K^2 + min(P, N) N A) time, N P bytes besides the
    output."""
    n_cells, n_particles = child_log_weight.shape
    k = sensor.shape[0]
    width = footprint_cells.shape[1] + 1
    has_blocking = False
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
    for p in np.argsort(locations):
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
    has_blocking = False
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
