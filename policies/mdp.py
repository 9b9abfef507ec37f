"""The MDP over cells and its exact solution by policy iteration.

States are the cells, actions the model's actions, transitions the motion model
``T[a, l, j]`` (sparse: ``model.self_prob`` and ``model.neighbors``), discount ``gamma``.

Reward convention: ``R(j)`` is the reward for *being in* cell ``j`` after a move, so

    Q(l, a) = sum_j T[a, l, j] (R(j) + gamma V(j)),    V(l) = max_a Q(l, a).

The reward of the cell the robot starts in is not counted (it has been collected already).

``passable`` (N,), optional everywhere: the probability that each cell can be entered (the belief's
expected passability in a world with blocking labels, :mod:`policies.passability`); the move from
``l`` to its neighbour ``j`` then succeeds with ``p_move * passable[j]`` and the robot stays
otherwise. None: the design's motion (every cell enterable), computed with no passable factor at
all (not a factor of 1.0), so the paper's planner does not depend on this option's arithmetic.
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

from onlinemap.errors import InvalidOptionError, ModelError
from .kernels.mdp import action_values as kernel_action_values
from .kernels.mdp import improve_policy, policy_rows
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
    """(N, A) ``Q(l, a) = sum_j T[a, l, j] (R(j) + gamma V(j))`` for every cell and action, O(N A):
    ``(1 - g) F(l) + g F(j)`` with ``F = R + gamma V`` and g the move's probability
    (:func:`move_probabilities`; with no ``passable``, ``p_move`` for every action, a blocked move
    staying in place). A numba kernel (:func:`policies.kernels.mdp.action_values`)."""
    q = np.empty((model.n_cells, model.n_actions))
    kernel_action_values(model.neighbors, model.p_move, _passable_array(passable), np.asarray(reward, dtype=np.float64),
                         np.asarray(value, dtype=np.float64), float(gamma), q)
    return q


_NO_PASSABLE = np.empty(0)  # the kernels' "None": the design's motion


def _passable_array(passable) -> np.ndarray:
    return _NO_PASSABLE if passable is None else np.asarray(passable, dtype=np.float64)


def _policy_rows(model: GridModel, policy: np.ndarray, passable: np.ndarray, gamma: float = 0.0,
                 reward: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The CSR (N, N) ``T_pi`` (``reward`` None) or ``I - gamma T_pi`` and ``T_pi R`` (N,)
    (:func:`policies.kernels.mdp.policy_rows`): data (E,), int32 columns (E,), int32 row
    pointers (N + 1,), the right-hand side (N,). At most 2 N entries, O(N)."""
    n = model.n_cells
    data, cols, indptr, rhs = np.empty(2 * n), np.empty(2 * n, dtype=np.intc), np.empty(n + 1, dtype=np.intc), np.empty(n)
    system = reward is not None
    count = policy_rows(model.neighbors, model.self_prob, model.p_move, passable, policy, float(gamma), system, data,
                        cols, indptr, rhs, reward if system else rhs)
    return data[:count], cols[:count], indptr, rhs


def policy_motion(model: GridModel, policy: np.ndarray, passable: np.ndarray | None = None) -> sp.csr_array:
    """Sparse (N, N) ``T_pi[l, j] = T[policy[l], l, j]``; at most 2 entries per row. O(N)."""
    data, cols, indptr, _ = _policy_rows(model, np.asarray(policy, dtype=np.int64), _passable_array(passable))
    return sp.csr_array((data, cols, indptr), shape=(model.n_cells, model.n_cells))


def evaluate_policy(model: GridModel, reward: np.ndarray, policy: np.ndarray, gamma: float,
                    passable: np.ndarray | None = None) -> np.ndarray:
    """(N,) exact ``V_pi``: solves ``(I - gamma T_pi) V = T_pi R`` with a sparse LU (``spsolve``).

    The system is built directly in CSR form (at most 2 N non-zeros, a numba kernel); on grids the
    factorisation costs about O(N^1.5)."""
    return _value(model, np.asarray(reward, dtype=np.float64), np.asarray(policy, dtype=np.int64), float(gamma),
                  _passable_array(passable))


def _value(model: GridModel, reward: np.ndarray, policy: np.ndarray, gamma: float, passable: np.ndarray) -> np.ndarray:
    """:func:`evaluate_policy` on checked arrays (``passable`` empty for the design's motion)."""
    return _solve_csr(*_policy_rows(model, policy, passable, gamma, reward))


def _solve_csr(data: np.ndarray, cols: np.ndarray, indptr: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """(N,) solution of the CSR system of :func:`_policy_rows` (rows sorted, no duplicates) for
    ``rhs`` (N,): SuperLU with spsolve's arguments (CSR, COLAMD ordering), so bit for bit
    spsolve's answer, without building a ``csr_array`` (its checks cost more than the solve on a
    10 x 10 grid). A singular system (never for gamma < 1) goes to spsolve, which warns and gives NaN."""
    n = rhs.shape[0]
    if _gssv is not None:
        x, info = _gssv(n, data.shape[0], data, cols, indptr, rhs, 0, options={"ColPerm": None})
        if info == 0:
            return x
    return np.asarray(spsolve(sp.csr_array((data, cols, indptr), shape=(n, n)), rhs), dtype=np.float64)


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
        raise InvalidOptionError(f"the discount gamma must be in [0, 1), got {gamma!r}")
    if initial_policy is None:
        return reward, gamma, None
    policy = np.array(initial_policy, dtype=np.int64)
    if policy.shape != (model.n_cells,) or np.any(policy < 0) or np.any(policy >= model.n_actions):
        raise InvalidOptionError(f"initial_policy must be ({model.n_cells},) actions in 0..{model.n_actions - 1}")
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
    moves = _passable_array(passable)
    q = np.empty((model.n_cells, model.n_actions))
    for iteration in range(1, int(max_iterations) + 1):
        value = _value(model, reward, policy, gamma, moves)
        if not improve_policy(model.neighbors, model.p_move, moves, reward, value, gamma, float(tolerance), q, policy):
            return PolicyIterationResult(value, q, policy, iteration)
    raise RuntimeError(f"policy iteration did not converge in {max_iterations} iterations")
