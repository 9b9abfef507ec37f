"""The honest metrics (issue 40, item 1): the expected location distance against a breadth-first
search written here on row and column coordinates; the calibration gaps as a statistical property
of exact Bayes on worlds drawn from its own prior (tolerance from the sample size) and against an
overconfident belief; the told-location map of blocking worlds against the enumeration of every
map (static) or every map history (dynamic) with the true path known."""

import itertools
from collections import deque

import numpy as np
import pandas as pd
import pytest

import onlinemap as om
from onlinemap import metrics
from onlinemap.estimators import make_estimator, run_estimator
from onlinemap.estimators.base import Trajectory
from onlinemap.evaluate import from_steps, metric_bounds, run_metrics, step_metrics, told_location
from onlinemap.simulate import Run

WALLS = """\
..#.
.##.
...#
#.#.
"""  # the top-right pair and the bottom-right corner are free and walled in: no path reaches them


def bfs_rows(layout: str, source: int) -> np.ndarray:
    """Moves from ``source`` to every cell entering only free cells ('.'), row/column steps; a
    cell no path reaches gets its Manhattan distance (the documented fallback)."""
    grid = [list(line) for line in layout.splitlines()]
    rows, cols = len(grid), len(grid[0])
    sr, sc = divmod(source, cols)
    distance = {(sr, sc): 0}
    queue = deque([(sr, sc)])
    while queue:
        r, c = queue.popleft()
        for dr, dc in ((-1, 0), (0, 1), (1, 0), (0, -1)):
            rr, cc = r + dr, c + dc
            if 0 <= rr < rows and 0 <= cc < cols and grid[rr][cc] == "." and (rr, cc) not in distance:
                distance[rr, cc] = distance[r, c] + 1
                queue.append((rr, cc))
    return np.array([distance.get((r, c), abs(r - sr) + abs(c - sc)) for r in range(rows) for c in range(cols)],
                    dtype=float)


def test_floor_distances_match_a_breadth_first_search_with_the_grid_fallback():
    model, true_map = om.door_world(WALLS, blocking=True)
    passable = ~model.blocking[true_map]
    distances = metrics.FloorDistances(model.neighbors, passable)
    for source in range(model.n_cells):
        np.testing.assert_array_equal(distances[source], bfs_rows(WALLS, source))
    assert distances[0][15] == 6  # the walled-in corner: Manhattan, though no path reaches it
    assert distances[1][13] == 5  # around the wall: 5 moves, Manhattan 3


def test_off_by_one_is_not_lost():
    """Two beliefs with the same location error (1: no mass on the true cell): one on the next
    cell scores 1 cell, one across the floor scores the moves there."""
    model, true_map = om.door_world(WALLS, blocking=True)
    distances = metrics.FloorDistances(model.neighbors, ~model.blocking[true_map])
    near, far = np.zeros(16), np.zeros(16)
    near[0], far[13] = 1.0, 1.0
    assert metrics.location_error(near, 1) == metrics.location_error(far, 1) == 1.0
    assert metrics.location_distance(near, 1, distances) == 1.0
    assert metrics.location_distance(far, 1, distances) == 5.0
    spread = np.full(16, 1 / 16)
    assert metrics.location_distance(spread, 1, distances) == pytest.approx(bfs_rows(WALLS, 1).mean())
    # over time: one true cell per step, an (N, N) table works as well
    table = np.array([bfs_rows(WALLS, s) for s in range(16)])
    beliefs, truth = np.stack([near, far, spread]), np.array([0, 7, 5])
    expected = [beliefs[t] @ table[truth[t]] for t in range(3)]
    np.testing.assert_allclose(metrics.location_distance(beliefs, truth, table), expected)
    np.testing.assert_allclose(metrics.location_distance(beliefs, truth, distances), expected)


def test_without_blocking_labels_the_distance_is_the_grid_distance():
    model = om.grid_model(3, 4, 2, footprint="cross")
    run = om.simulate(model, None, np.random.default_rng(0).integers(4, size=20), seed=1)
    trajectory = run_estimator(make_estimator("bk", model), run.actions, run.observations)
    rows, cols = np.divmod(np.arange(12), 4)
    manhattan = np.abs(rows[:, None] - rows) + np.abs(cols[:, None] - cols)
    expected = [trajectory.location[t] @ manhattan[run.locations[t]] for t in range(run.n_steps)]
    np.testing.assert_allclose(step_metrics(run, trajectory)["location_distance"], expected)


