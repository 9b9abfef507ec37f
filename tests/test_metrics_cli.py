"""Metrics by hand, and the command line end to end."""

import json

import numpy as np
import pandas as pd
import pytest

import onlinemap as om
from onlinemap.cli import main


def test_metrics_by_hand():
    maps = np.array([[0.9, 0.1], [0.25, 0.75], [0.5, 0.5]])
    assert om.metrics.map_error(maps, np.array([0, 1, 1])) == pytest.approx(1 - (0.9 + 0.75 + 0.5) / 3)
    assert om.metrics.location_error(np.array([0.2, 0.8]), 1) == pytest.approx(0.2)
    assert om.metrics.total_variation([0.2, 0.8], [0.5, 0.5]) == pytest.approx(0.3)
    assert om.metrics.normalized_entropy([0.25] * 4) == pytest.approx(1.0)
    assert om.metrics.normalized_entropy([1.0, 0.0]) == pytest.approx(0.0)
    over_time = np.stack([maps, maps])
    np.testing.assert_allclose(om.metrics.map_error(over_time, np.array([[0, 1, 1]] * 2)),
                               [1 - 2.15 / 3] * 2)
    assert om.metrics.wrong_cells(maps, [1, 1, 0]) == 1


def test_map_error_reads_the_true_label_not_the_most_likely_one():
    """Every true label below is not the most likely one (argmax is [0, 2, 1]): a map_error that
    ignored the true map (scoring the argmax, or the max probability) would give 1 - 1.9 / 3."""
    maps = np.array([[0.6, 0.3, 0.1], [0.2, 0.2, 0.6], [0.1, 0.7, 0.2]])
    truth = np.array([1, 0, 2])  # P(true label) = 0.3, 0.2, 0.2
    assert om.metrics.map_error(maps, truth) == pytest.approx(1 - 0.7 / 3)
    assert om.metrics.wrong_cells(maps, truth) == 3
    # over time, a different true map at each step (the map changes): each step reads its own
    binary = np.array([[0.9, 0.1], [0.25, 0.75], [0.5, 0.5]])
    truths = np.array([[0, 1, 1], [1, 0, 0]])  # step 1: P(true) = 0.1, 0.25, 0.5
    np.testing.assert_allclose(om.metrics.map_error(np.stack([binary, binary]), truths),
                               [1 - 2.15 / 3, 1 - 0.85 / 3])


def test_cli_run_table_and_out(tmp_path, capsys):
    assert main(["run", "--world", "corridor:6", "--steps", "30", "--seed", "1", "--out", str(tmp_path)]) == 0
    text = capsys.readouterr().out
    assert "exact" in text and "dead_reckoning" in text
    assert len(pd.read_csv(tmp_path / "summary.csv")) == 2
    frame = pd.read_csv(tmp_path / "steps.csv")
    assert set(frame.estimator) == {"exact", "dead_reckoning"} and len(frame) == 60
    final = frame[frame.t == 29].set_index("estimator")
    assert final.loc["exact", "map_error"] < final.loc["dead_reckoning", "map_error"]


def test_cli_door_world_skips_exact_with_reason(caplog):
    assert main(["run", "--world", "door", "--steps", "5"]) == 0
    assert "exact: skipped" in caplog.text and "limit" in caplog.text


def test_cli_errors_are_clear(capsys):
    with pytest.raises(SystemExit) as exit_info:  # a usage error, found while parsing the arguments
        main(["run", "--world", "maze:3"])
    assert exit_info.value.code == 2 and "unknown kind" in capsys.readouterr().err
    assert main(["run", "--estimators", "nope"]) == 2
    with pytest.raises(SystemExit):
        main(["--help"])
    assert "run" in capsys.readouterr().out


def test_cli_bench_quick_json(tmp_path, capsys):
    path = tmp_path / "b.json"
    assert main(["bench", "exact", "--quick", "--json", str(path)]) == 0
    record = json.loads(path.read_text())  # machine info, versions and the rows
    rows = record["rows"]
    assert record["machine"]["numba"] and record["quick"] is True
    assert {r["case"] for r in rows} >= {"corridor:8 static", "corridor:8 dynamic"}
    assert all(r["ratio"] > 0 for r in rows)
