"""The RBPF's label prior (onlinemap.estimators.rbpf_prior): None changes nothing; a fixed vector is
the RBPF of a model with that prior and, with room for every child, the exact filter with the same
option; "learn" converges to the frequencies a world was drawn from (tolerance from the number of
cells read) and stays close to the exact hierarchical posterior on a tiny world; bad options are
refused; checkpoints round trip bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

import onlinemap as om
from onlinemap.errors import CheckpointError, InvalidOptionError
from estimator_cases import beliefs, random_run


def drawn_world(rows, cols, theta, blocking, seed, steps, p_obs=0.9):
    """A grid world whose labels are drawn iid from ``theta`` (the start free), and a random walk on it."""
    model = om.grid_model(rows, cols, len(theta), p_obs=p_obs, p_move=0.8, blocking=blocking, footprint="cross")
    rng = np.random.default_rng(seed)
    labels = rng.choice(len(theta), size=model.n_cells, p=theta)
    labels[model.start] = 0
    return model, labels, om.simulate(model, labels, om.random_walk(model, steps - 1, rng), rng)


WORLDS = [
    ("corridor", lambda: om.corridor(8, 3, p_obs=0.8)),
    ("door dynamic", lambda: om.door_world(p_move=0.8, p_door=0.05)[0]),
    ("door blocking cross", lambda: om.door_world(p_move=0.8, blocking=True, footprint="cross")[0]),
]


@pytest.mark.parametrize("name,make", WORLDS, ids=[w[0] for w in WORLDS])
def test_without_a_label_prior_every_run_is_as_it_was(name, make):
    model = make()
    run = random_run(model, 40, seed=3)
    plain = om.make_estimator("rbpf", model, n_particles=64, seed=1)
    given = om.make_estimator("rbpf", model, n_particles=64, seed=1, label_prior=None)
    assert "_label_frequencies" not in vars(given) and given.label_frequencies is None
    assert repr(given) == repr(plain)  # the options it does not use are not shown
    for a, b in zip(beliefs(plain, run), beliefs(given, run)):
        np.testing.assert_array_equal(a.map, b.map)
        np.testing.assert_array_equal(a.location, b.location)
        assert a.log_evidence == b.log_evidence


FIXED = np.array([0.5, 0.3, 0.2])


def test_a_fixed_vector_is_the_filter_of_a_model_with_that_prior():
    model = om.grid_model(6, 6, 3, p_obs=0.85, p_move=0.8, blocking=[2], footprint="cross")
    with_prior = om.grid_model(6, 6, 3, p_obs=0.85, p_move=0.8, blocking=[2], footprint="cross", label_prior=FIXED)
    run = random_run(model, 60, seed=2)
    tilted = om.make_estimator("rbpf", model, n_particles=200, seed=4, label_prior=FIXED)
    reference = om.make_estimator("rbpf", with_prior, n_particles=200, seed=4)
    np.testing.assert_array_equal(tilted.label_frequencies, FIXED)
    for a, b in zip(beliefs(tilted, run), beliefs(reference, run)):
        np.testing.assert_allclose(a.map, b.map, atol=1e-9)
        np.testing.assert_allclose(a.location, b.location, atol=1e-9)


@pytest.mark.parametrize("blocking", [None, [2]])
def test_a_fixed_vector_with_room_for_every_child_is_the_exact_filter_with_it(blocking):
    model = om.grid_model(1, 4, 3, p_obs=0.85, p_move=0.8, blocking=blocking)
    run = random_run(model, 7, seed=5)
    rbpf = om.make_estimator("rbpf", model, n_particles=2 ** 7, seed=0, label_prior=FIXED)  # P >= 2^T: exact
    exact = om.make_estimator("exact", model, label_prior=FIXED)
    for a, b in zip(beliefs(rbpf, run), beliefs(exact, run)):
        np.testing.assert_allclose(a.map, b.map, atol=1e-9)
        np.testing.assert_allclose(a.location, b.location, atol=1e-9)


@pytest.mark.parametrize("seed", [1, 3])
def test_learned_frequencies_converge_to_those_the_world_was_drawn_from(seed):
    """The learned frequencies are ``(alpha + c) / (A + n)``, c the expected counts of the n read
    cells. Per label, ``|c_k - true count_k| <= sum over read cells of (1 - P(true label))`` (the
    mass the belief puts off the true labels: its map error over the read cells, ``e n``), and the
    pseudo-counts move the mean by at most ``A / (A + n)``; the read cells' true frequencies are
    within 4 sd, ``4 sqrt(theta (1 - theta) / n)``, of theta. So ``|learned - theta| <= 4 sd + e
    + A / (A + n)``: a filter that did not learn (uniform, 1/3) misses 0.6 by more than that."""
    theta = np.array([0.6, 0.3, 0.1])
    model, labels, run = drawn_world(15, 15, theta, [2], seed, steps=800)
    est = om.make_estimator("rbpf", model, n_particles=200, seed=seed, label_prior="learn")
    for belief in beliefs(est, run):
        pass
    assert_learned_near_theta(model, labels, theta, est.label_frequencies, belief.map)


def assert_learned_near_theta(model, labels, theta, learned, final_map):
    """``|learned - theta| <= 4 sqrt(theta (1 - theta) / n) + e + A / (A + n)`` (A = K = 3), n the
    cells read (those whose marginal in ``final_map`` (N, K) left the tilted prior: the learner's
    criterion, written here), e the mean mass off their true ``labels``; and the bound excludes the
    uniform 1/3 for ``theta[0]``, so the check can fail."""
    unread = model.label_prior * learned
    unread /= unread.sum(axis=1, keepdims=True)
    read = np.abs(final_map - unread).max(axis=1) > 1e-9
    n = int(read.sum())
    assert n > 100  # the walk read most of the floor
    off_truth = float((1 - final_map[np.flatnonzero(read), labels[read]]).mean())
    tolerance = 4 * np.sqrt(theta * (1 - theta) / n) + off_truth + 3 / (3 + n)
    assert np.all(np.abs(learned - theta) <= tolerance), (learned, theta, tolerance)
    assert abs(1 / 3 - theta[0]) > tolerance[0]  # the test can fail


def map_tv(a: om.Belief, b: om.Belief) -> float:
    """Mean over cells of the total variation between two beliefs' map marginals."""
    return float(0.5 * np.abs(a.map - b.map).sum(axis=1).mean())


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_learning_is_close_to_the_exact_hierarchical_posterior_on_a_tiny_world(seed):
    """4 cells, 3 labels (the last blocks), 30 steps, 2000 particles, learning every step. The plug-in is an
    approximation (a read cell's prior counts the cell itself; weights are not reweighted): its
    mean map TV to the exact "learn" filter, averaged over steps, measured 0.006-0.009 on these
    seeds; the tolerance 0.03 is about 3x that, and the exact filter with the independent prior is
    farther from the exact "learn" posterior than that on every seed (measured 0.055-0.16): the
    test tells learning from not learning. (Max over steps and cells: 0.06 plug-in against 0.19-0.23.)"""
    model = om.grid_model(1, 4, 3, p_obs=0.85, p_move=0.8, blocking=[2])
    rng = np.random.default_rng(seed)
    labels = rng.choice(3, size=4, p=[0.6, 0.3, 0.1])
    labels[0] = 0
    run = om.simulate(model, labels, om.random_walk(model, 29, rng), rng)
    exact = list(beliefs(om.make_estimator("exact", model, label_prior="learn"), run))
    independent = list(beliefs(om.make_estimator("exact", model), run))
    learned = list(beliefs(om.make_estimator("rbpf", model, n_particles=2000, seed=seed, label_prior="learn",
                                             learn_every=1), run))
    tv_learned = np.mean([map_tv(a, b) for a, b in zip(exact, learned)])
    tv_independent = np.mean([map_tv(a, b) for a, b in zip(exact, independent)])
    assert tv_learned <= 0.03 < tv_independent, (tv_learned, tv_independent)