def _prior_runs(model: om.GridModel, n_runs: int, steps: int, seed: int):
    """``n_runs`` runs of worlds drawn from the model's own prior, each scored with exact Bayes."""
    rng = np.random.default_rng(seed)
    for _ in range(n_runs):
        run = om.simulate(model, None, seed=rng, steps=steps)
        yield run, run_estimator(make_estimator("exact", model), run.actions, run.observations)


def _tolerance(values: np.ndarray) -> float:
    """Four standard errors of the mean of i.i.d. per-run values (a false alarm 1 in 16,000)."""
    return 4 * values.std(ddof=1) / np.sqrt(len(values))


def test_exact_bayes_is_calibrated_and_a_sharpened_belief_is_not():
    """E[P(true cell)] = E[sum_i P(i)^2] at every step when the world is drawn from the model and
    the belief is the exact posterior, so each run's gap has mean 0. Squaring and renormalising
    the beliefs (claiming more than they know) must show a negative gap beyond the tolerance."""
    model = om.grid_model(2, 3, 2, p_obs=0.8, p_move=0.7, blocking=1)
    gaps, sharp = [], []
    for run, trajectory in _prior_runs(model, 300, 12, seed=0):
        gaps.append(run_metrics(run, trajectory)["location_calibration_gap"])
        location = trajectory.location ** 2
        location /= location.sum(axis=1, keepdims=True)
        sharp.append(run_metrics(run, trajectory._replace(location=location))["location_calibration_gap"])
    gaps, sharp = np.array(gaps), np.array(sharp)
    assert abs(gaps.mean()) < _tolerance(gaps)
    assert sharp.mean() < -_tolerance(sharp)


def test_the_map_calibration_of_exact_bayes_over_the_cells_read():
    """With a floor that never slips and no blocking labels, the robot knows the cells it read,
    so the read set is a function of the data and the identity holds over it too; a sharpened map
    belief fails it."""
    model = om.grid_model(2, 3, 3, p_obs=0.7, p_move=1.0, footprint=((0, 0), (0, 1)))
    gaps, sharp = [], []
    for run, trajectory in _prior_runs(model, 300, 6, seed=1):
        gaps.append(run_metrics(run, trajectory)["map_calibration_gap"])
        maps = trajectory.map ** 3
        maps /= maps.sum(axis=-1, keepdims=True)
        sharp.append(run_metrics(run, trajectory._replace(map=maps))["map_calibration_gap"])
    gaps, sharp = np.array(gaps), np.array(sharp)
    assert abs(gaps.mean()) < _tolerance(gaps)
    assert sharp.mean() < -_tolerance(sharp)


def test_calibration_of_a_hand_built_belief_sequence():
    """Three steps of a corridor of 3 cells whose true cells and beliefs are given: the means and
    the gaps by hand; the map over the cells read by each step (cell 0, then 0 and 1)."""
    model = om.corridor(3, p_move=0.8)
    run = Run(model, np.array([1, 1]), np.array([0, 1, 1]), np.zeros((3, 3), dtype=int), np.array([0, 0, 0]))
    location = np.array([[1.0, 0, 0], [0.5, 0.5, 0], [0.2, 0.2, 0.6]])
    maps = np.array([[[0.5, 0.5]] * 3, [[0.9, 0.1], [0.6, 0.4], [0.5, 0.5]], [[1.0, 0], [0.2, 0.8], [0.5, 0.5]]])
    row = run_metrics(run, Trajectory(location, maps, np.zeros(3), 0.0))
    p_true, claimed = [1.0, 0.5, 0.2], [1.0, 0.5, 0.44]
    assert row["mean_location_p_true"] == pytest.approx(np.mean(p_true))
    assert row["mean_location_claimed"] == pytest.approx(np.mean(claimed))
    assert row["location_calibration_gap"] == pytest.approx(np.mean(p_true) - np.mean(claimed))
    map_true = [0.5, (0.9 + 0.6) / 2, (1.0 + 0.2) / 2]
    map_claimed = [0.5, (0.82 + 0.52) / 2, (1.0 + 0.68) / 2]
    assert row["map_calibration_gap"] == pytest.approx(np.mean(map_true) - np.mean(map_claimed))
    distances = [0.0, 0.5, 0.2 + 0.6]  # the true cell 0, then 1, 1
    assert row["mean_location_distance"] == pytest.approx(np.mean(distances))
    assert row["late_location_distance"] == pytest.approx(np.mean(distances[1:]))


