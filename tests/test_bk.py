"""Boyen-Koller: exact at the first step, a hand-derived 2-cell update, every step against
the projection filter written by enumeration, and worse than the RBPF on the scripted
corridor."""

import numpy as np
import pytest

import onlinemap as om
from onlinemap.metrics import total_variation
from estimator_cases import beliefs, exact_trajectory, random_run
from oracles import BruteForce

MODELS = [
    ("corridor static", lambda: om.corridor(4, 2, p_obs=0.85, p_move=0.7)),
    ("corridor K=3 dynamic", lambda: om.corridor(3, 3, p_obs=0.8, p_move=0.75, p_change=0.1, start=1)),
    ("grid 2x2 dynamic", lambda: om.grid_model(2, 2, 2, p_obs=0.8, p_move=0.7, change=[[0.9, 0.1], [0.2, 0.8]],
                                               label_prior=[0.3, 0.7])),
]


@pytest.mark.parametrize("name,make", MODELS, ids=[m[0] for m in MODELS])
def test_first_step_equals_exact(name, make):
    model = make()
    for z in range(model.n_labels):
        bk = om.make_estimator("bk", model).step(None, z)
        exact = om.make_estimator("exact", model).step(None, z)
        np.testing.assert_allclose(bk.location, exact.location, atol=1e-14)
        np.testing.assert_allclose(bk.map, exact.map, atol=1e-14)
        assert bk.log_evidence == pytest.approx(exact.log_evidence, abs=1e-14)


def test_hand_derived_two_cell_update():
    """2-cell corridor, p_obs 0.9, p_move 0.8, uniform prior. Step 0 sees 0 at cell 0:
    mu_0 = (0.9, 0.1). Step 1, right, sees 1: q = (0.2, 0.8); P(z=1 | L=0) = 0.9*0.1 + 0.1*0.9
    = 0.18, P(z=1 | L=1) = 0.5, Z = 0.2*0.18 + 0.8*0.5 = 0.436. q' = (0.036, 0.4) / Z;
    mu_0'(k) = mu_0(k) (0.2 O[k, 1] + 0.4) / Z; mu_1'(k) = 0.5 (0.8 O[k, 1] + 0.036) / Z."""
    model = om.corridor(2, 2, p_obs=0.9, p_move=0.8)
    est = om.make_estimator("bk", model)
    est.step(None, 0)
    belief = est.step("right", 1)
    z_total = 0.436
    np.testing.assert_allclose(belief.location, [0.036 / z_total, 0.4 / z_total], atol=1e-14)
    np.testing.assert_allclose(belief.map[0], [0.9 * 0.42 / z_total, 0.1 * 0.58 / z_total], atol=1e-14)
    np.testing.assert_allclose(belief.map[1], [0.5 * 0.116 / z_total, 0.5 * 0.756 / z_total], atol=1e-14)
    assert belief.log_evidence == pytest.approx(np.log(0.5) + np.log(z_total), abs=1e-14)
    # here BK still equals exact (the first update only couples cell 0 with a known location) ...
    exact = om.make_estimator("exact", model)
    exact.step(None, 0)
    np.testing.assert_allclose(exact.step("right", 1).map, belief.map, atol=1e-14)
    # ... but the next step needs the location/map correlation that BK has thrown away
    assert np.abs(exact.step("left", 0).map - est.step("left", 0).map).max() > 1e-3


def projection_filter(model, actions, observations):
    """Reference BK by enumeration: at each step rebuild the joint over (l, m) as the product
    of the previous marginals, apply the full transition and likelihood, marginalise."""
    oracle = BruteForce.of(model)
    location, maps = np.eye(model.n_cells)[model.start], np.array(model.label_prior)
    log_ev, out = 0.0, []
    for t, z in enumerate(observations):
        joint = np.array([location[l] * np.prod([maps[i, m[i]] for i in range(oracle.n)])
                          for l, m in oracle.states])
        if t:
            joint = joint @ oracle.transition(actions[t - 1])
        joint = joint * oracle.likelihood(z)
        log_ev += np.log(joint.sum())
        location, maps = oracle.marginals(joint / joint.sum())
        out.append((location, maps, log_ev))
    return out


@pytest.mark.parametrize("name,make", MODELS, ids=[m[0] for m in MODELS])
def test_every_step_equals_projection_by_enumeration(name, make):
    model = make()
    run = random_run(model, 8, seed=2)
    est = om.make_estimator("bk", model)
    for (location, maps, log_ev), belief in zip(projection_filter(model, run.actions, run.observations),
                                                beliefs(est, run), strict=True):
        np.testing.assert_allclose(belief.location, location, atol=1e-12)
        np.testing.assert_allclose(belief.map, maps, atol=1e-12)
        assert belief.log_evidence == pytest.approx(log_ev, abs=1e-12)


def mean_tv_to_exact(name, run, **options):
    exact = exact_trajectory(run)
    other = om.run_estimator(om.make_estimator(name, run.model, **options), run.actions, run.observations)
    return (total_variation(other.location, exact.location).mean(),
            total_variation(other.map, exact.map).mean())


