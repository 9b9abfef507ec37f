"""numba kernel of the information-gain planner (``policies/info_gain.py``): roll an action
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


@njit(cache=True)
def _draw(cdf_row, u):
    """Index of the first entry of the cumulative row ``cdf_row`` above ``u``."""
    k = cdf_row.shape[0]
    for b in range(k - 1):
        if u < cdf_row[b]:
            return b
    return k - 1


@njit(cache=True)
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
def _entropy(row):
    acc = 0.0
    for x in row:
        if x > 0.0:
            acc -= x * math.log(x)
    return acc


@njit(cache=True)
def _uncertainty(locations, maps, weights, ov_cell, ov_val, ov_stamp, ov_n, powers, dynamic, h,
                 location_weight, n_cells, mixture, scratch, scratch2):
    """``location_weight * H(L) + sum_i H(M_i)`` of the weighted particles after h steps.
    O(R N K + N K^2 + R H K^2)."""
    r_count, _, k = maps.shape
    location = np.zeros(n_cells)
    mixture[:] = 0.0
    for p in range(r_count):
        w = weights[p]
        if w == 0.0:
            continue
        location[locations[p]] += w
        for i in range(n_cells):
            for b in range(k):
                mixture[i, b] += w * maps[p, i, b]
    if dynamic and h > 0:
        for i in range(n_cells):
            for b in range(k):
                acc = 0.0
                for a in range(k):
                    acc += mixture[i, a] * powers[h, a, b]
                scratch[b] = acc
            mixture[i] = scratch
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
    total = location_weight * _entropy(location)
    for i in range(n_cells):
        for b in range(k):  # rounding: keep every term a probability
            if mixture[i, b] < 0.0:
                mixture[i, b] = 0.0
        total += _entropy(mixture[i])
    return total


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
    mixture = np.empty((n_cells, k))
    here_m = np.empty(k)
    there_m = np.empty(k)
    scratch = np.empty(k)
    scratch2 = np.empty(k)
    if checkpoints[0]:
        out[0] = _uncertainty(loc, maps, weights, ov_cell, ov_val, ov_stamp, ov_n, powers, dynamic, 0,
                              location_weight, n_cells, mixture, scratch, scratch2)
    for h in range(1, horizon + 1):
        a = actions[h - 1]
        if world_uniforms[h - 1, 0] < p_move:
            where = moves[a, where]
        if dynamic:
            for i in range(n_cells):
                labels[i] = _draw(change_cdf[labels[i]], change_uniforms[h - 1, i])
        z = _draw(sensor_cdf[labels[where]], world_uniforms[h - 1, 1])
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
        if top == -np.inf:  # the hypothesis left every particle behind: keep them, equally weighted
            lw[:] = 0.0
            top = 0.0
        total = 0.0
        for p in range(r_count):
            total += math.exp(lw[p] - top)
        norm = top + math.log(total)
        for p in range(r_count):
            lw[p] -= norm
            weights[p] = math.exp(lw[p])
        if checkpoints[h]:
            out[h] = _uncertainty(loc, maps, weights, ov_cell, ov_val, ov_stamp, ov_n, powers, dynamic, h,
                                  location_weight, n_cells, mixture, scratch, scratch2)


# --- shortest expected paths (policies/passability.py) ------------------------------------------
@njit(cache=True)
def _heap_push(keys, items, size, key, item):
    """Push (key, item) onto the binary min-heap held in ``keys[:size]``, ``items[:size]``."""
    i = size
    keys[i] = key
    items[i] = item
    while i > 0:
        parent = (i - 1) // 2
        if keys[parent] <= keys[i]:
            break
        keys[parent], keys[i] = keys[i], keys[parent]
        items[parent], items[i] = items[i], items[parent]
        i = parent
    return size + 1


@njit(cache=True)
def _heap_pop(keys, items, size):
    """Remove the smallest key of the heap (read it from ``keys[0]``, ``items[0]`` first)."""
    size -= 1
    keys[0] = keys[size]
    items[0] = items[size]
    i = 0
    while True:
        left = 2 * i + 1
        smallest = i
        if left < size and keys[left] < keys[smallest]:
            smallest = left
        if left + 1 < size and keys[left + 1] < keys[smallest]:
            smallest = left + 1
        if smallest == i:
            return size
        keys[smallest], keys[i] = keys[i], keys[smallest]
        items[smallest], items[i] = items[i], items[smallest]
        i = smallest


@njit(cache=True)
def shortest_paths(adjacent, enter_cost, distance, forward):
    """Dijkstra from every cell with a finite ``distance`` (its start value, e.g. 0 at the sources)
    over the graph whose edges are ``u -> adjacent[a, u]`` for every action a (an entry equal to u
    or negative is no edge), edge ``u -> v`` costing ``enter_cost[v]`` (inf: no edge).

    ``forward`` True: ``distance[v]`` <- min over sources s of start(s) + the cheapest path s -> v
    (``adjacent`` = the moves, (A, N)). False: the same over reversed edges, ``distance[u]`` <- the
    cheapest path from u to a source (``adjacent`` = the predecessors, (A, N): ``adjacent[a, v]`` is
    the cell that moves into v under a, and an edge settled from v costs ``enter_cost[v]``).
    ``enter_cost`` (N,) must be >= 0. In place on ``distance`` (N,). Cost O(N A log(N A)).
    """
    n_actions, n_cells = adjacent.shape
    capacity = n_cells * (n_actions + 1)
    keys = np.empty(capacity)
    items = np.empty(capacity, dtype=np.int64)
    done = np.zeros(n_cells, dtype=np.bool_)
    size = 0
    for u in range(n_cells):
        if distance[u] < np.inf:
            size = _heap_push(keys, items, size, distance[u], u)
    while size > 0:
        d = keys[0]
        u = items[0]
        size = _heap_pop(keys, items, size)
        if done[u]:
            continue
        done[u] = True
        for a in range(n_actions):
            v = adjacent[a, u]
            if v < 0 or v == u or done[v]:
                continue
            step = enter_cost[v] if forward else enter_cost[u]
            if d + step < distance[v]:
                distance[v] = d + step
                size = _heap_push(keys, items, size, distance[v], v)
    return distance
