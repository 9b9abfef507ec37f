"""Kernels of layered EM (``onlinemap/layered_em.py``): one stretch of a run, every start cell at once.

Shapes: S steps in the stretch, N cells, D relative offsets (the box of cells the stretch's
actions can reach from its start), F footprint offsets, K labels, A actions. The state of the
stretch's HMM is ``(x, d)``: the stretch started at cell x and is now at offset d from it, the
cell ``x + cell_shift[d]``. A press of action a from cell c moves to ``neighbors[c, a]``, offset
``d + delta[a]``, with probability ``enter[tau, c]`` (0 where the press cannot move), emitting
``move[tau, target]``; otherwise it stays, emitting ``stay[tau, c]``; step 0 emits ``first[x]``.
Rows ``f[tau, x]`` and ``b[tau, x]`` are scaled to a maximum of 1 per start cell x, their logs
kept in ``log_f[tau, x]`` / ``log_b[tau, x]``.

Bundles: :class:`Grid` (the model's tables, built once per fit), :class:`Stretch` (one
stretch's data and offsets, built once per stretch), :class:`Emissions` (a stretch's tables
under one map) and :class:`Counts` (the M-step's statistics). numba types a bundle argument in
Python on every call from Python (measured: a forward pass of a stretch on a 2 x 3 grid took
6.2 us with bundles, 2.5 us with their fields), and a fit makes thousands of such calls; so the kernels take
their bundles as their fields, last (``*fields``: ``kernel(..., *grid, *stretch, *emissions)``,
each bundle's fields in its NamedTuple's order, the bundles in the order the kernel's docstring
names), and rebuild them inside (:func:`_bundles`), as the RBPF's do
(:mod:`onlinemap.kernels.rbpf`). The kernels that allocate nothing are loop kernels
(:data:`~onlinemap.kernels.loop_kernel`, no reference counting), so their bundles reach the
inlined helpers at no cost; :func:`stretch_tables` allocates its two (K,) scratch rows and
passes them with its bundles to its loop kernel (a plain kernel counts the references of a
bundle it rebuilt at every use in its loop: 1.2-1.6x slower on a 32 x 32 building, measured).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from . import loop_kernel


class Grid(NamedTuple):
    """The model's tables the stretch kernels read, built once per fit."""

    sensor: np.ndarray  # (K, K) O floored at ``floor``
    passable_label: np.ndarray  # (K,) 1.0 for labels a robot can enter
    cells: np.ndarray  # (N, F) footprint cells, -1 off the grid
    neighbors: np.ndarray  # (N, A) the cell a press of a moves to
    predecessor: np.ndarray  # (A, N) the cell a move by a comes from, -1 if none
    shifts: np.ndarray  # (A + 1, F) the offset that read, one step before, the cell offset f reads now after
    #                     action a (row A: no move), -1 if none
    ahead: np.ndarray  # (A,) the offset reading the cell an action enters, -1 if none
    p_move: float
    blocking: bool  # some labels block
    floor: float  # the least probability a reading or a press counts with


class Stretch(NamedTuple):
    """One stretch's data and the offsets its actions can reach from its start (a row-major box of D cells)."""

    readings: np.ndarray  # (S, F) -1 off the grid
    actions: np.ndarray  # (S - 1,)
    cell_shift: np.ndarray  # (D,) offset d is the cell x + cell_shift[d] for the start x
    delta: np.ndarray  # (A,) an action moves offset d to d + delta[a]
    origin: int  # the offset of the start


class Emissions(NamedTuple):
    """A stretch's emissions and move probabilities under one map (:func:`stretch_tables`)."""

    first: np.ndarray  # (N,) P(z_0 | x)
    stay: np.ndarray  # (S, N) step tau's readings at a cell reached by staying
    move: np.ndarray  # (S, N) ... by the step's action
    enter: np.ndarray  # (S, N) the probability a press moves, 0 where it cannot


class Counts(NamedTuple):
    """The M-step's statistics of a stretch (:func:`stretch_counts` adds to them)."""

    counts: np.ndarray  # (N, K) expected readings z of each cell
    entered: np.ndarray  # (N,) expected presses into each cell that moved
    bumped: np.ndarray  # (N,) ... that failed


