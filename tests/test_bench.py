"""``onlinemap bench``: all benchmarks in one table, JSON records, and the peers benchmark
(onlinemap vs pgmpy / hmmlearn in one process, answers checked to agree)."""

import json
import sys

import numpy as np
import pytest

from onlinemap.bench import run_benchmarks
from onlinemap.cli import main


@pytest.fixture
def no_pgmpy(monkeypatch):
    monkeypatch.setitem(sys.modules, "pgmpy", None)  # import pgmpy now raises ImportError
    monkeypatch.setitem(sys.modules, "pgmpy.inference", None)


def test_bench_peers_without_peer_libraries_says_how_to_install(no_pgmpy, capsys):
    assert main(["bench", "peers"]) == 2
    assert "pip install pgmpy==1.1.2 hmmlearn==0.3.3 filterpy==2.0.0" in capsys.readouterr().err


def test_bench_with_no_name_runs_everything_else_and_writes_json(no_pgmpy, monkeypatch, tmp_path, capsys):
    from onlinemap import bench
    from onlinemap.bench.peers import bench_peers

    def tiny(quick):
        return [{"case": "a", "ms": 2.0, "reference": "r", "reference_ms": 1.0, "ratio": 2.0, "target": 3.0},
                {"case": "b", "ms": 1.0, "reference": "r", "reference_ms": 1.0, "ratio": 1.0, "target": np.nan}]

    monkeypatch.setattr(bench, "BENCHMARK_MODULES", ())
    monkeypatch.setattr(bench, "_BENCHMARKS", {"tiny": tiny, "peers": bench_peers})
    path = tmp_path / "history.jsonl"
    for _ in range(2):
        assert main(["bench", "--quick", "--json", str(path)]) == 0
    out = capsys.readouterr()
    assert "skipped peers" in out.err and "1 of 1 targets met" in out.out
    records = [json.loads(line) for line in path.read_text().splitlines()]
    assert len(records) == 2  # .jsonl appends: a history
    record = records[0]
    assert set(record["skipped"]) == {"peers"}
    assert record["machine"]["onlinemap"] and record["machine"]["cpu_count"] >= 1
    assert [row["case"] for row in record["rows"]] == ["a", "b"]
    assert record["rows"][0]["meets_target"] is True and record["rows"][1]["target"] is None  # NaN -> null
    single = tmp_path / "bench.json"
    assert main(["bench", "tiny", "--json", str(single)]) == 0
    assert json.loads(single.read_text())["rows"][0]["benchmark"] == "tiny"


def test_bench_peers_agrees_with_pgmpy_and_hmmlearn_and_shows_filterpys_residual_bias():
    pytest.importorskip("pgmpy")
    pytest.importorskip("hmmlearn")
    pytest.importorskip("filterpy")
    table = run_benchmarks(["peers"], quick=True)
    assert set(table["reference"]) == {"pgmpy VariableElimination", "hmmlearn CategoricalHMM", "filterpy monte_carlo"}
    exact = table[table["reference"] != "filterpy monte_carlo"]
    assert np.all(exact["max_abs_diff"] < 1e-9)
    assert np.all(table["ms"] > 0) and np.all(table["reference_ms"] > 0)
    # resampling: copy shares agree within the row's tolerance (5 standard deviations of the
    # difference), but for filterpy's biased residual scheme (shares [.6875, .3125, 0, 0], not
    # [.5, .3, .15, .05]: a difference of .1875 in particle 0's, against a tolerance of .11)
    resampling = table[table["reference"] == "filterpy monte_carlo"]
    resampling = resampling.set_index(resampling["case"].str.split().str[0])
    assert sorted(resampling.index) == ["multinomial", "residual", "stratified", "systematic"]
    unbiased = resampling.drop(index="residual")
    assert np.all(unbiased["max_abs_diff"] <= unbiased["tolerance"])
    assert resampling.loc["residual", "max_abs_diff"] > resampling.loc["residual", "tolerance"]
    assert resampling.loc["residual", "copy_shares"].startswith("filterpy [0.69, 0.31, 0.0, 0.0]")


def test_bench_rbpf_per_particle_rows():
    """The rows of ``bench rbpf`` per particle (issue 25), on tiny worlds: update and belief for
    each size and thread count, beside a copy pass of the filter's bytes in use, and blocking +
    cross against the paper model per live particle (no timing is checked)."""
    import onlinemap as om
    from onlinemap.bench.rbpf import per_particle_rows

    worlds = {"door 10x10": (*om.door_world(), (60,)),
              "door 10x10 blocking+cross": (*om.door_world(blocking=True, footprint="cross"), (60,))}
    rows = per_particle_rows(True, worlds, thread_counts=[1])
    assert [row["case"].split(": ")[1] for row in rows] == ["update", "belief", "update", "belief",
                                                            "update against the paper model's"]
    for row in rows:
        assert row["ms"] > 0 and row["reference_ms"] > 0 and 0 < row["live"] <= 60
        assert 0 < row["bytes_per_particle"] <= row["allocated_bytes_per_particle"]
    cross = rows[-1]
    assert cross["target"] == 2.0 and cross["reference_ms"] == pytest.approx(rows[0]["ms"] * cross["live"] / 60)


def test_bench_rbpf_replay_rows_replay_what_replay_study_replays():
    """The replay rows (issue 21) on a short run: the live run and the 1000-particle FC replay are
    those of ``replay_study`` on seed 0 (the sweep engine's path: world spec, planner defaults,
    filter seed, scoring), computed independently; before any window ends ``move_lag`` = 100
    steps back the move filter has not moved, so it equals FC; the targets are set where the issue
    puts them and the map-error verdict follows the number (no timing is checked)."""
    from onlinemap.bench.rbpf import MAP_ERROR_TARGET, replay_rows
    from onlinemap.studies.exploration import replay_study

    rows = replay_rows(60, 2000, replays=1, reference_note="; test")
    assert [row["case"] for row in rows] == [
        "replay info_gain paper world, 60 steps P=1000: FC",
        "replay info_gain paper world, 60 steps P=1000: FC + move_window=20",
        "replay info_gain paper world, 60 steps P=2000: FC (reference filter; test)"]
    fc, move, reference = rows
    study = replay_study("info_gain", seeds=[0], steps=60, replay_particles=(1000,), replays=1, progress=False)
    errors = study.set_index("filter")["final_map_error"]
    assert fc["live_map_error"] == pytest.approx(errors["live"], abs=1e-12)
    assert fc["map_error"] == pytest.approx(errors["rbpf 1000"], abs=1e-12)
    assert move["map_error"] == fc["map_error"]
    assert reference["map_error"] == fc["reference_map_error"] == move["reference_map_error"]
    for row in rows:
        assert row["ms"] > 0 and row["reference_ms"] == fc["ms"] and 0 <= row["map_error"] <= 1
    assert np.isnan(fc["target"]) and move["target"] == 2.0 and np.isnan(reference["target"])
    assert move["map_error_target"] == MAP_ERROR_TARGET == 0.19
    assert move["meets_map_error_target"] == (move["map_error"] <= 0.19) and fc["meets_map_error_target"] is None