# --- the told-location map of blocking worlds ------------------------------------------------
def _step_likelihood(model: om.GridModel, before, after, action, at_before: int, at_after: int) -> np.ndarray:
    """P(L_t | L_{t-1}, a_t, the labels before the change) for a batch of label vectors (M, N),
    written from the model's definition: the intended cell reached with p_move unless it blocks."""
    target = model.neighbors[at_before, action]
    if target == at_before:
        return np.full(len(before), float(at_after == at_before))
    passable = ~model.blocking[before[:, target]]
    if at_after == target:
        return np.where(passable, model.p_move, 0.0)
    return np.where(passable, 1 - model.p_move, 1.0)


def _reading_likelihood(model: om.GridModel, labels, location: int, observation) -> np.ndarray:
    out = np.ones(len(labels))
    for cell, z in zip(model.footprint_cells[location], np.atleast_1d(observation)):
        if cell >= 0:
            out *= model.sensor[labels[:, cell], z]
    return out


def _brute_force(model: om.GridModel, run: Run) -> np.ndarray:
    """(N, K) P(m_{i,T-1} = k | every reading, the true path) by enumerating every map history
    (every map when the world is static)."""
    n, k, t_steps = model.n_cells, model.n_labels, run.n_steps
    histories = 1 if model.is_static else t_steps
    every = np.array(list(itertools.product(range(k), repeat=n * histories))).reshape(-1, histories, n)
    labels = [every[:, min(t, histories - 1)] for t in range(t_steps)]
    weight = model.label_prior[np.arange(n), labels[0]].prod(axis=1)
    for t in range(t_steps):
        if t > 0:
            weight = weight * _step_likelihood(model, labels[t - 1], labels[t], run.actions[t - 1],
                                               run.locations[t - 1], run.locations[t])
            if not model.is_static:
                weight = weight * model.change[labels[t - 1], labels[t]].prod(axis=1)
        weight = weight * _reading_likelihood(model, labels[t], run.locations[t], run.observations[t])
    marginal = np.stack([np.bincount(labels[-1][:, i], weights=weight, minlength=k) for i in range(n)])
    return marginal / weight.sum()


def _prefix(run: Run, t: int) -> Run:
    return Run(run.model, run.actions[:t], run.locations[:t + 1], run.maps[:t + 1], run.observations[:t + 1])


def _presses(run: Run) -> tuple[int, int, int]:
    """(presses that a blocking cell stopped, presses towards a passable cell that slipped,
    moves) of the run."""
    before = run.locations[:-1]
    target = run.model.neighbors[before, run.actions]
    stayed = (target != before) & (run.locations[1:] == before)
    blocked = run.model.blocking[run.maps[:-1][np.arange(len(target)), target]]
    return int((stayed & blocked).sum()), int((stayed & ~blocked).sum()), int((run.locations[1:] != before).sum())


@pytest.mark.parametrize("footprint, seed", [("cell", 9), ("cross", 24)])
def test_told_location_map_of_a_static_blocking_world_against_every_map(footprint, seed):
    model, true_map = om.door_world(".o\n#.\n.c\n", blocking=True, footprint=footprint, p_move=0.7, p_obs=0.75)
    run = om.simulate(model, true_map, np.random.default_rng(seed).integers(4, size=9), seed=seed)
    assert min(_presses(run)) >= 1  # every kind of evidence is in the run
    told = told_location(model, run)
    np.testing.assert_allclose(told.map, _brute_force(model, run), atol=1e-12)
    for t in range(run.n_steps):  # the error at step t is that of the map told the first t + 1 steps
        expected = 1 - _brute_force(model, _prefix(run, t))[np.arange(model.n_cells), run.maps[t]].mean()
        assert told.map_error[t] == pytest.approx(expected, abs=1e-12)


def test_told_location_map_of_a_dynamic_blocking_world_against_every_map_history():
    change = om.model.symmetric_channel(2, 0.85)
    model = om.grid_model(2, 2, 2, p_obs=0.8, p_move=0.75, change=change, blocking=1, footprint="cross",
                          label_prior=[0.6, 0.4])
    run = om.simulate(model, np.array([0, 1, 0, 0]), [1, 2, 2], seed=6)  # 2^16 map histories
    assert min(_presses(run)) >= 1
    told = told_location(model, run)
    np.testing.assert_allclose(told.map, _brute_force(model, run), atol=1e-12)
    for t in range(run.n_steps):
        expected = 1 - _brute_force(model, _prefix(run, t))[np.arange(model.n_cells), run.maps[t]].mean()
        assert told.map_error[t] == pytest.approx(expected, abs=1e-12)


