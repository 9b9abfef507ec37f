"""numba kernel of the information-gain planner (``policies/rollouts.py``): roll action sequences
out against hypothetical worlds through a thinned copy of a particle belief and measure the
belief's uncertainty along the way; the bundles and the world step both rollout kernels share.

The thinned belief is R particles (a ``ParticleSnapshot``: locations (R,), dense map marginals
``maps (R, N, K)``, log weights (R,)). A rollout never writes to them: each particle's updated
cells go to a small overlay of at most H entries (H = the sequence's length), read before the
particle's own map. With map dynamics, marginals are brought forward by ``powers[d] = C^d``
(``onlinemap.kernels.rbpf.carried``, the filter's own rule).

Uncertainty (nats): ``U = location_weight * H(L) + sum_i H(M_i)``, ``H(L)`` the entropy of the
weighted particle locations and ``M_i`` the weighted mixture of the particles' marginals of
cell ``i`` (the belief's map marginal).

Bundles: the model's motion and sensor tables are the RBPF's ``World``
(``onlinemap.estimators.rbpf_kernels.world_tables``); :class:`RolloutTables` adds what only the
rollouts read. The loops over particles and cells run in :data:`~onlinemap.kernels.inner_kernel` kernels
(bundles cost nothing there), those over worlds and candidates in one loop kernel called from
Python; the entry point allocates in Python (a compiled entry point would compile every kernel's
code once more: each compiled function links and compiles its callees' code anew).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from onlinemap.kernels import aligned, inner_kernel, loop_kernel
from onlinemap.kernels.rbpf import carried


class RolloutTables(NamedTuple):
    """The model's tables as the rollouts take them, for horizons up to H."""

    sensor_cdf: np.ndarray  # (K, Z) cumulative rows of O
    change_cdf: np.ndarray  # (K, K) cumulative rows of C
    powers: np.ndarray  # (H + 1, K, K) C^d
    dynamic: bool  # map dynamics (C is not the identity)


class Hypotheses(NamedTuple):
    """S hypothetical worlds and the random numbers of their steps (common to every candidate)."""

    locations: np.ndarray  # (S,) int64
    labels: np.ndarray  # (S, N) int64
    world_u: np.ndarray  # (S, H, 1 + F): the move, then each reading
    change_u: np.ndarray  # (S, H, N), (S, H, 0) in a static world
    proposal_u: np.ndarray  # (S, H, R): each particle's proposal


class Scoring(NamedTuple):
    """Which step counts are scored (``checkpoints`` (H + 1,) bool) and the weight of H(L)."""

    location_weight: float
    checkpoints: np.ndarray


class _Rollout(NamedTuple):
    """One rollout's particles (``loc``, ``lw``, ``weights`` (R,)), world labels (N,) and overlays:
    particle p's j-th updated cell ``cell[p, j]``, its marginal ``val[p, j]`` (K,) stamped
    ``stamp[p, j]``, ``n[p]`` entries."""

    loc: np.ndarray
    lw: np.ndarray
    weights: np.ndarray
    labels: np.ndarray
    cell: np.ndarray
    val: np.ndarray
    stamp: np.ndarray
    n: np.ndarray


class _Scratch(NamedTuple):
    """Scratch of a rollout: ``location`` (N,), ``mixture`` (N, K), ``here``/``there``/``tmp`` (K,),
    ``readings`` (F,)."""

    location: np.ndarray
    mixture: np.ndarray
    here: np.ndarray
    there: np.ndarray
    tmp: np.ndarray
    readings: np.ndarray


@inner_kernel
def draw(cdf_row, u):
    """Index of the first entry of the cumulative row ``cdf_row`` above ``u``."""
    k = cdf_row.shape[0]
    for b in range(k - 1):
        if u < cdf_row[b]:
            return b
    return k - 1


@inner_kernel
def world_step(world, tables, where, labels, a, world_u, change_u, readings):
    """One step of the hypothetical world (``onlinemap.simulate.world_step``'s order and rules):
    the move with ``world_u[0] < p_move`` unless the intended cell's label blocks, the labels by
    ``change_cdf`` with ``change_u`` (N,), the readings with ``world_u[1 + f]`` (-1 off the grid).
    Returns the new location; ``labels`` and ``readings`` (F,) are written in place. O(N + F)."""
    if world_u[0] < world.p_move:
        target = world.moves[a, where]
        if not world.blocking[labels[target]]:
            where = target
    if tables.dynamic:
        for i in range(labels.shape[0]):
            labels[i] = draw(tables.change_cdf[labels[i]], change_u[i])
    for f in range(world.footprint_cells.shape[1]):
        c = world.footprint_cells[where, f]
        readings[f] = -1 if c < 0 else draw(tables.sensor_cdf[labels[c]], world_u[1 + f])
    return where


