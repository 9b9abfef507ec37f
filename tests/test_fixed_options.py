"""Public attributes that a checkpoint records are validated when assigned, so that no assignment
writes a checkpoint that cannot be loaded (issue 43, section 2, item 11)."""

from __future__ import annotations

import numpy as np
import pytest

import onlinemap as om


@pytest.fixture
def rbpf():
    model = om.corridor(6)
    est = om.make_estimator("rbpf", model, n_particles=8, seed=0, move_window=3)
    est.step(None, 0)
    est.step(1, 1)
    return est


@pytest.mark.parametrize("attribute, value", [("n_particles", 7), ("move_window", 50), ("move_every", 0),
                                              ("move_lag", 3), ("proposal", "transition"), ("resampling", "residual"),
                                              ("resample_threshold", 0.2), ("lazy_dynamics", False)])
def test_an_option_that_sizes_the_state_is_fixed_once_built(rbpf, attribute, value, tmp_path):
    before = getattr(rbpf, attribute)
    with pytest.raises(om.InvalidOptionError, match=f"{attribute} is fixed when the rbpf estimator is built"):
        setattr(rbpf, attribute, value)
    assert getattr(rbpf, attribute) == before
    om.save(rbpf, tmp_path / "robot.npz")  # what was saved loads and steps as the original does
    loaded = om.load(tmp_path / "robot.npz")
    np.testing.assert_array_equal(loaded.step(1, 0).map, rbpf.step(1, 0).map)


@pytest.mark.parametrize("value", [0, 1, "yes", None, 0.0])
def test_recover_from_depletion_takes_only_a_bool(rbpf, value):
    with pytest.raises(om.InvalidOptionError, match="recover_from_depletion must be True or False"):
        rbpf.recover_from_depletion = value
    assert rbpf.recover_from_depletion is True
    rbpf.recover_from_depletion = np.bool_(False)
    assert rbpf.recover_from_depletion is False


def test_other_estimators_fix_their_constant_options():
    est = om.make_estimator("online_em", om.corridor(5), window=4)
    with pytest.raises(om.InvalidOptionError, match="window is fixed"):
        est.window = 9
    exact = om.make_estimator("exact", om.corridor(4))
    with pytest.raises(om.InvalidOptionError, match="max_bytes is fixed"):
        exact.max_bytes = 1
