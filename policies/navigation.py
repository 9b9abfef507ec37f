"""Navigation through a changing building (Thrun, Burgard and Fox, section 4; DESIGN.md section 8):
shortest expected paths to a goal by dynamic programming over the belief's map marginals,
re-planned every step.

The cost model. Every step costs 1; standing on the goal ends the task. From cell ``l`` the action
``a`` aims at ``j = neighbors[l, a]``; an attempt succeeds with ``p_move`` if ``j``'s label lets
the robot in, otherwise the robot stays (the model's blocking semantics, DESIGN.md section 7; a
move off the grid always stays, which is how the robot waits in place). The plan treats a move as
a commitment: press into ``j`` until entered. ``j``'s label when the robot arrives ``tau`` steps
from now is drawn from the marginal brought forward by the map dynamics, ``M[j] C^tau`` (``M``
(N, K) the belief's marginals), so a door believed closed now may have reopened by then; while
the robot presses, the label moves on by C, conditioned on every failed attempt. A door seen
closed therefore costs its expected time to reopen (``1 / p_door`` in the door world), not a
fresh draw per attempt. A label that can never become passable (a wall: ``permanent_labels``)
costs one failed step, after which the robot re-plans from where it is; a cell more likely than
not to hold such a label is planned as a wall (a 5% chance that a wall is free is no reason to
press into it again and again: the model forgets the failure, the belief may not learn from it when
the chance comes from another location hypothesis's map).

Value iteration over (cell, step) (the kernel :func:`policies.kernels.navigation.goal_value_iteration`):
with ``G[tau](j, k)`` the expected steps of pressing into ``j`` from step ``tau`` on, its label
being ``k``, and ``m = M[j] C^tau``, ``s`` its permanently blocking mass,

    G[tau](j, k) = 1 + p_k V[tau+1](j) + (1 - p_k) sum_k' C[k, k'] G[tau+1](j, k'),  p_k = p_move [k passable]
    Q[tau](l, a) = s (1 + V[tau+1](l)) + sum_{k not permanent} m_k G[tau](j, k)     (j != l)
    Q[tau](l, a) = 1 + V[tau+1](l)   (j == l: wait),   Q[tau](goal, .) = 0,   V[tau] = min_a Q[tau],

from ``tau = H - 1`` down to 0. Beyond the horizon ``H`` arrival marginals are frozen at
``M C^H``; that stationary problem is solved exactly: ``G(j, k) = alpha_k + V(j)`` with
``alpha = (I - D C)^-1 1`` over the labels that are not permanent (``D = diag(1 - p_k)``:
:func:`commitment_steps`), and ``V`` a shortest path with cost ``(s_j + sum_k m_k alpha_k) /
(1 - s_j)`` per move into ``j`` (Dijkstra). The robot waits at a closed door (presses into it, or
stays) exactly when that is expected to be cheaper than the detour. The action under location
uncertainty is the one optimal at the most probable of the likely cells (voting; ties go to the
lowest expected cost ``sum_l P(l) Q[0](l, a)``, ``Q[0](goal, .) = 0``: :func:`best_action`).

The approximations: cells are independent (the belief's marginals); the label found on arriving at
a cell is a fresh draw from its marginal (a cell passed twice is not remembered); a commitment is
kept to the end (the robot re-plans every step with its updated belief, so in fact it can give
up); a wall's one failed step is then forgotten.

Costs, N cells, A actions, K labels, H the horizon (at most ``horizon``, default
``2 (rows + cols)``; shorter where C mixes faster: it ends once ``C^tau`` is within 1e-3 of its
limit, about ``log(2000) / (2 p_door)`` steps in the door world, 0 in a static world, where a plan
is one Dijkstra): O(H K^3) once per planner for the powers of C, then per plan O(H N K^2) for the
arrival marginals (one matrix product), O(N A log N) for the Dijkstra and O(H N (K^2 + A)) for the
value iteration; memory O(H N K).
"""

from __future__ import annotations

import logging
import numbers
from typing import NamedTuple

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import breadth_first_order

from onlinemap import arguments
from onlinemap.belief import Belief
from onlinemap.errors import InvalidOptionError
from .kernels.navigation import goal_value_iteration
from onlinemap.model import GridModel

from .passability import PressMemory, paths_to

logger = logging.getLogger(__name__)

