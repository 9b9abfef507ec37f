"""policies.info_gain: the expected information gain against brute-force enumeration of the
exact belief and every observation outcome; the particle rollout kernel against the same
enumeration; a hand-checkable decision; planning leaves the live estimator bit-identical;
and info_gain beats the paper's entropy planner in the paper's world (paired over seeds)."""

import itertools
import math

import numpy as np
import pytest
from scipy import stats

import onlinemap as om
from onlinemap import checkpoint
from onlinemap.errors import InvalidOptionError, ModelError
from onlinemap.estimators import fork, make_estimator
from oracles import BruteForce
from policies import InfoGainExplorer, expected_uncertainty, explore, exploration_world, make_planner
from onlinemap.estimators.base import ParticleSnapshot
from onlinemap.estimators.rbpf_kernels import world_tables
from policies.information import uncertainty
from policies.explore import exploration
from policies.rollouts import footprint_expected_uncertainty, particle_expected_uncertainty


def entropy(p):
    p = np.asarray(p)
    return float(-(p[p > 0] * np.log(p[p > 0])).sum())


def oracle_observations(oracle):
    """Every observation of the oracle's sensor: a label, or a tuple of readings, each a label or
    -1 for an offset that is off the grid from some cell."""
    if oracle.single:
        return list(range(oracle.k))
    per_offset = [list(range(oracle.k)) + ([-1] if any(reads[f] is None for reads in oracle.reads) else [])
                  for f in range(len(oracle.reads[0]))]
    return list(itertools.product(*per_offset))


def brute_expected_uncertainty(oracle, joint, actions, location_weight):
    """E[location_weight H(L) + sum_i H(m_i)] after each prefix of ``actions``, enumerating every
    observation sequence over the (l, m) states of the oracle."""
    out = np.zeros(len(actions) + 1)
    loc, maps = oracle.marginals(joint)
    out[0] = location_weight * entropy(loc) + sum(entropy(row) for row in maps)
    for h in range(1, len(actions) + 1):
        for zs in itertools.product(oracle_observations(oracle), repeat=h):
            p = joint.copy()
            for a, z in zip(actions[:h], zs):
                p = (p @ oracle.transition(a)) * oracle.likelihood(z)
            total = p.sum()  # P(z_1..h | data)
            if total == 0:
                continue
            loc, maps = oracle.marginals(p / total)
            out[h] += total * (location_weight * entropy(loc) + sum(entropy(row) for row in maps))
    return out


def brute_joint(oracle, actions, observations):
    p = oracle.prior.copy()
    for t, z in enumerate(observations):
        if t > 0:
            p = p @ oracle.transition(actions[t - 1])
        p = p * oracle.likelihood(z)
        p /= p.sum()
    return p


TINY_WORLDS = {
    "corridor4": lambda: om.corridor(4, 2, p_obs=0.85, p_move=0.7),
    "grid2x2": lambda: om.grid_model(2, 2, 2, p_obs=0.8, p_move=0.75,
                                     change=om.model.symmetric_channel(2, 0.9)),
    # a footprint reading off the grid (-1) at the right end, and a label that blocks
    "corridor3 footprint": lambda: om.corridor(3, 2, p_obs=0.85, p_move=0.7, blocking=1,
                                               footprint=((0, 0), (0, 1))),
    "corridor3 right": lambda: om.corridor(3, 2, p_obs=0.85, p_move=0.7, footprint=((0, 1),)),
}


@pytest.mark.parametrize("world", sorted(TINY_WORLDS))
def test_expected_uncertainty_equals_brute_force(world):
    model = TINY_WORLDS[world]()
    oracle = BruteForce.of(model)
    rng = np.random.default_rng(3)
    past_actions = rng.integers(model.n_actions, size=3)
    est = make_estimator("exact", model)
    past_obs = om.simulate(model, om.sample_map(model, 5), past_actions, seed=2).observations  # possible ones
    for t, z in enumerate(past_obs):
        est.step(None if t == 0 else int(past_actions[t - 1]), z)
    joint = brute_joint(oracle, past_actions, past_obs)
    for actions in ([0], [1, 1], [model.n_actions - 1, 0, 1]):
        got = expected_uncertainty(est, actions, hypotheses=None, location_weight=0.7)
        want = brute_expected_uncertainty(oracle, joint, actions, 0.7)
        np.testing.assert_allclose(got, want, rtol=1e-10, atol=1e-12)


def test_planner_gains_with_the_exact_estimator_equal_brute_force():
    model = TINY_WORLDS["grid2x2"]()
    oracle = BruteForce.of(model)
    est = make_estimator("exact", model)
    est.step(None, 1)
    est.step(2, 0)
    planner = InfoGainExplorer(model, seed=0, hypotheses=None, press_lengths=(1, 2), location_weight=1.5)
    planner.bind(est)
    plan = planner.plan(est.belief)
    joint = brute_joint(oracle, [2], [1, 0])
    i0 = math.log(2) - entropy([0.8, 0.2])  # one observation of a uniform binary cell at p_obs 0.8
    for c, sequence in enumerate(plan.sequences):
        want = brute_expected_uncertainty(oracle, joint, list(sequence[:2]), 1.5 * i0)
        np.testing.assert_allclose(plan.gain[c], want[0] - want[[1, 2]], rtol=1e-10, atol=1e-12)
    c, j = plan.chosen  # the best utility among macro-actions not pressing into a wall the robot is at
    location, _ = oracle.marginals(joint)
    blocked = np.array([location @ (np.diagonal(oracle.motion[s[0]]) == 1.0) for s in plan.sequences])
    assert blocked[c] < 0.5 and plan.utility[c, j] == plan.utility[blocked < 0.5].max()


def test_sampled_expectation_agrees_with_enumeration():
    """The sampled backend (worlds from the exact joint, forks of the estimator) is unbiased: its
    mean over S worlds is within 4 standard errors of the enumeration."""
    model = TINY_WORLDS["corridor4"]()
    est = make_estimator("exact", model)
    for a, z in [(None, 0), (1, 1), (1, 1)]:
        est.step(a, z)
    actions = [0, 0]
    exact = expected_uncertainty(est, actions, hypotheses=None)
    rng = np.random.default_rng(7)
    samples = np.array([expected_uncertainty(est, actions, hypotheses=1, seed=rng)[-1] for _ in range(400)])
    assert abs(samples.mean() - exact[-1]) < 4 * samples.std(ddof=1) / math.sqrt(len(samples))


