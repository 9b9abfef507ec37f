"""The hindsight study (onlinemap/studies/hindsight.py): its paired test against the exact
Wilcoxon null distribution written out here, and its rows of one run against the fitters."""

from __future__ import annotations

import itertools

import numpy as np
import pandas as pd
import pytest

import onlinemap as om
from onlinemap.hindsight import told_location
from onlinemap.metrics import map_error
from onlinemap.studies.hindsight import METHODS, floor_worlds, paired_tests, remap_rows


def exact_signed_rank_p(differences):
    """P(W+ <= w+) under the null, every sign pattern of the ranks equally likely (no ties, no zeros)."""
    ranks = np.argsort(np.argsort(np.abs(differences))) + 1
    observed = ranks[np.asarray(differences) > 0].sum()
    totals = [sum(r for r, s in zip(ranks, signs) if s) for signs in itertools.product((0, 1), repeat=len(ranks))]
    return np.mean(np.array(totals) <= observed)


def test_paired_tests_is_the_one_sided_signed_rank_test():
    differences = np.array([-0.05, -0.031, 0.012, -0.02, -0.044, 0.007, -0.013])
    rows = []
    for run, d in enumerate(differences):
        for method, error in (("flat_em", 0.7), ("layered_em", 0.7 + d), ("told_location", 0.6),
                              ("layered_em_learned", 0.5), ("told_location_learned", 0.45)):
            rows.append({"kind": "building", "world": "w", "planner": "random", "seed": run, "method": method,
                         "final_map_error": error})
    table = paired_tests(pd.DataFrame(rows), pairs=(("layered_em", "flat_em"),))
    row = table.iloc[0]
    assert row["runs"] == 7 and row["a_lower"] == 5
    assert row["mean_difference"] == pytest.approx(differences.mean())
    assert row["wilcoxon_p"] == pytest.approx(exact_signed_rank_p(differences), abs=1e-12)
    assert row["excess_over_told"] == pytest.approx(0.7 + differences.mean() - 0.6)


def test_remap_rows_score_each_method_on_the_run():
    # the uniform table stated: the replayed filter does not learn, so its map is the genealogy's mixture
    model, true_map = om.building(12, 12, seed=1, p_move=0.9, label_prior=np.full(4, 0.25))
    run = om.simulate(model, true_map, om.random_walk(model, 60, seed=1), seed=1)
    rows = {row["method"]: row for row in remap_rows(run, None, {"flat_em": {"n_iter": 3}})}
    assert sorted(rows) == sorted(m for m in METHODS if m != "filter")
    np.testing.assert_allclose(rows["layered_em_learned_alignment"]["final_map_error"],
                               map_error(om.fit_layered_map(model, run.actions, run.observations, label_prior="learn")
                                         .map_with_prior(model.label_prior), true_map))
    told = told_location(model, run, label_prior="learn")
    assert rows["told_location_learned"]["final_map_error"] == pytest.approx(map_error(told, true_map))
    assert rows["told_location_learned"]["confidently_wrong"] == int(np.sum(told[np.arange(len(true_map)), true_map] < 0.1))
    fit = om.fit_layered_map(model, run.actions, run.observations, label_prior="learn")
    assert rows["layered_em_learned"]["final_map_error"] == pytest.approx(map_error(fit.map, true_map))
    # one replay gives both RBPF rows; in a static world the genealogy's mixture is the filter's map
    assert rows["rbpf_smoothed"]["final_map_error"] == pytest.approx(rows["rbpf_filtered"]["final_map_error"], abs=1e-9)
    assert 1 <= rows["rbpf_smoothed"]["distinct_paths"] <= 1000


def test_floor_worlds_name_the_files_under_the_folder():
    worlds = floor_worlds("/maps")
    assert worlds[0] == "layout:/maps/movingai/arena.map,region=0:32x0:32"
    assert worlds[2] == "layout:/maps/ros/nav2_depot/depot.yaml,cell_size=0.25,region=16:24x0:8"