def test_bk_is_further_from_exact_than_rbpf_on_scripted_corridor():
    run = om.scenarios.murphy_corridor()
    bk_location, bk_map = mean_tv_to_exact("bk", run)
    for seed in range(3):
        rb_location, rb_map = mean_tv_to_exact("rbpf", run, n_particles=100, seed=seed)
        assert rb_location < bk_location and rb_map < bk_map, (seed, rb_location, bk_location, rb_map, bk_map)
    assert bk_map > 0.02  # not a near-tie


def test_impossible_observation_keeps_state():
    model = om.corridor(3, p_obs=1.0, p_move=1.0)
    est = om.make_estimator("bk", model)
    est.step(None, 1)
    before = est.step("left", 1)
    with pytest.raises(om.ImpossibleObservationError, match="probability zero"):
        est.step("left", 0)
    assert est.t == 1 and est.belief is before
    np.testing.assert_array_equal(est.step("right", 0).location, [0, 1, 0])


def test_bad_input_keeps_state():
    est = om.make_estimator("bk", om.corridor(4))
    est.step(None, 0)
    before = est.belief
    for action, observation in [(5, 0), (None, 0), (0, 7), ("up", 0)]:
        with pytest.raises((om.InvalidActionError, om.InvalidObservationError)):
            est.step(action, observation)
    assert est.belief is before and est.t == 0


def test_product_of_marginals_is_a_distribution():
    model = om.door_world(p_door=0.05)[0]
    run = random_run(model, 30, seed=1)
    belief = om.run_estimator(om.make_estimator("bk", model), run.actions, run.observations)
    np.testing.assert_allclose(belief.location.sum(axis=1), 1, atol=1e-12)
    np.testing.assert_allclose(belief.map.sum(axis=2), 1, atol=1e-12)
    assert belief.map.shape == (30, 100, 4)


def assert_probabilities(belief, t):
    """Every probability in [0, 1], rows summing to 1, entropies finite (scipy's, and ours)."""
    from scipy.stats import entropy

    from onlinemap.metrics import map_entropy, normalized_entropy

    for what, p in (("location", belief.location), ("map", belief.map)):
        assert p.min() >= 0 and p.max() <= 1, (what, t, p.min(), p.max() - 1)
        np.testing.assert_allclose(p.sum(axis=-1), 1.0, rtol=0, atol=1e-12, err_msg=f"{what} at t={t}")
        assert np.isfinite(entropy(p, axis=-1)).all() and np.isfinite(normalized_entropy(p)).all(), (what, t)
    assert np.isfinite(map_entropy(belief.map)).all()


def test_issue_case_footprint_blocking_dynamic_noiseless_stays_in_zero_one():
    """Regression (issue 24 item 8): with a footprint, blocking, map dynamics and p_obs = 1 the
    footprint update's ``Z - (mass of the locations reading cell i)`` fell below 0 by rounding
    and the map held -2.4e-16 at t = 33 (entropies NaN), and entries above 1 elsewhere."""
    model = om.grid_model(1, 3, 2, blocking=[1], footprint="square", change=[[.9, .1], [.1, .9]], p_obs=1.0)
    run = om.simulate(model, steps=34, seed=221)
    est = om.make_estimator("bk", model)
    for t, belief in enumerate(beliefs(est, run)):
        assert_probabilities(belief, t)


@pytest.mark.parametrize("n_labels", [2, 3])
@pytest.mark.parametrize("blocking", [None, [1]], ids=["free", "blocking"])
@pytest.mark.parametrize("footprint", ["cross", "square"])
def test_noiseless_footprint_worlds_stay_in_zero_one(footprint, blocking, n_labels):
    """Each of these worlds gave entries below 0 or above 1 within 60 steps for every seed."""
    from onlinemap.model import symmetric_channel

    for shape in ((1, 3), (2, 3)):
        model = om.grid_model(*shape, n_labels, blocking=blocking, footprint=footprint, p_obs=1.0,
                              change=symmetric_channel(n_labels, 0.9))
        for seed in range(3):
            est = om.make_estimator("bk", model)
            for t, belief in enumerate(beliefs(est, om.simulate(model, steps=60, seed=seed))):
                assert_probabilities(belief, t)


def test_an_observation_below_float64s_range_is_refused_not_a_map_of_zeros():
    """Issue 43 section 2 item 10: with a sensor entry of 5e-324 (the smallest subnormal) bk
    returned map rows of all zeros for the cells never read: the total P(z) = 5e-324 was
    subnormal (O[:, z]'s largest entry is 1, so the rescaling by it does nothing) and
    ``maps * Z / Z`` rounded 0.5 * 5e-324 to 0. Exact Bayes refuses the step; bk now does too,
    leaving its state as it was. The filter's own arithmetic, worked by hand: the robot at cell 0,
    surely label 0 (prior row [1, 0]), reads 1: P(z) = 1 * O[0, 1] = 5e-324."""
    sensor = np.array([[1.0, 5e-324], [0.0, 1.0]])
    prior = np.array([[1.0, 0.0], [0.5, 0.5], [0.5, 0.5], [0.5, 0.5]])
    model = om.grid_model(1, 4, 2, sensor=sensor, label_prior=prior)
    for name in ("exact", "bk"):
        est = om.make_estimator(name, model)
        with pytest.raises(om.ImpossibleObservationError, match="below float64's range"):
            est.step(None, 1)
        assert est.t == -1 and est.belief is None
        belief = est.step(None, 0)  # the state was left as it was: the likely reading goes through
        np.testing.assert_allclose(belief.map, prior)
