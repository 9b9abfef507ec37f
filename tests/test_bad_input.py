"""Bad input: a specific error naming the problem, and the estimator's state unchanged."""

import numpy as np
import pytest

import estimator_cases
import onlinemap as om

ESTIMATORS = ["exact", "dead_reckoning"]


def snapshot(est):
    """Every attribute (estimator_cases.snapshot) and the current belief, copied."""
    b = est.belief
    return estimator_cases.snapshot(est), est.t, b.location.copy(), b.map.copy(), b.log_evidence


def assert_same(est, snap):
    state, t, loc, maps, log_ev = snap
    estimator_cases.assert_state_unchanged(est, state)
    assert est.t == t
    np.testing.assert_array_equal(est.belief.location, loc)
    np.testing.assert_array_equal(est.belief.map, maps)
    assert est.belief.log_evidence == log_ev or (np.isnan(log_ev) and np.isnan(est.belief.log_evidence))


def warmed(name, model=None):
    model = model or om.corridor(5, p_obs=0.9)
    est = om.make_estimator(name, model)
    est.step(None, 0)
    est.step(1, 1)
    return est


@pytest.mark.parametrize("name", ESTIMATORS)
@pytest.mark.parametrize("action,observation,error,match", [
    (2, 0, om.InvalidActionError, "out of range"),
    (-1, 0, om.InvalidActionError, "out of range"),
    ("up", 0, om.InvalidActionError, "unknown action name"),
    (None, 0, om.InvalidActionError, "needs an action"),
    (float("nan"), 0, om.InvalidActionError, "nan"),
    (0.5, 0, om.InvalidActionError, "whole number"),
    (np.array([0, 1]), 0, om.InvalidActionError, "int index"),
    (True, 0, om.InvalidActionError, "int index"),
    (1, 2, om.InvalidObservationError, "out of range"),
    (1, float("nan"), om.InvalidObservationError, "nan"),
    (1, "door", om.InvalidObservationError, "unknown observation name"),
    (1, [0], om.InvalidObservationError, "int index"),
])
def test_bad_step_raises_and_keeps_state(name, action, observation, error, match):
    est = warmed(name)
    snap = snapshot(est)
    with pytest.raises(error, match=match):
        est.step(action, observation)
    assert_same(est, snap)
    est.step(0, 0)  # still usable
    assert est.t == snap[1] + 1


@pytest.mark.parametrize("name", ESTIMATORS)
def test_action_at_first_step_is_refused(name):
    est = om.make_estimator(name, om.corridor(4))
    with pytest.raises(om.InvalidActionError, match="first step"):
        est.step(1, 0)
    assert est.t == -1 and est.belief is None
    assert est.step(None, "0").t == 0  # names work too


def test_impossible_observation_keeps_state():
    model = om.corridor(3, p_obs=1.0, p_move=1.0)  # noiseless sensor, no slips
    est = om.make_estimator("exact", model)
    est.step(None, 1)
    est.step("left", 1)  # cell 0 again: must still read 1
    snap = snapshot(est)
    with pytest.raises(om.ImpossibleObservationError, match="probability zero"):
        est.step("left", 0)
    assert_same(est, snap)


def test_dynamic_impossible_observation_keeps_state():
    # every cell starts as 1; a 1 may become 0, a 0 never becomes 1; noiseless sensor, no slips
    model = om.grid_model(1, 3, 2, p_obs=1.0, p_move=1.0, change=[[1, 0], [0.5, 0.5]], label_prior=[0, 1])
    est = om.make_estimator("exact", model)
    est.step(None, 1)
    est.step("right", 0)  # cell 1 changed to 0: possible
    est.step("right", 1)  # cell 2 still 1: possible
    snap = snapshot(est)
    with pytest.raises(om.ImpossibleObservationError):
        est.step("left", 1)  # cell 1 read 0, and 0 never becomes 1
    assert_same(est, snap)
    assert est.step("left", 0).t == 3


def test_unknown_estimator_and_option():
    with pytest.raises(om.UnknownEstimatorError, match="available"):
        om.make_estimator("kalman", om.corridor(4))
    with pytest.raises(om.UnknownEstimatorError, match="no option 'n_particles'"):
        om.make_estimator("exact", om.corridor(4), n_particles=3)
    with pytest.raises(om.ModelError, match="model must be a GridModel"):
        om.make_estimator("exact", "corridor")