BAD = [
    ({"label_prior": "lern"}, "label_prior"),
    ({"label_prior": [0.5, 0.5]}, "one frequency per label"),
    ({"label_prior": [0.7, 0.7, -0.4]}, "summing to 1"),
    ({"prior_strength": 2.0}, "prior_strength"),
    ({"label_prior": "learn", "prior_strength": 0}, "prior_strength"),
    ({"learn_every": 5}, "learn_every"),
    ({"label_prior": "learn", "learn_every": 0}, "learn_every"),
    ({"label_prior": [0, 0, 1.0]}, "probability zero"),
]


@pytest.mark.parametrize("options,words", BAD, ids=[str(b[0]) for b in BAD])
def test_bad_options_are_refused_naming_the_problem(options, words):
    prior = np.tile([0.5, 0.5, 0.0], (4, 1)) if words == "probability zero" else None
    model = om.grid_model(1, 4, 3, label_prior=prior)
    with pytest.raises(InvalidOptionError, match=words):
        om.make_estimator("rbpf", model, **options)


def test_learning_is_refused_in_a_dynamic_world():
    model = om.door_world(p_door=0.05)[0]
    with pytest.raises(InvalidOptionError, match=r"static world.*C = I"):
        om.make_estimator("rbpf", model, label_prior="learn")
    om.make_estimator("rbpf", model, label_prior=[0.4, 0.4, 0.1, 0.1])  # a fixed tilt is sound there