@pytest.mark.parametrize("p_change", [0.0, 0.1])
def test_particle_rollout_equals_brute_force_for_an_exact_particle_belief(p_change):
    """With deterministic motion (p_move = 1), a weighted set of (location, product map) particles
    is an exact belief and the RBPF update of each particle is exact. The kernel's expected
    uncertainty over sampled worlds must match the enumeration over every observation
    sequence (4 standard errors), at every prefix length."""
    model = om.corridor(4, 2, p_obs=0.8, p_move=1.0, p_change=p_change)
    oracle = BruteForce.of(model)
    rng = np.random.default_rng(11)
    maps = rng.dirichlet([1.0, 1.0], size=(3, 4))
    particles = ParticleSnapshot(np.array([0, 1, 3]), maps, np.log([0.5, 0.3, 0.2]))
    joint = np.zeros(len(oracle.states))
    for s, (l, m) in enumerate(oracle.states):
        for p in range(3):
            if particles.locations[p] == l:
                joint[s] += math.exp(particles.log_weights[p]) * np.prod([maps[p, i, m[i]] for i in range(4)])
    actions = np.array([1, 1, 0])
    want = brute_expected_uncertainty(oracle, joint, actions, 1.0)
    values = []
    for _ in range(1500):
        p = rng.choice(3, p=np.exp(particles.log_weights))
        labels = (rng.random((1, 4)) > maps[p, :, 0]).astype(np.int64)  # label 1 w.p. maps[p, i, 1]
        worlds = (particles.locations[[p]], labels)
        values.append(particle_expected_uncertainty(model, particles, actions[None], np.ones(4, bool), worlds,
                                                    rng)[0])
    values = np.array(values)
    np.testing.assert_allclose(values[:, 0], want[0], rtol=1e-12)
    error = np.abs(values.mean(axis=0) - want)[1:]
    assert np.all(error < 4 * values.std(axis=0, ddof=1)[1:] / math.sqrt(len(values)) + 1e-9), (error, want)


def test_a_robot_unsure_of_its_cell_goes_where_the_hypotheses_differ():
    """Corridor with known labels 0, 0, 0, 1, 0, start at cell 1, p_move = 0.5: after one press
    right seeing 0 the robot is at cell 1 or 2, even odds, far from the walls. One step left
    teaches nothing (every cell it could reach reads 0, and it spreads the belief); going right
    does (from 2 it may reach the cell labelled 1), by a margin of 0.2 nats at 1 and 2 steps."""
    prior = np.full((5, 2), [0.999, 0.001])
    prior[3] = [0.001, 0.999]
    model = om.corridor(5, 2, p_obs=0.9, p_move=0.5, label_prior=prior, start=1)
    est = make_estimator("exact", model)
    est.step(None, 0)
    est.step(1, 0)
    assert abs(est.belief.location[1] - est.belief.location[2]) < 0.01
    planner = InfoGainExplorer(model, seed=0, hypotheses=None, press_lengths=(1, 2), step_cost=0.0)
    planner.bind(est)
    plan = planner.plan(est.belief)
    left, right = plan.names.index("press left"), plan.names.index("press right")
    assert plan.names[plan.chosen[0]] == "press right"
    assert np.all(plan.gain[right] > plan.gain[left] + 0.2), plan.gain


def test_a_lost_robot_presses_into_a_wall():
    """Unknown map, slippery floor: after three presses right the robot is spread over cells 0-3
    of a 5-cell corridor. The best macro-action is a long press (into a wall), not one step."""
    model = om.corridor(5, 2, p_obs=0.9, p_move=0.6)
    est = make_estimator("exact", model)
    for a, z in [(None, 0), (1, 1), (1, 0), (1, 1)]:
        est.step(a, z)
    planner = InfoGainExplorer(model, seed=0, hypotheses=None, press_lengths=(1, 2, 6), step_cost=0.05,
                               location_weight=1.0)
    planner.bind(est)
    plan = planner.plan(est.belief)
    c, j = plan.chosen
    assert plan.names[c].startswith("press") and plan.lengths[j] == 6


def _state(est):
    return checkpoint.state_dict(est), est.belief


@pytest.mark.parametrize("name,options", [("rbpf", {"n_particles": 300, "seed": 4}), ("exact", {}),
                                          ("bk", {})])
def test_planning_leaves_the_live_estimator_bit_identical(name, options):
    model, true_map = om.door_world(".o.\n#c.\n", p_door=0.05)
    if name == "rbpf":
        model, true_map = exploration_world(p_door=0.01, p_move=0.8, floor_plan=None)
    est = make_estimator(name, model, **options)
    twin = make_estimator(name, model, **options)
    run = om.simulate(model, true_map, np.random.default_rng(0).integers(4, size=30), seed=1)
    for t in range(run.n_steps):
        a = None if t == 0 else int(run.actions[t - 1])
        est.step(a, int(run.observations[t]))
        twin.step(a, int(run.observations[t]))
    before = checkpoint.state_dict(est)
    rng_before = est._rng.bit_generator.state if hasattr(est, "_rng") else None
    planner = make_planner("info_gain", model, seed=0, hypotheses=3, commit=1)
    planner.bind(est)
    for _ in range(3):
        planner.choose(est.belief)
    assert checkpoint.same_tree(before, checkpoint.state_dict(est))
    if rng_before is not None:
        assert est._rng.bit_generator.state == rng_before
    for a, z in [(1, 0), (2, 1), (3, 0)]:  # and it continues exactly as a twin that never planned
        np.testing.assert_array_equal(est.step(a, z).map, twin.step(a, z).map)


def test_exact_sample_states_follow_the_joint():
    """Drawn states against the brute-force joint of the oracle (independent of the filter): a
    chi-square test over the (location, map) states, 20 000 draws."""
    model = om.corridor(3, 2, p_obs=0.85, p_move=0.7)
    actions, observations = [1, 1], [0, 1, 1]
    est = make_estimator("exact", model)
    for t, z in enumerate(observations):
        est.step(None if t == 0 else actions[t - 1], z)
    oracle = BruteForce.of(model)
    joint = brute_joint(oracle, actions, observations)
    locations, maps = est.sample_states(20_000, np.random.default_rng(3))
    assert locations.dtype == maps.dtype == np.int64 and maps.shape == (20_000, 3)
    index = {state: i for i, state in enumerate(oracle.states)}
    counts = np.bincount([index[(int(l), tuple(int(v) for v in m))] for l, m in zip(locations, maps)],
                         minlength=len(joint))
    keep = joint > 0
    assert counts[~keep].sum() == 0
    assert stats.chisquare(counts[keep], 20_000 * joint[keep] / joint[keep].sum()).pvalue > 1e-4