MIXED = 1e-3  # the horizon ends where C^tau is this close to its limit (label_powers)
CREDIBLE = 0.95  # the location hypotheses that vote for the action (best_action): the likeliest cells holding this
RELAXED_WALL = 0.999  # with no finite plan: only a cell believed a wall above this is planned as one
NEVER = 1e9  # steps charged for what never ends (a cell from which the goal cannot be reached); values cap here


def goal_cell(model: GridModel, goal) -> int:
    """The cell index of ``goal``: an index in ``0..N-1`` or a ``(row, col)`` pair on the grid.
    Anything else, or a goal off the grid, raises InvalidOptionError naming the goal."""
    if isinstance(goal, np.ndarray) and goal.ndim == 0:  # np.array(99): a cell index in an array
        goal = goal.item()
    if isinstance(goal, numbers.Integral) and not isinstance(goal, (bool, np.bool_)):
        if not 0 <= int(goal) < model.n_cells:
            raise InvalidOptionError(f"goal {goal!r} is off the grid: cells are 0..{model.n_cells - 1}")
        return int(goal)
    if isinstance(goal, (tuple, list, np.ndarray)) and len(goal) == 2 and all(
            isinstance(x, numbers.Integral) and not isinstance(x, (bool, np.bool_)) for x in goal):
        row, col = (int(x) for x in goal)
        if not (0 <= row < model.rows and 0 <= col < model.cols):
            raise InvalidOptionError(f"goal {tuple(goal)!r} (row, col) is off the {model.rows} x {model.cols} grid")
        return row * model.cols + col
    raise InvalidOptionError(f"goal must be a cell index or a (row, col) pair, got {goal!r}")


def default_horizon(model: GridModel) -> int:
    """``2 (rows + cols)``: about twice the longest shortest path of an open grid."""
    return 2 * (model.rows + model.cols)


def label_powers(model: GridModel, horizon: int) -> np.ndarray:
    """(H' + 1, K, K) ``C^tau`` for ``tau = 0..H'``, ``H' <= horizon``: it stops early at the
    first power within :data:`MIXED` (entrywise) of the limit ``C^inf`` (when the powers converge;
    found by repeated squaring), whose label distributions then hardly move any more; ``H' = 0``
    in a static world. O(H K^3)."""
    limit = model.change
    for _ in range(64):  # C^(2^64): the limit of any aperiodic chain, to rounding
        following = limit @ limit
        following /= following.sum(axis=1, keepdims=True)  # rounding would grow with every squaring
        if np.abs(following - limit).max() <= 1e-15:
            break
        limit = following
    converged = np.abs(limit @ model.change - limit).max() <= 1e-12
    plan_work = model.n_cells * (model.n_labels ** 2 + model.n_actions)  # a plan: O(H N (K^2 + A))
    if not converged:  # C never mixes (it cycles): the powers run to the horizon
        arguments.bounded_work(f"a plan to a goal over horizon={horizon} ({model.n_cells} cells, C never mixes)",
                               (int(horizon) + 1) * plan_work, "lower horizon", error=InvalidOptionError)
    powers = [np.eye(model.n_labels)]
    while len(powers) <= int(horizon) and not (converged and np.abs(powers[-1] - limit).max() <= MIXED):
        powers.append(powers[-1] @ model.change)
        if len(powers) % 1024 == 0:  # C mixes slowly: refuse before the plan grows astronomical
            arguments.bounded_work(f"a plan to a goal over horizon={horizon} ({model.n_cells} cells, C mixes after "
                                   f"more than {len(powers) - 1} steps)", len(powers) * plan_work, "lower horizon",
                                   error=InvalidOptionError)
    return np.stack(powers)


def permanent_labels(model: GridModel) -> np.ndarray:
    """(K,) bool: the labels that never let the robot in, now or after any number of changes by C
    (no passable label is reachable from them). Door world: wall, and closed door if p_door = 0.
    O(K^3) at most."""
    can_pass = ~model.blocking
    while True:
        more = can_pass | (model.change[:, can_pass] > 0).any(axis=1)
        if np.array_equal(more, can_pass):
            return ~can_pass
        can_pass = more


