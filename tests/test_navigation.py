"""policies.navigation and policies.navigate: the goal planners against references written here
(Dijkstra with heapq; the minimum over every policy, enumerated with itertools.product, of the
Markov chain the planner's rules define, arrival marginals from matrix powers), hand-checkable
detours, waits and votes, bad goals, the navigation loop and its paired world, and
``onlinemap track --planner goto`` end to end in a subprocess."""

import heapq
import itertools
import math

import numpy as np
import pandas as pd
import pytest

import onlinemap as om
from onlinemap.belief import Belief
from onlinemap.errors import InvalidOptionError, ModelError
from onlinemap.model import CLOSED_DOOR, DOOR_LABELS, FREE, OPEN_DOOR, WALL, door_change
from onlinemap.worlds import parse_world
from policies import (NAVIGATION_COLUMNS, make_planner, navigate, oracle_steps, planner_options, true_distances,
                      with_floor_plan)
from estimator_cases import assert_state_unchanged, snapshot
from policies.explore import seed_streams
from policies.navigate import PairedWorld
from policies.navigation import GoTo, StaticGoTo, goal_cell, label_powers, plan_to_goal


def heap_dijkstra(model, step_cost, goal):
    """(N,) cheapest total cost to ``goal``, a move from l into j = neighbors[l, a] != l costing
    ``step_cost[j]`` (inf: no move), by the textbook heap algorithm on the reversed moves."""
    n = model.n_cells
    into = {j: [] for j in range(n)}
    for l in range(n):
        for a in range(model.n_actions):
            j = int(model.neighbors[l, a])
            if j != l and np.isfinite(step_cost[j]):
                into[j].append(l)
    best = np.full(n, np.inf)
    best[goal] = 0.0
    heap = [(0.0, goal)]
    while heap:
        d, j = heapq.heappop(heap)
        if d > best[j]:
            continue
        for l in into[j]:
            if d + step_cost[j] < best[l]:
                best[l] = d + step_cost[j]
                heapq.heappush(heap, (best[l], l))
    return best


def known(model, labels, location=None, t=0) -> Belief:
    """A belief certain of the map ``labels`` and of the location (default the start)."""
    where = np.eye(model.n_cells)[model.start if location is None else location]
    return Belief(t, where, np.eye(model.n_labels)[np.asarray(labels)])


def random_door_map(rng, rows, cols):
    labels = rng.choice([FREE, WALL, OPEN_DOOR, CLOSED_DOOR], p=[0.6, 0.2, 0.1, 0.1], size=rows * cols)
    labels[0] = FREE
    return labels


@pytest.mark.parametrize("seed", range(12))
def test_plan_on_a_known_static_map_is_the_shortest_path(seed):
    """p_move = 1 and a certain map: expected steps = steps of the shortest path (walls and
    closed doors block), and the chosen action starts a shortest path."""
    rng = np.random.default_rng(seed)
    rows, cols = int(rng.integers(2, 7)), int(rng.integers(2, 7))
    labels = random_door_map(rng, rows, cols)
    model = om.grid_model(rows, cols, 4, p_move=1.0, label_names=DOOR_LABELS, blocking=("wall", "closed_door"))
    goal = int(rng.integers(model.n_cells))
    steps = heap_dijkstra(model, np.where(model.blocking[labels], np.inf, 1.0), goal)
    plan = plan_to_goal(model, np.eye(4)[labels], goal)
    assert plan.horizon == 0  # static: one Dijkstra, nothing varies over time
    np.testing.assert_array_equal(plan.value, steps)
    if not model.blocking[labels[goal]]:
        planner = GoTo(om.grid_model(rows, cols, 4, p_move=1.0, label_names=DOOR_LABELS,
                                     blocking=("wall", "closed_door"), label_prior=[0.25] * 4), goal=goal)
        for location in np.flatnonzero(np.isfinite(steps) & (steps > 0)):
            action = planner.choose(known(model, labels, location))
            assert steps[model.neighbors[location, action]] == steps[location] - 1


@pytest.mark.parametrize("seed", range(8))
def test_plan_with_uncertain_walls_in_a_static_world_is_dijkstra_on_expected_steps(seed):
    """Nothing changes: pressing into j finds a wall with probability s_j (one step lost, then the
    robot tries again, s_j / (1 - s_j) lost steps on average) or a passable label, then enters
    after 1 / p_move presses on average (geometric); a cell with s_j > 1/2 is a wall. The plan
    is Dijkstra on those costs."""
    rng = np.random.default_rng(100 + seed)
    rows, cols = int(rng.integers(2, 6)), int(rng.integers(2, 6))
    model = om.grid_model(rows, cols, 3, p_move=float(rng.uniform(0.3, 1.0)), blocking=[2])
    maps = rng.dirichlet([1.0, 1.0, 1.0], size=model.n_cells)
    maps[rng.random(model.n_cells) < 0.2] = [0.0, 0.0, 1.0]  # some certain walls
    maps[rng.random(model.n_cells) < 0.2] = [0.2, 0.2, 0.6]  # some likely walls
    wall = np.where(maps[:, 2] > 0.5, 1.0, maps[:, 2])
    goal = int(rng.integers(model.n_cells))
    with np.errstate(divide="ignore"):
        expected = heap_dijkstra(model, wall / (1 - wall) + 1 / model.p_move, goal)
    np.testing.assert_allclose(plan_to_goal(model, maps, goal).value, expected, rtol=1e-12)


