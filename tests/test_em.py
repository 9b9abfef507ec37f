"""Online and offline EM against independent references: hmmlearn (one Baum-Welch iteration),
dense-matrix forward-backward and online EM written here from DESIGN.md section 3 (motion
rebuilt by ``oracles.grid_motion``), closed-form counts when the location is known, and the
scripted corridor of DESIGN.md section 5."""

import itertools
import warnings

import numpy as np
import pytest

import onlinemap as om
from onlinemap import metrics
from onlinemap.estimators.offline_em import baum_welch
from onlinemap.hmm import forward_backward, temper
from estimator_cases import assert_state_unchanged, beliefs, random_run, snapshot
from oracles import grid_motion


# --- dense references ----------------------------------------------------------------------
def dense_forward_backward(motion, prior, actions, observations, emission):
    """Textbook scaled forward-backward with dense (A, N, N) transitions: (filtered, posterior, log lik)."""
    filtered, norms = [], []
    for t, z in enumerate(observations):
        p = prior if t == 0 else filtered[-1] @ motion[actions[t - 1]]
        p = p * emission[:, z]
        norms.append(p.sum())
        filtered.append(p / p.sum())
    beta = np.ones(len(prior))
    posterior = [None] * len(observations)
    for t in range(len(observations) - 1, -1, -1):
        post = filtered[t] * beta
        posterior[t] = post / post.sum()
        if t > 0:
            beta = motion[actions[t - 1]] @ (emission[:, observations[t]] * beta) / norms[t]
    return np.array(filtered), np.array(posterior), float(np.log(norms).sum())


def dense_counts(posterior, observations, n_labels):
    counts = np.zeros((posterior.shape[1], n_labels))
    for t, z in enumerate(observations):
        counts[:, z] += posterior[t]
    return counts


def reference_online_em(model, actions, observations, window, decay, pseudo_count):
    """DESIGN.md section 3's online EM, step by step with dense matrices: per step (filtered L_t, B_t)."""
    motion = grid_motion(model.rows, model.cols, model.p_move)
    start = np.eye(model.n_cells)[model.start]
    emission = np.array(model.label_prior) @ np.array(model.sensor)
    stats = np.zeros_like(emission)
    filtered_history, out = [], []
    for t in range(len(observations)):
        s = 0 if window == "max" else max(0, t - window + 1)
        prior = start if s == 0 else filtered_history[s - 1] @ motion[actions[s - 1]]
        filtered, posterior, _ = dense_forward_backward(motion, prior, actions[s:t], observations[s:t + 1], emission)
        stats = decay * stats + dense_counts(posterior, observations[s:t + 1], model.n_labels)
        emission = (stats + pseudo_count) / (stats + pseudo_count).sum(axis=1, keepdims=True)
        filtered_history.append(filtered[-1])
        out.append((filtered[-1], emission))
    return out


def random_emission(n, k, seed):
    return np.random.default_rng(seed).dirichlet(np.ones(k), size=n)


def feed(est, run):
    return list(beliefs(est, run))


# --- the shared HMM ------------------------------------------------------------------------
@pytest.mark.parametrize("rows,cols,k", [(1, 5, 2), (2, 3, 3), (3, 3, 2)])
def test_sparse_forward_backward_equals_dense(rows, cols, k):
    model = om.grid_model(rows, cols, k, p_move=0.7, start=1)
    run = random_run(model, 12, seed=rows * 10 + cols)
    emission = random_emission(model.n_cells, k, seed=3)
    prior = np.random.default_rng(4).dirichlet(np.ones(model.n_cells))
    fit = forward_backward(model, prior, run.actions, run.observations, emission)
    filtered, posterior, log_lik = dense_forward_backward(grid_motion(rows, cols, 0.7), prior, run.actions,
                                                          run.observations, emission)
    np.testing.assert_allclose(fit.filtered, filtered, atol=1e-12)
    np.testing.assert_allclose(fit.posterior, posterior, atol=1e-12)
    assert fit.log_likelihood == pytest.approx(log_lik, abs=1e-10)


