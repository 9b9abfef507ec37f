"""Rao-Blackwellised particle filter against exact Bayes (itself tested against brute force):
equal when the location is known (p_move = 1), within Monte-Carlo tolerance with many
particles, lazy map dynamics equal to eager, optimal proposal with lower weight variance,
and bad or impossible input leaving everything (random generator included) unchanged."""

import logging

import numpy as np
import pytest
from scipy import stats

import onlinemap as om
from estimator_cases import (RBPF_THREADS, assert_state_unchanged, beliefs, exact_trajectory, random_run, small_chunks,
                             snapshot)

STATIC = dict(p_obs=0.85, p_move=0.7)
DYNAMIC_3X3 = dict(p_obs=0.8, p_move=0.7, change=[[0.9, 0.05, 0.05], [0.1, 0.8, 0.1], [0.2, 0.2, 0.6]])


def rbpf_steps(run, **options):
    """Yield the RBPF's belief after each step of ``run``."""
    return beliefs(om.make_estimator("rbpf", run.model, **options), run)


# Monte-Carlo tolerances of the 20,000-particle tests. A marginal p is a weighted mean of particle
# values in [0, 1], so its standard error is at most SE = sqrt(p (1 - p) / ESS_t); resampling adds
# variance inherited from earlier steps, so the error's standard deviation is r SE. Measured over 100
# filter seeds (100-199) on the tests' runs, r is at most 1.24 with the optimal proposal, 1.72 with
# the transition one (residual resampling) and 1.41 with Fearnhead-Clifford (max over steps and
# entries, static or dynamic; the median is 0.4-0.7: particles carry marginals, not 0/1 values).
# A test compares K = T (N + N K) entries; for a false-failure rate of 1e-3 (Bonferroni) each is held
# to z = Phi^-1(1 - 1e-3 / (2 K)) standard deviations (4.6 for 15 steps, 4.8 for 30), plus 1 / ESS_t
# for entries within one particle's weight of 0 or 1. The log evidence's error, in units of
# sqrt(T / ESS_T), had standard deviation at most 0.15 / 0.35 / 0.10 over the same seeds; it is held to
# z = 3.29 (two-sided 1e-3) of them.
FALSE_FAILURE = 1e-3
INFLATION = {"optimal": 1.25, "transition": 1.75, "fearnhead_clifford": 1.45}
LOG_EVIDENCE_SD = {"optimal": 0.15, "transition": 0.35, "fearnhead_clifford": 0.10}


def assert_within_monte_carlo_error(belief, exact, t, scheme):
    """The step-t belief of a many-particle RBPF (``scheme``: its proposal, or fearnhead_clifford)
    against ``exact`` (a Trajectory), with the tolerance derived above."""
    n_steps, n_cells, n_labels = exact.map.shape
    z = stats.norm.isf(FALSE_FAILURE / (2 * n_steps * (n_cells + n_cells * n_labels)))
    ess = belief.effective_sample_size
    for estimate, truth in ((belief.location, exact.location[t]), (belief.map, exact.map[t])):
        tolerance = z * INFLATION[scheme] * np.sqrt(truth * (1 - truth) / ess) + 1 / ess
        assert np.all(np.abs(estimate - truth) <= tolerance), (t, np.abs(estimate - truth).max())
    if t == n_steps - 1:
        tolerance = stats.norm.isf(FALSE_FAILURE / 2) * LOG_EVIDENCE_SD[scheme] * np.sqrt(n_steps / ess)
        assert belief.log_evidence == pytest.approx(exact.log_evidence[-1], abs=tolerance)


KNOWN_LOCATION = [
    ("corridor static", lambda: om.corridor(6, 2, p_obs=0.8, p_move=1.0)),
    ("corridor K=3 dynamic", lambda: om.corridor(5, 3, p_obs=0.8, p_move=1.0, p_change=0.1, start=2)),
    ("grid 2x3 dynamic", lambda: om.grid_model(2, 3, 2, p_obs=0.75, p_move=1.0, change=[[0.9, 0.1], [0.3, 0.7]],
                                               label_prior=[0.4, 0.6])),
]


