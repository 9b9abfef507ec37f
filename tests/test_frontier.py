"""policies.passability and the frontier planner: shortest expected paths against Floyd-Warshall
on a dense cost matrix built here from the definition (and scipy's Dijkstra as a peer); blocked
moves against a loop over cells."""

import numpy as np
import pytest
from scipy.sparse.csgraph import dijkstra

import onlinemap as om
from onlinemap.belief import Belief
from onlinemap.errors import InvalidOptionError, ModelError
from onlinemap.model import GridModel, symmetric_channel
from policies import make_planner
from policies.frontier import FrontierExplorer, location_hypotheses
from policies.passability import (blocked_probability, distances_from, distances_to, enter_costs,
                                  expected_passability, unblocked_actions)


def floyd_warshall(model: GridModel, passable: np.ndarray, min_passable: float) -> np.ndarray:
    """(N, N) cheapest total of 1 / (p_move passable[j]) over paths i -> j, entering only cells with
    passable >= min_passable, by Floyd-Warshall over a dense matrix."""
    n = model.n_cells
    dist = np.full((n, n), np.inf)
    np.fill_diagonal(dist, 0.0)
    for i in range(n):
        for a in range(model.n_actions):
            j = int(model.neighbors[i, a])
            if j != i and passable[j] >= min_passable and model.p_move > 0:
                dist[i, j] = min(dist[i, j], 1.0 / (model.p_move * passable[j]))
    for k in range(n):
        dist = np.minimum(dist, dist[:, k:k + 1] + dist[k:k + 1, :])
    return dist


def random_topology(seed: int) -> GridModel:
    """Each action a random permutation of the cells (fixed points: no move); not symmetric."""
    rng = np.random.default_rng(seed)
    n, a_count = int(rng.integers(2, 12)), int(rng.integers(1, 5))
    neighbors = np.stack([rng.permutation(n) for _ in range(a_count)], axis=1)
    return GridModel(rows=1, cols=n, neighbors=neighbors, p_move=float(rng.uniform(0.1, 1.0)),
                     change=np.eye(2), sensor=symmetric_channel(2, 0.9), label_prior=[0.5, 0.5], start=0,
                     action_names=tuple(f"a{k}" for k in range(a_count)), label_names=("0", "1"),
                     blocking=np.array([False, True]))


CASES = [("random", seed) for seed in range(30)] + [("grid", seed) for seed in range(10)]


@pytest.mark.parametrize("kind,seed", CASES)
def test_distances_equal_floyd_warshall(kind, seed):
    rng = np.random.default_rng(seed)
    model = random_topology(seed) if kind == "random" else om.grid_model(
        int(rng.integers(1, 6)), int(rng.integers(2, 7)), 2, p_move=float(rng.uniform(0.2, 1.0)))
    passable = rng.uniform(0, 1, model.n_cells) * (rng.random(model.n_cells) > 0.2)
    min_passable = float(rng.choice([0.05, 0.3]))
    brute = floyd_warshall(model, passable, min_passable)
    sources = rng.choice(model.n_cells, size=int(rng.integers(1, model.n_cells + 1)), replace=False)
    np.testing.assert_allclose(distances_from(model, passable, sources, min_passable), brute[sources], rtol=1e-12)
    np.testing.assert_allclose(distances_to(model, passable, sources, min_passable), brute[:, sources].min(axis=1),
                               rtol=1e-12)
    # the peer: scipy's Dijkstra on a dense matrix of the cheapest edge i -> j (0: no edge; no cost is 0)
    costs = enter_costs(model, passable, min_passable)
    graph = np.full((model.n_cells,) * 2, np.inf)
    rows, cols = np.nonzero(model.neighbors != np.arange(model.n_cells)[:, None])
    np.minimum.at(graph, (rows, model.neighbors[rows, cols]), costs[model.neighbors[rows, cols]])
    graph[np.isinf(graph)] = 0.0
    np.testing.assert_allclose(dijkstra(graph, indices=sources), brute[sources], rtol=1e-12)