@pytest.mark.parametrize("name, options, stop", [("rbpf", dict(n_particles=100, seed=7, learn_every=2), 30),
                                                 ("bk", dict(learn_every=3), 31)])
def test_a_learning_filter_resumes_from_its_checkpoint_bit_for_bit(tmp_path, name, options, stop):
    """The RBPF and BK with label_prior="learn", saved mid-run and loaded: the same beliefs,
    evidence and learned frequencies as the filter that ran straight through."""
    model, _, run = drawn_world(8, 8, [0.6, 0.3, 0.1], [2], seed=2, steps=60)
    settings = dict(label_prior="learn", prior_strength=1.5, **options)
    straight = om.make_estimator(name, model, **settings)
    expected = list(beliefs(straight, run))
    est = om.make_estimator(name, model, **settings)
    for _ in beliefs(est, run, stop=stop):
        pass
    om.save(est, tmp_path / "learning.npz")
    resumed = om.load(tmp_path / "learning.npz")
    np.testing.assert_array_equal(resumed.label_frequencies, est.label_frequencies)
    for got, want in zip(beliefs(resumed, run, start=stop), expected[stop:]):
        np.testing.assert_array_equal(got.map, want.map)
        np.testing.assert_array_equal(got.location, want.location)
        assert got.log_evidence == want.log_evidence
    np.testing.assert_array_equal(resumed.label_frequencies, straight.label_frequencies)
    assert not np.allclose(straight.label_frequencies, 1 / 3)  # it learned something


@pytest.mark.parametrize("bad", [np.array([0.5, 0.5, 0.5]), np.array([1.0, 0.0, 0.0]), np.array([0.5, 0.5])])
def test_a_checkpoint_with_broken_frequencies_is_refused(bad):
    model, _, run = drawn_world(8, 8, [0.6, 0.3, 0.1], [2], seed=2, steps=10)
    est = om.make_estimator("rbpf", model, n_particles=20, seed=7, label_prior="learn")
    for _ in beliefs(est, run):
        pass
    est._label_frequencies = bad
    with pytest.raises(CheckpointError, match="_label_frequencies"):
        type(est).check_state(est)
