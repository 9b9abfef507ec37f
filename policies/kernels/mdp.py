"""numba kernels of policy iteration on the cell MDP (``policies/mdp.py``): a policy's sparse system
and the greedy improvement. The sparse solve between them stays SuperLU's (``policies.mdp``).

Shapes: N cells, A actions. The topology is the model's ``neighbors (N, A)`` (a move that stays is
``neighbors[l, a] == l``) and ``self_prob (A, N)`` (``T[a, l, l]``). ``passable`` (N,) is the
chance each cell can be entered, or empty (0,) for the design's motion (every cell enterable).
Both kernels compute each entry with the same operations, in the same order, as the numpy
expressions in ``policies/mdp.py``'s docstrings, so the results are the same bit for bit.
"""

from __future__ import annotations

import math

from numba import njit


@njit(cache=True)
def policy_rows(neighbors, self_prob, p_move, passable, policy, gamma, system, data, cols, indptr, rhs, reward):
    """The policy's transition matrix ``T_pi[l, j] = T[policy[l], l, j]`` in CSR form (rows sorted,
    one entry per row for a cell whose action stays, two otherwise): ``cols`` (2N,) int32,
    ``indptr`` (N + 1,) int32; returns the number of entries E. ``system`` False: ``data[:E]`` the
    probabilities. ``system`` True: ``data[:E]`` those of ``I - gamma T_pi`` and ``rhs`` (N,)
    ``T_pi R`` (``reward`` (N,)), the system of the policy's value. The move from l to its
    neighbour j succeeds with ``p_move`` (``p_move passable[j]`` with ``passable``). O(N)."""
    n = neighbors.shape[0]
    count = 0
    indptr[0] = 0
    for l in range(n):
        j = neighbors[l, policy[l]]
        moves = j != l
        if passable.shape[0] == 0:
            stay = self_prob[policy[l], l]
            go = p_move if moves else 0.0
        else:
            go = p_move * passable[j] if moves else 0.0
            stay = 1.0 - go
        first, second = (j, l) if j < l else (l, j)
        p_first, p_second = (go, stay) if j < l else (stay, go)
        if system:
            rhs[l] = p_first * reward[first] + p_second * reward[second]
            data[count] = (1.0 if first == l else 0.0) - gamma * p_first
        else:
            data[count] = p_first
        cols[count] = first
        count += 1
        if moves:
            data[count] = (1.0 if second == l else 0.0) - gamma * p_second if system else p_second
            cols[count] = second
            count += 1
        indptr[l + 1] = count
    return count


@njit(cache=True)
def action_values(neighbors, p_move, passable, reward, value, gamma, q):
    """``q`` (N, A) <- ``Q(l, a) = (1 - g) F(l) + g F(j)``, ``F = R + gamma V`` (``reward``,
    ``value`` (N,)), j the action's neighbour, g its move probability (``p_move``; with
    ``passable``, ``p_move passable[j]`` for a move and 0 for a stay). O(N A)."""
    n, actions = neighbors.shape
    for l in range(n):
        future_l = reward[l] + gamma * value[l]
        for a in range(actions):
            j = neighbors[l, a]
            future_j = reward[j] + gamma * value[j]
            if passable.shape[0] == 0:
                q[l, a] = (1.0 - p_move) * future_l + p_move * future_j
            else:
                go = p_move * passable[j] if j != l else 0.0
                q[l, a] = (1.0 - go) * future_l + go * future_j


@njit(cache=True)
def improve_policy(neighbors, p_move, passable, reward, value, gamma, tolerance, q, policy):
    """:func:`action_values` into ``q``, then ``policy`` (N,) <- the greedy action (the first best,
    NaN counting as best, as ``np.argmax``) where it beats the policy's own by more than
    ``tolerance (1 + |Q|)``. Returns whether any action changed. O(N A)."""
    action_values(neighbors, p_move, passable, reward, value, gamma, q)
    changed = False
    for l in range(q.shape[0]):
        best = 0
        if not math.isnan(q[l, 0]):
            for a in range(1, q.shape[1]):
                if math.isnan(q[l, a]):
                    best = a
                    break
                if q[l, a] > q[l, best]:
                    best = a
        current = q[l, policy[l]]
        if q[l, best] > current + tolerance * (1.0 + abs(current)):
            policy[l] = best
            changed = True
    return changed
