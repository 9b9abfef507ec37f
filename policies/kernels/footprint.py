"""numba kernels of the information-gain planner's rollouts for footprint and blocking models
(``policies/rollouts.py``): the thinned particle belief of :mod:`policies.kernels.planning`, for
any sensor footprint and blocking labels (DESIGN.md section 7), with the filter of
``onlinemap.kernels.rbpf.rbpf_enumerate_cells`` in its optimal-proposal form: particle p at l
pressing towards n enumerates its two successors (stay, move), the move entered with
``p_move * P(m_n passable)`` judged on n's marginal before this step's map change, n conditioned
on the outcome (passable if it moved; ``(1 - p_move) + p_move [blocks]`` if it stayed) and
carried by C, then every reading of the footprint at the successor through O (-1 off the grid,
with probability 1); one successor is drawn in proportion to motion x likelihood and the weight
is multiplied by their sum. No resampling; a particle whose weight falls below 1e-9 of the
largest is dropped (it would cost as much as any other for nothing).

Overlays: a particle's changed cells go to slots ``ov_val (R, W, K)`` stamped with their step,
found through ``ov_index (R, N)`` (-1: the particle's base map), so a read is O(K) (O(K^2) with
map dynamics) whatever the horizon. W = H (F + 1) slots hold every cell a rollout of H steps can
change. Every rollout resets the slots it used.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import numpy as np
from numba import njit

from onlinemap.kernels import aligned, inner_kernel, loop_kernel, thread_kernel
from onlinemap.kernels.rbpf import carried
from onlinemap.kernels.rbpf_parallel import in_threads, thread_runs

from .mixture import mixture_uncertainty
from .planning import normalise, world_step
from .rollout_buffers import Overlays, States, empty_overlays, kept_works, step_scratch


NEGLIGIBLE = math.log(1e-9)  # a rollout drops a particle whose weight falls below 1e-9 of the largest


class Candidates(NamedTuple):
    """``sequences`` (C, H) actions, -1 at a step where the action is chosen in closed loop on the
    rollout's own belief towards the candidate's target (:func:`_closed_loop_action` with
    ``distances[c]`` (N,) and ``go`` (N, A), the chance each press moves)."""

    sequences: np.ndarray
    distances: np.ndarray
    go: np.ndarray


class Agreement(NamedTuple):
    """``disputed`` (D,) sorted: the cells whose base marginals differ between particles;
    ``entropy`` (H + 1,): the summed entropy of the other cells' base marginals at step h."""

    disputed: np.ndarray
    entropy: np.ndarray


class Beliefs(NamedTuple):
    """:func:`rollout_beliefs`' output: ``location`` (H + 1, N) and ``maps`` (H + 1, N, K) the
    weighted particle locations and map mixture after each step, ``where`` (H + 1,) the world's
    location and ``readings`` (H, F) its readings."""

    location: np.ndarray
    maps: np.ndarray
    where: np.ndarray
    readings: np.ndarray


@njit(cache=True, inline="always")
def _state(overlays, x):
    """Rollout state x's :class:`Overlays` (views)."""
    return Overlays(overlays.index[x], overlays.cell[x], overlays.val[x], overlays.stamp[x], overlays.n[x],
                    overlays.touched[x], overlays.touched_list[x])


@njit(cache=True, inline="always")
def _marginal(maps, ov, tables, p, c, h, out, column):
    """out (K,) <- particle p's marginal of cell c at rollout step h (an overlay slot if it has one);
    returns ``sum_b out[b] column[b]`` (added in order of b as each entry is made: a reading's
    likelihood with ``column = O[:, z]``). A caller that wants only ``out`` passes ``out`` itself
    and drops the sum (inlined, the compiler removes it)."""
    slot = ov.index[p, c]
    d = h if slot < 0 else h - ov.stamp[p, slot]
    if not tables.dynamic:
        d = 0
    total = 0.0
    for b in range(out.shape[0]):
        out[b] = carried(maps, tables.powers, d, p, c, b) if slot < 0 else carried(ov.val, tables.powers, d, p,
                                                                                   slot, b)
        total += out[b] * column[b]
    return total


