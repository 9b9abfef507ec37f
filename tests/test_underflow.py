"""Observations of tiny but positive probability (issue 14 item 2): every estimator stays valid,
or refuses the observation as impossible and changes nothing. Never ``1/norm = inf``, a belief
of NaN, or an estimator that refuses everything afterwards.

Reference for the exact filter: brute-force enumeration of the joint (tests/oracles.py) carried
in log space, so that it does not underflow where the filter must not either.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.special import logsumexp

import onlinemap as om
from onlinemap.checkpoint import first_difference
from estimator_cases import NAMES, assert_valid_belief
from oracles import BruteForce

TINY_WORLDS = {  # 2-cell corridors where z = 1 is (nearly) explained by label 1 only
    "sensor-1e-300": dict(sensor=[[1, 0], [1 - 1e-300, 1e-300]]),
    "sensor-1e-310 (subnormal)": dict(sensor=[[1, 0], [1, 1e-310]]),
    "prior-1e-300": dict(sensor=[[0.9, 0.1], [0.1, 0.9]], label_prior=[1 - 1e-300, 1e-300]),
    "sensor-and-prior-1e-300": dict(sensor=[[1, 0], [1 - 1e-300, 1e-300]], label_prior=[1 - 1e-300, 1e-300]),
    "column-1e-300": dict(sensor=[[1 - 1e-300, 1e-300], [1 - 1e-300, 1e-300]]),
}
OBSERVATIONS = [1, 1, 0, 1, 1, 1, 0, 0, 1, 1]  # the unlikely observation first, and again and again


def tiny_world(kind):
    return om.grid_model(1, 2, 2, p_move=0.5, **TINY_WORLDS[kind])


def log_space_filter(model, actions, observations):
    """Brute-force filtering in log space: per step (location (N,), map (N, K), log evidence)."""
    oracle = BruteForce.of(model)
    with np.errstate(divide="ignore"):
        log_prior = np.array([sum(np.log(model.label_prior[i, m[i]]) for i in range(oracle.n)) if l == model.start
                              else -np.inf for l, m in oracle.states])
        log_sensor = np.log(np.array(model.sensor))
        log_trans = {a: np.log(oracle.transition(a)) for a in range(model.n_actions)}
    log_p, log_evidence, out = log_prior, 0.0, []
    for t, z in enumerate(observations):
        if t > 0:
            log_p = logsumexp(log_p[:, None] + log_trans[actions[t - 1]], axis=0)
        log_p = log_p + np.array([log_sensor[m[l], z] for l, m in oracle.states])
        total = logsumexp(log_p)
        log_evidence += total
        log_p = log_p - total
        out.append((*oracle.marginals(np.exp(log_p)), log_evidence))
    return out


@pytest.mark.parametrize("kind", TINY_WORLDS)
def test_exact_matches_log_space_enumeration(kind):
    """Regression: a subnormal total made 1/norm overflow; every later step was refused."""
    model = tiny_world(kind)
    actions = [1, 0] * len(OBSERVATIONS)
    want = log_space_filter(model, actions, OBSERVATIONS)
    est = om.make_estimator("exact", model)
    for t, z in enumerate(OBSERVATIONS):
        belief = est.step(None if t == 0 else actions[t - 1], z)
        location, maps, log_evidence = want[t]
        np.testing.assert_allclose(belief.location, location, rtol=0, atol=1e-9)
        np.testing.assert_allclose(belief.map, maps, rtol=0, atol=1e-9)
        assert math.isclose(belief.log_evidence, log_evidence, rel_tol=1e-9), (t, belief.log_evidence, log_evidence)


def drive(name, model, actions, observations):
    """Every step gives a valid belief, or ImpossibleObservationError with the state unchanged.
    Returns how many steps were refused."""
    est = om.make_estimator(name, model, **({"seed": 0, "n_particles": 50} if name == "rbpf" else {}))
    refused = 0
    for z in observations:
        t = est.t + 1
        before = est.state_dict()
        try:
            belief = est.step(None if t == 0 else actions[t - 1], z)
        except om.ImpossibleObservationError:
            refused += 1
            assert first_difference(before, est.state_dict()) is None
            continue
        assert_valid_belief(belief, model, t, atol=1e-6)
    return refused


@pytest.mark.parametrize("kind", TINY_WORLDS)
@pytest.mark.parametrize("name", NAMES)
def test_every_estimator_stays_valid_on_tiny_probabilities(name, kind):
    """Regression: online EM returned the location [inf, nan] after a first observation of
    probability 1e-310 and refused everything after; offline EM refused every observation of
    probability 1e-300 (messages below 1e-280 were flushed to zero)."""
    refused = drive(name, tiny_world(kind), [1, 0] * len(OBSERVATIONS), OBSERVATIONS)
    # the EM estimators' B = label_prior @ O gives the observation probability 1e-600 = 0 there: refused
    if name in ("exact", "bk", "dead_reckoning") or kind != "sensor-and-prior-1e-300":
        assert refused == 0, f"{name} refused {refused} observations of positive probability"


@pytest.mark.parametrize("name", NAMES)
def test_long_runs_of_unlikely_observations(name):
    """300 steps of a sensor that reports the unlikely label with probability 1e-300 per step:
    the evidence falls far below float64's range (log evidence about -69000); beliefs stay valid."""
    model = om.corridor(4, p_obs=1 - 1e-300, p_move=0.9)
    rng = np.random.default_rng(0)
    steps = 300 if name != "offline_em" else 60  # offline EM refits on the whole run at every step
    refused = drive(name, model, [int(a) for a in rng.integers(2, size=steps)], [1] * steps)
    assert refused == 0


SUBNORMAL_WORLDS = {  # issue 24 item 2: 5-cell corridors whose observation is still subnormal after rescaling
    "sensor-3e-312 at step 1": (dict(sensor=[[1.0, 3e-312], [0.0, 1.0]], label_prior=[1.0, 0.0]), [0, 1]),
    "sensor-3e-312 at step 1, dynamic": (dict(sensor=[[1.0, 3e-312], [0.0, 1.0]], label_prior=[1.0, 0.0],
                                              change=[[1.0, 0.0], [0.5, 0.5]]), [0, 1]),  # 0 never becomes 1
    "sensor-1e-310 at step 0": (dict(sensor=[[1.0, 1e-310], [0.0, 1.0]], label_prior=[1.0, 0.0]), [1]),
    "prior-3e-312": (dict(p_obs=1.0, label_prior=[1.0, 3e-312]), [1]),
    "prior-5e-324": (dict(p_obs=1.0, label_prior=[1.0, 5e-324]), [1]),
}


@pytest.mark.parametrize("kind", SUBNORMAL_WORLDS)
@pytest.mark.parametrize("name", NAMES)
def test_subnormal_predictive_probability_is_refused_or_valid(name, kind):
    """Regression (issue 24 item 2): exact raised a raw OverflowError (``math.ldexp`` raises
    instead of returning inf) when a step's total was still subnormal after dividing the
    likelihood by its maximum, so that the power of two bringing it near 1 overflowed. Exact
    refuses such an observation as impossible (below float64's range), the state unchanged;
    every estimator either refuses so or gives a valid belief."""
    options, observations = SUBNORMAL_WORLDS[kind]
    model = om.grid_model(1, 5, 2, **options)
    refused = drive(name, model, [1] * len(observations), observations)
    if name == "exact":
        assert refused == 1
