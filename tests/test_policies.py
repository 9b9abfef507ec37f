"""policies: entropy reward, policy iteration, planners.

References: value iteration on dense transition tensors built here from the design's definition
of the motion model (not from the library's sparse motion), scipy.stats.entropy for the reward.
"""

import re

import numpy as np
import pytest
from scipy.stats import entropy

import onlinemap as om
from onlinemap.belief import Belief
from onlinemap.errors import InvalidOptionError, ModelError
from onlinemap.model import GridModel, symmetric_channel
from estimator_cases import binomial_ok
from policies import (PLANNERS, EntropyExplorer, RandomWalk, Sweep, action_values, collected_entropy_reward, entropy_reward,
                      evaluate_policy, make_planner, policy_iteration, policy_motion, sweep_actions)


def dense_motion(model: GridModel, passable=None) -> np.ndarray:
    """(A, N, N) T[a, i, j] straight from DESIGN.md section 1, one entry at a time; with
    ``passable`` (N,), the move into j succeeds with p_move * passable[j] (section 7)."""
    n, a_count = model.n_cells, model.n_actions
    passable = np.ones(n) if passable is None else passable
    motion = np.zeros((a_count, n, n))
    for a in range(a_count):
        for i in range(n):
            j = model.neighbors[i, a]
            if j == i:
                motion[a, i, i] = 1.0
            else:
                motion[a, i, j] += model.p_move * passable[j]
                motion[a, i, i] += 1.0 - model.p_move * passable[j]
    return motion


def value_iteration(motion: np.ndarray, reward: np.ndarray, gamma: float) -> tuple[np.ndarray, np.ndarray]:
    """(V*, Q*) by value iteration to a sup-norm change below 1e-13."""
    value = np.zeros(motion.shape[1])
    while True:
        q = np.einsum("aij,j->ia", motion, reward + gamma * value)
        new = q.max(axis=1)
        if np.abs(new - value).max() < 1e-13:
            return new, q
        value = new


def random_mdp(seed: int) -> tuple[GridModel, np.ndarray, float]:
    """A random topology: each action a random permutation of the cells (fixed points = no move)."""
    rng = np.random.default_rng(seed)
    n, a_count = int(rng.integers(2, 9)), int(rng.integers(1, 5))
    neighbors = np.stack([rng.permutation(n) for _ in range(a_count)], axis=1)
    model = GridModel(rows=1, cols=n, neighbors=neighbors, p_move=float(rng.uniform(0.05, 1.0)),
                      change=np.eye(2), sensor=symmetric_channel(2, 0.9), label_prior=[0.5, 0.5],
                      start=0, action_names=tuple(f"a{k}" for k in range(a_count)), label_names=("0", "1"))
    reward = rng.normal(size=n) * rng.choice([0.01, 1.0, 100.0])
    return model, reward, float(rng.uniform(0.0, 0.99))


@pytest.mark.parametrize("seed", range(40))
def test_policy_iteration_equals_value_iteration_on_random_mdps(seed):
    model, reward, gamma = random_mdp(seed)
    result = policy_iteration(model, reward, gamma)
    v_star, q_star = value_iteration(dense_motion(model), reward, gamma)
    scale = 1.0 + np.abs(v_star).max()
    np.testing.assert_allclose(result.value, v_star, atol=1e-9 * scale)
    np.testing.assert_allclose(result.q, q_star, atol=1e-9 * scale)
    cells = np.arange(model.n_cells)
    # the policy is greedy for its own Q, and V is the value of following it
    np.testing.assert_allclose(result.q[cells, result.policy], result.q.max(axis=1), atol=1e-9 * scale)
    np.testing.assert_allclose(result.value, result.q[cells, result.policy], atol=1e-9 * scale)
    # started from its own answer it finds nothing to improve and stops after one evaluation
    assert policy_iteration(model, reward, gamma, initial_policy=result.policy).iterations == 1