@pytest.mark.parametrize("name,make", KNOWN_LOCATION, ids=[m[0] for m in KNOWN_LOCATION])
@pytest.mark.parametrize("n_particles", [1, 7])
@pytest.mark.parametrize("proposal,resampling,threshold", [("optimal", "residual", 0.5),
                                                           ("transition", "multinomial", 1.0)])
def test_known_location_equals_exact(name, make, n_particles, proposal, resampling, threshold):
    """With no slips every particle follows the true path and holds the exact map marginals."""
    model = make()
    run = random_run(model, 12, seed=3)
    exact = exact_trajectory(run)
    beliefs = rbpf_steps(run, n_particles=n_particles, proposal=proposal, resampling=resampling,
                         resample_threshold=threshold, seed=0)
    for t, belief in enumerate(beliefs):
        np.testing.assert_allclose(belief.location, exact.location[t], atol=1e-12, rtol=0)
        np.testing.assert_allclose(belief.map, exact.map[t], atol=1e-12, rtol=0)
        assert belief.log_evidence == pytest.approx(exact.log_evidence[t], abs=1e-12)
        assert belief.effective_sample_size == pytest.approx(n_particles)


@pytest.mark.parametrize("p_change", [0.0, 0.05], ids=["static", "dynamic"])
@pytest.mark.parametrize("proposal", ["optimal", "transition"])
def test_many_particles_match_exact_within_monte_carlo_tolerance(p_change, proposal):
    """20000 particles on a 6-cell corridor with slips: every marginal and the log evidence within
    the Monte-Carlo tolerance derived above (assert_within_monte_carlo_error)."""
    model = om.corridor(6, 2, p_change=p_change, **STATIC)
    run = random_run(model, 15, seed=4)
    exact = exact_trajectory(run)
    for t, belief in enumerate(rbpf_steps(run, n_particles=20_000, proposal=proposal, resampling="residual", seed=1)):
        assert 0.2 * 20_000 < belief.effective_sample_size <= 20_000
        assert_within_monte_carlo_error(belief, exact, t, proposal)


def test_few_particles_are_close_and_error_shrinks_with_particles():
    """Mean map TV to exact over 4 filter seeds: a sampling filter's error falls as 1 / sqrt(P), so
    100 times the particles divide it by 10 (the default, Fearnhead-Clifford, does far better: 0.016
    with 10 particles, 4e-6 with 1000, means over filter seeds 100-139). The 4-seed mean at 10
    particles has standard error 0.0026 (per-seed sd 0.0052) and stays above 0.0105 in 999 draws of
    1000, so the check fails a correct filter by chance with probability below 1e-3."""
    run = om.scenarios.murphy_corridor()
    exact = exact_trajectory(run)

    def error(n_particles):
        errors = []
        for seed in range(4):
            est = om.make_estimator("rbpf", run.model, n_particles=n_particles, seed=seed)
            trajectory = om.run_estimator(est, run.actions, run.observations)
            errors.append(om.metrics.total_variation(trajectory.map, exact.map).mean())
        return np.mean(errors)

    small, large = error(10), error(1000)
    assert large < small / 10


@pytest.mark.parametrize("resampling,threshold,block", [("residual", 0.5, None), ("systematic", 1.0, 2)])
def test_lazy_dynamics_equals_eager(resampling, threshold, block):
    """C applied lazily (C^dt when a cell is read) equals C applied to every cell every step."""
    model = om.grid_model(3, 3, 3, **DYNAMIC_3X3)
    run = random_run(model, 40, seed=5)
    options = dict(n_particles=300, resampling=resampling, resample_threshold=threshold, seed=2, block_cells=block)
    lazy = rbpf_steps(run, lazy_dynamics=True, **options)
    eager = rbpf_steps(run, lazy_dynamics=False, **options)
    for a, b in zip(lazy, eager):
        np.testing.assert_allclose(a.location, b.location, atol=1e-12, rtol=0)
        np.testing.assert_allclose(a.map, b.map, atol=1e-12, rtol=0)
        assert a.log_evidence == pytest.approx(b.log_evidence, abs=1e-12)


