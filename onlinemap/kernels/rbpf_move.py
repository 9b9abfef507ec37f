"""numba kernels of the RBPF's resample-move step (``estimators/rbpf_move.py``; Gilks and Berzuini
2001): every particle's path as shared copy-on-write blocks of steps, and the Metropolis-Hastings
move that redraws a window of a particle's past.

Path history (:class:`Paths`, ``PathHistory.arrays()``; the map pool's layout,
``kernels/rbpf.py``, for steps instead of cells):

- ``rows (R, B)``: the locations at B consecutive steps; ``row_block (R,)`` the block of steps a
  row holds (block b: steps ``b B .. b B + B - 1``); ``refcount (R,)``; ``free (R,)`` with
  ``free_top (1,)``: a stack of unused rows;
- ``table (P, C)``: the row holding block b of particle p's path, -1 for a block no step has
  reached yet (the same for every particle);
- ``actions (T,)`` the action before each step, ``readings (T, F)`` each step's readings.

A step takes over the table rows of the slots resampling gave to a copy (``take_over_slots``, as
the maps' table) and writes every slot's location; a write into a row other particles share copies
it first (``row_for_write``). Particles descend from few ancestors, so their old blocks are shared.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from . import loop_kernel
from .rbpf import row_for_write, take_over_slots, write_cell
from .rbpf_enumerate import successor


class Paths(NamedTuple):
    """The path history's arrays (module docstring)."""

    rows: np.ndarray
    row_block: np.ndarray
    refcount: np.ndarray
    free: np.ndarray
    free_top: np.ndarray
    table: np.ndarray
    actions: np.ndarray
    readings: np.ndarray


class MoveScratch(NamedTuple):
    """The move's scratch, for N cells and a window of W steps: ``base``, ``cur`` (N, K) the
    particle's map without the window's readings and with a path's; ``marks`` (5, N) zeros
    (which particle loaded, read, wrote, reached a cell; the step a cell can last be at and still
    reach the window's right end); ``position`` (N,) -1; ``back`` (N,); ``support`` (W + 1, N),
    ``size`` (W + 1,), ``alpha`` (W + 1, N), ``succ`` (W + 1, N, 2), ``succ_pr`` (W + 1, N, 2): the
    forward filter; ``old``, ``new`` (W + 1,) the paths; ``probs`` (2N,), ``cells`` (2N,) a draw's;
    ``touched`` (W F,) the cells the old path read; ``values`` (K,)."""

    base: np.ndarray
    cur: np.ndarray
    marks: np.ndarray
    position: np.ndarray
    back: np.ndarray
    support: np.ndarray
    size: np.ndarray
    alpha: np.ndarray
    succ: np.ndarray
    succ_pr: np.ndarray
    old: np.ndarray
    new: np.ndarray
    probs: np.ndarray
    cells: np.ndarray
    touched: np.ndarray
    values: np.ndarray


@loop_kernel
def paths_record(paths, ancestors, locations, t):
    """Write step t into the path history: slot p takes over ``ancestors[p]``'s table row (the
    slots of a step's commit; ``ancestors[p] = p`` keeps its own), then every slot's location
    ``locations (P,)`` goes to step t of its path, a fresh row where block ``t // B`` begins (or
    where the row is shared: copy-on-write of the first ``t % B`` entries). Needs
    ``path_free_top[0] >= P``. O(P_copied C + P B) at most (C the table's width)."""
    take_over_slots(paths, ancestors)
    block = paths.rows.shape[1]
    b = t // block
    j = t % block
    for p in range(paths.table.shape[0]):
        r = paths.table[p, b]
        if r < 0:
            paths.free_top[0] -= 1
            r = paths.free[paths.free_top[0]]
            paths.row_block[r] = b
            paths.refcount[r] = 1
            paths.table[p, b] = r
        else:
            r, source = row_for_write(paths, p, b)
            if source >= 0:
                for i in range(j):
                    paths.rows[r, i] = paths.rows[source, i]
        paths.rows[r, j] = locations[p]


