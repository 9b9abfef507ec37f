"""The EM-mapping studies (onlinemap.studies.mapping) on a few runs: their tables hold what they
say (intervals around the means, failures reported), and `onlinemap reproduce loop|anneal|blocking`
prints and writes them."""

import numpy as np
import pandas as pd
import pytest

from onlinemap.evaluate import read_cells
from onlinemap.studies import mapping as ms
from onlinemap.stats import mean_interval


def test_loop_world_never_reads_off_the_grid_on_its_ring():
    model = ms.loop_world()
    run = ms.loop_run(model, 2, seed=0)
    ring = np.unique(run.locations[~np.r_[False, run.slipped]])
    assert model.start == 6 and (model.footprint_cells[[6, 7, 8, 11, 13, 16, 17, 18]] >= 0).all()
    assert run.n_steps == 17 and len(ring) >= 5


def test_loop_study_summary_matches_its_runs():
    estimators = [("offline grid EM", "offline_em", {}), ("bk", "bk", {}), ("exact", "exact", {})]
    per_run, summary = ms.loop_study(4, seed=1, estimators=estimators, progress=False)
    assert len(per_run) == 8 and list(summary["estimator"]) == ["offline grid EM", "bk", "exact"]
    em = per_run[per_run["estimator"] == "offline grid EM"]
    expected = mean_interval(em["read_map_error"].to_numpy(), 0.95, bounds=(0.0, 1.0))
    row = summary.iloc[0]
    low, high = row["read_map_error_low"], row["read_map_error_high"]
    assert (row["read_map_error"], low, high) == pytest.approx(tuple(expected))
    assert row["runs"] == 4 and row["error"] == ""
    exact = summary.iloc[2]  # 25 cells: exact Bayes refuses, and the table says why
    assert exact["runs"] == 0 and "MemoryLimitError" in exact["error"]
    # the read cells of a run: every cell offset by the footprint from where the robot was
    run = ms.loop_run(ms.loop_world(), 3, int(per_run["seed"].iloc[0]))
    read = {int(c) for l in run.locations for c in run.model.footprint_cells[l] if c >= 0}
    assert set(read_cells(run).tolist()) == read


def test_anneal_study_compares_against_the_best_restart():
    per_run, summary = ms.anneal_study(3, seed=2, restarts=2, progress=False)
    assert len(per_run) == 6 and (per_run["objective_gap"] >= -1e-9).all()
    assert (per_run["local_maximum"] == (per_run["objective_gap"] > 1e-3)).all()
    assert (per_run["best_objective"] >= per_run["objective"] - 1e-9).all()
    assert list(summary["estimator"]) == ["plain EM", f"annealed EM {ms.ANNEAL}"]
    stuck = per_run.pivot(index="run", columns="estimator", values="local_maximum")
    plain, annealed = stuck["plain EM"], stuck[f"annealed EM {ms.ANNEAL}"]
    assert list(summary["stuck_alone"]) == [int((plain > annealed).sum()), int((annealed > plain).sum())]


def test_blocking_study_runs_every_estimator_on_the_same_runs():
    estimators = [("bk", "bk", {}), ("dead_reckoning", "dead_reckoning", {})]
    per_run, summary = ms.blocking_study(2, seed=3, steps=20, estimators=estimators, progress=False)
    seeds = per_run.groupby("estimator", sort=False)["seed"].apply(list)
    assert seeds["bk"] == seeds["dead_reckoning"] == [3, 4]
    assert (summary["policy"] == "random walk").all() and (summary["runs"] == 2).all()
    dead = per_run[per_run["estimator"] == "dead_reckoning"]
    assert np.allclose(dead["read_map_error"], 0.75)  # the uniform prior over 4 labels


def test_blocking_study_planners_half_scores_like_the_random_walk():
    """Planners closed on the rbpf, scored over the cells read as the random walk is: the study's
    row equals _final_scores recomputed by hand from policies.exploration with the same seed."""
    from policies.explore import exploration

    estimators = [("rbpf P=20", "rbpf", {"n_particles": 20})]
    per_run, summary = ms.blocking_study(2, seed=4, steps=8, policies=("random walk", "entropy", "info_gain"),
                                         estimators=estimators, planner_estimators=estimators,
                                         planner_options={"info_gain": {"hypotheses": 2}}, progress=False)
    assert list(summary["policy"]) == ["random walk", "entropy", "info_gain"] and (summary["runs"] == 2).all()
    assert (summary["error"] == "").all()
    assert np.isfinite(per_run[list(ms.BLOCKING_MEASURES)].to_numpy(dtype=float)).all()
    row = per_run[per_run["policy"] == "info_gain"].iloc[0]
    model, true_map = ms.blocking_world()
    found = exploration(model, true_map, "info_gain", "rbpf", 8, int(row["seed"]), progress=False,
                        estimator_options={"n_particles": 20}, planner_options={"hypotheses": 2})
    seen = read_cells(found.run)
    p_true = found.trajectory.map[-1][seen, found.run.final_map[seen]]
    assert row["read_map_error"] == pytest.approx(1 - p_true.mean())
    assert row["read_wrong_cells"] == (found.trajectory.map[-1][seen].argmax(1) != found.run.final_map[seen]).sum()
    assert row["final_location_error"] == pytest.approx(1 - found.trajectory.location[-1, found.run.locations[-1]])


def test_every_study_uses_the_engines_metric_names():
    """Regression (issue 24 item 17): ``reproduce loop`` said ``map_error`` / ``lost`` where every other
    table says ``read_map_error`` (over the cells read) / ``ends_lost``."""
    from onlinemap.evaluate import RUN_METRICS
    for study in ms.STUDIES.values():
        assert not set(study.measures) - set(RUN_METRICS) - {"any_wrong_cell", "local_maximum", "objective_gap"}


def test_cli_prints_and_writes_the_table(tmp_path, capsys):
    from onlinemap.cli import main

    assert main(["reproduce", "anneal", "--runs", "2", "--out", str(tmp_path)]) == 0
    text = capsys.readouterr().out
    assert "plain EM" in text and "local_maximum" in text
    assert len(pd.read_csv(tmp_path / "anneal_runs.csv")) == 4


def test_cli_reports_a_refused_estimator_below_the_table_not_in_a_column(tmp_path, capsys):
    """Issue 42 item 7: ``reproduce loop`` padded every row with an ``error`` column (empty but
    for exact Bayes, which refuses 25 cells). The table holds the estimators that ran; a refused
    one is a line below it naming the error. The CSV keeps its ``error`` column."""
    from onlinemap.cli import main

    assert main(["reproduce", "loop", "--runs", "2", "--out", str(tmp_path)]) == 0
    lines = capsys.readouterr().out.splitlines()
    header = next(line for line in lines if line.split()[:2] == ["estimator", "runs"])
    assert "error" not in header.split()
    table = lines[lines.index(header) + 1:lines.index(header) + 1 + len(ms.LOOP_ESTIMATORS) - 1]
    assert all(line.split()[-1].endswith("]") for line in table)  # no trailing error text on any row
    assert not any(line.lstrip().startswith("exact ") for line in table)
    refused = [line for line in lines if line.startswith("exact: not run (MemoryLimitError: ")]
    assert len(refused) == 1
    summary = pd.read_csv(tmp_path / "loop_summary.csv", keep_default_na=False)
    assert summary.set_index("estimator").loc["exact", "error"].startswith("MemoryLimitError")
