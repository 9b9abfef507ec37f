"""``onlinemap reproduce corridor`` and its building blocks (onlinemap.studies.corridor, onlinemap.plots)."""

import math

import numpy as np
import pandas as pd
import pytest
from scipy.optimize import brentq

import onlinemap as om
from onlinemap import evaluate
from onlinemap.stats import wilson_interval
from onlinemap.studies import corridor as reproduce
from onlinemap.cli import main

SMALL = [("exact", "exact", {}), ("dead_reckoning", "dead_reckoning", {}),
         ("online_em W=max decay=1.0", "online_em", {"window": "max", "decay": 1.0}),
         ("offline_em", "offline_em", {})]


@pytest.mark.parametrize("k,n", [(0, 10), (3, 10), (10, 10), (81, 263), (1, 2)])
@pytest.mark.parametrize("confidence", [0.9, 0.95])
def test_wilson_interval_solves_the_score_test(k, n, confidence):
    z = {0.9: 1.6448536269514722, 0.95: 1.959963984540054}[confidence]
    p_hat = k / n

    def score(p):  # the interval is where |p_hat - p| <= z sqrt(p (1 - p) / n)
        return (p_hat - p) ** 2 - z**2 * p * (1 - p) / n

    low = 0.0 if k == 0 else brentq(score, 1e-12, p_hat - 1e-12)
    high = 1.0 if k == n else brentq(score, p_hat + 1e-12, 1 - 1e-12)
    ours = wilson_interval(k, n, confidence)
    assert ours[0] == pytest.approx(low, abs=1e-9)
    assert ours[1] == pytest.approx(high, abs=1e-9)


def test_wilson_interval_is_vectorised():
    low, high = wilson_interval(np.array([0, 5]), np.array([10, 10]))
    assert low.shape == (2,) and np.all(low <= high)


def test_way_back_of_the_scripted_corridor_starts_after_the_turn():
    run = om.scenarios.murphy_corridor()
    assert np.flatnonzero(evaluate.way_back(run)).tolist() == list(range(8, 15))


def test_every_configured_estimator_exists_and_labels_are_unique():
    labels = [label for label, _, _ in reproduce.CORRIDOR_ESTIMATORS]
    assert len(labels) == len(set(labels))
    model = om.corridor(4)
    for _, name, options in reproduce.CORRIDOR_ESTIMATORS:
        om.make_estimator(name, model, **options)  # unknown names or options raise
    windows_decays = {(o["window"], o["decay"]) for _, n, o in reproduce.CORRIDOR_ESTIMATORS if n == "online_em"}
    assert windows_decays == {(w, d) for w in (1, 2, 4, 8, "max") for d in (0.8, 0.9, 0.95, 1.0)}


def test_corridor_table_scores_match_a_direct_computation():
    run = om.scenarios.murphy_corridor()
    table, trajectories = reproduce.corridor_table(run, SMALL, progress=False)
    assert table["estimator"].tolist() == [label for label, _, _ in SMALL]
    exact = om.run_estimator(om.make_estimator("exact", run.model), run.actions, run.observations)
    np.testing.assert_array_equal(trajectories["exact"].location, exact.location)
    p_true = exact.location[np.arange(15), run.locations]
    row = table.set_index("estimator").loc["exact"]
    assert row["final_p_true"] == pytest.approx(p_true[-1])
    assert row["min_p_true_way_back"] == pytest.approx(p_true[8:].min())
    assert row["wrong_visited"] == 0 and not row["ends_lost"]
    em = table.set_index("estimator").loc["online_em W=max decay=1.0"]
    assert em["wrong_visited"] >= 1 and em["astray_way_back"]



def told_the_truth(run):
    """A trajectory certain of the true location and the true labels at every step."""
    steps = np.arange(run.n_steps)
    location = np.zeros((run.n_steps, run.model.n_cells))
    location[steps, run.locations] = 1.0
    maps = np.eye(run.model.n_labels)[run.maps]  # (T, N, K) one-hot
    return om.Trajectory(location, maps, np.zeros(run.n_steps), 0.0)


