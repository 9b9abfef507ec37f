"""numba kernel of the goal planner (``policies/navigation.py``): backward value iteration over
(cell, step) in which a move is a commitment to enter the intended cell, whose label evolves by
the map dynamics C while the robot presses into it.

Shapes: H + 1 steps, N cells, A actions, K labels. The topology is the model's
``neighbors (N, A)`` (a move that stays is ``neighbors[l, a] == l``).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from onlinemap.kernels import loop_kernel


@njit(cache=True)
def goal_value_iteration(arrival, change, passable, permanent, neighbors, p_move, goal, terminal,
                         terminal_commit, never, action_cost):
    """Backward value iteration to ``goal`` from step H (``terminal`` V (N,), ``terminal_commit``
    G (N, K)) down to step 0; writes Q of step 0 into ``action_cost`` (N, A), returns V of step 0.

    ``arrival`` (H + 1, N, K) the label marginals of each cell tau steps from now, ``change`` C,
    ``passable`` (K,) 1.0 for labels that let the robot in, ``permanent`` (K,) labels that never
    become passable. For tau = H' - 1 .. 0 (H' = max(H, 1)), with m = arrival[tau, j]:

    - ``G(j, k) = 1 + p_k V'(j) + (1 - p_k) sum_k' C[k, k'] G'(j, k')``, ``p_k = p_move passable[k]``:
      the expected steps of pressing into j until entered, j's label k now (``never`` for a
      permanent label: pressed for ever); primes are step tau + 1;
    - entering j from l: ``Q(l, a) = s (1 + V'(l)) + sum_{k not permanent} m_k G(j, k)`` with
      ``s = sum_{k permanent} m_k`` (a wall costs one failed step, then the robot re-plans);
      staying (``j == l``): ``1 + V'(l)``; ``Q(goal, .) = 0``; ``V(l) = min_a Q(l, a)``.

    Every value is capped at ``never``. O(H N (K^2 + A)) time, O(N K) extra memory."""
    n = neighbors.shape[0]
    k_count = arrival.shape[2]
    value = terminal.copy()
    commit = terminal_commit.copy()
    new_value = np.empty(n)
    new_commit = np.empty((n, k_count))
    enter = np.empty(n)
    blocked = np.empty(n)
    for tau in range(max(arrival.shape[0] - 1, 1) - 1, -1, -1):
        _commit_step(arrival[tau], change, passable, permanent, p_move, never, value, commit, new_commit, enter,
                     blocked)
        _value_step(neighbors, goal, never, tau, value, enter, blocked, new_value, action_cost)
        value, new_value = new_value, value
        commit, new_commit = new_commit, commit
    return value


@loop_kernel
def _commit_step(arrival, change, passable, permanent, p_move, never, value, commit, new_commit, enter, blocked):
    """One step back of :func:`goal_value_iteration`'s commitments: ``new_commit`` G (N, K) from
    the next step's ``value`` V' and ``commit`` G'; ``enter[j] = sum_{k not permanent} m_k G(j,
    k)`` and ``blocked[j] = sum_{k permanent} m_k`` for m = ``arrival[j]`` (N, K) this step's
    marginals. O(N K^2)."""
    n, k_count = arrival.shape
    for j in range(n):
        for k in range(k_count):
            if permanent[k]:
                new_commit[j, k] = never
                continue
            p = p_move * passable[k]
            acc = 0.0
            for k2 in range(k_count):
                c = change[k, k2]
                if c != 0.0:
                    acc += c * commit[j, k2]
            new_commit[j, k] = min(1.0 + p * value[j] + (1.0 - p) * acc, never)
        entering = 0.0
        wall = 0.0
        for k in range(k_count):
            m = arrival[j, k]
            if permanent[k]:
                wall += m
            else:
                entering += m * new_commit[j, k]
        enter[j] = entering
        blocked[j] = wall


@loop_kernel
def _value_step(neighbors, goal, never, tau, value, enter, blocked, new_value, action_cost):
    """One step back of :func:`goal_value_iteration`'s values: ``new_value`` V (N,) from the next
    step's ``value`` V' and this step's ``enter`` and ``blocked`` (:func:`_commit_step`); at step
    0 (``tau == 0``) Q into ``action_cost`` (N, A). O(N A)."""
    n, a_count = neighbors.shape
    for l in range(n):
        best = np.inf
        for a in range(a_count):
            j = neighbors[l, a]
            if l == goal:
                cost = 0.0
            elif j == l:
                cost = 1.0 + value[l]
            else:
                cost = blocked[j] * (1.0 + value[l]) + enter[j]
            cost = min(cost, never)
            if tau == 0:
                action_cost[l, a] = cost
            if cost < best:
                best = cost
        new_value[l] = best