@njit(cache=True, inline="always")
def _gate(world, tables, s, before, cells):
    """Successor s's motion probability when the move is gated by blocking: ``p_move P(m_n
    passable)`` to move, the rest to stay, judged on n's marginal ``before`` (K,) at step h - 1.
    Where positive, ``cells[0]`` <- n's marginal given the outcome (passable if it moved; ``(1 -
    p_move) + p_move [blocks]`` if it stayed), carried by C (``before`` is then scratch)."""
    k = before.shape[0]
    p_move, blocking = world.p_move, world.blocking
    passable = 0.0
    for b in range(k):
        if not blocking[b]:
            passable += before[b]
    probability = p_move * passable if s == 1 else 1.0 - p_move * passable
    if probability > 0.0:
        total = 0.0
        for b in range(k):
            factor = (0.0 if blocking[b] else 1.0) if s == 1 else (1.0 - p_move) + (p_move if blocking[b] else 0.0)
            cells[0, b] = before[b] * factor
            total += cells[0, b]
        for b in range(k):
            cells[0, b] /= total
        if tables.dynamic:
            for b in range(k):
                acc = 0.0
                for a in range(k):
                    acc += cells[0, a] * world.change[a, b]
                before[b] = acc  # scratch: n's marginal at step h, given the outcome
            for b in range(k):
                cells[0, b] = before[b]
    return probability


@njit(cache=True, inline="always")
def _successor(maps, ov, world, tables, p, l, n, s, h, step):
    """Successor s (0 stay, 1 move) of particle p at l pressing towards n, at step h: returns
    ``(cell, motion probability x likelihood, used)``, writing into row s of ``step`` the changed
    cells' ids (used,) and their marginals at step h, before the readings, ``cells (used, K)``;
    read f's likelihood ``lams[f]`` and its row of ``cells``, ``slots[f]`` (-1: no reading). Those
    are complete only when the returned weight is positive, as it is for the successor drawn, the
    one whose rows :func:`_read` turns into posteriors. ``before[s]`` (K,): n's marginal at step
    h - 1 (read by the caller when the move is gated by blocking, :func:`_gate`)."""
    ids, cells, lams, slots, readings = step.ids[s], step.cells[s], step.lams[s], step.slots[s], step.readings
    gated = world.has_blocking and n != l
    if s == 1:
        if n == l:
            return l, 0.0, 0
        j = n
        probability = world.p_move
    else:
        j = l
        probability = 1.0 if n == l else 1.0 - world.p_move
    used = 0
    if gated:
        probability = _gate(world, tables, s, step.before[s], cells)
        if probability <= 0.0:
            return j, 0.0, 0
        ids[0] = n
        used = 1
    elif probability <= 0.0:
        return j, 0.0, 0
    likelihood = probability
    for f in range(world.footprint_cells.shape[1]):
        c = world.footprint_cells[j, f]
        z = readings[f]
        slots[f] = -1
        if c < 0 or z < 0:
            if c < 0 and z < 0:
                continue
            return j, 0.0, 0
        w = used
        lam = 0.0
        if gated and ids[0] == c:  # the cell the move tried to enter, given the move's outcome
            w = 0
            for b in range(world.sensor.shape[0]):
                lam += cells[w, b] * world.likelihood[z, b]
        else:
            lam = _marginal(maps, ov, tables, p, c, h, cells[w], world.likelihood[z])
            ids[w] = c
            used += 1
        if lam <= 0.0:
            return j, 0.0, 0
        lams[f] = lam
        slots[f] = w
        likelihood *= lam
    return j, likelihood, used


@njit(cache=True, inline="always")
def _read(likelihood, step, s):
    """The rows ``cells`` (W, K) of successor s (:func:`_successor`) given their readings:
    ``cells[w] <- cells[w] O[:, z] / lam`` for read f's row w = ``slots[f]`` (``likelihood`` (Z,
    K): the world's contiguous O.T, whose rows vectorise). Each footprint cell is read once, so no
    likelihood depends on another read's posterior."""
    cells, lams, slots, readings = step.cells[s], step.lams[s], step.slots[s], step.readings
    k = likelihood.shape[1]
    for f in range(slots.shape[0]):
        w = slots[f]
        if w < 0:
            continue
        z = readings[f]
        lam = lams[f]
        for b in range(k):
            cells[w, b] = cells[w, b] * likelihood[z, b] / lam


