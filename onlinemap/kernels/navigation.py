"""numba kernel of the goal planner (``policies/navigation.py``): backward value iteration over
(cell, step) with time-dependent passability.

Shapes: H + 1 steps of passability, N cells, A actions. The topology is the model's
``neighbors (N, A)`` (a move that stays is ``neighbors[l, a] == l``).
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def goal_value_iteration(passable, neighbors, p_move, goal, terminal, action_cost):
    """Backward value iteration to ``goal`` from the value ``terminal`` (N,) at step H.

    ``passable`` (H + 1, N): the probability that each cell is passable for the move made
    ``tau`` steps from now (row H only matters through ``terminal``). For ``tau = H' - 1 .. 0``
    with ``H' = max(H, 1)``:
    ``Q(l, a) = 1 + p V(j) + (1 - p) V(l)``, ``j = neighbors[l, a]``, ``p = p_move passable[tau, j]``
    (0 where ``j == l``), ``Q(goal, .) = 0``, ``V(l) = min_a Q(l, a)``. Writes ``Q`` of step 0
    into ``action_cost`` (N, A) and returns ``V`` of step 0 (N,). Values must be finite (the
    caller caps unreachable cells). O(H N A) time, O(N) extra memory."""
    n, a_count = neighbors.shape
    value = terminal.copy()
    following = np.empty(n)
    for tau in range(max(passable.shape[0] - 1, 1) - 1, -1, -1):
        for l in range(n):
            best = np.inf
            for a in range(a_count):
                j = neighbors[l, a]
                if l == goal:
                    cost = 0.0
                elif j == l:
                    cost = 1.0 + value[l]
                else:
                    p = p_move * passable[tau, j]
                    cost = 1.0 + p * value[j] + (1.0 - p) * value[l]
                if tau == 0:
                    action_cost[l, a] = cost
                if cost < best:
                    best = cost
            following[l] = best
        value, following = following, value
    return value
