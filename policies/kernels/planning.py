"""numba kernel of the information-gain planner (``policies/rollouts.py``): roll an action
sequence out against one hypothetical world through a thinned copy of a particle belief and
measure the belief's uncertainty along the way.

The thinned belief is R particles, each a location and dense map marginals ``maps (R, N, K)``
with log weights (R,). A rollout never writes to them: each particle's updated cells go to a
small overlay of at most H entries (H = the sequence's length), read before the particle's own
map. With map dynamics, marginals are brought forward by ``powers[d] = C^d``.

Uncertainty (nats): ``U = location_weight * H(L) + sum_i H(M_i)``, ``H(L)`` the entropy of the
weighted particle locations and ``M_i`` the weighted mixture of the particles' marginals of
cell ``i`` (the belief's map marginal).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from onlinemap.kernels import loop_kernel


@njit(cache=True)
def draw(cdf_row, u):
    """Index of the first entry of the cumulative row ``cdf_row`` above ``u``."""
    k = cdf_row.shape[0]
    for b in range(k - 1):
        if u < cdf_row[b]:
            return b
    return k - 1


@loop_kernel
def _current(maps, ov_cell, ov_val, ov_stamp, ov_n, powers, dynamic, p, c, h, out):
    """out (K,) <- particle p's marginal of cell c after h rollout steps."""
    k = out.shape[0]
    for j in range(ov_n[p]):
        if ov_cell[p, j] == c:
            d = h - ov_stamp[p, j]
            for b in range(k):
                if dynamic and d > 0:
                    acc = 0.0
                    for a in range(k):
                        acc += ov_val[p, j, a] * powers[d, a, b]
                    out[b] = acc
                else:
                    out[b] = ov_val[p, j, b]
            return
    for b in range(k):
        if dynamic and h > 0:
            acc = 0.0
            for a in range(k):
                acc += maps[p, c, a] * powers[h, a, b]
            out[b] = acc
        else:
            out[b] = maps[p, c, b]


@njit(cache=True)
def entropy(row):
    """Entropy in nats of the probabilities ``row`` (K,). O(K)."""
    acc = 0.0
    for x in row:
        if x > 0.0:
            acc -= x * math.log(x)
    return acc


@loop_kernel
def _uncertainty(locations, maps, weights, ov_cell, ov_val, ov_stamp, ov_n, powers, dynamic, h,
                 location_weight, location, mixture, scratch, scratch2):
    """``location_weight * H(L) + sum_i H(M_i)`` of the weighted particles after h steps
    (``location`` (N,) and ``mixture`` (N, K): scratch). O(R N K + N K^2 + R H K^2)."""
    r_count, n_cells, k = maps.shape
    location[:] = 0.0
    mixture[:] = 0.0
    flat = mixture.reshape(n_cells * k)  # one contiguous loop per particle: the same sums, faster
    for p in range(r_count):
        w = weights[p]
        if w == 0.0:
            continue
        location[locations[p]] += w
        row = maps[p].reshape(n_cells * k)
        for j in range(n_cells * k):
            flat[j] += w * row[j]
    if dynamic and h > 0:
        for i in range(n_cells):
            for b in range(k):
                acc = 0.0
                for a in range(k):
                    acc += mixture[i, a] * powers[h, a, b]
                scratch[b] = acc
            for b in range(k):
                mixture[i, b] = scratch[b]
    for p in range(r_count):
        w = weights[p]
        if w == 0.0:
            continue
        for j in range(ov_n[p]):
            c = ov_cell[p, j]
            _current(maps, ov_cell, ov_val, ov_stamp, ov_n, powers, dynamic, p, c, h, scratch)
            for b in range(k):  # the particle's base marginal of c, brought to step h
                if dynamic and h > 0:
                    acc = 0.0
                    for a in range(k):
                        acc += maps[p, c, a] * powers[h, a, b]
                    scratch2[b] = acc
                else:
                    scratch2[b] = maps[p, c, b]
            for b in range(k):
                mixture[c, b] += w * (scratch[b] - scratch2[b])
    total = location_weight * entropy(location)
    for i in range(n_cells):
        for b in range(k):  # rounding: keep every term a probability
            if mixture[i, b] < 0.0:
                mixture[i, b] = 0.0
        total += entropy(mixture[i])
    return total


@njit(cache=True)
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