def test_costs_without_blocking_are_one_over_p_move_per_step():
    model = om.grid_model(3, 4, 2, p_move=0.8)
    belief = Belief(0, model.location_prior(), model.label_prior)
    passable = expected_passability(model, belief)
    assert np.array_equal(passable, np.ones(12))
    d = distances_from(model, passable, [0])[0]
    rows, cols = np.divmod(np.arange(12), 4)
    np.testing.assert_allclose(d, (rows + cols) / 0.8)  # Manhattan distance / p_move
    assert np.array_equal(blocked_probability(model, belief), np.zeros(4))


def test_blocked_probability_equals_a_loop_over_cells():
    model, _ = om.door_world("...\n.#.\n...\n", blocking=True)
    rng = np.random.default_rng(0)
    location = rng.dirichlet(np.ones(9))
    maps = rng.dirichlet(np.ones(4), size=9)
    belief = Belief(0, location, maps.copy())
    expected = np.zeros(4)
    for cell in range(9):
        for a in range(4):
            j = model.neighbors[cell, a]
            if j != cell:
                expected[a] += location[cell] * (maps[j, 1] + maps[j, 3])  # wall or closed door
    np.testing.assert_allclose(blocked_probability(model, belief), expected, rtol=1e-12)
    np.testing.assert_allclose(expected_passability(model, belief), maps[:, 0] + maps[:, 2], rtol=1e-12)
    # certain to be in the centre's west neighbour (cell 3) facing a certain wall east (cell 4)
    maps[4] = [0, 1, 0, 0]
    belief = Belief(0, np.eye(9)[3], maps.copy())
    east = model.action_names.index("east")
    assert blocked_probability(model, belief)[east] == 1.0
    assert unblocked_actions(model, belief).tolist() == [a != east for a in range(4)]
    maps[[0, 4, 6]] = [0, 1, 0, 0]  # walled in on every side but the west edge, which is no label
    assert unblocked_actions(model, Belief(0, np.eye(9)[3], maps.copy())).tolist() == [False, False, False, True]


def test_passability_refuses_bad_input():
    model = om.grid_model(2, 3, 2)
    with pytest.raises(ModelError, match="passable"):
        distances_to(model, np.ones(5), [0])
    with pytest.raises(ModelError, match="passable"):
        distances_to(model, np.full(6, 1.5), [0])
    with pytest.raises(ModelError, match="targets"):
        distances_to(model, np.ones(6), [6])
    with pytest.raises(ModelError, match="targets"):
        distances_to(model, np.ones(6), [])
    with pytest.raises(ModelError, match="sources"):
        distances_from(model, np.ones(6), [0.5])
    with pytest.raises(InvalidOptionError, match="min_passable"):
        distances_to(model, np.ones(6), [0], min_passable=0.0)


# --- the frontier planner -------------------------------------------------------------------------


def known_map(model: GridModel, labels, unknown) -> np.ndarray:
    """(N, K) map belief: ``labels`` (N,) certain, the cells ``unknown`` uniform."""
    maps = np.eye(model.n_labels)[np.asarray(labels)]
    maps[list(unknown)] = 1.0 / model.n_labels
    return maps


@pytest.mark.parametrize("blocking", [None, 1])
def test_frontier_goes_to_the_unknown_end_of_a_corridor(blocking):
    model = om.corridor(8, blocking=blocking)
    left, right = model.action_names.index("left"), model.action_names.index("right")
    maps = known_map(model, np.zeros(8, dtype=int), [7])
    for cell in range(7):
        planner = make_planner("frontier", model)
        assert planner.choose(Belief(0, np.eye(8)[cell], maps.copy())) == right, cell
        assert planner.last_plan.targets.tolist() == [7] and planner.last_plan.mode == "frontier"
    mirrored = known_map(model, np.zeros(8, dtype=int), [0])
    assert make_planner("frontier", model).choose(Belief(0, np.eye(8)[5], mirrored)) == left
    # a robot unsure where it is (cells 1-4) still heads for the unknown end
    unsure = Belief(0, np.r_[0, .25, .25, .25, .25, 0, 0, 0], maps.copy())
    assert make_planner("frontier", model).choose(unsure) == right


