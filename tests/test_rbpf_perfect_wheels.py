"""Perfect wheels (``p_move = 1``) with blocking labels: a press whose outcome the parent's map
rules out (a failed press into a cell surely passable) is a child of probability zero, not a
division by zero (issue 43, section 2, item 1)."""

from __future__ import annotations

import numpy as np

import onlinemap as om


def test_the_minimal_case_steps_and_matches_exact_bayes():
    model = om.grid_model(2, 2, 3, blocking=[0], p_move=1.0)
    steps = [(None, 0), (1, 1), (2, 0), (0, 0), (3, 2), (1, 1)]
    rbpf = om.make_estimator("rbpf", model, n_particles=256, seed=0)  # room for every child: exact
    exact = om.make_estimator("exact", model)
    for action, observation in steps:
        got, want = rbpf.step(action, observation), exact.step(action, observation)
        np.testing.assert_allclose(got.location, want.location, atol=1e-12)
        np.testing.assert_allclose(got.map, want.map, atol=1e-12)
    assert rbpf.recoveries == 0


def test_runs_drawn_from_the_model_with_perfect_wheels_never_die():
    for model, true_map in (om.door_world(blocking=True, footprint="cross", p_move=1.0),
                            om.building(16, 16, seed=0, p_move=1.0)):
        for seed in range(3):
            run = om.simulate(model, true_map, om.random_walk(model, 120, seed=seed), seed=seed)
            est = om.make_estimator("rbpf", model, n_particles=30, seed=seed)
            trajectory = om.run_estimator(est, run.actions, run.observations)
            assert np.all(np.isfinite(trajectory.location)) and est.recoveries == 0
