"""The location of a robot told the true map (``run_facts.told_map_location``), against a brute
force over every location path written here (motion, footprint and sensor from the design's
words, not the module's tables), the exact estimator given the true map, and calibration; and
its metrics (``told_map_location_error``, ``told_map_location_distance``,
``excess_location_distance``) in the scorer and the tables."""

from __future__ import annotations

import dataclasses
import itertools
import math

import numpy as np
import pytest

import onlinemap as om
from onlinemap import run_facts
from onlinemap.errors import ModelError
from onlinemap.estimators import make_estimator, run_estimator
from onlinemap.evaluate import from_steps, metric_bounds, metric_definition, run_metrics, step_metrics
from onlinemap.run_facts import told_map_location

DELTAS = {"north": (-1, 0), "east": (0, 1), "south": (1, 0), "west": (0, -1), "left": (0, -1), "right": (0, 1)}


def _move(model, maps_before, here: int, action: int, there: int) -> float:
    """P(L_t = there | L_{t-1} = here, a_t, m_{t-1}) from DESIGN.md sections 1 and 7."""
    row, col = divmod(here, model.cols)
    drow, dcol = DELTAS[model.action_names[action]]
    r, c = row + drow, col + dcol
    if not (0 <= r < model.rows and 0 <= c < model.cols):
        return float(there == here)
    target = r * model.cols + c
    go = model.p_move * (not model.blocking[maps_before[target]])
    return go if there == target else (1.0 - go if there == here else 0.0)


def _reading(model, labels, here: int, readings) -> float:
    """P(z_t | L_t = here, m_t): each offset reads its cell through O, -1 with probability 1 off the grid."""
    row, col = divmod(here, model.cols)
    p = 1.0
    for (drow, dcol), z in zip(model.footprint, np.atleast_1d(readings)):
        r, c = row + drow, col + dcol
        if 0 <= r < model.rows and 0 <= c < model.cols:
            p *= model.sensor[labels[r * model.cols + c], z] if z >= 0 else 0.0
        else:
            p *= float(z == -1)
    return p


def brute_force(model, run, t: int) -> np.ndarray:
    """(N,) P(L_t | a_1..t, z_0..t, m_0..t): the joint of every path l_1..l_t (l_0 the start) and
    the readings, summed by its last cell."""
    out = np.zeros(model.n_cells)
    for path in itertools.product(range(model.n_cells), repeat=t):
        cells = (model.start, *path)
        p = _reading(model, run.maps[0], cells[0], run.observations[0])
        for s in range(1, t + 1):
            p *= _move(model, run.maps[s - 1], cells[s - 1], int(run.actions[s - 1]), cells[s])
            if p == 0.0:
                break
            p *= _reading(model, run.maps[s], cells[s], run.observations[s])
        out[cells[-1]] += p
    return out / out.sum()


def _check_every_step(model, run) -> None:
    beliefs = told_map_location(model, run)
    assert beliefs.shape == (run.n_steps, model.n_cells)
    assert (beliefs.max(axis=1) < 0.99).any()  # the location is in doubt somewhere: not a trivial case
    for t in range(run.n_steps):
        np.testing.assert_allclose(beliefs[t], brute_force(model, run, t), rtol=0, atol=1e-12, err_msg=f"step {t}")


def _blocking_grid():
    """2 x 4 cells from the second, a wall in the bottom row, the cross footprint: readings off the
    grid at every cell, the same off-grid offsets at the two middle cells of a row (they do not give
    the cell away)."""
    model = om.grid_model(2, 4, 2, p_obs=0.8, p_move=0.7, blocking=[1], footprint="cross", start=1)
    return model, np.array([0, 0, 0, 0, 0, 0, 1, 0])