def test_particle_snapshot_and_sampled_states_read_the_particles():
    """All particles: the filter's public particles, weights and maps; thinned to M by systematic
    sampling: each particle kept floor or ceil of M times its weight (summed per cell), each map a
    particle's, weights equal; sampled states: locations with the particles' weights (chi-square)."""
    model, true_map = exploration_world(p_door=0.01, p_move=0.8, floor_plan=None)
    est = make_estimator("rbpf", model, n_particles=200, seed=4)
    run = om.simulate(model, true_map, np.random.default_rng(0).integers(4, size=15), seed=1)
    for t in range(run.n_steps):
        est.step(None if t == 0 else int(run.actions[t - 1]), int(run.observations[t]))
    whole = est.particle_snapshot()
    np.testing.assert_array_equal(whole.locations, est.particles)
    np.testing.assert_allclose(np.exp(whole.log_weights), est.weights, rtol=1e-12)
    np.testing.assert_array_equal(whole.maps, est.particle_maps())
    thinned = est.particle_snapshot(64, np.random.default_rng(1))
    assert len(thinned.locations) == 64 and np.allclose(thinned.log_weights, -math.log(64))
    share = 64 * est.weights / est.weights.sum()
    low = np.bincount(est.particles, weights=np.floor(share), minlength=model.n_cells)
    high = np.bincount(est.particles, weights=np.ceil(share), minlength=model.n_cells)
    got = np.bincount(thinned.locations, minlength=model.n_cells)
    assert np.all((low - 1e-9 <= got) & (got <= high + 1e-9))
    for location, maps in zip(thinned.locations, thinned.maps):  # each a copy of a particle's map
        assert any(np.array_equal(maps, whole.maps[i]) for i in np.flatnonzero(whole.locations == location))
    locations, maps = est.sample_states(20_000, np.random.default_rng(2))
    p = np.bincount(est.particles, weights=est.weights, minlength=model.n_cells)
    seen = p > 0
    counts = np.bincount(locations, minlength=model.n_cells)
    assert counts[~seen].sum() == 0 and maps.shape == (20_000, model.n_cells)
    assert stats.chisquare(counts[seen], 20_000 * p[seen] / p[seen].sum()).pvalue > 1e-4
    mixture = np.einsum("p,pnk->nk", est.weights / est.weights.sum(), whole.maps)  # each cell's label marginal
    cell = int(np.argmax(-(mixture * np.log(np.maximum(mixture, 1e-300))).sum(axis=1)))  # the least certain
    labels = np.bincount(maps[:, cell], minlength=model.n_labels)
    assert stats.chisquare(labels[mixture[cell] > 0], 20_000 * mixture[cell][mixture[cell] > 0]).pvalue > 1e-4


def test_pending_counts_the_presses_left_of_the_chosen_macro_action():
    """After a plan, ``pending`` is the committed presses not yet made (the chosen length, at most
    ``commit``, minus the one just made); it falls by one a decision and the next plan comes at 0."""
    model, true_map = exploration_world(p_door=0.0, p_move=0.8, floor_plan=None)
    est = make_estimator("rbpf", model, n_particles=100, seed=0)
    planner = make_planner("info_gain", model, seed=0, hypotheses=2, commit=3)
    planner.bind(est)
    belief = est.step(None, int(om.simulate(model, true_map, [], seed=0).observations[0]))
    assert planner.pending == 0
    planner.choose(belief)
    plan = planner.last_plan
    committed = min(int(plan.lengths[plan.chosen[1]]), 3)
    assert planner.pending == committed - 1
    for left in range(committed - 2, -1, -1):
        planner.choose(belief)
        assert planner.pending == left and planner.last_plan is plan
    planner.choose(belief)
    assert planner.last_plan is not plan


def test_fork_is_independent_and_continues_like_the_original():
    model = om.corridor(6, 2)
    est = make_estimator("rbpf", model, n_particles=50, seed=2)
    est.step(None, 0)
    copy = fork(est)
    assert copy.model is est.model and copy._rng is not est._rng
    a = copy.step(1, 1)
    b = est.step(1, 1)
    np.testing.assert_array_equal(a.map, b.map)
    copy.step(1, 0)
    assert est.t == 1 and copy.t == 2


def test_bad_options_raise_invalid_option_errors_and_unbound_use_model_errors():
    model, _ = exploration_world(p_door=0.0, p_move=0.8, floor_plan=None)
    for options in ({"hypotheses": 0}, {"rollout_particles": 0}, {"commit": 0}, {"gamma": 1.0},
                    {"step_cost": -1.0}, {"press_lengths": [0, 2]}, {"threads": 0}, {"threads": 10**6}):
        with pytest.raises(InvalidOptionError):
            make_planner("info_gain", model, **options)
    planner = make_planner("info_gain", model, seed=0)
    est = make_estimator("rbpf", model, n_particles=10, seed=0)
    belief = est.step(None, 0)
    state = planner.rng.bit_generator.state
    with pytest.raises(ModelError, match="bind"):
        planner.choose(belief)
    assert planner.rng.bit_generator.state == state
    with pytest.raises(ModelError, match="different model"):
        planner.bind(make_estimator("rbpf", om.door_world(p_move=0.8)[0], n_particles=10))
    with pytest.raises(ModelError):
        expected_uncertainty(make_estimator("exact", om.corridor(3)), [0])


def test_a_plan_on_two_threads_chooses_as_on_one():
    """The building's rollouts split between threads: the same run, action for action and belief
    for belief (the scores are the same bits, tests above)."""
    model, true_map = om.building(12, 12, seed=1, p_move=0.8)
    runs = [exploration(model, true_map, "info_gain", "rbpf", 25, 4, estimator_options={"n_particles": 100},
                        planner_options={"threads": threads}, progress=False, score=False) for threads in (1, 2)]
    assert runs[0].run.actions.tolist() == runs[1].run.actions.tolist()
    assert np.array_equal(runs[0].trajectory.map, runs[1].trajectory.map)


def test_explore_runs_info_gain_by_name_reproducibly():
    model, true_map = exploration_world(p_door=0.01, p_move=0.8, floor_plan=None)
    options = {"n_particles": 100}
    first = explore(model, true_map, "info_gain", "rbpf", steps=40, seed=3, estimator_options=options)
    second = explore(model, true_map, "info_gain", "rbpf", steps=40, seed=3, estimator_options=options)
    assert first["action"].equals(second["action"]) and np.array_equal(first["map_error"], second["map_error"])