def test_one_baum_welch_iteration_equals_hmmlearn():
    from hmmlearn.hmm import CategoricalHMM

    model = om.corridor(5, 3, p_obs=0.8, p_move=0.7)
    actions = np.ones(15, dtype=np.int64)  # one action only: hmmlearn has no action-dependent transitions
    observations = np.random.default_rng(0).integers(0, 3, size=16)
    emission = random_emission(5, 3, seed=1)
    hmm = CategoricalHMM(n_components=5, n_features=3, params="e", init_params="", n_iter=1)
    hmm.startprob_ = np.eye(5)[0]
    hmm.transmat_ = grid_motion(1, 5, 0.7)[1]
    hmm.emissionprob_ = emission.copy()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        hmm.fit(observations.reshape(-1, 1))
    ours = baum_welch(model, actions, observations, n_iter=1, pseudo_count=0.0, initial=emission)
    np.testing.assert_allclose(ours.observation_matrix, hmm.emissionprob_, atol=1e-8, rtol=0)
    assert ours.log_likelihood == pytest.approx(hmm.score(observations.reshape(-1, 1)), abs=1e-8)
    np.testing.assert_allclose(ours.location, hmm.predict_proba(observations.reshape(-1, 1)), atol=1e-8)


def test_map_read_off_inverts_the_binary_sensor_channel():
    model = om.corridor(4, p_obs=0.9, p_move=1.0)
    est = om.make_estimator("online_em", model, pseudo_count=0.5)
    belief = feed(est, om.simulate(model, [0, 1, 1, 0], [1, 1, 1, 0, 0], seed=0))[-1]
    b1 = belief.observation_matrix[:, 1]
    expected = np.clip((b1 - 0.1) / 0.8, 0, 1)  # B = m O  =>  P(m = 1) = (B[:, 1] - 0.1) / (0.9 - 0.1)
    np.testing.assert_allclose(belief.map[:, 1], expected, atol=1e-12)
    np.testing.assert_allclose(belief.map.sum(axis=1), 1.0)


# --- online EM -----------------------------------------------------------------------------
@pytest.mark.parametrize("window", [1, 3, "max"])
@pytest.mark.parametrize("decay", [0.7, 1.0])
@pytest.mark.parametrize("pseudo_count", [0.05, 1.0])
def test_online_em_with_known_location_is_decayed_counting(window, decay, pseudo_count):
    model = om.corridor(6, p_obs=0.9, p_move=1.0)
    rng = np.random.default_rng(7)
    actions = rng.integers(0, 2, size=24)
    observations = rng.integers(0, 2, size=25)
    path = [0]
    for a in actions:
        path.append(min(max(path[-1] + (1 if a == 1 else -1), 0), 5))
    est = om.make_estimator("online_em", model, window=window, decay=decay, pseudo_count=pseudo_count)
    for t in range(25):
        belief = est.step(None if t == 0 else actions[t - 1], observations[t])
        counts = np.zeros((6, 2))  # S_t = sum_u decay^(t-u) sum_{tau in window(u)} [l_tau = i, z_tau = k]
        for u in range(t + 1):
            first = 0 if window == "max" else max(0, u - window + 1)
            for tau in range(first, u + 1):
                counts[path[tau], observations[tau]] += decay ** (t - u)
        expected = (counts + pseudo_count) / (counts + pseudo_count).sum(axis=1, keepdims=True)
        np.testing.assert_allclose(belief.observation_matrix, expected, atol=1e-12, rtol=0)
        np.testing.assert_allclose(belief.location, np.eye(6)[path[t]], atol=1e-15)


@pytest.mark.parametrize("window,decay", [(1, 1.0), (2, 0.8), (4, 0.95), ("max", 0.9)])
def test_online_em_equals_dense_reference_on_a_grid(window, decay):
    model = om.grid_model(2, 3, 2, p_obs=0.85, p_move=0.7)
    run = random_run(model, 14, seed=5)
    est = om.make_estimator("online_em", model, window=window, decay=decay, pseudo_count=0.2)
    reference = reference_online_em(model, run.actions, run.observations, window, decay, 0.2)
    for belief, (filtered, emission) in zip(feed(est, run), reference):
        np.testing.assert_allclose(belief.location, filtered, atol=1e-12)
        np.testing.assert_allclose(belief.observation_matrix, emission, atol=1e-12)


