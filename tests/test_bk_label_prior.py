"""Boyen-Koller's label prior (onlinemap.estimators.bk; onlinemap.label_prior): without learning every
run is as it was; a fixed vector is BK on a model with that prior; "learn" converges to the
frequencies a world was drawn from (tolerance from the number of cells read); bad options are
refused; a learning filter resumes from its checkpoint bit for bit."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import onlinemap as om
from onlinemap.errors import CheckpointError, InvalidOptionError
from estimator_cases import beliefs, random_run
from test_rbpf_label_prior import assert_learned_near_theta, drawn_world

WORLDS = [
    ("corridor", lambda: om.corridor(8, 3, p_obs=0.8)),
    ("door dynamic", lambda: om.door_world(p_move=0.8, p_door=0.05)[0]),
    ("door blocking cross", lambda: om.door_world(p_move=0.8, blocking=True, footprint="cross")[0]),
]


@pytest.mark.parametrize("name,make", WORLDS, ids=[w[0] for w in WORLDS])
@pytest.mark.parametrize("label_prior", [None, "model"])
def test_without_learning_every_run_is_as_it_was(name, make, label_prior):
    """The reference is BK's update written out here for the paper's sensor (the module's
    docstring), run on the corridor; on the others the options must leave the state untouched."""
    model = make()
    run = random_run(model, 40, seed=3)
    plain = om.make_estimator("bk", model)
    given = om.make_estimator("bk", model, label_prior=label_prior)
    assert "_label_frequencies" not in vars(given) and given.label_frequencies is None
    assert repr(given) == repr(plain) and "label_prior" not in repr(given)
    location, maps = model.location_prior(), np.array(model.label_prior)
    for t, (a, b) in enumerate(zip(beliefs(plain, run), beliefs(given, run))):
        np.testing.assert_array_equal(a.map, b.map)
        np.testing.assert_array_equal(a.location, b.location)
        assert a.log_evidence == b.log_evidence
        if name == "corridor":  # static, one reading of the own cell: q' = q lam / Z, mu' = mu (q O + Z - q lam) / Z
            if t:
                location = om.model.apply_motion(model, location, int(run.actions[t - 1]))
            o = model.sensor[:, int(run.observations[t])]
            lam = maps @ o
            z = float(location @ lam)
            maps = maps * (location[:, None] * o + (z - location * lam)[:, None]) / z
            location = location * lam / z
            np.testing.assert_allclose(b.map, maps, atol=1e-12)
            np.testing.assert_allclose(b.location, location, atol=1e-12)


FIXED = np.array([0.5, 0.3, 0.2])


def test_a_fixed_vector_is_bk_on_a_model_with_that_prior():
    model = om.grid_model(6, 6, 3, p_obs=0.85, p_move=0.8, blocking=[2], footprint="cross")
    with_prior = dataclasses.replace(model, label_prior=FIXED)
    run = random_run(model, 60, seed=2)
    tilted = om.make_estimator("bk", model, label_prior=FIXED)
    reference = om.make_estimator("bk", with_prior)
    np.testing.assert_array_equal(tilted.label_frequencies, FIXED)
    for a, b in zip(beliefs(tilted, run), beliefs(reference, run)):
        np.testing.assert_allclose(a.map, b.map, atol=1e-12)
        np.testing.assert_allclose(a.location, b.location, atol=1e-12)


@pytest.mark.parametrize("seed", [1, 3, 4])
def test_learned_frequencies_converge_to_those_the_world_was_drawn_from(seed):
    """As the RBPF's test (test_rbpf_label_prior): ``|learned - theta| <= 4 sqrt(theta (1 - theta) / n)
    + e + A / (A + n)``, n the cells read, e the belief's mass off the true labels of the read
    cells (the expected counts differ from the true ones by at most e n), A = K the Dirichlet's
    total pseudo-count. Labels drawn i.i.d. from theta; BK learns every 10 steps (the default).
    Motion never slips (p_move 1, nothing blocks): BK's location stays exact and its map is each
    cell's posterior under the plug-in prior, so e is small (measured 0.006-0.012); with slips BK's
    factored map is too poor (e about 0.45) for the bound to tell learning from not learning."""
    theta = np.array([0.6, 0.3, 0.1])
    model = om.grid_model(15, 15, 3, p_obs=0.9, p_move=1.0, footprint="cross")
    rng = np.random.default_rng(seed)
    labels = rng.choice(3, size=model.n_cells, p=theta)
    run = om.simulate(model, labels, om.random_walk(model, 799, rng), rng)
    est = om.make_estimator("bk", model, label_prior="learn")
    for belief in beliefs(est, run):
        pass
    assert_learned_near_theta(model, labels, theta, est.label_frequencies, belief.map)


def test_learning_improves_the_map_of_a_world_drawn_from_a_skewed_prior():
    """On a world drawn from theta = (0.8, 0.15, 0.05) the cells BK has not read well are better
    guessed with the learned frequencies: the mean probability of the true label over all cells
    is higher with learning than with the uniform prior (each unread cell alone: 0.8 against 1/3)."""
    model, labels, run = drawn_world(15, 15, np.array([0.8, 0.15, 0.05]), [2], 5, steps=300)
    finals = {}
    for label_prior in ("learn", None):
        for belief in beliefs(om.make_estimator("bk", model, label_prior=label_prior), run):
            pass
        finals[label_prior] = float(belief.map[np.arange(model.n_cells), labels].mean())
    assert finals["learn"] > finals[None] + 0.1, finals


BAD = [
    ({"label_prior": "lern"}, "label_prior"),
    ({"label_prior": "fixed"}, "'model'"),
    ({"label_prior": [0.5, 0.5]}, "one frequency per label"),
    ({"prior_strength": 2.0}, "prior_strength"),
    ({"learn_every": 5}, "learn_every"),
    ({"label_prior": "model", "learn_every": 5}, "learn_every"),
    ({"label_prior": "learn", "learn_every": 0}, "learn_every"),
    ({"label_prior": "learn", "learn_every": 2.5}, "learn_every"),
]


@pytest.mark.parametrize("options,words", BAD, ids=[str(b[0]) for b in BAD])
def test_bad_options_are_refused_naming_the_problem(options, words):
    with pytest.raises(InvalidOptionError, match=words):
        om.make_estimator("bk", om.grid_model(1, 4, 3), **options)


def test_learning_is_refused_in_a_dynamic_world():
    model = om.door_world(p_door=0.05)[0]
    with pytest.raises(InvalidOptionError, match=r"static world.*C = I"):
        om.make_estimator("bk", model, label_prior="learn")


@pytest.mark.parametrize("bad", [np.array([0.5, 0.5, 0.5]), np.array([1.0, 0.0, 0.0]), np.array([0.5, 0.5])])
def test_a_checkpoint_with_broken_frequencies_is_refused(bad):
    model, _, run = drawn_world(8, 8, [0.6, 0.3, 0.1], [2], seed=2, steps=10)
    est = om.make_estimator("bk", model, label_prior="learn")
    for _ in beliefs(est, run):
        pass
    est._label_frequencies = bad
    with pytest.raises(CheckpointError, match="_label_frequencies"):
        type(est).check_state(est)