def test_excess_map_error_and_the_per_step_table_agree_with_the_run_metrics():
    """``excess_map_error`` is the final map error less the told-location map's; a per-step table
    read back (from_steps) gives the run's honest metrics."""
    model, true_map = om.door_world(WALLS, blocking=True, footprint="cross")
    run = om.simulate(model, true_map, np.random.default_rng(5).integers(4, size=40), seed=6)
    trajectory = run_estimator(make_estimator("rbpf", model, n_particles=64, seed=0), run.actions, run.observations)
    row = run_metrics(run, trajectory)
    told = told_location(model, run).map
    told_error = 1 - told[np.arange(16), run.final_map].mean()
    assert row["told_location_map_error"] == pytest.approx(told_error, abs=1e-15)
    assert row["excess_map_error"] == pytest.approx(row["final_map_error"] - told_error, abs=1e-15)
    steps = step_metrics(run, trajectory).assign(run=0)
    back = from_steps(steps, ["run"]).iloc[0]
    for name in ("told_location_map_error", "excess_map_error", "mean_location_distance", "late_location_distance",
                 "location_calibration_gap", "map_calibration_gap", "mean_read_map_claimed"):
        assert back[name] == pytest.approx(row[name], abs=1e-12), name


def test_the_new_metrics_have_their_ranges():
    assert metric_bounds("excess_map_error") == (-1.0, 1.0)
    assert metric_bounds("location_calibration_gap") == (-1.0, 1.0)
    assert metric_bounds("late_location_distance") == (0.0, np.inf)
    assert metric_bounds("mean_location_claimed") == (0.0, 1.0)
    assert metric_bounds("told_location_map_error") == (0.0, 1.0)


def test_a_per_step_table_without_the_new_columns_still_reads():
    table = pd.DataFrame({"run": 0, "t": [0, 1], "map_error": [0.5, 0.4], "location_error": [0.1, 0.2]})
    row = from_steps(table, ["run"]).iloc[0]
    assert "location_calibration_gap" not in row and row["final_map_error"] == 0.4


def test_explore_prints_the_honest_metrics_with_a_legend(capsys):
    """The table of ``onlinemap explore`` has a column per honest metric, and under it one line
    saying what each means."""
    from onlinemap.cli import main
    from onlinemap.evaluate import HONEST_METRICS

    assert main(["explore", "--world", "door,blocking=1,footprint=cross", "--planner", "random",
                 "--estimator", "bk", "--steps", "12"]) == 0
    printed = capsys.readouterr().out.splitlines()
    header = next(line for line in printed if line.split()[:1] == ["planner"])
    for name in HONEST_METRICS:
        assert name in header.split()
        assert any(line.startswith(f"{name}: ") and len(line.split()) > 8 for line in printed), name


def test_where_the_model_learns_its_label_frequencies_the_told_location_robot_learns_them_too():
    """A generated building says its label frequencies are unknown (the filters learn them by
    default), so the anchor's robot learns them too. With a perfect sensor every read cell is
    known, the frequencies are the Dirichlet(1, ..., 1) posterior mean of the read cells' true
    labels, and every unread cell has them as its belief: the error at every step in closed form.
    With a noisy sensor: the map given the true path from the whole run's counts
    (``hindsight.path_map``, another code path), at the end and on a prefix."""
    from onlinemap.hindsight import path_map

    model, true_map = om.building(12, 12, seed=2, p_move=0.8, p_obs=1.0)
    assert model.unknown_label_frequencies
    run = om.simulate(model, true_map, om.random_walk(model, 80, seed=3), seed=3)
    cells = model.footprint_cells[run.locations]
    k, every = model.n_labels, np.arange(model.n_cells)
    expected = []
    for t in range(run.n_steps):
        read = np.unique(cells[: t + 1][cells[: t + 1] >= 0])
        theta = (1.0 + np.bincount(true_map[read], minlength=k)) / (k + len(read))
        p_true = theta[true_map]
        p_true[read] = 1.0
        expected.append(1.0 - p_true.mean())
    np.testing.assert_allclose(told_location(model, run).map_error, expected, atol=1e-9)

    model, true_map = om.building(12, 12, seed=2, p_move=0.8)
    run = om.simulate(model, true_map, om.random_walk(model, 120, seed=4), seed=4)
    told = told_location(model, run)
    np.testing.assert_allclose(told.map, path_map(model, run.locations, run.actions, run.observations), atol=1e-9)
    prefix = path_map(model, run.locations[:61], run.actions[:60], run.observations[:61])
    assert abs((1.0 - prefix[every, true_map].mean()) - told.map_error[60]) < 1e-9