@pytest.mark.parametrize("seed", range(20))
def test_policy_iteration_on_the_beliefs_passability_equals_value_iteration(seed):
    model, reward, gamma = random_mdp(200 + seed)
    rng = np.random.default_rng(seed)
    passable = rng.uniform(0, 1, model.n_cells) * (rng.random(model.n_cells) > 0.3)
    motion = dense_motion(model, passable)
    result = policy_iteration(model, reward, gamma, passable=passable)
    v_star, q_star = value_iteration(motion, reward, gamma)
    scale = 1.0 + np.abs(v_star).max()
    np.testing.assert_allclose(result.value, v_star, atol=1e-9 * scale)
    np.testing.assert_allclose(result.q, q_star, atol=1e-9 * scale)
    policy = rng.integers(model.n_actions, size=model.n_cells)
    t_pi = motion[policy, np.arange(model.n_cells)]
    np.testing.assert_allclose(policy_motion(model, policy, passable).toarray(), t_pi, atol=1e-15)
    exact = np.linalg.solve(np.eye(model.n_cells) - gamma * t_pi, t_pi @ reward)
    np.testing.assert_allclose(evaluate_policy(model, reward, policy, gamma, passable), exact, rtol=1e-10, atol=1e-10)
    with pytest.raises(ModelError, match="passable"):
        policy_iteration(model, reward, gamma, passable=np.full(model.n_cells, 1.5))


def numpy_policy_system(model, policy, gamma, reward, passable):
    """The policy's system ``(I - gamma T_pi) V = T_pi R`` as planners built it in numpy before the
    kernels (policies/mdp.py up to 0.9): CSR ``I - gamma T_pi`` and the right-hand side."""
    import scipy.sparse as sp

    n = model.n_cells
    cells = np.arange(n)
    targets = model.neighbors[cells, policy]
    moves = targets != cells
    if passable is None:
        stay, go = model.self_prob[policy, cells], np.where(moves, model.p_move, 0.0)
    else:
        go = np.where(moves, model.p_move * passable[targets], 0.0)
        stay = 1.0 - go
    swap = targets < cells
    cols = np.stack([np.minimum(cells, targets), np.maximum(cells, targets)], axis=1)
    probs = np.stack([np.where(swap, go, stay), np.where(swap, stay, go)], axis=1)
    keep = np.stack([np.ones(n, dtype=bool), moves], axis=1)
    values = (cols == cells[:, None]) - gamma * probs
    indptr = np.concatenate([[0], np.cumsum(keep.sum(axis=1))])
    return sp.csr_array((values[keep], cols[keep], indptr), shape=(n, n)), (probs * reward[cols]).sum(axis=1)


def numpy_policy_iteration(model, reward, gamma, policy, passable, tolerance=1e-10):
    """Policy iteration as the planners ran it in numpy before the kernels: spsolve, Q, greedy."""
    from scipy.sparse.linalg import spsolve

    cells = np.arange(model.n_cells)
    if passable is None:
        go = np.full(model.neighbors.shape, model.p_move)
    else:
        go = np.where(model.neighbors != cells[:, None], model.p_move * passable[model.neighbors], 0.0)
    for iteration in range(1, 1000):
        value = spsolve(*numpy_policy_system(model, policy, gamma, reward, passable))
        future = reward + gamma * value
        q = (1.0 - go) * future[:, None] + go * future[model.neighbors]
        best = np.argmax(q, axis=1)
        current = q[cells, policy]
        better = q[cells, best] > current + tolerance * (1.0 + np.abs(current))
        if not better.any():
            return value, q, policy, iteration
        policy = np.where(better, best, policy)