ROOM = """\
.....#####
.....#...#
.....#...#
.....##o##
..........
"""


def test_frontier_leaves_a_room_by_its_only_door():
    """The room (rows 1-2, columns 6-8), its walls and its open door (row 3, column 7) are known;
    everything outside is unknown. From every room cell the robot moves closer to the door, and
    the targets lie outside the room, through the door."""
    model, true_map = om.door_world(ROOM, blocking=True, footprint="cross")
    rows, cols = np.divmod(np.arange(model.n_cells), model.cols)
    room = (rows <= 3) & (cols >= 5)
    maps = known_map(model, true_map, np.flatnonzero(~room))
    door = 3 * model.cols + 7
    for cell in np.flatnonzero(room & (true_map == 0)):
        planner = FrontierExplorer(model)
        action = planner.choose(Belief(0, np.eye(model.n_cells)[cell], maps.copy()))
        after = model.neighbors[cell, action]
        assert abs(rows[after] - 3) + abs(cols[after] - 7) < abs(rows[cell] - 3) + abs(cols[cell] - 7), \
            (cell, model.action_names[action])
        assert not room[planner.last_plan.targets].any() or set(planner.last_plan.targets) == {door}
    # the door closed for sure: no way out, every reachable footprint is known, so the robot
    # revisits the most uncertain reachable places (the walls next to the unknown) instead
    closed = maps.copy()
    closed[door] = np.eye(4)[3]
    planner = FrontierExplorer(model)
    planner.choose(Belief(0, np.eye(model.n_cells)[model.cols + 6], closed))
    assert planner.last_plan.mode == "revisit" and room[planner.last_plan.targets].all()


def test_frontier_blacklists_a_target_it_makes_no_progress_towards():
    """The same belief over and over (the robot's presses change nothing): after ``patience``
    decisions without progress the target is blacklisted and another chosen; a press that left
    the belief unchanged is not repeated while the belief stays the same."""
    model = om.corridor(8)
    maps = known_map(model, np.zeros(8, dtype=int), [0, 7])
    b = Belief(0, np.eye(8)[5], maps)  # the unknown end 7 is nearer than 0
    planner = FrontierExplorer(model, patience=3)
    first = planner.choose(b)
    assert planner.last_plan.targets.tolist() == [7] and model.action_names[first] == "right"
    second = planner.choose(b)  # unchanged belief after "right": "right" was futile
    assert model.action_names[second] == "left" and planner.presses.futile.tolist() == [False, True]
    for _ in range(3):
        planner.choose(b)
    assert planner.blacklist.tolist() == [False] * 7 + [True]
    assert planner.plan(b).targets.tolist() == [0]
    # when every frontier cell is blacklisted, the list is cleared
    planner.blacklist[0] = True
    assert planner.plan(b).targets.tolist() == [7] and not planner.blacklist.any()


def test_location_hypotheses_keep_the_most_probable_cells():
    cells, weights = location_hypotheses(np.array([0.1, 0.0, 0.6, 0.3]), 16)
    assert cells.tolist() == [2, 3, 0] and np.allclose(weights, [0.6, 0.3, 0.1])
    cells, weights = location_hypotheses(np.array([0.1, 0.0, 0.6, 0.3]), 2)
    assert cells.tolist() == [2, 3] and np.allclose(weights, [2 / 3, 1 / 3])