#: where each bundle's fields end in a kernel's ``*fields`` (grid, stretch, emissions, counts)
_GRID_END = len(Grid._fields)
_STRETCH_END = _GRID_END + len(Stretch._fields)
_EMISSIONS_END = _STRETCH_END + len(Emissions._fields)


@njit(cache=True, inline="always")
def _bundles(fields):
    """``(grid, stretch, emissions)`` rebuilt from a kernel's ``*fields`` (module docstring)."""
    return (Grid(*fields[:_GRID_END]), Stretch(*fields[_GRID_END:_STRETCH_END]),
            Emissions(*fields[_STRETCH_END:_EMISSIONS_END]))


@njit(cache=True, inline="always")
def _rescale(row, top):
    """Divide ``row`` by its maximum ``top`` in place (a row of zeros, an impossible start, stays)."""
    if top > 0.0:
        for d in range(row.shape[0]):
            row[d] /= top


@njit(cache=True)
def stretch_tables(labels, ratio, continuation, *fields):
    """The stretch's emissions and move probabilities under the map marginals ``labels`` (N, K),
    written into the :class:`Emissions` of ``*fields`` (the fields of the :class:`Grid`, the
    :class:`Stretch` and the :class:`Emissions`).

    first (N,) ``P(z_0 | x)``; stay and move (S, N) the predictive of step tau's readings at a
    cell reached by staying / by the step's action, under ``labels`` updated by step tau - 1's
    readings of the same cells (a slip reads again what it read); with ``continuation``, a cell a
    move reads for the first time has its labels multiplied by ``psi(k) = sum_l r(l) ratio[l,
    k]``, r the label posterior of the cell the same offset read before the move (its neighbour
    behind it) and ratio (K, K) ``P(l, k) / (P(l) P(k))`` of adjacent labels (walls and corridors
    continue); enter (S, N) ``p_move P(target passable | labels, its latest reading)``, 0 where
    the press cannot move. Every factor is floored at ``grid.floor``. O(S N F K^2).
    """
    grid, stretch, out = _bundles(fields)
    k = labels.shape[1]
    _tables_rows(grid, stretch, labels, ratio, continuation, out, np.empty(k), np.ones(k))


@loop_kernel
def _tables_rows(grid, stretch, labels, ratio, continuation, out, r, psi):
    """:func:`stretch_tables`'s loop over the steps, r and psi (K,) scratch: a loop kernel, so
    that the bundles it rebuilt reach the inlined helpers uncounted (module docstring)."""
    readings, actions = stretch.readings, stretch.actions
    _first_emissions(grid, labels, readings[0], out.first)
    for tau in range(1, readings.shape[0]):
        a = actions[tau - 1]
        before, now = readings[tau - 1], readings[tau]
        _emission_rows(grid, labels, ratio, before, now, a, continuation, out.stay[tau], out.move[tau], r, psi)
        _enter_row(grid, labels, before, a, out.enter[tau])


@njit(cache=True, inline="always")
def _first_emissions(grid, labels, now, first):
    """``first[c] = prod_f max(P(z_0f | cell c's offset f), floor)`` under ``labels``, a
    reading off the grid where the cell is on it (or the reverse) counting as ``floor``."""
    cells, sensor, floor = grid.cells, grid.sensor, grid.floor
    for c in range(cells.shape[0]):
        value = 1.0
        for f in range(cells.shape[1]):
            cell = cells[c, f]
            z = now[f]
            if (cell < 0) != (z < 0):
                value *= floor
            elif cell >= 0:
                p = 0.0
                for j in range(labels.shape[1]):
                    p += labels[cell, j] * sensor[j, z]
                value *= max(p, floor)
        first[c] = value