# Seeds from the power wanted: one-sided paired t-test at alpha = 0.05 with power 0.95 (z_a = z_b =
# 1.645), n = ((z_a + z_b) / d)^2 + z_a^2 / 2 (the second term corrects the normal approximation for
# the t), d = mean / sd of the per-seed difference of the mean map error over the run (entropy -
# info_gain), measured with these settings on 40 pilot seeds (1000-1039, disjoint from the test's):
# mean 0.0436, sd 0.0615, d = 0.71: n = (3.29 / 0.71)^2 + 1.35 = 22.8; the noncentral t gives power
# 0.951 at 23. (The final map error alone has d = 0.50 on the same pilots and needs 46 seeds: the
# mean over the run counts every step's error, early steps included, where info_gain's lead is
# widest, d = 1.4-2.2 at steps 100-200, and the end too.)
PAIRED_SEEDS = 23


@pytest.mark.slow
def test_info_gain_maps_the_papers_world_better_than_the_entropy_planner():
    """The paper's world (10 x 10 doors, uniform prior, p_move 0.8, p_obs 0.9), RBPF with 100
    particles, 600 steps, paired seeds: info_gain's map error, averaged over the run (the area
    under its map-error curve), is lower than the paper's entropy planner's, one-sided paired
    t-test p < 0.05 (power 0.95 for the effect measured on other seeds, above). (Full size, 20
    seeds of 1000 steps with 1000 particles, final map error: see the guide's Exploration page.)"""
    model, true_map = exploration_world(p_door=0.0, p_move=0.8, floor_plan=None)
    mean_error = {planner: np.array([explore(model, true_map, planner, "rbpf", steps=600, seed=seed,
                                             estimator_options={"n_particles": 100})["map_error"].mean()
                                     for seed in range(PAIRED_SEEDS)])
                  for planner in ("info_gain", "entropy")}
    assert stats.ttest_rel(mean_error["info_gain"], mean_error["entropy"], alternative="less").pvalue < 0.05


def test_bench_planning_reports_ms_per_decision_and_the_whole_loop():
    from onlinemap.bench import run_benchmarks

    table = run_benchmarks(["planning"], quick=True)
    assert list(table["case"].str.contains("per decision")) == [True, False, True, False, False, False]
    assert list(table["case"].str.contains("whole loop")) == [False, False, False, False, True, True]
    assert table["case"].iloc[-2].startswith("32x32 building") and "particle_context" not in table["case"].iloc[-2]
    assert "label_prior=particle_context" in table["case"].iloc[-1]
    assert (table["ms"] > 0).all() and (table["reference_ms"] > 0).all() and (table["cpu_ms"].iloc[-2:] > 0).all()


def corner_of(model, cell):
    """The grid corner nearest ``cell`` (ties to the north and west), by brute force."""
    r, c = divmod(cell, model.cols)
    row = 0 if r <= (model.rows - 1) / 2 else model.rows - 1
    col = 0 if c <= (model.cols - 1) / 2 else model.cols - 1
    return row * model.cols + col


@pytest.mark.parametrize("shape", [(4, 5), (5, 4), (1, 6), (3, 3)])
def test_anchor_actions_press_into_the_nearest_corner(shape):
    """From a known cell, the anchor presses end in the nearest corner on a floor that never slips,
    and stay there on one that slips (every press only moves towards the corner)."""
    from policies.info_gain import anchor_actions

    model = om.grid_model(*shape, 2, p_move=1.0)
    for cell in range(model.n_cells):
        location = np.zeros(model.n_cells)
        location[cell] = 1.0
        belief = om.Belief(0, location, np.full((model.n_cells, 2), 0.5))
        actions = anchor_actions(model, belief, max(shape))
        end = cell
        for a in actions:
            end = int(model.neighbors[end, a])
        assert end == corner_of(model, cell)


def test_info_gain_explores_a_one_cell_grid_past_its_first_anchor():
    """Issue 43 section 2 item 9: on a 1 x 1 grid ``anchor_actions`` returned no press (both
    axes of size 1 skipped) and info_gain's queue ran empty at its first anchor: ``IndexError:
    pop from empty list`` at step 8. The one cell is its own corner: the anchor presses in place."""
    import policies
    from policies.info_gain import anchor_actions

    model = om.grid_model(1, 1, 2)
    belief = om.Belief(0, np.ones(1), np.full((1, 2), 0.5))
    assert anchor_actions(model, belief, 3).tolist() == [0, 0, 0]
    frame = policies.explore(model, om.sample_map(model, 0), "info_gain", "rbpf", steps=30, seed=0,
                             estimator_options={"n_particles": 5})
    assert len(frame) == 30 and (frame["true_location"] == 0).all()


def test_info_gain_re_anchors_every_anchor_every_steps():
    """With commit 1 and anchor_every = 2 H + 3: 2 H + 3 plans, then 2 H presses into the corner
    nearest the expected location (no plan meanwhile), 3 plans, and the next anchor."""
    from policies.info_gain import anchor_actions

    model, _ = exploration_world(p_door=0.0, p_move=0.8, floor_plan=None)
    est = make_estimator("rbpf", model, n_particles=50, seed=0)
    belief = est.step(None, 0)
    presses = 13
    planner = make_planner("info_gain", model, seed=0, hypotheses=2, commit=1, anchor_every=2 * presses + 3)
    planner.bind(est)
    plans = []

    def calls(n):
        out = []
        for _ in range(n):
            out.append(planner.choose(belief))
            plans.append(planner.last_plan)
        return out

    calls(2 * presses + 3)
    assert len({id(p) for p in plans}) == 2 * presses + 3  # a plan every call
    anchor = anchor_actions(model, belief, presses).tolist()
    assert calls(2 * presses) == anchor and all(p is plans[2 * presses + 2] for p in plans[-2 * presses:])
    calls(3)
    assert len({id(p) for p in plans[-3:]}) == 3
    assert calls(2 * presses) == anchor
    for too_short in (0, 2 * presses, True):
        with pytest.raises(ModelError, match="anchor_every"):
            make_planner("info_gain", model, anchor_every=too_short)


