"""The MDP over cells and its exact solution by policy iteration.

States are the cells, actions the model's actions, transitions the motion model
``T[a, l, j]`` (sparse: ``model.self_prob`` and ``model.neighbors``), discount ``gamma``.

Reward convention: ``R(j)`` is the reward for *being in* cell ``j`` after a move, so

    Q(l, a) = sum_j T[a, l, j] (R(j) + gamma V(j)),    V(l) = max_a Q(l, a).

The reward of the cell the robot starts in is not counted (it has been collected already).

``passable`` (N,), optional everywhere: the probability that each cell can be entered (the belief's
expected passability in a world with blocking labels, :mod:`policies.passability`); the move from
``l`` to its neighbour ``j`` then succeeds with ``p_move * passable[j]`` and the robot stays
otherwise. None: the design's motion (every cell enterable), bit for bit as before.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import spsolve

try:  # SuperLU's driver, the one spsolve calls; without spsolve's per-call checks and conversions
    from scipy.sparse.linalg._dsolve._superlu import gssv as _gssv
except ImportError:  # pragma: no cover - a SciPy that moved it: spsolve, the same solve
    _gssv = None

from onlinemap.errors import ModelError
from onlinemap.model import GridModel


class PolicyIterationResult(NamedTuple):
    """Solution of the cell MDP. N cells, A actions."""

    value: np.ndarray  # (N,) V of the returned policy (optimal)
    q: np.ndarray  # (N, A) Q(l, a) with the convention above
    policy: np.ndarray  # (N,) int64 greedy action per cell
    iterations: int  # number of policy evaluations performed


def move_probabilities(model: GridModel, passable: np.ndarray) -> np.ndarray:
    """(N, A) ``p_move * passable[neighbors[l, a]]``, 0 where the move leaves the grid. O(N A)."""
    moves = model.neighbors != np.arange(model.n_cells)[:, None]
    return np.where(moves, model.p_move * np.asarray(passable, dtype=np.float64)[model.neighbors], 0.0)


def action_values(model: GridModel, reward: np.ndarray, value: np.ndarray, gamma: float,
                  passable: np.ndarray | None = None) -> np.ndarray:
    """(N, A) ``Q(l, a) = sum_j T[a, l, j] (R(j) + gamma V(j))`` for every cell and action, O(N A)."""
    future = reward + gamma * value  # (N,)
    if passable is not None:
        go = move_probabilities(model, passable)
        return (1.0 - go) * future[:, None] + go * future[model.neighbors]
    # a blocked move leaves the robot in place (neighbors[l, a] == l): both terms are future[l]
    return (1.0 - model.p_move) * future[:, None] + model.p_move * future[model.neighbors]


def _policy_rows(model: GridModel, policy: np.ndarray,
                 passable: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Row l of ``T_pi`` as two (column, probability) pairs: (N, 2) columns sorted within each
    row, (N, 2) probabilities, (N, 2) mask of the pairs that exist (a cell that cannot move
    has only its diagonal)."""
    n = model.n_cells
    cells = np.arange(n)
    targets = model.neighbors[cells, policy]
    moves = targets != cells
    if passable is None:
        stay, go = model.self_prob[policy, cells], np.where(moves, model.p_move, 0.0)
    else:  # move_probabilities' entries for the policy's actions
        go = np.where(moves, model.p_move * passable[targets], 0.0)
        stay = 1.0 - go
    swap = targets < cells  # the move's column comes first in the row
    cols = np.empty((n, 2), dtype=np.int64)
    np.minimum(cells, targets, out=cols[:, 0])
    np.maximum(cells, targets, out=cols[:, 1])
    probs = np.empty((n, 2))
    probs[:, 0] = np.where(swap, go, stay)
    probs[:, 1] = np.where(swap, stay, go)
    keep = np.ones((n, 2), dtype=np.bool_)
    keep[:, 1] = moves  # a swapped row has a move, so both its pairs exist
    return cols, probs, keep


def _csr(cols: np.ndarray, values: np.ndarray, keep: np.ndarray) -> sp.csr_array:
    """CSR (N, N) matrix from per-row (column, value) pairs, without a COO round trip."""
    n = cols.shape[0]
    return sp.csr_array((values[keep], cols[keep], _row_pointers(keep, np.int64)), shape=(n, n))


def _row_pointers(keep: np.ndarray, dtype) -> np.ndarray:
    """(N + 1,) CSR row pointers of the per-row pairs ``keep`` (N, 2) marks as present."""
    indptr = np.zeros(keep.shape[0] + 1, dtype=dtype)
    np.cumsum(keep.sum(axis=1), out=indptr[1:])
    return indptr


def policy_motion(model: GridModel, policy: np.ndarray, passable: np.ndarray | None = None) -> sp.csr_array:
    """Sparse (N, N) ``T_pi[l, j] = T[policy[l], l, j]``; at most 2 entries per row. O(N)."""
    cols, probs, keep = _policy_rows(model, np.asarray(policy), passable)
    return _csr(cols, probs, keep)