@pytest.mark.parametrize("stretch", [256, 2])
@pytest.mark.parametrize("seed", [1, 2, 6])  # walks that leave the robot in doubt (1 and 6 press into the wall)
def test_blocking_grid_with_a_cross_footprint_matches_the_brute_force(seed, stretch, monkeypatch):
    monkeypatch.setattr(run_facts, "STRETCH", stretch)  # 2: the forward pass is cut into stretches
    model, true_map = _blocking_grid()
    run = om.simulate(model, true_map, om.random_walk(model, 5, seed=seed), seed=seed)
    assert (run.observations == -1).any()  # readings off the grid
    _check_every_step(model, run)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_paper_model_on_a_corridor_of_4_matches_the_brute_force(seed):
    model = om.corridor(4, p_obs=0.85, p_move=0.8)
    true_map = np.array([0, 1, 1, 0])
    run = om.simulate(model, true_map, om.random_walk(model, 7, seed=seed), seed=seed)
    _check_every_step(model, run)


def test_a_changing_corridor_matches_the_brute_force():
    """The paper's model in a dynamic world: the map changes at most steps, a stretch per change."""
    model = om.corridor(4, p_obs=0.85, p_move=0.8, p_change=0.3)
    run = om.simulate(model, np.array([0, 1, 0, 0]), om.random_walk(model, 7, seed=4), seed=4)
    assert (run.maps[1:] != run.maps[:-1]).any(axis=1).sum() >= 3
    _check_every_step(model, run)


@pytest.mark.parametrize("footprint, seed", [(None, 1), (None, 6), (((0, 0), (0, 1)), 4), (((0, 0), (0, 1)), 7)])
def test_a_door_that_opens_and_closes_matches_the_brute_force(footprint, seed):
    """A 2 x 3 door world whose door flips: a closed door blocks, judged on the labels before the
    step's change; the readings see the labels after it. Read with the paper's sensor, and with
    the own cell and the one east of it (off the grid from the east column)."""
    model, true_map = om.door_world("..c\n.#.", p_door=0.4, p_move=0.75, blocking=True, footprint=footprint)
    run = om.simulate(model, true_map, om.random_walk(model, 5, seed=seed), seed=seed)
    assert (run.maps[1:, 2] != run.maps[:-1, 2]).any()
    _check_every_step(model, run)


def test_in_a_static_world_it_is_the_exact_filter_told_the_map_by_its_prior():
    """The exact joint filter whose label prior is one-hot at the true map knows the map: its
    location belief is the told-map belief, on a longer run than the brute force can take."""
    model, true_map = _blocking_grid()
    told = dataclasses.replace(model, label_prior=np.eye(2)[true_map])
    run = om.simulate(model, true_map, om.random_walk(model, 60, seed=5), seed=5)
    exact = run_estimator(make_estimator("exact", told), run.actions, run.observations)
    np.testing.assert_allclose(told_map_location(model, run), exact.location, rtol=0, atol=1e-10)


def test_an_exact_filter_is_calibrated():
    """Worlds drawn from the model: mean P(true cell) equals the mean of sum_i P(i)^2 (DESIGN.md
    section 9), within 4 standard errors of the per-run differences."""
    model = om.grid_model(3, 3, 2, p_obs=0.8, p_move=0.7, blocking=[1], label_prior=[0.8, 0.2])
    gaps, p_trues = [], []
    for seed in range(300):
        rng = np.random.default_rng(seed)
        true_map = om.sample_map(model, rng)
        true_map[model.start] = 0
        run = om.simulate(model, true_map, om.random_walk(model, 19, rng), rng)
        beliefs = told_map_location(model, run)
        p_true = beliefs[np.arange(run.n_steps), run.locations]
        gaps.append(float((p_true - (beliefs ** 2).sum(axis=1)).mean()))
        p_trues.append(p_true.mean())
    gaps = np.array(gaps)
    assert 0.3 < np.mean(p_trues) < 0.9  # the robot is often unsure: the check has something to check
    assert abs(gaps.mean()) <= 4 * gaps.std(ddof=1) / math.sqrt(len(gaps))