@njit(cache=True)
def rollout_uncertainty(locations, maps, log_weights, moves, p_move, likelihood, sensor_cdf, change_cdf,
                        powers, dynamic, actions, hyp_location, hyp_labels, world_uniforms, change_uniforms,
                        proposal_uniforms, location_weight, checkpoints, out):
    """Simulate ``actions`` (H,) in the world ``(hyp_location, hyp_labels (N,))`` and filter the
    simulated observations through the particles; ``out[h]`` <- the uncertainty after h steps
    for every h with ``checkpoints[h]`` (``out[0]``: now; other entries untouched).

    World step h (DESIGN.md section 1 order): move with probability ``p_move`` when
    ``world_uniforms[h - 1, 0] < p_move``, labels change by ``change_cdf`` (K, K) cumulative
    rows with ``change_uniforms[h - 1]`` (N,) when ``dynamic``, observe by ``sensor_cdf`` with
    ``world_uniforms[h - 1, 1]``. Filter step: the optimal proposal of the RBPF (particle p
    moves with probability ``p_move * P(z | there) / (p_move P(z | there) + (1 - p_move)
    P(z | here))``, drawn with ``proposal_uniforms[h - 1, p]``, weight times the denominator),
    the visited cell's marginal times ``likelihood[z]`` renormalised; no resampling.
    Inputs: ``locations`` (R,), ``maps`` (R, N, K), ``log_weights`` (R,), ``moves`` (A, N),
    ``likelihood`` (K, K) rows ``O[:, z]``, ``powers`` (H + 1, K, K) ``C^d``.
    Cost O(H R (H + K^2)) for the steps plus O(R N K) per checkpoint.
    """
    r_count, n_cells, k = maps.shape
    horizon = actions.shape[0]
    ov_cell = np.full((r_count, max(horizon, 1)), -1, dtype=np.int64)
    ov_val = np.empty((r_count, max(horizon, 1), k))
    ov_stamp = np.zeros((r_count, max(horizon, 1)), dtype=np.int64)
    ov_n = np.zeros(r_count, dtype=np.int64)
    loc = locations.copy()
    lw = log_weights.copy()
    weights = np.exp(lw)
    labels = hyp_labels.copy()
    where = hyp_location
    location = np.empty(n_cells)
    mixture = np.empty((n_cells, k))
    here_m = np.empty(k)
    there_m = np.empty(k)
    scratch = np.empty(k)
    scratch2 = np.empty(k)
    if checkpoints[0]:
        out[0] = _uncertainty(loc, maps, weights, ov_cell, ov_val, ov_stamp, ov_n, powers, dynamic, np.int64(0),
                              location_weight, location, mixture, scratch, scratch2)  # int64: one compile
    for h in range(1, horizon + 1):
        a = actions[h - 1]
        if world_uniforms[h - 1, 0] < p_move:
            where = moves[a, where]
        if dynamic:
            for i in range(n_cells):
                labels[i] = draw(change_cdf[labels[i]], change_uniforms[h - 1, i])
        z = draw(sensor_cdf[labels[where]], world_uniforms[h - 1, 1])
        lik = likelihood[z]
        top = -np.inf
        for p in range(r_count):
            here = loc[p]
            there = moves[a, here]
            _current(maps, ov_cell, ov_val, ov_stamp, ov_n, powers, dynamic, p, here, h, here_m)
            lam_here = 0.0
            for b in range(k):
                lam_here += here_m[b] * lik[b]
            target = here
            lam = lam_here
            weight = lam_here
            if there != here:
                _current(maps, ov_cell, ov_val, ov_stamp, ov_n, powers, dynamic, p, there, h, there_m)
                lam_there = 0.0
                for b in range(k):
                    lam_there += there_m[b] * lik[b]
                move = p_move * lam_there
                weight = move + (1.0 - p_move) * lam_here
                if proposal_uniforms[h - 1, p] * weight < move:
                    target = there
                    lam = lam_there
                    for b in range(k):
                        here_m[b] = there_m[b]
            if weight > 0.0 and lw[p] > -np.inf:
                lw[p] += math.log(weight)
            else:
                lw[p] = -np.inf
            loc[p] = target
            slot = -1
            for j in range(ov_n[p]):
                if ov_cell[p, j] == target:
                    slot = j
            if slot < 0:
                slot = ov_n[p]
                ov_n[p] += 1
                ov_cell[p, slot] = target
            for b in range(k):
                ov_val[p, slot, b] = here_m[b] * lik[b] / lam if lam > 0.0 else here_m[b]
            ov_stamp[p, slot] = h
            if lw[p] > top:
                top = lw[p]
        normalise(lw, top, -np.inf)
        for p in range(r_count):
            weights[p] = math.exp(lw[p])
        if checkpoints[h]:
            out[h] = _uncertainty(loc, maps, weights, ov_cell, ov_val, ov_stamp, ov_n, powers, dynamic, h,
                                  location_weight, location, mixture, scratch, scratch2)
