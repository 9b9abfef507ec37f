"""numba kernels of the RBPF's resample-move step (``estimators/rbpf_move.py``; Gilks and Berzuini
2001): every particle's path as shared copy-on-write blocks of steps, and the Metropolis-Hastings
move that redraws a window of a particle's past.

Path history (the map pool's layout, ``kernels/rbpf.py``, for steps instead of cells):

- ``path_rows (R, B)``: the locations at B consecutive steps; ``path_row_block (R,)`` the block of
  steps a row holds (block b: steps ``b B .. b B + B - 1``); ``path_refcount (R,)``;
  ``path_free (R,)`` with ``path_free_top (1,)``: a stack of unused rows;
- ``path_table (P, C)``: the row holding block b of particle p's path, -1 for a block no step
  has reached yet (the same for every particle).

A step takes over the table rows of the slots resampling gave to a copy (``_take_over_slots``, as
the maps' table) and writes every slot's location; a write into a row other particles share copies
it first (``_row_for_write``). Particles descend from few ancestors, so their old blocks are shared.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from . import loop_kernel
from .rbpf import _row_for_write, _successor, _take_over_slots, _write_cell


@njit(cache=True)
def paths_record(path_rows, path_row_block, path_refcount, path_free, path_free_top, path_table, ancestors,
                 locations, t):
    """Write step t into the path history: slot p takes over ``ancestors[p]``'s table row (the
    slots of a step's commit; ``ancestors[p] = p`` keeps its own), then every slot's location
    ``locations (P,)`` goes to step t of its path, a fresh row where block ``t // B`` begins (or
    where the row is shared: copy-on-write of the first ``t % B`` entries). Needs
    ``path_free_top[0] >= P``. O(P_copied C + P B) at most (C the table's width)."""
    _take_over_slots(path_refcount, path_free, path_free_top, path_table, ancestors)
    block = path_rows.shape[1]
    b = t // block
    j = t % block
    for p in range(path_table.shape[0]):
        r = path_table[p, b]
        if r < 0:
            path_free_top[0] -= 1
            r = path_free[path_free_top[0]]
            path_row_block[r] = b
            path_refcount[r] = 1
            path_table[p, b] = r
        else:
            r, source = _row_for_write(path_row_block, path_refcount, path_free, path_free_top, path_table, p, b)
            if source >= 0:
                for i in range(j):
                    path_rows[r, i] = path_rows[source, i]
        path_rows[r, j] = locations[p]


@njit(cache=True)
def rbpf_move(locations, log_weights, pool, pool_stamps, row_block, refcount, free, free_top, table, cell_block,
              cell_slot, dynamic, powers, max_age, path_rows, path_row_block, path_refcount, path_free, path_free_top,
              path_table, t, first, starts, window, actions, readings, moves, predecessor, p_move, footprint_cells,
              likelihood, uniforms, counts):
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
    accepted). Map pool arguments as :func:`~onlinemap.kernels.rbpf.rbpf_commit` (``*blocks.writes()``)
    and the history's (module docstring); ``actions (T,)`` the action before each step,
    ``readings (T, F)``, ``moves (A, N)``, ``predecessor (A, N)`` (the cell a move enters j from,
    -1), ``footprint_cells (N, F)``, ``likelihood (Z, K)`` (row z: ``O[:, z]``). Needs, before a
    particle, ``min(2 W F, n_blocks)`` free map rows and ``W // B + 2`` free path rows.

    Cost per particle: O(W S (F K + 1) + W^2) for S the mean number of cells the window can take at
    a step (the reachable support: a few to tens), plus the writes of an accepted move (copy-on-write
    of at most 2 W F map blocks and 2 path blocks). Memory: O(W N) scratch."""
    n_cells = cell_block.shape[0]
    k = pool.shape[2]
    width = window + 1
    scratch_ints = np.zeros((5, n_cells), dtype=np.int64)  # loaded, current, done, reached, reach
    position = np.full(n_cells, -1, dtype=np.int64)
    return _move_particles(locations, log_weights, pool, pool_stamps, row_block, refcount, free, free_top, table,
                           cell_block, cell_slot, dynamic, powers, max_age, path_rows, path_row_block, path_refcount,
                           path_free, path_free_top, path_table, t, first, starts, window, actions, readings, moves,
                           predecessor, p_move, footprint_cells, likelihood, uniforms, counts, np.empty((n_cells, k)),
                           np.empty((n_cells, k)), scratch_ints, position, np.empty(n_cells, dtype=np.int64),
                           np.empty((width, n_cells), dtype=np.int64), np.empty(width, dtype=np.int64),
                           np.empty((width, n_cells)), np.empty((width, n_cells, 2), dtype=np.int64),
                           np.empty((width, n_cells, 2)), np.empty(width, dtype=np.int64),
                           np.empty(width, dtype=np.int64), np.empty(2 * n_cells),
                           np.empty(2 * n_cells, dtype=np.int64),
                           np.empty(window * footprint_cells.shape[1], dtype=np.int64), np.empty(k))


@njit(cache=True, inline="always")
def _path_at(path_rows, path_table, p, step):
    """Particle p's location at ``step``."""
    block = path_rows.shape[1]
    return path_rows[path_table[p, step // block], step % block]


@njit(cache=True, inline="always")
def _load(pool, table, cell_block, cell_slot, p, c, base, loaded, mark):
    """``base[c]`` <- particle p's marginal of cell c (a static world: no aging), once per
    particle (``loaded[c] == mark`` once done)."""
    if loaded[c] != mark:
        loaded[c] = mark
        r = table[p, cell_block[c]]
        for b in range(base.shape[1]):
            base[c, b] = pool[r, cell_slot[c], b]


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
def _revisit_ratio(path, s, window, footprint_cells, readings, likelihood, base, cur, current, mark):
    """``R(path)`` of :func:`rbpf_move`: the product, over the window's readings in order, of
    ``P(z | cell, m_- updated by the path's earlier readings of it) / P(z | cell, m_-)``.
    Leaves in ``cur[c]`` (``current[c] == mark``) each read cell's marginal given the path's
    readings."""
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


@loop_kernel
def _move_particles(locations, log_weights, pool, pool_stamps, row_block, refcount, free, free_top, table, cell_block,
                    cell_slot, dynamic, powers, max_age, path_rows, path_row_block, path_refcount, path_free,
                    path_free_top, path_table, t, first, starts, window, actions, readings, moves, predecessor, p_move,
                    footprint_cells, likelihood, uniforms, counts, base, cur, marks, position, back, support, size,
                    alpha, succ, succ_pr, old, new, probs, cells, touched, values):
    """:func:`rbpf_move`'s loop over the particles, in its scratch: ``base``, ``cur`` (N, K);
    ``marks`` (5, N) zeros (which particle loaded, read, wrote, reached a cell; the step a cell
    can last be at and still reach the window's right end); ``position`` (N,) -1; the rest
    written before read."""
    n_particles = locations.shape[0]
    n_reads = footprint_cells.shape[1]
    block = path_rows.shape[1]
    need_map = min(2 * window * n_reads, table.shape[1])
    need_path = window // block + 2
    loaded, current, done, reached, reach = marks[0], marks[1], marks[2], marks[3], marks[4]
    for p in range(first, n_particles):
        if log_weights[p] == -np.inf:
            continue
        if free_top[0] < need_map or path_free_top[0] < need_path:
            return p
        mark = p + 1
        s = starts[p]
        for tau in range(window + 1):
            old[tau] = _path_at(path_rows, path_table, p, s + tau)
        bridge = s + window < t
        right = _path_at(path_rows, path_table, p, s + window + 1) if bridge else -1
        # m_-: the particle's map without the window's readings (divided out, then normalised)
        n_touched = 0
        for tau in range(1, window + 1):
            for f in range(n_reads):
                c = footprint_cells[old[tau], f]
                z = readings[s + tau, f]
                if c < 0 or z < 0:
                    continue
                if loaded[c] != mark:
                    _load(pool, table, cell_block, cell_slot, p, c, base, loaded, mark)
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
        # the bridge: reach[c] >= tau where a robot at c at window step tau may still get to the
        # right end (a superset: staying is assumed possible)
        if bridge:
            reached[right] = mark
            reach[right] = window + 1
            back[0] = right
            n_back = 1
            for tau in range(window, 0, -1):
                a = actions[s + tau + 1]
                for e in range(n_back):
                    i = predecessor[a, back[e]]
                    if i >= 0 and reached[i] != mark:
                        reached[i] = mark
                        reach[i] = tau
                        back[n_back] = i
                        n_back += 1
        # forward filtering over the reachable support
        support[0, 0] = old[0]
        size[0] = 1
        alpha[0, 0] = 1.0
        possible = True
        for tau in range(1, window + 1):
            a = actions[s + tau]
            count = 0
            for e in range(size[tau - 1]):
                i = support[tau - 1, e]
                weight = alpha[tau - 1, e]
                n = moves[a, i]
                for sc in range(2):
                    j, pr = _successor(i, n, p_move, sc)
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
                    succ[tau, e, sc] = f
                    succ_pr[tau, e, sc] = pr
            size[tau] = count
            total = 0.0
            for f in range(count):
                j = support[tau, f]
                position[j] = -1
                emission = 1.0
                for g in range(n_reads):
                    c = footprint_cells[j, g]
                    z = readings[s + tau, g]
                    if c < 0 or z < 0:
                        if c >= 0 or z >= 0:
                            emission = 0.0
                    else:
                        _load(pool, table, cell_block, cell_slot, p, c, base, loaded, mark)
                        emission *= _dot(base, c, likelihood, z)
                alpha[tau, f] *= emission
                total += alpha[tau, f]
            if total <= 0.0:
                possible = False
                break
            for f in range(count):
                alpha[tau, f] /= total
        if not possible:  # only a state whose path the data rule out (not a filter's)
            continue
        # backward sampling: the window's last step given the right end, then each predecessor
        count = 0
        total = 0.0
        a = actions[s + window + 1] if bridge else 0
        for e in range(size[window]):
            weight = alpha[window, e]
            if weight <= 0.0:
                continue
            if bridge:
                i = support[window, e]
                n = moves[a, i]
                for sc in range(2):
                    j, pr = _successor(i, n, p_move, sc)
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
        if count == 0:
            continue
        chosen = cells[_draw(probs, count, total, uniforms[p, window])]
        new[window] = support[window, chosen]
        for tau in range(window - 1, -1, -1):
            count = 0
            total = 0.0
            for e in range(size[tau]):
                for sc in range(2):
                    if succ[tau + 1, e, sc] == chosen and alpha[tau, e] > 0.0:
                        probs[count] = alpha[tau, e] * succ_pr[tau + 1, e, sc]
                        cells[count] = e
                        total += probs[count]
                        count += 1
            chosen = cells[_draw(probs, count, total, uniforms[p, tau])]
            new[tau] = support[tau, chosen]
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
            revisit = _revisit_ratio(old if which == 0 else new, s, window, footprint_cells, readings, likelihood,
                                     base, cur, current, 2 * mark + which)
            ratio = revisit if which == 0 else revisit / ratio
        if not (ratio >= 1.0 or uniforms[p, window + 1] < ratio):
            continue
        counts[1] += 1
        # the new path's cells (m_- updated by its readings), then the old path's other cells (m_-),
        # through one inlined copy of the write
        n_new = window * n_reads
        for i in range(n_new + n_touched):
            if i < n_new:
                c = footprint_cells[new[1 + i // n_reads], i % n_reads]
                if c < 0 or current[c] != 2 * mark + 1 or done[c] == mark:
                    continue
            else:
                c = touched[i - n_new]
                if done[c] == mark:
                    continue
            done[c] = mark
            source = cur if i < n_new else base
            for b in range(values.shape[0]):
                values[b] = source[c, b]
            _write_cell(pool, pool_stamps, row_block, refcount, free, free_top, table, cell_block, cell_slot, dynamic,
                        powers, max_age, t, p, c, values)
        for tau in range(1, window + 1):
            step = s + tau
            r, source = _row_for_write(path_row_block, path_refcount, path_free, path_free_top, path_table, p,
                                       step // block)
            if source >= 0:
                for i in range(block):
                    path_rows[r, i] = path_rows[source, i]
            path_rows[r, step % block] = new[tau]
        if not bridge:
            locations[p] = new[window]
    return n_particles

