"""Navigation through a changing building (Thrun, Burgard and Fox, section 4; DESIGN.md section 8):
shortest expected paths to a goal by dynamic programming over the belief's passability,
re-planned every step.

The cost model. From cell ``l`` the action ``a`` aims at ``j = neighbors[l, a]``; the move
succeeds with ``p_move`` times the probability that ``j`` is passable when the move is made,
otherwise the robot stays (the model's blocking semantics, DESIGN.md section 7; a move off the
grid always stays). Every step costs 1; standing on the goal ends the task. The move made ``tau``
steps from now (``tau = 0``: the next action, judged on the labels of now) meets cell ``i``
passable with

    q[tau, i] = sum_k (M C^tau)[i, k] [k does not block],    M (N, K) the map marginals,

so a door believed closed now may have reopened by the time the robot gets there, and a door far
away counts with its long-run passability. Each attempt is one independent draw from these
marginals (the expected-passability reading of the integrated occupancy map): the plan is
optimistic about pressing again into a cell that just refused the robot, and the belief corrects
it, because a failed move is evidence that the estimator folds into the map before the next plan.

Value iteration over (cell, time):

    V[tau](goal) = 0,
    V[tau](l) = min_a Q[tau](l, a),   Q[tau](l, a) = 1 + p V[tau+1](j) + (1 - p) V[tau+1](l),
                                       p = p_move q[tau, j] (0 where j == l),

with ``V[tau] = V[H]`` for ``tau >= H``: beyond the horizon ``H`` the passabilities are frozen at
``q[H]``, and ``V[H]`` is that stationary problem's exact solution, a shortest path with edge cost
``1 / (p_move q[H, j])`` into ``j`` (Dijkstra). Pressing into a door is how the robot waits: the
move fails while the door is closed, so the robot waits exactly when that is expected to be
cheaper than the detour. The action under location uncertainty is
``argmin_a sum_l P(l) Q[0](l, a)`` with ``Q[0](goal, .) = 0`` (a hypothesis that is already at
the goal has nothing left to pay); ties go to the lowest action index.

Costs, N cells, A actions, K labels, H the horizon: passabilities O(H K^2 + H N K), Dijkstra
O(N A log N), value iteration O(H N A); memory O(H N) for ``q`` plus O(N A). In a static world
(C the identity) or wherever C leaves the labels' passability fixed, ``H`` drops to 0 and a plan
is one Dijkstra.
"""

from __future__ import annotations

import numbers
from typing import NamedTuple

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import breadth_first_order, dijkstra

from onlinemap.belief import Belief
from onlinemap.errors import ModelError
from onlinemap.kernels.navigation import goal_value_iteration
from onlinemap.model import GridModel

NEVER = 1e9  # steps charged, in the action choice, for a cell from which the goal cannot be reached


def goal_cell(model: GridModel, goal) -> int:
    """The cell index of ``goal``: an index in ``0..N-1`` or a ``(row, col)`` pair on the grid.
    Anything else, or a goal off the grid, raises ModelError naming the goal."""
    if isinstance(goal, numbers.Integral) and not isinstance(goal, (bool, np.bool_)):
        if not 0 <= int(goal) < model.n_cells:
            raise ModelError(f"goal {goal!r} is off the grid: cells are 0..{model.n_cells - 1}")
        return int(goal)
    if isinstance(goal, (tuple, list, np.ndarray)) and len(goal) == 2 and all(
            isinstance(x, numbers.Integral) and not isinstance(x, (bool, np.bool_)) for x in goal):
        row, col = (int(x) for x in goal)
        if not (0 <= row < model.rows and 0 <= col < model.cols):
            raise ModelError(f"goal {tuple(goal)!r} (row, col) is off the {model.rows} x {model.cols} grid")
        return row * model.cols + col
    raise ModelError(f"goal must be a cell index or a (row, col) pair, got {goal!r}")


def default_horizon(model: GridModel) -> int:
    """``2 (rows + cols)``: about twice the longest shortest path of an open grid."""
    return 2 * (model.rows + model.cols)


def label_passability(model: GridModel, horizon: int) -> np.ndarray:
    """(H + 1, K) ``v[tau] = C^tau [k not blocking]``: the probability that a cell of label ``k``
    now is passable ``tau`` steps later. Stops early (fewer rows) once ``v`` is a fixed point of
    C, which it then stays: 1 row in a static world. O(H K^2)."""
    rows = [(~model.blocking).astype(np.float64)]
    for _ in range(int(horizon)):
        following = model.change @ rows[-1]
        if np.array_equal(following, rows[-1]):
            break
        rows.append(following)
    return np.stack(rows)


def passability(model: GridModel, maps: np.ndarray, horizon: int) -> np.ndarray:
    """(H' + 1, N) ``q[tau, i]``: the probability that cell ``i``, with label marginals ``maps``
    (N, K) now, is passable for the move made ``tau`` steps from now; ``H' <= horizon`` (see
    :func:`label_passability`). O(H K^2 + H N K)."""
    return label_passability(model, horizon) @ np.asarray(maps, dtype=np.float64).T


