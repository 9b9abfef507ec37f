"""The exploration studies' yardsticks (onlinemap.evaluate): the three readings of "wrong cells"
against a per-cell loop, and the map of a robot told its location against the exact joint filter
on a floor that never slips (where the location is known, so the exact map marginals are exactly
that map); and the replay study (onlinemap.studies.exploration) against a hand recomputation."""

import numpy as np
import pytest

import onlinemap as om
from onlinemap.errors import ModelError
from onlinemap.estimators import make_estimator
from onlinemap.evaluate import CONFIDENT, cell_counts, told_location_map


def test_cell_counts_match_a_per_cell_loop():
    rng = np.random.default_rng(0)
    for k in (2, 3, 4):
        beliefs = rng.dirichlet(np.full(k, 0.7), size=60)
        beliefs[:5] = 1.0 / k  # uninformed cells
        truth = rng.integers(k, size=60)
        wrong = unsure = confident_wrong = 0
        for p, label in zip(beliefs, truth):
            best = int(np.argmax(p))
            wrong += best != label
            unsure += not (best == label and p[best] >= CONFIDENT)
            confident_wrong += best != label and p[best] >= CONFIDENT
        assert cell_counts(beliefs, truth) == (wrong, unsure, confident_wrong)


@pytest.mark.parametrize("footprint", ["cell", "cross"])
@pytest.mark.parametrize("static", [True, False])
def test_told_location_map_equals_the_exact_filter_when_the_floor_never_slips(footprint, static):
    change = None if static else om.model.symmetric_channel(2, 0.9)
    model = om.grid_model(2, 3, 2, p_obs=0.8, p_move=1.0, change=change, footprint=footprint)
    true_map = np.array([0, 1, 1, 0, 0, 1])
    run = om.simulate(model, true_map, np.random.default_rng(1).integers(4, size=12), seed=2)
    exact = make_estimator("exact", model)
    for t in range(run.n_steps):
        exact.step(None if t == 0 else int(run.actions[t - 1]), run.observations[t])
    np.testing.assert_allclose(told_location_map(model, run), exact.belief.map, atol=1e-12)


def test_replay_study_feeds_the_live_runs_data_to_fresh_filters():
    """Each replay row is a fresh RBPF (seed 10000 + replay) fed the live run's actions and
    observations (the live run: policies.exploration of the same seed, 64 particles); the
    told-location row is told_location_map of the same run."""
    from policies import exploration, exploration_world
    from onlinemap.studies.exploration import replay_study
    from onlinemap.estimators import run_estimator

    table = replay_study(seeds=[3], steps=40, n_particles=64, replay_particles=(32,), replays=1, progress=False)
    assert table["filter"].tolist() == ["live", "rbpf 32", "told location"]
    model, true_map = exploration_world(p_door=0.0, p_move=0.8, floor_plan=None)
    found = exploration(model, true_map, "info_gain", "rbpf", 40, 3, estimator_options={"n_particles": 64})
    truth = found.run.maps[-1]
    replayed = run_estimator(make_estimator("rbpf", model, seed=10_000, n_particles=32), found.run.actions,
                             found.run.observations).map[-1]
    told = told_location_map(model, found.run)
    expected = [found.frame["map_error"].iloc[-1], 1 - replayed[np.arange(100), truth].mean(),
                1 - told[np.arange(100), truth].mean()]
    np.testing.assert_allclose(table["final_map_error"], expected, rtol=1e-12)


def test_the_told_location_map_of_a_static_world_equals_the_step_by_step_filter():
    """The static shortcut (log-sum of the readings per cell) against the per-step filter it
    replaces, on a footprint run with off-grid readings."""
    model = om.grid_model(3, 3, 3, p_obs=0.7, p_move=0.8, footprint="cross")
    run = om.simulate(model, None, np.random.default_rng(4).integers(4, size=30), seed=5)
    belief = np.array(np.broadcast_to(model.label_prior, (model.n_cells, model.n_labels)))
    for location, observation in zip(run.locations, run.observations):
        for cell, z in zip(model.footprint_cells[location], np.atleast_1d(observation)):
            if cell >= 0:
                belief[cell] *= model.sensor[:, z]
                belief[cell] /= belief[cell].sum()
    np.testing.assert_allclose(told_location_map(model, run), belief, atol=1e-12)


def test_summary_keeps_a_metric_no_run_reached():
    """Mean and t-interval of each metric per group, by hand; a metric with no value in any run
    (steps to a map error never reached) keeps its columns as NaN instead of vanishing."""
    import pandas as pd
    from scipy import stats

    from onlinemap.studies.base import summary_of

    runs = pd.DataFrame({"planner": ["a", "a", "a", "b", "b"], "seed": [0, 1, 2, 0, 1],
                         "steps": [10.0, 12.0, 17.0, 3.0, 5.0], "never": [float("nan")] * 5})
    summary = summary_of(runs, ["steps", "never"], ["planner"])
    a = summary[summary["planner"] == "a"].iloc[0]
    values = [10.0, 12.0, 17.0]
    half = stats.t.ppf(0.975, 2) * stats.sem(values)
    assert a["runs"] == 3 and a["steps"] == pytest.approx(13.0)
    assert (a["steps_low"], a["steps_high"]) == pytest.approx((13.0 - half, 13.0 + half))
    assert {"never", "never_low", "never_high"} <= set(summary.columns)
    assert summary[["never", "never_low", "never_high"]].isna().all().all()