@pytest.mark.parametrize("with_passable", [False, True])
def test_policy_iteration_is_the_numpy_and_spsolve_answer_bit_for_bit(with_passable):
    """The kernels build the policy's system and improve the policy with the same operations, in
    the same order, as the numpy code they replaced, and SuperLU gets spsolve's arguments: the
    same bits for the value, Q, the policy and the iteration count, so no planner's run moves."""
    from scipy.sparse.linalg import spsolve

    for seed in range(12):
        model, reward, gamma = random_mdp(300 + seed)
        rng = np.random.default_rng(seed)
        passable = rng.uniform(0, 1, model.n_cells) * (rng.random(model.n_cells) > 0.2) if with_passable else None
        policy = rng.integers(model.n_actions, size=model.n_cells)
        expected = spsolve(*numpy_policy_system(model, policy, gamma, reward, passable))
        assert evaluate_policy(model, reward, policy, gamma, passable).tobytes() == expected.tobytes()
        result = policy_iteration(model, reward, gamma, initial_policy=policy, passable=passable)
        value, q, final, iterations = numpy_policy_iteration(model, reward, gamma, policy, passable)
        assert (result.value.tobytes(), result.q.tobytes(), result.iterations) == (value.tobytes(), q.tobytes(), iterations)
        np.testing.assert_array_equal(result.policy, final)
        assert action_values(model, reward, value, gamma, passable).tobytes() == q.tobytes()


@pytest.mark.parametrize("seed", range(10))
def test_warm_start_and_policy_evaluation_match_dense_references(seed):
    model, reward, gamma = random_mdp(100 + seed)
    motion = dense_motion(model)
    rng = np.random.default_rng(seed)
    policy = rng.integers(model.n_actions, size=model.n_cells)
    cells = np.arange(model.n_cells)
    t_pi = motion[policy, cells]
    np.testing.assert_allclose(policy_motion(model, policy).toarray(), t_pi, atol=1e-15)
    exact = np.linalg.solve(np.eye(model.n_cells) - gamma * t_pi, t_pi @ reward)
    np.testing.assert_allclose(evaluate_policy(model, reward, policy, gamma), exact, rtol=1e-10, atol=1e-10)
    cold = policy_iteration(model, reward, gamma)
    warm = policy_iteration(model, reward, gamma, initial_policy=policy)
    np.testing.assert_allclose(warm.value, cold.value, rtol=1e-9, atol=1e-9)


def test_policy_iteration_on_a_grid_walks_towards_the_reward():
    model = om.grid_model(6, 7, 2, p_move=0.8)
    reward = np.zeros(model.n_cells)
    goal = model.n_cells - 1  # bottom-right corner
    reward[goal] = 1.0
    result = policy_iteration(model, reward, 0.9)
    names = [model.action_names[a] for a in result.policy]
    rows, cols = np.divmod(np.arange(model.n_cells), model.cols)
    for cell in range(model.n_cells - 1):
        assert names[cell] in ("east", "south"), (cell, names[cell])
        if rows[cell] == model.rows - 1:
            assert names[cell] == "east"
        if cols[cell] == model.cols - 1:
            assert names[cell] == "south"
    assert result.value.argmax() == goal


def test_policy_iteration_rejects_bad_input():
    model = om.grid_model(2, 3, 2)
    with pytest.raises(ModelError, match="shape"):
        policy_iteration(model, np.zeros(5))
    with pytest.raises(ModelError, match="NaN"):
        policy_iteration(model, np.full(6, np.nan))
    with pytest.raises(InvalidOptionError, match="gamma"):
        policy_iteration(model, np.zeros(6), gamma=1.0)
    with pytest.raises(InvalidOptionError, match="initial_policy"):
        policy_iteration(model, np.zeros(6), initial_policy=np.full(6, 4))


def belief(location, maps) -> Belief:
    return Belief(0, np.asarray(location, dtype=float), np.asarray(maps, dtype=float))