def test_online_em_log_evidence_is_the_sum_of_one_step_predictions():
    model = om.corridor(5, p_move=0.8)
    run = random_run(model, 10, seed=2)
    est = om.make_estimator("online_em", model, window="max")
    beliefs = feed(est, run)
    motion = grid_motion(1, 5, 0.8)
    total = 0.0
    for t, z in enumerate(run.observations):  # log P(z_t | z_0..t-1) under B_{t-1}
        emission = (model.label_prior @ model.sensor) if t == 0 else beliefs[t - 1].observation_matrix
        _, _, before = dense_forward_backward(motion, np.eye(5)[0], run.actions[:t - 1], run.observations[:t],
                                              emission) if t else (None, None, 0.0)
        _, _, upto = dense_forward_backward(motion, np.eye(5)[0], run.actions[:t], run.observations[:t + 1], emission)
        total += upto - before
        assert beliefs[t].log_evidence == pytest.approx(total, abs=1e-10)


# --- offline EM ----------------------------------------------------------------------------
def test_offline_em_step_refits_on_the_prefix_and_fit_smooths():
    model = om.corridor(5, p_move=0.8)
    run = random_run(model, 9, seed=3)
    est = om.make_estimator("offline_em", model, pseudo_count=0.3)
    beliefs = feed(est, run)
    for t in (0, 4, 8):
        prefix = est.fit(run.actions[:t], run.observations[:t + 1])
        np.testing.assert_array_equal(beliefs[t].observation_matrix, prefix.observation_matrix)
        np.testing.assert_array_equal(beliefs[t].location, prefix.location[-1])
        assert beliefs[t].log_evidence == prefix.log_likelihood
    whole = est.fit(run.actions, run.observations)
    assert whole.converged
    _, posterior, log_lik = dense_forward_backward(grid_motion(1, 5, 0.8), np.eye(5)[0], run.actions,
                                                   run.observations, whole.observation_matrix)
    np.testing.assert_allclose(whole.location, posterior, atol=1e-12)
    assert whole.log_likelihood == pytest.approx(log_lik, abs=1e-10)


def test_offline_em_step_warns_once_that_it_refits_and_points_to_fit():
    """Issue 24 item 18: offline_em through step re-fits on all data at every step (O(T^2) over
    a run, 17.7 s for 200 door-world steps) without a word. Its first step warns, naming fit;
    evaluations that time every estimator step by step on purpose do not."""
    from onlinemap.evaluate import timed_trajectory

    model = om.corridor(5)
    run = random_run(model, 6, seed=1)
    with pytest.warns(om.PerformanceWarning) as caught:
        feed(om.make_estimator("offline_em", model), run)
    assert len(caught) == 1  # once, at the first step (pytest.warns records every repeat)
    message = str(caught[0].message)
    assert "re-fits" in message and "every step" in message and ".fit(actions, observations)" in message
    assert caught[0].filename.endswith("estimator_cases.py")  # attributed to the caller of step
    with warnings.catch_warnings():
        warnings.simplefilter("error", om.PerformanceWarning)
        timed_trajectory("offline_em", model, {}, run)
        feed(om.make_estimator("online_em", model), run)


