"""``hindsight.path_log_likelihood``: the joint probability of a whole path and its readings with
the map summed out, against a brute force over every map (``oracles.BruteForce``'s motion and
sensor, written from DESIGN.md section 1; the maps enumerated with itertools.product)."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

import onlinemap as om
from onlinemap.errors import InvalidOptionError, ModelError
from onlinemap.hindsight import path_log_likelihood
from oracles import BruteForce


def brute_force(model, locations, actions, observations, theta) -> float:
    """log sum_m prod_i theta[m_i] prod_t P(x_t | x_{t-1}, a_t, m) P(z_t | x_t, m), x_0 the start."""
    oracle = BruteForce.of(model)
    n_maps = model.n_labels ** model.n_cells
    likelihoods = [oracle.likelihood(z) for z in observations]  # over states (l, m), m fastest
    total = 0.0
    for index, m in enumerate(itertools.product(range(model.n_labels), repeat=model.n_cells)):
        p = math.prod(theta[label] for label in m) * float(locations[0] == model.start)
        for t, l in enumerate(locations):
            if t > 0:
                p *= oracle.move(int(actions[t - 1]), int(locations[t - 1]), m, int(l))
            p *= likelihoods[t][int(l) * n_maps + index]
        total += p
    return math.log(total) if total > 0 else -math.inf


def _blocking_run(seed):
    """2 x 4 cells, a wall in the bottom row, the cross footprint: the two middle cells of a row
    share their off-grid readings, so several paths fit the readings."""
    model = om.grid_model(2, 4, 2, p_obs=0.8, p_move=0.7, blocking=[1], footprint="cross", start=1)
    run = om.simulate(model, np.array([0, 0, 0, 0, 0, 0, 1, 0]), om.random_walk(model, 6, seed=seed), seed=seed)
    return model, run


def _other_paths(model, run):
    """Every path the actions allow (each step: the cell pressed into, or a stay)."""
    paths = [[model.start]]
    for a in run.actions:
        paths = [p + [q] for p in paths for q in sorted({p[-1], int(model.neighbors[p[-1], a])})]
    return paths


@pytest.mark.parametrize("seed", [1, 2, 6])
def test_every_path_of_a_blocking_grid_with_a_cross_footprint_matches_the_brute_force(seed):
    model, run = _blocking_run(seed)
    theta = np.array([0.7, 0.3])
    scored = 0
    for path in _other_paths(model, run):
        want = brute_force(model, path, run.actions, run.observations, theta)
        got = path_log_likelihood(model, path, run.actions, run.observations, theta)
        if want == -math.inf:
            assert got == -math.inf
        else:
            assert got == pytest.approx(want, rel=1e-12, abs=1e-12)
            scored += 1
    assert scored >= 2  # several paths explain the readings: the comparison has something to compare


@pytest.mark.parametrize("seed", [0, 1])
def test_the_paper_model_on_a_corridor_matches_the_brute_force_under_its_own_prior(seed):
    model = om.corridor(4, p_obs=0.85, p_move=0.8)
    run = om.simulate(model, np.array([0, 1, 1, 0]), om.random_walk(model, 6, seed=seed), seed=seed)
    theta = np.asarray(model.label_prior)
    theta = theta[0] if theta.ndim == 2 else theta
    for path in _other_paths(model, run)[:40]:
        want = brute_force(model, path, run.actions, run.observations, theta)
        assert path_log_likelihood(model, path, run.actions, run.observations) == pytest.approx(want, rel=1e-12)


def test_a_path_the_model_rules_out_scores_minus_infinity():
    model, run = _blocking_run(0)
    jump = np.array(run.locations)
    jump[1] = 5 if model.neighbors[jump[0], run.actions[0]] != 5 and jump[0] != 5 else 4  # neither pressed nor stayed
    assert path_log_likelihood(model, jump, run.actions, run.observations) == -math.inf


@pytest.mark.parametrize("frequencies", [[0.5], [np.nan, 1.0], [-0.1, 1.1], [0.0, 0.0]])
def test_bad_frequencies_are_refused(frequencies):
    model, run = _blocking_run(0)
    with pytest.raises(InvalidOptionError, match="frequencies"):
        path_log_likelihood(model, run.locations, run.actions, run.observations, frequencies)


def test_a_dynamic_world_is_refused():
    model = om.corridor(4, p_obs=0.85, p_move=0.8, p_change=0.3)
    run = om.simulate(model, np.array([0, 1, 0, 0]), om.random_walk(model, 4, seed=0), seed=0)
    with pytest.raises(ModelError, match="static"):
        path_log_likelihood(model, run.locations, run.actions, run.observations)
