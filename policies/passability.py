"""The belief's passability and shortest expected paths over it (DESIGN.md sections 7 and 8).

In a world with blocking labels (``model.has_blocking``) a move into cell ``j`` succeeds with
probability ``p_move`` times ``[m_j passable]``. Planners see only the belief's marginals, so they
use the *expected* passability ``passable[j] = P(m_j not blocking)`` (from the map belief) and, for
paths, this expected-cost model:

    entering j costs c(j) = 1 / (p_move * passable[j])      (expected presses until one succeeds)

the mean of a geometric number of independent presses, each succeeding with ``p_move * passable[j]``.
It is exact for slips and optimistic about a label that stays blocking (pressing again into a closed
door never succeeds); planners re-plan every step, and a failed press lowers ``passable[j]`` in the
next belief, which raises c(j). A cell with ``passable[j] < min_passable`` (or ``p_move = 0``)
cannot be entered: c(j) = inf. The expected steps ``d(i, S)`` from cell ``i`` to a set of cells
``S`` is the cheapest path's total c (Dijkstra, :func:`policies.kernels.paths.shortest_paths`);
it satisfies ``d(i) = min over moves i -> j of (1 / q_j + d(j))``, ``q_j = p_move passable[j]``,
i.e. ``d(i) = min_a [1 + q_j d(j) + (1 - q_j) d(i)]``, the one-step rule planners act by.

Without blocking labels ``passable`` is all ones and every move costs ``1 / p_move``.
Pure functions of (model, belief); N cells, A actions, K labels.
"""

from __future__ import annotations

import numpy as np

from onlinemap import arguments
from onlinemap.belief import Belief
from onlinemap.errors import InvalidOptionError, ModelError
from .kernels.paths import shortest_paths
from onlinemap.model import GridModel, passable_probability

#: a move the belief says blocks with more than this probability is not pressed when another exists
BLOCKED_ABOVE = 0.99
_LEFT_OUT = 1e-9  # location mass the hypotheses of location_hypotheses may leave out


def expected_passability(model: GridModel, belief: Belief) -> np.ndarray:
    """(N,) ``P(m_j not blocking)`` under the belief's map marginals (N, K), clipped to [0, 1]
    (rounding); ones when no label blocks. O(N K)."""
    if not model.has_blocking:
        return np.ones(model.n_cells)
    return np.clip(passable_probability(model, belief.map), 0.0, 1.0)


def enter_costs(model: GridModel, passable: np.ndarray, min_passable: float = 0.05) -> np.ndarray:
    """(N,) ``c(j) = 1 / (p_move passable[j])``, inf where ``passable[j] < min_passable`` or
    ``p_move = 0``. ``passable`` (N,) in [0, 1]. O(N)."""
    passable = _passable(model, passable)
    min_passable = arguments.real("min_passable", min_passable, low=0.0, high=1.0, low_open=True,
                                  error=InvalidOptionError)
    go = model.p_move * passable
    entered = (passable >= min_passable) & (go > 0)
    return np.divide(1.0, go, out=np.full(len(go), np.inf), where=entered)  # no 1 / tiny outside


def distances_to(model: GridModel, passable: np.ndarray, targets, min_passable: float = 0.05) -> np.ndarray:
    """(N,) expected steps ``d(i, S)`` from every cell to the nearest of ``targets`` S (cell
    indices), by :func:`enter_costs`; 0 on S, inf where S cannot be reached. Dijkstra over reversed
    moves: O(N A log(N A))."""
    return paths_to(model, enter_costs(model, passable, min_passable), _cells("targets", model, targets))