@pytest.mark.parametrize("pseudo_count", [0.0, 0.5])
@pytest.mark.parametrize("seed", [0, 1])
def test_plain_em_objective_is_right_and_never_decreases(pseudo_count, seed):
    model = om.grid_model(2, 3, 3, p_obs=0.8, p_move=0.7)
    run = random_run(model, 25, seed)
    initial = random_emission(6, 3, seed)
    fit = baum_welch(model, run.actions, run.observations, n_iter=30, tol=0, pseudo_count=pseudo_count,
                     initial=initial)
    motion = grid_motion(2, 3, 0.7)
    for j in (0, 1, 5, 29):  # objective of iteration j = log lik + c sum log B of B_j (B_j = after j M-steps)
        b_j = initial if j == 0 else baum_welch(model, run.actions, run.observations, n_iter=j, tol=0,
                                                pseudo_count=pseudo_count, initial=initial).observation_matrix
        _, _, log_lik = dense_forward_backward(motion, np.eye(6)[0], run.actions, run.observations, b_j)
        prior = pseudo_count * np.log(b_j).sum() if pseudo_count else 0.0
        assert fit.objectives[j] == pytest.approx(log_lik + prior, abs=1e-9)
    assert len(fit.objectives) == 30
    assert np.all(np.diff(fit.objectives) >= -1e-9)
    assert fit.objectives[-1] > fit.objectives[0] + 1.0


def test_annealing_at_tau_one_is_plain_em():
    model = om.corridor(6, p_move=0.8)
    run = random_run(model, 20, seed=4)
    plain = baum_welch(model, run.actions, run.observations, n_iter=40)
    flat = baum_welch(model, run.actions, run.observations, n_iter=40, anneal=(1.0, 1.0, 1.0))
    np.testing.assert_array_equal(plain.observation_matrix, flat.observation_matrix)
    np.testing.assert_array_equal(plain.objectives, flat.objectives)


def test_annealing_schedule_and_tempering():
    p = np.array([[0.5, 0.3, 0.2], [0.1, 0.1, 0.8]])
    np.testing.assert_allclose(temper(p, 0.5), p**2 / (p**2).sum(axis=1, keepdims=True))
    np.testing.assert_allclose(temper(p, 1e-3), [[1, 0, 0], [0, 0, 1]], atol=1e-12)
    assert temper(p, 1.0) is p
    schedule = om.estimators.offline_em.check_anneal((1.0, 0.5, 0.1))
    assert [schedule.tau(j) for j in range(5)] == [1.0, 0.5, 0.25, 0.125, 0.1]
    model = om.corridor(6, p_move=0.8)
    run = random_run(model, 20, seed=4)
    annealed = baum_welch(model, run.actions, run.observations, n_iter=200, anneal=(1.0, 0.7, 0.2))
    plain = baum_welch(model, run.actions, run.observations, n_iter=200)
    assert annealed.converged and plain.converged
    assert not np.allclose(annealed.observation_matrix, plain.observation_matrix)
    # sharper posteriors give a more decided map (lower mean label entropy)
    assert metrics.map_entropy(annealed.map) < metrics.map_entropy(plain.map)


# --- the scripted corridor (DESIGN.md section 5, claim 1) ----------------------------------
RUN = om.scenarios.murphy_corridor()
VISITED = np.unique(RUN.locations)
WAY_BACK = np.arange(8, RUN.n_steps)  # steps after the turn at the right end
WINDOWS_DECAYS = list(itertools.product([1, 2, 4, 8, "max"], [0.8, 0.9, 0.95, 1.0]))  # reproduce corridor's 20


def corridor_outcome(name, **options):
    trajectory = om.run_estimator(om.make_estimator(name, RUN.model, **options), RUN.actions, RUN.observations)
    p_true = trajectory.location[np.arange(RUN.n_steps), RUN.locations]
    return p_true, metrics.wrong_cells(trajectory.map[-1], RUN.final_map, VISITED)


# The guide's numbers for this run (Estimators page), at the precision it states them (the run is deterministic).
def test_exact_bayes_learns_the_corridor_and_knows_where_it_is():
    p_true, wrong = corridor_outcome("exact")
    assert f"{p_true[-1]:.2f}" == "0.92"  # the guide: "ends at P(true location) 0.92"
    assert wrong == 0


@pytest.mark.parametrize("window,decay", WINDOWS_DECAYS)
def test_online_em_locks_onto_a_wrong_map_and_gets_lost(window, decay):
    """The guide: every pair ends with 3 to 6 visited cells wrong, P(true location) on the way back
    falling to 0.0002-0.02 (one significant digit: [0.00015, 0.025))."""
    p_true, wrong = corridor_outcome("online_em", window=window, decay=decay)
    assert 3 <= wrong <= 6
    assert 0.00015 <= p_true[WAY_BACK].min() < 0.025


