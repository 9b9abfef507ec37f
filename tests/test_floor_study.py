"""The floor study (issue 40, item 4) at a tiny size: a 12 x 12 crop of a shipped MovingAI floor,
30 steps. The table's columns, the told-location anchor against evaluate's told-location map
computed here from the same run, estimator options passed through, resuming from parts, the
per-run extras against hand-computed values, and the ``label_prior=floor`` world key against
label counts done here."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import policies
from onlinemap.errors import InvalidOptionError, ModelError
from onlinemap.evaluate import told_location_map
from onlinemap.studies.floors import COLUMNS, REAL_FLOORS, floor_study, floor_worlds, run_extras
from onlinemap.worlds import parse_world

FLOORS = Path(__file__).resolve().parent / "data" / "floors"
CROP = f"layout:{FLOORS / 'room-32-32-4.map'},region=0:12x0:12"  # 12 x 12 cells, rooms and doorways
STEPS = 30


@pytest.fixture(scope="module")
def study():
    return floor_study([CROP], buildings=(), planners=("frontier", "random"), seeds=[0, 1], steps=STEPS,
                       n_particles=50, progress=False)


def test_one_row_per_run_with_every_column(study):
    runs, summary = study
    assert list(runs.columns[-len(COLUMNS):]) == list(COLUMNS)
    assert sorted(zip(runs["planner"], runs["seed"])) == [("frontier", 0), ("frontier", 1), ("random", 0),
                                                          ("random", 1)]
    assert (runs["floor"] == CROP).all()
    assert runs[list(COLUMNS[:9])].notna().all().all()
    np.testing.assert_allclose(runs["excess_map_error"],
                               runs["final_map_error"] - runs["told_location_map_error"], atol=1e-12)
    assert list(summary["planner"]) == ["frontier", "random"]
    assert (summary["runs"] == 2).all()
    assert {"stalled", "died", "late_location_distance_low", "excess_map_error_high"} <= set(summary.columns)
    by_planner = runs.groupby("planner")["final_map_error"].mean()
    np.testing.assert_allclose(summary.set_index("planner")["final_map_error"], by_planner[summary["planner"]])


def test_told_location_anchor_is_evaluates_told_location_map(study):
    """The same run played again (the sweep's explore task is policies.exploration with the task's
    seed), its told-location map from evaluate, its error computed here."""
    runs, _ = study
    world = parse_world(CROP)
    found = policies.exploration(world.model, world.true_map, "frontier", "rbpf", STEPS, seed=1,
                                 estimator_options={"n_particles": 50}, progress=False)
    row = runs[(runs["planner"] == "frontier") & (runs["seed"] == 1)].iloc[0]
    final = found.run.final_map
    beliefs = found.trajectory.map[-1]
    assert row["final_map_error"] == pytest.approx(1.0 - beliefs[np.arange(len(final)), final].mean(), abs=1e-12)
    told = told_location_map(world.model, found.run)
    told_error = 1.0 - told[np.arange(len(final)), final].mean()
    assert row["told_location_map_error"] == pytest.approx(told_error, abs=1e-12)
    assert row["cells_visited"] == len(np.unique(found.run.locations))


def test_estimator_options_pass_through_as_a_grid(tmp_path):
    kwargs = dict(buildings=(), planners=("random",), seeds=[0], steps=STEPS, progress=False,
                  estimator_options={"proposal": ["transition", "optimal"]}, n_particles=[20, 40])
    runs, summary = floor_study([CROP], out=tmp_path, **kwargs)
    assert sorted(zip(runs["opt_n_particles"], runs["opt_proposal"])) == [
        (20, "optimal"), (20, "transition"), (40, "optimal"), (40, "transition")]
    assert len(summary) == 4 and runs["options"].nunique() == 4
    parts = sorted(p.name for p in Path(tmp_path).rglob("*.npz"))
    assert len(parts) == 4
    again, _ = floor_study([CROP], out=tmp_path, **kwargs)  # resumed: every task read from its part
    assert sorted(p.name for p in Path(tmp_path).rglob("*.npz")) == parts
    pd.testing.assert_frame_equal(again, runs)


def test_an_option_the_estimator_refuses_fails_before_any_run(tmp_path):
    with pytest.raises(Exception, match="no_such_option"):
        floor_study([CROP], buildings=(), planners=("random",), seeds=[0], steps=STEPS, progress=False,
                    estimator_options={"no_such_option": 1}, out=tmp_path)
    assert not list(Path(tmp_path).rglob("*.npz"))


def test_planner_options_given_flat_are_refused_before_any_run(tmp_path):
    """Regression: ``planner_options={"loop_closing": True}`` (flat, not per planner) was ignored
    silently, and the runs were those of the default planner."""
    with pytest.raises(InvalidOptionError, match="per planner name.*'loop_closing'"):
        floor_study([CROP], buildings=(), planners=("info_gain",), seeds=[0], steps=STEPS, progress=False,
                    planner_options={"loop_closing": True}, out=tmp_path)
    assert not list(Path(tmp_path).rglob("*.npz"))


def test_run_extras_by_hand():
    t = np.arange(100)
    location_error = np.linspace(0.0, 0.99, 100)
    cells = np.r_[np.arange(40), np.full(60, 7)]  # 40 distinct cells, then stays on cell 7 for 60 steps
    frame = pd.DataFrame({"t": t, "location_error": location_error, "true_location": cells,
                          "map_error": np.full(100, 0.5), "log_evidence": -np.arange(100.0)})
    extras = run_extras(frame)
    assert extras["late_location_error"] == pytest.approx(location_error[t >= 49.5].mean())
    assert extras["cells_visited"] == 40
    assert extras["stalled"] and not extras["died"]
    moving = frame.assign(true_location=np.arange(100) % 13)
    assert not run_extras(moving)["stalled"]
    assert run_extras(frame.assign(log_evidence=np.r_[np.zeros(99), -np.inf]))["died"]
    assert run_extras(frame.assign(location_error=np.r_[np.full(99, 0.5), np.nan]))["died"]


def test_floor_worlds_names_buildings_and_keys():
    worlds = floor_worlds(["room", CROP], buildings=("16x16",), building_seeds=(3, 4), world_keys="p_move=0.95")
    assert list(worlds) == ["room", CROP, "building:16x16,seed=3", "building:16x16,seed=4"]
    assert all(spec.endswith(",p_move=0.95") for spec in worlds.values())
    assert Path(worlds["room"].removeprefix("layout:").split(",")[0]).is_absolute()
    assert parse_world(worlds["building:16x16,seed=4"]).model.p_move == 0.95
    with pytest.raises(ModelError, match="neither a real floor"):
        floor_worlds(["no_such_floor"], buildings=())
    with pytest.raises(ModelError):  # a bad key fails when the study is built, not in a worker
        floor_worlds(["room"], buildings=(), world_keys="p_move=2")
    assert set(REAL_FLOORS) == {"maze", "room", "random", "arena", "tb3_world", "nav2_depot"}


@pytest.mark.parametrize("spec", ["building:16x16,seed=2", CROP, "door"])
def test_label_prior_floor_is_the_maps_label_frequencies(spec):
    plain = parse_world(spec)
    told = parse_world(spec + ",label_prior=floor")
    np.testing.assert_array_equal(told.true_map, plain.true_map)
    counts = {label: int(np.sum(plain.true_map == label)) for label in range(plain.model.n_labels)}
    expected = np.array([counts[label] / plain.model.n_cells for label in range(plain.model.n_labels)])
    np.testing.assert_allclose(told.model.label_prior, np.tile(expected, (plain.model.n_cells, 1)), atol=1e-15)
    assert told.label_prior == "floor" and plain.label_prior is None
    np.testing.assert_array_equal(told.model.sensor, plain.model.sensor)


@pytest.mark.parametrize("spec, message", [
    ("building:16x16,label_prior=learn", "label_prior takes 'floor'"),
    ("building:16x16,label_prior=floor,floor_plan=0.9", "give one"),
    ("grid:3x3,label_prior=floor", "unknown option 'label_prior'"),
])
def test_label_prior_key_refused(spec, message):
    with pytest.raises(ModelError, match=message):
        parse_world(spec)


def test_world_list_keeps_a_specs_keys_with_it():
    from onlinemap.cli.reproduce import world_list

    assert world_list("maze, layout:a.map,cell_size=2,region=0:12x0:12,room") == [
        "maze", "layout:a.map,cell_size=2,region=0:12x0:12", "room"]
    assert world_list("building:16x16,seed=3") == ["building:16x16,seed=3"]


def test_command_line_writes_the_tables(tmp_path, capsys):
    from onlinemap.cli import main

    status = main(["--no-progress", "reproduce", "floors", "--floors", CROP, "--buildings", "", "--planners",
                   "random", "--runs", "1", "--steps", str(STEPS), "-o", "n_particles=50", "--out", str(tmp_path)])
    assert status == 0
    printed = capsys.readouterr().out
    assert "told_location_map_error" in printed and "excess_map_error" in printed
    runs = pd.read_csv(tmp_path / "floors_runs.csv")
    assert list(runs.columns[-len(COLUMNS):]) == list(COLUMNS) and len(runs) == 1
    assert (tmp_path / "floors.parts").is_dir()
