"""Layered EM (onlinemap/layered_em.py) against independent references: brute-force enumeration of
paths (itertools.product) for the E-step with one step per stretch, and a known-pose run (perfect
sensor, p_move = 1) whose map must come out exactly."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

import onlinemap as om
from onlinemap.errors import InvalidOptionError, ModelError
from onlinemap.layered_em import MAX_STRETCH, SELECT_AFTER, default_stretch, fit_layered_map, localize_stretches


def brute_force_poses(model, actions, observations, labels):
    """P(L_t | z) and log P(z) by summing over every path, with the motion and sensor written out
    here: a move into j succeeds with p_move P(j passable) under ``labels``."""
    n, t = model.n_cells, len(observations)
    passable = labels @ (~model.blocking).astype(float)
    emission = labels @ model.sensor
    marginals, evidence = np.zeros((t, n)), 0.0
    for path in itertools.product(range(n), repeat=t):
        if path[0] != model.start:
            continue
        p = emission[path[0], observations[0]]
        for step in range(1, t):
            here, there = path[step - 1], path[step]
            target = model.neighbors[here, actions[step - 1]]
            go = model.p_move * passable[target] if target != here else 0.0
            p *= (go if there == target and target != here else 0.0) + ((1.0 - go) if there == here else 0.0)
            p *= emission[there, observations[step]]
        evidence += p
        for step in range(t):
            marginals[step, path[step]] += p
    return marginals / evidence, np.log(evidence)


@pytest.mark.parametrize("blocking", [None, 1])
def test_one_step_stretches_are_exact_forward_backward(blocking):
    model = om.grid_model(2, 3, 2, p_obs=0.8, p_move=0.7, blocking=blocking)
    rng = np.random.default_rng(0)
    labels = rng.dirichlet(np.ones(2), size=model.n_cells)
    actions = rng.integers(0, model.n_actions, size=4)
    observations = rng.integers(0, 2, size=5)
    poses, log_evidence = localize_stretches(model, actions, observations, labels, stretch=1)
    expected, expected_evidence = brute_force_poses(model, actions, observations, labels)
    np.testing.assert_allclose(poses, expected, atol=1e-12)
    assert log_evidence == pytest.approx(expected_evidence, abs=1e-10)


def test_layered_em_with_one_step_stretches_starts_from_exact_localisation():
    """The first E-step of a one-step-stretch fit with no annealing is forward-backward over the
    locations in the sweep's map: its poses are a distribution per step and the start is sure."""
    model = om.grid_model(2, 3, 2, p_obs=0.8, p_move=0.7)
    true_map = np.array([0, 1, 0, 1, 1, 0])
    run = om.simulate(model, true_map, om.random_walk(model, 6, seed=1), seed=1)
    fit = fit_layered_map(model, run.actions, run.observations, stretch=1, n_iter=3, anneal=None)
    assert fit.poses.shape == (7, 6) and fit.local_maps.shape == (7, 6, 2)
    np.testing.assert_allclose(fit.poses.sum(axis=1), 1.0)
    assert fit.poses[0, model.start] == pytest.approx(1.0)
    np.testing.assert_allclose(fit.map.sum(axis=1), 1.0)


@pytest.mark.parametrize("stretch", [1, 5, None])
def test_known_poses_recover_the_true_map(stretch):
    """A perfect sensor and p_move = 1: every pose is known, so every cell read has its true label
    (up to the evidence floor) and every cell never read keeps its prior."""
    model = om.grid_model(4, 5, 3, p_obs=1.0, p_move=1.0)
    true_map = np.random.default_rng(2).integers(0, 3, size=model.n_cells)
    run = om.simulate(model, true_map, om.random_walk(model, 40, seed=3), seed=3)
    fit = fit_layered_map(model, run.actions, run.observations, stretch=stretch)
    read = np.unique(run.locations)
    assert np.all(fit.map[read, true_map[read]] > 1 - 1e-5)
    unread = np.setdiff1d(np.arange(model.n_cells), read)
    np.testing.assert_allclose(fit.map[unread], model.label_prior[unread], atol=1e-12)


