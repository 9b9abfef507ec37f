"""The frontier planner's and info_gain's rules on worlds of 3 to 9 cells where the gain, the
expected distance, the score and the chosen target or action are worked out by hand (issue 43
section 3). Entropies are computed here from their formula; no expected value is read from the
planners.

Frontier (policies/frontier.py's docstring): the gain of a cell sums the footprint's *uncertain*
cells' normalised entropies (strictly above ``threshold``); the expected distance averages the
hypotheses' path costs (``1 / (p_move passable)`` per cell entered); the target maximises
``gain - distance_cost E``; reachable means some hypothesis reaches it; a target on which E has
not fallen by half a step, against where it stood at the last fall or rise, for ``patience``
decisions is blacklisted. info_gain (policies/info_gain.py): ``utility = gain - step_cost I0
length`` with ``I0`` the information of one reading of an unknown cell, ``step_cost`` "auto"
0.05 in the paper's world and 0.6 with frontier targets, the shorter macro-action first on ties,
the frontier's press when no macro-action pays.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import onlinemap as om
from onlinemap.belief import Belief
from policies import FrontierExplorer, InfoGainExplorer, make_planner
from policies.passability import unblocked_actions


def h(p) -> float:
    """Entropy in nats of a distribution, from its formula."""
    return -sum(x * math.log(x) for x in p if x > 0)


def belief(location, maps) -> Belief:
    return Belief(0, np.asarray(location, dtype=float), np.asarray(maps, dtype=float))


def one_hot(n, cell):
    out = np.zeros(n)
    out[cell] = 1.0
    return out


# --- frontier: the gain ---------------------------------------------------------------------------
def test_the_gain_sums_the_footprints_uncertain_cells_only():
    """1 x 5 corridor, K = 2, the sensor reading a cell and both its neighbours. Normalised entropies
    u = H / ln 2: cell 0 certain (0), cell 1 [0.9, 0.1] (0.469, not above 0.5: not uncertain), cell 2
    [0.8, 0.2] (0.722), cell 3 certain, cell 4 uniform (1). g(c) sums u over c - 1, c, c + 1 where
    u > 0.5: g = [0, u2, u2, u2 + 1, 1]."""
    model = om.corridor(5, 2, footprint=((0, -1), (0, 0), (0, 1)))
    maps = [[1, 0], [0.9, 0.1], [0.8, 0.2], [1, 0], [0.5, 0.5]]
    u1, u2 = h([0.9, 0.1]) / math.log(2), h([0.8, 0.2]) / math.log(2)
    assert u1 < 0.5 < u2
    plan = FrontierExplorer(model).plan(belief(one_hot(5, 0), maps))
    np.testing.assert_allclose(plan.gain, [0, u2, u2, u2 + 1, 1], rtol=1e-12, atol=1e-15)
    assert plan.mode == "frontier"


def test_a_cell_exactly_at_the_threshold_is_not_uncertain():
    """K = 4 and [0.5, 0.5, 0, 0]: u = ln 2 / ln 4 = 1/2 exactly, the default threshold; "uncertain"
    is strictly above it, so nothing is a frontier and the robot revisits (gain = u itself)."""
    model = om.corridor(3, 4)
    maps = [[1, 0, 0, 0], [1, 0, 0, 0], [0.5, 0.5, 0, 0]]
    plan = FrontierExplorer(model).plan(belief(one_hot(3, 0), maps))
    assert plan.mode == "revisit"
    np.testing.assert_allclose(plan.gain, [0, 0, 0.5], atol=1e-15)
    plan = FrontierExplorer(model, threshold=0.49).plan(belief(one_hot(3, 0), maps))
    assert plan.mode == "frontier" and plan.targets.tolist() == [2]


# --- frontier: the score and the target -------------------------------------------------------------
@pytest.mark.parametrize("distance_cost, target, action", [
    (0.2, 0, "left"),    # 0.722 - 0.2 = 0.522 > 1 - 0.6 = 0.4
    (0.15, 0, "left"),   # 0.572 > 0.55
    (0.13, 4, "right"),  # 0.592 < 0.61: the two meet at distance_cost 0.139
    (0.05, 4, "right"),  # 0.672 < 0.85
    (0.0, 4, "right"),   # the most informative reachable place
])
def test_the_target_trades_the_gain_against_the_distance(distance_cost, target, action):
    """1 x 5 corridor, perfect wheels (a step costs 1), the sensor reads the robot's cell, the robot
    surely at cell 1. Cell 0 [0.8, 0.2] (u = 0.722, 1 step away), cell 4 uniform (u = 1, 3 steps
    away), the rest certain. Score = g - distance_cost E: cell 0 wins while 0.722 - c > 1 - 3 c,
    i.e. c > (1 - 0.722) / 2 = 0.139."""
    model = om.corridor(5, 2, p_move=1.0)
    maps = [[0.8, 0.2], [1, 0], [1, 0], [1, 0], [0.5, 0.5]]
    u0 = h([0.8, 0.2]) / math.log(2)
    planner = FrontierExplorer(model, distance_cost=distance_cost)
    chosen = planner.choose(belief(one_hot(5, 1), maps))
    plan = planner.last_plan
    np.testing.assert_allclose(plan.expected_distance, [1, 0, 1, 2, 3], atol=1e-12)
    np.testing.assert_allclose(plan.score[[0, 4]], [u0 - distance_cost, 1 - 3 * distance_cost], atol=1e-12)
    assert plan.targets.tolist() == [target] and model.action_names[chosen] == action


def test_the_expected_distance_averages_over_the_location_belief():
    """1 x 5 corridor, p_move 0.5 (a step costs 2 expected presses), the robot at cell 0 with 0.75 and
    at cell 2 with 0.25: E(c) = 0.75 * 2 c + 0.25 * 2 |c - 2| = [1, 2, 3, 5, 7] (the most probable
    cell alone would give [0, 2, 4, 6, 8])."""
    model = om.corridor(5, 2, p_move=0.5)
    maps = [[1, 0]] * 4 + [[0.5, 0.5]]
    plan = FrontierExplorer(model).plan(belief([0.75, 0, 0.25, 0, 0], maps))
    np.testing.assert_allclose(plan.expected_distance, [1, 2, 3, 5, 7], rtol=1e-12)


def test_the_action_minimises_the_expected_steps_over_the_location_belief():
    """1 x 5 corridor, p_move 0.5, the only uncertain cell 2 (the target): D = [4, 2, 0, 2, 4].
    The robot is at cell 3 with 0.4 (where "left" is best), at 0 and 1 with 0.3 each.
    cost(a) = sum_l P(l) [1 + q D(j) + (1 - q) D(l)] (q = 0.5, 0 into the grid's edge):
    left = 0.4 (1 + 0 + 1) + 0.3 (1 + 4) + 0.3 (1 + 2 + 1) = 3.5,
    right = 0.4 (1 + 2 + 1) + 0.3 (1 + 1 + 2) + 0.3 (1 + 0 + 1) = 3.4: "right"."""
    model = om.corridor(5, 2, p_move=0.5)
    maps = [[1, 0], [1, 0], [0.5, 0.5], [1, 0], [1, 0]]
    planner = FrontierExplorer(model)
    action = planner.choose(belief([0.3, 0.3, 0, 0.4, 0], maps))
    plan = planner.last_plan
    assert plan.targets.tolist() == [2]
    np.testing.assert_allclose(plan.distance, [4, 2, 0, 2, 4], atol=1e-12)
    np.testing.assert_allclose(plan.action_cost, [3.5, 3.4], rtol=1e-12)
    assert model.action_names[action] == "right"


BLOCKED = [[1, 0, 0], [1, 0, 0], [0, 0, 1], [1, 0, 0], [0.5, 0.5, 0]]  # K = 3, label 2 blocks: cell 2 a wall


def test_a_target_behind_a_wall_is_reachable_only_if_some_hypothesis_reaches_it():
    """1 x 5 corridor, labels 0, 1 passable and 2 blocking, perfect wheels; cell 2 surely a wall,
    cell 4 uncertain ([0.5, 0.5, 0]: passable for sure, u = ln 2 / ln 3 = 0.63) and cell 0 more so
    after a change below. Surely at cell 1: cells 2, 3, 4 are unreachable (E at the penalty
    N / (p_move min_passable) = 5 / 0.05 = 100) and the target is cell 0. Split between cells 1
    and 3: every cell but the wall is reachable by some hypothesis, E = (E_1 + E_3) / 2."""
    model = om.corridor(5, 3, p_move=1.0, blocking=[2])
    maps = np.array(BLOCKED, dtype=float)
    maps[0] = [0.6, 0.4, 0.0]  # u = 0.61: uncertain, less than cell 4
    plan = FrontierExplorer(model, distance_cost=0.0).plan(belief(one_hot(5, 1), maps))
    assert plan.reachable.tolist() == [True, True, False, False, False]
    np.testing.assert_allclose(plan.expected_distance, [1, 0, 100, 100, 100], atol=1e-9)
    assert plan.targets.tolist() == [0]
    plan = FrontierExplorer(model, distance_cost=0.0).plan(belief([0, 0.5, 0, 0.5, 0], maps))
    assert plan.reachable.tolist() == [True, True, False, True, True]
    np.testing.assert_allclose(plan.expected_distance, [50.5, 50, 100, 50, 50.5], atol=1e-9)
    assert plan.targets.tolist() == [4]  # u = 0.63 > 0.61 and no distance cost


def test_with_no_reachable_frontier_the_robot_revisits_by_the_unthresholded_gain():
    """The corridor with the wall at cell 2; the only uncertain cell (4, u = 0.63) lies behind it,
    and cell 0 is [0.9, 0.1, 0] (u = H(0.9, 0.1) / ln 3 = 0.296, below the threshold). Surely at
    cell 1 no frontier is reachable: the gain drops the threshold, g = u = [0.296, 0, 0, 0, 0.63],
    and the target is the reachable cell of positive gain, cell 0 ("left")."""
    model = om.corridor(5, 3, p_move=1.0, blocking=[2])
    maps = np.array(BLOCKED, dtype=float)
    maps[0] = [0.9, 0.1, 0.0]
    planner = FrontierExplorer(model)
    action = planner.choose(belief(one_hot(5, 1), maps))
    plan = planner.last_plan
    assert plan.mode == "revisit"
    np.testing.assert_allclose(plan.gain, [h([0.9, 0.1]) / math.log(3), 0, 0, 0, math.log(2) / math.log(3)],
                               rtol=1e-12, atol=1e-15)
    assert plan.targets.tolist() == [0] and model.action_names[action] == "left"


def test_a_lost_robot_scores_the_footprints_certain_cells():
    """lost_entropy 0.5 and the location uniform over a 1 x 5 corridor (normalised entropy 1): the
    gain is sum_f (1 - u) over the footprint (the robot's cell and both neighbours), with u = [0, 1,
    0.722, 1, 1]: g = [1, 1.278, 0.278, 0.278, 0]."""
    model = om.corridor(5, 2, footprint=((0, -1), (0, 0), (0, 1)))
    maps = [[1, 0], [0.5, 0.5], [0.8, 0.2], [0.5, 0.5], [0.5, 0.5]]
    c2 = 1 - h([0.8, 0.2]) / math.log(2)
    plan = FrontierExplorer(model, lost_entropy=0.5).plan(belief(np.full(5, 0.2), maps))
    assert plan.mode == "relocalise"
    np.testing.assert_allclose(plan.gain, [1, 1 + c2, c2, c2, 0], rtol=1e-12, atol=1e-15)


# --- frontier: progress and the blacklist -------------------------------------------------------------
def tracked(positions, patience=2):
    """A 1 x 9 corridor, perfect wheels, only cell 8 uncertain: its E = 8 - (mean location), a
    decision per location belief (a mix of two neighbouring cells with the given mean). Returns the
    planner after the decisions."""
    model = om.corridor(9, 2, p_move=1.0)
    maps = [[1, 0]] * 8 + [[0.5, 0.5]]
    planner = FrontierExplorer(model, patience=patience)
    for mean in positions:
        low = int(math.floor(mean))
        location = np.zeros(9)
        location[low] += 1 - (mean - low)
        location[min(low + 1, 8)] += mean - low
        planner.choose(belief(location, maps))
        assert planner.last_plan.expected_distance[8] == pytest.approx(8 - mean, abs=1e-12)
    return planner


def test_falls_of_half_a_step_counted_from_the_last_progress_are_progress():
    """E = 8, 7.6, 7.2, 6.8, 6.4, 6.0: each decision gains 0.4 (< 0.5) but every second one is 0.8
    below the last progress: never two decisions in a row without progress, no blacklist at
    patience 2."""
    assert not tracked([0, 0.4, 0.8, 1.2, 1.6, 2.0]).blacklist.any()
    # a fall of exactly half a step is progress: E = 8, 7.5, 7 (exact in binary floating point)
    assert not tracked([0, 0.5, 1.0]).blacklist.any()
    assert not tracked([0, 0.5, 0.5]).blacklist.any()  # 8, then 7.5 progress, then one decision without


def test_a_target_without_progress_for_patience_decisions_is_blacklisted():
    """E = 8, 8, 8: the second and third decisions make no progress: blacklisted at patience 2
    (not after the second decision alone)."""
    assert not tracked([0, 0]).blacklist.any()
    assert tracked([0, 0, 0]).blacklist.tolist() == [False] * 8 + [True]
    assert not tracked([0, 0, 0], patience=None).blacklist.any()


def test_after_a_rise_progress_counts_from_the_higher_distance():
    """E = 7, 8 (a rise: no progress, the baseline becomes 8), 7.4 (0.6 below 8: progress), 7.0 (0.4
    below 7.4: none), 6.8 (0.6 below 7.4: progress): no blacklist at patience 2."""
    assert not tracked([1, 0, 0.6, 1.0, 1.2]).blacklist.any()
    # and a fall of less than half a step after the rise is none: 7, 8, 7.6 -> blacklisted
    assert tracked([1, 0, 0.4]).blacklist[8]


# --- the documented fallback of unblocked_actions ----------------------------------------------------
def test_when_every_press_is_blocked_every_press_is_allowed():
    """1 x 3 corridor, label 1 blocks; the robot surely at cell 1 between two certain walls: both
    presses are blocked with probability 1 (> 0.99), so none is "unblocked" and the documented
    fallback allows every press. With the left wall only 0.5 (or 0.99) sure, only "left" is allowed."""
    model = om.corridor(3, 2, blocking=[1])
    assert unblocked_actions(model, belief([0, 1, 0], [[0, 1], [1, 0], [0, 1]])).tolist() == [True, True]
    assert unblocked_actions(model, belief([0, 1, 0], [[0.5, 0.5], [1, 0], [0, 1]])).tolist() == [True, False]
    # blocked with probability 0.99 exactly (1 - 0.01) is "at most" the limit: still allowed
    assert unblocked_actions(model, belief([0, 1, 0], [[0.01, 0.99], [1, 0], [0, 1]])).tolist() == [True, False]


# --- info_gain: the step cost -------------------------------------------------------------------------
def test_step_cost_auto_is_0_05_in_the_papers_world_and_0_6_with_frontier_targets():
    """I0 (one reading of a uniformly unknown cell) by hand: ln 2 - H(0.8, 0.2) = 0.193 nats in a
    binary corridor at p_obs 0.8; ln 4 - H(0.9, 0.1/3 x 3) = 0.9514 in the door world at p_obs 0.9 (the README's 0.19 and 0.95)."""
    paper = InfoGainExplorer(om.corridor(6, 2, p_obs=0.8), seed=0)
    assert paper.targets == 0 and paper.step_cost == 0.05
    door, _ = om.door_world(blocking=True, footprint="cross")
    blocking = InfoGainExplorer(door, seed=0)
    assert blocking.targets == 4 and blocking.step_cost == 0.6
    assert math.log(2) - h([0.8, 0.2]) == pytest.approx(0.1927, abs=1e-4)
    assert math.log(4) - h([0.9] + [0.1 / 3] * 3) == pytest.approx(0.9514, abs=1e-4)


def walked(cell):
    """A 1 x 7 corridor, K = 3 (label 2 blocks), perfect sensor and wheels; the floor plan says cells
    0-5 hold label 0 for sure and cell 6 label 1 (passable) or 2 (blocking), half and half; an
    exact filter that has read ``cell`` (its start): it knows where it is, and cell 6 is the only
    unknown. Entering cell 6 reads 1 there; failing to enter it leaves the robot reading 0: either
    way the robot learns cell 6 (ln 2 nats) and still knows where it is. I0, one perfect reading of
    a cell whose 3 labels are equally likely, is ln 3."""
    prior = [[1.0, 0.0, 0.0]] * 6 + [[0.0, 0.5, 0.5]]
    model = om.corridor(7, 3, p_obs=1.0, p_move=1.0, blocking=[2], label_prior=prior, start=cell)
    est = om.make_estimator("exact", model)
    b = est.step(None, 0)
    assert b.location[cell] == 1.0 and b.map[6].tolist() == [0.0, 0.5, 0.5] and (b.map[:6, 0] == 1).all()
    return model, est, b


@pytest.mark.parametrize("step_cost, pays", [(0.0, True), (0.3, True), (0.33, False), ("auto", False)])
def test_the_step_cost_decides_whether_pressing_on_pays(step_cost, pays):
    """From cell 4 two presses right learn cell 6 (ln 2 nats); one press teaches nothing. So
    utility(press right, 2) = ln 2 - 2 step_cost ln 3, positive exactly while step_cost <
    ln 2 / (2 ln 3) = 0.315; "auto" (0.6 in a world with blocking labels and frontier targets)
    makes nothing pay."""
    model, est, b = walked(4)
    planner = InfoGainExplorer(model, seed=0, hypotheses=None, press_lengths=[1, 2], step_cost=step_cost)
    planner.bind(est)
    plan = planner.plan(b)
    right = plan.names.index("press right")
    cost = 0.6 if step_cost == "auto" else step_cost
    np.testing.assert_allclose(plan.gain[right], [0.0, math.log(2)], atol=1e-12)
    np.testing.assert_allclose(plan.utility[right], [-cost * math.log(3), math.log(2) - 2 * cost * math.log(3)],
                               atol=1e-12)
    assert bool(plan.pays) is pays
    if pays:
        assert plan.chosen == (right, 1)  # press right twice (a target move, later in the list, ties)


def test_when_nothing_pays_the_robot_takes_the_frontiers_press():
    """From cell 1 with press_lengths [1] no macro-action reaches the unknown cell 6: every gain is 0
    and every utility -0.6 ln 3. The best of them would be "press left" (the first on ties), but
    nothing pays, so the next presses are the frontier baseline's: "right", towards cell 6."""
    model, est, b = walked(1)
    planner = InfoGainExplorer(model, seed=0, hypotheses=None, press_lengths=[1])
    planner.bind(est)
    plan = planner.plan(b)
    np.testing.assert_allclose(plan.gain, 0.0, atol=1e-12)
    np.testing.assert_allclose(plan.utility, -0.6 * math.log(3), atol=1e-12)
    assert not bool(plan.pays) and plan.names[plan.chosen[0]] == "press left"
    assert model.action_names[planner.choose(b)] == "right"
    assert model.action_names[FrontierExplorer(model).choose(b)] == "right"
    # a utility of exactly 0 does not pay either: step_cost 0 and nothing to learn
    planner = InfoGainExplorer(model, seed=0, hypotheses=None, press_lengths=[1], step_cost=0.0)
    planner.bind(est)
    plan = planner.plan(b)
    assert plan.utility.max() == 0.0 and not bool(plan.pays)


def test_ties_go_to_the_shorter_macro_action():
    """From cell 5 one press right learns cell 6 (ln 2 nats); two presses teach no more. With
    step_cost 0, utilities tie at ln 2 for lengths 1 and 2: the shorter is chosen."""
    model, est, b = walked(5)
    planner = InfoGainExplorer(model, seed=0, hypotheses=None, press_lengths=[1, 2], step_cost=0.0)
    planner.bind(est)
    plan = planner.plan(b)
    right = plan.names.index("press right")
    np.testing.assert_allclose(plan.utility[right], [math.log(2)] * 2, atol=1e-12)
    assert plan.chosen == (right, 0)


def test_a_macro_action_whose_first_press_meets_a_wall_is_never_chosen():
    """At cell 0 (the corridor's left end), with press_lengths [1] and step_cost 0, nothing is learnt
    either way: every utility is 0 and the first candidate, "press left", would win the tie; but its
    press surely leaves the robot where it is, so "press right" is chosen."""
    model, est, b = walked(0)
    planner = InfoGainExplorer(model, seed=0, hypotheses=None, press_lengths=[1], step_cost=0.0)
    planner.bind(est)
    plan = planner.plan(b)
    np.testing.assert_allclose(plan.utility, 0.0, atol=1e-12)
    assert plan.names[plan.chosen[0]] == "press right"


def test_a_first_press_that_leaves_the_robot_in_place_half_the_time_is_left_out():
    """Cell 1 is free or a wall, half and half, the rest of the corridor known free. From cell 0 a
    press right with perfect wheels either moves (cell 1 free) or not (a wall), and both read 0: the
    robot is at cell 0 or 1 with 1/2 each. "press left" would tell them apart (both end at cell 0):
    the most informative press, but it leaves the robot in place with probability exactly 1/2,
    which the rule ("with probability >= 1/2") leaves out."""
    prior = [[1.0, 0.0, 0.0], [0.5, 0.0, 0.5]] + [[1.0, 0.0, 0.0]] * 5
    model = om.corridor(7, 3, p_obs=1.0, p_move=1.0, blocking=[2], label_prior=prior, start=0)
    est = om.make_estimator("exact", model)
    est.step(None, 0)
    b = est.step(model.action_names.index("right"), 0)
    np.testing.assert_allclose(b.location, [0.5, 0.5, 0, 0, 0, 0, 0], atol=1e-12)
    planner = InfoGainExplorer(model, seed=0, hypotheses=None, press_lengths=[1], step_cost=0.0)
    planner.bind(est)
    plan = planner.plan(b)
    left = plan.names.index("press left")
    assert plan.utility[left, 0] > np.delete(plan.utility[:, 0], left).max()
    assert plan.chosen[0] != left