@njit(cache=True)
def rbpf_move(locations, log_weights, pool, paths, world, t, first, starts, window, uniforms, counts):
    """One Metropolis-Hastings move of a window of every live particle's past (static world, no
    blocking labels, a sensor without zeros), in place; particles ``first..P - 1``. Returns the
    particle it stopped before for want of free rows (P when done): the caller grows the pools and
    calls again from there.

    Particle p's window is ``x_{s+1..s+W}``, ``s = starts[p]`` (``s + W <= t``, W = ``window``),
    redrawn given ``x_s``, ``x_{s+W+1}`` (when ``s + W < t``) and every observation, the rest of
    the path kept. The target is the filter's, ``p(x_{0:t} | z_{0:t})``: in a static world the
    data outside the window depend on the path outside it only, so the window's conditional law is
    ``prod T(x_{tau-1}, x_tau) p(z_window | x_window, m_-)`` with ``m_-`` the particle's map without
    the window's readings: a cell's marginal is ``prior x prod O(., z)`` over its readings, so they
    are divided out exactly (a sensor without zeros). Proposal: forward filtering, backward
    sampling on the location chain over the cells the window's actions can reach from ``x_s`` (and
    from which ``x_{s+W+1}`` can still be reached), emissions ``e_tau(l) = prod_f sum_k m_-(c_f)[k]
    O(k, z_f)`` over the cells ``c_f`` a robot at l reads (1 for an offset off the grid reading -1,
    0 where only one of them is). The target differs from the proposal only where a path reads a
    cell it has read before in the window (the map then knows the earlier reading): the acceptance
    ratio is ``R(new) / R(old)``, ``R(x) = prod over readings of P(z | cell, m_- updated along x) /
    P(z | cell, m_-)`` (1 at a cell's first reading; the motion terms cancel). An accepted path's
    cells get their marginals given it (the old path's readings divided out, the new one's
    multiplied in), its steps are written into the history, and if the window ends at t the
    location moves. Weights are unchanged: the move leaves the target invariant (Gilks and
    Berzuini 2001). A proposal equal to the old window changes nothing.

    Random numbers: ``uniforms (P, W + 2)``: column tau draws ``x_{s+tau}`` backwards (0 is never
    used: ``x_s`` is fixed), column W + 1 the acceptance. ``counts (2,)`` += (windows proposed,
    accepted). ``pool`` the maps (:class:`~onlinemap.kernels.rbpf.Pool`), ``paths`` the
    history (:class:`Paths`), ``world`` the model's tables (:class:`~onlinemap.kernels.rbpf.World`:
    moves, predecessor, footprint_cells, likelihood). Needs, before a particle,
    ``min(2 W F, n_blocks)`` free map rows and ``W // B + 2`` free path rows.

    Cost per particle: O(W S (F K + 1) + W^2) for S the mean number of cells the window can take at
    a step (the reachable support: a few to tens), plus the writes of an accepted move (copy-on-write
    of at most 2 W F map blocks and 2 path blocks). Memory: O(W N) scratch."""
    n_cells = pool.cell_block.shape[0]
    k = pool.rows.shape[2]
    width = window + 1
    scratch = MoveScratch(np.empty((n_cells, k)), np.empty((n_cells, k)), np.zeros((5, n_cells), dtype=np.int64),
                          np.full(n_cells, -1, dtype=np.int64), np.empty(n_cells, dtype=np.int64),
                          np.empty((width, n_cells), dtype=np.int64), np.empty(width, dtype=np.int64),
                          np.empty((width, n_cells)), np.empty((width, n_cells, 2), dtype=np.int64),
                          np.empty((width, n_cells, 2)), np.empty(width, dtype=np.int64),
                          np.empty(width, dtype=np.int64), np.empty(2 * n_cells), np.empty(2 * n_cells, dtype=np.int64),
                          np.empty(window * world.footprint_cells.shape[1], dtype=np.int64), np.empty(k))
    return _move_particles(locations, log_weights, pool, paths, world, t, first, starts, window, uniforms, counts,
                           scratch)