@njit(cache=True, inline="always")
def _keep(ov, p, h, ids, cells, used, n_touched):
    """Particle p's overlay slots of the cells ``ids`` (used,) <- ``cells`` (used, K), stamped h
    (a slot taken for a cell without one); each cell flagged in ``touched`` and listed once.
    Returns the new count of touched cells."""
    for v in range(used):
        c = ids[v]
        slot = ov.index[p, c]
        if slot < 0:
            slot = ov.n[p]
            ov.n[p] += 1
            ov.index[p, c] = slot
            ov.cell[p, slot] = c
        for b in range(cells.shape[1]):
            ov.val[p, slot, b] = cells[v, b]
        ov.stamp[p, slot] = h
        if not ov.touched[c]:
            ov.touched[c] = True
            ov.touched_list[n_touched] = c
            n_touched += 1
    return n_touched


@inner_kernel
def _filter_step(loc, lw, maps, ov, world, tables, a, h, proposal_u, step, n_touched):
    """Every particle (``loc``, ``lw`` (R,)) takes step h (action a, ``step.readings``); weights
    renormalised (all particles kept, equally weighted, if none explains the readings). Cells any
    particle changes are flagged and listed in ``ov`` (:func:`_keep`); returns their new count
    (``n_touched`` before). Both successors' likelihoods are computed, the posterior cells only for
    the one drawn. O(R (F + 1) K) (K^2 with map dynamics)."""
    before = step.before
    top = -np.inf
    for p in range(loc.shape[0]):
        if lw[p] == -np.inf:
            continue
        l = loc[p]
        n = world.moves[a, l]
        if world.has_blocking and n != l:
            _marginal(maps, ov, tables, p, n, h - 1, before[0], before[0])
            for b in range(before.shape[1]):
                before[1, b] = before[0, b]
        j0, w0, u0 = l, 0.0, 0
        j1, w1, u1 = l, 0.0, 0
        for s in range(2):  # one copy of the successor's code for both: half the code to compile
            j, w, u = _successor(maps, ov, world, tables, p, l, n, s, h, step)
            if s == 0:
                j0, w0, u0 = j, w, u
            else:
                j1, w1, u1 = j, w, u
        total = w0 + w1
        if not total > 0.0:
            lw[p] = -np.inf
            continue
        s = 1 if proposal_u[p] * total < w1 else 0
        lw[p] += math.log(total)
        loc[p] = j1 if s == 1 else j0
        _read(world.likelihood, step, s)
        n_touched = _keep(ov, p, h, step.ids[s], step.cells[s], u1 if s == 1 else u0, n_touched)
        if lw[p] > top:
            top = lw[p]
    normalise(lw, top, NEGLIGIBLE)  # a particle this far behind is dropped from the rollout
    return n_touched


@inner_kernel
def _closed_loop_action(loc, lw, moves, distance, go, weights):
    """``argmin_a sum_p w_p [go(l_p, a) D(n) + (1 - go(l_p, a)) D(l_p)]``, ``n = moves[a, l_p]``:
    the expected distance ``D`` (N,) to the candidate's target after the press, ``go`` (N, A) the
    chance the press moves (0 where it cannot); ties to the lowest action. ``weights`` (R,):
    ``w_p = exp(lw_p)``, filled by the caller once for all of a state's candidates. O(R A)."""
    best = -1
    best_cost = np.inf
    for a in range(go.shape[1]):
        cost = 0.0
        for p in range(loc.shape[0]):
            if lw[p] == -np.inf:
                continue
            l = loc[p]
            cost += weights[p] * (go[l, a] * distance[moves[a, l]] + (1.0 - go[l, a]) * distance[l])
        if cost < best_cost:
            best_cost = cost
            best = a
    return best


@inner_kernel
def _reset(ov, n_touched):
    """Empty every particle's overlay and the touched set after a rollout. O(slots used)."""
    for p in range(ov.n.shape[0]):
        for j in range(ov.n[p]):
            ov.index[p, ov.cell[p, j]] = -1
        ov.n[p] = 0
    for j in range(n_touched):
        ov.touched[ov.touched_list[j]] = False


