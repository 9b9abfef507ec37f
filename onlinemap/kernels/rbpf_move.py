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
from .rbpf_enumerate import gated_successor


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
    ``touched`` ((W + 1) (F + 1),) the cells the old window touched (read, or pressed into with
    blocking labels); ``fresh`` (the same) those the new one touched, in order; ``values`` (K,)."""

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
    fresh: np.ndarray
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


class Draws(NamedTuple):
    """A move's random draws: ``starts (P,)`` each window's left end s, ``uniforms (P, W + 2)``."""

    starts: np.ndarray
    uniforms: np.ndarray


class MapEvidence(NamedTuple):
    """The map's evidence beyond the readings: ``rebuild`` (m_- rebuilt, not divided), ``prior (N, K)``
    ``prior_i(k) w(k)`` (w the label-prior tilt), ``gate (2, K)`` a press's factor on its target's
    label k (``GridModel.press_likelihood``): row 0 moved in, ``[k passable]``, row 1 stayed,
    ``1 - p_move [k passable]``."""

    prior: np.ndarray
    gate: np.ndarray
    rebuild: bool


@njit(cache=True)
def rbpf_move(locations, log_weights, pool, paths, world, evidence, t, first, starts, window, uniforms, counts):
    """One Metropolis-Hastings move of a window of every live particle's past (a static world), in
    place; particles ``first..P - 1``. Returns the particle it stopped before for want of free rows
    (P when done): the caller grows the pools and calls again from there.

    Particle p's window is ``x_{s+1..s+W}``, ``s = starts[p]`` (``s + W <= t``, W = ``window``),
    redrawn given ``x_s``, ``x_{s+W+1}`` (when ``s + W < t``) and every observation, the rest of
    the path kept; the math is in ``estimators/rbpf_move.py``. In short: the target is the
    window's law given the rest, ``prod T0 prod_c E_{m_-}[prod_{window events at c} f_e]`` (events:
    readings, and with blocking labels presses, ``evidence.gate``); ``m_-``, the particle's map
    without the window's events, is the stored marginal with the readings divided out, or
    (``evidence.rebuild``) rebuilt from the path history (:func:`_map_rebuilt`); the proposal is
    forward filtering, backward sampling with every event at its mean under ``m_-``; the
    acceptance ratio ``R(new) / R(old)`` (:func:`_revisit_ratio`) corrects for cells the window
    touches twice. An accepted path's cells get their marginals given it, its steps are written
    into the history, and if the window ends at t the location moves. Weights are unchanged. A
    proposal equal to the old window changes nothing.

    Random numbers: ``uniforms (P, W + 2)``: column tau draws ``x_{s+tau}`` backwards (0 is never
    used: ``x_s`` is fixed), column W + 1 the acceptance. ``counts (2,)`` += (windows proposed,
    accepted). ``pool`` the maps (:class:`~onlinemap.kernels.rbpf.Pool`), ``paths`` the
    history (:class:`Paths`), ``world`` the model's tables (:class:`~onlinemap.kernels.rbpf.World`:
    moves, predecessor, footprint_cells, likelihood, blocking), ``evidence``
    (:class:`MapEvidence`). Needs, before a particle, ``min(2 (W + b) (F + b), n_blocks)`` free map
    rows (b = 1 with blocking labels, else 0) and ``W // B + 2`` free path rows.

    Cost per particle: O(W S (F K + 1) + W^2) for S the mean number of cells the window can take at
    a step (the reachable support: a few to tens), plus O(t (F + 1) + W F K) for a rebuild, plus the
    writes of an accepted move (copy-on-write of at most 2 (W + 1) (F + 1) map blocks and 2 path
    blocks). Memory: O(W N) scratch."""
    n_cells = pool.cell_block.shape[0]
    k = pool.rows.shape[2]
    width = window + 1
    events = width * (world.footprint_cells.shape[1] + 1)
    scratch = MoveScratch(np.empty((n_cells, k)), np.empty((n_cells, k)), np.zeros((5, n_cells), dtype=np.int64),
                          np.full(n_cells, -1, dtype=np.int64), np.empty(n_cells, dtype=np.int64),
                          np.empty((width, n_cells), dtype=np.int64), np.empty(width, dtype=np.int64),
                          np.empty((width, n_cells)), np.empty((width, n_cells, 2), dtype=np.int64),
                          np.empty((width, n_cells, 2)), np.empty(width, dtype=np.int64),
                          np.empty(width, dtype=np.int64), np.empty(2 * n_cells), np.empty(2 * n_cells, dtype=np.int64),
                          np.empty(events, dtype=np.int64), np.empty(events, dtype=np.int64), np.empty(k))
    return _move_particles(locations, log_weights, pool, paths, world, evidence, t, first, Draws(starts, uniforms),
                           window, counts, scratch)


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
def _dot(base, c, factor):
    """``sum_k base[c, k] factor[k]``: the mean of an event's factor (K,) under cell c's marginal."""
    acc = 0.0
    for b in range(base.shape[1]):
        acc += base[c, b] * factor[b]
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
def _pressed(world, action, here, there):
    """(target, moved): the cell a press of ``action`` from ``here`` is gated by (-1: no blocking
    labels or no neighbour) and whether the robot, now ``there``, went in."""
    n = world.moves[action, here]
    if not world.has_blocking or n == here:
        return -1, False
    return n, there == n


@njit(cache=True, inline="always")
def _event(scratch, c, factor, mark, n_fresh):
    """One event of a path at cell c with ``factor`` (K,): returns (``E_cur[factor] / E_{m_-}[factor]``,
    1 at the cell's first event, which lists c in ``scratch.fresh``, and that list's count)."""
    base, cur, current = scratch.base, scratch.cur, scratch.marks[1]
    ratio = 1.0
    if current[c] == mark:
        lam = _dot(cur, c, factor)
        ratio = lam / _dot(base, c, factor)
        for b in range(cur.shape[1]):
            cur[c, b] = cur[c, b] * factor[b] / lam
    else:
        current[c] = mark
        scratch.fresh[n_fresh] = c
        n_fresh += 1
        lam = _dot(base, c, factor)
        for b in range(cur.shape[1]):
            cur[c, b] = base[c, b] * factor[b] / lam
    return ratio, n_fresh


@njit(cache=True, inline="always")
def _revisit_ratio(path, s, window, bridge, right, world, evidence, paths, scratch, mark):
    """``(R(path), n_fresh)`` of :func:`rbpf_move`: the product, over the window's events in time
    order (a step's press, then its readings; the bridge's press last), of ``E[f_e | m_- updated
    by the path's earlier events at the cell] / E_{m_-}[f_e]``. Leaves in ``scratch.cur[c]``
    (``current[c] == mark``) each touched cell's marginal given the path's events, and lists the
    cells in ``scratch.fresh[:n_fresh]`` in first-touch order."""
    footprint_cells, readings, likelihood = world.footprint_cells, paths.readings, world.likelihood
    ratio = 1.0
    n_fresh = 0
    last = window + 1 if bridge else window
    for tau in range(1, last + 1):
        there = right if tau > window else path[tau]
        n, moved = _pressed(world, paths.actions[s + tau], path[tau - 1], there)
        if n >= 0:  # its m_- was loaded by the forward filter or the rebuild
            r, n_fresh = _event(scratch, n, evidence.gate[0 if moved else 1], mark, n_fresh)
            ratio *= r
        if tau > window:
            continue
        for f in range(footprint_cells.shape[1]):
            c = footprint_cells[path[tau], f]
            z = readings[s + tau, f]
            if c < 0 or z < 0:
                continue
            r, n_fresh = _event(scratch, c, likelihood[z], mark, n_fresh)
            ratio *= r
    return ratio, n_fresh


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
    _normalise(base, touched, n_touched)
    return n_touched


@njit(cache=True, inline="always")
def _normalise(base, cells, count):
    """``base[c]`` normalised for the cells ``cells[:count]``."""
    for i in range(count):
        c = cells[i]
        total = 0.0
        for b in range(base.shape[1]):
            total += base[c, b]
        for b in range(base.shape[1]):
            base[c, b] /= total


@njit(cache=True, inline="always")
def _mark_touched(c, scratch, mark, n_touched, prior):
    """List c (once) in ``scratch.touched`` with ``base[c]`` <- ``prior[c]``; returns the count."""
    loaded = scratch.marks[0]
    if loaded[c] != mark:
        loaded[c] = mark
        scratch.touched[n_touched] = c
        n_touched += 1
        for b in range(prior.shape[1]):
            scratch.base[c, b] = prior[c, b]
    return n_touched


@njit(cache=True, inline="always")
def _times(base, c, factor):
    """``base[c]`` <- ``normalise(base[c] * factor)`` (at every event: a long history would underflow;
    a sum of 0, a history the particle cannot have, is left as is)."""
    total = 0.0
    for b in range(base.shape[1]):
        base[c, b] *= factor[b]
        total += base[c, b]
    if total > 0.0:
        for b in range(base.shape[1]):
            base[c, b] /= total


@njit(cache=True, inline="always")
def _map_rebuilt(world, evidence, paths, p, s, window, t, bridge, right, scratch, mark):
    """``scratch.base`` <- m_- rebuilt at the cells the old window (``scratch.old``) touches (read, or
    pressed into at steps ``s+1..s+W`` and the bridge's ``s+W+1``; listed in ``scratch.touched``):
    ``evidence.prior`` times every factor of the path outside the window (readings of steps ``0..s``,
    ``s+W+1..t``; presses of ``1..s``, ``s+W+2..t``). Needs the history from step 0 (no recovery).
    Returns the count. O(t (F + 1) + W F K)."""
    footprint_cells, readings, likelihood = world.footprint_cells, paths.readings, world.likelihood
    old, base, loaded = scratch.old, scratch.base, scratch.marks[0]
    n_touched = 0
    last = window + 1 if bridge else window
    for tau in range(1, last + 1):
        there = right if tau > window else old[tau]
        n, moved = _pressed(world, paths.actions[s + tau], old[tau - 1], there)
        if n >= 0:
            n_touched = _mark_touched(n, scratch, mark, n_touched, evidence.prior)
        if tau <= window:
            for f in range(footprint_cells.shape[1]):
                c = footprint_cells[old[tau], f]
                if c >= 0 and readings[s + tau, f] >= 0:
                    n_touched = _mark_touched(c, scratch, mark, n_touched, evidence.prior)
    _normalise(base, scratch.touched, n_touched)
    previous = _path_at(paths, p, 0)
    for u in range(t + 1):
        here = _path_at(paths, p, u)
        if u >= 1 and (u <= s or u > s + last):
            n, moved = _pressed(world, paths.actions[u], previous, here)
            if n >= 0 and loaded[n] == mark:
                _times(base, n, evidence.gate[0 if moved else 1])
        if u <= s or u > s + window:
            for f in range(footprint_cells.shape[1]):
                c = footprint_cells[here, f]
                z = readings[u, f]
                if c >= 0 and z >= 0 and loaded[c] == mark:
                    _times(base, c, likelihood[z])
        previous = here
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
def _step_motion(pool, world, p, i, n, sc, scratch, mark):
    """(cell, probability) of successor sc of a robot at i whose action points at n, under m_-:
    a press into n (blocking labels) moves with ``p_move P_{m_-}(n passable)``."""
    gated = world.has_blocking and n != i
    passable = 0.0 if gated else 1.0
    if gated:
        _load(pool, p, n, scratch.base, scratch.marks[0], mark)
        for b in range(scratch.base.shape[1]):
            if not world.blocking[b]:
                passable += scratch.base[n, b]
    return gated_successor(i, n, world.p_move, sc, gated, passable)


@njit(cache=True, inline="always")
def _spread(pool, world, paths, p, s, tau, bridge, scratch, mark):
    """The forward filter's step tau before its emissions: the successors of step tau - 1's support
    (``scratch.support``, ``alpha``) under the window's action (:func:`_step_motion`), those that
    can still reach the right end with a bridge, with their summed weights; ``succ``, ``succ_pr``
    each predecessor's successors. Returns their number."""
    support, alpha, position = scratch.support, scratch.alpha, scratch.position
    reached, reach = scratch.marks[3], scratch.marks[4]
    a = paths.actions[s + tau]
    count = 0
    for e in range(scratch.size[tau - 1]):
        i = support[tau - 1, e]
        weight = alpha[tau - 1, e]
        n = world.moves[a, i]
        for sc in range(2):
            j, pr = _step_motion(pool, world, p, i, n, sc, scratch, mark)
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
                emission *= _dot(base, c, likelihood[z])
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
        count = _spread(pool, world, paths, p, s, tau, bridge, scratch, mark)
        scratch.size[tau] = count
        total = _emitted(pool, world, paths, p, s, tau, count, scratch, mark)
        if total <= 0.0:
            possible = False
            break
        for f in range(count):
            scratch.alpha[tau, f] /= total
    return possible


@njit(cache=True, inline="always")
def _backward(pool, world, paths, p, s, window, bridge, right, uniforms, scratch, mark):
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
                j, pr = _step_motion(pool, world, p, i, n, sc, scratch, mark)
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
def _write_move(pool, paths, t, p, s, window, n_fresh, n_touched, scratch, mark):
    """An accepted move's writes: the cells the new path touched (``scratch.fresh``: m_- updated by
    its events), then the old path's other cells (m_-), through one inlined copy of the write; then
    the window's steps into the path history."""
    done, values = scratch.marks[2], scratch.values
    for i in range(n_fresh + n_touched):
        c = scratch.fresh[i] if i < n_fresh else scratch.touched[i - n_fresh]
        if done[c] == mark:
            continue
        done[c] = mark
        source = scratch.cur if i < n_fresh else scratch.base
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
        paths.rows[r, step % block] = scratch.new[tau]


@loop_kernel
def _move_particles(locations, log_weights, pool, paths, world, evidence, t, first, draws, window, counts, scratch):
    """:func:`rbpf_move`'s loop over the particles, in its ``scratch`` (:class:`MoveScratch`)."""
    n_particles = locations.shape[0]
    gated = int(world.has_blocking)
    need_map = min(2 * (window + gated) * (world.footprint_cells.shape[1] + gated), pool.table.shape[1])
    need_path = window // paths.rows.shape[1] + 2
    old, new = scratch.old, scratch.new
    for p in range(first, n_particles):
        if log_weights[p] == -np.inf:
            continue
        if pool.free_top[0] < need_map or paths.free_top[0] < need_path:
            return p
        mark = p + 1
        s = draws.starts[p]
        for tau in range(window + 1):
            old[tau] = _path_at(paths, p, s + tau)
        bridge = s + window < t
        right = _path_at(paths, p, s + window + 1) if bridge else -1
        if evidence.rebuild:
            n_touched = _map_rebuilt(world, evidence, paths, p, s, window, t, bridge, right, scratch, mark)
        else:
            n_touched = _map_without_window(pool, world, paths, p, s, window, scratch, mark)
        if bridge:
            _mark_bridge(world, paths, s, window, right, scratch, mark)
        if not _forward(pool, world, paths, p, s, window, bridge, scratch, mark):
            continue
        if not _backward(pool, world, paths, p, s, window, bridge, right, draws.uniforms[p], scratch, mark):
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
        n_fresh = 0
        for which in range(2):  # R(old), then R(new) / R(old): one inlined copy of the code to compile
            revisit, n_fresh = _revisit_ratio(old if which == 0 else new, s, window, bridge, right, world, evidence,
                                              paths, scratch, 2 * mark + which)
            ratio = revisit if which == 0 else revisit / ratio
        if not (ratio >= 1.0 or draws.uniforms[p, window + 1] < ratio):
            continue
        counts[1] += 1
        _write_move(pool, paths, t, p, s, window, n_fresh, n_touched, scratch, mark)
        if not bridge:
            locations[p] = new[window]
    return n_particles
