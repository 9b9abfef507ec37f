"""numba kernels that select and write a step of the RBPF (``estimators/rbpf.py``): the sampling
schemes' pick among enumerated children, Fearnhead-Clifford's selection and placement of P
children, and the commits that write the slots and their changed cells into the particle maps
(:class:`~onlinemap.kernels.rbpf.Pool`), serially or staged for the threads
(``rbpf_parallel``).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from . import PREFETCH_AHEAD, loop_kernel, prefetch, thread_kernel
from .rbpf import (Pool, World, age, copy_row, evidence, observed_cell, prefetch_cell, row_for_write, set_slot,
                   take_over_slots, write_cell)
from .rbpf_enumerate import (Children, FootprintScratch, Proposed, footprint_child, passable_before,
                             prefetch_footprint)
from .resampling import optimal_keep_into


class Slots(NamedTuple):
    """Fearnhead-Clifford's kept children in the P slots (:func:`rbpf_keep_children`): each slot's
    ``ancestors`` (its parent; ``p`` itself where the slot keeps its particle), ``slot_child`` (the
    child in it, -1 for none) and ``log_weights`` (the kept weight's log, -inf for none)."""

    ancestors: np.ndarray
    slot_child: np.ndarray
    log_weights: np.ndarray


class Staged(NamedTuple):
    """A step's writes staged before the threaded commit (P slots, W cells each): ``locations``
    (P,) each slot's new cell (-1: no write), ``ids`` (P, W) the cells written (-1: none),
    ``cells`` (P, W, K) their marginals; ``target``, ``source`` (P, W): the row each write goes to
    and the row copied into it first (-1: none), planned by :func:`plan_writes`."""

    locations: np.ndarray
    ids: np.ndarray
    cells: np.ndarray
    target: np.ndarray
    source: np.ndarray


#: where each bundle's fields end in the ``*fields`` of :func:`rbpf_commit_children_cells` (slots, world, pool)
#: and of :func:`rbpf_pick_children` (children, proposed)
_CHILDREN_END = len(Children._fields)
_SLOTS_END = len(Slots._fields)
_WORLD_END = _SLOTS_END + len(World._fields)


@njit(cache=True, inline="always")
def copy_child(child_ids, child_cells, c, new_ids, new_cells, p):
    """``new_ids[p], new_cells[p] <- child_ids[c], child_cells[c]`` ((W,), (W, K)), element by
    element: a whole-row assignment compiles numba's shape-mismatch message (string formatting,
    seconds of compilation per kernel) for a check these shapes never fail."""
    for w in range(new_ids.shape[1]):
        new_ids[p, w] = child_ids[c, w]
        for b in range(new_cells.shape[2]):
            new_cells[p, w, b] = child_cells[c, w, b]


@njit(cache=True, inline="always")
def _drawn_optimally(child_log_weight, first, stop, uniform):
    """(child, log of the sum) of the children ``first..stop - 1`` (at least one), one drawn in
    proportion to ``exp(child_log_weight)`` with ``uniform``."""
    top = -np.inf
    for c in range(first, stop):
        top = max(top, child_log_weight[c])
    total = 0.0
    for c in range(first, stop):
        total += math.exp(child_log_weight[c] - top)
    target = uniform * total
    chosen = stop - 1
    for c in range(first, stop):
        target -= math.exp(child_log_weight[c] - top)
        if target < 0.0:
            chosen = c
            break
    return chosen, top + math.log(total)


@njit(cache=True)
def rbpf_pick_children(ancestors, m, optimal, uniforms, new_ids, *fields):
    """The sampling schemes on enumerated children (``rbpf_enumerate_cells`` with every parent's
    log weight 0, into ``children``, M = ``m`` of them): slot p draws one child of its ancestor
    ``ancestors[p]`` with ``uniforms[p]``. Optimal proposal: in proportion to ``T P(z | child)``,
    increment ``log sum`` of those; transition proposal: in proportion to ``T`` over every
    successor (one the observation rules out, left out of the children, gives weight 0),
    increment ``log P(z | child)``. Writes ``proposed`` (locations (P,), cells (P, W, K),
    log_increments (P,)) and ``new_ids`` (P, W). A slot with weight 0 gets location -1 (no write).
    O(P W K). ``*fields``: the fields of the :class:`~onlinemap.kernels.rbpf_enumerate.Children`,
    then those of the :class:`~onlinemap.kernels.rbpf_enumerate.Proposed` (``kernels/rbpf.py``:
    bundles and dispatch)."""
    children, proposed = Children(*fields[:_CHILDREN_END]), Proposed(*fields[_CHILDREN_END:])
    child_parent, child_location, child_log_weight = children.parent, children.location, children.log_weight
    child_log_motion, child_ids, child_cells = children.log_motion, children.ids, children.cells  # locals: NRT
    new_locations, new_cells, log_increments = proposed.locations, proposed.cells, proposed.log_increments
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
            chosen, log_increments[p] = _drawn_optimally(child_log_weight, start[q], start[q + 1], uniforms[p])
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
            copy_child(child_ids, child_cells, chosen, new_ids, new_cells, p)


@njit(cache=True)
def rbpf_keep_children(child_parent, child_location, weights, n_cells, uniform, order, kept, kept_weights, ancestors,
                       slot_child, new_log_weights):
    """Fearnhead-Clifford's selection of P of the M children (``weights`` (M,), normalised; the
    first M entries of ``child_parent`` and ``child_location``): order them by location
    (:func:`children_by_location`, into ``order``), keep P by optimal resampling with ``uniform``
    (:func:`~onlinemap.kernels.resampling.optimal_keep_into`, into ``kept`` and ``kept_weights``)
    and place them in the slots (:func:`place_children`: the fields of :class:`Slots`, arrays
    here: each bundle costs its Python caller some 5 us to type). Returns c (0 when every child was
    kept). O(M + N)."""
    m = weights.shape[0]
    n_particles = ancestors.shape[0]
    children_by_location(child_location[:m], np.zeros(n_cells + 1, dtype=np.int64), order[:m])
    n_kept, c = optimal_keep_into(weights, n_particles, uniform, order[:m], kept, kept_weights)
    place_children(child_parent, kept[:n_kept], kept_weights[:n_kept], ancestors, slot_child, new_log_weights,
                   np.zeros(n_particles, dtype=np.bool_), np.zeros(n_particles, dtype=np.bool_))
    return c


@loop_kernel
def children_by_location(child_location, starts, order):
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
def place_children(child_parent, kept, kept_weights, ancestors, slot_child, new_log_weights, has_child, filled):
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
def rbpf_commit_cells(locations, t, ancestors, new_locations, new_ids, new_cells, *fields):
    """Apply a validated step whose changed cells are given, in place: the slots taken over
    (:func:`~onlinemap.kernels.rbpf.take_over_slots`), then each particle with
    ``new_locations[p] >= 0`` writes up to W cells (:func:`~onlinemap.kernels.rbpf.write_cell`):
    ``new_ids`` (P, W) the cells (-1: none), ``new_cells`` (P, W, K) their marginals at step t, and
    moves there; ``new_locations[p] = -1`` leaves slot p as it is. ``new_ids`` None: one cell, the
    one each moves to, ``new_cells`` (P, 1, K) (the paper's model; its own compile, without the
    loop over W: 2 ns a particle less, measured). Needs ``free_top[0] >= W P``. O(P n_blocks) for
    the table rows taken over, O(P W B K) for the blocks copied. ``*fields``: the pool's fields
    (``kernels/rbpf.py``: bundles and dispatch)."""
    pool = Pool(*fields)
    take_over_slots(pool, ancestors)
    for p in range(pool.table.shape[0]):
        if new_locations[p] < 0:
            continue
        if new_ids is None:
            write_cell(pool, t, p, new_locations[p], new_cells[p, 0])
        else:
            for w in range(new_ids.shape[1]):
                if new_ids[p, w] >= 0:
                    write_cell(pool, t, p, new_ids[p, w], new_cells[p, w])
        locations[p] = new_locations[p]


@njit(cache=True)
def rbpf_commit_children(locations, t, ancestors, slot_child, child_location, likelihood, *fields):
    """Fearnhead-Clifford's commit (:func:`rbpf_keep_children` placed the kept children in the
    slots: ``ancestors``, ``slot_child``): each slot p takes over its ancestor's table row, then
    its child's observed cell, the posterior given z (likelihood (K,)) of cell
    ``child_location[c]`` of the parent's map, is computed as ``rbpf_enumerate`` defines it and
    written (needs ``free_top[0] >= P``); the locations follow. ``slot_child[p] = -1`` leaves slot
    p as it is. O(P B K) at most, O(P K^2) for the posteriors. ``*fields``: the pool's fields
    (``kernels/rbpf.py``: bundles and dispatch)."""
    pool = Pool(*fields)
    take_over_slots(pool, ancestors)
    _write_children(locations, pool, t, slot_child, child_location, likelihood, np.empty(likelihood.shape[0]))


@njit(cache=True, inline="always")
def _prefetch_write(pool, p, cell):
    """Ask for what particle p's write of ``cell`` reads: the cell's marginal and its row's count;
    and for a free row a copy will soon take (the second on the stack), its first slot and its
    bookkeeping."""
    prefetch_cell(pool, p, cell)
    prefetch(pool.refcount, (pool.table[p, pool.cell_block[cell]],))
    if pool.free_top[0] > 1:
        fresh = pool.free[pool.free_top[0] - 2]
        prefetch(pool.rows, (fresh, 0, 0))
        prefetch(pool.refcount, (fresh,))
        prefetch(pool.row_block, (fresh,))


@njit(cache=True, inline="always")
def _move_to_children(locations, slot_child, child_location):
    """locations[p] <- the location of slot p's child (unchanged where it has none)."""
    for p in range(locations.shape[0]):
        if slot_child[p] >= 0:
            locations[p] = child_location[slot_child[p]]


@loop_kernel
def _write_children(locations, pool, t, slot_child, child_location, likelihood, values):
    """The writes of :func:`rbpf_commit_children` once the slots are taken over; ``values`` (K,)
    scratch."""
    table, cell_block, cell_slot = pool.table, pool.cell_block, pool.cell_slot
    for p in range(table.shape[0]):
        ahead = p + PREFETCH_AHEAD
        if ahead < table.shape[0] and slot_child[ahead] >= 0:
            _prefetch_write(pool, ahead, child_location[slot_child[ahead]])
        c = slot_child[p]
        if c < 0:
            continue
        j = child_location[c]
        r = table[p, cell_block[j]]  # the parent's row (only its sole user writes a row in place)
        d = age(pool.stamps, pool.stamped, t, r, cell_slot[j])
        lam = evidence(pool.rows, pool.powers, d, r, cell_slot[j], likelihood)
        observed_cell(pool.rows, pool.powers, d, r, cell_slot[j], likelihood, lam, values)
        write_cell(pool, t, p, j, values)
    _move_to_children(locations, slot_child, child_location)


@njit(cache=True)
def rbpf_commit_children_cells(locations, t, child_location, neighbors, readings, *fields):
    """:func:`rbpf_commit_children` for blocking labels and sensor footprints: each kept child's
    W changed cells are computed from its parent's map as ``rbpf_enumerate_cells`` defines them
    (:func:`~onlinemap.kernels.rbpf_enumerate.footprint_child`; the parent's location is read
    before any slot moves) and written. Needs ``free_top[0] >= W P``. O(P F K^2 + P W B K).
    ``*fields``: the fields of the :class:`Slots`, the :class:`~onlinemap.kernels.rbpf.World` and
    the pool, in that order (``kernels/rbpf.py``: bundles and dispatch)."""
    slots, world, pool = Slots(*fields[:_SLOTS_END]), World(*fields[_SLOTS_END:_WORLD_END]), Pool(*fields[_WORLD_END:])
    k = world.sensor.shape[0]
    n_reads = world.footprint_cells.shape[1]
    width = n_reads + int(world.has_blocking)
    take_over_slots(pool, slots.ancestors)
    scratch = FootprintScratch(np.empty(k), np.empty(k), np.empty(n_reads), np.empty(width, dtype=np.int64),
                               np.empty((width, k)))
    _write_children_cells(locations, pool, world, t, slots, child_location, neighbors, readings, scratch)


@njit(cache=True, inline="always")
def _child_cells(pool, world, t, table_row, l, j, neighbors, readings, scratch, ids, cells):
    """The changed cells (``ids`` (W,), ``cells`` (W, K)) of the child at cell j of a parent at l
    whose map has block rows ``table_row``
    (:func:`~onlinemap.kernels.rbpf_enumerate.footprint_child`, with posteriors)."""
    n = neighbors[l]
    gated = world.has_blocking and n != l
    if gated:
        passable_before(pool, table_row, world, t, n, scratch.before)
    footprint_child(pool, table_row, world, t, j, n, gated, readings, scratch, ids, cells, True)


@loop_kernel
def _write_children_cells(locations, pool, world, t, slots, child_location, neighbors, readings, scratch):
    """The writes of :func:`rbpf_commit_children_cells` once the slots are taken over (slot p then
    holds its parent's rows); ``scratch``: a :class:`FootprintScratch`."""
    slot_child, ids, cells = slots.slot_child, scratch.ids, scratch.cells
    for p in range(pool.table.shape[0]):
        ahead = p + PREFETCH_AHEAD
        if ahead < pool.table.shape[0] and slot_child[ahead] >= 0:
            _prefetch_write(pool, ahead, child_location[slot_child[ahead]])
            prefetch_footprint(pool, world.footprint_cells, ahead, child_location[slot_child[ahead]])
        c = slot_child[p]
        if c < 0:
            continue
        # the parent's location (no slot has moved yet); slot p holds its rows since the take-over
        _child_cells(pool, world, t, pool.table[p], locations[slots.ancestors[p]], child_location[c], neighbors,
                     readings, scratch, ids, cells)
        for w in range(ids.shape[0]):  # computed from the parent's rows before any of them is copied
            if ids[w] >= 0:
                write_cell(pool, t, p, ids[w], cells[w])
    _move_to_children(locations, slot_child, child_location)


@njit(cache=True, inline="always")
def _prefetch_child(pool, slots, child_location, ahead, stop):
    """Ask for the marginal of the cell slot ``ahead``'s child enters, from its parent's rows, if
    that slot (below ``stop``) has a child."""
    if ahead < stop and slots.slot_child[ahead] >= 0:
        prefetch_cell(pool, slots.ancestors[ahead], child_location[slots.slot_child[ahead]])


@thread_kernel
def stage_children(pool, t, slots, child_location, likelihood, staged, start, stop):
    """The writes :func:`_write_children` makes, staged for slots ``start..stop - 1`` before the
    commit (from the parents' rows, ``table[ancestors[p]]``, which the take-over gives slot p):
    ``staged.locations`` (P,) the child's cell (-1: no child), ``staged.ids`` (P, 1) the same,
    ``staged.cells`` (P, 1, K) its observed cell's posterior."""
    cell_block, cell_slot = pool.cell_block, pool.cell_slot
    for p in range(start, stop):
        _prefetch_child(pool, slots, child_location, p + PREFETCH_AHEAD, stop)
        c = slots.slot_child[p]
        staged.locations[p] = -1
        staged.ids[p, 0] = -1
        if c >= 0:
            j = child_location[c]
            r = pool.table[slots.ancestors[p], cell_block[j]]
            d = age(pool.stamps, pool.stamped, t, r, cell_slot[j])
            lam = evidence(pool.rows, pool.powers, d, r, cell_slot[j], likelihood)
            observed_cell(pool.rows, pool.powers, d, r, cell_slot[j], likelihood, lam, staged.cells[p, 0])
            staged.locations[p] = j
            staged.ids[p, 0] = j


@thread_kernel
def stage_children_cells(locations, pool, world, t, slots, child_location, neighbors, readings, staged, start, stop,
                         scratch):
    """The writes :func:`_write_children_cells` makes, staged for slots ``start..stop - 1`` before
    the commit (as :func:`stage_children`): ``staged.locations`` (P,), ``staged.ids`` (P, W),
    ``staged.cells`` (P, W, K); ``scratch`` a :class:`FootprintScratch` (its ``before``,
    ``given``, ``lams``)."""
    for p in range(start, stop):
        _prefetch_child(pool, slots, child_location, p + PREFETCH_AHEAD, stop)
        c = slots.slot_child[p]
        staged.locations[p] = -1
        if c < 0:
            for w in range(staged.ids.shape[1]):
                staged.ids[p, w] = -1
            continue
        q = slots.ancestors[p]
        j = child_location[c]
        _child_cells(pool, world, t, pool.table[q], locations[q], j, neighbors, readings, scratch, staged.ids[p],
                     staged.cells[p])
        staged.locations[p] = j


@loop_kernel
def plan_writes(pool, staged):
    """The bookkeeping of copy-on-write for staged writes, in the order the serial commit makes
    them (slots in order, then their cells): ``staged.target`` (P, W) <- the row each write goes
    to, ``staged.source`` (P, W) <- the row to copy into it first (-1: none;
    :func:`~onlinemap.kernels.rbpf.row_for_write`). Slots with ``staged.locations[p] < 0`` and
    cells -1 write nothing. O(P W)."""
    new_ids, target, source = staged.ids, staged.target, staged.source
    for p in range(new_ids.shape[0]):
        for w in range(new_ids.shape[1]):
            target[p, w] = -1
            source[p, w] = -1
            if staged.locations[p] >= 0 and new_ids[p, w] >= 0:
                target[p, w], source[p, w] = row_for_write(pool, p, pool.cell_block[new_ids[p, w]])


@thread_kernel
def copy_planned(pool, t, staged, start, stop):
    """The copies :func:`plan_writes` planned, for slots ``start..stop - 1`` (each reads a row
    no write of this step changes before every copy is made, and fills a row only its slot uses)."""
    for p in range(start, stop):
        for w in range(staged.target.shape[1]):
            if staged.source[p, w] >= 0:
                copy_row(pool, t, staged.source[p, w], staged.target[p, w])


@thread_kernel
def write_planned(pool, t, staged, locations, start, stop):
    """The staged writes of slots ``start..stop - 1`` into their planned rows (rows only their
    slot uses, once the copies are made), then their locations (``staged.locations[p] < 0``:
    kept)."""
    for p in range(start, stop):
        for w in range(staged.target.shape[1]):
            if staged.target[p, w] >= 0:
                set_slot(pool, t, staged.target[p, w], pool.cell_slot[staged.ids[p, w]], staged.cells[p, w])
        if staged.locations[p] >= 0:
            locations[p] = staged.locations[p]
