"""Learning the label frequencies is what a building or a read floor says (GridModel's
unknown_label_frequencies; onlinemap.label_prior): the flag is set by the worlds that lack a stated
prior and by nothing else, it is part of the model (equality, checkpoints, repr) and leaves older
checkpoints' bytes alone, and the estimators' default label_prior=None follows it where they can
learn (the same run as label_prior="learn"), the model's table elsewhere (the same run as
label_prior="model", which is also the run on the model without the flag)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import onlinemap as om
from onlinemap.checkpoint import decode_model, encode_model
from onlinemap.errors import InvalidOptionError, ModelError
from onlinemap.model import model_difference
from onlinemap.worlds import parse_world
from estimator_cases import beliefs

FLOOR = "type octile\nheight 6\nwidth 12\nmap\n@@@@@@@@@@@@\n@....@.....@\n@....@.....@\n@..........@\n@....@.....@\n@@@@@@@@@@@@\n"


def test_buildings_and_read_floors_leave_their_frequencies_unknown_and_nothing_else_does(tmp_path):
    path = tmp_path / "floor.map"
    path.write_text(FLOOR)
    assert om.building(12, 12, seed=1)[0].unknown_label_frequencies
    assert om.read_layout(path)[0].unknown_label_frequencies
    assert not om.building(12, 12, seed=1, label_prior=[0.4, 0.4, 0.1, 0.1])[0].unknown_label_frequencies
    assert not om.read_layout(path, label_prior=[0.4, 0.4, 0.1, 0.1])[0].unknown_label_frequencies
    for model in (om.door_world()[0], om.corridor(5), om.grid_model(3, 3, 3)):
        assert not model.unknown_label_frequencies
    assert parse_world("building:12x12,seed=1").model.unknown_label_frequencies
    for keys in ("label_prior=uniform", "label_prior=floor", "floor_plan=0.9"):
        world = parse_world(f"building:12x12,seed=1,{keys}")
        assert not world.model.unknown_label_frequencies, keys
    uniform = parse_world("building:12x12,seed=1,label_prior=uniform").model
    np.testing.assert_array_equal(uniform.label_prior, parse_world("building:12x12,seed=1").model.label_prior)
    with pytest.raises(ModelError, match="'uniform'"):
        parse_world("building:12x12,seed=1,label_prior=flat")


def test_the_flag_is_part_of_the_model():
    model = om.building(12, 12, seed=1)[0]
    known = dataclasses.replace(model, unknown_label_frequencies=False)
    assert model_difference(model, known) == "unknown_label_frequencies"
    assert "label frequencies unknown" in repr(model) and "unknown" not in repr(known)
    assert model_difference(decode_model(encode_model(model)), model) is None
    with pytest.raises(ModelError, match="unknown_label_frequencies"):
        dataclasses.replace(model, unknown_label_frequencies=1)


def test_a_model_without_the_flag_encodes_as_before():
    """A checkpoint's model tree of the paper's world names the fields it always had: the bytes
    of its checkpoints (and so the stored ones it is compared with) do not move."""
    fields = encode_model(om.door_world()[0])["fields"]
    assert set(fields) == {"rows", "cols", "neighbors", "p_move", "change", "sensor", "label_prior", "start",
                           "action_names", "label_names", "blocking", "footprint"}
    assert "unknown_label_frequencies" in encode_model(om.building(12, 12, seed=1)[0])["fields"]


def same_run(a, b, run):
    for x, y in zip(beliefs(a, run), beliefs(b, run)):
        np.testing.assert_array_equal(x.map, y.map)
        np.testing.assert_array_equal(x.location, y.location)
        assert x.log_evidence == y.log_evidence


OPTIONS = {"rbpf": {"n_particles": 60, "seed": 2}, "bk": {}}


def building_run(steps=40, **options):
    model, true_map = om.building(12, 12, seed=2, **options)
    return model, om.simulate(model, true_map, om.random_walk(model, steps - 1, seed=3), seed=3)


@pytest.mark.parametrize("name", ["rbpf", "bk"])
def test_on_a_building_the_default_learns_and_model_is_the_uniform_baseline(name):
    model, run = building_run()
    default = om.make_estimator(name, model, **OPTIONS[name])
    same_run(default, om.make_estimator(name, model, label_prior="learn", learn_every=10, **OPTIONS[name]), run)
    assert not np.allclose(default.label_frequencies, 0.25)  # it learned
    assert "label_prior='learn'" in repr(default)
    baseline = om.make_estimator(name, model, label_prior="model", **OPTIONS[name])
    same_run(baseline, om.make_estimator(name, dataclasses.replace(model, unknown_label_frequencies=False),
                                         **OPTIONS[name]), run)
    assert baseline.label_frequencies is None and "_label_frequencies" not in vars(baseline)
    om.make_estimator(name, model, prior_strength=2.0, learn_every=3, **OPTIONS[name])  # they apply to the default


@pytest.mark.parametrize("name", ["rbpf", "bk"])
def test_in_a_building_whose_doors_change_the_default_is_the_fixed_prior(name):
    """The plug-in filters learn in static worlds only: with p_door > 0, None is the model's table
    (the same run as "model"), and an explicit "learn" is refused."""
    model, run = building_run(p_door=0.05)
    assert model.unknown_label_frequencies and not model.is_static
    default = om.make_estimator(name, model, **OPTIONS[name])
    same_run(default, om.make_estimator(name, model, label_prior="model", **OPTIONS[name]), run)
    assert default.label_frequencies is None
    with pytest.raises(InvalidOptionError, match="static world"):
        om.make_estimator(name, model, label_prior="learn")
    with pytest.raises(InvalidOptionError, match="prior_strength"):
        om.make_estimator(name, model, prior_strength=2.0)


def test_the_rbpf_with_resample_move_learns_by_default():
    model, run = building_run(blocking=False, footprint="cell")
    moving = dict(n_particles=60, seed=2, move_window=4, move_every=5, move_lag=0)
    same_run(om.make_estimator("rbpf", model, **moving),
             om.make_estimator("rbpf", model, label_prior="learn", **moving), run)


def test_the_rbpf_learns_every_ten_steps_by_default():
    model, run = building_run(steps=25)
    est = om.make_estimator("rbpf", model, n_particles=60, seed=2)
    seen = []
    for _ in beliefs(est, run):
        seen.append(est.label_frequencies)
    changed = [t for t in range(1, len(seen)) if not np.array_equal(seen[t], seen[t - 1])]
    assert changed == [10, 20]


def test_the_exact_filter_follows_the_model():
    """A tiny grid whose frequencies are unknown: None is the exact hierarchical filter."""
    model = om.grid_model(1, 4, 3, p_obs=0.85, blocking=[2], unknown_label_frequencies=True)
    run = om.simulate(model, np.array([0, 0, 1, 2]), om.random_walk(model, 15, seed=1), seed=1)
    same_run(om.make_estimator("exact", model), om.make_estimator("exact", model, label_prior="learn"), run)
    same_run(om.make_estimator("exact", model, label_prior="model"),
             om.make_estimator("exact", dataclasses.replace(model, unknown_label_frequencies=False)), run)


@pytest.mark.parametrize("name", ["online_em", "offline_em"])
@pytest.mark.parametrize("option", [{"label_prior": "learn"}, {"prior_strength": 2.0}, {"learn_every": 5}])
def test_the_em_estimators_refuse_the_label_prior_options(name, option):
    with pytest.raises(InvalidOptionError, match="parameter"):
        om.make_estimator(name, om.building(12, 12, seed=1)[0], **option)