def test_entropy_reward_matches_its_formula():
    rng = np.random.default_rng(0)
    for _ in range(20):
        n, k = rng.integers(2, 12), rng.integers(2, 5)
        location = rng.dirichlet(np.full(n, 0.3))
        maps = rng.dirichlet(np.full(k, 0.5), size=n)
        h_l = entropy(location) / np.log(n)
        h_m = entropy(maps, axis=1) / np.log(k)
        expected = h_l * (1 - h_m) + (1 - h_l) * h_m
        np.testing.assert_allclose(entropy_reward(belief(location, maps)), expected, atol=1e-12)
        np.testing.assert_allclose(collected_entropy_reward(belief(location, maps)),
                                   expected * (1 - location), atol=1e-12)


def corridor_belief(n, known, location) -> Belief:
    """Map: cells in ``known`` certain (label 0), the others uniform."""
    maps = np.full((n, 2), 0.5)
    maps[known] = [1.0, 0.0]
    return belief(location, maps)


def test_a_certain_robot_goes_to_the_unknown_cell():
    model = om.corridor(8)
    known = [0, 1, 2, 3, 5, 6, 7]
    b = corridor_belief(8, known, np.eye(8)[3])  # certain to be in cell 3; cell 4 unknown
    reward = entropy_reward(b)
    assert reward.argmax() == 4 and reward[4] == pytest.approx(1.0) and np.allclose(reward[known], 0)
    assert model.action_names[EntropyExplorer(model).choose(b)] == "right"
    b = corridor_belief(8, known, np.eye(8)[6])  # now in cell 6: the unknown cell is to the left
    assert model.action_names[EntropyExplorer(model).choose(b)] == "left"


def test_a_lost_robot_goes_to_the_cells_it_knows():
    model = om.corridor(8)
    b = corridor_belief(8, [4, 5, 6, 7], np.full(8, 1 / 8))  # lost; knows the right half
    reward = entropy_reward(b)
    np.testing.assert_allclose(reward, [0, 0, 0, 0, 1, 1, 1, 1], atol=1e-12)
    assert model.action_names[EntropyExplorer(model).choose(b)] == "right"
    b = corridor_belief(8, [0, 1, 2, 3], np.full(8, 1 / 8))  # knows the left half
    assert model.action_names[EntropyExplorer(model).choose(b)] == "left"


def test_collected_reward_moves_a_robot_off_the_cell_it_just_observed():
    model = om.corridor(3)
    maps = np.full((3, 2), 0.5)  # nothing known, robot certain to be in the middle
    b = belief([0.0, 1.0, 0.0], maps)
    assert collected_entropy_reward(b)[1] == 0.0
    assert entropy_reward(b)[1] == 1.0
    # certain to be at the left end, bumping the wall collects nothing; moving right does
    # (19.75 against 18.77), whereas the plain reward counts the wall cell again (20 against 20)
    b = belief([1.0, 0.0, 0.0], maps)
    left, right = model.action_names.index("left"), model.action_names.index("right")
    collected = EntropyExplorer(model, reward=collected_entropy_reward)
    assert collected.choose(b) == right
    assert collected.plan.q[0, right] > collected.plan.q[0, left] + 0.5
    plain = EntropyExplorer(model, reward=entropy_reward)
    plain.choose(b)
    assert plain.plan.q[0, right] == pytest.approx(plain.plan.q[0, left], abs=1e-9)


def test_explorer_replans_every_k_steps():
    model = om.corridor(8)
    explorer = EntropyExplorer(model, replan_every=3)
    b = corridor_belief(8, [0, 1, 2], np.eye(8)[1])
    plans = []
    for _ in range(7):
        explorer.choose(b)
        plans.append(explorer.plan)
    assert [plans[i] is plans[i - 1] for i in range(1, 7)] == [True, True, False, True, True, False]
    with pytest.raises(InvalidOptionError):
        EntropyExplorer(model, replan_every=0)


def test_random_walk_is_reproducible_and_uniform():
    model, _ = om.door_world()
    b = belief(model.location_prior(), model.label_prior)
    walk_a, walk_b = RandomWalk(model, seed=3), RandomWalk(model, seed=3)
    draws = np.array([walk_a.choose(b) for _ in range(4000)])
    assert np.array_equal(draws, [walk_b.choose(b) for _ in range(4000)])
    assert not np.array_equal(draws[:50], [RandomWalk(model, seed=4).choose(b) for _ in range(50)])
    counts = np.bincount(draws, minlength=4)
    assert np.all(binomial_ok(counts, 4000, 0.25))  # each count ~ Binomial(4000, 1/4)