def never_passable(model):
    """(K,) bool: labels from which C never reaches a label that lets the robot in."""
    can = ~model.blocking
    for _ in range(model.n_labels):
        can = can | ((model.change > 0) & can).any(axis=1)
    return ~can


def policy_cost(model, maps, goal, policy, cache):
    """(N,) expected steps to ``goal`` from every cell at step 0 under ``policy`` ((H + 1, N)
    actions: ``policy[tau]`` at steps tau < H, ``policy[H]`` from H on), by the rules the planner
    assumes, written out as a Markov chain over states ("free", l) and ("press", l, a, k):
    a free robot's move aims at j = neighbors[l, a] (j == l: it stays); j's label on arrival is
    drawn from maps[j] C^min(tau, H); a label that never lets it in costs the step and leaves it
    free where it was; otherwise each step is a press that enters with p_move [label passable],
    the label moving by C after each failure; a cell more likely than not to hold such a label is
    a wall. Every step costs 1; a free robot on the goal is done.
    From step H the chain is time-homogeneous: a linear solve (inf where the goal is not sure).
    ``cache``: a dict keeping the step matrices across calls for the same model, maps and goal."""
    n, k_count = model.n_cells, model.n_labels
    horizon = len(policy) - 1
    change, enter = model.change, model.p_move * (~model.blocking)
    wall = never_passable(model)
    assert not change[np.ix_(~wall, wall)].any()  # nothing falls into a wall while pressed
    maps = np.where((maps[:, wall].sum(axis=1) > 0.5)[:, None], wall / wall.sum(), maps)  # (one wall label here)
    arrival = [maps @ np.linalg.matrix_power(change, min(tau, horizon)) for tau in range(horizon + 1)]
    states = [("free", l) for l in range(n)] + [("press", l, a, k) for l in range(n)
                                                 for a in range(model.n_actions) for k in range(k_count)]
    index = {state: i for i, state in enumerate(states)}

    def press(l, a, k, weight, row):
        """One press into neighbors[l, a] whose label is k, with probability ``weight``."""
        row[index["free", model.neighbors[l, a]]] += weight * enter[k]
        for k2 in range(k_count):
            row[index["press", l, a, k2]] += weight * (1 - enter[k]) * change[k, k2]

    def step_matrix(tau, actions):
        key = (tau, tuple(actions))
        if key not in cache:
            cache[key] = build(tau, actions)
        return cache[key]

    def build(tau, actions):
        matrix = np.zeros((len(states), len(states)))
        for i, state in enumerate(states):
            if state == ("free", goal):
                continue
            if state[0] == "press":
                press(*state[1:], 1.0, matrix[i])
                continue
            l = state[1]
            j = model.neighbors[l, actions[l]]
            if j == l:
                matrix[i, index["free", l]] = 1.0
                continue
            matrix[i, index["free", l]] = arrival[tau][j, wall].sum()
            for k in np.flatnonzero(~wall):
                press(l, actions[l], k, arrival[tau][j, k], matrix[i])
        return matrix

    done = np.array([state == ("free", goal) for state in states])
    matrix = step_matrix(horizon, policy[horizon])
    sure = done.copy()  # states from which the goal can be reached
    for _ in states:
        sure = sure | ((matrix > 0) & sure).any(axis=1)
    for _ in states:  # ... and no state from which it cannot
        sure = sure & ~((matrix > 0) & ~sure).any(axis=1)
    inner = sure & ~done
    value = np.where(done, 0.0, np.inf)
    value[inner] = np.linalg.solve(np.eye(inner.sum()) - matrix[np.ix_(inner, inner)], np.ones(inner.sum()))
    for tau in range(horizon - 1, -1, -1):
        matrix = step_matrix(tau, policy[tau])
        with np.errstate(invalid="ignore"):  # 0 x inf: a move that cannot happen costs nothing
            value = np.where(done, 0.0, 1.0 + np.where(matrix > 0, matrix * value, 0.0).sum(axis=1))
    return value[:n]


@pytest.mark.parametrize("seed", range(6))
def test_time_dependent_plan_is_the_best_of_every_policy(seed):
    """Doors that open and close (door dynamics on a 1 x 4 corridor, horizon 2): the plan's
    expected steps from every cell equal the minimum over all 2^(3 x 3) policies (time-dependent
    actions at steps 0 and 1, a stationary one after), each evaluated as a Markov chain."""
    rng = np.random.default_rng(200 + seed)
    model = om.grid_model(1, 4, 4, p_move=float(rng.uniform(0.5, 1.0)), change=door_change(rng.uniform(0.05, 0.4)),
                          label_names=DOOR_LABELS, blocking=("wall", "closed_door"))
    maps = rng.dirichlet([0.5] * 4, size=4)
    goal = int(rng.integers(4))
    horizon = 2
    others = [l for l in range(4) if l != goal]
    best = np.full(4, np.inf)
    best_first = np.full((4, 2), np.inf)
    cache = {}
    for choice in itertools.product(range(2), repeat=len(others) * (horizon + 1)):
        policy = np.zeros((horizon + 1, 4), dtype=int)
        policy[:, others] = np.reshape(choice, (horizon + 1, len(others)))
        cost = policy_cost(model, maps, goal, policy, cache)
        best = np.minimum(best, cost)
        for l in others:
            best_first[l, policy[0, l]] = min(best_first[l, policy[0, l]], cost[l])
    plan = plan_to_goal(model, maps, goal, horizon)
    assert plan.horizon == horizon
    np.testing.assert_allclose(plan.value, best, rtol=1e-12)
    np.testing.assert_allclose(plan.q[others], best_first[others], rtol=1e-12)
    assert np.all(plan.q[goal] == 0)


