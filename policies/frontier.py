"""Frontier exploration on the belief (Yamauchi 1997; DESIGN.md section 8): the classical baseline.

Every step, from the belief's marginals (N cells, K labels, A actions, F footprint offsets):

1. *Uncertain cells*: ``u_i`` = the normalised label entropy of cell i (in [0, 1]); cell i is
   uncertain when ``u_i > threshold``. Normalised by ``log K`` (a uniformly unknown cell is 1), or,
   given ``scale`` (the entropy of a cell not yet read under a learned or given label prior, as
   :class:`~policies.info_gain.InfoGainExplorer` passes it), ``min(H(m_i) / scale, 1)``: an unread
   cell is one cell of uncertainty whatever the prior (under a floor's learned frequencies its
   entropy over ``log K`` can fall below ``threshold``, and no unread cell would be a frontier).
2. *Gain* of standing in cell c: ``g(c) = sum_f u_{c_f} [u_{c_f} > threshold]`` over the on-grid
   cells ``c_f = footprint_cells[c, f]`` the sensor would read there (in cells' worth of
   uncertainty). The *frontier* is the cells with ``g(c) > 0``.
3. *Expected distance* to c under the location belief: ``E(c) = sum_l P(l) d(l, c)`` with ``d`` the
   expected steps of :mod:`policies.passability` (entering j costs ``1 / (p_move passable_j)``), over
   the ``hypotheses`` most probable cells ``l`` (the smallest set holding all but 1e-9 of the mass,
   or the ``hypotheses`` most probable; renormalised). A pair that no path joins counts
   ``N / (p_move min_passable)``, more than any path; c is *reachable* when some hypothesis reaches it.
4. *Target*: the reachable frontier cell of highest score ``g(c) - distance_cost * E(c)`` (ties: all
   of them). ``distance_cost`` is in cells of uncertainty per step: large, the nearest frontier
   (Yamauchi's rule, the gain only breaking ties); 0, the most informative reachable place.
5. *Action*: with ``D(x)`` the expected steps from x to the nearest target,
   ``argmin_a sum_l P(l) [1 + q D(j) + (1 - q) D(l)]``, ``j = neighbors[l, a]``, ``q = p_move
   passable_j`` (0 off the grid edge or into an impassable cell): the expected steps to the target
   after pressing a, averaged over where the robot may be (not only its most likely cell). Ties go
   to the lowest action index; a press the belief says blocks (:func:`~policies.passability.
   unblocked_actions`) is never chosen while another exists, nor a futile one (rule 7).
6. *Inaccessible targets* (Yamauchi's list of inaccessible frontiers): when ``E`` of the first
   target has not fallen by half a step (below where it stood at the last such fall, or at its
   last rise) for ``patience`` decisions in a row, that target goes on a blacklist and is
   no target while any other frontier cell is reachable; when none is, the list is cleared. This is
   what gets a robot out of a belief it cannot resolve by pressing on: two location hypotheses whose
   maps are shifted copies both explain every failed press into a wall, so the marginal map keeps
   showing a way through it (``patience`` None: never blacklist).
7. *Futile presses* (:class:`~policies.passability.PressMemory`): a press after which the belief
   did not change at all is left out until it changes (the planner, a function of the belief,
   would otherwise press it forever).

Corner cases. *No frontier left* (every reachable cell's footprint is certain, or the rest cannot be
reached): the gain drops the threshold, ``g(c) = sum_f u_{c_f}``, and the robot revisits the most
uncertain reachable places (in a dynamic world, where doors' uncertainty grows back). *A lost robot*
(location spread over many cells): the expected distance and the action average over the location
hypotheses, so it heads where most of them agree; with ``lost_entropy`` set, a robot whose
normalised location entropy exceeds it re-localises instead: the gain counts the footprint's
*certain* cells, ``sum_f (1 - u_{c_f})``, so it returns to mapped places whose readings tell the
hypotheses apart. *Corridors*: the same rules with two actions.

Defaults (``threshold`` 0.5, ``distance_cost`` 0.2, ``patience`` 3, ``min_passable`` 0.05,
``hypotheses`` 16, ``lost_entropy`` None) were tuned on the 10 x 10 door world with blocking walls
and a cross footprint, uniform label prior, ``p_move`` 0.8, RBPF with 1000 particles, 12 seeds
(100-111, apart from the seeds of any reported study), 300 steps, for the fewest steps to map
error 0.1: ``distance_cost`` 0.1-0.3 is best (0: the robot wanders to far-off gains and gets lost;
1 or more, the pure nearest frontier, it gets lost too, median never reaching 0.1); ``patience``
3 beats 8 and never (2 and 3 alike over 24 seeds: mean 132 and 133 steps); ``threshold`` 0.2-0.7 and ``min_passable`` 0.05-0.15 made no difference
beyond the noise; one hypothesis (the most likely cell) instead of 16 was slower; re-localising
at ``lost_entropy`` 0.3 was slower (mean steps to 0.1 from 138 to 161-174), so it is off.

Cost per decision: ``M`` = at most ``hypotheses`` Dijkstras plus one, O((M + 1) N A log(N A)),
plus O(N (F + K + A)) for the entropies, gains and action values.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from onlinemap import arguments
from onlinemap.belief import Belief
from onlinemap.errors import InvalidOptionError, ModelError
from onlinemap.metrics import normalized_entropy
from onlinemap.model import GridModel

from .information import entropy
from .loop_closing import loop_closer
from .passability import (PressMemory, distances_from, distances_to, expected_passability, location_hypotheses,
                          steps_after_press)

_PROGRESS = 0.5  # expected steps the distance to the target must fall by to count as progress


class FrontierPlan(NamedTuple):
    """One decision of :class:`FrontierExplorer`. N cells, A actions."""

    gain: np.ndarray  # (N,) g(c) as used (after the fallbacks)
    expected_distance: np.ndarray  # (N,) E(c), unreachable pairs at the penalty
    reachable: np.ndarray  # (N,) bool
    targets: np.ndarray  # (T,) the chosen cells
    distance: np.ndarray  # (N,) D(x) to the nearest target, unreachable at the penalty
    action_cost: np.ndarray  # (A,) sum_l P(l) [1 + q D(j) + (1 - q) D(l)]
    mode: str  # "frontier", "revisit" (no frontier left) or "relocalise" (lost)
    score: np.ndarray  # (N,) g(c) - distance_cost E(c) over the candidate cells, -inf elsewhere


class FrontierExplorer:
    """Nearest-frontier exploration on the belief (see the module docstring for the rules).

    Options: ``threshold`` in (0, 1), the normalised label entropy above which a cell is uncertain;
    ``distance_cost`` >= 0, cells of uncertainty one expected step is worth; ``min_passable`` in
    (0, 1], the expected passability below which a cell cannot be entered; ``hypotheses`` >= 1, the
    most location hypotheses the expected distance averages over; ``lost_entropy`` in (0, 1] or
    None, the normalised location entropy above which the robot re-localises (None: never);
    ``patience`` >= 1 or None, the decisions without progress after which a target is blacklisted;
    ``loop_closing`` (default False) returns to places mapped while the robot was localised when the
    location belief spreads, with ``close_above``, ``close_below`` and ``close_steps``
    (:mod:`policies.loop_closing`, :func:`~policies.loop_closing.loop_closer`).
    Re-plans at every call; never touches an estimator. Needs ``p_move > 0``.
    """

    def __init__(self, model: GridModel, *, threshold: float = 0.5, distance_cost: float = 0.2,
                 min_passable: float = 0.05, hypotheses: int = 16, lost_entropy: float | None = None,
                 patience: int | None = 3, loop_closing: bool = False, close_above: float | None = None,
                 close_below: float | None = None, close_steps: int | None = None):
        self.threshold = arguments.real("threshold", threshold, low=0.0, high=1.0, low_open=True, high_open=True,
                                        error=InvalidOptionError)
        self.distance_cost = arguments.real("distance_cost", distance_cost, low=0.0, high=math.inf, high_open=True,
                                            error=InvalidOptionError)
        self.min_passable = arguments.real("min_passable", min_passable, low=0.0, high=1.0, low_open=True,
                                           error=InvalidOptionError)
        self.hypotheses = arguments.integer("hypotheses", hypotheses, minimum=1, error=InvalidOptionError)
        self.lost_entropy = None if lost_entropy is None else arguments.real(
            "lost_entropy", lost_entropy, low=0.0, high=1.0, low_open=True, error=InvalidOptionError)
        self.patience = None if patience is None else arguments.integer("patience", patience, minimum=1,
                                                                        error=InvalidOptionError)
        if model.p_move <= 0:
            raise ModelError("frontier needs p_move > 0: with p_move = 0 the robot never reaches a frontier")
        self.model = model
        self.penalty = model.n_cells / (model.p_move * self.min_passable)  # above any path's cost
        self.last_plan: FrontierPlan | None = None
        self.blacklist = np.zeros(model.n_cells, dtype=bool)  # (N,) targets found inaccessible
        self._target = -1  # the first target of the last decision, its E then, decisions without progress
        self._last_distance = math.inf
        self._stalled = 0
        self.presses = PressMemory(model)  # blocked and futile presses
        self.closer = loop_closer(model, loop_closing, close_above, close_below, close_steps, self.min_passable)

    def choose(self, belief: Belief, scale: float | None = None) -> int:
        """The next press (module docstring); ``scale`` as in :meth:`plan`."""
        if self.closer is not None and self.closer.update(belief).closing:
            action = self.closer.press(belief, self.closer.last.target, self.presses)
            self.presses.pressed(belief, action)
            return action
        plan = self.plan(belief, scale)
        self._track(int(plan.targets[0]), float(plan.expected_distance[plan.targets[0]]))
        action = int(np.argmin(np.where(self.presses.allowed(belief), plan.action_cost, np.inf)))
        self.presses.pressed(belief, action)
        return action

    def plan(self, belief: Belief, scale: float | None = None) -> FrontierPlan:
        """Targets, distances and the expected cost of every action (module docstring, steps 1-5).
        ``scale`` > 0: the entropy (nats) that counts as one cell of uncertainty (step 1); None: ``log K``."""
        if scale is not None:
            scale = arguments.real("scale", scale, low=0.0, high=math.inf, low_open=True, high_open=True,
                                   error=InvalidOptionError)
        model = self.model
        passable = expected_passability(model, belief)
        cells, weights = location_hypotheses(belief.location, self.hypotheses)
        paths = distances_from(model, passable, cells, self.min_passable)  # (M, N)
        expected = weights @ np.where(np.isfinite(paths), paths, self.penalty)
        reachable = np.isfinite(paths).any(axis=0)
        gain, mode = self._gain(belief, reachable, scale)
        candidates = reachable & (gain > 0)
        if (candidates & self.blacklist).any():
            if (candidates & ~self.blacklist).any():
                candidates &= ~self.blacklist
            else:
                self.blacklist[:] = False
        score = np.where(candidates if candidates.any() else reachable, gain - self.distance_cost * expected, -np.inf)
        best = score.max()
        targets = np.flatnonzero(score >= best - 1e-12 * (1.0 + abs(best)))
        to_target = distances_to(model, passable, targets, self.min_passable)
        to_target = np.where(np.isfinite(to_target), to_target, self.penalty)
        action_cost = belief.location @ steps_after_press(model, passable, to_target, self.min_passable)
        self.last_plan = FrontierPlan(gain, expected, reachable, targets, to_target, action_cost, mode, score)
        return self.last_plan

    def _track(self, target: int, distance: float) -> None:
        """Count the decisions in a row without progress towards ``target`` (E falling by half a step
        below where it stood at the last progress, or a rise, which re-baselines); blacklist it at
        ``patience``."""
        if target != self._target or distance <= self._last_distance - _PROGRESS:
            self._stalled, self._last_distance = 0, distance
        else:
            self._stalled += 1
            self._last_distance = max(self._last_distance, distance)
            if self.patience is not None and self._stalled >= self.patience:
                self.blacklist[target] = True
                self._stalled = 0
        self._target = target

    def _gain(self, belief: Belief, reachable: np.ndarray, scale: float | None) -> tuple[np.ndarray, str]:
        """(N,) the gain of standing in each cell, and the mode it was computed in."""
        model = self.model
        unknown = normalized_entropy(belief.map) if scale is None else np.minimum(entropy(belief.map) / scale, 1.0)
        on_grid = model.footprint_cells >= 0
        seen = model.footprint_cells.clip(0)
        if self.lost_entropy is not None and model.n_cells > 1 \
                and float(normalized_entropy(belief.location)) > self.lost_entropy:
            return np.where(on_grid, 1.0 - unknown[seen], 0.0).sum(axis=1), "relocalise"
        uncertain = np.where(unknown > self.threshold, unknown, 0.0)
        gain = np.where(on_grid, uncertain[seen], 0.0).sum(axis=1)
        if (gain[reachable] > 0).any():
            return gain, "frontier"
        return np.where(on_grid, unknown[seen], 0.0).sum(axis=1), "revisit"

    def __repr__(self) -> str:
        return (f"FrontierExplorer(threshold={self.threshold}, distance_cost={self.distance_cost}, "
                f"min_passable={self.min_passable}, hypotheses={self.hypotheses}, "
                f"lost_entropy={self.lost_entropy}, patience={self.patience}"
                + ("" if self.closer is None else f", loop_closing=True, {self.closer!r}") + ")")