@pytest.mark.parametrize("resampling,threshold", [("residual", 0.5), ("residual", 1.0), ("fearnhead_clifford", 0.5)])
def test_block_size_does_not_change_results(resampling, threshold):
    """Maps are stored as shared copy-on-write blocks of B cells; B (dividing N or not, 1 or
    all of N) changes where numbers live (and the order of rounding), not the values."""
    model = om.grid_model(3, 3, 3, **DYNAMIC_3X3)
    run = random_run(model, 40, seed=10)
    options = dict(n_particles=60, resampling=resampling, resample_threshold=threshold, seed=4)
    reference = list(rbpf_steps(run, block_cells=9, **options))
    for block in (1, 2, 4, None):
        for a, b in zip(rbpf_steps(run, block_cells=block, **options), reference):
            np.testing.assert_allclose(a.location, b.location, atol=1e-14, rtol=0)
            np.testing.assert_allclose(a.map, b.map, atol=1e-14, rtol=0)


def test_refresh_keeps_ages_bounded_and_values_unchanged(monkeypatch):
    """Lazy dynamics needs C^age for the age of every stamp; rows are refreshed in turn (and
    old copies on copy) so ages stay <= 2 h + 1 and the table of powers stays fixed however
    long the run. Shown with h = 4 over 300 steps: ages bounded, beliefs equal to eager C.
    (Systematic resampling: refreshing changes rounding, and the binomial draws inside numpy's
    multinomial, which residual resampling uses, can turn a 1e-16 change of exactly tied
    weights into a different draw; the filters would then differ by chance, not by error.)"""
    import onlinemap.estimators.block_pool as block_pool

    monkeypatch.setattr(block_pool, "REFRESH_STEPS", 4)
    model = om.grid_model(1, 12, 3, p_obs=0.8, p_move=0.8, change=DYNAMIC_3X3["change"])
    run = random_run(model, 300, seed=12)
    options = dict(n_particles=30, resample_threshold=1.0, resampling="systematic", block_cells=3, seed=6)
    lazy = om.make_estimator("rbpf", model, **options)
    eager = om.make_estimator("rbpf", model, lazy_dynamics=False, **options)
    powers = lazy._blocks.powers.shape
    for t in range(run.n_steps):
        args = (None if t == 0 else run.actions[t - 1], run.observations[t])
        a, b = lazy.step(*args), eager.step(*args)
        live = lazy._blocks.refcount > 0
        assert t - lazy._blocks.stamps[live].min() <= 2 * 4 + 1
        np.testing.assert_allclose(a.map, b.map, atol=1e-12, rtol=0)
        np.testing.assert_allclose(a.location, b.location, atol=1e-12, rtol=0)
    assert lazy._blocks.powers.shape == powers == (17, 3, 3)


def test_optimal_proposal_has_lower_weight_variance():
    """Resampling every step, the weights after a step are the incremental weights of one
    step; the optimal proposal minimises their variance given the ancestors. Over 10 seeds
    the optimal proposal's mean squared coefficient of variation (P / ESS - 1) must be lower
    in every seed. (Over seeds 100-139 the ratio optimal / transition was 0.41, sd 0.018, at
    most 0.45: a seed where it reaches 1 is 33 standard deviations away.)"""
    model = om.corridor(10, 2, p_obs=0.9, p_move=0.7)
    run = random_run(model, 40, seed=6)
    for seed in range(10):
        cv2 = {}
        for proposal in ("optimal", "transition"):
            beliefs = list(rbpf_steps(run, n_particles=200, proposal=proposal, resampling="residual",
                                      resample_threshold=1.0, seed=seed))
            cv2[proposal] = np.mean([200 / b.effective_sample_size - 1 for b in beliefs[1:]])
        assert cv2["optimal"] < cv2["transition"], (seed, cv2)


def test_same_seed_same_result_and_generator_seed():
    run = random_run(om.corridor(8, p_change=0.02), 30, seed=7)
    a = list(rbpf_steps(run, n_particles=50, seed=11))
    b = list(rbpf_steps(run, n_particles=50, seed=np.random.default_rng(11)))
    c = list(rbpf_steps(run, n_particles=50, seed=12))
    np.testing.assert_array_equal(a[-1].map, b[-1].map)
    assert not np.array_equal(a[-1].map, c[-1].map)