def test_failed_means_ends_lost_or_a_wrong_visited_cell():
    """``failed`` on trajectories edited by hand on the corridor run (visits cells 0-6, never 7):
    a wrong label on a visited cell fails, on the unvisited cell it does not; a final P(true
    location) of 0.4 fails (lost: below 0.5), 0.5 does not; and on real filters: dead reckoning
    ends with 3 visited cells wrong but not lost (P 0.63), so it fails on the wrong cells alone."""
    run = om.scenarios.murphy_corridor()
    assert sorted(set(run.locations.tolist())) == list(range(7))

    def outcome(edit):
        trajectory = told_the_truth(run)
        edit(trajectory.location[-1], trajectory.map[-1])
        row = evaluate.run_metrics(run, trajectory)
        return row["wrong_cells"], row["wrong_visited"], row["ends_lost"], row["failed"]

    def relabel(cell):
        def edit(location, cells):
            cells[cell] = cells[cell, ::-1]  # binary labels: the wrong one is certain
        return edit

    def p_true(p):
        def edit(location, cells):
            location[:] = 0.0
            location[run.locations[-1]], location[5] = p, 1.0 - p
        return edit

    assert outcome(lambda location, cells: None) == (0, 0, False, False)
    assert outcome(relabel(3)) == (1, 1, False, True)  # a wrong visited cell
    assert outcome(relabel(7)) == (1, 0, False, False)  # never visited: not a failure
    assert outcome(p_true(0.4)) == (0, 0, True, True)  # ends lost
    assert outcome(p_true(0.5)) == (0, 0, False, False)
    for name, failed in (("exact", False), ("dead_reckoning", True)):
        trajectory = om.run_estimator(om.make_estimator(name, run.model), run.actions, run.observations)
        row = evaluate.run_metrics(run, trajectory)
        wrong = np.argmax(trajectory.map[-1, :7], axis=1) != run.final_map[:7]  # visited cells, by hand
        lost = trajectory.location[-1, run.locations[-1]] < 0.5
        assert (row["wrong_visited"], row["ends_lost"], row["failed"]) == (wrong.sum(), lost, failed)
    assert wrong.sum() == 3 and not lost  # dead reckoning fails on its wrong cells alone

def test_random_study_summary_counts_the_per_run_table():
    per_run, summary = reproduce.random_corridor_study(4, seed=1, estimators=SMALL, progress=False)
    assert len(per_run) == 7 * len(SMALL)  # one run per length 6..12 (4 runs, rounded up to a multiple of 7)
    assert sorted(set(per_run["n_cells"])) == list(range(6, 13)) and (per_run["wrong_visited"] >= 0).all()
    assert summary["estimator"].tolist() == [label for label, _, _ in SMALL]
    for _, row in summary.iterrows():
        runs = per_run[per_run["estimator"] == row["estimator"]]
        for outcome in reproduce.STUDY_OUTCOMES:
            assert row[outcome] == pytest.approx(runs[outcome].mean())
            assert row[f"{outcome}_low"] <= row[outcome] <= row[f"{outcome}_high"]
    text = reproduce.with_intervals(summary)
    assert text.loc[0, "wrong_map"].count("[") == 1


@pytest.fixture
def small_list(monkeypatch):
    monkeypatch.setattr(reproduce, "CORRIDOR_ESTIMATORS", SMALL)


def test_cli_reproduce_corridor_writes_tables_and_figures(tmp_path, capsys, small_list):
    assert main(["reproduce", "corridor", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "online_em W=max decay=1.0" in out and "min_p_true_way_back" in out
    summary = pd.read_csv(tmp_path / "corridor_summary.csv")
    assert summary["estimator"].tolist() == [label for label, _, _ in SMALL]
    steps = pd.read_csv(tmp_path / "corridor_steps.csv")
    assert len(steps) == 15 * len(SMALL)
    pngs = sorted(p.name for p in tmp_path.glob("*.png"))
    assert "corridor_overview.png" in pngs and "corridor_online_em_W_max_decay_1.0.png" in pngs
    assert len(pngs) == len(SMALL) + 1
    assert all((tmp_path / name).read_bytes()[:4] == b"\x89PNG" for name in pngs)


def test_cli_reproduce_corridor_random(tmp_path, capsys, small_list):
    assert main(["reproduce", "corridor", "--random", "3", "--seed", "2", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "Wilson" in out and "astray_way_back" in out
    summary = pd.read_csv(tmp_path / "corridor_random_summary.csv")
    assert (summary["runs"] == 7).all()
    assert (tmp_path / "corridor_random.png").exists()
    assert math.isclose(len(pd.read_csv(tmp_path / "corridor_random_runs.csv")), 7 * len(SMALL))


def test_cli_reproduce_refuses_bad_arguments():
    with pytest.raises(SystemExit):
        main(["reproduce", "hallway"])
    for bad in (["--random", "-1"], ["--random", "0"], ["--random", "x"], ["--confidence", "1.5"]):
        with pytest.raises(SystemExit) as exit_info:
            main(["reproduce", "corridor", *bad])
        assert exit_info.value.code == 2
