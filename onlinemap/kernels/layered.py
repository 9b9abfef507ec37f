"""Kernels of layered EM (``onlinemap/layered_em.py``): one stretch of a run, every start cell at once.

Shapes: S steps in the stretch, N cells, D relative offsets (the box of cells the stretch's
actions can reach from its start), F footprint offsets, K labels, A actions. The state of the
stretch's HMM is ``(x, d)``: the stretch started at cell x and is now at offset d from it, the
cell ``x + cell_shift[d]``. A press of action a from cell c moves to ``neighbors[c, a]``, offset
``d + delta[a]``, with probability ``enter[tau, c]`` (0 where the press cannot move), emitting
``move[tau, target]``; otherwise it stays, emitting ``stay[tau, c]``; step 0 emits ``first[x]``.
Rows ``f[tau, x]`` and ``b[tau, x]`` are scaled to a maximum of 1 per start cell x, their logs
kept in ``log_f[tau, x]`` / ``log_b[tau, x]``.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, inline="always")
def _rescale(row, top):
    """Divide ``row`` by its maximum ``top`` in place (a row of zeros, an impossible start, stays)."""
    if top > 0.0:
        for d in range(row.shape[0]):
            row[d] /= top


@njit(cache=True)
def stretch_tables(labels, sensor, passable_label, readings, previous_shift, cells, neighbors, predecessor, actions,
                   ahead, p_move, blocking, floor, continuation, ratio, first, stay, move, enter):
    """The stretch's emissions and move probabilities under the map marginals ``labels`` (N, K).

    sensor (K, K) O floored; passable_label (K,); readings (S, F), -1 off the grid;
    previous_shift (A + 1, F): the offset that read, one step before, the cell offset f reads
    now after action a (row A: no move), -1 if none; cells (N, F) footprint cells, -1 off the
    grid; neighbors (N, A); predecessor (A, N) the cell a move by a comes from, -1 if none;
    actions (S - 1,); ahead (A,) the offset reading the cell an action enters, -1 if none;
    blocking: labels block. Writes first (N,) ``P(z_0 | x)``; stay and move (S, N) the predictive
    of step tau's readings at a cell reached by staying / by the step's action, under ``labels``
    updated by step tau - 1's readings of the same cells (a slip reads again what it read); with
    ``continuation``, a cell a move reads for the first time has its labels multiplied by
    ``psi(k) = sum_l r(l) ratio[l, k]``, r the label posterior of the cell the same offset read
    before the move (its neighbour behind it) and ratio (K, K) ``P(l, k) / (P(l) P(k))`` of
    adjacent labels (walls and corridors continue); enter (S, N) ``p_move P(target passable |
    labels, its latest reading)``, 0 where the press cannot move. Every factor is floored at
    ``floor``. O(S N F K^2).
    """
    n, n_read = cells.shape
    k = labels.shape[1]
    n_steps = readings.shape[0]
    n_actions = neighbors.shape[1]
    r = np.empty(k)
    psi = np.ones(k)
    for c in range(n):
        value = 1.0
        for f in range(n_read):
            cell = cells[c, f]
            z = readings[0, f]
            if (cell < 0) != (z < 0):
                value *= floor
            elif cell >= 0:
                p = 0.0
                for j in range(k):
                    p += labels[cell, j] * sensor[j, z]
                value *= max(p, floor)
        first[c] = value
    for tau in range(1, n_steps):
        a = actions[tau - 1]
        for row in range(2):
            shift = previous_shift[n_actions] if row == 0 else previous_shift[a]
            out = stay if row == 0 else move
            for c in range(n):
                value = 1.0
                for f in range(n_read):
                    cell = cells[c, f]
                    z = readings[tau, f]
                    if (cell < 0) != (z < 0):
                        value *= floor
                        continue
                    if cell < 0:
                        continue
                    g = shift[f]
                    zp = readings[tau - 1, g] if g >= 0 else -1
                    behind = -1
                    if continuation and row == 1 and g < 0 and predecessor[a, c] >= 0:
                        behind = cells[predecessor[a, c], f]
                    zb = readings[tau - 1, f]
                    if behind >= 0 and zb >= 0:
                        norm = 0.0
                        for j in range(k):
                            r[j] = labels[behind, j] * sensor[j, zb]
                            norm += r[j]
                        for j in range(k):
                            psi[j] = 0.0
                            for i in range(k):
                                psi[j] += r[i] * ratio[i, j]
                            psi[j] /= norm
                    else:
                        psi[:] = 1.0
                    num = 0.0
                    den = 0.0
                    for j in range(k):
                        w = labels[cell, j] * (sensor[j, zp] if zp >= 0 else 1.0) * psi[j]
                        den += w
                        num += w * sensor[j, z]
                    value *= max(num / den, floor)
                out[tau, c] = value
        for c in range(n):
            target = neighbors[c, a]
            if target == c:
                enter[tau, c] = 0.0
                continue
            if not blocking:
                enter[tau, c] = p_move
                continue
            zp = readings[tau - 1, ahead[a]] if ahead[a] >= 0 else -1
            num = 0.0
            den = 0.0
            for j in range(k):
                w = labels[target, j] * (sensor[j, zp] if zp >= 0 else 1.0)
                den += w
                num += w * passable_label[j]
            enter[tau, c] = p_move * num / den


@njit(cache=True)
def stretch_forward(neighbors, actions, cell_shift, delta, origin, first, stay, move, enter, f, log_f):
    """The forward pass: ``f[tau, x, d] exp(log_f[tau, x]) = P(z_0..tau, d_tau = d | x_m = x)``.
    f (S, N, D) and log_f (S, N) are written (f zeroed here). O(S N D)."""
    n_steps, n, n_off = f.shape
    f[:] = 0.0
    for x in range(n):
        f[0, x, origin] = first[x]
        log_f[0, x] = 0.0
    for tau in range(1, n_steps):
        a = actions[tau - 1]
        for x in range(n):
            for d in range(n_off):
                v = f[tau - 1, x, d]
                if v == 0.0:
                    continue
                c = x + cell_shift[d]
                target = neighbors[c, a]
                p = enter[tau, c]
                f[tau, x, d] += v * (1.0 - p) * stay[tau, c]
                if target != c and p > 0.0:
                    f[tau, x, d + delta[a]] += v * p * move[tau, target]
            top = 0.0
            for d in range(n_off):
                top = max(top, f[tau, x, d])
            _rescale(f[tau, x], top)
            log_f[tau, x] = log_f[tau - 1, x] + np.log(top) if top > 0.0 else -np.inf


@njit(cache=True)
def stretch_backward(neighbors, actions, cell_shift, delta, stay, move, enter, f, end, b, log_b):
    """The backward pass from ``end`` (N,), the message of the cell the stretch ends in (the rest of
    the run given that cell): ``b[tau, x, d] exp(log_b[tau, x]) = P(z_tau+1.., rest | d_tau = d,
    x)``, computed where ``f[tau, x, d] > 0`` (0 elsewhere). O(S N D)."""
    n_steps, n, n_off = f.shape
    b[:] = 0.0
    last = n_steps - 1
    for x in range(n):
        top = 0.0
        for d in range(n_off):
            if f[last, x, d] > 0.0:
                b[last, x, d] = end[x + cell_shift[d]]
                top = max(top, b[last, x, d])
        _rescale(b[last, x], top)
        log_b[last, x] = np.log(top) if top > 0.0 else -np.inf
    for tau in range(last, 0, -1):
        a = actions[tau - 1]
        for x in range(n):
            top = 0.0
            for d in range(n_off):
                if f[tau - 1, x, d] == 0.0:
                    continue
                c = x + cell_shift[d]
                target = neighbors[c, a]
                p = enter[tau, c]
                v = (1.0 - p) * stay[tau, c] * b[tau, x, d]
                if target != c and p > 0.0:
                    v += p * move[tau, target] * b[tau, x, d + delta[a]]
                b[tau - 1, x, d] = v
                top = max(top, v)
            _rescale(b[tau - 1, x], top)
            log_b[tau - 1, x] = log_b[tau, x] + np.log(top) if top > 0.0 else -np.inf


@njit(cache=True)
def collapse(f_last, cell_shift, weight, out):
    """``out[c] = sum_{x, d: x + cell_shift[d] = c} weight[x] f_last[x, d]``: where the stretch
    ends, from start weights (N,). out (N,) zeroed here. O(N D)."""
    out[:] = 0.0
    n, n_off = f_last.shape
    for x in range(n):
        if weight[x] == 0.0:
            continue
        for d in range(n_off):
            out[x + cell_shift[d]] += weight[x] * f_last[x, d]


@njit(cache=True)
def stretch_counts(neighbors, actions, cell_shift, delta, stay, move, enter, f, b, weight, prune, readings, cells,
                   counts, entered, bumped):
    """The M-step's statistics of the stretch, each start x with ``weight[x] > prune`` (its
    tempered pose posterior) and its offsets by their posterior given x: adds to counts (N, K)
    ``sum_{x, tau, d} weight[x] P(d_tau = d | x, data) [reading z of cell c at tau]``, and to
    entered / bumped (N,) the expected presses into each cell that moved / failed. O(S F n D)
    for n such starts."""
    n_steps, n, n_off = f.shape
    n_read = cells.shape[1]
    for x in range(n):
        w = weight[x]
        if w <= prune:
            continue
        for tau in range(n_steps):
            total = 0.0
            for d in range(n_off):
                total += f[tau, x, d] * b[tau, x, d]
            if total == 0.0:
                break
            for d in range(n_off):
                g = f[tau, x, d] * b[tau, x, d]
                if g == 0.0:
                    continue
                g *= w / total
                c = x + cell_shift[d]
                for j in range(n_read):
                    cell = cells[c, j]
                    z = readings[tau, j]
                    if cell >= 0 and z >= 0:
                        counts[cell, z] += g
            if tau == 0:
                continue
            a = actions[tau - 1]
            total = 0.0
            for d in range(n_off):
                v = f[tau - 1, x, d]
                if v == 0.0:
                    continue
                c = x + cell_shift[d]
                target = neighbors[c, a]
                p = enter[tau, c]
                total += v * (1.0 - p) * stay[tau, c] * b[tau, x, d]
                if target != c and p > 0.0:
                    total += v * p * move[tau, target] * b[tau, x, d + delta[a]]
            if total == 0.0:
                break
            for d in range(n_off):
                v = f[tau - 1, x, d]
                if v == 0.0:
                    continue
                c = x + cell_shift[d]
                target = neighbors[c, a]
                if target == c:
                    continue
                p = enter[tau, c]
                bumped[target] += w * v * (1.0 - p) * stay[tau, c] * b[tau, x, d] / total
                entered[target] += w * v * p * move[tau, target] * b[tau, x, d + delta[a]] / total