@njit(cache=True, inline="always")
def _current(maps, rollout, tables, p, c, h, out):
    """out (K,) <- particle p's marginal of cell c after h rollout steps."""
    for j in range(rollout.n[p]):
        if rollout.cell[p, j] == c:
            d = h - rollout.stamp[p, j] if tables.dynamic else 0
            for b in range(out.shape[0]):
                out[b] = carried(rollout.val, tables.powers, d, p, j, b)
            return
    d = h if tables.dynamic else 0
    for b in range(out.shape[0]):
        out[b] = carried(maps, tables.powers, d, p, c, b)


@inner_kernel
def entropy(row):
    """Entropy in nats of the probabilities ``row`` (K,). O(K)."""
    acc = 0.0
    for x in row:
        if x > 0.0:
            acc -= x * math.log(x)
    return acc


@inner_kernel
def _uncertainty(locations, maps, rollout, tables, h, location_weight, scratch):
    """``location_weight * H(L) + sum_i H(M_i)`` of the particles ``locations`` (R,) weighted by
    ``rollout.weights`` after h steps. O(R N K + N K^2 + R H K^2)."""
    r_count, n_cells, k = maps.shape
    location, mixture, tmp = scratch.location, scratch.mixture, scratch.tmp
    location[:] = 0.0
    mixture[:] = 0.0
    flat = mixture.reshape(n_cells * k)  # one contiguous loop per particle: the same sums, faster
    for p in range(r_count):
        w = rollout.weights[p]
        if w == 0.0:
            continue
        location[locations[p]] += w
        row = maps[p].reshape(n_cells * k)
        for j in range(n_cells * k):
            flat[j] += w * row[j]
    if tables.dynamic and h > 0:
        whole = mixture.reshape(1, n_cells, k)
        for i in range(n_cells):
            for b in range(k):
                tmp[b] = carried(whole, tables.powers, h, 0, i, b)
            for b in range(k):
                mixture[i, b] = tmp[b]
    base = h if tables.dynamic else 0
    for p in range(r_count):
        w = rollout.weights[p]
        if w == 0.0:
            continue
        for j in range(rollout.n[p]):  # entry j is the particle's only one of its cell (:func:`_write`)
            c = rollout.cell[p, j]
            d = h - rollout.stamp[p, j] if tables.dynamic else 0
            for b in range(k):  # less the particle's base marginal of c, brought to step h
                mixture[c, b] += w * (carried(rollout.val, tables.powers, d, p, j, b)
                                      - carried(maps, tables.powers, base, p, c, b))
    total = location_weight * entropy(location)
    for i in range(n_cells):
        for b in range(k):  # rounding: keep every term a probability
            if mixture[i, b] < 0.0:
                mixture[i, b] = 0.0
        total += entropy(mixture[i])
    return total


@inner_kernel
def normalise(lw, top, drop_below):
    """Log weights ``lw`` (R,) in place so that ``sum exp(lw) = 1``, given ``top = max(lw)``; a
    particle with ``lw - top < drop_below`` is dropped (-inf); when every particle is at -inf
    (the world left them all behind) they are kept, equally weighted. O(R)."""
    if top == -np.inf:
        lw[:] = 0.0
        top = 0.0
    total = 0.0
    for p in range(lw.shape[0]):
        if lw[p] - top < drop_below:
            lw[p] = -np.inf
        total += math.exp(lw[p] - top)
    norm = top + math.log(total)
    for p in range(lw.shape[0]):
        lw[p] -= norm


@njit(cache=True, inline="always")
def _write(rollout, p, target, h, cell, lik, lam):
    """Particle p's overlay entry of ``target`` <- ``cell * lik / lam`` (``cell`` where lam is 0),
    stamped h: its own entry if it has one, else a new one."""
    slot = -1
    for j in range(rollout.n[p]):
        if rollout.cell[p, j] == target:
            slot = j
    if slot < 0:
        slot = rollout.n[p]
        rollout.n[p] += 1
        rollout.cell[p, slot] = target
    for b in range(cell.shape[0]):
        rollout.val[p, slot, b] = cell[b] * lik[b] / lam if lam > 0.0 else cell[b]
    rollout.stamp[p, slot] = h