def test_a_world_the_fork_cannot_explain_is_left_out_and_planning_never_raises():
    """Issue 24, defect 1: a rollout whose simulated readings a fork of the filter cannot explain
    (one particle that may follow a slip the world did not take, depletion recovery off, a
    sensor reading off the grid at the corridor's end) used to raise ImpossibleObservationError
    out of ``planner.choose``. Such a world has probability zero under the fork's belief: it is
    left out of the mean; the planner chooses and the live filter is untouched."""
    model = om.corridor(4, 2, p_move=0.6, footprint=((0, 1),), blocking=1)
    est = make_estimator("rbpf", model, n_particles=1, seed=0)
    est.recover_from_depletion = False
    belief = est.step(None, 0)
    before = checkpoint.state_dict(est)
    actions = [1, 1, 1, 0, 0, 0]
    for seed in range(5):
        got = expected_uncertainty(est, actions, hypotheses=30, seed=seed)
        assert np.all(np.isfinite(got)) and got[0] == uncertainty(belief)
    planner = make_planner("info_gain", model, seed=0, hypotheses=30, anchor_every=None)
    planner.bind(est)
    for _ in range(10):
        assert 0 <= planner.choose(belief) < model.n_actions
    assert checkpoint.same_tree(before, checkpoint.state_dict(est))


def test_rollouts_read_the_cell_the_sensor_reads():
    """Issue 24, defect 9: with the one-offset footprint ((0, 1),) the sensor reads the cell to
    the robot's right, and so must the rollouts. A robot that cannot move (p_move = 0) at cell 0,
    known to hold label 0, has read cell 1 once (marginal [0.9, 0.1]): one more step reads cell 1
    again, an expected gain of I(m_1; z) (information_reward, computed by hand below), not the
    nothing of re-reading its own known cell. The rollout gain of a world is g(z) =
    H(m_1) - H(m_1 | z), one of two values, so the mean over S worlds has standard deviation at
    most |g(0) - g(1)| / 2 / sqrt(S): 4 of them (false failure about 6e-5)."""
    prior = np.array([[0.999, 0.001], [0.5, 0.5], [0.5, 0.5]])
    model = om.corridor(3, 2, p_obs=0.9, p_move=0.0, footprint=((0, 1),), label_prior=prior)
    est = make_estimator("rbpf", model, n_particles=20, seed=0)
    belief = est.step(None, 0)
    np.testing.assert_allclose(belief.map[1], [0.9, 0.1])
    marginal, sensor = belief.map[1], model.sensor
    after = {z: marginal * sensor[:, z] / (marginal @ sensor[:, z]) for z in (0, 1)}
    gains = {z: entropy(marginal) - entropy(after[z]) for z in (0, 1)}
    want = sum((marginal @ sensor[:, z]) * gains[z] for z in (0, 1))
    hypotheses = 400
    planner = make_planner("info_gain", model, seed=1, hypotheses=hypotheses, press_lengths=(1,),
                           anchor_every=None)
    planner.bind(est)
    plan = planner.plan(belief)
    tolerance = 4 * abs(gains[0] - gains[1]) / 2 / math.sqrt(hypotheses)
    np.testing.assert_allclose(plan.gain[:, 0], want, atol=tolerance)
    assert want > 0.1


# --- the rollouts of footprint and blocking models (policies.kernels.footprint.plan_rollouts) ------
def one_hot_particles(model, joint):
    """Every (location, map) state of the oracle with positive probability as a particle whose map
    is certain: an exact particle belief of ``joint``."""
    oracle = BruteForce.of(model)
    keep = np.flatnonzero(joint > 0)
    locations = np.array([oracle.states[s][0] for s in keep])
    maps = np.array([np.eye(model.n_labels)[list(oracle.states[s][1])] for s in keep])
    labels = np.array([oracle.states[s][1] for s in keep])
    return ParticleSnapshot(locations, maps, np.log(joint[keep] / joint[keep].sum())), labels


FOOTPRINT_WORLDS = {  # (model, planned actions, past actions): p_move = 1, so every particle's successor is
    # determined by its certain map and the exact particle belief stays exact
    "corridor blocking, right footprint": (lambda: om.corridor(3, 2, p_obs=0.85, p_move=1.0, blocking=1,
                                                               footprint=((0, 0), (0, 1))), [1, 1, 0], [1, 0]),
    "2 x 2 blocking, cross": (lambda: om.grid_model(2, 2, 2, p_obs=0.8, p_move=1.0, blocking=1, footprint="cross"),
                              [1], [1, 2]),
    # with map dynamics a certain label does not stay certain: one step only
    "corridor blocking, dynamic": (lambda: om.corridor(3, 2, p_obs=0.85, p_move=1.0, blocking=1, p_change=0.1,
                                                       footprint=((0, 0), (0, 1))), [1], [1, 0]),
}


@pytest.mark.parametrize("world", sorted(FOOTPRINT_WORLDS))
def test_footprint_rollouts_equal_the_exact_forks_for_an_exact_particle_belief(world):
    """The numba rollouts of a footprint/blocking model, on a particle set that is the exact
    belief (one particle per state), against the exact forks (``expected_uncertainty`` of the
    ``exact`` estimator, every observation enumerated; equal to brute force above): the mean over
    worlds drawn from the belief is within 4 standard errors at every prefix. The standard error
    is measured from 40 batch means of 100 worlds each (independent batches, t with 39 degrees
    of freedom: 4 of them is a false failure of about 3e-4 per entry, 1e-3 over a test's 1-3)."""
    make, actions, past = FOOTPRINT_WORLDS[world]
    model = make()
    oracle = BruteForce.of(model)
    run = om.simulate(model, om.sample_map(model, 5), past, seed=2)
    est = make_estimator("exact", model)
    for t, z in enumerate(run.observations):
        est.step(None if t == 0 else int(past[t - 1]), z)
    want = expected_uncertainty(est, actions, hypotheses=None)
    np.testing.assert_allclose(want, brute_expected_uncertainty(oracle, brute_joint(oracle, past, run.observations),
                                                                actions, 1.0), rtol=1e-9)
    particles, labels = one_hot_particles(model, brute_joint(oracle, past, run.observations))
    rng = np.random.default_rng(11)
    sequences, checkpoints = np.array([actions]), np.ones(len(actions) + 1, dtype=bool)
    batches = []
    for _ in range(40):
        chosen = rng.choice(len(labels), size=100, p=np.exp(particles.log_weights))
        batches.append(footprint_expected_uncertainty(model, particles, sequences, checkpoints,
                                                      (particles.locations[chosen], labels[chosen]), rng)[0])
    batches = np.array(batches)
    np.testing.assert_allclose(batches[:, 0], want[0], rtol=1e-12)
    error = np.abs(batches.mean(axis=0) - want)[1:]
    assert np.all(error < 4 * batches.std(axis=0, ddof=1)[1:] / math.sqrt(len(batches)) + 1e-12), (error, want)