@pytest.mark.parametrize("layout", ["...\n...\n", "....\n....\n....\n", om.DOOR_WORLD_10X10])
def test_sweep_covers_every_cell_without_slips_and_ignores_beliefs(layout):
    model, true_map = om.door_world(layout, p_move=1.0)
    actions = sweep_actions(model)
    run = om.simulate(model, true_map, actions, seed=0)
    assert set(run.locations) == set(range(model.n_cells))
    assert run.locations[-1] == model.start  # one cycle returns to the corner
    sweep = Sweep(model)
    b = belief(model.location_prior(), model.label_prior)
    chosen = [sweep.choose(b) for _ in range(2 * len(actions))]
    assert np.array_equal(chosen, np.concatenate([actions, actions]))


def test_sweep_in_a_corridor_and_unknown_planners():
    model = om.corridor(5)
    assert [model.action_names[a] for a in sweep_actions(model)] == ["right"] * 5 + ["left"] * 5
    with pytest.raises(ModelError, match="unknown planner"):
        make_planner("greedy", model)
    for stuck in (om.corridor(5, p_move=0.0), om.door_world("...\n...\n", p_move=0.0)[0]):
        with pytest.raises(ModelError, match="p_move > 0"):
            Sweep(stuck)
        with pytest.raises(ModelError, match="p_move > 0"):
            make_planner("sweep", stuck)


# --- every planner in a world with blocking labels ------------------------------------------------
#: options that keep the registered planners quick here (info_gain) or that they need (a goal)
PLANNER_OPTIONS = {"info_gain": {"hypotheses": 2, "rollout_particles": 16}, "goto": {"goal": 99},
                   "static_goto": {"goal": 99}}


def blocking_runs(planner: str, prior: str, steps: int):
    """An exploration of the blocking, cross-footprint door world, and the belief each decision saw."""
    from policies import with_floor_plan
    from policies.explore import exploration

    model, true_map = om.door_world(blocking=True, footprint="cross")
    if prior == "floor plan":  # walls known at 0.999 from the start, door states unknown
        model = with_floor_plan(model, true_map, 0.999)
    options = PLANNER_OPTIONS.get(planner)
    return model, exploration(model, true_map, planner, "rbpf", steps=steps, seed=5, progress=False,
                              estimator_options={"n_particles": 50}, planner_options=options)


@pytest.mark.parametrize("prior", ["floor plan", "uniform"])
@pytest.mark.parametrize("planner", sorted(PLANNERS))
def test_no_planner_presses_twice_in_a_row_into_what_the_belief_says_blocks(planner, prior):
    """A move whose intended cell holds a blocking label with probability > 0.99 under the belief
    (summed over the location belief; a move off the grid edge holds no label and does not count)
    is not chosen at two decisions in a row while another move is possible. Before planners read
    the belief's passability, ``entropy`` pressed ``south`` into a closed door 115 times of 120."""
    from onlinemap.belief import Belief
    from policies.passability import BLOCKED_ABOVE, blocked_probability

    steps = 30 if planner == "info_gain" else 120
    model, found = blocking_runs(planner, prior, steps)
    trajectory, actions = found.trajectory, found.run.actions
    bad = []
    for t, action in enumerate(actions):  # action t was chosen from the belief after step t
        blocked = blocked_probability(model, Belief(t, trajectory.location[t], trajectory.map[t]))
        bad.append(bool(blocked[action] > BLOCKED_ABOVE and (blocked <= BLOCKED_ABOVE).any()))
    twice = [t for t in range(1, len(bad)) if bad[t] and bad[t - 1]]
    assert not twice, (planner, twice[:5])
    if prior == "floor plan":  # the walls are known: the check had something to catch
        assert max(blocked_probability(model, Belief(t, trajectory.location[t], trajectory.map[t])).max()
                   for t in range(len(actions))) > BLOCKED_ABOVE


