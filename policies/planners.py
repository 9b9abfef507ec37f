"""Planners: one interface, ``choose(belief) -> action index``.

- :class:`EntropyExplorer` re-plans from the belief (entropy reward, policy iteration) and
  acts by maximising ``sum_l P(l) Q(l, a)`` (the Q-MDP rule: act as if the location
  uncertainty vanished after this step).
- :class:`RandomWalk` draws actions uniformly.
- :class:`Sweep` follows a fixed boustrophedon (lawn-mower) pattern and ignores beliefs.

In a world with blocking labels (``model.has_blocking``) every planner plans with the belief's
passability (:mod:`policies.passability`): the entropy planner's MDP moves into cell j with
``p_move * P(m_j passable)``, and no planner presses a move the belief says blocks with
probability above 0.99 (:func:`~policies.passability.unblocked_actions`) while another exists.
Without blocking labels nothing of this runs: the planners are bit for bit the design's.

:data:`PLANNERS` is the registry (name -> class and fixed options; the exploration planner
``info_gain`` lives in :mod:`policies.info_gain`, the baseline ``frontier`` in
:mod:`policies.frontier`, the goal planners ``goto`` and ``static_goto`` in
:mod:`policies.navigation`); :func:`make_planner` builds one by name and
:func:`planner_options` lists a name's options without building anything.
"""

from __future__ import annotations

import inspect
import math
from typing import NamedTuple, Protocol, runtime_checkable

import numpy as np

from onlinemap import arguments
from onlinemap.belief import Belief
from onlinemap.errors import InvalidOptionError, ModelError
from onlinemap.model import GridModel
from onlinemap.rng import SeedLike, as_generator

from .frontier import FrontierExplorer
from .info_gain import InfoGainExplorer
from .mdp import PolicyIterationResult, policy_iteration
from .navigation import GoTo, StaticGoTo
from .passability import PressMemory, expected_passability, unblocked_actions
from .rewards import RewardFunction, collected_entropy_reward, entropy_reward


@runtime_checkable
class Planner(Protocol):
    """Chooses the next action from the current belief."""

    model: GridModel

    def choose(self, belief: Belief) -> int:
        """The action (index into ``model.action_names``) to take next."""


class EntropyExplorer:
    """Active exploration (DESIGN.md section 4).

    Every ``replan_every`` calls: reward ``R = reward(belief)`` (default
    :func:`~policies.rewards.entropy_reward`), ``Q`` by :func:`~policies.mdp.policy_iteration`
    with discount ``gamma`` (warm-started from the previous plan; with blocking labels, on the
    belief's expected passability). Every call: the action maximising ``sum_l P(l) Q(l, a)``
    (ties go to the lowest action index); with blocking labels, among those the belief does not
    say block and that are not futile (:class:`~policies.passability.PressMemory`: a press after
    which the belief did not change is not repeated until it changes).
    Cost per re-plan: a few sparse solves over N cells; per call O(N A).
    """

    def __init__(self, model: GridModel, gamma: float = 0.95, replan_every: int = 1,
                 reward: RewardFunction = entropy_reward):
        self.model = model
        self.gamma = arguments.real("gamma", gamma, low=0.0, high=1.0, high_open=True, error=InvalidOptionError)
        self.replan_every = arguments.integer("replan_every", replan_every, minimum=1, error=InvalidOptionError)
        if not callable(reward):
            raise InvalidOptionError(f"reward must be a function of the belief (policies.rewards), got {reward!r}")
        self.reward = reward
        self.plan: PolicyIterationResult | None = None
        self.presses = PressMemory(model)  # with blocking labels: blocked and futile presses
        self._calls = 0

    def choose(self, belief: Belief) -> int:
        if self.plan is None or self._calls % self.replan_every == 0:
            previous = None if self.plan is None else self.plan.policy
            passable = expected_passability(self.model, belief) if self.model.has_blocking else None
            self.plan = policy_iteration(self.model, self.reward(belief), self.gamma,
                                         initial_policy=previous, passable=passable)
        self._calls += 1
        value = belief.location @ self.plan.q
        if not self.model.has_blocking:
            return int(np.argmax(value))
        action = int(np.argmax(np.where(self.presses.allowed(belief), value, -np.inf)))
        self.presses.pressed(belief, action)
        return action

    def __repr__(self) -> str:
        return (f"EntropyExplorer(gamma={self.gamma}, replan_every={self.replan_every}, "
                f"reward={getattr(self.reward, '__name__', self.reward)})")


class RandomWalk:
    """Uniformly random actions from ``seed`` (an int, None or a Generator). With blocking labels,
    uniform over the actions the belief does not say block when it says some do
    (:func:`~policies.passability.unblocked_actions`); otherwise it ignores beliefs."""

    def __init__(self, model: GridModel, seed: SeedLike = None):
        self.model = model
        self.rng = as_generator(arguments.seed("seed", seed, error=InvalidOptionError))

    def choose(self, belief: Belief) -> int:
        if self.model.has_blocking:
            allowed = np.flatnonzero(unblocked_actions(self.model, belief))
            if len(allowed) < self.model.n_actions:
                return int(allowed[self.rng.integers(len(allowed))])
        return int(self.rng.integers(self.model.n_actions))

    def __repr__(self) -> str:
        return "RandomWalk()"


