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


# --- constructors, world specs and options (issue 14 items 9 and 10) ----------------------------------
@pytest.mark.parametrize("build,words", [
    (lambda: om.corridor(1.5), "n_cells must be a whole number"),  # gave 1 cell
    (lambda: om.corridor(8, n_labels=2.5), "n_labels must be a whole number"),  # gave 2
    (lambda: om.grid_model(2.7, 3.9), "rows must be a whole number"),  # gave 2 x 3
    (lambda: om.corridor(None), "n_cells must be an integer, got NoneType"),
    (lambda: om.corridor("8"), "n_cells must be an integer, got str"),
    (lambda: om.corridor(8, p_obs=float("nan")), "p_obs must be in"),
    (lambda: om.corridor(8, p_move=float("inf")), "p_move must be in"),
    (lambda: om.corridor(8, p_obs="0.9"), "p_obs must be a number"),
    (lambda: om.corridor(10**30), "n_cells must be at most"),  # OverflowError / MemoryError before
    (lambda: om.grid_model(10**5, 10**5), "at most"),
    (lambda: om.grid_model(2, 2, label_names=["a", "a"]), "label_names must be distinct"),
    (lambda: om.grid_model(2, 2, label_prior=[[0.5, 0.5], [1.0]]), "label_prior must be a rectangular table"),
    (lambda: om.grid_model(2, 2, sensor=[["a", "b"], ["c", "d"]]), "sensor matrix O must be a rectangular"),
    (lambda: om.grid_model(2, 2, change=None, sensor=[[1, 0], [0, None]]), "sensor matrix O"),
    (lambda: om.grid_model(2, 3, n_labels=1), "n_labels must be at least 2"),  # ZeroDivisionError before
    (lambda: om.door_world(12345), "layout must be a str"),
    (lambda: om.corridor(8, start=2.5), "start must be a whole number"),
])
def test_constructors_refuse_instead_of_coercing(build, words):
    with pytest.raises(om.ModelError, match=words):
        build()


def test_integral_values_of_other_types_are_accepted():
    assert om.corridor(8.0).n_cells == 8 and om.corridor(np.int64(5), n_labels=np.int32(3)).n_labels == 3
    assert om.grid_model(2, 3, label_names=("a", "b")).label_names == ("a", "b")


@pytest.mark.parametrize("spec,words", [
    ("corridor:8,p_obs=abc", "p_obs must be a number"),
    ("grid:2x3,n_labels=1", "n_labels must be at least 2"),
    ("grid:3x3x", "cols must be a whole number"),
    ("grid:3", "a grid's size is RxC"),
    ("corridor:99999999999999999", "whole number"),
    ("corridor:-4", "whole number"),
    ("corridor:8,p_obs=nan", "p_obs must be in"),
    ("corridor:8,p_obs=0.9,p_obs=0.8", "given twice"),
    ("corridor:8,n_labels=2.5", "n_labels must be a whole number"),
    ("grid:3x3,blocking=\u0661", "unknown blocking label '\u0661'"),  # an Arabic-Indic 1 was label 1 (issue 24 item 11)
    ("grid:3x3,blocking=\u00b9", "unknown blocking label '\u00b9'"),  # a superscript 1: a raw ValueError
])
def test_world_specs_refuse_with_one_clear_error(spec, words):
    from onlinemap.worlds import parse_world

    with pytest.raises(om.ModelError, match=words):
        parse_world(spec)


@pytest.mark.parametrize("name,options,words", [
    ("offline_em", {"n_iter": 1.5}, "n_iter must be a whole number"),  # became 1
    ("offline_em", {"anneal": (1.0, "0.5", 0.1)}, "anneal\\[1\\] must be a number"),
    ("online_em", {"decay": "0.5"}, "decay must be a number"),  # was accepted
    ("online_em", {"window": None}, "window"),
    ("online_em", {"window": 2.5}, "window"),
    ("online_em", {"pseudo_count": None}, "pseudo_count must be a number"),
    ("rbpf", {"n_particles": "abc"}, "n_particles must be an integer"),
    ("rbpf", {"seed": -1}, "seed must be at least 0"),
    ("rbpf", {"lazy_dynamics": "no"}, "lazy_dynamics must be True or False"),
    ("rbpf", {"resampling": ["residual"]}, "resampling must be one of"),
    ("rbpf", {"resample_threshold": float("nan")}, "resample_threshold must be in"),
])
def test_options_refuse_with_option_errors(name, options, words):
    with pytest.raises(om.InvalidOptionError, match=words):
        om.make_estimator(name, om.corridor(4), **options)


