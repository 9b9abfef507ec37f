"""The simulator against the model's probabilities, with binomial tolerances."""

import numpy as np
import pytest

import onlinemap as om
from estimator_cases import binomial_ok


def test_slip_frequency_matches_p_move():
    model = om.grid_model(5, 5, 2, p_move=0.7)
    run = om.simulate(model, None, om.random_walk(model, 20000, seed=1), seed=2)
    before = run.locations[:-1]
    possible = model.neighbors[before, run.actions] != before
    moved = run.locations[1:] != before
    assert binomial_ok(moved[possible].sum(), possible.sum(), 0.7)
    assert np.all(~moved[~possible])  # off-grid moves always stay
    assert run.slipped.sum() == (possible & ~moved).sum()


def test_observation_noise_and_map_changes():
    model = om.corridor(6, 3, p_obs=0.8, p_change=0.05)
    run = om.simulate(model, None, om.random_walk(model, 20000, seed=3), seed=4)
    seen_right = run.observations == run.maps[np.arange(run.n_steps), run.locations]
    assert binomial_ok(seen_right.sum(), run.n_steps, 0.8)
    changes = (run.maps[1:] != run.maps[:-1]).sum()
    assert binomial_ok(changes, (run.n_steps - 1) * 6, 0.05)


def test_same_seed_same_run_and_generators_are_used():
    model = om.corridor(8, p_change=0.1)
    a = om.simulate(model, None, om.random_walk(model, 50, seed=7), seed=9)
    b = om.simulate(model, None, om.random_walk(model, 50, seed=7), seed=9)
    np.testing.assert_array_equal(a.observations, b.observations)
    np.testing.assert_array_equal(a.maps, b.maps)
    state = np.random.get_state()[1].copy()
    om.simulate(model, None, [1, 1, 0], seed=np.random.default_rng(0))
    np.testing.assert_array_equal(np.random.get_state()[1], state)  # global state untouched


def test_run_frame_and_there_and_back():
    model = om.corridor(4)
    actions = om.there_and_back(model)
    np.testing.assert_array_equal(actions, [1, 1, 1, 0, 0, 0])
    run = om.simulate(model, [0, 1, 0, 1], ["right", "left"], seed=0)
    frame = run.to_frame()
    assert list(frame.columns[:5]) == ["t", "action", "true_location", "true_label", "observation"]
    assert len(frame) == 3 and frame.action.iloc[1] == "right"
    with pytest.raises(om.ModelError):
        om.there_and_back(om.grid_model(2, 2))
    with pytest.raises(om.InvalidActionError):
        om.simulate(model, None, ["up"])
    with pytest.raises(om.ModelError):
        om.simulate(model, [0, 1, 2, 0])


def test_murphy_corridor_is_the_scripted_run():
    run = om.scenarios.murphy_corridor()
    np.testing.assert_array_equal(run.locations, [0, 1, 2, 3, 3, 4, 5, 6, 5, 4, 3, 2, 1, 0, 0])
    np.testing.assert_array_equal(run.actions, [1] * 7 + [0] * 7)
    np.testing.assert_array_equal(run.observations, [0, 1, 0, 1, 1, 0, 1, 0, 1, 0, 1, 0, 1, 0, 0])
    assert run.slipped.tolist() == [False, False, False, True] + [False] * 10


@pytest.mark.parametrize("footprint", [None, "cross"])
def test_run_steps_feed_a_step_loop_exactly_as_run_estimator_does(footprint):
    """Issue 24 item 18: a helper yields the (action, observation) pairs of a ``step`` loop."""
    model = om.grid_model(3, 3, 2, footprint=footprint)
    run = om.simulate(model, None, om.random_walk(model, 12, seed=1), seed=2)
    pairs = list(run.steps())
    assert len(pairs) == run.n_steps and pairs[0][0] is None
    assert [a for a, _ in pairs[1:]] == run.actions.tolist() and all(type(a) is int for a, _ in pairs[1:])
    assert all(np.array_equal(z, run.observations[t]) for t, (_, z) in enumerate(pairs))
    est = om.make_estimator("exact", model)
    beliefs = [est.step(a, z) for a, z in run.steps()]
    reference = om.run_estimator(om.make_estimator("exact", model), run.actions, run.observations)
    np.testing.assert_array_equal(np.stack([b.location for b in beliefs]), reference.location)