def sweep_actions(model: GridModel) -> np.ndarray:
    """One cycle of the boustrophedon from the top-left corner, as action indices.

    Grid: rows 0, 1, ..., R-1, R-2, ..., 1 (then back to 0), alternately east and west along
    each, one step south (north on the way back) between rows. Each row is pressed
    ``ceil((cols - 1) / p_move)`` times so that, with slips, the robot is expected to reach the
    far end (extra presses at the edge stay put). Corridor: right then left, as many presses.
    Raises ModelError when p_move = 0 (the robot never moves: no sweep covers the grid).
    """
    names = model.action_names
    if model.p_move <= 0:
        raise ModelError("Sweep needs p_move > 0: with p_move = 0 the robot never moves, so no number "
                         "of presses reaches the far end of a row")
    presses = max(1, math.ceil((model.cols - 1) / model.p_move))
    if set(names) == {"left", "right"}:
        return np.array([names.index("right")] * presses + [names.index("left")] * presses, dtype=np.int64)
    if set(names) != {"north", "east", "south", "west"}:
        raise ModelError(f"Sweep needs corridor (left, right) or grid (north, east, south, west) actions, got {names}")
    east, west, north, south = (names.index(n) for n in ("east", "west", "north", "south"))
    order = list(range(model.rows)) + list(range(model.rows - 2, 0, -1)) + [0]
    actions = []
    for k, (row, next_row) in enumerate(zip(order[:-1], order[1:])):
        actions += [east if k % 2 == 0 else west] * presses
        actions.append(south if next_row > row else north)
    return np.array(actions, dtype=np.int64)


class Sweep:
    """Coverage sweep: repeats :func:`sweep_actions` open loop, whatever the belief.

    With blocking labels, a press the belief says blocks
    (:func:`~policies.passability.unblocked_actions`) is skipped, and so are the presses after it
    in the cycle up to the first one the belief lets through: a row cut by a wall ends at the
    wall, and the sweep goes on with the step to the next row. (Every press of the cycle blocked:
    nothing is skipped.)"""

    def __init__(self, model: GridModel):
        self.model = model
        self.actions = sweep_actions(model)
        self._calls = 0

    def choose(self, belief: Belief) -> int:
        if self.model.has_blocking:
            allowed = unblocked_actions(self.model, belief)
            cycle = np.roll(self.actions, -(self._calls % len(self.actions)))
            through = np.flatnonzero(allowed[cycle])
            self._calls += int(through[0]) if len(through) else 0
        action = int(self.actions[self._calls % len(self.actions)])
        self._calls += 1
        return action

    def __repr__(self) -> str:
        return f"Sweep({len(self.actions)} actions per cycle)"


class PlannerEntry(NamedTuple):
    """A registered planner: its class and the keyword arguments its name fixes."""

    cls: type
    fixed: dict


#: name -> planner class (and fixed keywords). The options of a name are its class's keyword
#: parameters after the model, less ``seed`` and the fixed ones (:func:`planner_options`).
PLANNERS: dict[str, PlannerEntry] = {
    "entropy": PlannerEntry(EntropyExplorer, {}),
    "entropy_collect": PlannerEntry(EntropyExplorer, {"reward": collected_entropy_reward}),
    "random": PlannerEntry(RandomWalk, {}),
    "sweep": PlannerEntry(Sweep, {}),
    "info_gain": PlannerEntry(InfoGainExplorer, {}),
    "frontier": PlannerEntry(FrontierExplorer, {}),
    "goto": PlannerEntry(GoTo, {}),
    "static_goto": PlannerEntry(StaticGoTo, {}),
}


def _entry(name: str) -> PlannerEntry:
    if name not in PLANNERS:
        raise ModelError(f"unknown planner {name!r}; available: {', '.join(PLANNERS)}")
    return PLANNERS[name]


def _parameters(cls: type) -> list[inspect.Parameter]:
    """The keyword parameters of ``cls.__init__`` after ``self`` and the model."""
    params = list(inspect.signature(cls.__init__).parameters.values())[2:]
    return [p for p in params if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)]


def planner_options(name: str) -> dict[str, object]:
    """The options of planner ``name`` and their defaults (no planner is built)."""
    entry = _entry(name)
    return {p.name: p.default for p in _parameters(entry.cls) if p.name != "seed" and p.name not in entry.fixed}


def planner_class(name: str) -> type:
    """The class :func:`make_planner` builds for ``name`` (its ``__init__`` annotates the options)."""
    return _entry(name).cls


def make_planner(name: str, model: GridModel, seed: SeedLike = None, **options) -> Planner:
    """Planner by registered name (:data:`PLANNERS`): ``entropy`` (:class:`EntropyExplorer`;
    options gamma, replan_every, reward), ``entropy_collect`` (the same with
    :func:`~policies.rewards.collected_entropy_reward`), ``random`` (:class:`RandomWalk`),
    ``sweep`` (:class:`Sweep`), ``info_gain`` (:class:`~policies.info_gain.InfoGainExplorer`),
    ``frontier`` (:class:`~policies.frontier.FrontierExplorer`),
    ``goto`` and ``static_goto`` (:class:`~policies.navigation.GoTo`, :class:`~policies.navigation.StaticGoTo`;
    options goal (required), horizon).
    ``seed`` goes to planners that draw random numbers. Unknown options raise InvalidOptionError."""
    entry = _entry(name)
    known = planner_options(name)
    unknown = sorted(set(options) - set(known))
    if unknown:
        raise InvalidOptionError(f"planner {name!r} has no option {', '.join(unknown)}; its options: "
                                 f"{', '.join(known) or 'none'}")
    if any(p.name == "seed" for p in _parameters(entry.cls)):
        options["seed"] = seed
    return entry.cls(model, **entry.fixed, **options)