def evaluate_policy(model: GridModel, reward: np.ndarray, policy: np.ndarray, gamma: float,
                    passable: np.ndarray | None = None) -> np.ndarray:
    """(N,) exact ``V_pi``: solves ``(I - gamma T_pi) V = T_pi R`` with a sparse LU (``spsolve``).

    The system is built directly in CSR form (at most 2 N non-zeros); on grids the
    factorisation costs about O(N^1.5)."""
    policy = np.asarray(policy)
    cols, probs, keep = _policy_rows(model, policy, passable)
    diagonal = cols == np.arange(model.n_cells)[:, None]
    rhs = (probs * reward[cols]).sum(axis=1)
    return _solve_csr(cols, diagonal - gamma * probs, keep, rhs)


def _solve_csr(cols: np.ndarray, values: np.ndarray, keep: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """(N,) solution of the CSR system of :func:`_csr` (rows sorted, no duplicates) for ``rhs``
    (N,): SuperLU with spsolve's arguments (CSR, COLAMD ordering), so bit for bit spsolve's
    answer, without building a ``csr_array`` (its checks cost more than the solve on a 10 x 10
    grid). A singular system (never for gamma < 1) goes to spsolve, which warns and gives NaN."""
    n = cols.shape[0]
    if _gssv is not None:
        data = values[keep]
        x, info = _gssv(n, data.shape[0], data, cols[keep].astype(np.intc), _row_pointers(keep, np.intc), rhs, 0,
                        options={"ColPerm": None})
        if info == 0:
            return x
    return np.asarray(spsolve(_csr(cols, values, keep), rhs), dtype=np.float64)


def _check_passable(model: GridModel, passable) -> np.ndarray | None:
    if passable is None:
        return None
    passable = np.asarray(passable, dtype=np.float64)
    if passable.shape != (model.n_cells,) or not np.all((passable >= 0.0) & (passable <= 1.0)):
        raise ModelError(f"passable must be ({model.n_cells},) probabilities in [0, 1] (one per cell)")
    return passable


def _check(model: GridModel, reward, gamma: float, initial_policy) -> tuple[np.ndarray, float, np.ndarray]:
    reward = np.asarray(reward, dtype=np.float64)
    if reward.shape != (model.n_cells,):
        raise ModelError(f"reward must have shape ({model.n_cells},) (one value per cell), got {reward.shape}")
    if not np.all(np.isfinite(reward)):
        raise ModelError("reward contains NaN or infinite values")
    gamma = float(gamma)
    if not 0.0 <= gamma < 1.0:
        raise ModelError(f"the discount gamma must be in [0, 1), got {gamma!r}")
    if initial_policy is None:
        return reward, gamma, None
    policy = np.array(initial_policy, dtype=np.int64)
    if policy.shape != (model.n_cells,) or np.any(policy < 0) or np.any(policy >= model.n_actions):
        raise ModelError(f"initial_policy must be ({model.n_cells},) actions in 0..{model.n_actions - 1}")
    return reward, gamma, policy


def policy_iteration(model: GridModel, reward, gamma: float = 0.95, *, initial_policy=None,
                     max_iterations: int = 1000, tolerance: float = 1e-10,
                     passable: np.ndarray | None = None) -> PolicyIterationResult:
    """Solve the cell MDP: exact evaluation of the current policy (one sparse linear solve),
    greedy improvement, until the policy no longer changes.

    reward: (N,) ``R(j)`` for being in cell ``j``; gamma in [0, 1). ``initial_policy`` (N,)
    warm-starts the iteration (e.g. the previous plan when the reward changed a little). By
    default the start is the policy greedy for ``rows + cols`` value-iteration sweeps from
    ``V = 0``: information about a distant reward travels one cell per improvement step, and a
    sweep (O(N A), vectorised) costs about a tenth of a sparse solve, so a 64 x 64 grid with a
    single rewarding cell takes 1 evaluation instead of 126. This only chooses the start; the
    result is the exact optimum either way. An action is replaced only if another is better
    by more than ``tolerance * (1 + |Q|)``, so ties cannot make it cycle. ``passable`` (N,):
    the motion of a world with blocking labels (module docstring); None: the design's motion.

    Cost per iteration: one sparse LU solve plus O(N A); a handful of iterations in practice.
    """
    reward, gamma, policy = _check(model, reward, gamma, initial_policy)
    passable = _check_passable(model, passable)
    if policy is None:
        value = np.zeros_like(reward)
        for _ in range(model.rows + model.cols):
            value = action_values(model, reward, value, gamma, passable).max(axis=1)
        policy = np.argmax(action_values(model, reward, value, gamma, passable), axis=1)
    cells = np.arange(model.n_cells)
    for iteration in range(1, int(max_iterations) + 1):
        value = evaluate_policy(model, reward, policy, gamma, passable)
        q = action_values(model, reward, value, gamma, passable)
        best = np.argmax(q, axis=1)
        current = q[cells, policy]
        better = q[cells, best] > current + tolerance * (1.0 + np.abs(current))
        if not better.any():
            return PolicyIterationResult(value, q, policy, iteration)
        policy = np.where(better, best, policy)
    raise RuntimeError(f"policy iteration did not converge in {max_iterations} iterations")