def test_the_action_is_voted_by_the_likely_locations_ties_by_expected_cost():
    """A free 1 x 5 corridor, p_move 0.8, goal cell 2, the robot in cell 1 with probability p or
    in cell 4. By hand: entering a free cell takes 1 / 0.8 = 1.25 presses on average, so
    V = (2.5, 1.25, 0, 1.25, 2.5) and Q(1, right) = 1.25, Q(1, left) = 1.25 + V(0) = 3.75,
    Q(4, left) = 1.25 + V(3) = 2.5, Q(4, right) = 1 + V(4) = 3.5 (pressing into the end wall: one
    step in place). Cell 1 votes right, cell 4 left: the likelier one wins; at p = 1/2 the tie
    goes to the lower expected cost, right (1.25 p + 3.5 (1 - p) = 2.375 against 3.125)."""
    model = om.grid_model(1, 5, 2, p_move=0.8, label_names=("free", "wall"), blocking=["wall"])
    maps = np.eye(2)[np.zeros(5, dtype=int)]
    planner = GoTo(model, goal=2)
    for p in (0.3, 0.49, 0.5, 0.51, 0.8):
        chosen = planner.choose(Belief(0, np.array([0, p, 0, 0, 1 - p]), maps))
        assert model.action_names[chosen] == ("right" if p >= 0.5 else "left")
    np.testing.assert_allclose(planner.plan.q[[1, 4]], [[3.75, 1.25], [2.5, 3.5]], rtol=1e-12)


def test_the_robot_does_not_hedge_between_location_hypotheses():
    """A free 2 x 5 grid, p_move 0.8, goal (0, 2); the robot at (0, 1) with p = 0.55, else at
    (0, 3). Entering a free cell takes 1.25 presses, so from (0, 1): east 1.25, west
    1.25 + V(0, 0) = 3.75, south 1.25 + V(1, 1) = 3.75, north (the edge: a step in place)
    1 + 1.25 = 2.25; mirrored from (0, 3). Expected: north 2.25, east 0.55 x 1.25 + 0.45 x 3.75
    = 2.375, west 2.625. The lowest expected cost stays north for ever (and learns nothing); the
    vote goes east (0.55 against 0.45)."""
    model, true_map = om.door_world(".....\n.....\n", blocking=True)
    planner = GoTo(model, goal=(0, 2))

    def choose(cells, probabilities):
        location = np.zeros(10)
        location[cells] = probabilities
        return model.action_names[planner.choose(Belief(0, location, np.eye(4)[true_map]))], location

    action, location = choose([1, 3], [0.55, 0.45])
    assert action == "east"
    np.testing.assert_allclose(location @ planner.plan.q, [2.25, 2.375, 3.75, 2.625], rtol=1e-12)
    assert choose([1, 3], [0.45, 0.55])[0] == "west"
    # cells outside the 95% most likely ones do not vote: (1, 4) would vote north and west
    assert choose([1, 3, 9], [0.50, 0.47, 0.03])[0] == "east"
    assert choose([1, 3, 9], [0.48, 0.44, 0.08])[0] == "west"  # 0.44 + 0.08 against 0.48


# --- hand-checkable: detour or wait -------------------------------------------------------------
def door_ahead(detour_rows: int, p_door: float):
    """Start (0, 0), goal (0, 2), a door between them at (0, 1) believed closed; the detour goes
    down column 0, across the bottom row and up column 2: 2 detour_rows + 2 steps."""
    layout = ".c.\n" + ".#.\n" * (detour_rows - 1) + "...\n"
    model, true_map = om.door_world(layout, p_move=1.0, p_door=p_door, blocking=True, start=0)
    return model, true_map


def test_a_short_detour_beats_waiting_at_a_closed_door():
    model, true_map = door_ahead(1, p_door=0.05)  # ".c.\n...": the detour is south, east, east, north
    planner = GoTo(model, goal=(0, 2))
    assert model.action_names[planner.choose(known(model, true_map))] == "south"
    assert planner.plan.q[0, 1] > planner.plan.q[0, 2] == 4.0  # east = waiting at the door


def test_a_long_detour_loses_to_a_door_that_reopens_quickly():
    model, true_map = door_ahead(19, p_door=0.3)  # detour 2 x 19 + 2 = 40 steps
    planner = GoTo(model, goal=(0, 2))
    # it waits: north (into the grid's edge) and east (into the door, certainly closed now) both
    # leave it where it is, equally cheap; ties go to the lowest action index
    assert model.action_names[planner.choose(known(model, true_map))] == "north"
    assert planner.plan.q[0, 0] == planner.plan.q[0, 1] == planner.plan.q[0].min()
    # by hand: the closed door opens after 1 / p_door steps on average (geometric), the press
    # that finds it open gets in (p_move = 1), one more step to the goal: 1 / 0.3 + 1 + 1
    assert planner.plan.q[0, 1] == pytest.approx(1 / 0.3 + 2, rel=1e-12)
    assert planner.plan.q[0, 2] > planner.plan.q[0, 1]  # south: a step away, and back or round
    # a door that reopens after 1 / 0.05 = 20 steps on average: worth waiting for against a
    # 40-step detour, not against a 12-step one
    for rows, action in ((19, "north"), (5, "south")):
        model, true_map = door_ahead(rows, p_door=0.05)
        planner = GoTo(model, goal=(0, 2))
        assert model.action_names[planner.choose(known(model, true_map))] == action
        assert planner.plan.q[0, 1] == pytest.approx(1 / 0.05 + 2, rel=1e-12)
    slow, true_map = door_ahead(19, p_door=0.001)  # the same 40-step detour, a door that stays shut
    assert slow.action_names[GoTo(slow, goal=(0, 2)).choose(known(slow, true_map))] == "south"