@pytest.mark.parametrize("planner", sorted(PLANNERS))
def test_planning_leaves_the_live_estimator_bit_identical_in_a_blocking_world(planner):
    from onlinemap import checkpoint
    from onlinemap.estimators import make_estimator

    model, true_map = om.door_world(blocking=True, footprint="cross")
    est = make_estimator("rbpf", model, n_particles=40, seed=1)
    run = om.simulate(model, true_map, np.random.default_rng(0).integers(4, size=12), seed=2)
    for t in range(run.n_steps):
        est.step(None if t == 0 else int(run.actions[t - 1]), run.observations[t])
    before, rng_before = checkpoint.state_dict(est), est._rng.bit_generator.state
    chooser = make_planner(planner, model, seed=0, **PLANNER_OPTIONS.get(planner, {}))
    if hasattr(chooser, "bind"):
        chooser.bind(est)
    for _ in range(3):
        assert 0 <= chooser.choose(est.belief) < model.n_actions
    assert checkpoint.same_tree(before, checkpoint.state_dict(est))
    assert est._rng.bit_generator.state == rng_before


def test_random_and_sweep_skip_presses_the_belief_says_block():
    """Robot certain to be in the middle of the top row of a 3 x 3 blocking world whose middle row
    is known to be wall: south is out; west and east are open."""
    model, _ = om.door_world("...\n###\n...\n", blocking=True)
    maps = np.tile([1.0, 0.0, 0.0, 0.0], (9, 1))
    maps[3:6] = [0.0, 1.0, 0.0, 0.0]
    b = belief(np.eye(9)[1], maps)
    south = model.action_names.index("south")
    walk = RandomWalk(model, seed=3)
    draws = np.array([walk.choose(b) for _ in range(3000)])
    counts = np.bincount(draws, minlength=4)
    assert counts[south] == 0 and np.all(binomial_ok(np.delete(counts, south), 3000, 1 / 3))
    sweep = Sweep(model)
    expected = [a for a in sweep_actions(model) if a != south]  # the belief stays: every south is skipped
    assert [sweep.choose(b) for _ in range(len(expected))] == expected
    # nothing blocks without blocking labels: the same belief leaves both planners as they were
    plain, _ = om.door_world("...\n###\n...\n")
    walk_a, walk_b = RandomWalk(plain, seed=3), RandomWalk(plain, seed=3)
    assert [walk_a.choose(b) for _ in range(50)] == [int(walk_b.rng.integers(4)) for _ in range(50)]


def test_entropy_planner_does_not_repeat_a_press_that_left_the_belief_unchanged():
    """A blocking corridor, robot certain at cell 1 facing an uncertain cell 2 to the right: it
    presses right; shown the same belief again (every hypothesis predicted the failure), it
    presses left instead, and right again once the belief has changed. Without blocking labels
    it is the paper's planner: the same belief, the same action."""
    model = om.corridor(5, blocking=1)
    maps = np.tile([1.0, 0.0], (5, 1))
    maps[2:] = [0.5, 0.5]
    b = belief(np.eye(5)[1], maps)
    right, left = model.action_names.index("right"), model.action_names.index("left")
    planner = EntropyExplorer(model)
    assert [planner.choose(b), planner.choose(b)] == [right, left]
    changed = maps.copy()
    changed[2] = [0.6, 0.4]
    assert planner.choose(belief(np.eye(5)[1], changed)) == right
    plain = EntropyExplorer(om.corridor(5))
    assert [plain.choose(b), plain.choose(b)] == [right, right]