def test_fraction_action_is_an_index_or_a_specific_error():
    """Regression: a fractions.Fraction action raised a bare TypeError."""
    from fractions import Fraction

    est = warmed("exact")
    assert est.step(Fraction(1, 1), 0).t == 2
    snap = snapshot(est)
    with pytest.raises(om.InvalidActionError, match="whole number"):
        est.step(Fraction(3, 2), 0)
    assert_same(est, snap)


@pytest.mark.parametrize("n_actions", [0, 3, 5])
def test_run_estimator_refuses_lengths_that_do_not_fit_naming_both(n_actions):
    """Regression (issue 24 item 18): a length mismatch raised a bare ValueError."""
    est = om.make_estimator("exact", om.corridor(4))
    before = estimator_cases.snapshot(est)
    with pytest.raises(om.InvalidActionError, match=f"5 observations need 4 actions, got {n_actions}"):
        om.run_estimator(est, [1] * n_actions, [0] * 5)
    estimator_cases.assert_state_unchanged(est, before)
    with pytest.raises(om.InvalidObservationError, match="at least one observation"):
        om.run_estimator(est, [], [])
    with pytest.raises(om.InvalidObservationError, match="observations must be a sequence"):
        om.run_estimator(est, [], iter([0]))
    estimator_cases.assert_state_unchanged(est, before)


def _refusals(calls):
    """(error type, message) of each call; a call that returns is a test failure."""
    found = []
    for call in calls:
        with pytest.raises(om.OnlineMapError) as info:
            call()
        found.append((type(info.value), str(info.value)))
    return found


def test_step_counts_are_whole_numbers_that_fit_in_memory():
    """Issue 43 section 2 item 6: ``om.simulate(..., steps=10**12)``, ``om.random_walk(m, 10**12)``
    / ``(m, -5)`` and ``policies.explore(..., steps=10**8)`` / NaN raised raw ``MemoryError`` /
    ``ValueError``; ``steps=2.5`` and ``'10'`` were accepted silently. Refused before anything
    is allocated: MemoryLimitError beyond this machine's memory (the bytes named), ModelError
    for a count that is not a whole number >= the minimum."""
    import policies
    from onlinemap.arguments import machine_memory

    model = om.grid_model(3, 3, 2)
    true_map = om.sample_map(model, 0)
    huge = [lambda: om.random_walk(model, 10**12), lambda: om.simulate(model, true_map, steps=10**12),
            lambda: policies.explore(model, true_map, "random", "bk", steps=10**12, seed=0)]
    if machine_memory() is not None:  # where the memory is unknown, no count is too large to try
        for kind, message in _refusals(huge):
            assert kind is om.MemoryLimitError and "1,000,000,000,000" in message and "GiB" in message, message
    bad = [lambda: om.random_walk(model, -5), lambda: om.random_walk(model, 2.5), lambda: om.random_walk(model, "10"),
           lambda: om.simulate(model, true_map, steps=2.5), lambda: om.simulate(model, true_map, steps="10"),
           lambda: om.simulate(model, true_map, steps=0), lambda: om.simulate(model, true_map, steps=float("nan")),
           lambda: policies.explore(model, true_map, "random", "bk", steps=float("nan"), seed=0),
           lambda: policies.explore(model, true_map, "random", "bk", steps=2.5, seed=0),
           lambda: policies.explore(model, true_map, "random", "bk", steps="10", seed=0)]
    expected = ["at least 0, got -5", "whole number, got 2.5", "integer, got str '10'", "whole number, got 2.5",
                "integer, got str '10'", "at least 1, got 0", "whole number, got nan", "whole number, got nan",
                "whole number, got 2.5", "integer, got str '10'"]
    for (kind, message), words in zip(_refusals(bad), expected):
        assert issubclass(kind, om.ModelError) and words in message, message  # InvalidOptionError for a planner loop's steps
    # whole numbers of any type still run, as before
    assert om.random_walk(model, 4.0, seed=1).tolist() == om.random_walk(model, np.int64(4), seed=1).tolist()
    assert om.simulate(model, true_map, steps=np.int32(3), seed=2).n_steps == 3