def test_static_goto_ignores_what_the_robot_has_seen():
    """A 20-step detour; the door, under the floor plan, open or closed with 1/2 each: about
    (2 + 22) / 2 = 12 steps through it, so the prior's plan goes through; seen closed (22 steps
    by the door) the detour wins, seen open (2 steps) the door."""
    model, true_map = door_ahead(9, p_door=0.05)
    model = with_floor_plan(model, true_map, 0.95)
    static, learned = StaticGoTo(model, goal=(0, 2)), GoTo(model, goal=(0, 2))
    closed = known(model, true_map)
    opened = known(model, np.where(true_map == CLOSED_DOOR, OPEN_DOOR, true_map))
    assert model.action_names[learned.choose(closed)] == "south"
    assert model.action_names[learned.choose(opened)] == "east"
    assert model.action_names[static.choose(closed)] == model.action_names[static.choose(opened)] == "east"
    prior_plan = plan_to_goal(model, model.label_prior, goal_cell(model, (0, 2)))
    np.testing.assert_array_equal(static.plan.q, prior_plan.q)


# --- bad goals -------------------------------------------------------------------------------------
def test_bad_goals_raise_model_errors_naming_the_goal():
    model, true_map = om.door_world(blocking=True, footprint="cross", p_door=0.05)
    model = with_floor_plan(model, true_map, 0.95)
    for goal in (100, -1, (10, 0), (0, 10), (-1, 3)):
        with pytest.raises(InvalidOptionError, match=rf"goal {__import__('re').escape(repr(goal))} .*off the"):
            make_planner("goto", model, goal=goal)
    for goal in ("north", 2.5, (1, 2, 3), True, None):
        with pytest.raises(InvalidOptionError, match="goal"):
            make_planner("goto", model, goal=goal)
    wall = int(np.flatnonzero(true_map == WALL)[0])
    with pytest.raises(InvalidOptionError, match=rf"goal {wall} \(cell {wall}\) is a wall under the prior.* 0.95"):
        make_planner("goto", model, goal=wall)
    with pytest.raises(InvalidOptionError, match=r"goal \(3, 0\) \(cell 30\) is a wall"):
        make_planner("static_goto", model, goal=(3, 0))
    enclosed, enclosed_map = om.door_world("..#.\n..#.\n", blocking=True)
    enclosed = with_floor_plan(enclosed, enclosed_map, 0.95)
    with pytest.raises(InvalidOptionError, match=r"goal \(0, 3\) \(cell 3\) cannot be reached from the start cell 0"):
        make_planner("goto", enclosed, goal=(0, 3))
    assert make_planner("goto", enclosed, goal=(1, 1)).goal == 5
    stuck, stuck_map = om.door_world("...\n...\n", blocking=True, p_move=0.0)
    with pytest.raises(ModelError, match="p_move = 0"):
        make_planner("goto", stuck, goal=2)
    with pytest.raises(InvalidOptionError, match="horizon"):
        make_planner("goto", model, goal=0, horizon=-1)
    assert planner_options("goto") == planner_options("static_goto") == {"goal": None, "horizon": None}


def test_a_door_the_prior_believes_closed_is_a_wall_only_if_it_never_opens():
    layout = "..c..\n"
    for p_door, fails in ((0.0, True), (0.05, False)):
        model, true_map = om.door_world(layout + "#####\n", blocking=True, p_door=p_door)
        model = with_floor_plan(model, true_map, 0.95)
        prior = np.array(model.label_prior)
        prior[2] = [0, 0, 0.05, 0.95]  # the door: believed closed
        model = om.GridModel(**{**{f: getattr(model, f) for f in om.model.DEFINING_FIELDS}, "label_prior": prior})
        if fails:
            with pytest.raises(InvalidOptionError, match=r"goal \(0, 4\) \(cell 4\) cannot be reached"):
                GoTo(model, goal=(0, 4))
        else:
            assert GoTo(model, goal=(0, 4)).goal == 4


# --- the navigation loop ---------------------------------------------------------------------------
OPEN = "....\n....\n....\n"  # 3 x 4, no walls, no doors


@pytest.fixture(scope="module")
def open_world():
    model, true_map = om.door_world(OPEN, blocking=True, footprint="cross", p_move=0.9)
    return with_floor_plan(model, true_map, 0.95), true_map


def test_navigate_reaches_the_goal_in_a_small_open_world(open_world):
    model, true_map = open_world
    found = navigate(model, true_map, (2, 3), max_steps=60, seed=4, estimator_options={"n_particles": 200})
    frame = found.frame
    assert tuple(frame.columns) == NAVIGATION_COLUMNS
    assert found.reached_at is not None and len(frame) == found.reached_at + 1  # stops on the goal
    assert frame["true_location"].iloc[-1] == 11 and (frame["true_location"].iloc[:-1] != 11).all()
    rows, cols = np.divmod(frame["true_location"].to_numpy(), 4)
    np.testing.assert_array_equal(frame["distance_to_goal"], (2 - rows) + (3 - cols))  # Manhattan, no walls
    # the estimator saw what the world emitted: a fresh filter fed the run's record agrees
    replay = om.make_estimator("rbpf", model, n_particles=200, seed=seed_streams(4)[2])
    for t, observation in enumerate(found.run.observations):
        belief = replay.step(None if t == 0 else int(found.run.actions[t - 1]), observation)
        assert belief.location.tobytes() == found.trajectory.location[t].tobytes()