NAN, INF = float("nan"), float("inf")
#: per planner, options of the wrong type or out of range (issue 24, defect 3); frontier's are in test_frontier
BAD_OPTIONS = {
    "info_gain": [("hypotheses", NAN), ("hypotheses", "x"), ("hypotheses", 1.5), ("hypotheses", True),
                  ("hypotheses", 0), ("rollout_particles", 2.5), ("rollout_particles", "8"),
                  ("press_lengths", "x"), ("press_lengths", [1.5]), ("press_lengths", []), ("press_lengths", [0, 2]),
                  ("press_lengths", 3), ("step_cost", "x"), ("step_cost", None), ("step_cost", NAN),
                  ("step_cost", INF), ("step_cost", -1.0), ("location_weight", None), ("location_weight", INF),
                  ("location_weight", NAN), ("commit", None), ("commit", True), ("commit", 1.5), ("commit", 0),
                  ("gamma", None), ("gamma", NAN), ("gamma", 1.0), ("anchor_every", NAN), ("anchor_every", "x"),
                  ("anchor_every", True), ("anchor_every", 2.5)],
    "entropy": [("gamma", NAN), ("gamma", "x"), ("gamma", None), ("gamma", -0.1), ("replan_every", 1.5),
                ("replan_every", True), ("replan_every", "x"), ("replan_every", 0), ("reward", "x")],
    "entropy_collect": [("gamma", INF), ("replan_every", None)],
    "goto": [("horizon", 1.5), ("horizon", "x"), ("horizon", True), ("horizon", NAN), ("horizon", -1),
             ("goal", "x"), ("goal", 1.5), ("goal", None)],
    "static_goto": [("horizon", INF), ("goal", (0, 99))],
}


@pytest.mark.parametrize("planner,option,value", [(p, o, v) for p, cases in BAD_OPTIONS.items() for o, v in cases])
def test_bad_planner_options_raise_invalid_option_errors_naming_them(planner, option, value):
    model, _ = om.door_world()
    options = {"goal": 99} if planner in ("goto", "static_goto") else {}
    options[option] = value
    with pytest.raises(InvalidOptionError, match=option):
        make_planner(planner, model, seed=0, **options)


@pytest.mark.parametrize("planner", ["random", "info_gain"])
@pytest.mark.parametrize("seed", ["x", -1, 1.5, True])
def test_bad_planner_seeds_raise_invalid_option_errors(planner, seed):
    with pytest.raises(InvalidOptionError, match="seed"):
        make_planner(planner, om.door_world()[0], seed=seed)


def test_astronomical_plans_are_refused_with_their_cost():
    """A plan estimated above onlinemap.arguments.MAX_OPERATIONS (or info_gain's exact enumeration
    above MAX_PLAN_FORKS forks) is refused when the planner is built, naming the options to lower
    and the estimate, instead of running for minutes."""
    from policies.info_gain import MAX_PLAN_FORKS

    model, _ = om.door_world(blocking=True, footprint="cross")
    for options, named in (({"hypotheses": 10**6}, "hypotheses"), ({"press_lengths": [10**6]}, "press_lengths"),
                           ({"rollout_particles": 10**7}, "rollout_particles")):
        with pytest.raises(InvalidOptionError, match=f"(?s)operations.*{named}"):
            make_planner("info_gain", model, **options)
    square, _ = om.door_world(footprint="square")
    with pytest.raises(InvalidOptionError, match=re.escape(f"{MAX_PLAN_FORKS:.0e} estimator forks")):
        make_planner("info_gain", square, hypotheses=None, press_lengths=(1,))
    make_planner("info_gain", om.corridor(4), hypotheses=None, press_lengths=(1, 2, 6))  # 2^6 forks: fine
    cycling, _ = om.door_world(p_door=1.0)  # doors swap every step: C never mixes
    with pytest.raises(InvalidOptionError, match="(?s)horizon=1000000000.*operations.*horizon"):
        make_planner("goto", cycling, goal=99, horizon=10**9)
    make_planner("goto", om.door_world()[0], goal=99, horizon=10**9)  # static: a plan is one Dijkstra