@inner_kernel
def _fork(states, x, y):
    """Rollout state y (empty) <- a copy of state x: the particles, the hypothetical world and the
    overlays, slot for slot in the same order (so every later sum runs in the same order).
    O(R (1 + W K) + N + T) for the W slots used and T cells touched."""
    ov = states.overlays
    k = ov.val.shape[3]
    for p in range(states.loc.shape[1]):
        states.loc[y, p] = states.loc[x, p]
        states.lw[y, p] = states.lw[x, p]
        for j in range(ov.n[x, p]):
            c = ov.cell[x, p, j]
            ov.cell[y, p, j] = c
            ov.stamp[y, p, j] = ov.stamp[x, p, j]
            ov.index[y, p, c] = j
            for b in range(k):
                ov.val[y, p, j, b] = ov.val[x, p, j, b]
        ov.n[y, p] = ov.n[x, p]
    for i in range(states.labels.shape[1]):
        states.labels[y, i] = states.labels[x, i]
    states.where[y] = states.where[x]
    for j in range(states.n_touched[x]):
        c = ov.touched_list[x, j]
        ov.touched_list[y, j] = c
        ov.touched[y, c] = True
    states.n_touched[y] = states.n_touched[x]


@inner_kernel
def _press(moves, candidates, work, g, x, h, n_free, n_pending, n_groups):
    """Every candidate of group g (in rollout state x) chooses its press at step h: its
    sequence's, or in closed loop on the state's belief (:func:`_closed_loop_action`). A candidate
    pressing otherwise than the group's first joins the group of its press, made the first time
    from a copy of the state (:func:`_fork`) and put on the stack. Returns (the group's first
    candidate, n_free, n_pending, n_groups)."""
    states, groups = work.states, work.groups
    lead, weighted = -1, False
    for a in range(groups.parted.shape[0]):
        groups.parted[a] = -1
    for c in range(candidates.sequences.shape[0]):
        if groups.group[c] != g:
            continue
        a = candidates.sequences[c, h - 1]
        if a < 0:
            if not weighted:  # the state's weights, the same for each of its candidates
                for p in range(states.lw.shape[1]):
                    work.mixture.weights[p] = math.exp(states.lw[x, p])
                weighted = True
            a = _closed_loop_action(states.loc[x], states.lw[x], moves, candidates.distances[c], candidates.go,
                                    work.mixture.weights)
        groups.action[c] = a
        if lead < 0:
            lead = c
        elif a != groups.action[lead]:  # c presses otherwise: its own group, from a copy of the state
            if groups.parted[a] < 0:
                n_free -= 1
                y = groups.free[n_free]
                _fork(states, x, y)
                groups.parted[a] = n_groups
                groups.pending[n_pending, 0], groups.pending[n_pending, 1], groups.pending[n_pending, 2] = \
                    n_groups, y, h
                n_pending += 1
                n_groups += 1
            groups.group[c] = groups.parted[a]
    return lead, n_free, n_pending, n_groups


@inner_kernel
def _start_world(particles, hypotheses, s, scoring, now, work, out):
    """World s starts: rollout state 0 <- the particles and the world's labels and location, every
    candidate in group 0, the other states free (the last freed on top), ``out[c, 0] += now``
    where step 0 is scored. Returns the count of free states."""
    states, groups = work.states, work.groups
    n_seq = groups.group.shape[0]
    for x in range(n_seq):
        groups.free[x] = n_seq - 1 - x
    for p in range(particles.locations.shape[0]):
        states.loc[0, p] = particles.locations[p]
        states.lw[0, p] = particles.log_weights[p]
    for i in range(states.labels.shape[1]):
        states.labels[0, i] = hypotheses.labels[s, i]
    states.where[0] = hypotheses.locations[s]
    for c in range(n_seq):
        groups.group[c] = 0
        if scoring.checkpoints[0]:
            out[c, 0] += now
    groups.pending[0, 0], groups.pending[0, 1], groups.pending[0, 2] = 0, 0, 1
    return n_seq - 1  # state 0 starts the world