def test_navigation_runs_with_one_seed_meet_the_same_doors_and_slips():
    """Paired runs: whatever the robot does, the maps (door changes) and the slips of step t
    are the same for every run with one seed; moves follow the blocking rule."""
    model, true_map = om.door_world(blocking=True, footprint="cross", p_door=0.1)
    runs = [navigate(model, true_map, (9, 9), planner, max_steps=40, seed=7,
                     estimator_options={"n_particles": 30}).run for planner in ("goto", "random", "static_goto")]
    slipped = []
    for run in runs:
        before, after = run.locations[:-1], run.locations[1:]
        intended = model.neighbors[before, run.actions]
        enters = ~model.blocking[run.maps[:-1][np.arange(len(before)), intended]]
        assert np.all((after == before) | ((after == intended) & enters))  # stays or makes its move
        moving = (intended != before) & enters  # the move is possible: it fails only by a slip
        slipped.append(dict(zip(np.flatnonzero(moving), after[moving] == before[moving])))
    steps = min(len(run.maps) for run in runs)
    assert steps > 20 and all(np.array_equal(run.maps[:steps], runs[0].maps[:steps]) for run in runs)
    assert (runs[0].maps[:steps] != runs[0].maps[0]).any()  # the doors did change
    for t in set(slipped[0]) & set(slipped[1]):
        assert slipped[0][t] == slipped[1][t]
    assert len(set(slipped[0]) & set(slipped[1])) > 5


def test_navigate_stops_after_max_steps_and_takes_any_planner(open_world):
    model, true_map = open_world
    short = navigate(model, true_map, 11, "static_goto", max_steps=2, seed=0, estimator_options={"n_particles": 50})
    assert short.reached_at is None and len(short.frame) == 3
    home = navigate(model, true_map, 0, max_steps=5, seed=0, estimator_options={"n_particles": 50})
    assert home.reached_at == 0 and len(home.frame) == 1 and home.frame["distance_to_goal"].iloc[0] == 0
    walk = navigate(model, true_map, 5, "random", max_steps=300, seed=1, estimator_options={"n_particles": 50})
    assert walk.reached_at is not None and walk.frame["true_location"].iloc[-1] == 5
    with pytest.raises(InvalidOptionError, match="goal once"):
        navigate(model, true_map, 5, max_steps=5, seed=0, planner_options={"goal": 6})
    with pytest.raises(InvalidOptionError, match=r"goes to cell 6, not to the goal 5"):
        navigate(model, true_map, 5, GoTo(model, goal=6), max_steps=5, seed=0)
    with pytest.raises(InvalidOptionError, match=r"goal \(3, 0\) .*off the"):
        navigate(model, true_map, (3, 0), max_steps=5, seed=0)
    with pytest.raises(InvalidOptionError, match="max_steps"):
        navigate(model, true_map, 5, max_steps=-1, seed=0)


@pytest.mark.parametrize("seed", range(5))
def test_true_distances_are_shortest_paths_on_the_true_map(seed):
    rng = np.random.default_rng(300 + seed)
    labels = random_door_map(rng, 5, 6)
    model = om.grid_model(5, 6, 4, label_names=DOOR_LABELS, blocking=("wall", "closed_door"))
    goal = int(rng.integers(30))
    expected = heap_dijkstra(model, np.where(model.blocking[labels], np.inf, 1.0), goal)
    np.testing.assert_array_equal(true_distances(model, labels, goal), expected)


def test_planning_leaves_the_live_estimator_bit_identical():
    model, true_map = om.door_world(blocking=True, footprint="cross", p_door=0.05)
    model = with_floor_plan(model, true_map, 0.95)
    estimator = om.make_estimator("rbpf", model, n_particles=100, seed=3)
    run = om.simulate(model, true_map, [1, 1, 2, 2, 1], seed=3)
    for t, observation in enumerate(run.observations):
        belief = estimator.step(None if t == 0 else int(run.actions[t - 1]), observation)
    before = snapshot(estimator)
    for name in ("goto", "static_goto"):
        make_planner(name, model, goal=(9, 9)).choose(belief)
    assert_state_unchanged(estimator, before)
    # and the filter goes on exactly as one that never planned
    twin = om.make_estimator("rbpf", model, n_particles=100, seed=3)
    for t, observation in enumerate(run.observations):
        twin.step(None if t == 0 else int(run.actions[t - 1]), observation)
    going_on, twin_going_on = estimator.step(0, run.observations[-1]), twin.step(0, run.observations[-1])
    assert going_on.location.tobytes() == twin_going_on.location.tobytes()
    assert going_on.map.tobytes() == twin_going_on.map.tobytes()


def test_oracle_walks_the_shortest_path_when_nothing_slips_or_changes(open_world):
    model, true_map = om.door_world(".....\n.###.\n.....\n", blocking=True, p_move=1.0)
    assert oracle_steps(model, true_map, (2, 4), max_steps=20, seed=0) == 6
    assert oracle_steps(model, true_map, (2, 4), max_steps=5, seed=0) is None
    assert oracle_steps(model, true_map, 0, max_steps=5, seed=0) == 0
    # a closed door that never opens on the short way: the oracle sees it and goes round
    model, true_map = om.door_world(".c...\n.#.#.\n.....\n", blocking=True, p_move=1.0)
    assert oracle_steps(model, true_map, (0, 2), max_steps=20, seed=0) == 6


