"""Hindsight maps (onlinemap/hindsight.py): the told-location map with blocking labels against a
brute-force enumeration of every map (itertools.product), the table's counts on a hand-made belief,
and the errors."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

import onlinemap as om
from onlinemap.errors import InvalidOptionError
from onlinemap.hindsight import compare_hindsight, hindsight_map, hindsight_table, told_location


def brute_force_told(model, run):
    """P(m_i = k | true path, readings) by summing over all K^N maps, the motion and sensor written here."""
    n, k = model.n_cells, model.n_labels
    marginals = np.zeros((n, k))
    for labels in itertools.product(range(k), repeat=n):
        labels = np.array(labels)
        p = np.prod(model.label_prior[np.arange(n), labels])
        for t in range(run.n_steps):
            p *= model.sensor[labels[run.locations[t]], run.observations[t]]
            if t:
                here, there = run.locations[t - 1], run.locations[t]
                target = model.neighbors[here, run.actions[t - 1]]
                if target != here:
                    go = model.p_move * (not model.blocking[labels[target]])
                    p *= go if there == target else 1.0 - go
        marginals[np.arange(n), labels] += p
    return marginals / marginals.sum(axis=1, keepdims=True)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_told_location_with_blocking_matches_brute_force(seed):
    model = om.grid_model(2, 3, 2, p_obs=0.8, p_move=0.7, blocking=1)
    true_map = np.array([0, 1, 0, 0, 0, 1])
    run = om.simulate(model, true_map, om.random_walk(model, 12, seed=seed), seed=seed)
    np.testing.assert_allclose(told_location(model, run), brute_force_told(model, run), atol=1e-12)


def test_table_counts_on_a_hand_made_belief():
    true_map = np.array([0, 1, 1])
    belief = np.array([[0.95, 0.05], [0.5, 0.5], [0.92, 0.08]])  # right, unsure (tie -> label 0: wrong), confidently wrong
    row = hindsight_table(true_map, {"x": belief}).iloc[0]
    assert row["wrong_cells"] == 2 and row["confidently_wrong"] == 1
    assert row["final_map_error"] == pytest.approx((0.05 + 0.5 + 0.92) / 3)


def test_compare_hindsight_rows_and_the_known_pose_case():
    """With a perfect sensor and p_move = 1 every method knows the path: layered EM and the
    told-location map agree on every cell's most probable label."""
    model, true_map = om.building(12, 12, seed=4, p_obs=1.0, p_move=1.0, label_prior=np.full(4, 0.25))
    run = om.simulate(model, true_map, om.random_walk(model, 120, seed=5), seed=5)
    table = compare_hindsight(run, filter_map=np.full((model.n_cells, 4), 0.25),
                              options={"flat_em": {"n_iter": 5}, "layered_em": {"stretch": 10}})
    assert list(table["method"]) == ["filter", "flat_em", "layered_em", "told_location"]
    errors = dict(zip(table["method"], table["final_map_error"]))
    assert errors["filter"] == pytest.approx(0.75)
    assert errors["layered_em"] == pytest.approx(errors["told_location"], abs=1e-3)


def test_bad_requests_raise():
    model = om.grid_model(2, 3, 2)
    run = om.simulate(model, np.zeros(6, dtype=int), om.random_walk(model, 5, seed=0), seed=0)
    with pytest.raises(InvalidOptionError, match="unknown hindsight method"):
        hindsight_map(model, run, "smoothed")
    with pytest.raises(InvalidOptionError, match="true path"):
        hindsight_map(model, (run.actions, run.observations), "told_location")
    with pytest.raises(InvalidOptionError, match="run_or_data"):
        hindsight_map(model, run.observations, "flat_em")


def test_told_location_with_a_learned_prior_is_the_fixed_point():
    """label_prior="learn": the frequencies theta of the told-location map satisfy theta =
    (alpha + sum over cells read of P(label)) / (A + cells read), checked here with the map's own
    rows; every unread cell has theta; the cells read match the model-prior map's evidence."""
    model, true_map = om.building(12, 12, seed=2, p_move=0.9)
    run = om.simulate(model, true_map, om.random_walk(model, 120, seed=2), seed=2)
    learned = told_location(model, run, label_prior="learn")
    cells = model.footprint_cells[run.locations]
    read = np.unique(cells[cells >= 0])
    unread = np.setdiff1d(np.arange(model.n_cells), read)
    theta = learned[unread[0]]
    np.testing.assert_allclose(learned[unread], np.broadcast_to(theta, (len(unread), model.n_labels)), atol=1e-15)
    np.testing.assert_allclose(theta, (1.0 + learned[read].sum(axis=0)) / (model.n_labels + len(read)), atol=1e-9)
    uniform = told_location(model, run, label_prior="model")[read] * theta  # the uniform prior's map times theta: the same evidence
    np.testing.assert_allclose(learned[read], uniform / uniform.sum(axis=1, keepdims=True), atol=1e-9)
