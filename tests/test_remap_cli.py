"""``onlinemap remap``: a run read from track-style JSON lines is remapped and scored (the table's
numbers match the library's on the same run), --out writes remap.csv, bad input is one line, exit 2."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from onlinemap.hindsight import hindsight_map
from onlinemap.worlds import parse_world
from test_cli import assert_one_line_error, cli

WORLD = "grid:3x4,p_move=0.9"


def write_run(path, run, with_locations=True):
    with open(path, "w") as out:
        for t in range(run.n_steps):
            record = {"observation": int(run.observations[t])}
            if t:
                record["action"] = run.model.action_names[run.actions[t - 1]]
            if with_locations:
                record["location"] = int(run.locations[t])
            out.write(json.dumps(record) + "\n")


def test_remap_reads_a_run_and_scores_it(tmp_path):
    spec = parse_world(WORLD)
    run = spec.simulate(30, 4)
    write_run(tmp_path / "run.jsonl", run)
    code, out, err = cli(["remap", "--world", WORLD, "--seed", "4", "--input", str(tmp_path / "run.jsonl"),
                          "--estimator", "bk", "--stretch", "3", "--out", str(tmp_path / "out")])
    assert code == 0, err
    table = pd.read_csv(tmp_path / "out" / "remap.csv")
    assert list(table["method"]) == ["filter (bk)", "flat_em", "layered_em", "told_location"]
    errors = dict(zip(table["method"], table["final_map_error"]))
    expected = hindsight_map(spec.model, run, "told_location").map[np.arange(12), run.final_map]
    assert errors["told_location"] == pytest.approx(1 - expected.mean())
    assert "layered_em" in out


def test_remap_without_locations_leaves_the_told_location_map_out(tmp_path):
    run = parse_world(WORLD).simulate(20, 1)
    write_run(tmp_path / "run.jsonl", run, with_locations=False)
    code, out, err = cli(["remap", "--world", WORLD, "--seed", "1", "--input", str(tmp_path / "run.jsonl"),
                          "--estimator", "bk", "--methods", "flat_em"])
    assert code == 0, err
    assert "flat_em" in out and "told_location" not in out


@pytest.mark.parametrize("lines, word", [(["{\"observation\": 0}", "not json"], "line 2"),
                                         (["{\"observation\": 0}", "{\"action\": \"up\", \"observation\": 0}"], "up")])
def test_remap_refuses_bad_input_in_one_line(tmp_path, lines, word):
    (tmp_path / "bad.jsonl").write_text("\n".join(lines) + "\n")
    code, _, err = cli(["remap", "--world", WORLD, "--input", str(tmp_path / "bad.jsonl")])
    assert_one_line_error(code, err, word)


def test_remap_refuses_an_unknown_method():
    code, _, err = cli(["remap", "--world", WORLD, "--methods", "smoothed"])
    assert_one_line_error(code, err, "smoothed")


def test_remap_with_a_learned_label_prior(tmp_path):
    """--label-prior learn: layered EM and the told-location map with the learned frequencies,
    the same numbers as the library's."""
    spec = parse_world(WORLD)
    run = spec.simulate(30, 4)
    write_run(tmp_path / "run.jsonl", run)
    code, out, err = cli(["remap", "--world", WORLD, "--seed", "4", "--input", str(tmp_path / "run.jsonl"), "--estimator", "bk",
                          "--methods", "layered_em", "--label-prior", "learn", "--out", str(tmp_path / "out")])
    assert code == 0, err
    errors = dict(pd.read_csv(tmp_path / "out" / "remap.csv")[["method", "final_map_error"]].values)
    for method in ("layered_em", "told_location"):
        belief = hindsight_map(spec.model, run, method, label_prior="learn").map
        assert errors[method] == pytest.approx(1 - belief[np.arange(12), run.final_map].mean())


def test_remap_with_the_smoother_and_the_learned_alignment(tmp_path):
    """--methods rbpf_smoothed,layered_em_learned_alignment: the smoother's replay (--particles,
    seed --seed) adds the row rbpf_filtered; the numbers are the library's on the same run."""
    from onlinemap.hindsight import smoothed_rbpf_map

    spec = parse_world(WORLD)
    run = spec.simulate(30, 4)
    write_run(tmp_path / "run.jsonl", run)
    code, out, err = cli(["remap", "--world", WORLD, "--seed", "4", "--input", str(tmp_path / "run.jsonl"),
                          "--estimator", "bk", "--methods", "rbpf_smoothed,layered_em_learned_alignment",
                          "--particles", "50", "--out", str(tmp_path / "out")])
    assert code == 0, err
    errors = dict(pd.read_csv(tmp_path / "out" / "remap.csv")[["method", "final_map_error"]].values)
    smoothed = smoothed_rbpf_map(spec.model, run.actions, run.observations, n_particles=50, seed=4)
    expected = {"rbpf_smoothed": smoothed.map, "rbpf_filtered": smoothed.filtered,
                "layered_em_learned_alignment": hindsight_map(spec.model, run, "layered_em_learned_alignment").map}
    for method, belief in expected.items():
        assert errors[method] == pytest.approx(1 - belief[np.arange(12), run.final_map].mean())
