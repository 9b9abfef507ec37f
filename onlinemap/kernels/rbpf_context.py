"""numba kernels of the RBPF's per-particle context prior (``label_prior="particle_context"``,
:mod:`onlinemap.estimators.rbpf_prior`): the tilt, before a step, of the cells each particle may
read in it, and its undo when the step then raises.

A particle's cells have a status (P, N) uint8: :data:`UNTOUCHED`, :data:`TILTED` (its prior
tilted by its context, not read yet) or :data:`READ` (read by the particle's path). A cell's
context in particle p is the base-(K + 2) number of its north, south, west and east neighbour
states (``label_prior.context_codes``): 0 off the grid, 1 not read by p, 2 + the most probable
label of p's marginal (the first of ties, as ``numpy.argmax``). Static worlds only: marginals
are read as stored (no lazy dynamics).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from . import loop_kernel
from .rbpf import Pool, write_cell

UNTOUCHED, TILTED, READ = 0, 1, 2


class TiltLog(NamedTuple):
    """The undo log of :func:`context_tilt`, one entry per write (M of them): the ``particle`` and
    ``cell`` (M,), the ``row`` (M,) the particle held before, whether the write ``copied`` it (M,)
    bool, and the slot's ``values`` (M, K) before (a write in place)."""

    particle: np.ndarray
    cell: np.ndarray
    row: np.ndarray
    copied: np.ndarray
    values: np.ndarray


def tilt_log(size: int, n_labels: int) -> TiltLog:
    """An empty :class:`TiltLog` for ``size`` writes of K = ``n_labels`` labels. O(size K)."""
    return TiltLog(np.empty(size, dtype=np.int64), np.empty(size, dtype=np.int64), np.empty(size, dtype=np.int64),
                   np.empty(size, dtype=np.bool_), np.empty((size, n_labels)))


_LOG_END = len(TiltLog._fields)


@njit(cache=True, inline="always")
def _candidate(status, footprint, targets, locations, weights, p, f):
    """The f-th footprint cell of the cell particle p's step may enter, if p is live and has
    neither read nor tilted it; else -1."""
    cell = -1
    if weights[p] > 0.0:
        c = footprint[targets[locations[p]], f]
        if c >= 0 and status[p, c] == UNTOUCHED:
            cell = c
    return cell


@loop_kernel
def context_tilt_count(locations, weights, targets, footprint, status) -> int:
    """How many (particle, cell) pairs :func:`context_tilt` writes: every live particle's (weight
    > 0) untouched cells of the footprint (N, F) of ``targets[location]`` (N,), the cell the
    step's action points at. O(P F)."""
    count = 0
    for p in range(len(locations)):
        for f in range(footprint.shape[1]):
            if _candidate(status, footprint, targets, locations, weights, p, f) >= 0:
                count += 1
    return count


@loop_kernel
def context_tilt(t, locations, weights, targets, footprint, neighbours, status, ratios, values, *fields):
    """Tilt, in place, each candidate cell c of each particle p (:func:`context_tilt_count`, the
    same order): its marginal ``normalise(m_pc * ratios[code])`` written at step t
    (:func:`~onlinemap.kernels.rbpf.write_cell`: a shared block copied first), its status
    :data:`TILTED`; ``code`` its context in p (module docstring; ``neighbours`` (N, 4), -1 off the
    grid), ``ratios`` ((K + 2)^4, K). ``*fields``: a :class:`TiltLog` of M entries (filled, for
    :func:`context_untilt`), then the pool's (``kernels/rbpf.py``: bundles and dispatch).
    ``values`` (K,) scratch. Needs ``free_top[0] >= M``. O(P F (4 K + K) + M B K)."""
    log, pool = TiltLog(*fields[:_LOG_END]), Pool(*fields[_LOG_END:])
    rows, table, cell_block, cell_slot, refcount = pool.rows, pool.table, pool.cell_block, pool.cell_slot, pool.refcount
    n_labels = rows.shape[2]
    base = n_labels + 2
    m = 0
    for p in range(len(locations)):
        for f in range(footprint.shape[1]):
            c = _candidate(status, footprint, targets, locations, weights, p, f)
            if c < 0:
                continue
            code = 0
            for d in range(neighbours.shape[1]):
                j = neighbours[c, d]
                state = 0
                if j >= 0:
                    state = 1
                    if status[p, j] == READ:
                        r = table[p, cell_block[j]]
                        best = 0
                        for k in range(1, n_labels):
                            if rows[r, cell_slot[j], k] > rows[r, cell_slot[j], best]:
                                best = k
                        state = 2 + best
                code = code * base + state
            r = table[p, cell_block[c]]
            slot = cell_slot[c]
            total = 0.0
            for k in range(n_labels):
                log.values[m, k] = rows[r, slot, k]
                values[k] = rows[r, slot, k] * ratios[code, k]
                total += values[k]
            for k in range(n_labels):
                values[k] /= total
            log.particle[m], log.cell[m], log.row[m], log.copied[m] = p, c, r, refcount[r] > 1
            write_cell(pool, t, p, c, values)
            status[p, c] = TILTED
            m += 1


@loop_kernel
def context_untilt(count, status, *fields):
    """Undo the first ``count`` writes of :func:`context_tilt` (``*fields``: its :class:`TiltLog`,
    then the pool's), last first: a copied
    block goes back to the row the particle held (the fresh row back on the free stack, where it
    was taken from), a slot written in place gets its values back, the cell's status
    :data:`UNTOUCHED`. The pool's rows in use, table, counts and free stack are then as before
    the tilt. O(count K)."""
    log, pool = TiltLog(*fields[:_LOG_END]), Pool(*fields[_LOG_END:])
    rows, table, cell_block, cell_slot, refcount = pool.rows, pool.table, pool.cell_block, pool.cell_slot, pool.refcount
    for i in range(count - 1, -1, -1):
        p, c, r = log.particle[i], log.cell[i], log.row[i]
        b = cell_block[c]
        if log.copied[i]:
            refcount[table[p, b]] = 0
            pool.free_top[0] += 1
            table[p, b] = r
            refcount[r] += 1
        else:
            for k in range(rows.shape[2]):
                rows[r, cell_slot[c], k] = log.values[i, k]
        status[p, c] = UNTOUCHED


@loop_kernel
def read_weight(status, weights, out):
    """out (N,) <- ``sum_p weights[p] [status[p, i] == READ]``: the weight of the particles that have
    read each cell (``status`` (P, N), ``weights`` (P,)). O(P N)."""
    out[:] = 0.0
    for p in range(status.shape[0]):
        w = weights[p]
        if w > 0.0:
            for i in range(status.shape[1]):
                if status[p, i] == READ:
                    out[i] += w


@loop_kernel
def context_mark_read(status, ancestors, locations, footprint, pressed):
    """After a step, in place: each slot p with ``ancestors[p] != p`` takes its ancestor's statuses
    (sources keep their own slot, so every copy is made before any slot is marked), then every
    slot marks :data:`READ` the footprint (N, F) of its location and, where ``pressed[p] >= 0``,
    the cell its move pressed into. O(P_copied N + P F)."""
    n_particles = status.shape[0]
    for p in range(n_particles):
        q = ancestors[p]
        if q != p:
            for i in range(status.shape[1]):
                status[p, i] = status[q, i]
    for p in range(n_particles):
        for f in range(footprint.shape[1]):
            c = footprint[locations[p], f]
            if c >= 0:
                status[p, c] = READ
        if pressed[p] >= 0:
            status[p, pressed[p]] = READ
