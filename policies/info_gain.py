"""Information-gain exploration (Stachniss, Grisetti and Burgard 2005; DESIGN.md section 7).

The paper's planner (:class:`~policies.planners.EntropyExplorer`) acts by the Q-MDP rule, which
assumes the location uncertainty vanishes after one step: it cannot value an action whose payoff
is knowing where the robot is. This planner scores *macro-actions* by what they are expected to
teach the filter about the location and the map, measured on the filter itself:

    utility(m) = U(now) - E[ U(after m) ] - step_cost * I0 * len(m),
    U(belief)  = location_weight * I0 * H(L) + sum_i H(m_i)            (nats)

``H(L)`` is the entropy of the location marginal, ``H(m_i)`` that of cell i's label marginal;
``I0`` is what one observation teaches about a cell whose label is uniformly unknown
(:func:`~policies.information.information_reward`: 0.95 nats in the door world at ``p_obs`` 0.9, 0.19 in a binary
world at ``p_obs`` 0.8), so ``step_cost`` and ``location_weight`` mean the same in
every world (a nat of location is worth ``location_weight`` observations of an unknown cell).
Where the estimator learns (or is given) the label frequencies of cells not yet read, ``I0`` is
taken at those frequencies (``information_unit="prior"``, the default; :meth:`InfoGainExplorer.unit`):
under a building's learned frequencies (about 56% free, 39% wall) an unread cell holds 0.87
nats of label entropy against 1.39 under the uniform prior, and one observation teaches 0.59
nats of it against 0.95 (0.48 at the paper's world's own frequencies); measured in the uniform
unit, mapping a new cell looked worth half as much against the same location term and step
cost, and runs read less of the world. Measured in the paper's world with the learned prior (RBPF
1000 particles, 1000 steps, 6 seeds, ``planners_study``): map error 0.201 -> 0.111, the
told-location map of the readings 0.206 -> 0.073, mean location error 0.357 -> 0.406. There a
larger ``location_weight`` buys location with map (12 seeds, late location error, the second half's
mean 1 - P(true cell), and map error): 4 -> 0.41 and 0.11, 8 -> 0.34 and 0.23, 16 -> 0.24 and 0.28,
the robot covering less of the world; a filter told the map is at 0.27 on the data of weight 4. The
frontier targets count an unread cell as one cell of uncertainty the same way
(:meth:`InfoGainExplorer.unread_entropy`). With the model's fixed prior (the paper's worlds) the
unit is the uniform one, as before.
The expectation is over the observations the robot would make: a hypothetical world (a location
and a map) is drawn from the current belief, the macro-action is rolled out in it (slips, map
changes, sensor noise), the simulated observations go through a copy of the filter, and the
copy's uncertainty is measured. The same hypotheses and random numbers serve every candidate
(common random numbers), so the candidates are compared on the same futures.

Candidates (each scored at several lengths, the prefixes of one rollout):

- *press d*: press one direction ``k`` times, ``k`` in ``press_lengths`` (default 1, 2, 4, 8 and
  enough presses to cross the grid with slips). Pressing against the grid's edge is what lets a
  lost robot relocalise; pressing into the unknown is how a localised one maps.
- *plan*: a walk from the most probable location on the ``Q`` of the policy-iteration plan
  (:func:`~policies.mdp.policy_iteration`) for the per-cell information reward
  ``R(i) = H(m_i) - E_z H(m_i | z)`` (what one observation of cell i would teach a localised
  robot); see :func:`greedy_path`.

The chosen macro-action is executed for at most ``commit`` steps, then the planner re-plans.
With frontier targets (``targets``, outside the paper's world), candidates also move towards the
best frontier targets (not the cell the robot most probably stands on), and when no macro-action
pays its cost (every utility <= 0: what is left to learn lies beyond the horizon) the next
``commit`` presses are the frontier baseline's (:class:`~policies.frontier.FrontierExplorer`).
A macro-action whose first press most probably meets a wall is never chosen.

*Re-anchoring.* An expected-entropy score trusts the belief: once every particle agrees on a
wrong trajectory (P particles cannot hold the 2^T trajectories a slipping robot may have taken),
it sees nothing to learn about the location. So every ``anchor_every`` steps the planner checks
the belief against the grid itself: it presses into the corner nearest the expected location
(``press_lengths[-1]`` presses along each axis, enough to cross the grid with slips), which puts
the true robot in a known cell whatever the particles believed. Measured on the paper's world
(20 seeds, 1000 particles, 1000 steps; ``policies.studies``): anchoring every 60 steps takes the
mean location error from 0.70 to 0.50 at the same map error (0.25); every 40 steps, 0.39 but map
error 0.35; every 30, 0.27 but the robot does little else (map error 0.64).

Backends (who plays "a copy of the filter"): a particle filter (an estimator that
:class:`~onlinemap.estimators.base.HoldsParticles`, ``rbpf``) is rolled out in numba on a thinned
copy of its particles (:mod:`policies.rollouts`, where the cost per plan and the measured times
are); any other estimator is forked and stepped with simulated observations, or, with
``hypotheses=None``, every observation sequence is enumerated (:mod:`policies.information`).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from onlinemap import arguments
from onlinemap.belief import Belief
from onlinemap.errors import InvalidOptionError, ModelError
from onlinemap.estimators import Estimator
from onlinemap.estimators.base import HoldsParticles
from onlinemap.estimators.rbpf_kernels import thread_count
from onlinemap.model import GridModel
from onlinemap.rng import SeedLike, as_generator

from .frontier import FrontierExplorer, FrontierPlan
from .information import (entropy, expected_uncertainty, information_reward, observation_count, sample_states,
                          unit_information)
from .kernels.rollout_buffers import KeptBuffers
from .loop_closing import loop_closer
from .mdp import PolicyIterationResult, policy_iteration
from .passability import (PressMemory, distances_to, expected_passability, move_chances, press_costs,
                          unblocked_actions)
from .rollouts import (footprint_expected_uncertainty, particle_expected_uncertainty, rollout_operations,
                       rollout_tables)

MAX_PLAN_FORKS = 10**5  # an exact enumeration forking the estimator more often than this is refused


def _lengths(value) -> np.ndarray:
    """``press_lengths``: a non-empty sequence of whole numbers >= 1, sorted and unique."""
    if isinstance(value, (str, bytes)) or not hasattr(value, "__iter__"):
        raise InvalidOptionError(f"press_lengths must be a sequence of whole numbers >= 1, got {value!r}")
    lengths = [arguments.integer(f"press_lengths[{i}]", v, minimum=1, error=InvalidOptionError)
               for i, v in enumerate(value)]
    if not lengths:
        raise InvalidOptionError("press_lengths must not be empty")
    return np.unique(np.asarray(lengths, dtype=np.int64))


def greedy_path(model: GridModel, q: np.ndarray, start: int, length: int) -> np.ndarray:
    """(length,) actions of a walk from ``start`` that takes, at each cell, the action of highest
    ``q`` (N, A) among those reaching a cell not yet on the walk (any moving action if none does).
    With a per-cell reward that is not used up, the policy-iteration policy may stay on a
    rewarding cell forever (press into a wall); the walk never stands still. O(length A)."""
    path = np.empty(length, dtype=np.int64)
    seen, cell = {start}, start
    for h in range(length):
        targets = model.neighbors[cell]
        moving = targets != cell
        fresh = moving & ~np.isin(targets, list(seen))
        allowed = fresh if fresh.any() else moving if moving.any() else np.ones_like(moving)
        path[h] = int(np.argmax(np.where(allowed, q[cell], -np.inf)))
        cell = int(targets[path[h]])
        seen.add(cell)
    return path


def anchor_actions(model: GridModel, belief: Belief, presses: int) -> np.ndarray:
    """(2 presses,) actions that press into the grid corner nearest the belief's expected location:
    ``presses`` times towards the nearer of the two column edges, then as many towards the nearer
    row edge. An action "goes towards" an edge when it moves every cell off that edge and keeps
    the edge's cells in place (found from ``model.neighbors``, so any 4-connected grid works). A
    1 x 1 grid: ``presses`` presses of action 0. O(N A)."""
    rows, cols = np.divmod(np.arange(model.n_cells), model.cols)
    expected = (belief.location @ rows, belief.location @ cols)
    sequence = []
    for axis, coordinate, size in ((1, cols, model.cols), (0, rows, model.rows)):
        if size == 1:  # a corridor has no second axis to anchor
            continue
        edge = 0 if expected[axis] <= (size - 1) / 2 else size - 1
        on_edge = coordinate == edge
        towards = [a for a in range(model.n_actions)
                   if np.all(model.neighbors[on_edge, a] == np.flatnonzero(on_edge))
                   and np.all(np.abs(coordinate[model.neighbors[~on_edge, a]] - edge)
                              < np.abs(coordinate[~on_edge] - edge))]
        if not towards:
            raise ModelError("anchor_actions needs a grid whose actions move along its rows and columns")
        sequence += [towards[0]] * presses
    if model.n_cells == 1:  # a single cell is its own corner: any press anchors (and moves nothing)
        sequence = [0] * presses
    return np.asarray(sequence, dtype=np.int64)


class MacroScore(NamedTuple):
    """The scores of one plan. C candidate sequences, H their common length."""

    names: tuple[str, ...]  # (C,) e.g. "press east", "plan"
    sequences: np.ndarray  # (C, H) actions
    lengths: np.ndarray  # (L,) the prefix lengths scored
    gain: np.ndarray  # (C, L) expected uncertainty drop U(now) - E[U(after k steps)], nats
    utility: np.ndarray  # (C, L) gain - step_cost * I0 * k
    chosen: tuple[int, int]  # (candidate, length index) of the best utility
    targets: np.ndarray  # (C,) the target cell of a move towards one (sequence -1), -1 for fixed presses
    pays: bool = True  # some macro-action's utility is positive (else, with targets, the frontier leads)
    unit: float = math.nan  # I0 of this plan, nats (information_unit): utility / unit is in observations of an unread cell


class Candidates(NamedTuple):
    """The macro-actions of one plan. C candidates, H steps, N cells, A actions."""

    names: tuple[str, ...]  # (C,)
    sequences: np.ndarray  # (C, H) actions; -1: chosen in closed loop towards the target
    targets: np.ndarray  # (C,) target cells, -1 for fixed sequences
    distances: np.ndarray | None  # (C, N) expected steps to each candidate's target (None: no targets)
    go: np.ndarray | None  # (N, A) the chance each press moves (move_chances)


DEFAULT_TARGETS = 4  # frontier targets among the candidates, outside the paper's world
STEP_COST = 0.05  # step_cost "auto" in the paper's world (chosen on 8 seeds of it)
# step_cost "auto" with frontier targets: tuned on the blocking + cross door world, 1000 particles,
# 300 steps, mean steps to map error 0.1 over 8 seeds: seeds 0-7, 0.05 -> 142, 0.2 -> 131,
# 0.35 -> 117, 0.6 -> 112, 1.0 -> 133 (frontier 142); seeds 8-15, 0.45 -> 126, 0.6 -> 115,
# 0.75 -> 117 (frontier 131). Measured apart from these seeds, on seeds 20-39 (the guide's Exploration page).
TARGETS_STEP_COST = 0.6
#: ``information_unit``: "prior", I0 of a cell at the label frequencies of cells not yet read (the
#: estimator's ``label_frequencies``, learned or given; uniform when it keeps the model's table);
#: "uniform", I0 of a uniformly unknown cell whatever the prior
INFORMATION_UNITS = ("prior", "uniform")


def _finite(distance: np.ndarray, penalty: float) -> np.ndarray:
    """``distance`` with the unreachable (inf) at ``penalty``."""
    return np.where(np.isfinite(distance), distance, penalty)


def frontier_targets(model: GridModel, plan: FrontierPlan, count: int, spacing: int = 3,
                     skip: np.ndarray | None = None) -> np.ndarray:
    """Up to ``count`` target cells from a frontier plan: the highest ``plan.score`` first, each
    at least ``spacing`` cells (grid distance, rows plus columns) from those already taken, so
    the candidates go to different places; none where ``skip`` (N,) bool is set (the cell the
    robot most probably stands on: a move there is no move). O(N log N + count N)."""
    order = np.argsort(-plan.score, kind="stable")
    order = order[np.isfinite(plan.score[order])]
    if skip is not None:
        order = order[~skip[order]]
    chosen: list[int] = []
    places: list[tuple[int, int]] = []  # (row, col) of the chosen cells
    for cell in order:
        if len(chosen) == count:
            break
        row, col = divmod(int(cell), model.cols)
        if all(abs(row - r) + abs(col - c) >= spacing for r, c in places):
            chosen.append(int(cell))
            places.append((row, col))
    return np.asarray(chosen, dtype=np.int64)


def descent(model: GridModel, go: np.ndarray, distance: np.ndarray, start: int, length: int) -> np.ndarray:
    """(length,) the presses of a robot that never slips, from ``start``, each the one of least
    expected steps to the target after it (``steps_after_press`` with ``go`` (N, A) and
    ``distance`` (N,)), moving to the intended cell. O(length A)."""
    path = np.empty(length, dtype=np.int64)
    cell = start
    for h in range(length):
        cost = 1.0 + go[cell] * distance[model.neighbors[cell]] + (1.0 - go[cell]) * distance[cell]
        path[h] = int(np.argmin(cost))
        if go[cell, path[h]] > 0:
            cell = int(model.neighbors[cell, path[h]])
    return path


class InfoGainExplorer:
    """Information-gain exploration with macro-actions (see the module docstring).

    Options: ``hypotheses`` S worlds drawn per plan (None: exact enumeration of the observations,
    generic backend only); ``rollout_particles`` R particles of an rbpf belief used for rollouts
    (None: all); ``press_lengths`` the prefix lengths scored (default 1, 2, 4, 8 and
    ``ceil((max(rows, cols) - 1) / p_move) + 1``); ``step_cost`` the cost of a step, in units of
    the information one observation gives about a cell of unknown label (``I0`` above;
    ``"auto"``: 0.05 without frontier targets, 0.6 with them, :data:`TARGETS_STEP_COST`);
    ``location_weight`` the weight of ``H(L)`` in ``U``, also in units of ``I0``; ``commit`` the most steps of a chosen
    macro-action executed before re-planning; ``anchor_every`` the steps from the start of one press into
    the nearest corner to the start of the next (None: never; ``"auto"``: twice the anchor's
    presses plus 8, 60 in the 10 x 10 world; see the module docstring); ``gamma`` the discount of the
    policy-iteration plan; ``seed`` (int, None or Generator) the planner's own random stream;
    ``loop_closing`` (default False) returns to places mapped while the robot was localised when the
    location belief spreads, with ``close_above``, ``close_below`` and ``close_steps``
    (:mod:`policies.loop_closing`, :func:`~policies.loop_closing.loop_closer`);
    ``information_unit`` (:data:`INFORMATION_UNITS`, default "prior") the cell whose ``I0`` is the
    unit of ``step_cost`` and ``location_weight`` (:meth:`unit`); ``threads`` (default 1;
    None: ``NUMBA_NUM_THREADS``) the threads a plan's rollouts use with an rbpf (footprint and
    blocking worlds: the hypothetical worlds split between them, the scores the same bit for bit
    whatever the count; :func:`policies.kernels.footprint.plan_rollouts`).

    The planner rolls hypotheses out on copies of the live estimator, so it must see it:
    :func:`policies.explore` calls :meth:`bind` before the first decision. Planning never
    changes the live estimator (its arrays and random generator).
    """

    def __init__(self, model: GridModel, seed: SeedLike = None, *, hypotheses: int | None = 12,
                 rollout_particles: int | None = 64, press_lengths=None, step_cost: float | str = "auto",
                 location_weight: float = 4.0, commit: int = 8, anchor_every: int | str | None = "auto",
                 gamma: float = 0.95, targets: int | str = "auto", loop_closing: bool = False,
                 close_above: float | None = None, close_below: float | None = None, close_steps: int | None = None,
                 information_unit: str = "prior", threads: int | None = 1):
        self.model = model
        self.threads = thread_count(threads)
        self.hypotheses = None if hypotheses is None else arguments.integer("hypotheses", hypotheses, minimum=1,
                                                                            error=InvalidOptionError)
        self.rollout_particles = None if rollout_particles is None else arguments.integer(
            "rollout_particles", rollout_particles, minimum=1, error=InvalidOptionError)
        self.location_weight = arguments.real("location_weight", location_weight, low=0.0, high=math.inf,
                                              high_open=True, error=InvalidOptionError)
        self.commit = arguments.integer("commit", commit, minimum=1, error=InvalidOptionError)
        self.gamma = arguments.real("gamma", gamma, low=0.0, high=1.0, high_open=True, error=InvalidOptionError)
        if press_lengths is None:
            longest = math.ceil((max(model.rows, model.cols) - 1) / max(model.p_move, 0.05)) + 1
            press_lengths = sorted({k for k in (1, 2, 4, 8) if k < longest} | {longest})
        self.press_lengths = _lengths(press_lengths)
        paper = model.is_paper_model
        if isinstance(targets, str):
            arguments.choice("targets", targets, ("auto",), error=InvalidOptionError)
            targets = 0 if paper or model.p_move == 0 else DEFAULT_TARGETS
        self.targets = arguments.integer("targets", targets, minimum=0, error=InvalidOptionError)
        if isinstance(step_cost, str):
            arguments.choice("step_cost", step_cost, ("auto",), error=InvalidOptionError)
            step_cost = STEP_COST if self.targets == 0 else TARGETS_STEP_COST
        self.step_cost = arguments.real("step_cost", step_cost, low=0.0, high=math.inf, high_open=True,
                                        error=InvalidOptionError)
        self._check_cost(self.rollout_particles)
        anchor_length = int(self.press_lengths[-1]) * ((model.rows > 1) + (model.cols > 1))
        if isinstance(anchor_every, str):
            arguments.choice("anchor_every", anchor_every, ("auto",), error=InvalidOptionError)
            # 60 in the 10 x 10 world: under half the steps anchoring; no corner to press into in a building
            anchor_every = 2 * anchor_length + 8 if self.targets == 0 else None
        if anchor_every is not None:
            anchor_every = arguments.integer("anchor_every", anchor_every, error=InvalidOptionError)
            if anchor_every <= anchor_length:
                raise InvalidOptionError(f"anchor_every must be 'auto', None or longer than the {anchor_length} presses "
                                         f"of an anchor (the robot would do nothing else), got {anchor_every!r}")
        self.anchor_every = anchor_every
        self.rng = as_generator(arguments.seed("seed", seed, error=InvalidOptionError))
        self.estimator: Estimator | None = None
        self.last_plan: MacroScore | None = None
        self._queue: list[int] = []
        self._since_anchor = 0
        self._pi: PolicyIterationResult | None = None
        self._tables = rollout_tables(model, int(self.press_lengths[-1]))
        self._kept = KeptBuffers()  # the rollouts' buffers, reused from plan to plan
        self.frontier = FrontierExplorer(model) if self.targets else None  # where the unknown is
        self.presses = PressMemory(model)  # blocked and futile presses, for the moves towards a target
        self.closer = loop_closer(model, loop_closing, close_above, close_below, close_steps,
                                  0.05 if self.frontier is None else self.frontier.min_passable)
        self._target, self._target_steps = -1, 0
        self.information_unit = arguments.choice("information_unit", information_unit, INFORMATION_UNITS,
                                                 error=InvalidOptionError)
        self._uniform_nats = unit_information(model.sensor)  # I0 of a uniformly unknown cell

    def _check_cost(self, particles: int | None) -> None:
        """Refuse (InvalidOptionError naming the options, with the estimate) a plan of more than
        :data:`onlinemap.arguments.MAX_OPERATIONS` operations or, enumerating, :data:`MAX_PLAN_FORKS` forks.
        ``particles``: the R particles a rollout carries (None: not known yet, checked at bind)."""
        model, horizon = self.model, int(self.press_lengths[-1])
        candidates = model.n_actions + max(self.targets, 1)
        if self.hypotheses is None:
            outcomes = observation_count(model)
            forks, level = 0, 1
            for _ in range(horizon):
                level *= outcomes
                forks += candidates * level
                if forks > MAX_PLAN_FORKS:
                    raise InvalidOptionError(
                        f"info_gain with hypotheses=None enumerates every observation ({outcomes} a step) over "
                        f"press_lengths up to {horizon}: more than {MAX_PLAN_FORKS:.0e} estimator forks a plan "
                        f"(at least {forks:.3g}); give hypotheses (worlds sampled) or shorter press_lengths")
            return
        if particles is None:
            return
        work = rollout_operations(model, self.hypotheses, candidates, horizon, len(self.press_lengths), particles)
        arguments.bounded_work(
            f"a plan of info_gain (hypotheses={self.hypotheses} worlds x {candidates} candidates x press_lengths up "
            f"to {horizon} steps x {particles} particles)", work,
            "lower hypotheses, rollout_particles or press_lengths", error=InvalidOptionError)

    def bind(self, estimator: Estimator) -> None:
        """Plan on copies of ``estimator`` (the live filter of the exploration loop)."""
        if estimator.model is not self.model:
            raise ModelError("the estimator was built for a different model than the planner")
        if self.rollout_particles is None and isinstance(estimator, HoldsParticles):
            self._check_cost(estimator.n_particles)
        self.estimator = estimator
        self._queue = []
        self._since_anchor = 0
        self._target, self._target_steps = -1, 0

    def unit(self) -> float:
        """``I0`` of the next plan, nats: with ``information_unit="prior"`` what one observation
        teaches about a cell not yet read, at the bound estimator's ``label_frequencies`` (learned
        or given: :func:`~policies.information.unit_information`), so that ``step_cost`` and
        ``location_weight`` keep their meaning (observations of an unread cell) when a sharper
        prior leaves less to learn per cell; that of a uniformly unknown cell when the estimator
        has no frequencies (the model's own table) or with ``information_unit="uniform"``. O(K^2)."""
        frequencies = self._unread_frequencies()
        if frequencies is None:
            return self._uniform_nats
        nats = unit_information(self.model.sensor, frequencies)
        return nats if nats > 0.0 else self._uniform_nats  # a prior sure of every unread cell: keep the uniform scale

    def unread_entropy(self) -> float | None:
        """The label entropy (nats) of a cell not yet read, at the bound estimator's
        ``label_frequencies``, with ``information_unit="prior"``: the frontier's unit of
        uncertainty (:meth:`policies.frontier.FrontierExplorer.plan` ``scale``) for the targets
        and the fallback presses. None (the frontier's ``log K``) without frequencies, with a
        prior sure of every unread cell, or with ``information_unit="uniform"``. O(K)."""
        frequencies = self._unread_frequencies()
        nats = None if frequencies is None else float(entropy(np.asarray(frequencies)))
        return nats if nats else None

    def _unread_frequencies(self) -> np.ndarray | None:
        """(K,) the label frequencies of cells not yet read that the unit follows: the bound
        estimator's ``label_frequencies`` with ``information_unit="prior"``, else None."""
        if self.information_unit == "uniform":
            return None
        return getattr(self.estimator, "label_frequencies", None)

    @property
    def pending(self) -> int:
        """The presses of the chosen macro-action (or anchor, or moves towards a target) still to
        make; 0: the next :meth:`choose` decides anew (it plans, or anchors)."""
        return len(self._queue) + self._target_steps

    def choose(self, belief: Belief) -> int:
        if self.estimator is None:
            raise ModelError("info_gain plans on the live estimator: call planner.bind(estimator) first "
                             "(policies.explore does)")
        if self.closer is not None and self.closer.update(belief).closing:
            self._queue, self._target_steps = [], 0  # exploring resumes with a new plan
            self._since_anchor += 1
            action = self.closer.press(belief, self.closer.last.target, self.presses)
            self.presses.pressed(belief, action)
            return action
        if self._queue and self.model.has_blocking and not unblocked_actions(self.model, belief)[self._queue[0]]:
            self._queue = []  # the belief now says the next press blocks: re-plan
        if self._target_steps and self._target >= 0 and belief.location[self._target] > 0.5:
            self._target_steps = 0  # most probably there: re-plan
        if not self._queue and not self._target_steps:
            if self.anchor_every is not None and self._since_anchor >= self.anchor_every:
                self._queue = anchor_actions(self.model, belief, int(self.press_lengths[-1])).tolist()
                self._since_anchor = 0
            else:
                plan = self.plan(belief)
                c, j = plan.chosen
                steps = min(int(plan.lengths[j]), self.commit)
                if not plan.pays and self.frontier is not None:  # the frontier baseline's presses
                    self._target, self._target_steps = -1, steps
                elif plan.targets[c] >= 0:
                    self._target, self._target_steps = int(plan.targets[c]), steps
                else:
                    self._queue = plan.sequences[c, :steps].tolist()
        self._since_anchor += 1
        if self._target_steps:
            self._target_steps -= 1
            action = (self.toward(belief, self._target) if self._target >= 0
                      else self.frontier.choose(belief, self.unread_entropy()))
        else:
            action = int(self._queue.pop(0))
        self.presses.pressed(belief, action)
        return action

    def toward(self, belief: Belief, target: int) -> int:
        """The press that brings the robot closest to ``target`` in expected steps, averaged over
        the location belief (the frontier's rule, :func:`~policies.passability.steps_after_press`
        on the belief's passability), among the presses :class:`~policies.passability.PressMemory`
        allows. O(N A log(N A)) (one Dijkstra)."""
        frontier = self.frontier  # a target comes from it: set whenever targets > 0
        cost = press_costs(self.model, belief, expected_passability(self.model, belief), [target],
                           frontier.min_passable, frontier.penalty)
        return int(np.argmin(np.where(self.presses.allowed(belief), cost, np.inf)))

    def candidates(self, belief: Belief) -> Candidates:
        """Press each direction H times; then, with ``targets`` 0, the :func:`greedy_path` on the
        policy-iteration ``Q`` of :func:`~policies.information.information_reward` from the most probable location (with
        blocking labels, on the belief's expected passability; one warm-started policy iteration
        over N cells); with ``targets`` T > 0, the moves towards each of the best T frontier
        targets (:func:`frontier_targets`), in closed loop (sequence -1: each press chosen on the
        rollout's belief by :func:`~policies.passability.steps_after_press`; O(T N A log(N A)))."""
        model, horizon = self.model, int(self.press_lengths[-1])
        names = [f"press {name}" for name in model.action_names]
        sequences = [np.full(horizon, a, dtype=np.int64) for a in range(model.n_actions)]
        targets = [-1] * len(names)
        passable = expected_passability(model, belief) if model.has_blocking else None
        if self.targets == 0:
            reward = information_reward(belief, model.sensor)
            self._pi = policy_iteration(model, reward, self.gamma, passable=passable,
                                        initial_policy=None if self._pi is None else self._pi.policy)
            path = greedy_path(model, self._pi.q, int(np.argmax(belief.location)), horizon)
            if not any(np.array_equal(path, s) for s in sequences):
                names.append("plan")
                sequences.append(path)
                targets.append(-1)
            return Candidates(tuple(names), np.stack(sequences), np.asarray(targets), None, None)
        passable = expected_passability(model, belief) if passable is None else passable
        frontier = self.frontier
        chosen = frontier_targets(model, frontier.plan(belief, self.unread_entropy()), self.targets,
                                  skip=belief.location > 0.5)
        distances = [np.zeros(model.n_cells)] * len(names)
        for cell in chosen:
            names.append(f"to {divmod(int(cell), model.cols)}")
            sequences.append(np.full(horizon, -1, dtype=np.int64))
            targets.append(int(cell))
            distances.append(_finite(distances_to(model, passable, [cell], frontier.min_passable), frontier.penalty))
        return Candidates(tuple(names), np.stack(sequences), np.asarray(targets), np.stack(distances),
                          move_chances(model, passable, frontier.min_passable))

    def plan(self, belief: Belief) -> MacroScore:
        """Score every candidate at every length in ``press_lengths`` and pick the best utility
        (ties: the shorter, then the earlier candidate), leaving out macro-actions whose first
        action leaves the robot in place with probability >= 1/2 (pressing into a wall it is
        known to stand against; otherwise, when nothing pays its cost, such a press costs least
        and the robot would stand still); with blocking labels, also those whose first press the
        belief says blocks (:func:`~policies.passability.unblocked_actions`), and a queued press it
        says blocks ends the queue.
        Never changes the live estimator."""
        est = self.estimator
        unit = self.unit()
        location_nats = self.location_weight * unit
        names, sequences, targets, distances, go = self.candidates(belief)
        horizon = sequences.shape[1]
        lengths = self.press_lengths
        checkpoints = np.zeros(horizon + 1, dtype=np.bool_)
        checkpoints[0] = True
        checkpoints[lengths] = True
        if self.hypotheses is not None and isinstance(est, HoldsParticles):
            worlds = sample_states(est, self.hypotheses, self.rng)
            particles = est.particle_snapshot(self.rollout_particles, self.rng)
            if self.model.is_paper_model and distances is None:
                expected = particle_expected_uncertainty(self.model, particles, sequences, checkpoints, worlds,
                                                         self.rng, location_nats, self._tables)
            else:
                expected = footprint_expected_uncertainty(self.model, particles, sequences, checkpoints, worlds,
                                                          self.rng, location_nats, self._tables, distances, go,
                                                          self.threads, kept=self._kept)
        else:  # forks take fixed actions: a move towards a target is its walk from the most probable cell
            start = int(np.argmax(belief.location))
            fixed = [s if t < 0 else descent(self.model, go, distances[c], start, horizon)
                     for c, (s, t) in enumerate(zip(sequences, targets))]
            expected = np.stack([expected_uncertainty(est, s, hypotheses=self.hypotheses, seed=self.rng,
                                                      location_weight=location_nats) for s in fixed])
        gain = expected[:, :1] - expected[:, lengths]
        utility = gain - self.step_cost * unit * lengths[None, :]
        # a macro-action whose first press most probably hits a wall only re-reads the same cell
        first = np.maximum(sequences[:, 0], 0)  # a move towards a target chooses its presses as it goes
        stays = belief.location @ (self.model.neighbors[:, first] == np.arange(self.model.n_cells)[:, None])
        through = (stays < 0.5) | np.all(stays >= 0.5) | (targets >= 0)
        if self.model.has_blocking:  # nor one whose first press the belief says blocks
            through &= unblocked_actions(self.model, belief)[first] | (targets >= 0)
            through = through if through.any() else np.ones_like(through)
        allowed = np.where(through[:, None], utility, -np.inf)
        best = np.flatnonzero(allowed.T.ravel() == allowed.max())[0]  # length-major: shorter first
        j, c = divmod(int(best), len(names))
        self.last_plan = MacroScore(names, sequences, lengths, gain, utility, (c, j), targets, allowed.max() > 0.0,
                                   unit)
        return self.last_plan

    def __repr__(self) -> str:
        return (f"InfoGainExplorer(hypotheses={self.hypotheses}, rollout_particles={self.rollout_particles}, "
                f"press_lengths={self.press_lengths.tolist()}, step_cost={self.step_cost}, "
                f"location_weight={self.location_weight}, commit={self.commit}, anchor_every={self.anchor_every}, "
                f"targets={self.targets}" + ("" if self.closer is None else f", loop_closing=True, {self.closer!r}")
                + ("" if self.information_unit == "prior" else f", information_unit={self.information_unit!r}") + ")")