def test_metric_ranges_bound_each_metric_by_its_own_kind():
    """Errors lie in [0, 1]; steps to a map error, the area under the error curve (error x
    steps) and times in [0, inf); counts of cells in [0, N] (a study's interval of the steps to
    map error 0.1 was once cut at 1 because the name holds "error")."""
    import math

    from onlinemap.evaluate import metric_bounds

    assert metric_bounds("final_map_error") == (0.0, 1.0)
    assert metric_bounds("reached_map_error_10") == (0.0, 1.0)
    for name in ("steps_to_map_error_10", "steps_to_map_error_05", "map_error_area", "ms_per_step"):
        assert metric_bounds(name) == (0.0, math.inf), name
    assert metric_bounds("wrong_cells", 100) == metric_bounds("final_known_cells", 100) == (0.0, 100.0)
    assert metric_bounds("final_log_evidence") == (-math.inf, math.inf)


def test_a_study_read_off_the_per_step_table_equals_the_study_of_the_same_runs():
    """``steps_study`` (the per-step table of ``compare_planners``, scored per run) gives the
    per-run values and the summary ``planners_study`` computes by running the tasks, on every
    metric a per-step table holds (exactly: the same runs, the same definitions)."""
    from onlinemap.studies import exploration

    world, planners = "door,blocking=1,footprint=cross", ["random", "frontier"]
    options = {"n_particles": 30}
    direct = exploration.planners_study(world, planners, seeds=[0, 1], steps=60, estimator_options=options,
                                        progress=False)
    table = exploration.compare_planners(world, planners, "rbpf", 60, [0, 1], estimator_options=options,
                                         progress=False)
    read = exploration.steps_study(table, planners)
    metrics = [c for c in read.runs.columns if c in exploration.METRICS and c != "ms_per_step"]
    assert {"final_map_error", "wrong_cells", "map_error_area", "steps_to_map_error_20"} <= set(metrics)
    np.testing.assert_array_equal(read.runs[["planner", "seed"]].to_numpy(), direct.runs[["planner", "seed"]].to_numpy())
    np.testing.assert_array_equal(read.runs[metrics].to_numpy(float), direct.runs[metrics].to_numpy(float))
    columns = [c for c in read.summary.columns if not c.startswith("ms_per_step")]
    assert set(columns) <= set(direct.summary.columns)
    np.testing.assert_array_equal(read.summary[columns[3:]].to_numpy(float), direct.summary[columns[3:]].to_numpy(float))
    assert list(read.summary[columns[:3]].itertuples(index=False)) == list(direct.summary[columns[:3]].itertuples(index=False))


def test_a_study_keeps_the_runs_it_is_asked_for_as_exploration_plays_them():
    """``keep``: the study hands back the true run and the beliefs of the runs it names, the very
    ones :func:`policies.exploration` gives for that world, planner and seed (so a notebook plots a
    study's run without running it again), and its table is the one it gives without ``keep``.
    A run the study does not have, or a study whose runs leave the process, is refused."""
    import policies
    from onlinemap.studies import exploration
    from onlinemap.worlds import parse_world

    worlds, planners, options = ["door,blocking=1,footprint=cross", "grid:3x4,footprint=cross"], ["random", "frontier"], \
        {"n_particles": 20}
    kept = [(worlds[1], "frontier", 1), (worlds[0], "random", 0)]
    study = exploration.planners_study(worlds, planners, seeds=[0, 1], steps=30, estimator_options=options,
                                       progress=False, keep=kept)
    plain = exploration.planners_study(worlds, planners, seeds=[0, 1], steps=30, estimator_options=options,
                                       progress=False)
    assert sorted(study.played) == sorted(kept)
    runs, summary = study  # still the pair every study returns
    assert runs is study.runs and summary is study.summary
    metrics = [c for c in plain.runs.columns if c in exploration.METRICS and c != "ms_per_step"]
    np.testing.assert_array_equal(study.runs[metrics].to_numpy(float), plain.runs[metrics].to_numpy(float))
    assert dict(plain.played) == {}
    from onlinemap.sweeps.runner import played_map
    for world, planner, seed in kept:
        model = parse_world(world).model
        alone = policies.exploration(model, played_map(world, seed), planner, "rbpf", 30, seed=seed,
                                     estimator_options=options, progress=False)
        played = study.played[world, planner, seed]
        np.testing.assert_array_equal(played.run.actions, alone.run.actions)
        np.testing.assert_array_equal(played.run.locations, alone.run.locations)
        np.testing.assert_array_equal(played.trajectory.map, alone.trajectory.map)
        np.testing.assert_array_equal(played.trajectory.location, alone.trajectory.location)
    with pytest.raises(ModelError, match="does not have"):
        exploration.planners_study(worlds[0], planners, seeds=[0], steps=5, progress=False,
                                   keep=[(worlds[0], "info_gain", 0)])
    with pytest.raises(ModelError, match="workers=0"):
        exploration.planners_study(worlds[0], planners, seeds=[0], steps=5, progress=False, workers=2,
                                   keep=[(worlds[0], "random", 0)])
    from onlinemap.sweeps import sweep
    with pytest.raises(om.OnlineMapError, match="on_played needs workers=0"):
        sweep(exploration.exploration_spec(worlds[0], planners, 5, [0]), on_played=lambda task, played: None)