@thread_kernel
def roll_worlds(particles, world, tables, candidates, hypotheses, scoring, agreement, work, start, stop, values):
    """:func:`plan_rollouts` for worlds ``start`` to ``stop - 1`` in the buffers ``work``, world
    s's scores into ``values[s]`` (C, H + 1), zero on entry: every candidate from the particles,
    candidates that press alike sharing one rollout state, a state stepped to the horizon before
    the next is taken from the stack (depth first: its memory stays in cache). One compiled function
    for the loops (a compiled caller compiles its callees again); GIL released for Python threads."""
    states, groups, maps = work.states, work.groups, particles.maps
    n_seq, horizon = candidates.sequences.shape
    zero = np.int64(0)  # not the literal 0: mixture_uncertainty compiles once, for int64 h and counts
    now = mixture_uncertainty(particles.locations, particles.log_weights, maps, _state(states.overlays, 0), tables,
                              zero, scoring.location_weight, zero, agreement.entropy[0], agreement.disputed,
                              work.mixture)
    for s in range(start, stop):
        n_free = _start_world(particles, hypotheses, s, scoring, now, work, values[s])
        n_groups, n_pending = np.int64(1), 1  # not the literal 1: _press compiles once
        while n_pending > 0:
            n_pending -= 1
            g, x, first = groups.pending[n_pending, 0], groups.pending[n_pending, 1], groups.pending[n_pending, 2]
            ov = _state(states.overlays, x)
            for h in range(first, horizon + 1):
                lead, n_free, n_pending, n_groups = _press(world.moves, candidates, work, g, x, h, n_free, n_pending,
                                                           n_groups)
                a = groups.action[lead]
                states.where[x] = world_step(world, tables, states.where[x], states.labels[x], a,
                                             hypotheses.world_u[s, h - 1], hypotheses.change_u[s, h - 1],
                                             work.step.readings)
                states.n_touched[x] = _filter_step(states.loc[x], states.lw[x], maps, ov, world, tables, a, h,
                                                   hypotheses.proposal_u[s, h - 1], work.step, states.n_touched[x])
                if scoring.checkpoints[h]:
                    value = mixture_uncertainty(states.loc[x], states.lw[x], maps, ov, tables, h,
                                                scoring.location_weight, states.n_touched[x], agreement.entropy[h],
                                                agreement.disputed, work.mixture)
                    for c in range(n_seq):
                        if groups.group[c] == g:
                            values[s, c, h] += value
            _reset(ov, states.n_touched[x])
            states.n_touched[x] = 0
            groups.free[n_free] = x
            n_free += 1


def plan_rollouts(particles, world, tables, candidates, hypotheses, scoring, agreement, out, threads=1, kept=None):
    """Roll every candidate out in every hypothetical world through the thinned particle belief
    and add up its uncertainty: ``out[c, h] += U`` after h steps of candidate c in world s, for
    every h with ``scoring.checkpoints[h]`` (``out`` (C, H + 1); the caller divides by S).

    ``particles``: a ``ParticleSnapshot`` (``maps`` C-contiguous); ``world``: the RBPF's ``World``
    bundle; ``tables``: :class:`~policies.kernels.planning.RolloutTables`; ``candidates``:
    :class:`Candidates`; ``hypotheses``: :class:`~policies.kernels.planning.Hypotheses` (the same
    random numbers for every candidate); ``scoring``: :class:`~policies.kernels.planning.Scoring`;
    ``agreement``: :class:`Agreement`.

    With common random numbers, candidates that have pressed alike so far in a world are in the
    same state: such a group shares one rollout state (one of C), stepped and scored once. When
    its candidates press differently, the state is copied (:func:`_fork`, before the step) for
    each other press, and that group waits on a stack (:func:`roll_worlds`). The scores are those
    of rolling every candidate out alone, bit for bit; in the door world and 16 x 16 buildings
    5-30% of the steps are shared (plans 18% faster, measured on recorded plans). The buffers
    are allocated (or taken from ``kept``) here, the loops run in the kernel :func:`roll_worlds` (a compiled entry point
    would compile every kernel's code once more).

    ``threads``: the worlds go in that many contiguous runs (at most S) to Python threads
    (:func:`roll_worlds` releases the GIL; a run has its own buffers); each world's scores are
    added into ``out`` in world order, as one thread does: the same bits for any ``threads``.
    Cost O(S C H R (F + 1) K) for the steps (K^2 with map dynamics) plus O(S C R (D + H F) K)
    per checkpoint, less the shared steps, over the threads; memory O(threads C R (N + H F K) + S C H).
    ``kept``: a :class:`~policies.kernels.rollout_buffers.KeptBuffers` the caller keeps between
    its plans (never two at once), holding the threads' buffers for the next plan
    (:func:`~policies.kernels.rollout_buffers.kept_works`; cleared if the plan raises); the same scores."""
    n_worlds = hypotheses.locations.shape[0]
    if candidates.sequences.shape[0] == 0 or n_worlds == 0:  # nothing to score (no rollout state to start from)
        return
    runs = thread_runs(n_worlds, 1, threads)
    works = kept_works(kept, len(runs), particles, world, candidates, agreement, hypotheses.labels.dtype)
    values = np.zeros((n_worlds,) + out.shape)
    try:
        in_threads([functools.partial(roll_worlds, particles, world, tables, candidates, hypotheses, scoring,
                                      agreement, work, start, stop, values) for work, (start, stop) in zip(works, runs)])
    except BaseException:
        if kept is not None:  # a plan cut short may leave its overlays written
            kept.clear()
        raise
    for s in range(n_worlds):  # in world order, as one thread adds them
        out += values[s]