@inner_kernel
def _filter_step(maps, world, tables, rollout, a, h, lik, proposal_u, scratch):
    """Every particle takes step h (action a, a reading of likelihood ``lik`` (K,)) by the optimal
    proposal of the RBPF (p moves with probability ``p_move P(z | there) / (p_move P(z | there)
    + (1 - p_move) P(z | here))``, drawn with ``proposal_u[p]``, weight times the denominator),
    the visited cell's marginal times ``lik`` renormalised; no resampling. O(R (H + K^2))."""
    loc, lw, here_m, there_m = rollout.loc, rollout.lw, scratch.here, scratch.there
    p_move = world.p_move
    top = -np.inf
    for p in range(loc.shape[0]):
        here = loc[p]
        there = world.moves[a, here]
        lam_here, lam_there = 0.0, 0.0
        for s in range(1 if there == here else 2):  # one copy of _current for both cells: less code to compile
            out = here_m if s == 0 else there_m
            _current(maps, rollout, tables, p, here if s == 0 else there, h, out)
            lam = 0.0
            for b in range(out.shape[0]):
                lam += out[b] * lik[b]
            if s == 0:
                lam_here = lam
            else:
                lam_there = lam
        target = here
        lam = lam_here
        weight = lam_here
        if there != here:
            move = p_move * lam_there
            weight = move + (1.0 - p_move) * lam_here
            if proposal_u[p] * weight < move:
                target = there
                lam = lam_there
                for b in range(here_m.shape[0]):
                    here_m[b] = there_m[b]
        if weight > 0.0 and lw[p] > -np.inf:
            lw[p] += math.log(weight)
        else:
            lw[p] = -np.inf
        loc[p] = target
        _write(rollout, p, target, h, here_m, lik, lam)
        if lw[p] > top:
            top = lw[p]
    normalise(lw, top, -np.inf)
    for p in range(loc.shape[0]):
        rollout.weights[p] = math.exp(lw[p])


@loop_kernel
def _roll_all(particles, world, tables, sequences, hypotheses, scoring, rollout, scratch, total):
    """:func:`rollout_uncertainty` in the buffers ``rollout`` and ``scratch``: every sequence in
    every world, each step the world's (:func:`world_step`), then the particles'
    (:func:`_filter_step`), scored at the checkpoints (:func:`_uncertainty`). One compiled
    function for the loops (each compiled caller compiles its callees' code again)."""
    for p in range(rollout.weights.shape[0]):
        rollout.weights[p] = math.exp(particles.log_weights[p])
    now = 0.0
    if scoring.checkpoints[0]:
        now = _uncertainty(particles.locations, particles.maps, rollout, tables, np.int64(0),  # int64: one compile
                           scoring.location_weight, scratch)
    for s in range(hypotheses.locations.shape[0]):
        for c in range(sequences.shape[0]):
            for p in range(rollout.loc.shape[0]):
                rollout.loc[p] = particles.locations[p]
                rollout.lw[p] = particles.log_weights[p]
                rollout.n[p] = 0
            for i in range(rollout.labels.shape[0]):
                rollout.labels[i] = hypotheses.labels[s, i]
            where = hypotheses.locations[s]
            total[c, 0] += now
            for h in range(1, sequences.shape[1] + 1):
                a = sequences[c, h - 1]
                where = world_step(world, tables, where, rollout.labels, a, hypotheses.world_u[s, h - 1],
                                   hypotheses.change_u[s, h - 1], scratch.readings)
                _filter_step(particles.maps, world, tables, rollout, a, h, world.likelihood[scratch.readings[0]],
                             hypotheses.proposal_u[s, h - 1], scratch)
                if scoring.checkpoints[h]:
                    total[c, h] += _uncertainty(rollout.loc, particles.maps, rollout, tables, h,
                                                scoring.location_weight, scratch)


def rollout_uncertainty(particles, world, tables, sequences, hypotheses, scoring, total):
    """Roll every action sequence ``sequences`` (C, H) out in every world of ``hypotheses`` (the
    paper's sensor and motion: F = 1) through the particles and add up its uncertainty:
    ``total[c, h] += U`` after h steps of candidate c in world s, for every h with
    ``scoring.checkpoints[h]`` (``total`` (C, H + 1); the caller divides by S). U at step 0 is the
    same in every world: computed once.

    World step h (DESIGN.md section 1 order, :func:`world_step`); filter step: the RBPF's optimal
    proposal (:func:`_filter_step`). ``particles``: a ``ParticleSnapshot``; ``world``: the RBPF's
    ``World`` bundle; ``tables``: :class:`RolloutTables`. Allocates the rollout's buffers here and
    runs the loop kernel :func:`_roll_all` (a compiled entry point would compile every kernel's
    code once more). Cost O(S C (H R (H + K^2) + n_checkpoints R N K)) plus O(R N K) for step 0.
    """
    r_count, n_cells, k = particles.maps.shape
    width = max(sequences.shape[1], 1)
    rollout = _Rollout(aligned(r_count, np.int64), aligned(r_count), aligned(r_count),
                       aligned(n_cells, hypotheses.labels.dtype), aligned((r_count, width), np.int64, -1),
                       aligned((r_count, width, k)), aligned((r_count, width), np.int64, 0),
                       aligned(r_count, np.int64, 0))
    scratch = _Scratch(aligned(n_cells), aligned((n_cells, k)), aligned(k), aligned(k), aligned(k),
                       aligned(world.footprint_cells.shape[1], np.int64))
    _roll_all(particles, world, tables, sequences, hypotheses, scoring, rollout, scratch, total)
