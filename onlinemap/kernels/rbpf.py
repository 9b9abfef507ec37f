"""numba kernels of the Rao-Blackwellised particle filter (``estimators/rbpf.py``): the particle
maps' pool, its bundle and the reads and writes every other RBPF kernel makes of it.

Particle maps are stored as shared, copy-on-write blocks of B cells, handed to the kernels as one
:class:`Pool` (``BlockPool.arrays()``):

- ``rows (R, B, K)``: block rows of per-cell label marginals; ``stamps (R, B)``: the step at which
  each marginal was last brought up to date (dynamic worlds with lazy dynamics; a (R, 0) array
  otherwise, never read); ``row_block (R,)``: which block of the map a row holds; ``refcount
  (R,)``: how many particles use the row; ``free (R,)`` with ``free_top (1,)``: a stack of unused
  rows.
- ``table (P, n_blocks)``: the row holding block b of particle p's map, so cell i of particle p
  is ``rows[table[p, cell_block[i]], cell_slot[i]]``; ``block_members (n_blocks, B)`` lists each
  block's cells (-1 pads a partial block). Blocks are runs of a corridor or square tiles of a 2D
  grid, so a robot stays in one block for several steps.

With lazy dynamics the marginal of a cell at step t is ``row @ powers[t - stamp]`` (``powers[d] =
C^d``, :func:`carried`). Resampling copies table rows (n_blocks ints per particle that replaces a
dropped one) instead of maps; a particle writing into a shared block first copies that one block
(B K floats). The model's motion and sensor tables travel as one :class:`World`.

The jobs live in their own modules: ``rbpf_enumerate`` (children and proposals), ``rbpf_commit``
(selection and the writes of a step), ``rbpf_recovery`` (relocation after depletion),
``rbpf_parallel`` (the threaded drivers), ``rbpf_move`` (the resample-move step), ``rbpf_context``
(the per-particle context prior's tilts).

Bundles and dispatch: numba types a bundle argument in Python on every call from Python, some 5
us for a :class:`Pool` against 0.1 us per array typed in C (measured), which a small filter's
step would pay several times. So the entry points a step calls from Python
(:func:`rbpf_refresh`, :func:`rbpf_map_mixture`, :func:`particle_maps`, the commits, the
proposal, the sampling schemes' pick and the enumerations' range kernels) take their bundles as
their fields, last (``*fields``: ``kernel(..., *children, *blocks.arrays())``), and rebuild them
(``Pool(*fields[i:])``); each bundle's fields in its NamedTuple's order, the bundles in the order
the kernel's docstring names, split at module constants (``len(Children._fields)``...).

Bundles and reference counting: a plain ``njit`` kernel (numba counts references) that passed a
bundle into inlined helpers in a loop ran 250-800x slower (every field access counted each array
of the tuple; measured): such kernels take the bundle's fields into locals
first and use the array helpers; bundles reach inlined helpers only inside
:data:`~onlinemap.kernels.loop_kernel` and :data:`~onlinemap.kernels.thread_kernel`, where they
cost nothing (measured).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from . import PREFETCH_AHEAD, loop_kernel, prefetch, thread_kernel


class Pool(NamedTuple):
    """The particle maps' arrays (module docstring), ``max_age`` the age beyond which a copied
    slot is brought up to date (``REFRESH_STEPS``)."""

    rows: np.ndarray
    stamps: np.ndarray
    row_block: np.ndarray
    refcount: np.ndarray
    free: np.ndarray
    free_top: np.ndarray
    table: np.ndarray
    cell_block: np.ndarray
    cell_slot: np.ndarray
    block_members: np.ndarray
    powers: np.ndarray
    stamped: bool
    max_age: int


class World(NamedTuple):
    """The model's motion and sensor tables the RBPF's kernels read (built once per model by the
    estimators): ``p_move``; ``blocking (K,)`` bool and ``has_blocking`` (any of it); ``press
    (2, K)``, what a press says about the label of the cell pressed into
    (``GridModel.press_likelihood``: row 0 entered ``[k passable]``, row 1 stayed ``1 - p_move [k
    passable]``); ``change (K, K)`` C; ``footprint_cells (N, F)`` (-1 off the grid); ``sensor (K,
    Z)``; ``likelihood (Z, K)`` (row z: ``sensor[:, z]``); ``moves (A, N)``; ``predecessor (A, N)``
    (the cell a move enters j from, -1)."""

    p_move: float
    blocking: np.ndarray
    has_blocking: bool
    press: np.ndarray
    change: np.ndarray
    footprint_cells: np.ndarray
    sensor: np.ndarray
    likelihood: np.ndarray
    moves: np.ndarray
    predecessor: np.ndarray


@njit(cache=True, inline="always")
def age(stamps, dynamic, t, r, j):
    """Steps since slot j of block row r was last brought up to date (0 in a static world)."""
    d = 0
    if dynamic:
        d = t - stamps[r, j]
    return d


@njit(cache=True, inline="always")
def carried(rows, powers, d, r, j, b):
    """P(label b) of slot j of block row r carried forward by ``C^d`` (``d`` steps after its
    stamp): ``(row @ C^d)[b]``, the row itself where d = 0.

    (The inlined helpers here have one ``return`` statement and loops without ``break``: numba then
    prunes the reference counting of their array arguments, which otherwise costs atomic
    operations on every call, several times the arithmetic. ``return a if c else b`` is two.)"""
    value = rows[r, j, b]
    if d != 0:
        value = 0.0
        for a in range(rows.shape[2]):
            value += rows[r, j, a] * powers[d, a, b]
    return value


@njit(cache=True, inline="always")
def evidence(rows, powers, d, r, j, likelihood):
    """``P(z | cell) = sum_b current(b) likelihood[b]`` for slot j of block row r, ``d`` steps
    after its stamp (:func:`age`; the callers compute it: an age read inside a looping helper
    defeats the pruning of reference counts)."""
    acc = 0.0
    for b in range(likelihood.shape[0]):
        acc += carried(rows, powers, d, r, j, b) * likelihood[b]
    return acc


@njit(cache=True, inline="always")
def observed_cell(rows, powers, d, r, j, likelihood, lam, out):
    """out (K,) <- the posterior of slot j of row r (``d`` steps after its stamp) after seeing a
    label of likelihood ``likelihood`` (``lam`` = its evidence, from :func:`evidence`); the prior
    unchanged where ``lam`` is 0."""
    for b in range(likelihood.shape[0]):  # divide (1 / lam overflows for a subnormal lam)
        current = carried(rows, powers, d, r, j, b)
        out[b] = current * likelihood[b] / lam if lam > 0.0 else current


@njit(cache=True, inline="always")
def prefetch_cell(pool, q, cell):
    """Ask for particle q's marginal of ``cell`` (and its stamp) ahead of its use (:func:`prefetch`)."""
    r = pool.table[q, pool.cell_block[cell]]
    prefetch(pool.rows, (r, pool.cell_slot[cell], 0))
    if pool.stamped:
        prefetch(pool.stamps, (r, pool.cell_slot[cell]))