@pytest.mark.parametrize("p_door", [0.02, 0.05, 0.3])
def test_the_horizon_ends_where_the_doors_have_mixed(p_door):
    """Door dynamics: P(open at tau | open now) = 1/2 + (1 - 2 p)^tau / 2, the limit 1/2; the
    powers stop at the first tau with (1 - 2 p)^tau / 2 <= 1e-3, within the given horizon."""
    model, _ = om.door_world(p_door=p_door)
    expected = math.ceil(math.log(2e-3) / math.log(1 - 2 * p_door))
    powers = label_powers(model, 1000)
    assert len(powers) - 1 == expected
    for tau in (0, 1, expected):
        np.testing.assert_allclose(powers[tau], np.linalg.matrix_power(model.change, tau), atol=1e-14)
    assert len(label_powers(model, 5)) == min(expected, 5) + 1  # the horizon given caps it
    assert len(label_powers(om.door_world(p_door=0.0)[0], 100)) == 1  # static: no time dependence
    assert len(label_powers(om.door_world(p_door=1.0)[0], 30)) == 31  # periodic: never mixes


def test_track_with_a_goal_planner_drives_a_simulated_robot_to_the_goal():
    """``onlinemap track --planner goto --goal ROW,COL`` in a subprocess: every output line
    carries an action; a simulated robot that takes those actions reaches the goal."""
    import json
    import subprocess
    import sys

    spec = "grid:3x4,blocking=1,footprint=cross"
    model = parse_world(spec).model
    true_map = np.array([0, 0, 0, 0, 0, 1, 1, 0, 0, 0, 0, 0])  # a wall in the middle: go round it
    world = PairedWorld(model, true_map, np.random.default_rng(5))
    proc = subprocess.Popen([sys.executable, "-m", "onlinemap", "track", "--world", spec, "--estimator", "exact",
                             "--planner", "goto", "--goal", "2,3"], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    observation, location, _ = world.reset()
    record = {"observation": observation.tolist()}
    for t in range(60):
        proc.stdin.write(json.dumps(record) + "\n")
        proc.stdin.flush()
        line = json.loads(proc.stdout.readline())
        assert line["t"] == t and line["action"] in model.action_names
        if location == 11:
            break
        observation, location, _ = world.advance(model.action_names.index(line["action"]))
        record = {"action": line["action"], "observation": observation.tolist()}
    proc.stdin.close()
    assert proc.wait(timeout=60) == 0, proc.stderr.read()
    assert location == 11, t
    assert '"planner": "GoTo(goal=11' in proc.stderr.read()


def test_track_refuses_a_bad_goal_or_a_goal_without_planner(monkeypatch, capsys):
    import io
    import sys

    from onlinemap.cli import main

    monkeypatch.setattr(sys, "stdin", io.StringIO(""))
    spec = ["track", "--world", "grid:3x4,blocking=1", "--estimator", "exact"]
    assert main(spec + ["--goal", "3"]) == 2 and "--goal needs --planner" in capsys.readouterr().err
    assert main(spec + ["--planner", "goto", "--goal", "9,9"]) == 2
    assert "goal (9, 9) (row, col) is off the 3 x 4 grid" in capsys.readouterr().err
    assert main(spec + ["--planner", "goto", "--goal", "x"]) == 2 and "--goal must be" in capsys.readouterr().err
    assert main(spec + ["--planner", "goto"]) == 2 and "--planner goto needs --goal CELL" in capsys.readouterr().err


# --- the navigation study on the sweep engine (onlinemap.studies.navigation) ------------------------
def test_navigation_metrics_by_hand():
    from onlinemap.evaluate import SUCCESS_WITHIN, navigation_metrics

    assert SUCCESS_WITHIN == 4
    row = navigation_metrics(30, 10)
    assert row["reached"] and row["oracle_reached"] and row["steps_over_oracle"] == 3.0 and row["success"]
    assert not navigation_metrics(41, 10)["success"]  # 4.1 times the oracle's steps
    missed = navigation_metrics(None, 10)
    assert not missed["reached"] and not missed["success"] and np.isnan(missed["steps_to_goal"])
    assert np.isnan(navigation_metrics(12, None)["steps_over_oracle"])  # the oracle never got there


def test_far_goals_are_the_free_cells_farthest_with_every_door_open():
    from onlinemap.studies.navigation import far_goals

    model, true_map = om.door_world("..#.\n.#c.\n....\n", blocking=True)
    # from cell 0 round the wall: cell 3 is 7 moves (0 4 8 9 10 11 7 3, or through the door 6),
    # cell 7 is 6, cell 11 is 5, cell 10 is 4; the door cell itself is no goal
    assert far_goals(model, true_map, 3) == [3, 7, 11]
    assert far_goals(model, true_map) == [3]


def test_navigation_tasks_on_the_engine_record_the_oracle_and_the_distance():
    """A navigate spec (goals): every planner to the goal on the same seeds, the oracle shared; a
    planner without a goal (random) runs as it is; the per-step distance to the goal ends at 0."""
    import policies

    spec = {"worlds": ["door,blocking=1,footprint=cross,p_door=0.05"], "floor_plan": 0.95, "goals": [[2, 1]],
            "seeds": 2, "steps": 60, "rows": "step", "planners": {"goto": {}, "random": {}},
            "estimators": {"rbpf": {"n_particles": 50}}}
    steps = om.sweep(spec, workers=0, progress=False)
    assert set(steps["kind"]) == {"navigate"} and set(steps["goal"]) == {21}
    goto = steps[steps["planner"] == "goto"]
    for _, run in goto.groupby("seed"):
        assert run["distance_to_goal"].iloc[-1] == 0 and (run["true_location"].iloc[-1] == 21)
    runs = om.sweep({**spec, "rows": "task"}, workers=0, progress=False)
    oracle = runs.groupby("seed")["oracle_steps"].nunique()
    assert (oracle == 1).all()  # one oracle per (world, goal, seed), whatever the planner
    model, true_map = om.door_world(blocking=True, footprint="cross", p_door=0.05)
    model = policies.with_floor_plan(model, true_map, 0.95)
    for seed in (0, 1):
        expected = policies.oracle_steps(model, true_map, 21, max_steps=59, seed=seed)
        assert runs.loc[runs["seed"] == seed, "oracle_steps"].iloc[0] == expected
        found = policies.navigate(model, true_map, 21, "goto", max_steps=59, seed=seed,
                                  estimator_options={"n_particles": 50})
        row = runs[(runs["seed"] == seed) & (runs["planner"] == "goto")].iloc[0]
        assert row["steps_to_goal"] == found.reached_at and row["success"] == (found.reached_at <= 4 * expected)


def test_navigate_command_prints_and_writes(tmp_path, capsys):
    from onlinemap.cli import main

    assert main(["navigate", "--goal", "2,1", "--repeats", "2", "--steps", "60", "-o", "n_particles=50",
                 "--out", str(tmp_path)]) == 0
    text = capsys.readouterr().out
    assert "goal cell 21" in text and "static_goto" in text and "success" in text
    for name in ("navigate_runs.csv", "navigate_summary.csv", "navigate_route.png", "navigate_vs_oracle.png"):
        assert (tmp_path / name).stat().st_size > 0
    assert main(["navigate", "--goal", "0,5", "--repeats", "1"]) == 2  # a wall: refused, one line
    assert "goal" in capsys.readouterr().err


def test_navigate_command_without_goal_in_a_world_without_free_labels_goes_to_the_far_cell(capsys):
    """Issue 42 item 7: ``navigate --world corridor:8`` (labels '0', '1', none named free) died in
    ``far_goals(...)[0]`` with an IndexError. Every label lets the robot in, so the far goal is the
    cell farthest from the start: the corridor's other end, the 3 x 3 grid's opposite corner."""
    from onlinemap.cli import main
    from onlinemap.studies.navigation import far_goals

    for world, goal in (("corridor:8", 7), ("grid:3x3", 8)):
        spec = parse_world(world)
        assert far_goals(spec.model, spec.initial_map(0)) == [goal]
        assert main(["navigate", "--world", world, "--repeats", "1", "--steps", "12", "-o", "n_particles=20"]) == 0
        out = capsys.readouterr().out
        assert f"goal cell {goal} " in out
        # every metric of the table defined under it (issue 42 item 7)
        assert "\nsuccess: share of runs reaching the goal within 4x the oracle's steps\n" in out
        assert "\nsteps_over_oracle: steps_to_goal / oracle_steps, per run\n" in out


def test_navigate_command_refuses_a_wall_goal_before_running_anything(capsys):
    """Issue 42 item 7: ``navigate --goal 3,0`` (a wall of the door world's floor plan) ran all its
    tasks, then said "rerun to retry". The goal is checked against the floor plan first."""
    from onlinemap.cli import main

    assert main(["navigate", "--goal", "3,0", "--repeats", "1", "-o", "n_particles=20"]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""  # no run started
    assert "wall" in captured.err and "cell 30" in captured.err and "rerun" not in captured.err


def test_navigate_command_refuses_planners_that_ignore_the_goal(capsys):
    """Issue 42 item 7: ``navigate --planner info_gain`` / ``frontier`` were accepted, and reached
    the goal in no run, since they never read it."""
    from onlinemap.cli import main

    for planners, named in (("info_gain", "info_gain"), ("goto,frontier", "frontier")):
        assert main(["navigate", "--planner", planners, "--repeats", "1"]) == 2
        err = capsys.readouterr().err
        assert f"--planner {named}" in err and "goal" in err and "goto, static_goto" in err
        assert len(err.strip().splitlines()) == 1


def test_navigate_command_says_so_when_no_oracle_reaches_the_goal(tmp_path, capsys):
    """Issue 43 section 2 item 2: with no run's oracle at the goal within --steps, ``navigate``
    ended in ``KeyError: 'n'`` (an empty summary), wrote no table with --out, and its rerun (which
    resumes) crashed again. Now it says why there is nothing to compare and writes the tables."""
    from onlinemap.cli import main

    argv = ["navigate", "--goal", "99", "--steps", "10", "--repeats", "1", "-o", "n_particles=20",
            "--out", str(tmp_path)]
    for _ in range(2):  # the rerun resumes from navigate.parts
        assert main(argv) == 0
        out = capsys.readouterr().out
        assert "the oracle reaches goal cell 99 within 10 steps in none of the 1 run(s)" in out
    runs = pd.read_csv(tmp_path / "navigate_runs.csv")
    assert len(runs) == 2 and not runs["oracle_reached"].any()
    summary = pd.read_csv(tmp_path / "navigate_summary.csv")
    assert summary.empty and {"planner", "runs", "success"} <= set(summary.columns)


def test_a_navigation_prints_on_one_line(open_world):
    """Issue 42 item 7: ``repr`` of a Navigation was 29 lines (the frame printed whole)."""
    model, true_map = open_world
    found = navigate(model, true_map, 8, "goto", max_steps=40, seed=0, estimator_options={"n_particles": 20})
    text = repr(found)
    assert "\n" not in text and len(text) < 200, text
    where = "never reached" if found.reached_at is None else f"reached at step {found.reached_at}"
    assert text.startswith(f"Navigation(goal cell 8 {where}; {len(found.frame)} steps from cell {model.start} to "
                           f"{found.run.locations[-1]}; frame {len(found.frame)} rows x ")


def test_navigate_takes_a_goal_in_a_0d_array_and_refuses_planners_that_are_not_planners(open_world):
    """Issue 43 section 2 item 8: ``policies.navigate(m, tm, np.array(99), ...)`` raised
    ``TypeError: len() of unsized object``; a planner of None or 5 raised AttributeError. A 0-d
    integer array is the cell it holds; anything without ``choose`` is a ModelError naming it."""
    model, true_map = open_world
    options = {"n_particles": 20}
    in_array = navigate(model, true_map, np.array(11), "goto", max_steps=30, seed=1, estimator_options=options)
    plain = navigate(model, true_map, 11, "goto", max_steps=30, seed=1, estimator_options=options)
    assert in_array.frame.attrs["goal"] == 11 and in_array.reached_at == plain.reached_at
    assert in_array.run.locations.tolist() == plain.run.locations.tolist()
    with pytest.raises(ModelError, match=r"goal must be a cell index or a \(row, col\) pair, got 2.5"):
        navigate(model, true_map, np.array(2.5), "goto", max_steps=3, seed=1, estimator_options=options)
    for planner in (None, 5):
        with pytest.raises(ModelError, match=f"planner must be a registered name .* or an object with a "
                                             f"choose\\(belief\\) method, got {type(planner).__name__} {planner}"):
            navigate(model, true_map, 11, planner, max_steps=3, seed=1, estimator_options=options)


def _cut_corridor(wall_chance):
    """A 2 x 4 static grid, start 0 (top left), goal 3 (top right), column 1 (cells 1 and 5)
    believed a wall with ``wall_chance``: the belief's map cuts the goal off."""
    model = om.grid_model(2, 4, 2, blocking=[1], p_move=0.8)
    maps = np.tile([1.0, 0.0], (8, 1))
    maps[[1, 5]] = [1 - wall_chance, wall_chance]
    return model, Belief(0, np.eye(8)[0], maps)


def test_goto_without_a_finite_plan_plans_walls_below_the_relaxed_threshold_as_passable(caplog):
    model, belief = _cut_corridor(0.9)
    planner = GoTo(model, goal=3)
    assert np.isinf(plan_to_goal(model, belief.map, 3).q[0]).all()  # the cut: no finite plan
    # Relaxed, by hand (alpha = 1 / p_move = 1.25 for a free cell, a wall at 0.9 costs (0.9 + 0.1 alpha) / 0.1):
    # east 1 + 10.25 + 1.25 + 1.25 ... its Q is finite; the others only via cell 5 or by waiting, dearer.
    with caplog.at_level("WARNING", logger="policies.navigation"):
        first = planner.choose(belief)
        second = planner.choose(belief)
    assert model.action_names[first] == "east" and first != 0  # not the lowest index (north, into the edge)
    assert planner.no_plan == 2 and planner.events[0] == {"event": "no_plan", "t": 0, "fallback": "relaxed"}
    assert len([r for r in caplog.records if r.name == "policies.navigation"]) == 1  # warned once


def test_goto_cut_off_even_when_relaxed_moves_towards_the_goal_and_drops_futile_presses():
    model, belief = _cut_corridor(0.9995)  # above RELAXED_WALL: cut off even when relaxed
    planner = GoTo(model, goal=3)
    # towards the goal at cell 0: east enters cell 1 (2 moves from 3), south cell 4 (4 moves), north/west stay (3)
    assert model.action_names[planner.choose(belief)] == "east"
    assert planner.events[-1]["fallback"] == "towards_goal"
    # the same belief again: the press of east changed nothing (futile), so the planner leaves it out
    assert model.action_names[planner.choose(belief)] != "east"


def test_goto_with_a_finite_plan_records_no_event():
    model, belief = _cut_corridor(0.4)
    planner = GoTo(model, goal=3)
    assert model.action_names[planner.choose(belief)] == "east" and planner.events == []


def test_navigation_metrics_say_whether_the_run_stalled():
    from onlinemap.evaluate import navigation_metrics
    assert navigation_metrics(None, 40, stalled_at=57)["stalled"] is True
    assert navigation_metrics(30, 40)["stalled"] is False


def test_navigate_ends_a_stalled_run_and_reports_its_step():
    # dead reckoning never moves its belief in a static corridor pressing left at the left end (cell 0)
    model = om.grid_model(1, 6, 2, blocking=[1])
    class Left:
        goal = 5
        def choose(self, belief):
            return 0
    found = navigate(model, np.zeros(6, dtype=int), 5, Left(), "dead_reckoning", max_steps=200, seed=1, stall_after=4)
    assert found.stalled_at == 4 and found.reached_at is None and found.run.n_steps == 5
    assert "stalled at step 4" in repr(found)