def test_known_poses_with_blocking_walls_and_a_footprint():
    """The same in a building (walls and closed doors block, the cross footprint): the cells read
    get their true label, and the walls the robot bumped into count as evidence."""
    model, true_map = om.building(12, 12, seed=4, p_obs=1.0, p_move=1.0)
    run = om.simulate(model, true_map, om.random_walk(model, 150, seed=5), seed=5)
    fit = fit_layered_map(model, run.actions, run.observations, stretch=10)
    cells = model.footprint_cells[run.locations]
    read = np.unique(cells[cells >= 0])
    assert np.array_equal(np.argmax(fit.map[read], axis=1), true_map[read])
    assert np.all(fit.map[read, true_map[read]] > 1 - 1e-4)


def test_default_stretch_rule():
    # one expected slip in two stretches, S (1 - p) = 1/2: 1 / 0.1 = 10, 1 / 0.4 = 2.5 (rounded up), 1 / 1 = 1
    assert default_stretch(0.95) == 10 and default_stretch(0.8) == 3
    assert default_stretch(1.0) == 16 and default_stretch(0.5) == 1 and default_stretch(0.99) == 16


def test_bad_options_raise_and_name_the_problem():
    model = om.grid_model(2, 3, 2)
    run = om.simulate(model, np.zeros(6, dtype=int), om.random_walk(model, 5, seed=0), seed=0)
    with pytest.raises(InvalidOptionError, match="stretch"):
        fit_layered_map(model, run.actions, run.observations, stretch=0)
    with pytest.raises(InvalidOptionError, match="anneal"):
        fit_layered_map(model, run.actions, run.observations, anneal=(0.5, 0.5, 1.0))
    with pytest.raises(InvalidOptionError, match="n_iter"):
        fit_layered_map(model, run.actions, run.observations, n_iter=0)
    for starts in ((), (0.0,), (1.5,), "1"):
        with pytest.raises(InvalidOptionError, match="starts"):
            fit_layered_map(model, run.actions, run.observations, starts=starts)
    with pytest.raises(InvalidOptionError, match="stretch"):
        fit_layered_map(model, run.actions, run.observations, stretch=MAX_STRETCH + 1)
    dynamic = om.corridor(6, p_change=0.1)
    with pytest.raises(ModelError, match="static"):
        fit_layered_map(dynamic, [1, 1], [0, 1, 0])


def brute_force_stretches(model, actions, observations, labels, stretch):
    """P(x_m | z) and log P(z) by summing over every path, for a one-cell footprint: within a
    stretch a step that stayed predicts its reading by the cell's labels updated by the reading
    before (the same cell), a step that moved by the labels alone; a stretch's first step too."""
    n, t = model.n_cells, len(observations)
    passable = labels @ (~model.blocking).astype(float)
    sensor = model.sensor
    starts = list(range(0, t, stretch))
    marginals, evidence = np.zeros((len(starts), n)), 0.0
    for path in itertools.product(range(n), repeat=t):
        if path[0] != model.start:
            continue
        p = labels[path[0]] @ sensor[:, observations[0]]
        for step in range(1, t):
            here, there = path[step - 1], path[step]
            target = model.neighbors[here, actions[step - 1]]
            go = model.p_move * passable[target] if target != here else 0.0
            p *= (go if there == target and target != here else 0.0) + ((1.0 - go) if there == here else 0.0)
            q = labels[there]
            if step not in starts and there == here:
                q = q * sensor[:, observations[step - 1]]
            p *= (q @ sensor[:, observations[step]]) / q.sum()
        evidence += p
        for m, first in enumerate(starts):
            marginals[m, path[first]] += p
    return marginals / evidence, np.log(evidence)