@loop_kernel
def take_over_slots(shared, ancestors):
    """Slots taken over by a copy (``ancestors[p] != p``; such ancestors keep their own slot, so
    sources are never overwritten) release their rows and share the ancestor's: O(n_blocks) per
    copied particle, reference counts touched only where the two rows differ (a row both share
    keeps its count: it is named by both, so it never drops to 0 on the way). ``shared``: a
    :class:`Pool`, or any bundle of rows shared copy-on-write (``refcount``, ``free``,
    ``free_top``, ``table``: the path history's)."""
    refcount, free, free_top, table = shared.refcount, shared.free, shared.free_top, shared.table
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
def row_for_write(shared, p, b):
    """(row, source): the row particle p writes block b into, and the row to copy into it first
    (-1: none). A row p shares (count > 1) is replaced by a free one, which takes over p's
    reference: the bookkeeping of copy-on-write, without touching the rows. ``shared`` as
    :func:`take_over_slots`'s, with ``row_block``."""
    r = shared.table[p, b]
    source = -1
    if shared.refcount[r] > 1:
        shared.free_top[0] -= 1
        fresh = shared.free[shared.free_top[0]]
        shared.row_block[fresh] = b
        shared.refcount[r] -= 1
        shared.refcount[fresh] = 1
        shared.table[p, b] = fresh
        source = r
        r = fresh
    return r, source


@njit(cache=True, inline="always")
def copy_row(pool, t, source, row):
    """Block row ``row`` <- a copy of ``source`` (O(B K)); slots older than ``max_age`` steps are
    brought up to date (stamped t), so a copy never extends a row's age."""
    rows, stamps = pool.rows, pool.stamps
    for slot in range(rows.shape[1]):
        for label in range(rows.shape[2]):
            rows[row, slot, label] = rows[source, slot, label]
    if pool.stamped:
        for slot in range(rows.shape[1]):
            stamps[row, slot] = stamps[source, slot]
            if t - stamps[row, slot] > pool.max_age:
                for label in range(rows.shape[2]):
                    rows[row, slot, label] = carried(rows, pool.powers, t - stamps[source, slot], source, slot,
                                                     label)
                stamps[row, slot] = t


@njit(cache=True, inline="always")
def set_slot(pool, t, row, slot, values):
    """Slot ``slot`` of block row ``row`` <- ``values`` (K,), stamped t."""
    for label in range(pool.rows.shape[2]):
        pool.rows[row, slot, label] = values[label]
    if pool.stamped:
        pool.stamps[row, slot] = t


@njit(cache=True, inline="always")
def write_cell(pool, t, p, cell, values):
    """Particle p's marginal of ``cell`` <- ``values`` (K,), stamped t; the block is first copied if
    shared (:func:`row_for_write`, :func:`copy_row`: O(B K)). Takes a free row when it copies."""
    r, source = row_for_write(pool, p, pool.cell_block[cell])
    if source >= 0:
        copy_row(pool, t, source, r)
    set_slot(pool, t, r, pool.cell_slot[cell], values)