def commitment_steps(model: GridModel) -> np.ndarray:
    """(K,) ``alpha_k``: the expected steps of pressing into a cell whose label is ``k`` now until
    the robot is in, the label changing by C meanwhile: ``alpha = 1 + D C alpha`` over the labels
    that are not permanent (``D = diag(1 - p_move [k passable])``); :data:`NEVER` for permanent
    labels, and ``NEVER`` times the probability of falling into one on the way. All ``NEVER`` if
    ``p_move = 0``. O(K^3)."""
    permanent = permanent_labels(model)
    alpha = np.full(model.n_labels, NEVER)
    if model.p_move == 0:
        return alpha
    keep = ~permanent
    stay = 1.0 - model.p_move * (~model.blocking[keep])
    system = np.eye(keep.sum()) - stay[:, None] * model.change[np.ix_(keep, keep)]
    lost = stay * model.change[np.ix_(keep, permanent)].sum(axis=1)
    alpha[keep] = np.minimum(np.linalg.solve(system, 1.0 + NEVER * lost), NEVER)
    return alpha


class LabelTables(NamedTuple):
    """What a plan needs of the model's labels and dynamics (computed once per planner)."""

    powers: np.ndarray  # (H + 1, K, K) C^tau (label_powers)
    permanent: np.ndarray  # (K,) bool, labels that never let the robot in (permanent_labels)
    alpha: np.ndarray  # (K,) expected steps pressing into a label until in (commitment_steps)
    passable: np.ndarray  # (K,) float 1.0 for labels that let the robot in


def label_tables(model: GridModel, horizon: int | None = None) -> LabelTables:
    """The :class:`LabelTables` of ``model`` for ``horizon`` (None: :func:`default_horizon`)."""
    horizon = default_horizon(model) if horizon is None else horizon
    return LabelTables(label_powers(model, horizon), permanent_labels(model), commitment_steps(model),
                       (~model.blocking).astype(np.float64))


def _stationary_cost(model: GridModel, tables: LabelTables, arrival: np.ndarray, goal: int) -> np.ndarray:
    """(N,) expected steps to ``goal`` when every cell's label on arrival is drawn from
    ``arrival`` (N, K) for ever: the shortest path with cost ``(s_j + sum_k m_k alpha_k) /
    (1 - s_j)`` per move into ``j`` (``s_j`` its permanently blocking mass, ``alpha``
    :func:`commitment_steps`). inf where the goal cannot be reached. O(N A log N)."""
    permanent, alpha = tables.permanent, tables.alpha
    wall = arrival[:, permanent].sum(axis=1)
    entering = arrival[:, ~permanent] @ alpha[~permanent]
    with np.errstate(divide="ignore", invalid="ignore"):
        cost = np.where(wall < 1.0, (wall + entering) / (1.0 - wall), np.inf)
    cost[~(cost < NEVER)] = np.inf  # no way in
    return paths_to(model, cost, np.array([goal]))


class GoalPlan(NamedTuple):
    """A plan to one goal. N cells, A actions."""

    value: np.ndarray  # (N,) expected steps from each cell now (0 at the goal; inf: a chance >= 1e-3 of never)
    q: np.ndarray  # (N, A) expected steps after taking action a now and acting optimally after
    horizon: int  # H: arrival marginals M C^tau vary over steps 0..H-1 and are frozen from H on


def plan_to_goal(model: GridModel, maps: np.ndarray, goal: int, horizon: int | None = None, *,
                 tables: LabelTables | None = None, wall_above: float = 0.5) -> GoalPlan:
    """The value iteration of the module docstring for map marginals ``maps`` (N, K) and the goal
    cell ``goal`` (an index). ``horizon`` None: :func:`default_horizon`; ``tables``: the model's
    :func:`label_tables` for that horizon, if already computed. A cell whose permanently blocking
    mass exceeds ``wall_above`` is planned as a wall (1/2: more likely than not; :class:`GoTo`
    raises it to :data:`RELAXED_WALL` when the belief's map leaves no finite plan). Costs: the module's."""
    tables = label_tables(model, horizon) if tables is None else tables
    maps = np.array(maps, dtype=np.float64)
    wall = maps[:, tables.permanent].sum(axis=1)
    walls = wall > wall_above  # planned as walls: their permanent part alone, renormalised
    maps[walls] = np.where(tables.permanent, maps[walls], 0.0) / wall[walls, None]
    h = tables.powers.shape[0] - 1
    arrival = np.matmul(maps[None], tables.powers)  # (H + 1, N, K): M C^tau
    terminal = np.minimum(_stationary_cost(model, tables, arrival[h], goal), NEVER)
    commit = np.where(tables.permanent, NEVER, np.minimum(tables.alpha + terminal[:, None], NEVER))
    action_cost = np.empty((model.n_cells, model.n_actions))
    value = goal_value_iteration(arrival, model.change, tables.passable, tables.permanent, model.neighbors,
                                 model.p_move, goal, terminal, commit, NEVER, action_cost)
    never = NEVER / 1000  # a chance of 1/1000 or more of never arriving
    return GoalPlan(np.where(value >= never, np.inf, value), np.where(action_cost >= never, np.inf, action_cost), h)


