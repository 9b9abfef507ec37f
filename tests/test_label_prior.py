"""The hierarchical label prior (onlinemap.label_prior) and the exact filter that learns it,
against brute force: the Polya-urn sequence of predictives written here, and an enumeration of
every (path, map) of a small corridor."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

import onlinemap as om
from onlinemap.label_prior import dirichlet_multinomial_prior, posterior_frequencies, resolve_label_prior


def polya_probability(labels, alpha) -> float:
    """P(m) by the urn: each cell's label drawn from (alpha + counts so far) / (A + cells so far)."""
    counts = np.zeros(len(alpha))
    p = 1.0
    for i, k in enumerate(labels):
        p *= (alpha[k] + counts[k]) / (sum(alpha) + i)
        counts[k] += 1
    return p


@pytest.mark.parametrize("n_cells, alpha", [(3, [1.0, 1.0]), (4, [0.5, 2.0]), (3, [0.2, 1.0, 3.0])])
def test_dirichlet_multinomial_prior_is_the_polya_urn(n_cells, alpha):
    got = dirichlet_multinomial_prior(n_cells, np.array(alpha))
    maps = list(itertools.product(range(len(alpha)), repeat=n_cells))  # cell 0 the slowest digit
    want = np.array([polya_probability(m, alpha) for m in maps])
    np.testing.assert_allclose(got, want, rtol=1e-12)
    assert got.sum() == pytest.approx(1.0)


def brute_force_posterior(n_cells, p_move, p_obs, alpha, actions, observations):
    """(location (N,), map (N, K)) at the last step, enumerating every path and map of a corridor
    whose map prior is the Dirichlet-multinomial (computed by the urn)."""
    k = len(alpha)
    loc = np.zeros(n_cells)
    marg = np.zeros((n_cells, k))
    for labels in itertools.product(range(k), repeat=n_cells):
        prior = polya_probability(labels, alpha)
        # forward over locations given this map (the paper's model: motion ignores the map)
        belief = np.zeros(n_cells)
        belief[0] = 1.0
        sensor = lambda z, cell: p_obs if labels[cell] == z else (1 - p_obs) / (k - 1)  # noqa: E731
        belief *= [sensor(observations[0], c) for c in range(n_cells)]
        for a, z in zip(actions, observations[1:]):
            moved = np.zeros(n_cells)
            for c in range(n_cells):
                target = c + (1 if a == 1 else -1)
                if 0 <= target < n_cells:
                    moved[target] += p_move * belief[c]
                    moved[c] += (1 - p_move) * belief[c]
                else:
                    moved[c] += belief[c]
            belief = moved * [sensor(z, c) for c in range(n_cells)]
        weight = prior * belief
        loc += weight
        for i, label in enumerate(labels):
            marg[i, label] += weight.sum()
    total = loc.sum()
    return loc / total, marg / total


def test_exact_filter_learning_the_prior_matches_enumeration():
    model = om.corridor(4, n_labels=2, p_obs=0.8, p_move=0.7)
    actions = [1, 1, 0, 1, 1]
    observations = [0, 0, 1, 0, 0, 0]
    est = om.make_estimator("exact", model, label_prior="learn", prior_strength=1.0)
    belief = est.step(None, observations[0])
    for a, z in zip(actions, observations[1:]):
        belief = est.step(a, z)
    loc, marg = brute_force_posterior(4, 0.7, 0.8, [0.5, 0.5], actions, observations)
    np.testing.assert_allclose(belief.location, loc, atol=1e-12)
    np.testing.assert_allclose(belief.map, marg, atol=1e-12)


def test_learning_couples_the_cells():
    """Reading label 0 twice makes an unread cell more likely 0 under the learned prior, and not at
    all under the model's independent prior."""
    model = om.corridor(4, n_labels=2, p_obs=0.9, p_move=1.0)
    learned = om.make_estimator("exact", model, label_prior="learn")
    fixed = om.make_estimator("exact", model)
    for est in (learned, fixed):
        est.step(None, 0)
        est.step(1, 0)
    assert fixed.belief.map[3, 0] == pytest.approx(0.5)
    assert learned.belief.map[3, 0] > 0.6


def test_a_fixed_frequency_vector_is_the_model_with_that_prior():
    model = om.corridor(3, n_labels=3)
    freq = [0.6, 0.3, 0.1]
    with_option = om.make_estimator("exact", model, label_prior=freq)
    in_model = om.make_estimator("exact", om.corridor(3, n_labels=3, label_prior=np.array(freq)))
    for a, z in [(None, 0), (1, 1), (1, 2)]:
        b1, b2 = with_option.step(a, z), in_model.step(a, z)
    np.testing.assert_allclose(b1.map, b2.map, atol=1e-14)
    np.testing.assert_allclose(b1.location, b2.location, atol=1e-14)


@pytest.mark.parametrize("label_prior, strength, match", [
    ("learned", None, "label_prior must be"), ([0.5, 0.6], None, "summing to 1"), ([1.0], None, "one frequency"),
    ([0.5, np.nan], None, "in \\[0, 1\\]"), ("learn", -1.0, "positive finite"), ("learn", True, "positive finite"),
    (None, 2.0, "means nothing"),
])
def test_bad_options_are_named(label_prior, strength, match):
    with pytest.raises(om.InvalidOptionError, match=match):
        resolve_label_prior(2, label_prior, strength)
    with pytest.raises(om.InvalidOptionError, match=match):
        om.make_estimator("exact", om.corridor(3), label_prior=label_prior, prior_strength=strength)


def test_posterior_frequencies_is_the_dirichlet_mean():
    np.testing.assert_allclose(posterior_frequencies([1.0, 1.0], [3.0, 1.0]), [4 / 6, 2 / 6])


def test_default_is_the_model_prior_bit_for_bit():
    model = om.corridor(4)
    run = om.simulate(model, np.array([0, 1, 0, 1]), om.random_walk(model, 10, seed=0), seed=0)
    a = om.run_estimator(om.make_estimator("exact", model), run.actions, run.observations)
    b = om.run_estimator(om.make_estimator("exact", model, label_prior=None), run.actions, run.observations)
    assert np.array_equal(a.map, b.map) and np.array_equal(a.location, b.location)