def test_knowing_the_map_locates_at_least_as_well_as_the_rbpf():
    """Over 30 runs, the told-map robot's mean late P(true cell) is at least the RBPF's (which
    must learn the map), less 3 standard errors of the paired differences."""
    model = om.grid_model(3, 4, 2, p_obs=0.85, p_move=0.8, blocking=[1], footprint="cross")
    differences = []
    for seed in range(30):
        run = om.simulate(model, np.array([0, 0, 1, 0, 0, 0, 0, 0, 0, 1, 0, 0]),
                          om.random_walk(model, 40, seed=seed), seed=seed)
        rbpf = run_estimator(make_estimator("rbpf", model, n_particles=100, seed=seed), run.actions,
                             run.observations)
        late = np.arange(run.n_steps) >= (run.n_steps - 1) / 2
        told = told_map_location(model, run)[late, run.locations[late]]
        differences.append(told.mean() - rbpf.location[late, run.locations[late]].mean())
    differences = np.array(differences)
    assert differences.mean() >= -3 * differences.std(ddof=1) / math.sqrt(len(differences))


def test_a_run_of_another_grid_is_refused():
    model, true_map = _blocking_grid()
    run = om.simulate(model, true_map, om.random_walk(model, 3, seed=0), seed=0)
    with pytest.raises(ModelError, match="told_map_location"):
        told_map_location(om.grid_model(2, 3, 2, footprint="cross"), run)


def test_the_metrics_are_the_late_means_of_the_anchor_and_the_excess_is_a_difference():
    """``told_map_location_error`` and ``_distance`` are the means over the steps t >= (T - 1) / 2
    of the anchor's 1 - P(true cell) and expected floor distance (here an all-free floor: the
    Manhattan distance), the same from the per-step table (``from_steps``); the excess is the
    filter's late distance less the anchor's."""
    model = om.grid_model(3, 4, 2, p_obs=0.85, p_move=0.8, blocking=[1], footprint="cross")
    run = om.simulate(model, np.zeros(12, dtype=int), om.random_walk(model, 41, seed=1), seed=1)
    trajectory = run_estimator(make_estimator("rbpf", model, n_particles=50, seed=1), run.actions,
                               run.observations)
    steps = step_metrics(run, trajectory)
    row = run_metrics(run, trajectory, steps=steps)
    told = told_map_location(model, run)
    rows, cols = np.divmod(np.arange(12), 4)
    manhattan = np.abs(rows[:, None] - rows[None]) + np.abs(cols[:, None] - cols[None])
    late = np.arange(run.n_steps) >= (run.n_steps - 1) / 2  # 21 of 42 steps
    locations = run.locations[late]
    assert row["told_map_location_error"] == pytest.approx(1 - told[late, locations].mean(), abs=1e-12)
    expected = (told[late] * manhattan[locations]).sum(axis=1).mean()
    assert row["told_map_location_distance"] == pytest.approx(expected, abs=1e-12)
    filter_distance = (trajectory.location[late] * manhattan[locations]).sum(axis=1).mean()
    assert row["excess_location_distance"] == pytest.approx(filter_distance - expected, abs=1e-12)
    again = from_steps(steps.assign(run=0), ["run"]).iloc[0]
    for name in ("told_map_location_error", "told_map_location_distance", "excess_location_distance"):
        assert again[name] == pytest.approx(row[name], abs=1e-12)


def test_the_names_have_definitions_and_ranges():
    assert metric_bounds("told_map_location_error") == (0.0, 1.0)
    assert metric_bounds("told_map_location_distance") == (0.0, math.inf)
    assert metric_bounds("excess_location_distance") == (-math.inf, math.inf)
    for name in ("told_map_location_error", "told_map_location_distance", "excess_location_distance"):
        assert metric_definition(name)


def test_the_study_tables_carry_the_anchor_next_to_the_late_location_metrics():
    from onlinemap.cli.reproduce import FLOOR_METRICS
    from onlinemap.studies import exploration, floors

    for columns in (floors.COLUMNS, floors.SUMMARY, exploration.METRICS, FLOOR_METRICS):
        at = list(columns).index("late_location_distance")
        assert list(columns)[at + 1:at + 4] == ["told_map_location_error", "told_map_location_distance",
                                                 "excess_location_distance"]
