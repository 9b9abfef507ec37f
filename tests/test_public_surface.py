"""Hostile values over the whole public surface (issue 14, "make it hold"): model constructors,
world specs, estimator options, step inputs, checkpoint loading. Hypothesis draws random models,
options and inputs mixing plausible values with hostile ones (NaN, infinities, subnormals,
huge and negative ints, bools, strings, Fractions, None, ragged and non-numeric tables).

Properties: only :class:`onlinemap.OnlineMapError` subclasses escape; an accepted value gives
a working object; a refused step changes nothing (the whole state, random generator included).
Reproducible by default (``derandomize``); ``ONLINEMAP_HYPOTHESIS=explore`` searches afresh.
"""

from __future__ import annotations

import fractions
import math
import os

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

import onlinemap as om
from onlinemap.checkpoint import first_difference
from onlinemap.worlds import parse_world
from estimator_cases import NAMES, assert_valid_belief

settings.register_profile("surface-ci", max_examples=40, deadline=None, derandomize=True, print_blob=True,
                          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
settings.register_profile("surface-explore", max_examples=1000, deadline=None, print_blob=True,
                          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
PROFILE = "surface-explore" if os.environ.get("ONLINEMAP_HYPOTHESIS") == "explore" else "surface-ci"

HOSTILE = st.one_of(
    st.none(), st.booleans(), st.sampled_from([-1, 0, 2**63, -2**63, 10**30, 2**64 + 1]),
    st.floats(allow_nan=True, allow_infinity=True, allow_subnormal=True),
    st.sampled_from([math.nan, math.inf, -math.inf, 5e-324, -0.0, 1e308, 1.5, 0.5]),
    st.text(max_size=4), st.sampled_from(["0.5", "3", "nan", "max", ""]),
    st.fractions(max_denominator=4).filter(lambda f: abs(f) < 10),
    st.sampled_from([np.float32(0.5), np.int64(3), np.uint8(2), np.bool_(True), np.float64(np.nan), 1 + 0j]),
    st.lists(st.integers(0, 3), max_size=3), st.just(np.arange(3)), st.just({"a": 1}), st.just(b"1"),
)
SIZE = st.one_of(st.integers(1, 5), HOSTILE)
PROB = st.one_of(st.floats(0, 1), HOSTILE)
TABLE = st.one_of(
    st.none(), HOSTILE,
    st.lists(st.lists(st.one_of(st.floats(0, 1), HOSTILE), min_size=1, max_size=3), max_size=3),  # maybe ragged
    st.integers(1, 3).flatmap(lambda k: st.lists(st.lists(st.floats(0, 1), min_size=k, max_size=k),
                                                 min_size=k, max_size=k)),
    st.sampled_from([np.eye(2), np.full((2, 2), 0.5), np.array([[1.0, np.nan], [0, 1]]), np.ones((2, 3)) / 3,
                     np.array([["a", "b"], ["c", "d"]]), np.array([[0.5, 0.5], [0.5, 0.5]], dtype=np.float32)]),
)
NAMES_ARG = st.one_of(st.none(), HOSTILE, st.lists(st.one_of(st.text(max_size=2), HOSTILE), max_size=3))


def only_onlinemap_errors(build):
    """``build()``, returning its value, or None if it raised an OnlineMapError; any other
    exception fails the test."""
    try:
        return build()
    except om.OnlineMapError as error:
        assert str(error), "an error must say what is wrong"
        return None


@settings(settings.get_profile(PROFILE))
@given(n=SIZE, k=SIZE, p_obs=PROB, p_move=PROB, p_change=PROB, start=SIZE)
def test_corridor_refuses_with_model_errors(n, k, p_obs, p_move, p_change, start):
    model = only_onlinemap_errors(lambda: om.corridor(n, k, p_obs, p_move, p_change, start))
    if model is not None:  # accepted: the values were what they look like, never truncated
        assert model.n_cells == n and model.n_labels == k and model.start == start


@settings(settings.get_profile(PROFILE))
@given(rows=SIZE, cols=SIZE, k=SIZE, p_obs=PROB, change=TABLE, sensor=TABLE, prior=TABLE, start=SIZE,
       label_names=NAMES_ARG)
def test_grid_model_refuses_with_model_errors(rows, cols, k, p_obs, change, sensor, prior, start, label_names):
    model = only_onlinemap_errors(lambda: om.grid_model(rows, cols, k, p_obs=p_obs, change=change, sensor=sensor,
                                                        label_prior=prior, start=start, label_names=label_names))
    if model is not None:
        assert (model.rows, model.cols, model.n_labels) == (rows, cols, k)
        assert len(set(model.label_names)) == k


@settings(settings.get_profile(PROFILE))
@given(layout=st.one_of(HOSTILE, st.text(alphabet=".#oc\nx", max_size=30)), p_door=PROB, start=st.one_of(st.none(), SIZE))
def test_door_world_refuses_with_model_errors(layout, p_door, start):
    only_onlinemap_errors(lambda: om.door_world(layout, p_door=p_door, start=start))


@settings(settings.get_profile(PROFILE))
@given(rows=st.one_of(st.integers(8, 20), HOSTILE), cols=st.one_of(st.integers(8, 20), HOSTILE),
       seed=st.one_of(st.integers(0, 3), HOSTILE), room_size=st.one_of(st.tuples(SIZE, SIZE), HOSTILE),
       width=SIZE, extra=PROB, start=st.one_of(st.none(), SIZE))
def test_building_refuses_with_model_errors(rows, cols, seed, room_size, width, extra, start):
    built = only_onlinemap_errors(lambda: om.building(rows, cols, seed=seed, room_size=room_size, corridor_width=width,
                                                      extra_doors=extra, start=start))
    if built is not None:
        assert built[0].shape == (rows, cols)


WORLD_TEXT = st.one_of(
    st.text(max_size=30),
    st.tuples(st.sampled_from(["corridor", "grid", "door", "building", "layout", "maze", ""]), st.sampled_from(["", ":"]),
              st.one_of(st.text(alphabet="0123456789x-.e", max_size=8), st.sampled_from(["8", "2x3", "3x3x", "10**9", "12x10"])),
              st.lists(st.tuples(st.sampled_from(["p_obs", "p_move", "p_change", "p_door", "n_labels", "start", "seed", "extra_doors", "cell_size", "zz"]),
                                 st.sampled_from(["0.5", "abc", "nan", "inf", "-1", "1", "2.5", "", "1e400"])),
                       max_size=3))
    .map(lambda p: p[0] + p[1] + p[2] + "".join(f",{key}={value}" for key, value in p[3])),
)


@settings(settings.get_profile(PROFILE))
@given(spec=WORLD_TEXT)
def test_world_specs_refuse_with_model_errors(spec):
    only_onlinemap_errors(lambda: parse_world(spec))


def small_model(name):
    return om.corridor(3, p_change=0.05) if name == "exact" else om.grid_model(2, 2, 3)


@pytest.mark.parametrize("name", NAMES)
def test_options_refuse_with_option_errors(name):
    options = list(om.estimator_options(name))

    @settings(settings.get_profile(PROFILE))
    @given(values=st.fixed_dictionaries({}, optional={option: HOSTILE for option in options}))
    def check(values):
        est = only_onlinemap_errors(lambda: om.make_estimator(name, small_model(name), **values))
        if est is not None:
            assert_valid_belief(est.step(None, 0), est.model, 0)

    if options:
        check()


STEP_VALUE = st.one_of(st.integers(0, 3), HOSTILE)


@pytest.mark.parametrize("name", NAMES)
def test_hostile_steps_change_nothing(name):
    """Every step input drawn from plausible and hostile values: a valid belief, or a specific
    error with the whole state unchanged."""

    @settings(settings.get_profile(PROFILE))
    @given(steps=st.lists(st.tuples(STEP_VALUE, STEP_VALUE), min_size=1, max_size=8))
    def check(steps):
        est = om.make_estimator(name, small_model(name), **({"seed": 1, "n_particles": 20} if name == "rbpf" else {}))
        for action, observation in steps:
            action = None if est.t < 0 and isinstance(action, int) else action
            before = est.state_dict()
            try:
                belief = est.step(action, observation)
            except om.OnlineMapError as error:
                assert isinstance(error, (om.InvalidActionError, om.InvalidObservationError,
                                          om.ImpossibleObservationError)), repr(error)
                assert first_difference(before, est.state_dict()) is None
                continue
            assert_valid_belief(belief, est.model, est.t)

    check()


def test_make_estimator_and_load_refuse_bad_arguments(tmp_path):
    for bad in (None, "kalman", 3, ["exact"]):
        with pytest.raises(om.UnknownEstimatorError):
            om.make_estimator(bad, om.corridor(3))
        with pytest.raises(om.ModelError, match="must be a GridModel"):
            om.make_estimator("exact", bad)
    for content in (b"", b"PK\x03\x04", os.urandom(64)):
        (tmp_path / "x.npz").write_bytes(content)
        with pytest.raises(om.CheckpointError):
            om.load(tmp_path / "x.npz")
    with pytest.raises(om.CheckpointError, match="not a regular file"):
        om.load(tmp_path)
    with pytest.raises(om.OnlineMapError):
        om.make_estimator("exact", om.corridor(3), **{"max_bytes": fractions.Fraction(1, 2)})


@pytest.mark.parametrize("name", NAMES)
def test_estimator_options_show_the_defaults_the_estimator_runs(name):
    """Issue 42 item 7: ``om.estimator_options("rbpf")`` showed ``resampling: None``, a
    placeholder; the filter runs Fearnhead-Clifford (the class docstring's default with the
    optimal proposal). No option shows None where the estimator resolves it, and building with
    the listed defaults runs, step for step, as building with none."""
    options = om.estimator_options(name)
    if name == "rbpf":
        assert options["resampling"] == "fearnhead_clifford" and options["proposal"] == "optimal"
    model = small_model(name)
    seeded = {"seed": 3} if "seed" in options else {}
    plain = om.make_estimator(name, model, **seeded)
    listed = om.make_estimator(name, model, **{**options, **seeded})
    shown = getattr(plain, "effective_options", plain.options)
    assert shown == getattr(listed, "effective_options", listed.options)
    assert all(shown[key] == value for key, value in options.items() if key in shown and key != "seed")
    run = om.simulate(model, om.sample_map(model, 0), om.random_walk(model, 6, seed=1), seed=1)
    a, b = om.run_estimator(plain, run.actions, run.observations), om.run_estimator(listed, run.actions, run.observations)
    assert a.location.tobytes() == b.location.tobytes() and a.map.tobytes() == b.map.tobytes()