@njit(cache=True, inline="always")
def _emission_rows(grid, labels, ratio, before, now, a, continuation, stay, move, r, psi):
    """``stay[c]`` and ``move[c]``: c's footprint readings ``now`` (F,) predicted after a slip /
    a move by action a, each cell under its labels updated by the reading ``before`` (F,) of
    the offset that read it one step before (``grid.shifts``); with ``continuation``, a cell a
    move reads first takes the continuation factor of the cell behind it (:func:`_continuation`).
    r, psi (K,) scratch. O(N F K^2)."""
    cells, sensor, floor, predecessor = grid.cells, grid.sensor, grid.floor, grid.predecessor
    for row in range(2):
        shift = grid.shifts[grid.neighbors.shape[1]] if row == 0 else grid.shifts[a]
        out = stay if row == 0 else move
        for c in range(cells.shape[0]):
            value = 1.0
            for f in range(cells.shape[1]):
                cell = cells[c, f]
                z = now[f]
                if (cell < 0) != (z < 0):
                    value *= floor
                    continue
                if cell < 0:
                    continue
                g = shift[f]
                zp = before[g] if g >= 0 else -1
                behind = -1
                if continuation and row == 1 and g < 0 and predecessor[a, c] >= 0:
                    behind = cells[predecessor[a, c], f]
                zb = before[f]
                if behind >= 0 and zb >= 0:
                    _continuation(labels, sensor, ratio, behind, zb, r, psi)
                else:
                    psi[:] = 1.0
                value *= max(_predictive(labels, sensor, psi, cell, zp, z), floor)
            out[c] = value


@njit(cache=True, inline="always")
def _continuation(labels, sensor, ratio, behind, zb, r, psi):
    """``psi[k] = sum_l r(l) ratio[l, k]``, r (written, (K,)) the labels of cell ``behind``
    after its reading ``zb``, normalised. O(K^2)."""
    k = labels.shape[1]
    norm = 0.0
    for j in range(k):
        r[j] = labels[behind, j] * sensor[j, zb]
        norm += r[j]
    for j in range(k):
        psi[j] = 0.0
        for i in range(k):
            psi[j] += r[i] * ratio[i, j]
        psi[j] /= norm


@njit(cache=True, inline="always")
def _predictive(labels, sensor, psi, cell, zp, z):
    """``P(z | cell's labels times psi, updated by its earlier reading zp (-1: none))``. O(K)."""
    num = 0.0
    den = 0.0
    for j in range(labels.shape[1]):
        w = labels[cell, j] * (sensor[j, zp] if zp >= 0 else 1.0) * psi[j]
        den += w
        num += w * sensor[j, z]
    return num / den


@njit(cache=True, inline="always")
def _enter_row(grid, labels, before, a, enter):
    """``enter[c]``: the probability a press of a from c moves, ``p_move P(target passable |
    labels, the reading before of the offset ahead)``; 0 where the press cannot move."""
    neighbors, sensor, passable_label, p_move = grid.neighbors, grid.sensor, grid.passable_label, grid.p_move
    ahead = grid.ahead[a]
    for c in range(neighbors.shape[0]):
        target = neighbors[c, a]
        if target == c:
            enter[c] = 0.0
            continue
        if not grid.blocking:
            enter[c] = p_move
            continue
        zp = before[ahead] if ahead >= 0 else -1
        num = 0.0
        den = 0.0
        for j in range(labels.shape[1]):
            w = labels[target, j] * (sensor[j, zp] if zp >= 0 else 1.0)
            den += w
            num += w * passable_label[j]
        enter[c] = p_move * num / den


@loop_kernel
def stretch_forward(f, log_f, *fields):
    """The forward pass: ``f[tau, x, d] exp(log_f[tau, x]) = P(z_0..tau, d_tau = d | x_m = x)``.
    f (S, N, D) and log_f (S, N) are written (f zeroed here). ``*fields``: the fields of the
    :class:`Grid`, the :class:`Stretch` and the :class:`Emissions`. O(S N D)."""
    grid, stretch, emissions = _bundles(fields)
    neighbors, actions, cell_shift, delta = grid.neighbors, stretch.actions, stretch.cell_shift, stretch.delta
    first, stay, move, enter = emissions
    n_steps, n, n_off = f.shape
    f[:] = 0.0
    for x in range(n):
        f[0, x, stretch.origin] = first[x]
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