STEP_WORLDS = {
    "corridor blocking, right footprint": lambda: om.corridor(3, 2, p_obs=0.85, p_move=0.7, blocking=1,
                                                              footprint=((0, 0), (0, 1))),
    "corridor blocking, dynamic": lambda: om.corridor(3, 2, p_obs=0.85, p_move=0.7, blocking=1, p_change=0.1,
                                                      footprint=((0, 0), (0, 1))),
    "2 x 2 blocking, cross": lambda: om.grid_model(2, 2, 2, p_obs=0.8, p_move=0.6, blocking=1, footprint="cross"),
    "2 x 2 three labels, two blocking, dynamic": lambda: om.grid_model(
        2, 2, 3, p_obs=0.8, p_move=0.6, blocking=[1, 2], footprint="cross", change=om.model.symmetric_channel(3, 0.9)),
}


@pytest.mark.parametrize("world", sorted(STEP_WORLDS))
def test_a_rollout_step_is_bayes_in_expectation(world):
    """One rollout step of particles with uncertain maps on a slipping floor: each particle draws
    one successor by the optimal proposal, so its weight (the sum over successors of motion x
    likelihood) does not depend on the draw and the weighted location histogram and map mixture
    equal, in expectation over the draws, Bayes' posterior of the particle mixture given the
    action and the simulated reading, computed here by brute force over (l, m) states. Mean over
    4000 draws; an entry whose draws vary must lie within 4.5 standard errors (a false failure of
    about 7e-6 per entry, under 1e-3 over the at most 60 entries), the others to rounding."""
    from policies.kernels.footprint import Beliefs, rollout_beliefs
    from policies.kernels.planning import Hypotheses
    from policies.rollouts import rollout_tables

    model = STEP_WORLDS[world]()
    oracle = BruteForce.of(model)
    rng = np.random.default_rng(sorted(STEP_WORLDS).index(world))
    r_count, n, k, f = 3, model.n_cells, model.n_labels, model.n_readings
    locations = rng.integers(n, size=r_count)
    maps = rng.dirichlet(np.ones(k), size=(r_count, n))
    log_weights = np.log(rng.dirichlet(np.ones(r_count)))
    joint = np.array([sum(math.exp(log_weights[p]) * np.prod([maps[p, i, m[i]] for i in range(n)])
                          for p in range(r_count) if locations[p] == l) for l, m in oracle.states])
    tables = rollout_tables(model, 1)
    state = oracle.states[rng.choice(len(joint), p=joint)]
    world_u, change_u = rng.random((1, 1 + f)), rng.random((1, 0 if model.is_static else n))
    action = 1
    location_draws, map_draws = [], []
    for _ in range(4000):
        out_location, out_maps = np.zeros((2, n)), np.zeros((2, n, k))
        where, readings = np.zeros(2, dtype=np.int64), np.zeros((1, f), dtype=np.int64)
        rollout_beliefs(ParticleSnapshot(locations, maps, log_weights), world_tables(model), tables, np.array([action]),
                        Hypotheses(np.array([state[0]]), np.array([state[1]]), world_u[None], change_u[None],
                                   rng.random((1, 1, r_count))), Beliefs(out_location, out_maps, where, readings))
        location_draws.append(out_location[1])
        map_draws.append(out_maps[1])
    z = readings[0] if f > 1 else int(readings[0, 0])
    posterior = (joint @ oracle.transition(action)) * oracle.likelihood(z)
    want_location, want_maps = oracle.marginals(posterior / posterior.sum())
    for draws, want in ((np.array(location_draws), want_location), (np.array(map_draws), want_maps)):
        error = np.abs(draws.mean(axis=0) - want)
        assert np.all(error <= 4.5 * draws.std(axis=0, ddof=1) / math.sqrt(len(draws)) + 1e-10), error.max()


@pytest.mark.parametrize("p_door", [0.0, 0.05])
def test_rollout_uncertainty_equals_the_whole_beliefs(p_door):
    """plan_rollouts sums the entropy of the cells every particle agrees on once and recomputes
    only the disputed and touched cells: its U after every step equals U of the whole weighted
    particle belief that rollout_beliefs returns for the same world and random numbers."""
    from policies.kernels.footprint import Agreement, Beliefs, Candidates, plan_rollouts, rollout_beliefs
    from policies.kernels.planning import Hypotheses, Scoring
    from policies.rollouts import agreement, rollout_tables

    model, _ = om.door_world(blocking=True, footprint="cross", p_door=p_door)
    rng = np.random.default_rng(1)
    r_count, horizon, n = 20, 12, model.n_cells
    maps = np.repeat(rng.dirichlet(np.ones(4), size=n)[None], r_count, axis=0)
    maps[:, :30] = rng.dirichlet(np.ones(4), size=(r_count, 30))  # cells 0-29 disputed
    particles = ParticleSnapshot(rng.integers(0, n, r_count), maps, np.log(rng.dirichlet(np.ones(r_count))))
    tables = rollout_tables(model, horizon)
    actions, labels = rng.integers(0, 4, horizon), rng.integers(0, 4, n)
    world_u, proposal_u = rng.random((1, horizon, 6)), rng.random((1, horizon, r_count))
    change_u = rng.random((1, horizon, 0 if model.is_static else n))
    disputed, agree = agreement(model, particles, horizon, tables)
    assert disputed.tolist() == list(range(30))
    out = np.zeros((1, horizon + 1))
    world, hyp = world_tables(model), Hypotheses(np.array([55]), labels[None], world_u, change_u, proposal_u)
    plan_rollouts(particles, world, tables, Candidates(actions[None], np.zeros((1, n)), np.zeros((n, 4))), hyp,
                  Scoring(2.0, np.ones(horizon + 1, bool)), Agreement(disputed, agree), out)
    location, mixture = np.zeros((horizon + 1, n)), np.zeros((horizon + 1, n, 4))
    where, readings = np.zeros(horizon + 1, dtype=np.int64), np.zeros((horizon, 5), dtype=np.int64)
    rollout_beliefs(particles, world, tables, actions, hyp, Beliefs(location, mixture, where, readings))
    whole = [2.0 * entropy(location[h]) + sum(entropy(row) for row in mixture[h]) for h in range(horizon + 1)]
    np.testing.assert_allclose(out[0], whole, rtol=1e-12, atol=1e-10)