def walls_under_prior(model: GridModel) -> np.ndarray:
    """(N,) bool: the cells that are walls under the label prior, i.e. hold with probability
    above 1/2 a label that never lets the robot in (:func:`permanent_labels`). A door believed
    closed that may reopen is not a wall; one that never changes is. O(N K + K^3)."""
    return model.label_prior[:, permanent_labels(model)].sum(axis=1) > 0.5


def check_goal(model: GridModel, goal) -> int:
    """The cell of ``goal`` (:func:`goal_cell`), or InvalidOptionError naming it if it is off the grid, a
    wall under the prior (:func:`walls_under_prior`), or cut off from the start cell under the
    prior (every path crosses a wall). O(N A)."""
    cell = goal_cell(model, goal)
    walls = walls_under_prior(model)
    if walls[cell]:
        chance = model.label_prior[cell, permanent_labels(model)].sum()
        raise InvalidOptionError(f"goal {goal!r} (cell {cell}) is a wall under the prior: it holds a label that never "
                                 f"lets the robot in with probability {chance:.3g}")
    n = model.n_cells
    cells = np.repeat(np.arange(n), model.n_actions)
    targets = model.neighbors.ravel()
    keep = (targets != cells) & ~walls[targets] & (model.p_move > 0)
    graph = sp.csr_array((np.ones(keep.sum()), (cells[keep], targets[keep])), shape=(n, n))
    if cell not in breadth_first_order(graph, model.start, directed=True, return_predecessors=False):
        stuck = " (p_move = 0: the robot never moves)" if model.p_move == 0 else ""
        raise InvalidOptionError(f"goal {goal!r} (cell {cell}) cannot be reached from the start cell {model.start} "
                                 f"under the prior: every path crosses a wall{stuck}")
    return cell


def likely_cells(location: np.ndarray, goal: int) -> np.ndarray:
    """The cells that vote in :func:`best_action`: the location belief's :data:`CREDIBLE` set (its
    most likely cells holding that much of the probability), less the goal and cells of
    probability 0. ``location`` (N,). O(N log N)."""
    order = np.argsort(location, kind="stable")[::-1]
    held = np.cumsum(location[order])
    likely = order[:int(np.searchsorted(held, CREDIBLE * held[-1])) + 1]
    return likely[(likely != goal) & (location[likely] > 0)]


def best_action(location: np.ndarray, q: np.ndarray, goal: int) -> int:
    """The action most likely to be the best one: the largest total probability of the cells of
    the location belief's :data:`CREDIBLE` set (its most likely cells holding that much of the
    probability) at which it is optimal (within 1e-9 relative; the goal aside, where every action
    is free); ties go to the lowest expected cost ``sum_l P(l) Q(l, a)``, then to the lowest index.
    A sharp belief gives the MDP's action at the robot's cell.

    Why not the lowest expected cost alone (the Q-MDP rule): with location hypotheses that want
    different moves, an action that no likely hypothesis wants can have it (pressing into a wall,
    a compromise that keeps both hypotheses cheap), and taking it teaches the robot nothing, so it
    takes it for ever. Seen with the RBPF in the door world: two cells with the same view (65%,
    35%), and a minority hypothesis whose particles learned a shifted map while the plan runs on
    the mixture of all particles' maps. Voting (Simmons and Koenig 1995) moves the way the likely
    hypotheses want, and moving tells them apart. ``location`` (N,), ``q`` (N, A). O(N log N + N A)."""
    q = np.minimum(q, NEVER)
    costs = location @ q
    likely = likely_cells(location, goal)
    if not len(likely):
        return int(np.argmin(costs))
    here = q[likely]
    best = here.min(axis=1, keepdims=True)
    votes = location[likely] @ (here <= best + 1e-9 * (1.0 + np.abs(best)))
    winners = votes >= votes.max() * (1 - 1e-12)
    return int(np.argmin(np.where(winners, costs, np.inf)))


