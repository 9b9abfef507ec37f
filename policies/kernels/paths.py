"""numba kernel of the shortest expected paths (``policies/passability.py``): Dijkstra over the
cells with a binary heap, any enter costs.
"""

from __future__ import annotations

import numpy as np
from numba import njit


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
    size = np.int64(0)  # not a literal 0: the heap's functions compile once, for int64
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
