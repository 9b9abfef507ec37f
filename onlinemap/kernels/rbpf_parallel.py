"""Parallel drivers of the RBPF's kernels (``onlinemap/kernels/rbpf.py``), for ``threads > 1``.

Each driver splits the work into fixed chunks (``chunk`` particles, :data:`CHUNK` for the filter,
or ``BLOCK_GROUP`` map blocks) that do not depend on the number of threads, runs the serial kernel's inner loop on
each chunk under numba's ``prange``, and combines the chunks in chunk order. No chunk reads
what another writes, and every sum is taken in the order the serial kernel takes it, so the
results are the serial kernels' bit for bit, whatever the number of threads:

- :func:`rbpf_enumerate_parallel` / :func:`rbpf_enumerate_cells_parallel`: each chunk of parents
  writes its children from index ``2 * start`` on; the chunks are then moved together in order
  (one pass over the children; none when no child was left out);
- :func:`rbpf_propose_parallel`: particles are independent;
- :func:`rbpf_stage_children_parallel` / :func:`rbpf_stage_children_cells_parallel` then
  :func:`rbpf_commit_staged_parallel`: the commit in three passes. First every kept child's
  changed cells are computed from its parent's rows (nothing written yet); then the take-over
  and the bookkeeping of copy-on-write run serially, in the serial commit's order, so every
  write gets the row the serial commit gives it; then all block copies are made (each reads a
  row that no write has changed yet) and, after them, all writes (each into a row only its
  particle uses). The sampling schemes' commit is the same last step on their proposals;
- :func:`rbpf_map_mixture_parallel`: the weight of a row is summed over the particles in order by
  the chunk of blocks holding it; then each block adds its rows, in row order, into its own cells.

Cost: as the serial kernels, plus one pass to move the children together and one to sort the
rows by block; the serial parts (take-over, copy-on-write bookkeeping, Fearnhead-Clifford's
selection) stay serial. Compiled with ``parallel=True`` (a few seconds once, then cached); the
number of threads is numba's (``numba.set_num_threads``, at most ``NUMBA_NUM_THREADS``).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from .rbpf import (_copy_planned, _enumerate, _enumerate_cells, _mixture_rows, _plan_writes, _propose, _row_weights,
                   _rows_by_block, _stage_children, _stage_children_cells, _sum, _take_over_slots, _write_planned)

CHUNK = 1024  # particles per chunk (the drivers' ``chunk``), fixed: the chunks do not depend on the threads
BLOCK_GROUP = 8  # map blocks per chunk of the row weights: one cache line of a particle's table row


@njit(cache=True, inline="always")
def _chunks(n, chunk):
    """Number of chunks of ``chunk`` items covering ``n``."""
    return (n + chunk - 1) // chunk


@njit(cache=True)
def _gather_children(counts, chunk, child_parent, child_location, child_log_weight, child_log_motion, child_ids,
                     child_cells):
    """Move chunk c's ``counts[c]`` children from index ``2 c chunk`` to follow the previous chunks'
    (the stored ids, cells and log motion too when ``child_cells`` has rows); returns M. O(M)."""
    m = 0
    for c in range(counts.shape[0]):
        first = 2 * c * chunk
        if m != first:  # m < first: copying upwards never overwrites a child not yet moved
            for i in range(counts[c]):
                child_parent[m + i] = child_parent[first + i]
                child_location[m + i] = child_location[first + i]
                child_log_weight[m + i] = child_log_weight[first + i]
                if child_cells.shape[0] > 0:
                    child_log_motion[m + i] = child_log_motion[first + i]
                    child_ids[m + i] = child_ids[first + i]
                    child_cells[m + i] = child_cells[first + i]
        m += counts[c]
    return m


@njit(cache=True, parallel=True)
def rbpf_enumerate_parallel(locations, log_weights, pool, pool_stamps, table, cell_block, cell_slot, powers, dynamic,
                            t, neighbors, p_move, likelihood, child_parent, child_location, child_log_weight, chunk):
    """:func:`~onlinemap.kernels.rbpf.rbpf_enumerate` (the same children, in the same order)."""
    n = locations.shape[0]
    counts = np.empty(_chunks(n, chunk), dtype=np.int64)
    for c in prange(counts.shape[0]):
        start = c * chunk
        counts[c] = _enumerate(locations, log_weights, pool, pool_stamps, table, cell_block, cell_slot, powers,
                               dynamic, t, neighbors, p_move, likelihood, child_parent, child_location,
                               child_log_weight, start, min(n, start + chunk), 2 * start, np.empty(1))
    return _gather_children(counts, chunk, child_parent, child_location, child_log_weight, np.empty(0),
                            np.empty((0, 1), dtype=np.int64), np.empty((0, 1, 1)))


@njit(cache=True, parallel=True)
def rbpf_enumerate_cells_parallel(locations, log_weights, pool, pool_stamps, table, cell_block, cell_slot, powers,
                                  dynamic, t, neighbors, p_move, blocking, change, footprint_cells, sensor, readings,
                                  child_parent, child_location, child_log_weight, child_log_motion, child_ids,
                                  child_cells, chunk):
    """:func:`~onlinemap.kernels.rbpf.rbpf_enumerate_cells` (the same children, in the same order)."""
    n = locations.shape[0]
    k = sensor.shape[0]
    width = child_ids.shape[1]
    counts = np.empty(_chunks(n, chunk), dtype=np.int64)
    for c in prange(counts.shape[0]):
        start = c * chunk
        counts[c] = _enumerate_cells(locations, log_weights, pool, pool_stamps, table, cell_block, cell_slot, powers,
                                     dynamic, t, neighbors, p_move, blocking, change, footprint_cells, sensor,
                                     readings, child_parent, child_location, child_log_weight, child_log_motion,
                                     child_ids, child_cells, start, min(n, start + chunk), 2 * start, np.empty(k),
                                     np.empty(k), np.empty(footprint_cells.shape[1]), np.empty(width, dtype=np.int64),
                                     np.empty((width, k)))
    return _gather_children(counts, chunk, child_parent, child_location, child_log_weight, child_log_motion, child_ids,
                            child_cells)


@njit(cache=True, parallel=True)
def rbpf_propose_parallel(locations, pool, pool_stamps, table, cell_block, cell_slot, powers, dynamic, t, ancestors,
                          neighbors, p_move, likelihood, optimal, uniforms, new_locations, new_cells, log_increments,
                          chunk):
    """:func:`~onlinemap.kernels.rbpf.rbpf_propose`."""
    n = ancestors.shape[0]
    for c in prange(_chunks(n, chunk)):
        _propose(locations, pool, pool_stamps, table, cell_block, cell_slot, powers, dynamic, t, ancestors, neighbors,
                 p_move, likelihood, optimal, uniforms, new_locations, new_cells, log_increments, c * chunk,
                 min(n, (c + 1) * chunk))


@njit(cache=True, parallel=True)
def rbpf_stage_children_parallel(pool, pool_stamps, table, cell_block, cell_slot, powers, dynamic, t, ancestors,
                                 slot_child, child_location, likelihood, new_locations, new_ids, new_cells,
                                 chunk):
    """Fearnhead-Clifford's kept children's writes (:func:`~onlinemap.kernels.rbpf._stage_children`),
    staged from the parents' rows for :func:`rbpf_commit_staged_parallel`; writes only the staging
    arrays."""
    n = slot_child.shape[0]
    for c in prange(_chunks(n, chunk)):
        _stage_children(pool, pool_stamps, table, cell_block, cell_slot, powers, dynamic, t, ancestors, slot_child,
                        child_location, likelihood, new_locations, new_ids, new_cells, c * chunk,
                        min(n, (c + 1) * chunk))


@njit(cache=True, parallel=True)
def rbpf_stage_children_cells_parallel(locations, pool, pool_stamps, table, cell_block, cell_slot, powers, dynamic, t,
                                       ancestors, slot_child, child_location, neighbors, p_move, blocking, change,
                                       footprint_cells, sensor, readings, new_locations, new_ids, new_cells, chunk):
    """:func:`rbpf_stage_children_parallel` for blocking labels and sensor footprints
    (:func:`~onlinemap.kernels.rbpf._stage_children_cells`); writes only the staging arrays."""
    n = slot_child.shape[0]
    k = sensor.shape[0]
    for c in prange(_chunks(n, chunk)):
        _stage_children_cells(locations, pool, pool_stamps, table, cell_block, cell_slot, powers, dynamic, t, ancestors,
                              slot_child, child_location, neighbors, p_move, blocking, change, footprint_cells, sensor,
                              readings, new_locations, new_ids, new_cells, c * chunk, min(n, (c + 1) * chunk),
                              np.empty(k), np.empty(k), np.empty(footprint_cells.shape[1]))


@njit(cache=True, parallel=True)
def rbpf_commit_staged_parallel(locations, pool, pool_stamps, row_block, refcount, free, free_top, table, cell_block,
                                cell_slot, dynamic, powers, max_age, t, ancestors, new_locations, new_ids, new_cells,
                                target, source, chunk):
    """:func:`~onlinemap.kernels.rbpf.rbpf_commit_cells`, bit for bit: the take-over and the
    copy-on-write bookkeeping (:func:`~onlinemap.kernels.rbpf._plan_writes`, into ``target`` and
    ``source`` (P, W)) serially, then every block copy, then every write, then the locations.
    Needs ``free_top[0] >= W P``."""
    n = new_locations.shape[0]
    _take_over_slots(refcount, free, free_top, table, ancestors)
    _plan_writes(row_block, refcount, free, free_top, table, cell_block, new_locations, new_ids, target, source)
    for c in prange(_chunks(n, chunk)):
        _copy_planned(pool, pool_stamps, dynamic, powers, max_age, t, target, source, c * chunk,
                      min(n, (c + 1) * chunk))
    for c in prange(_chunks(n, chunk)):
        _write_planned(pool, pool_stamps, dynamic, t, cell_slot, new_ids, new_cells, target, c * chunk,
                       min(n, (c + 1) * chunk))
    for p in range(n):
        if new_locations[p] >= 0:
            locations[p] = new_locations[p]


@njit(cache=True, parallel=True)
def rbpf_map_mixture_parallel(pool, pool_stamps, row_block, refcount, table, block_members, powers, dynamic, t,
                              weights, out):
    """:func:`~onlinemap.kernels.rbpf.rbpf_map_mixture`, the same sums: the row weights by chunks of
    ``BLOCK_GROUP`` blocks (a row holds one block, and each row's weight adds its particles in
    order), then each block's rows in row order into its own cells."""
    n_blocks = table.shape[1]
    row_weight = np.zeros(pool.shape[0])
    total = _sum(weights)
    n_groups = (n_blocks + BLOCK_GROUP - 1) // BLOCK_GROUP
    for g in prange(n_groups):
        _row_weights(table, refcount, weights, total, row_weight, g * BLOCK_GROUP,
                     min(n_blocks, (g + 1) * BLOCK_GROUP), np.empty(BLOCK_GROUP, dtype=np.int64),
                     np.empty(BLOCK_GROUP, dtype=np.int64), np.empty(BLOCK_GROUP))
    starts = np.zeros(n_blocks + 1, dtype=np.int64)
    rows = np.empty(pool.shape[0], dtype=np.int64)
    _rows_by_block(row_block, row_weight, starts, rows)
    out[:] = 0.0
    for b in prange(n_blocks):
        _mixture_rows(pool, pool_stamps, row_block, block_members, powers, dynamic, t, row_weight,
                      rows[starts[b]:starts[b + 1]], out)