def paths_to(model: GridModel, enter_cost: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """(N,) the cheapest path from every cell to the nearest of ``targets`` (checked cell indices),
    a move into cell j costing ``enter_cost[j]`` (N,) >= 0 (inf: no way in); 0 on the targets, inf
    where none can be reached. Dijkstra over reversed moves: O(N A log(N A))."""
    distance = np.full(model.n_cells, np.inf)
    distance[targets] = 0.0
    return shortest_paths(model.predecessor, enter_cost, distance, False)


def distances_from(model: GridModel, passable: np.ndarray, sources, min_passable: float = 0.05) -> np.ndarray:
    """(M, N) expected steps ``d(s, j)`` from each of ``sources`` (M,) to every cell, by
    :func:`enter_costs`; inf where j cannot be reached from s. M Dijkstras: O(M N A log(N A))."""
    sources = _cells("sources", model, sources)
    costs = enter_costs(model, passable, min_passable)
    out = np.full((len(sources), model.n_cells), np.inf)
    for row, source in zip(out, sources):
        row[source] = 0.0
        shortest_paths(model.moves, costs, row, True)
    return out


def location_hypotheses(location: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray]:
    """The most probable cells of ``location`` (N,) holding all but 1e-9 of the mass, at most
    ``size`` of them, and their renormalised probabilities: (M,) cells, (M,) weights. O(N log N)."""
    order = np.argsort(-location, kind="stable")
    mass = np.cumsum(location[order])
    count = min(int(np.searchsorted(mass, mass[-1] * (1.0 - _LEFT_OUT))) + 1, size, len(order))
    cells = order[:count]
    return cells, location[cells] / location[cells].sum()


def move_chances(model: GridModel, passable: np.ndarray, min_passable: float = 0.05) -> np.ndarray:
    """(N, A) ``q = p_move passable[j]``, the chance that pressing a in cell l moves the robot to
    ``j = neighbors[l, a]`` by the expected-cost model; 0 off the grid edge and where
    ``passable[j] < min_passable``. O(N A)."""
    passable = _passable(model, passable)
    moves = model.neighbors != np.arange(model.n_cells)[:, None]
    enter = passable[model.neighbors]
    return np.where(moves & (enter >= min_passable), model.p_move * enter, 0.0)


def steps_after_press(model: GridModel, passable: np.ndarray, to_target: np.ndarray,
                      min_passable: float = 0.05) -> np.ndarray:
    """(N, A) ``1 + q D(j) + (1 - q) D(l)``: the expected steps to a target after pressing a in
    cell l, with ``D = to_target`` (N,) the expected steps from each cell (finite: unreachable
    cells at a penalty) and ``q`` :func:`move_chances`. O(N A)."""
    q = move_chances(model, passable, min_passable)
    return 1.0 + q * to_target[model.neighbors] + (1.0 - q) * to_target[:, None]


def press_costs(model: GridModel, belief: Belief, passable: np.ndarray, targets, min_passable: float,
                penalty: float) -> np.ndarray:
    """(A,) the expected steps to the nearest of ``targets`` after pressing each action, averaged
    over the location belief: ``sum_l P(l) [1 + q D(j) + (1 - q) D(l)]`` (:func:`steps_after_press`)
    with ``D`` = :func:`distances_to` the targets, unreachable cells at ``penalty`` (above any
    path's cost). O(N A log(N A)) (one Dijkstra)."""
    distance = distances_to(model, passable, targets, min_passable)
    distance = np.where(np.isfinite(distance), distance, penalty)
    return belief.location @ steps_after_press(model, passable, distance, min_passable)


def blocked_probability(model: GridModel, belief: Belief) -> np.ndarray:
    """(A,) ``P(the intended cell of action a holds a blocking label)`` under the belief's marginals:
    ``sum_l P(l) [j != l] (1 - passable[j])``, ``j = neighbors[l, a]``. A move off the grid edge
    (``j == l``) holds no label and counts 0; all zeros when no label blocks. O(N A)."""
    if not model.has_blocking:
        return np.zeros(model.n_actions)
    blocked = 1.0 - expected_passability(model, belief)[model.neighbors]  # (N, A)
    blocked[model.neighbors == np.arange(model.n_cells)[:, None]] = 0.0
    return belief.location @ blocked


def unblocked_actions(model: GridModel, belief: Belief, limit: float = BLOCKED_ABOVE) -> np.ndarray:
    """(A,) bool: the actions whose :func:`blocked_probability` is at most ``limit``; every action
    when none is (the robot must press something). O(N A)."""
    allowed = blocked_probability(model, belief) <= limit
    return allowed if allowed.any() else np.ones(model.n_actions, dtype=bool)


class PressMemory:
    """Which actions a planner may press: :func:`unblocked_actions`, less the *futile* ones.

    A press is futile when the belief after it equals the belief before it (marginals to 1e-12):
    every hypothesis predicted its outcome, typically a failed press into what each hypothesis's
    own map holds as a wall, which the marginals need not show (two hypotheses whose maps are
    shifted copies of each other each block the press, yet mix to a marginal map with a way
    through). A planner that is a function of the belief would press it forever; the memory
    leaves it out until the belief changes (unless nothing else is left). Call :meth:`allowed`
    at each decision and :meth:`pressed` with the action taken. O(N K + N A) per decision.
    """

    def __init__(self, model: GridModel):
        self.model = model
        self.futile = np.zeros(model.n_actions, dtype=bool)  # (A,) presses that left the belief as it was
        self._belief: Belief | None = None
        self._action = -1

    def allowed(self, belief: Belief) -> np.ndarray:
        """(A,) bool: the actions the planner may take now."""
        previous = self._belief
        if previous is not None and np.allclose(belief.location, previous.location, rtol=0, atol=1e-12) \
                and np.allclose(belief.map, previous.map, rtol=0, atol=1e-12):
            self.futile[self._action] = True
        else:
            self.futile[:] = False
        allowed = unblocked_actions(self.model, belief)
        return allowed & ~self.futile if (allowed & ~self.futile).any() else allowed

    def pressed(self, belief: Belief, action: int) -> None:
        """Remember the belief the last decision saw and the action it took."""
        self._belief, self._action = belief, int(action)


def _passable(model: GridModel, passable) -> np.ndarray:
    passable = np.asarray(passable, dtype=np.float64)
    if passable.shape != (model.n_cells,):
        raise ModelError(f"passable must have shape ({model.n_cells},) (one probability per cell), "
                         f"got {passable.shape}")
    if not np.all((passable >= 0.0) & (passable <= 1.0)):
        raise ModelError("passable must hold probabilities in [0, 1]")
    return passable


def _cells(name: str, model: GridModel, cells) -> np.ndarray:
    cells = np.atleast_1d(np.asarray(cells))
    if cells.ndim != 1 or cells.size == 0 or cells.dtype.kind not in "iu" \
            or np.any(cells < 0) or np.any(cells >= model.n_cells):
        raise ModelError(f"{name} must be a non-empty sequence of cell indices in 0..{model.n_cells - 1}")
    return cells.astype(np.int64)


__all__ = ["BLOCKED_ABOVE", "expected_passability", "enter_costs", "distances_to", "paths_to", "distances_from",
           "move_chances", "steps_after_press", "location_hypotheses", "press_costs", "blocked_probability", "unblocked_actions", "PressMemory"]
