"""Active loop closing for the exploration planners (after Stachniss, Hähnel and Burgard 2004,
"Exploration with active loop-closing for FastSLAM"; DESIGN.md sections 7 and 8).

A particle filter that maps while it explores keeps several location hypotheses, each with the
map its own path built. Pushing on into new corridors while they spread lets the wrong ones
build maps that explain their data as well as the right one's, and the filter loses the robot
for good. Returning to a place mapped while the robot knew where it was tells them apart: each
hypothesis predicts that place's readings from its own map, and only the right one predicts
them where it stands. The planners (:class:`~policies.info_gain.InfoGainExplorer`,
:class:`~policies.frontier.FrontierExplorer`, option ``loop_closing``) consult a
:class:`LoopCloser` at every decision:

- *Spread* of the location belief ``P`` (N,): the expected grid distance (rows plus columns)
  between two locations drawn independently from it, ``s = sum_ij P(i) P(j) d(i, j)``, i.e. the
  expected distance between two particles' locations (:func:`location_spread`; 0 when the belief
  holds one cell, 0.5 for two neighbours at 1/2 each).
- *Localised places*: every decision at which ``s <= close_below`` marks the belief's most
  probable cell (the start cell first): places the robot stood on while it was localised, so
  mapped in the history every surviving hypothesis shares.
- *Closing*: when ``s > close_above`` (and some place is marked), the planner stops exploring and
  heads for the localised place ``c`` of highest score ``sum_f (1 - u_{c_f}) - distance_cost E(c)``:
  the certain cells of the footprint read there (``u`` the normalised label entropy: readings
  every hypothesis can predict, so the ones that separate them), less the expected steps to it
  from the location hypotheses (``E`` as in :mod:`policies.frontier`, on the belief's
  passability). A place the belief most probably stands on (``P(c) > 1/2``) is done for this loop;
  the next best is taken. Each press is the one of least expected steps to the target, averaged
  over the location belief (:func:`~policies.passability.press_costs`), among the presses the
  planner's :class:`~policies.passability.PressMemory` allows.
- *Resuming*: when ``s <= close_below`` again (the loop closed), or every marked place is done,
  or after ``close_steps`` decisions of closing; in the last two cases (the loop did not close)
  the planner explores for ``close_steps`` decisions before it may close again, so a belief that
  revisiting cannot resolve does not hold the robot in place.

Cost per decision: O(N) for the spread; while closing, at most ``hypotheses`` + 1 Dijkstras,
O((M + 1) N A log(N A)), plus O(N (F + K)).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from onlinemap import arguments
from onlinemap.belief import Belief
from onlinemap.errors import InvalidOptionError
from onlinemap.metrics import normalized_entropy
from onlinemap.model import GridModel

from .passability import (PressMemory, distances_from, expected_passability, location_hypotheses, press_costs)

CLOSE_ABOVE = 1.0  # close_above None: cells of spread (tuned on frontier, building 1, 600 steps)
CLOSE_BELOW = 0.5  # close_below None
DISTANCE_COST = 0.2  # footprint cells of certainty one expected step is worth (the frontier's default)
HYPOTHESES = 16  # location hypotheses the expected distance to a place averages over (the frontier's default)


def _pair_distance(p: np.ndarray) -> float:
    """``E|X - Y|`` for X, Y independent on 0..n-1 with probabilities ``p`` (n,) summing to 1:
    ``2 sum_t F(t) (1 - F(t))``, F the cumulative distribution. O(n)."""
    cumulative = np.cumsum(p)[:-1]
    return 2.0 * float(np.sum(cumulative * (1.0 - cumulative)))


def location_spread(model: GridModel, location: np.ndarray) -> float:
    """The expected grid distance (rows plus columns) between two cells drawn independently from
    ``location`` (N,), in cells: ``sum_ij P(i) P(j) (|r_i - r_j| + |c_i - c_j|)``, which splits
    into the rows' and the columns' marginals. O(N)."""
    grid = np.asarray(location, dtype=np.float64).reshape(model.rows, model.cols)
    grid = grid / grid.sum()
    return _pair_distance(grid.sum(axis=1)) + _pair_distance(grid.sum(axis=0))


class ClosingStep(NamedTuple):
    """One decision of :class:`LoopCloser`."""

    closing: bool  # the planner heads for a localised place (else it explores)
    target: int  # the place it heads for, -1 when exploring
    spread: float  # location_spread of the belief, cells


class LoopCloser:
    """The explore / close switch of the module docstring, for one run (it remembers the
    localised places). ``close_above`` > ``close_below`` > 0 in cells of spread, ``close_steps``
    >= 1 decisions; ``min_passable`` as the planner's passability model uses it
    (:mod:`policies.passability`; a path that cannot be taken counts more steps than any path).
    Build it with :func:`loop_closer`."""

    def __init__(self, model: GridModel, close_above: float, close_below: float, close_steps: int,
                 min_passable: float = 0.05):
        self.model = model
        self.close_above, self.close_below, self.close_steps = close_above, close_below, close_steps
        self.min_passable = min_passable
        self.penalty = model.n_cells / (max(model.p_move, 1e-12) * min_passable)  # above any path's cost
        self.localised = np.zeros(model.n_cells, dtype=bool)  # (N,) places marked while localised
        self.done = np.zeros(model.n_cells, dtype=bool)  # (N,) places reached in this loop
        self.closing = False
        self._steps = 0  # decisions in this loop, or left to explore before the next may start
        self.last: ClosingStep | None = None

    def update(self, belief: Belief) -> ClosingStep:
        """Mark, switch and pick the target for this decision (module docstring)."""
        spread = location_spread(self.model, belief.location)
        concentrated = spread <= self.close_below
        if concentrated:
            self.localised[int(np.argmax(belief.location))] = True
        if self.closing:
            self._steps += 1
            if concentrated:
                self.closing, self._steps = False, 0
            elif self._steps > self.close_steps:
                self._give_up()
        elif self._steps > 0:
            self._steps -= 1
        elif spread > self.close_above and self.localised.any():
            self.closing, self._steps = True, 1
            self.done[:] = False
        target = self._target(belief) if self.closing else -1
        if self.closing and target < 0:
            self._give_up()
        self.last = ClosingStep(self.closing, target, spread)
        return self.last

    def _give_up(self) -> None:
        """The loop did not close: explore for ``close_steps`` decisions before the next."""
        self.closing, self._steps = False, self.close_steps

    def _target(self, belief: Belief) -> int:
        """The best localised place not yet done in this loop, -1 if none is left or reachable."""
        self.done |= self.localised & (belief.location > 0.5)
        places = self.localised & ~self.done
        if not places.any():
            return -1
        model = self.model
        passable = expected_passability(model, belief)
        cells, weights = location_hypotheses(belief.location, HYPOTHESES)
        paths = distances_from(model, passable, cells, self.min_passable)  # (M, N)
        places &= np.isfinite(paths).any(axis=0)
        if not places.any():
            return -1
        expected = weights @ np.where(np.isfinite(paths), paths, self.penalty)
        certain = 1.0 - normalized_entropy(belief.map)
        on_grid = model.footprint_cells >= 0
        known = np.where(on_grid, certain[model.footprint_cells.clip(0)], 0.0).sum(axis=1)
        score = np.where(places, known - DISTANCE_COST * expected, -np.inf)
        return int(np.argmax(score))

    def press(self, belief: Belief, target: int, presses: PressMemory) -> int:
        """The press of least expected steps to ``target`` among those ``presses`` allows."""
        cost = press_costs(self.model, belief, expected_passability(self.model, belief), [target],
                           self.min_passable, self.penalty)
        return int(np.argmin(np.where(presses.allowed(belief), cost, np.inf)))

    def __repr__(self) -> str:
        return f"close_above={self.close_above}, close_below={self.close_below}, close_steps={self.close_steps}"


def loop_closer(model: GridModel, loop_closing: bool, close_above: float | None, close_below: float | None,
                close_steps: int | None, min_passable: float = 0.05) -> LoopCloser | None:
    """The planners' options checked: None when ``loop_closing`` is False (then the threshold
    options must be None: they would mean nothing); else a :class:`LoopCloser` with
    ``close_above`` (None: :data:`CLOSE_ABOVE`), ``close_below`` (None: :data:`CLOSE_BELOW`, and
    below ``close_above``) and ``close_steps`` (None: ``rows + cols``, about the steps across the
    grid and back to a place half way). InvalidOptionError naming the option otherwise."""
    if not isinstance(loop_closing, (bool, np.bool_)):
        raise InvalidOptionError(f"loop_closing must be True or False, got {loop_closing!r}")
    given = [name for name, value in (("close_above", close_above), ("close_below", close_below),
                                      ("close_steps", close_steps)) if value is not None]
    if not loop_closing:
        if given:
            raise InvalidOptionError(f"{', '.join(given)} set how loop closing acts; they mean nothing with "
                                     f"loop_closing=False")
        return None
    above = CLOSE_ABOVE if close_above is None else arguments.real(
        "close_above", close_above, low=0.0, high=math.inf, low_open=True, high_open=True, error=InvalidOptionError)
    below = min(CLOSE_BELOW, above / 2) if close_below is None else arguments.real(
        "close_below", close_below, low=0.0, high=math.inf, low_open=True, high_open=True, error=InvalidOptionError)
    if below >= above:
        raise InvalidOptionError(f"close_below ({below}) must be below close_above ({above}): the robot would "
                                 f"stop closing a loop as soon as it starts one")
    steps = model.rows + model.cols if close_steps is None else arguments.integer(
        "close_steps", close_steps, minimum=1, error=InvalidOptionError)
    return LoopCloser(model, float(above), float(below), steps, min_passable)