class GoTo:
    """Go to ``goal`` (a cell index or ``(row, col)``) by the value iteration of
    :mod:`policies.navigation` on the belief's map marginals, re-planned at every call; the action
    is chosen under the location belief by :func:`best_action`.

    With no finite plan (every Q value infinite at every likely cell, :func:`likely_cells`: the
    belief's map cuts the goal off, e.g. two doors on the route learned as walls while the robot
    was lost) the planner falls back, first to a plan in which only cells believed a wall above
    :data:`RELAXED_WALL` are walls (a door believed a wall at 0.95 may still be one), then, if that
    is cut off too, to moving towards the goal as the crow flies (Q = 1 + the grid distance from
    the target cell to the goal); in both it leaves out the presses a
    :class:`~policies.passability.PressMemory` found futile, so it never presses one futile action
    for ever (presses believed blocked stay allowed: they are what the relaxed plan tries). Each such step is recorded in ``events`` (``{"event": "no_plan", "t": step,
    "fallback": "relaxed" | "towards_goal"}``; ``no_plan`` counts them) and the first one is
    logged as a warning by this module's logger. ``horizon``: H (None:
    :func:`default_horizon`). A goal off the grid, a wall under the model's label prior or
    unreachable from the start under it raises InvalidOptionError naming the goal (:func:`check_goal`).
    Cost per call: the module's (a call whose marginals equal the last call's reuses its plan)."""

    def __init__(self, model: GridModel, goal=None, horizon: int | None = None):
        if goal is None:
            raise InvalidOptionError(f"{type(self).__name__} needs a goal: goal=CELL (an index or (row, col))")
        self.model = model
        self.goal = check_goal(model, goal)
        self.horizon = default_horizon(model) if horizon is None else _horizon(horizon)
        self.tables = label_tables(model, self.horizon)
        self.plan: GoalPlan | None = None
        self._planned_on: np.ndarray | None = None
        self.memory = PressMemory(model)
        self.events: list[dict] = []  # the steps with no finite plan (see the class docstring)

    @property
    def no_plan(self) -> int:
        """The number of steps at which the belief's map left no finite plan."""
        return len(self.events)

    def marginals(self, belief: Belief) -> np.ndarray:
        """(N, K) the label marginals the plan is made on: the belief's."""
        return belief.map

    def choose(self, belief: Belief) -> int:
        maps = self.marginals(belief)
        if self._planned_on is None or not np.array_equal(maps, self._planned_on):
            self.plan = plan_to_goal(self.model, maps, self.goal, tables=self.tables)
            self._planned_on = np.array(maps)
        likely = likely_cells(belief.location, self.goal)
        if len(likely) and np.isinf(self.plan.q[likely]).all():
            return self._fallback(belief, maps, likely)
        return best_action(belief.location, self.plan.q, self.goal)

    def _fallback(self, belief: Belief, maps: np.ndarray, likely: np.ndarray) -> int:
        """The action when the plan on ``maps`` is infinite at every ``likely`` cell (class docstring)."""
        q = plan_to_goal(self.model, maps, self.goal, tables=self.tables, wall_above=RELAXED_WALL).q
        fallback = "relaxed"
        if np.isinf(q[likely]).all():
            fallback = "towards_goal"
            rows, cols = np.divmod(self.model.neighbors, self.model.cols)
            goal_row, goal_col = divmod(self.goal, self.model.cols)
            q = 1.0 + np.abs(rows - goal_row) + np.abs(cols - goal_col)
        self.memory.allowed(belief)  # updates which presses were futile; a press it believes blocked is still
        allowed = ~self.memory.futile if not self.memory.futile.all() else np.ones_like(self.memory.futile)
        action = best_action(belief.location, np.where(allowed, q, np.inf), self.goal)
        self.memory.pressed(belief, action)
        if not self.events:
            logger.warning("%r: no finite plan at step %d (the belief's map cuts the goal off); falling back to %s",
                           self, belief.t, "a plan with walls believed below %g as passable" % RELAXED_WALL
                           if fallback == "relaxed" else "moving towards the goal")
        self.events.append({"event": "no_plan", "t": int(belief.t), "fallback": fallback})
        return action

    def __repr__(self) -> str:
        return f"{type(self).__name__}(goal={self.goal}, horizon={self.horizon})"


def _horizon(value) -> int:
    return arguments.integer("horizon", value, minimum=0, error=InvalidOptionError)


class StaticGoTo(GoTo):
    """The baseline :class:`GoTo` improves on: plans on the model's label prior only (the floor
    plan, doors as the prior says, brought to the belief's step ``t`` by ``C^t``), never on what
    the robot has seen; it still acts under the location belief. Extra cost per call: O(K^3 log t)."""

    def marginals(self, belief: Belief) -> np.ndarray:
        return self.model.label_prior @ np.linalg.matrix_power(self.model.change, belief.t)