@pytest.mark.parametrize("blocking", [None, 1])
def test_stretches_are_decoded_exactly(blocking):
    """With S > 1 the offsets within each stretch are summed over exactly: the pose posteriors
    and the evidence equal the enumeration of every path (slips in a stretch read again)."""
    model = om.grid_model(2, 3, 2, p_obs=0.8, p_move=0.7, blocking=blocking)
    rng = np.random.default_rng(3)
    labels = rng.dirichlet(np.ones(2), size=model.n_cells)
    actions = rng.integers(0, model.n_actions, size=6)
    observations = rng.integers(0, 2, size=7)
    poses, log_evidence = localize_stretches(model, actions, observations, labels, stretch=3)
    expected, expected_evidence = brute_force_stretches(model, actions, observations, labels, 3)
    np.testing.assert_allclose(poses, expected, atol=1e-12)
    assert log_evidence == pytest.approx(expected_evidence, abs=1e-10)


def test_learned_label_prior_of_known_poses():
    """Known poses (perfect sensor, p_move = 1) and label_prior="learn": the frequencies are the
    Dirichlet posterior mean (alpha = 1 per label) given the true labels of the cells read, and
    every cell never read has them as its map."""
    model, true_map = om.building(12, 12, seed=4, p_obs=1.0, p_move=1.0)
    run = om.simulate(model, true_map, om.random_walk(model, 150, seed=5), seed=5)
    fit = fit_layered_map(model, run.actions, run.observations, stretch=10, label_prior="learn")
    cells = model.footprint_cells[run.locations]
    read = np.unique(cells[cells >= 0])
    expected = (1.0 + np.bincount(true_map[read], minlength=model.n_labels)) / (model.n_labels + len(read))
    np.testing.assert_allclose(fit.frequencies, expected, atol=1e-4)
    unread = np.setdiff1d(np.arange(model.n_cells), read)
    np.testing.assert_allclose(fit.map[unread], np.broadcast_to(fit.frequencies, (len(unread), model.n_labels)),
                               atol=1e-12)
    assert np.array_equal(np.argmax(fit.map[read], axis=1), true_map[read])


def test_the_likelier_start_continues():
    """Two sweep temperatures: the fit is the one of the start whose log-likelihood is higher
    after SELECT_AFTER iterations, continued (the same as starting from it alone)."""
    model, true_map = om.building(12, 12, seed=6, p_move=0.8)
    run = om.simulate(model, true_map, om.random_walk(model, 80, seed=6), seed=6)
    alone = {tau: fit_layered_map(model, run.actions, run.observations, starts=(tau,), n_iter=SELECT_AFTER)
             for tau in (1.0, 0.1)}
    best = max(alone, key=lambda tau: alone[tau].log_likelihoods[-1])
    both = fit_layered_map(model, run.actions, run.observations, starts=(1.0, 0.1), n_iter=SELECT_AFTER + 1)
    single = fit_layered_map(model, run.actions, run.observations, starts=(best,), n_iter=SELECT_AFTER + 1)
    np.testing.assert_array_equal(both.map, single.map)
    np.testing.assert_array_equal(both.log_likelihoods[:SELECT_AFTER], alone[best].log_likelihoods)


def test_map_with_another_prior_is_the_local_maps_under_it():
    """map_with_prior(the fit's own prior) is the fit's map; under another prior every cell's
    odds change by the prior's odds alone (the evidence of the local maps is kept)."""
    model, true_map = om.building(12, 12, seed=7, p_move=0.9)
    run = om.simulate(model, true_map, om.random_walk(model, 60, seed=7), seed=7)
    fit = fit_layered_map(model, run.actions, run.observations, label_prior="learn", n_iter=2)
    np.testing.assert_allclose(fit.map_with_prior(fit.frequencies), fit.map, atol=1e-12)
    uniform = fit.map_with_prior(model.label_prior)
    odds = np.log(uniform) - np.log(fit.map) + np.log(fit.frequencies)
    np.testing.assert_allclose(odds - odds[:, :1], 0.0, atol=1e-9)
