"""Every estimator with blocking labels and sensor footprints (issue 13) against brute-force
enumeration over (location, map) (tests/oracles.py), on a 2 x 3 binary grid and a 6-cell
corridor, static and dynamic: exact to 1e-10, bk against a projection filter written by
enumeration, dead reckoning against the same projection without observations."""

import numpy as np
import pytest

import onlinemap as om
from estimator_cases import beliefs
from oracles import BruteForce
from onlinemap.model import symmetric_channel

VARIANTS = {"blocking": dict(blocking=[1]), "cross": dict(footprint="cross"),
            "both": dict(blocking=[1], footprint="cross")}


def world(shape: str, dynamic: bool, variant: str) -> om.GridModel:
    rows, cols = (2, 3) if shape == "grid2x3" else (1, 6)
    change = symmetric_channel(2, 0.93) if dynamic else None
    return om.grid_model(rows, cols, 2, p_obs=0.85, p_move=0.75, change=change, label_prior=[0.7, 0.3],
                         start=1, **VARIANTS[variant])


CASES = [(shape, dynamic, variant) for shape in ("grid2x3", "corridor6") for dynamic in (False, True)
         for variant in VARIANTS]
IDS = [f"{s}-{'dynamic' if d else 'static'}-{v}" for s, d, v in CASES]
_ORACLES: dict = {}


def oracle(model: om.GridModel) -> BruteForce:
    key = (model.rows, model.cols, model.is_static, model.has_blocking, model.footprint)
    if key not in _ORACLES:
        _ORACLES[key] = BruteForce.of(model)
    return _ORACLES[key]


def run_of(model: om.GridModel, seed: int = 0, steps: int = 9) -> om.Run:
    return om.simulate(model, steps=steps, seed=seed)


def as_oracle_observations(run: om.Run) -> list:
    return [tuple(z) if run.observations.ndim > 1 else int(z) for z in run.observations]


@pytest.mark.parametrize("shape, dynamic, variant", CASES, ids=IDS)
def test_exact_filter_and_smoother_equal_enumeration(shape, dynamic, variant):
    model = world(shape, dynamic, variant)
    run = run_of(model)
    brute = oracle(model)
    reference = brute.filter(run.actions, as_oracle_observations(run))
    for belief, (location, maps, log_evidence) in zip(beliefs(om.make_estimator("exact", model), run), reference):
        np.testing.assert_allclose(belief.location, location, atol=1e-10)
        np.testing.assert_allclose(belief.map, maps, atol=1e-10)
        assert belief.log_evidence == pytest.approx(log_evidence, abs=1e-10)
    smoothed = om.exact_smooth(model, run.actions, run.observations)
    for t, (location, maps) in enumerate(brute.smooth(run.actions, as_oracle_observations(run))):
        np.testing.assert_allclose(smoothed.location[t], location, atol=1e-10)
        np.testing.assert_allclose(smoothed.map[t], maps, atol=1e-10)


def projection_filter(brute: BruteForce, model: om.GridModel, run: om.Run, observe: bool):
    """Boyen-Koller by enumeration: expand q(L) prod_i mu_i into the joint over states, apply the
    exact transition, project back onto the marginals (with blocking the prediction correlates
    L with the map), expand again, apply the exact likelihood and project."""

    def product(location, maps):
        return np.array([location[l] * np.prod([maps[i, m[i]] for i in range(brute.n)]) for l, m in brute.states])

    location, maps = model.location_prior(), np.array(model.label_prior)
    out = []
    for t, z in enumerate(as_oracle_observations(run)):
        if t > 0:
            location, maps = brute.marginals(product(location, maps) @ brute.transition(run.actions[t - 1]))
        if observe:
            joint = product(location, maps) * brute.likelihood(z)
            location, maps = brute.marginals(joint / joint.sum())
        out.append((location, maps))
    return out


@pytest.mark.parametrize("shape, dynamic, variant", CASES, ids=IDS)
@pytest.mark.parametrize("name", ["bk", "dead_reckoning"])
def test_factored_filters_equal_their_projection_by_enumeration(name, shape, dynamic, variant):
    model = world(shape, dynamic, variant)
    run = run_of(model, seed=1)
    reference = projection_filter(oracle(model), model, run, observe=name == "bk")
    for belief, (location, maps) in zip(beliefs(om.make_estimator(name, model), run), reference):
        np.testing.assert_allclose(belief.location, location, atol=1e-10)
        np.testing.assert_allclose(belief.map, maps, atol=1e-10)