@pytest.mark.parametrize("resampling", ["fearnhead_clifford", "residual"])
def test_the_genealogy_handed_out_is_the_callers(resampling):
    """update_with_ancestors returns a fresh array each step (a step works in buffers it reuses):
    later steps leave it as it was, and a caller writing into it changes nothing in the filter."""
    model, true_map = om.door_world()
    run = om.simulate(model, true_map, om.random_walk(model, 30, np.random.default_rng(4)), np.random.default_rng(4))
    est, scribbled = (om.make_estimator("rbpf", model, n_particles=16, seed=0, resampling=resampling) for _ in "ab")
    handed, kept = [], []
    for t, z in enumerate(run.observations):
        action = None if t == 0 else run.actions[t - 1]
        handed.append(est.update_with_ancestors(action, z))
        kept.append(handed[-1].copy())
        scribbled.update_with_ancestors(action, z)[:] = -1
    for ancestors, copy in zip(handed, kept):
        np.testing.assert_array_equal(ancestors, copy)
    assert any(np.array_equal(a, np.arange(16)) for a in kept[1:])  # steps that kept every slot's own
    assert any(not np.array_equal(a, np.arange(16)) for a in kept)  # and steps that did not
    np.testing.assert_array_equal(scribbled.particles, est.particles)
    np.testing.assert_array_equal(scribbled.weights, est.weights)


def test_a_filters_step_kit_goes_with_the_filter():
    """The step kit is kept beside the filter by ``id`` and dropped when the filter dies, so a later
    filter that reuses the id never finds another filter's kit (its buffers)."""
    import gc
    from onlinemap.estimators import rbpf
    est = om.make_estimator("rbpf", om.door_world()[0], n_particles=8, seed=0, resampling="residual")
    est.update(None, 0)
    key, kit = id(est), rbpf._KITS[id(est)]
    assert kit.n_particles == 8 and kit.proposal is not None
    del est
    gc.collect()
    assert key not in rbpf._KITS


def test_update_then_belief_equals_step_and_belief_is_cached():
    run = random_run(om.corridor(8, p_change=0.02), 10, seed=8)
    stepped = list(rbpf_steps(run, n_particles=40, seed=3))
    est = om.make_estimator("rbpf", run.model, n_particles=40, seed=3)
    assert est.belief is None
    for t in range(run.n_steps):
        est.update(None if t == 0 else run.actions[t - 1], run.observations[t])
    assert est.belief is est.belief and est.belief.t == run.n_steps - 1
    np.testing.assert_array_equal(est.belief.map, stepped[-1].map)
    np.testing.assert_allclose(np.exp(est._log_weights).sum(), 1.0)  # stored normalised
    assert 1.0 <= est.belief.effective_sample_size <= 40


@pytest.mark.parametrize("proposal", ["optimal", "transition"])
@pytest.mark.parametrize("p_change", [0.0, 0.1])
def test_impossible_observation_keeps_everything(proposal, p_change):
    """Every cell is label 0 for sure and the sensor is perfect: seeing 1 is impossible for
    every particle. The step resamples first (threshold 1.0) and draws motion uniforms; all of
    it must be undone, so the filter then continues exactly like one that never saw it."""
    model = om.corridor(4, 2, p_obs=1.0, p_move=0.6, p_change=0.0, label_prior=[1.0, 0.0])
    if p_change:
        model = om.grid_model(1, 4, 2, p_obs=1.0, p_move=0.6, change=[[1, 0], [p_change, 1 - p_change]],
                              label_prior=[1.0, 0.0])
    options = dict(n_particles=30, proposal=proposal, resampling="multinomial", resample_threshold=1.0, seed=5)
    est, twin = (om.make_estimator("rbpf", model, **options) for _ in range(2))
    for e in (est, twin):
        e.step(None, 0)
        e.step("right", 0)
    snap = snapshot(est)
    with pytest.raises(om.ImpossibleObservationError, match="every one of the 30 particles"):
        est.step("right", 1)
    assert_state_unchanged(est, snap)
    for action in ("right", "left", "right"):
        np.testing.assert_array_equal(est.step(action, 0).location, twin.step(action, 0).location)
    np.testing.assert_array_equal(est.particle_maps(), twin.particle_maps())