@njit(cache=True, inline="always")
def _path_at(paths, p, step):
    """Particle p's location at ``step``."""
    block = paths.rows.shape[1]
    return paths.rows[paths.table[p, step // block], step % block]


@njit(cache=True, inline="always")
def _load(pool, p, c, base, loaded, mark):
    """``base[c]`` <- particle p's marginal of cell c (a static world: no aging), once per
    particle (``loaded[c] == mark`` once done)."""
    if loaded[c] != mark:
        loaded[c] = mark
        r = pool.table[p, pool.cell_block[c]]
        for b in range(base.shape[1]):
            base[c, b] = pool.rows[r, pool.cell_slot[c], b]


@njit(cache=True, inline="always")
def _dot(base, c, likelihood, z):
    """``sum_k base[c, k] likelihood[z, k]``: P(reading z | cell c's marginal)."""
    acc = 0.0
    for b in range(base.shape[1]):
        acc += base[c, b] * likelihood[z, b]
    return acc


@njit(cache=True, inline="always")
def _draw(probs, count, total, uniform):
    """The index i < count drawn in proportion to ``probs[i]`` with ``uniform``."""
    target = uniform * total
    chosen = count - 1
    for i in range(count):
        target -= probs[i]
        if target < 0.0:
            chosen = i
            break
    return chosen


@njit(cache=True, inline="always")
def _revisit_ratio(path, s, window, world, paths, scratch, mark):
    """``R(path)`` of :func:`rbpf_move`: the product, over the window's readings in order, of
    ``P(z | cell, m_- updated by the path's earlier readings of it) / P(z | cell, m_-)``.
    Leaves in ``scratch.cur[c]`` (``current[c] == mark``) each read cell's marginal given the
    path's readings."""
    footprint_cells, readings, likelihood = world.footprint_cells, paths.readings, world.likelihood
    base, cur, current = scratch.base, scratch.cur, scratch.marks[1]
    ratio = 1.0
    for tau in range(1, window + 1):
        for f in range(footprint_cells.shape[1]):
            c = footprint_cells[path[tau], f]
            z = readings[s + tau, f]
            if c < 0 or z < 0:
                continue
            if current[c] == mark:
                lam = _dot(cur, c, likelihood, z)
                ratio *= lam / _dot(base, c, likelihood, z)
                for b in range(cur.shape[1]):
                    cur[c, b] = cur[c, b] * likelihood[z, b] / lam
            else:
                current[c] = mark
                lam = _dot(base, c, likelihood, z)
                for b in range(cur.shape[1]):
                    cur[c, b] = base[c, b] * likelihood[z, b] / lam
    return ratio


@njit(cache=True, inline="always")
def _map_without_window(pool, world, paths, p, s, window, scratch, mark):
    """``scratch.base`` <- m_-, particle p's marginals of the cells its old window (``scratch.old``)
    read, the window's readings divided out (then normalised); returns how many cells, listed in
    ``scratch.touched``."""
    footprint_cells, readings, likelihood = world.footprint_cells, paths.readings, world.likelihood
    base, loaded, touched, old = scratch.base, scratch.marks[0], scratch.touched, scratch.old
    n_touched = 0
    for tau in range(1, window + 1):
        for f in range(footprint_cells.shape[1]):
            c = footprint_cells[old[tau], f]
            z = readings[s + tau, f]
            if c < 0 or z < 0:
                continue
            if loaded[c] != mark:
                _load(pool, p, c, base, loaded, mark)
                touched[n_touched] = c
                n_touched += 1
            for b in range(base.shape[1]):
                base[c, b] /= likelihood[z, b]
    for i in range(n_touched):
        c = touched[i]
        total = 0.0
        for b in range(base.shape[1]):
            total += base[c, b]
        for b in range(base.shape[1]):
            base[c, b] /= total
    return n_touched


@njit(cache=True, inline="always")
def _mark_bridge(world, paths, s, window, right, scratch, mark):
    """The bridge: ``reach[c] >= tau`` (``reached[c] == mark``) where a robot at c at window step tau
    may still get to the right end ``right`` (a superset: staying is assumed possible)."""
    reached, reach, back = scratch.marks[3], scratch.marks[4], scratch.back
    reached[right] = mark
    reach[right] = window + 1
    back[0] = right
    n_back = 1
    for tau in range(window, 0, -1):
        a = paths.actions[s + tau + 1]
        for e in range(n_back):
            i = world.predecessor[a, back[e]]
            if i >= 0 and reached[i] != mark:
                reached[i] = mark
                reach[i] = tau
                back[n_back] = i
                n_back += 1


@njit(cache=True, inline="always")
def _spread(world, paths, s, tau, bridge, scratch, mark):
    """The forward filter's step tau before its emissions: the successors of step tau - 1's support
    (``scratch.support``, ``alpha``) under the window's action, those that can still reach the
    right end with a bridge, with their summed weights; ``succ``, ``succ_pr`` each predecessor's
    successors. Returns their number."""
    support, alpha, position = scratch.support, scratch.alpha, scratch.position
    reached, reach = scratch.marks[3], scratch.marks[4]
    a = paths.actions[s + tau]
    count = 0
    for e in range(scratch.size[tau - 1]):
        i = support[tau - 1, e]
        weight = alpha[tau - 1, e]
        n = world.moves[a, i]
        for sc in range(2):
            j, pr = successor(i, n, world.p_move, sc)
            f = -1
            if pr > 0.0 and weight > 0.0 and (not bridge or (reached[j] == mark and reach[j] >= tau)):
                f = position[j]
                if f < 0:
                    f = count
                    support[tau, f] = j
                    position[j] = f
                    alpha[tau, f] = 0.0
                    count += 1
                alpha[tau, f] += weight * pr
            scratch.succ[tau, e, sc] = f
            scratch.succ_pr[tau, e, sc] = pr
    return count


@njit(cache=True, inline="always")
def _emitted(pool, world, paths, p, s, tau, count, scratch, mark):
    """Step tau's weights times their emissions (what a robot there reads, under m_-); returns
    their sum."""
    footprint_cells, readings, likelihood = world.footprint_cells, paths.readings, world.likelihood
    support, alpha, base, loaded = scratch.support, scratch.alpha, scratch.base, scratch.marks[0]
    total = 0.0
    for f in range(count):
        j = support[tau, f]
        scratch.position[j] = -1
        emission = 1.0
        for g in range(footprint_cells.shape[1]):
            c = footprint_cells[j, g]
            z = readings[s + tau, g]
            if c < 0 or z < 0:
                if c >= 0 or z >= 0:
                    emission = 0.0
            else:
                _load(pool, p, c, base, loaded, mark)
                emission *= _dot(base, c, likelihood, z)
        alpha[tau, f] *= emission
        total += alpha[tau, f]
    return total


@njit(cache=True, inline="always")
def _forward(pool, world, paths, p, s, window, bridge, scratch, mark):
    """Forward filtering over the reachable support from ``scratch.old[0]``; False where the data
    rule out every path (only a state whose path they rule out: not a filter's)."""
    scratch.support[0, 0] = scratch.old[0]
    scratch.size[0] = 1
    scratch.alpha[0, 0] = 1.0
    possible = True
    for tau in range(1, window + 1):
        count = _spread(world, paths, s, tau, bridge, scratch, mark)
        scratch.size[tau] = count
        total = _emitted(pool, world, paths, p, s, tau, count, scratch, mark)
        if total <= 0.0:
            possible = False
            break
        for f in range(count):
            scratch.alpha[tau, f] /= total
    return possible


@njit(cache=True, inline="always")
def _backward(world, paths, s, window, bridge, right, uniforms, scratch):
    """Backward sampling into ``scratch.new``: the window's last step given the right end, then each
    predecessor, with ``uniforms`` (W + 2,) (column tau draws step tau). False where no last step
    reaches the right end."""
    support, alpha, probs, cells = scratch.support, scratch.alpha, scratch.probs, scratch.cells
    count = 0
    total = 0.0
    a = paths.actions[s + window + 1] if bridge else 0
    for e in range(scratch.size[window]):
        weight = alpha[window, e]
        if weight <= 0.0:
            continue
        if bridge:
            i = support[window, e]
            n = world.moves[a, i]
            for sc in range(2):
                j, pr = successor(i, n, world.p_move, sc)
                if j == right and pr > 0.0:
                    probs[count] = weight * pr
                    cells[count] = e
                    total += probs[count]
                    count += 1
        else:
            probs[count] = weight
            cells[count] = e
            total += weight
            count += 1
    drawn = count > 0
    if drawn:
        chosen = cells[_draw(probs, count, total, uniforms[window])]
        scratch.new[window] = support[window, chosen]
        for tau in range(window - 1, -1, -1):
            count = 0
            total = 0.0
            for e in range(scratch.size[tau]):
                for sc in range(2):
                    if scratch.succ[tau + 1, e, sc] == chosen and alpha[tau, e] > 0.0:
                        probs[count] = alpha[tau, e] * scratch.succ_pr[tau + 1, e, sc]
                        cells[count] = e
                        total += probs[count]
                        count += 1
            chosen = cells[_draw(probs, count, total, uniforms[tau])]
            scratch.new[tau] = support[tau, chosen]
    return drawn


@njit(cache=True, inline="always")
def _write_move(pool, world, paths, t, p, s, window, n_touched, scratch, mark):
    """An accepted move's writes: the new path's cells (m_- updated by its readings), then the old
    path's other cells (m_-), through one inlined copy of the write; then the window's steps into
    the path history."""
    footprint_cells, new = world.footprint_cells, scratch.new
    current, done, values = scratch.marks[1], scratch.marks[2], scratch.values
    n_reads = footprint_cells.shape[1]
    n_new = window * n_reads
    for i in range(n_new + n_touched):
        if i < n_new:
            c = footprint_cells[new[1 + i // n_reads], i % n_reads]
            if c < 0 or current[c] != 2 * mark + 1 or done[c] == mark:
                continue
        else:
            c = scratch.touched[i - n_new]
            if done[c] == mark:
                continue
        done[c] = mark
        source = scratch.cur if i < n_new else scratch.base
        for b in range(values.shape[0]):
            values[b] = source[c, b]
        write_cell(pool, t, p, c, values)
    block = paths.rows.shape[1]
    for tau in range(1, window + 1):
        step = s + tau
        r, source_row = row_for_write(paths, p, step // block)
        if source_row >= 0:
            for i in range(block):
                paths.rows[r, i] = paths.rows[source_row, i]
        paths.rows[r, step % block] = new[tau]


@loop_kernel
def _move_particles(locations, log_weights, pool, paths, world, t, first, starts, window, uniforms, counts, scratch):
    """:func:`rbpf_move`'s loop over the particles, in its ``scratch`` (:class:`MoveScratch`)."""
    n_particles = locations.shape[0]
    need_map = min(2 * window * world.footprint_cells.shape[1], pool.table.shape[1])
    need_path = window // paths.rows.shape[1] + 2
    old, new = scratch.old, scratch.new
    for p in range(first, n_particles):
        if log_weights[p] == -np.inf:
            continue
        if pool.free_top[0] < need_map or paths.free_top[0] < need_path:
            return p
        mark = p + 1
        s = starts[p]
        for tau in range(window + 1):
            old[tau] = _path_at(paths, p, s + tau)
        bridge = s + window < t
        right = _path_at(paths, p, s + window + 1) if bridge else -1
        n_touched = _map_without_window(pool, world, paths, p, s, window, scratch, mark)
        if bridge:
            _mark_bridge(world, paths, s, window, right, scratch, mark)
        if not _forward(pool, world, paths, p, s, window, bridge, scratch, mark):
            continue
        if not _backward(world, paths, s, window, bridge, right, uniforms[p], scratch):
            continue
        counts[0] += 1
        same = True
        for tau in range(1, window + 1):
            same = same and new[tau] == old[tau]
        if same:
            counts[1] += 1
            continue
        # Metropolis-Hastings: R(new) / R(old); cur keeps the new path's cells after the second
        ratio = 1.0
        for which in range(2):  # R(old), then R(new) / R(old): one inlined copy of the code to compile
            revisit = _revisit_ratio(old if which == 0 else new, s, window, world, paths, scratch, 2 * mark + which)
            ratio = revisit if which == 0 else revisit / ratio
        if not (ratio >= 1.0 or uniforms[p, window + 1] < ratio):
            continue
        counts[1] += 1
        _write_move(pool, world, paths, t, p, s, window, n_touched, scratch, mark)
        if not bridge:
            locations[p] = new[window]
    return n_particles