def test_frontier_action_costs_equal_their_definition():
    """sum_l P(l) [1 + q D(j) + (1 - q) D(l)] recomputed here with Floyd-Warshall distances."""
    model, true_map = om.door_world(ROOM, blocking=True, footprint="cross")
    rng = np.random.default_rng(3)
    maps = rng.dirichlet(np.ones(4), size=model.n_cells)
    location = rng.dirichlet(np.full(model.n_cells, 0.1))
    planner = FrontierExplorer(model, hypotheses=model.n_cells)
    plan = planner.plan(Belief(0, location, maps.copy()))
    passable = maps[:, 0] + maps[:, 2]
    brute = floyd_warshall(model, passable, planner.min_passable)
    d = np.where(np.isfinite(brute[:, plan.targets].min(1)), brute[:, plan.targets].min(1), planner.penalty)
    np.testing.assert_allclose(plan.distance, d, rtol=1e-12)
    expected = np.zeros(4)
    for cell in range(model.n_cells):
        for a in range(4):
            j = model.neighbors[cell, a]
            q = model.p_move * passable[j] if j != cell and passable[j] >= planner.min_passable else 0.0
            expected[a] += location[cell] * (1 + q * d[j] + (1 - q) * d[cell])
    np.testing.assert_allclose(plan.action_cost, expected, rtol=1e-12)
    keep = location > 0
    e = (location[keep] / location[keep].sum()) @ np.where(np.isfinite(brute[keep]), brute[keep], planner.penalty)
    np.testing.assert_allclose(plan.expected_distance, e, rtol=1e-9)


@pytest.mark.parametrize("option,value", [("threshold", 0.0), ("threshold", 1.0), ("threshold", "x"),
                                          ("distance_cost", -1.0), ("distance_cost", float("nan")),
                                          ("min_passable", 0.0), ("min_passable", 1.5), ("hypotheses", 0),
                                          ("hypotheses", 1.5), ("lost_entropy", 0.0), ("patience", 0),
                                          ("patience", True)])
def test_frontier_bad_options_raise_invalid_option_errors_naming_them(option, value):
    model = om.corridor(5)
    with pytest.raises(InvalidOptionError, match=option):
        make_planner("frontier", model, **{option: value})
    with pytest.raises(ModelError, match="p_move"):
        make_planner("frontier", om.corridor(5, p_move=0.0))


def test_frontier_relocalises_when_lost():
    """lost_entropy set and the location spread over the whole corridor: the gain counts the
    footprint's certain cells, so the robot heads for the mapped half (cells 0-3)."""
    model = om.corridor(8)
    maps = known_map(model, np.zeros(8, dtype=int), [4, 5, 6, 7])
    lost = Belief(0, np.full(8, 1 / 8), maps)
    planner = FrontierExplorer(model, lost_entropy=0.8)
    assert model.action_names[planner.choose(lost)] == "left" and planner.last_plan.mode == "relocalise"
    assert model.action_names[FrontierExplorer(model).choose(lost)] == "right"


def test_with_the_unread_cells_entropy_as_scale_a_sharp_prior_still_leaves_a_frontier():
    """Unread cells at learned frequencies (0.95, 0.05) hold 0.199 nats, 0.29 of log 2: below the
    threshold 0.5, so on log K no cell is a frontier and the robot revisits; with that entropy as
    the scale an unread cell is one cell of uncertainty, the gain equals its definition summed
    here cell by cell, and the robot heads for the unread end. A bad scale is refused and leaves
    the planner's last plan as it was."""
    model = om.corridor(8, footprint=((0, 0), (0, 1)))
    frequencies = np.array([0.95, 0.05])
    unread_nats = float(-(frequencies * np.log(frequencies)).sum())
    maps = known_map(model, np.zeros(8, dtype=int), [])
    maps[5:] = frequencies
    maps[4] = [0.9, 0.1]  # read once, against it: more uncertain than an unread cell, counts as one cell
    belief = Belief(0, np.eye(8)[1], maps)
    plain = FrontierExplorer(model)
    plain.plan(belief)
    assert plain.last_plan.mode == "revisit"
    planner = FrontierExplorer(model)
    action = planner.choose(belief, unread_nats)
    plan = planner.last_plan
    assert plan.mode == "frontier" and model.action_names[action] == "right"
    u = [min(-sum(p * np.log(p) for p in row if p > 0) / unread_nats, 1.0) for row in maps]
    for c in range(8):
        read = [c + d for d in (0, 1) if c + d < 8]
        assert plan.gain[c] == pytest.approx(sum(u[j] for j in read if u[j] > planner.threshold), rel=1e-12)
    for bad in (0.0, -1.0, float("nan"), "x"):
        with pytest.raises(InvalidOptionError, match="scale"):
            planner.plan(belief, bad)
        assert planner.last_plan is plan