@pytest.mark.parametrize("shape", [(1, 5, 3), (2, 7, 2), (24, 100, 4)])
def test_disputed_cells_are_those_some_particle_sees_otherwise(shape):
    """disputed_cells against numpy's compare-and-reduce: rows changed in one particle, in one
    entry only, in particle 0 only, and a NaN (never equal to itself)."""
    from policies.kernels.mixture import disputed_cells

    rng = np.random.default_rng(5)
    r_count, n, k = shape
    maps = np.repeat(rng.dirichlet(np.ones(k), size=n)[None], r_count, axis=0)
    for c in rng.choice(n, max(1, n // 4), replace=False):
        maps[rng.integers(r_count), c, rng.integers(k)] += 1e-12
    maps[0, n - 1] = np.nan
    expected = np.flatnonzero(np.any(maps != maps[:1], axis=(0, 2)))
    got = disputed_cells(maps)
    assert np.array_equal(got, expected) and got.dtype == expected.dtype
    assert len(expected) >= (2 if r_count > 1 else 1)  # rows were changed: the check has teeth


@pytest.mark.parametrize("p_door", [0.0, 0.05])
def test_candidates_pressing_alike_share_a_rollout_and_score_as_if_alone(p_door):
    """plan_rollouts steps the candidates that have pressed the same so far in a world once and
    copies the state when they part: every candidate's scores equal, bit for bit, those of a call
    with that candidate alone; and those of the worlds rolled out one at a time and added in order,
    whatever the threads the worlds are split between. Fixed sequences that share prefixes of 0 to 7 presses, and
    candidates choosing in closed loop (towards random distance fields), part at every step; half
    the cells agreed (their entropy is summed once and a touched one recomputed)."""
    from policies.kernels.footprint import Agreement, Candidates, plan_rollouts
    from policies.kernels.planning import Hypotheses, Scoring
    from policies.rollouts import agreement, rollout_tables

    model, _ = om.door_world(blocking=True, footprint="cross", p_door=p_door)
    rng = np.random.default_rng(3)
    r_count, horizon, n, worlds = 24, 9, model.n_cells, 4
    maps = np.repeat(rng.dirichlet(np.ones(4), size=n)[None], r_count, axis=0)
    maps[:, ::2] = rng.dirichlet(np.ones(4), size=(r_count, (n + 1) // 2))  # every other cell disputed
    particles = ParticleSnapshot(rng.integers(0, n, r_count), maps, np.log(rng.dirichlet(np.ones(r_count))))
    tables = rollout_tables(model, horizon)
    base = rng.integers(0, 4, horizon)
    sequences = [base.copy() for _ in range(6)] + [np.full(horizon, -1)] * 4 + [np.full(horizon, 2)]
    for c, parted in enumerate([0, 1, 3, 5, 7]):  # candidate c + 1 presses like base until step `parted`
        sequences[c + 1][parted:] = rng.integers(0, 4, horizon - parted)
    sequences = np.array(sequences, dtype=np.int64)
    distances = rng.random((len(sequences), n)) * 10
    distances[-2] = distances[-3]  # two candidates towards the same target never part
    go = rng.random((n, 4))
    hyp = (rng.integers(0, n, worlds), rng.integers(0, 4, (worlds, n)))
    world_u, proposal_u = rng.random((worlds, horizon, 6)), rng.random((worlds, horizon, r_count))
    change_u = rng.random((worlds, horizon, 0 if model.is_static else n))
    disputed, agree = agreement(model, particles, horizon, tables)
    checkpoints = np.zeros(horizon + 1, dtype=bool)
    checkpoints[[0, 1, 2, 4, 8, 9]] = True
    world, hyp = world_tables(model), Hypotheses(*hyp, world_u, change_u, proposal_u)

    def scores(rows, threads=1, worlds=slice(None)):
        out = np.zeros((len(rows), horizon + 1))
        plan_rollouts(particles, world, tables, Candidates(sequences[rows], distances[rows], go),
                      Hypotheses(*(x[worlds] for x in hyp)), Scoring(2.0, checkpoints), Agreement(disputed, agree), out,
                      threads)
        return out

    together = scores(np.arange(len(sequences)))
    alone = np.concatenate([scores(np.array([c])) for c in range(len(sequences))])
    assert np.array_equal(together, alone)
    in_order = np.zeros_like(together)  # the worlds one at a time, their scores added in world order
    for s in range(worlds):
        in_order += scores(np.arange(len(sequences)), worlds=slice(s, s + 1))
    assert np.array_equal(together, in_order)
    for threads in (2, 3, worlds + 1):  # the worlds split between threads: the same bits
        assert np.array_equal(scores(np.arange(len(sequences)), threads), together)
    assert np.array_equal(together[-3], together[-2])
    assert scores(np.arange(0)).shape == (0, horizon + 1)  # no candidate: nothing to roll out
    assert len({row.tobytes() for row in together}) >= 8  # the candidates differ: the check has teeth


# --- the explorer's hand-checkable choices (issue 22) -------------------------------------------------
@pytest.mark.parametrize("start", range(7))
def test_info_gain_goes_to_the_unknown_end_of_a_corridor(start):
    """A blocking corridor of 8 cells known to be free (prior 0.999) but for its right end (0.5):
    from every known cell the only thing left to learn lies to the right, and every planner seed
    presses right."""
    prior = np.tile([0.999, 0.001], (8, 1))
    prior[7] = [0.5, 0.5]
    model = om.corridor(8, 2, blocking=1, label_prior=prior, start=start)
    for seed in range(3):
        est = make_estimator("rbpf", model, n_particles=200, seed=seed)
        belief = est.step(None, 0)
        planner = make_planner("info_gain", model, seed=seed)
        planner.bind(est)
        assert model.action_names[planner.choose(belief)] == "right", (start, seed, planner.last_plan.names)
        assert planner.last_plan.targets.max() == 7  # the one frontier target: the unknown end


def test_info_gain_leaves_a_room_by_its_only_door():
    """The room of test_frontier (rows 1-2, columns 6-8; its walls and its open door at row 3,
    column 7, known at 0.999), everything outside unknown: from every room cell, for every planner
    seed, the first press brings the robot closer to the door (rows plus columns)."""
    from test_frontier import ROOM

    _, true_map = om.door_world(ROOM, blocking=True, footprint="cross")
    cols = 10
    rows_of, cols_of = np.divmod(np.arange(len(true_map)), cols)
    room = (rows_of <= 3) & (cols_of >= 5)
    prior = np.full((len(true_map), 4), 0.25)
    prior[room] = 0.001 / 3
    prior[np.flatnonzero(room), true_map[room]] = 0.999
    for cell in np.flatnonzero(room & (true_map == 0)):
        model, _ = om.door_world(ROOM, blocking=True, footprint="cross", label_prior=prior, start=int(cell))
        run = om.simulate(model, true_map, [], seed=int(cell))
        for seed in range(3):
            est = make_estimator("rbpf", model, n_particles=200, seed=seed)
            belief = est.step(None, run.observations[0])
            planner = make_planner("info_gain", model, seed=seed)
            planner.bind(est)
            after = model.neighbors[cell, planner.choose(belief)]
            assert abs(rows_of[after] - 3) + abs(cols_of[after] - 7) < abs(rows_of[cell] - 3) + abs(cols_of[cell] - 7)


def brute_mutual_information(frequencies, sensor):
    """I(m; z) = sum over (k, z) of P(k) O[k, z] log(O[k, z] / P(z)), the KL form, summed with
    itertools.product over labels and observations."""
    frequencies, sensor = np.asarray(frequencies, dtype=float), np.asarray(sensor, dtype=float)
    k_count, z_count = sensor.shape
    p_z = [sum(frequencies[k] * sensor[k, z] for k in range(k_count)) for z in range(z_count)]
    return sum(frequencies[k] * sensor[k, z] * math.log(sensor[k, z] / p_z[z])
               for k, z in itertools.product(range(k_count), range(z_count)) if frequencies[k] * sensor[k, z] > 0)


def test_unit_information_is_the_mutual_information_of_a_cell_and_its_reading():
    from policies.information import unit_information
    rng = np.random.default_rng(4)
    for k in (2, 3, 4):
        sensor = rng.dirichlet(np.ones(k), size=k)
        frequencies = rng.dirichlet(np.ones(k))
        assert unit_information(sensor, frequencies) == pytest.approx(brute_mutual_information(frequencies, sensor),
                                                                      rel=1e-12)
        assert unit_information(sensor) == pytest.approx(brute_mutual_information(np.full(k, 1 / k), sensor), rel=1e-12)


FREQUENCIES = (0.6, 0.3, 0.1)


@pytest.mark.parametrize("information_unit", ["prior", "uniform"])
def test_plan_scores_in_the_unit_of_an_unread_cell_equal_brute_force(information_unit):
    """A localised robot (p_move 1, known start: the factored BK belief is the exact joint) with
    a given label prior: every candidate's gain equals the brute-force enumeration of the joint
    whose cells are drawn from that prior, with H(L) weighted by location_weight * I0 and steps
    costing step_cost * I0, I0 the mutual information of a cell at those frequencies (or at the
    uniform prior with information_unit="uniform"). Pressing into the next cell, never read,
    teaches exactly one unit with the prior's unit, and I0(prior) / I0(uniform) (0.79) units with
    the uniform unit."""
    model = om.corridor(3, 3, p_obs=0.8, p_move=1.0)
    oracle = BruteForce.of(om.corridor(3, 3, p_obs=0.8, p_move=1.0, label_prior=FREQUENCIES))
    est = make_estimator("bk", model, label_prior=list(FREQUENCIES))
    est.step(None, 0)
    planner = InfoGainExplorer(model, seed=0, hypotheses=None, press_lengths=(1, 2), location_weight=1.5,
                               step_cost=0.3, targets=0, information_unit=information_unit)
    planner.bind(est)
    plan = planner.plan(est.belief)
    i0 = brute_mutual_information(FREQUENCIES if information_unit == "prior" else np.full(3, 1 / 3),
                                  np.asarray(model.sensor))
    assert plan.unit == pytest.approx(i0, rel=1e-12)
    joint = brute_joint(oracle, [], [0])
    for c, sequence in enumerate(plan.sequences):
        want = brute_expected_uncertainty(oracle, joint, list(sequence[:2]), 1.5 * i0)
        np.testing.assert_allclose(plan.gain[c], want[0] - want[[1, 2]], rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(plan.utility[c], plan.gain[c] - 0.3 * i0 * np.array([1, 2]), rtol=1e-12)
    right = plan.names.index("press right")
    read_one = plan.gain[right, 0] / i0  # cell 1, never read, at the prior
    prior_i0 = brute_mutual_information(FREQUENCIES, np.asarray(model.sensor))
    assert read_one == pytest.approx(1.0 if information_unit == "prior" else prior_i0 / i0, rel=1e-10)


def test_the_unit_follows_the_learned_frequencies_and_is_the_uniform_one_with_a_fixed_prior():
    """With a learned prior (a generated building's default) the plan's unit is the mutual
    information at the RBPF's current label frequencies and the frontier's scale their entropy;
    with the model's own uniform table (the paper's world) or information_unit="uniform", the unit
    of a uniformly unknown cell and the frontier's own log K."""
    model, true_map = om.building(10, 10, seed=1)
    run = om.simulate(model, true_map, np.random.default_rng(0).integers(model.n_actions, size=40), seed=0)
    for unit in ("prior", "uniform"):
        est = make_estimator("rbpf", model, n_particles=50, seed=0)
        for t, z in enumerate(run.observations):
            est.step(None if t == 0 else int(run.actions[t - 1]), z)
        assert not np.allclose(est.label_frequencies, 1 / model.n_labels)
        planner = InfoGainExplorer(model, seed=0, hypotheses=2, information_unit=unit)
        planner.bind(est)
        plan = planner.plan(est.belief)
        frequencies = est.label_frequencies if unit == "prior" else np.full(model.n_labels, 1 / model.n_labels)
        assert plan.unit == pytest.approx(brute_mutual_information(frequencies, np.asarray(model.sensor)), rel=1e-12)
        np.testing.assert_allclose(plan.utility, plan.gain - planner.step_cost * plan.unit * plan.lengths[None],
                                   rtol=1e-12)
        if unit == "prior":  # the frontier's unit of uncertainty: an unread cell's entropy
            assert planner.unread_entropy() == pytest.approx(entropy(est.label_frequencies), rel=1e-12)
        else:
            assert planner.unread_entropy() is None
    paper, _ = om.door_world(p_move=0.8)
    planner = InfoGainExplorer(paper, seed=0)
    planner.bind(make_estimator("rbpf", paper, n_particles=20, seed=0))
    assert planner.unit() == pytest.approx(brute_mutual_information(np.full(4, 0.25), np.asarray(paper.sensor)),
                                           rel=1e-12)
    assert planner.unread_entropy() is None


def test_a_bad_information_unit_is_refused():
    model, _ = om.door_world(p_move=0.8)
    for bad in ("learned", None, 1):
        with pytest.raises(InvalidOptionError, match="information_unit"):
            InfoGainExplorer(model, information_unit=bad)