def test_a_sampling_step_whose_draws_all_miss_enumerates_the_successors(caplog):
    """A perfect sensor, one particle drawn by motion alone: after "right, saw 0" the particle at
    cell c (0 or 1) knows cell c holds 0, so of its successors c (stay) and c + 1 (move) only the
    move explains "right, saw 1". Where the draw stayed (the filter used to raise), the step
    enumerates both successors instead, as Fearnhead-Clifford does: the particle ends at c + 1,
    which holds 1, whatever was drawn; nothing is relocated (no recovery)."""
    model = om.corridor(4, 2, p_obs=1.0, p_move=0.5)
    missed = 0
    for seed in range(40):  # the draw stays with probability 1/2: P(no miss in 40) = 2^-40
        est = om.make_estimator("rbpf", model, n_particles=1, proposal="transition", resampling="multinomial",
                                seed=seed)
        est.step(None, 0)
        c = est.step("right", 0).most_likely_location
        caplog.clear()
        with caplog.at_level(logging.INFO, logger="onlinemap.estimators.rbpf"):
            belief = est.step("right", 1)
        missed += any("enumerates the particles' successors" in r.getMessage() for r in caplog.records)
        assert belief.location[c + 1] == 1.0 and belief.map[c + 1, 1] == 1.0
        assert not belief.recovered and est.recoveries == 0
    assert missed > 0


def test_subnormal_likelihood_gives_a_valid_belief():
    """Only a label seen with probability 1e-323 (subnormal) explains the last observation."""
    model = om.grid_model(1, 1, 3, p_move=0.0, sensor=[[1, 0, 0], [1, 0, 0], [1, 1e-323, 0]])
    est = om.make_estimator("rbpf", model, n_particles=5, seed=0)
    for z in (0, 0, 1):
        belief = est.step(None if est.t < 0 else 0, z)
    np.testing.assert_allclose(belief.map, [[0, 0, 1]], atol=1e-12)
    assert np.isfinite(belief.log_evidence) and belief.log_evidence < -740


def test_bad_input_keeps_everything():
    est = om.make_estimator("rbpf", om.corridor(5, p_change=0.05), n_particles=20, seed=0)
    est.step(None, 0)
    est.step(1, 1)
    snap = snapshot(est)
    for action, observation in [(2, 0), (None, 0), (1, 2), ("up", 0), (1, float("nan"))]:
        with pytest.raises((om.InvalidActionError, om.InvalidObservationError)):
            est.step(action, observation)
    assert_state_unchanged(est, snap)


@pytest.mark.parametrize("options,match", [
    (dict(n_particles=0), "n_particles"), (dict(n_particles=2.5), "n_particles"),
    (dict(proposal="prior"), "proposal"), (dict(resampling="stratify"), "resampling"),
    (dict(resample_threshold=1.5), "resample_threshold"), (dict(block_cells=0), "block_cells"),
    (dict(proposal="transition", resampling="fearnhead_clifford"), "enumerates"),
])
def test_bad_options_are_refused(options, match):
    with pytest.raises(om.ModelError, match=match):
        om.make_estimator("rbpf", om.corridor(4), **options)


def test_memory_guard():
    """1000 particles on the dynamic door world take about 0.9 MB to start (pool, table, powers of C, a
    step's buffers: tests/test_memory_guards.py measures the estimate); half a megabyte is refused."""
    model = om.door_world(p_door=0.01)[0]
    with pytest.raises(om.MemoryLimitError, match="max_bytes"):
        om.make_estimator("rbpf", model, n_particles=1000, max_bytes=5 * 10**5)


def test_door_world_beliefs_are_distributions():
    model, true_map = om.door_world(p_door=0.02)
    rng = np.random.default_rng(9)
    run = om.simulate(model, true_map, om.random_walk(model, 60, rng), rng)
    trajectory = om.run_estimator(om.make_estimator("rbpf", model, n_particles=200, seed=0),
                                  run.actions, run.observations)
    np.testing.assert_allclose(trajectory.location.sum(axis=1), 1, atol=1e-12)
    np.testing.assert_allclose(trajectory.map.sum(axis=2), 1, atol=1e-12)
    dead = om.run_estimator(om.make_estimator("dead_reckoning", model), run.actions, run.observations)
    assert om.metrics.map_error(trajectory.map[-1], run.final_map) < om.metrics.map_error(dead.map[-1], run.final_map)