def test_blocking_walls_teach_exact_bayes_where_the_walls_are():
    """A robot that keeps bumping learns a wall it never sees: cells 2 and 3 are a wall (label 1)
    or a passable coloured cell (label 2); had cell 2 been passable, the robot would be seeing
    colour by now."""
    prior = [[1, 0, 0], [1, 0, 0], [0, 0.5, 0.5], [0, 0.5, 0.5]]
    model = om.corridor(4, 3, p_obs=0.9, p_move=0.9, blocking=[1], label_prior=prior)
    run = om.simulate(model, [0, 0, 1, 2], [1] * 20, seed=3)
    belief = list(beliefs(om.make_estimator("exact", model), run))[-1]
    assert belief.map[2, 1] > 0.99 and belief.location[1] > 0.99
    assert list(beliefs(om.make_estimator("bk", model), run))[-1].map[2, 1] == pytest.approx(0.5)


@pytest.mark.parametrize("name", ["exact", "bk", "dead_reckoning", "online_em", "offline_em"])
def test_checkpoints_of_footprint_and_blocking_estimators_resume_bit_identically(name, tmp_path):
    model = world("grid2x3", True, "both")
    run = run_of(model, seed=4, steps=12)
    est = om.make_estimator(name, model)
    list(beliefs(est, run, stop=6))
    resumed = om.load(om.save(est, tmp_path / "state.npz"))
    for a, b in zip(beliefs(est, run, start=6), beliefs(resumed, run, start=6)):
        assert a.location.tobytes() == b.location.tobytes() and a.map.tobytes() == b.map.tobytes()


@pytest.mark.parametrize("name", ["exact", "bk", "dead_reckoning", "online_em", "offline_em"])
def test_bad_or_impossible_footprint_observations_change_nothing(name):
    from estimator_cases import assert_state_unchanged, snapshot
    from onlinemap.errors import ImpossibleObservationError, InvalidObservationError

    model = om.grid_model(2, 3, 2, p_obs=1.0, footprint="cross", start=1)
    est = om.make_estimator(name, model)
    est.step(None, [0, -1, 0, 0, 0])  # cell 1 (top middle): only north is off the grid
    before = snapshot(est)
    for bad in ([0, 0, 0], [-1, -1, 0, 0, 0], [0, 0, 0, 0, 0], [0, -1, 0, 0, 5]):
        with pytest.raises(InvalidObservationError):
            est.step("east", bad)
        assert_state_unchanged(est, before)
    if name != "dead_reckoning":  # north from row 0 stays: the bottom row's off-grid pattern is impossible
        with pytest.raises(ImpossibleObservationError):
            est.step("north", [0, 0, 0, -1, 0])
        assert_state_unchanged(est, before)


@pytest.mark.parametrize("name", om.available_estimators())
def test_footprint_observation_is_f_readings_as_an_array_or_a_list(name):
    """Regression (issue 24 item 11): an ndarray of any shape with F elements ((5, 1), (1, 5))
    was accepted (ravelled) while the same nested list was refused. Both are refused now, with
    the state unchanged; a flat list, tuple or (F,) array is the observation."""
    from estimator_cases import assert_state_unchanged, snapshot
    from onlinemap.errors import InvalidObservationError
    from onlinemap.estimators.base import fork

    model = om.grid_model(2, 3, 2, p_obs=0.9, footprint="cross", start=1)
    est = om.make_estimator(name, model, **({"n_particles": 20, "seed": 0} if name == "rbpf" else {}))
    reading = [0, -1, 1, 0, 1]  # cell 1 (top middle): only north is off the grid
    est.step(None, reading)
    before = snapshot(est)
    for bad in (np.array(reading).reshape(5, 1), np.array(reading).reshape(1, 5), [[r] for r in reading],
                [reading], np.array(0)):
        with pytest.raises(InvalidObservationError, match="observation"):
            est.step("west", bad)
        assert_state_unchanged(est, before)
    for good in (tuple(reading), np.array(reading)):
        assert fork(est).step("west", good).t == 1
