"""``onlinemap compare`` and the accuracy study behind it."""

import numpy as np
import pandas as pd

import onlinemap.compare as compare
from onlinemap.cli import main
from onlinemap.compare import accuracy_study, compare_estimators, summarise


def test_study_distances_and_ordering():
    per_step = accuracy_study(["corridor:8"], n_runs=3, n_steps=30, particles=(10, 1000), seed=1, progress=False)
    summary = summarise(per_step).set_index("estimator")
    exact = summary.loc["exact"]
    assert exact["mean_location_tv"] == 0 and exact["worst_map_tv"] == 0
    assert per_step.groupby("estimator").size().nunique() == 1  # every estimator: runs x steps rows
    assert set(per_step["world"]) == {"corridor:8"} and per_step["run"].nunique() == 3
    assert np.all((per_step[["location_tv", "map_tv", "map_error"]] >= 0).to_numpy())
    assert np.all((per_step[["location_tv", "map_tv"]] <= 1 + 1e-12).to_numpy())
    for proposal in ("optimal", "transition"):  # more particles, closer to exact, and closer than bk
        many, few = summary.loc[f"rbpf {proposal} P=1000"], summary.loc[f"rbpf {proposal} P=10"]
        assert many["mean_map_tv"] < few["mean_map_tv"] / 2
        assert many["mean_map_tv"] < summary.loc["bk", "mean_map_tv"]
    assert summary.loc["dead_reckoning", "mean_map_error"] == 0.5  # uniform prior, binary labels


def test_online_em_only_if_registered(monkeypatch):
    names = [label for label, _, _ in compare_estimators((5,))]
    assert names == ["bk", "rbpf optimal P=5", "rbpf transition P=5", "online_em", "dead_reckoning"]
    monkeypatch.setattr(compare, "available_estimators", lambda: ("exact", "bk", "rbpf", "dead_reckoning"))
    assert "online_em" not in [label for label, _, _ in compare_estimators((5,))]


def test_cli_writes_tables_and_figures(tmp_path, capsys):
    out = tmp_path / "cmp"
    code = main(["compare", "--world", "corridor:5", "--world", "grid:2x2,p_change=0.05", "--runs", "2",
                 "--steps", "8", "--particles", "10,50", "--seed", "3", "--out", str(out)])
    assert code == 0
    printed = capsys.readouterr().out
    assert "worst_location_tv" in printed and "rbpf transition P=50" in printed
    summary = pd.read_csv(out / "compare_summary.csv")
    assert set(summary["world"]) == {"corridor:5", "grid:2x2,p_change=0.05"}
    assert len(pd.read_csv(out / "compare_steps.csv")) == 2 * 2 * 8 * summary["estimator"].nunique()
    for name in ("compare_error_vs_particles.png", "compare_error_over_time.png"):
        assert (out / name).stat().st_size > 10_000


def test_cli_refuses_bad_arguments(capsys):
    assert main(["compare", "--particles", "ten", "--runs", "1", "--steps", "2"]) == 2
    assert "--particles" in capsys.readouterr().err
    assert main(["compare", "--world", "corridor:30", "--runs", "1", "--steps", "2"]) == 2
    assert "max_bytes" in capsys.readouterr().err  # too big for exact: a clear error