# --- Fearnhead-Clifford: enumerate every successor, keep P by optimal resampling ---------------------
FC = dict(resampling="fearnhead_clifford")
FC_WORLDS = [
    ("corridor6 static", lambda: om.corridor(6, 2, **STATIC)),
    ("corridor6 dynamic", lambda: om.corridor(6, 2, p_change=0.05, **STATIC)),
    ("grid2x3 dynamic", lambda: om.grid_model(2, 3, 2, p_obs=0.8, p_move=0.7, change=[[0.9, 0.1], [0.3, 0.7]],
                                              label_prior=[0.4, 0.6])),
    ("corridor5 K=3 dynamic", lambda: om.corridor(5, 3, p_obs=0.8, p_move=0.6, p_change=0.1, start=2)),
]


@pytest.mark.parametrize("threads", RBPF_THREADS)
@pytest.mark.parametrize("name,make", FC_WORLDS, ids=[w[0] for w in FC_WORLDS])
def test_fearnhead_clifford_with_room_for_every_child_equals_exact(name, make, threads, monkeypatch):
    """9 steps (8 moves) have at most 2^8 = 256 trajectories: with 256 particles no child is
    dropped and the mixture over every trajectory is exact Bayes, to 1e-12 at every step; with
    the serial kernels and with the parallel ones (in chunks of 16 particles)."""
    small_chunks(monkeypatch)
    model = make()
    run = random_run(model, 9, seed=6)
    exact = exact_trajectory(run)
    est = om.make_estimator("rbpf", model, n_particles=256, seed=0, threads=threads, **FC)
    for t, belief in enumerate(beliefs(est, run)):
        np.testing.assert_allclose(belief.location, exact.location[t], atol=1e-12, rtol=0)
        np.testing.assert_allclose(belief.map, exact.map[t], atol=1e-12, rtol=0)
        assert belief.log_evidence == pytest.approx(exact.log_evidence[t], abs=1e-12)
        assert not est.resampled
    assert np.count_nonzero(est._weights) >= 16  # the run did branch: many live trajectories


@pytest.mark.parametrize("p_change", [0.0, 0.05], ids=["static", "dynamic"])
def test_fearnhead_clifford_many_particles_match_exact_within_monte_carlo_tolerance(p_change):
    """20000 particles, 30 steps with slips (up to 2^29 trajectories, so it drops children once past
    2^14 < 20000 < 2^15): within the Monte-Carlo tolerance derived above."""
    model = om.corridor(6, 2, p_change=p_change, **STATIC)
    run = random_run(model, 30, seed=4)
    exact = exact_trajectory(run)
    est = om.make_estimator("rbpf", model, n_particles=20_000, seed=1, **FC)
    dropped = False
    for t, belief in enumerate(beliefs(est, run)):
        dropped |= est.resampled
        assert_within_monte_carlo_error(belief, exact, t, "fearnhead_clifford")
    assert dropped and belief.effective_sample_size > 1000


def test_fearnhead_clifford_is_closer_to_exact_than_residual_resampling():
    """At equal particles (100) on random 8-cell corridor runs: mean TV to exact (location +
    mean cell) below 0.6 of the optimal proposal with residual resampling, the issue's target.
    Runs from the false-failure rate wanted (1e-3, z = 3.09): over 40 runs (seeds 100-139) the ratio
    of means is rho = 0.35 and a run's linearised ratio (FC - rho residual) / mean(residual) has sd
    0.107, so n = (3.09 x 0.107 / (0.6 - 0.35))^2 = 1.75; the per-run ratios are skewed (up to 0.68),
    and resampling the 40 runs puts P(ratio of means > 0.6) at 7e-3 for 2 runs and 8e-4 for 3: 3 runs."""
    model = om.corridor(8, p_change=0.02)
    tv = {"residual": [], "fearnhead_clifford": []}
    for seed in range(3):
        run = random_run(model, 60, seed=seed)
        exact = exact_trajectory(run)
        for scheme in tv:
            est = om.make_estimator("rbpf", model, n_particles=100, resampling=scheme, seed=seed)
            trajectory = om.run_estimator(est, run.actions, run.observations)
            tv[scheme].append(np.mean(om.metrics.total_variation(trajectory.location, exact.location)
                                      + om.metrics.total_variation(trajectory.map, exact.map).mean(axis=1)))
    assert np.mean(tv["fearnhead_clifford"]) < 0.6 * np.mean(tv["residual"]), tv