@loop_kernel
def stretch_backward(f, end, b, log_b, *fields):
    """The backward pass from ``end`` (N,), the message of the cell the stretch ends in (the rest of
    the run given that cell): ``b[tau, x, d] exp(log_b[tau, x]) = P(z_tau+1.., rest | d_tau = d,
    x)``, computed where ``f[tau, x, d] > 0`` (0 elsewhere). ``*fields``: as
    :func:`stretch_forward`'s. O(S N D)."""
    grid, stretch, emissions = _bundles(fields)
    neighbors, actions, cell_shift, delta = grid.neighbors, stretch.actions, stretch.cell_shift, stretch.delta
    _, stay, move, enter = emissions
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


@loop_kernel
def stretch_counts(f, b, weight, prune, *fields):
    """The M-step's statistics of the stretch, each start x with ``weight[x] > prune`` (its
    tempered pose posterior) and its offsets by their posterior given x: adds to out.counts (N,
    K) ``sum_{x, tau, d} weight[x] P(d_tau = d | x, data) [reading z of cell c at tau]``, and to
    out.entered / out.bumped (N,) the expected presses into each cell that moved / failed.
    O(S F n D) for n such starts. ``*fields``: the fields of the :class:`Grid`, the
    :class:`Stretch`, the :class:`Emissions` and the :class:`Counts` ``out``."""
    grid, stretch, emissions = _bundles(fields)
    out = Counts(*fields[_EMISSIONS_END:])
    for x in range(f.shape[1]):
        w = weight[x]
        if w <= prune:
            continue
        for tau in range(f.shape[0]):
            if _reading_counts(grid, stretch, f, b, x, tau, w, out.counts) == 0.0:
                break
            if tau == 0:
                continue
            if _press_counts(grid, stretch, emissions, f, b, x, tau, w, out) == 0.0:
                break


@njit(cache=True, inline="always")
def _reading_counts(grid, stretch, f, b, x, tau, w, counts):
    """Adds the readings of step tau, each offset by ``w P(d_tau = d | x, data)``, to counts
    (N, K); returns the step's total ``sum_d f b`` (0: start x is impossible, nothing added)."""
    cells, now, cell_shift = grid.cells, stretch.readings[tau], stretch.cell_shift
    n_off = f.shape[2]
    total = 0.0
    for d in range(n_off):
        total += f[tau, x, d] * b[tau, x, d]
    if total != 0.0:
        for d in range(n_off):
            g = f[tau, x, d] * b[tau, x, d]
            if g == 0.0:
                continue
            g *= w / total
            c = x + cell_shift[d]
            for j in range(cells.shape[1]):
                cell = cells[c, j]
                z = now[j]
                if cell >= 0 and z >= 0:
                    counts[cell, z] += g
    return total


@njit(cache=True, inline="always")
def _press_counts(grid, stretch, emissions, f, b, x, tau, w, out):
    """Adds step tau's press, weighted by ``w`` and its posterior given x, to out.entered (it
    moved) or out.bumped (it failed) of its target; returns the step's total (0: start x is
    impossible, nothing added)."""
    neighbors, cell_shift, delta = grid.neighbors, stretch.cell_shift, stretch.delta
    _, stay, move, enter = emissions
    a = stretch.actions[tau - 1]
    total = 0.0
    for d in range(f.shape[2]):
        v = f[tau - 1, x, d]
        if v == 0.0:
            continue
        c = x + cell_shift[d]
        target = neighbors[c, a]
        p = enter[tau, c]
        total += v * (1.0 - p) * stay[tau, c] * b[tau, x, d]
        if target != c and p > 0.0:
            total += v * p * move[tau, target] * b[tau, x, d + delta[a]]
    if total != 0.0:
        for d in range(f.shape[2]):
            v = f[tau - 1, x, d]
            if v == 0.0:
                continue
            c = x + cell_shift[d]
            target = neighbors[c, a]
            if target == c:
                continue
            p = enter[tau, c]
            out.bumped[target] += w * v * (1.0 - p) * stay[tau, c] * b[tau, x, d] / total
            out.entered[target] += w * v * p * move[tau, target] * b[tau, x, d + delta[a]] / total
    return total