def _stationary_cost(model: GridModel, q: np.ndarray, goal: int) -> np.ndarray:
    """(N,) expected steps to ``goal`` with passabilities ``q`` (N,) held forever: the shortest
    path with cost ``1 / (p_move q[j])`` per move into ``j`` (retrying a failed move is optimal
    when nothing changes, so each edge costs its geometric number of attempts). inf where the goal
    cannot be reached. O(N A log N)."""
    n = model.n_cells
    cells = np.repeat(np.arange(n), model.n_actions)
    targets = model.neighbors.ravel()
    success = model.p_move * q[targets]
    keep = (targets != cells) & (success > 0)
    # one edge per (from, to) pair: two actions into the same cell cost the same
    pairs, first = np.unique(targets[keep] * n + cells[keep], return_index=True)
    weight = 1.0 / success[keep][first]
    reverse = sp.csr_array((weight, (pairs // n, pairs % n)), shape=(n, n))  # edge j -> l for a move l -> j
    return dijkstra(reverse, directed=True, indices=goal)


class GoalPlan(NamedTuple):
    """A plan to one goal. N cells, A actions."""

    value: np.ndarray  # (N,) expected steps from each cell now (0 at the goal, inf: never)
    q: np.ndarray  # (N, A) expected steps after taking action a now and acting optimally after
    horizon: int  # H: passabilities vary over steps 0..H-1 and are frozen from H on


def plan_to_goal(model: GridModel, maps: np.ndarray, goal: int, horizon: int | None = None) -> GoalPlan:
    """The value iteration of the module docstring for map marginals ``maps`` (N, K) and the goal
    cell ``goal`` (an index). ``horizon`` None: :func:`default_horizon`. Costs: the module's."""
    horizon = default_horizon(model) if horizon is None else horizon
    q = passability(model, maps, horizon)
    h = q.shape[0] - 1
    terminal = np.minimum(_stationary_cost(model, q[h], goal), NEVER)  # finite: 0 * NEVER is 0
    action_cost = np.empty((model.n_cells, model.n_actions))
    value = goal_value_iteration(q, model.neighbors, model.p_move, goal, terminal, action_cost)
    return GoalPlan(np.where(value >= NEVER, np.inf, value), np.where(action_cost >= NEVER, np.inf, action_cost), h)


def walls_under_prior(model: GridModel) -> np.ndarray:
    """(N,) bool: the cells that are walls under the label prior, i.e. hold with probability
    above 1/2 a label that blocks and never changes (``C[k, k] = 1``). A door believed closed
    that may reopen is not a wall; one that never changes is. O(N K)."""
    permanent = model.blocking & (np.diag(model.change) == 1.0)
    return model.label_prior[:, permanent].sum(axis=1) > 0.5


def check_goal(model: GridModel, goal) -> int:
    """The cell of ``goal`` (:func:`goal_cell`), or ModelError naming it if it is off the grid, a
    wall under the prior (:func:`walls_under_prior`), or cut off from the start cell under the
    prior (every path crosses a wall). O(N A)."""
    cell = goal_cell(model, goal)
    walls = walls_under_prior(model)
    if walls[cell]:
        permanent = model.blocking & (np.diag(model.change) == 1.0)
        raise ModelError(f"goal {goal!r} (cell {cell}) is a wall under the prior: it holds a blocking label "
                         f"that never changes with probability {model.label_prior[cell, permanent].sum():.3g}")
    n = model.n_cells
    cells = np.repeat(np.arange(n), model.n_actions)
    targets = model.neighbors.ravel()
    keep = (targets != cells) & ~walls[targets] & (model.p_move > 0)
    graph = sp.csr_array((np.ones(keep.sum()), (cells[keep], targets[keep])), shape=(n, n))
    if cell not in breadth_first_order(graph, model.start, directed=True, return_predecessors=False):
        stuck = " (p_move = 0: the robot never moves)" if model.p_move == 0 else ""
        raise ModelError(f"goal {goal!r} (cell {cell}) cannot be reached from the start cell {model.start} "
                         f"under the prior: every path crosses a wall{stuck}")
    return cell


class GoTo:
    """Go to ``goal`` (a cell index or ``(row, col)``) by the value iteration of
    :mod:`policies.navigation` on the belief's map marginals, re-planned at every call; the action
    minimises the expected steps under the location belief. ``horizon``: H (None:
    :func:`default_horizon`). A goal off the grid, a wall under the model's label prior or
    unreachable from the start under it raises ModelError naming the goal (:func:`check_goal`). Cost per call: the
    module's (a call whose marginals equal the last call's reuses its plan)."""

    def __init__(self, model: GridModel, goal=None, horizon: int | None = None):
        if goal is None:
            raise ModelError(f"{type(self).__name__} needs a goal: goal=CELL (an index or (row, col))")
        self.model = model
        self.goal = check_goal(model, goal)
        self.horizon = default_horizon(model) if horizon is None else _horizon(horizon)
        self.plan: GoalPlan | None = None
        self._planned_on: np.ndarray | None = None

    def marginals(self, belief: Belief) -> np.ndarray:
        """(N, K) the label marginals the plan is made on: the belief's."""
        return belief.map

    def choose(self, belief: Belief) -> int:
        maps = self.marginals(belief)
        if self._planned_on is None or not np.array_equal(maps, self._planned_on):
            self.plan = plan_to_goal(self.model, maps, self.goal, self.horizon)
            self._planned_on = np.array(maps)
        costs = belief.location @ np.minimum(self.plan.q, NEVER)
        return int(np.argmin(costs))

    def __repr__(self) -> str:
        return f"{type(self).__name__}(goal={self.goal}, horizon={self.horizon})"


def _horizon(value) -> int:
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or int(value) < 0:
        raise ModelError(f"horizon must be a whole number of steps >= 0, got {value!r}")
    return int(value)


class StaticGoTo(GoTo):
    """The baseline :class:`GoTo` improves on: plans on the model's label prior only (the floor
    plan, doors as the prior says, brought to the belief's step ``t`` by ``C^t``), never on what
    the robot has seen; it still acts under the location belief. Extra cost per call: O(K^3 log t)."""

    def marginals(self, belief: Belief) -> np.ndarray:
        return self.model.label_prior @ np.linalg.matrix_power(self.model.change, belief.t)