def test_fearnhead_clifford_checkpoint_resume_is_bit_identical(tmp_path):
    model = om.grid_model(3, 3, 3, **DYNAMIC_3X3)
    run = random_run(model, 40, seed=13)
    options = dict(n_particles=50, seed=2, **FC)
    straight = list(rbpf_steps(run, **options))
    est = om.make_estimator("rbpf", model, **options)
    list(beliefs(est, run, stop=17))
    om.save(est, tmp_path / "fc.npz")
    resumed = om.load(tmp_path / "fc.npz")
    for a, b in zip(beliefs(resumed, run, start=17), straight[17:]):
        np.testing.assert_array_equal(a.location, b.location)
        np.testing.assert_array_equal(a.map, b.map)
        assert a.log_evidence == b.log_evidence


def test_fearnhead_clifford_bad_or_impossible_input_keeps_everything():
    model = om.corridor(4, 2, p_obs=1.0, p_move=0.6, label_prior=[1.0, 0.0])
    est, twin = (om.make_estimator("rbpf", model, n_particles=4, seed=5, **FC) for _ in range(2))
    for e in (est, twin):
        for action, z in ((None, 0), ("right", 0), ("right", 0), ("right", 0)):
            e.step(action, z)
    assert est.resampled  # 8 trajectories after 3 moves, 4 slots: children were dropped
    snap = snapshot(est)
    with pytest.raises(om.ImpossibleObservationError, match="every one of the 4 particles"):
        est.step("right", 1)
    for action, observation in [(2, 0), (None, 0), (1, 2), ("up", 0)]:
        with pytest.raises((om.InvalidActionError, om.InvalidObservationError)):
            est.step(action, observation)
    assert_state_unchanged(est, snap)
    for action in ("left", "left", "right"):
        np.testing.assert_array_equal(est.step(action, 0).location, twin.step(action, 0).location)
    np.testing.assert_array_equal(est.particle_maps(), twin.particle_maps())


def test_default_resampling_is_fearnhead_clifford_for_the_optimal_proposal():
    model = om.corridor(6)
    assert om.make_estimator("rbpf", model).resampling == "fearnhead_clifford"
    assert om.make_estimator("rbpf", model, proposal="transition").resampling == "residual"
    assert om.make_estimator("rbpf", model, resampling="systematic").resampling == "systematic"


# --- honest defaults on display (issue 24 item 15) -----------------------------------------------
def test_the_rbpf_shows_the_scheme_it_runs_and_what_tells_its_health():
    """repr and effective_options name the resampling it runs (not None) and leave out the
    threshold Fearnhead-Clifford ignores; the belief reports the distinct particle locations (the
    health signal under FC, where one particle starts and the ESS is small while the filter is
    exact); ``particles`` and ``weights`` are read-only copies whose weighted histogram is the
    location belief."""
    model = om.door_world()[0]
    run = om.simulate(model, om.door_world()[1], steps=15, seed=3)
    fc = om.make_estimator("rbpf", model, n_particles=50, seed=0)
    sampled = om.make_estimator("rbpf", model, n_particles=50, proposal="transition", seed=0)
    assert fc.options["resampling"] is None  # what was given (checkpoints compare it)
    assert fc.effective_options["resampling"] == "fearnhead_clifford" and "resample_threshold" not in fc.effective_options
    assert "resampling='fearnhead_clifford'" in repr(fc) and "resample_threshold" not in repr(fc)
    assert sampled.effective_options["resampling"] == "residual" and "resample_threshold=0.5" in repr(sampled)
    for est in (fc, sampled):
        for t in range(run.n_steps):
            belief = est.step(None if t == 0 else int(run.actions[t - 1]), run.observations[t])
        particles, weights = est.particles, est.weights
        assert not particles.flags.writeable and not weights.flags.writeable
        np.testing.assert_allclose(np.bincount(particles, weights=weights, minlength=model.n_cells),
                                   belief.location, atol=1e-12)
        assert belief.distinct_locations == len(set(particles[weights > 0].tolist()))
        assert f"{belief.distinct_locations} distinct particle locations" in repr(belief)
    first = om.make_estimator("rbpf", model, n_particles=50, seed=0)
    first.step(None, run.observations[0])
    after_one = first.step(int(run.actions[0]), run.observations[1])  # two children of one particle
    assert after_one.distinct_locations <= 2 and after_one.effective_sample_size < 2