@njit(cache=True)
def rbpf_refresh(t, start, count, *fields):
    """Bring rows ``start, start + 1, ...`` (``count`` of them, cyclically) up to date at step t:
    ``row <- row @ C^(t - stamp)``, stamp ``t``. Same values, bounded ages: called every step
    with ``count = ceil(R / h)``, every row is refreshed at least every h steps; with copies
    refreshed beyond age h (:func:`copy_row`), no stamp is older than 2 h + 1 steps, so a table
    of powers up to a few h suffices however long the run. O(count B K^2)."""
    pool = Pool(*fields)
    rows, stamps, refcount, powers = pool.rows, pool.stamps, pool.refcount, pool.powers  # locals: module docstring
    n_rows, block, k = rows.shape
    tmp = np.empty(k)
    for step in range(count):
        r = (start + step) % n_rows
        if refcount[r] == 0:
            continue
        for j in range(block):
            d = t - stamps[r, j]
            if d == 0:
                continue
            for b in range(k):
                tmp[b] = carried(rows, powers, d, r, j, b)
            for b in range(k):
                rows[r, j, b] = tmp[b]
            stamps[r, j] = t


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
def rbpf_map_mixture(t, weights, out, *fields):
    """out (N, K) <- ``sum_p weights[p] * current marginals of particle p``.

    First the weight of every row (:func:`row_weights`), O(P n_blocks) at most; then one pass over
    the rows in use, in row order, O(R_used B K), with K^2 flops per out-of-date cell in a dynamic
    world (:func:`_mixture`). R_used <= P n_blocks, and much less when particles share blocks.
    """
    pool = Pool(*fields)
    n_blocks = pool.table.shape[1]
    row_weight = np.zeros(pool.rows.shape[0])
    row_weights(pool.table, pool.refcount, weights, ordered_sum(weights), row_weight, np.int64(0),  # one compile
                n_blocks, np.empty(n_blocks, dtype=np.int64), np.empty(n_blocks, dtype=np.int64), np.empty(n_blocks))
    out[:] = 0.0
    _mixture(pool, t, row_weight, out)


@loop_kernel
def ordered_sum(values):
    """``sum(values)``, added in order from 0.0."""
    total = 0.0
    for i in range(values.shape[0]):
        total += values[i]
    return total


@thread_kernel
def row_weights(table, refcount, weights, total, out, first, last, split, current, acc):
    """out[r] <- the weight of every row r holding one of the blocks ``first..last - 1``: the sum
    of ``weights`` (P,) over the particles whose table names it, in increasing particle order
    (``out`` zero on entry; rows nobody names stay 0). A block every particle shares (its row's
    count is P) gets ``total``, the plain sum (:func:`ordered_sum`); elsewhere a run of particles naming
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
def _add_row(pool, t, r, w, out):
    """out[members] += ``w`` times the current marginals of block row r (its block's cells
    ``members`` (B,), -1 padding)."""
    members = pool.block_members[pool.row_block[r]]
    for j in range(members.shape[0]):
        i = members[j]
        if i >= 0:
            d = age(pool.stamps, pool.stamped, t, r, j)
            for b in range(out.shape[1]):
                out[i, b] += w * carried(pool.rows, pool.powers, d, r, j, b)


@loop_kernel
def _mixture(pool, t, row_weight, out):
    """out (N, K) += ``sum_r row_weight[r] * current marginals of block row r``, rows in order."""
    for r in range(pool.rows.shape[0]):
        if row_weight[r] != 0.0:
            _add_row(pool, t, r, row_weight[r], out)


@thread_kernel
def mixture_blocks(pool, t, row_weight, first, last, out):
    """:func:`_mixture` of the rows holding blocks ``first..last - 1`` (into those blocks' cells):
    O(R) to scan the rows, plus O(B K) per row of nonzero weight among them."""
    for r in range(pool.rows.shape[0]):
        if row_weight[r] != 0.0 and first <= pool.row_block[r] < last:
            _add_row(pool, t, r, row_weight[r], out)


@njit(cache=True)
def particle_maps(t, which, out, *fields):
    """out (M, N, K) <- the current map marginals of particles ``which`` (M,) (the planners'
    hypotheses, inspection and tests). O(M N K^2)."""
    pool = Pool(*fields)
    rows, stamps, table, cell_block, cell_slot, powers = (pool.rows, pool.stamps, pool.table, pool.cell_block,
                                                          pool.cell_slot, pool.powers)  # locals: module docstring
    dynamic = pool.stamped
    n_cells, k = out.shape[1], out.shape[2]
    for m in range(which.shape[0]):
        p = which[m]
        for i in range(n_cells):
            r = table[p, cell_block[i]]
            for b in range(k):
                d = age(stamps, dynamic, t, r, cell_slot[i])
                out[m, i, b] = carried(rows, powers, d, r, cell_slot[i], b)