@inner_kernel
def _whole_belief(loc, lw, maps, ov, tables, h, scratch, beliefs):
    """``beliefs.location[h]`` and ``beliefs.maps[h]`` <- the weighted particle locations and map
    mixture at step h (``scratch`` (K,)). O(R N K) (K^2 with map dynamics)."""
    beliefs.location[h] = 0.0
    beliefs.maps[h] = 0.0
    for p in range(loc.shape[0]):
        if lw[p] == -np.inf:
            continue
        w = math.exp(lw[p])
        beliefs.location[h, loc[p]] += w
        for c in range(maps.shape[1]):
            _marginal(maps, ov, tables, p, c, h, scratch, scratch)
            for b in range(scratch.shape[0]):
                beliefs.maps[h, c, b] += w * scratch[b]


@loop_kernel
def _roll_beliefs(particles, world, tables, actions, hypotheses, states, step, scratch, beliefs):
    """:func:`rollout_beliefs` in the buffers ``states`` (one rollout state, from the particles
    and world 0), ``step`` and ``scratch`` (K,)."""
    ov = _state(states.overlays, 0)
    loc, lw, labels = states.loc[0], states.lw[0], states.labels[0]
    where = states.where[0]
    n_touched = np.int64(0)
    for h in range(actions.shape[0] + 1):
        if h > 0:
            a = actions[h - 1]
            where = world_step(world, tables, where, labels, a, hypotheses.world_u[0, h - 1],
                               hypotheses.change_u[0, h - 1], step.readings)
            for f in range(step.readings.shape[0]):
                beliefs.readings[h - 1, f] = step.readings[f]
            n_touched = _filter_step(loc, lw, particles.maps, ov, world, tables, a, h, hypotheses.proposal_u[0, h - 1],
                                     step, n_touched)
        beliefs.where[h] = where
        _whole_belief(loc, lw, particles.maps, ov, tables, h, scratch, beliefs)


def rollout_beliefs(particles, world, tables, actions, hypotheses, beliefs):
    """One rollout of :func:`plan_rollouts` (world 0 of ``hypotheses``, the fixed ``actions``
    (H,)), keeping the whole belief in ``beliefs`` (:class:`Beliefs`). For tests.
    O(H R (N K + (F + 1) K^2))."""
    r_count, n_cells, k = particles.maps.shape
    n_reads = world.footprint_cells.shape[1]
    states = States(particles.locations.copy()[None], particles.log_weights.copy()[None],
                    hypotheses.labels[:1].copy(), hypotheses.locations[:1].copy(), aligned(1, np.int64, 0),
                    empty_overlays(1, r_count, n_cells, k, actions.shape[0], n_reads))
    _roll_beliefs(particles, world, tables, actions, hypotheses, states, step_scratch(n_reads, k), aligned(k), beliefs)