def test_online_em_corridor_ranges_are_the_readmes():
    """The ends of the guide's ranges over the 20 pairs are reached: "3 to 6" wrong visited cells,
    and "0.0002-0.02" for the lowest P(true location) on the way back."""
    outcomes = [corridor_outcome("online_em", window=window, decay=decay) for window, decay in WINDOWS_DECAYS]
    wrong = [w for _, w in outcomes]
    lowest = [p_true[WAY_BACK].min() for p_true, _ in outcomes]
    assert (min(wrong), max(wrong)) == (3, 6)
    assert (f"{min(lowest):.1g}", f"{max(lowest):.1g}") == ("0.0002", "0.02")


def test_offline_em_gets_every_visited_cell_right():
    p_true, wrong = corridor_outcome("offline_em")
    assert wrong == 0
    assert f"{p_true[-1]:.2f}" == "0.99"  # the guide: "(P 0.99)"


# --- bad input -----------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["online_em", "offline_em"])
@pytest.mark.parametrize("action,observation,error", [
    (2, 0, om.InvalidActionError), (None, 0, om.InvalidActionError), ("up", 0, om.InvalidActionError),
    (float("nan"), 0, om.InvalidActionError), (1, 2, om.InvalidObservationError),
    (1, float("nan"), om.InvalidObservationError), (1, "door", om.InvalidObservationError),
])
def test_bad_step_raises_and_keeps_state(name, action, observation, error):
    est = om.make_estimator(name, om.corridor(5))
    est.step(None, 0)
    est.step(1, 1)
    before = snapshot(est)
    with pytest.raises(error):
        est.step(action, observation)
    assert_state_unchanged(est, before)
    assert est.step(1, 0).t == 2


@pytest.mark.parametrize("window,decay", WINDOWS_DECAYS)
def test_online_em_without_pseudo_counts_refuses_an_impossible_observation_and_keeps_state(window, decay):
    """The guide: for every window and decay, the observation at step 11 is impossible."""
    est = om.make_estimator("online_em", RUN.model, window=window, decay=decay, pseudo_count=0.0)
    list(beliefs(est, RUN, stop=11))  # B becomes certain of a wrong map; z_11 has probability zero under it
    before = snapshot(est)
    with pytest.raises(om.ImpossibleObservationError, match="probability zero"):
        est.step(RUN.actions[10], RUN.observations[11])
    assert_state_unchanged(est, before)
    assert est.step(RUN.actions[10], 1 - RUN.observations[11]).t == 11


@pytest.mark.parametrize("name,options", [
    ("online_em", {"window": 0}), ("online_em", {"window": "all"}), ("online_em", {"window": 2.5}),
    ("online_em", {"decay": 0.0}), ("online_em", {"decay": 1.5}), ("online_em", {"pseudo_count": -1}),
    ("online_em", {"pseudo_count": float("nan")}), ("offline_em", {"n_iter": 0}),
    ("offline_em", {"anneal": (0.5, 0.9, 1.0)}), ("offline_em", {"anneal": (1.0, 1.5, 0.1)}),
    ("offline_em", {"anneal": "fast"}),
])
def test_bad_options_are_refused(name, options):
    with pytest.raises(om.ModelError):
        om.make_estimator(name, om.corridor(4), **options)


@pytest.mark.parametrize("name", ["online_em", "offline_em"])
def test_observation_impossible_under_the_prior_is_refused_with_state_kept(name):
    model = om.corridor(4, p_obs=1.0, label_prior=[1.0, 0.0])  # every cell is 0 and the sensor never errs
    est = om.make_estimator(name, model)
    before = snapshot(est)
    with pytest.raises(om.ImpossibleObservationError, match="probability zero"):
        est.step(None, 1)
    assert_state_unchanged(est, before)
    assert est.step(None, 0).t == 0
