"""The RBPF's genealogy smoother (onlinemap/hindsight.py, ``smoothed_rbpf_map``, method
``rbpf_smoothed``) and the genealogy the filter hands out (``update_with_ancestors``): against an
exact smoother by brute force over every path and map (itertools.product, the motion and the
sensor written here), against the told-location map when the one particle's path is the truth,
against the filter's own final map (the same mixture in a static world) and against the paths the
filter records itself for resample-move."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

import onlinemap as om
from onlinemap.errors import InvalidOptionError, ModelError
from onlinemap.estimators.rbpf import RaoBlackwellisedPF
from onlinemap.hindsight import hindsight_map, path_map, smoothed_rbpf_map, told_location


def brute_force_smoother(model, run):
    """P(m_i = k | a, z) by summing p(x_{1:T-1}, m, z | a) over every path from the start and
    every map: prior, sensor O[m_x, z] at each step, and each press's motion (move with p_move,
    times [target passable] with blocking labels; else stay)."""
    n, k, steps = model.n_cells, model.n_labels, run.n_steps
    marginals = np.zeros((n, k))
    for labels in itertools.product(range(k), repeat=n):
        labels = np.array(labels)
        prior = np.prod(model.label_prior[np.arange(n), labels])
        for rest in itertools.product(range(n), repeat=steps - 1):
            path = (model.start, *rest)
            p = prior * model.sensor[labels[path[0]], run.observations[0]]
            for t in range(1, steps):
                here, there = path[t - 1], path[t]
                target = model.neighbors[here, run.actions[t - 1]]
                go = 0.0 if target == here else model.p_move * (not model.blocking[labels[target]])
                p *= (go if there == target else 0.0) + (1.0 - go if there == here else 0.0)
                p *= model.sensor[labels[there], run.observations[t]]
                if p == 0.0:
                    break
            marginals[np.arange(n), labels] += p
    return marginals / marginals.sum(axis=1, keepdims=True)


TINY = {"plain": dict(), "blocking": dict(blocking=1)}


@pytest.mark.parametrize("kind", list(TINY))
def test_enough_particles_for_every_child_give_the_exact_smoother(kind):
    """Fearnhead-Clifford keeps every child while there are at most P of them: with P = 2^T it is
    exact Bayes, and so is the smoother (1e-9)."""
    model = om.grid_model(2, 2, 2, p_obs=0.8, p_move=0.7, **TINY[kind])
    run = om.simulate(model, np.array([0, 1, 0, 0]), om.random_walk(model, 5, seed=3), seed=3)
    exact = brute_force_smoother(model, run)
    smoothed = smoothed_rbpf_map(model, run.actions, run.observations, n_particles=2 ** run.n_steps, seed=0)
    np.testing.assert_allclose(smoothed.map, exact, atol=1e-9)
    assert smoothed.live_particles == smoothed.distinct_paths  # no child is kept twice


def test_many_sampled_particles_approach_the_exact_smoother():
    """The transition proposal with residual resampling every step: each cell's estimate is a
    weighted mean of P terms in [0, 1] after at most T resamplings, standard error at most 0.5
    sqrt(T / P) (each resampling adds at most the variance of a mean of P such terms); 5 of those."""
    model = om.grid_model(2, 2, 2, p_obs=0.8, p_move=0.7)
    run = om.simulate(model, np.array([0, 1, 1, 0]), om.random_walk(model, 5, seed=1), seed=1)
    exact = brute_force_smoother(model, run)
    n_particles = 20_000
    tolerance = 5 * 0.5 * math.sqrt(run.n_steps / n_particles)
    smoothed = smoothed_rbpf_map(model, run.actions, run.observations, n_particles=n_particles, seed=2,
                                 proposal="transition", resampling="residual", resample_threshold=1.0)
    assert np.abs(smoothed.map - exact).max() < tolerance
    assert np.abs(smoothed.map - exact).max() > 1e-9  # sampled, not exact: the tolerance is what is tested


def test_one_particle_on_the_true_path_gives_the_told_location_map():
    """p_move = 1 and no blocking labels: the one particle's path is the true one, and the map
    given it is the told-location map (run_facts' filter over the true path, another code path)."""
    model, true_map = om.door_world(p_move=1.0)
    run = om.simulate(model, true_map, om.random_walk(model, 60, seed=4), seed=4)
    smoothed = smoothed_rbpf_map(model, run.actions, run.observations, n_particles=1, seed=0)
    assert smoothed.distinct_paths == 1 and smoothed.common_steps == run.n_steps
    np.testing.assert_allclose(smoothed.map, told_location(model, run), atol=1e-12)


def test_in_a_static_world_the_genealogy_mixture_is_the_filters_map():
    """Each particle's filtered map is the exact map given its path: without recoveries (and
    with the model's fixed label prior) the smoother's mixture and the filter's final map agree
    (blocking walls, cross footprint)."""
    model, true_map = om.building(12, 12, seed=1, p_move=0.9)
    run = om.simulate(model, true_map, om.random_walk(model, 150, seed=2), seed=2)
    smoothed = smoothed_rbpf_map(model, run.actions, run.observations, n_particles=300, seed=0,
                                 label_prior="model")  # the model's table: a learned prior is a plug-in
    assert smoothed.recoveries == 0
    np.testing.assert_allclose(smoothed.map, smoothed.filtered, atol=1e-9)
    assert 1 <= smoothed.distinct_paths <= smoothed.live_particles <= 300
    assert 0 <= smoothed.common_steps < run.n_steps
    # distinct ancestors: never fewer going forward, all the live particles at the end; the paths
    # agree at least while one lineage holds them, and no longer than the step where two split
    lineages = smoothed.lineages
    assert np.all(np.diff(lineages) >= 0) and lineages[-1] == smoothed.live_particles
    assert np.argmax(lineages > 1) <= smoothed.common_steps and lineages[smoothed.common_steps] > 1


def test_path_map_takes_no_press_evidence_from_a_relocation():
    """A step that neither stays nor reaches the cell pressed into (a recovery's relocation) says
    nothing about the cell pressed into: only the readings count."""
    model = om.grid_model(1, 3, 2, p_obs=0.8, p_move=0.7, blocking=1)
    locations, actions = np.array([0, 2]), np.array([model.action_names.index("right")])  # pressed into cell 1
    observations = np.array([0, 1])
    expected = np.full((3, 2), 0.5)
    expected[0] = [0.8, 0.2]
    expected[2] = [0.2, 0.8]
    np.testing.assert_allclose(path_map(model, locations, actions, observations), expected, atol=1e-12)


def test_the_genealogy_is_the_paths_the_filter_records():
    """update_with_ancestors leaves the filter as update does (the same beliefs, bit for bit), and
    its ancestors traced back give the paths the filter records for resample-move (moves not yet
    due: move_lag beyond the run)."""
    model, true_map = om.door_world()
    run = om.simulate(model, true_map, om.random_walk(model, 40, seed=6), seed=6)
    plain = RaoBlackwellisedPF(model, n_particles=8, seed=3)
    traced = RaoBlackwellisedPF(model, n_particles=8, seed=3)
    recording = RaoBlackwellisedPF(model, n_particles=8, seed=3, move_window=2, move_lag=1000)
    locations, ancestors = [], []
    for t in range(run.n_steps):
        action = None if t == 0 else run.actions[t - 1]
        plain.update(action, run.observations[t])
        ancestors.append(traced.update_with_ancestors(action, run.observations[t]))
        recording.update(action, run.observations[t])
        locations.append(traced.particles)
        assert plain.belief.map.tobytes() == traced.belief.map.tobytes()
    slots = np.arange(8)
    paths = np.empty((8, run.n_steps), dtype=np.int64)
    for t in range(run.n_steps - 1, -1, -1):
        paths[:, t] = locations[t][slots]
        slots = ancestors[t][slots]
    live = traced.weights > 0
    np.testing.assert_array_equal(paths[live], recording._history.paths(run.n_steps - 1)[live])


def test_layered_em_learned_alignment_is_the_learned_fit_under_the_model_prior():
    model, true_map = om.building(12, 12, seed=2, p_move=0.9)
    run = om.simulate(model, true_map, om.random_walk(model, 80, seed=1), seed=1)
    fit = om.layered_em.fit_layered_map(model, run.actions, run.observations, label_prior="learn", stretch=10)
    expected = np.exp(np.log(model.label_prior) + fit.local_maps.sum(axis=0))
    expected /= expected.sum(axis=1, keepdims=True)
    got = hindsight_map(model, run, "layered_em_learned_alignment", stretch=10).map
    np.testing.assert_allclose(got, expected, atol=1e-9)


def test_bad_requests_raise():
    dynamic, true_map = om.door_world(p_door=0.05)
    run = om.simulate(dynamic, true_map, om.random_walk(dynamic, 5, seed=0), seed=0)
    with pytest.raises(ModelError, match="static world"):
        smoothed_rbpf_map(dynamic, run.actions, run.observations, n_particles=4)
    model, true_map = om.door_world()
    run = om.simulate(model, true_map, om.random_walk(model, 5, seed=0), seed=0)
    with pytest.raises(InvalidOptionError, match="move_window"):
        hindsight_map(model, run, "rbpf_smoothed", n_particles=4, move_window=2)
    with pytest.raises(InvalidOptionError, match="label_prior"):
        hindsight_map(model, run, "layered_em_learned_alignment", label_prior="learn")
