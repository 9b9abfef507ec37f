"""Experiment sweeps (issue 6): a dask cluster gives the serial table, interrupted sweeps
finish every task exactly once, malformed specs are refused before any task runs with the
line named, summaries' intervals match textbook values, tasks reproduce ``onlinemap run``."""

import os
import signal
import subprocess
import sys
import threading
import time
import tomllib
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy import stats

import onlinemap as om
from onlinemap import sweeps
from onlinemap.cli import main
from onlinemap.evaluate import compare_on_run
from onlinemap.stats import mean_interval

ROOT = Path(__file__).resolve().parents[1]
SPEC = """\
name = "small"
worlds = ["corridor:5", "corridor:5,p_change=0.02"]
seeds = 3
steps = 15
reference = "exact"

[estimators.exact]

[estimators.dead_reckoning]

[estimators.rbpf]
n_particles = [10, 40]
"""
N_TASKS = 2 * (1 + 1 + 2) * 3


def without_timing(table: pd.DataFrame) -> pd.DataFrame:
    return table.drop(columns=["ms_per_step"]).reset_index(drop=True)


@pytest.fixture(scope="module")  # started once: the test command runs a file on one worker (conftest)
def client():
    distributed = pytest.importorskip("distributed")
    cluster = sweeps.local_cluster(workers=2)
    client = distributed.Client(cluster)
    yield client
    client.close()
    cluster.close()


@pytest.fixture(scope="module")
def serial_table():
    return sweeps.sweep(sweeps.parse_spec(SPEC), workers=0, progress=False)


def write_spec(tmp_path: Path, text: str = SPEC, name: str = "spec.toml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


# --- the table -------------------------------------------------------------------------------
def test_serial_table_has_one_row_per_task_with_sane_metrics(serial_table):
    assert len(serial_table) == N_TASKS and serial_table["task"].is_unique
    assert set(serial_table["estimator"]) == {"exact", "dead_reckoning", "rbpf"}
    for column in ("final_map_error", "final_location_error", "mean_map_tv", "mean_location_tv"):
        assert serial_table[column].between(0, 1).all()
    exact = serial_table[serial_table["estimator"] == "exact"]
    assert (exact[["final_location_tv", "mean_map_tv"]] == 0).all().all()  # its own reference
    rbpf = serial_table[serial_table["estimator"] == "rbpf"]
    assert sorted(set(rbpf["opt_n_particles"])) == [10, 40]


def test_a_task_reproduces_onlinemap_run_with_the_same_seed(serial_table):
    world = om.worlds.parse_world("corridor:5,p_change=0.02")
    seed = 2
    rng = np.random.default_rng(seed)  # exactly what `onlinemap run --seed 2 --steps 15` does
    true_map = world.initial_map(rng)
    run = om.simulate(world.model, true_map, om.random_walk(world.model, 14, rng), rng)
    summary, _ = compare_on_run(run, ["exact", "dead_reckoning"], progress=False)
    mine = serial_table[(serial_table["world"] == world.spec) & (serial_table["seed"] == seed)]
    for name in ("exact", "dead_reckoning"):
        row = mine[mine["estimator"] == name].iloc[0]
        theirs = summary[summary["estimator"] == name].iloc[0]
        assert row["final_map_error"] == pytest.approx(theirs["final_map_error"], abs=1e-12)
        assert row["mean_location_error"] == pytest.approx(theirs["mean_location_error"], abs=1e-12)


def test_per_step_rows_end_with_the_per_task_values(serial_table):
    spec = sweeps.parse_spec(SPEC.replace('reference = "exact"', 'reference = "exact"\nrows = "step"'))
    steps = sweeps.sweep(spec, workers=0, progress=False)
    assert len(steps) == N_TASKS * 15
    last = steps[steps["t"] == 14].reset_index(drop=True)
    np.testing.assert_allclose(last["map_error"], serial_table["final_map_error"], atol=1e-12)
    np.testing.assert_allclose(last["map_tv"], serial_table["final_map_tv"], atol=1e-12)
    means = steps.groupby("task", sort=False)["location_error"].mean().to_numpy()
    np.testing.assert_allclose(means, serial_table["mean_location_error"], atol=1e-12)


# --- malformed specs ---------------------------------------------------------------------------
BAD_SPECS = [  # (replace this, with that, the line the error must name, words in the message)
    ("[estimators.rbpf]", "[estimators.rbfp]", 11, "unknown estimator 'rbfp'"),
    ("n_particles = [10, 40]", "n_particle = [10, 40]", 12, "unknown option"),
    ("n_particles = [10, 40]", 'n_particles = [10, "forty"]', 12, "expected int, got 'forty'"),
    ("n_particles = [10, 40]", "n_particles = 2.5", 12, "expected int"),
    ("n_particles = [10, 40]", "n_particles = [10, 0]", 11, "n_particles=0"),  # refused by rbpf itself
    ('steps = 15', 'steps = "15"', 4, "steps"),
    ('seeds = 3', 'seeds = -1', 3, "seeds"),
    ('worlds = ["corridor:5", "corridor:5,p_change=0.02"]', 'worlds = ["corridor:5", "coridor:5"]', 2,
     "unknown kind 'coridor'"),
    ('reference = "exact"', 'reference = "exakt"', 5, "unknown estimator 'exakt'"),
    ('reference = "exact"', 'reference = "exact"\nwalk = "zigzag"', 6, "walk"),
    ('name = "small"', 'name = "small"\nsed = 3', 2, "unknown key"),
    ("[estimators.exact]", "[estimators.exact]\nmax_bytes = 1000", 7, "MemoryLimitError"),
    ("steps = 15", "steps = 15 20", 4, "not valid TOML"),  # tomllib's own position
    ('seeds = 3', 'seeds = 3\nfloor_plan = 0.8', 4, "exploration sweeps"),
]


@pytest.mark.parametrize("old, new, line, words", BAD_SPECS, ids=[b[3] for b in BAD_SPECS])
def test_malformed_spec_is_refused_before_any_task_runs_naming_the_line(tmp_path, old, new, line, words):
    assert old in SPEC
    path = write_spec(tmp_path, SPEC.replace(old, new))
    results = tmp_path / "results.parts"
    with pytest.raises(om.SpecError) as error:
        om.sweep(path, workers=0, results_dir=results, progress=False)
    message = str(error.value)
    assert f"line {line}" in message, message
    assert str(path) in message and words in message, message
    assert not results.exists()  # nothing ran, nothing was written


def test_malformed_spec_on_the_command_line_exits_2_with_the_line(tmp_path, capsys):
    path = write_spec(tmp_path, SPEC.replace("[estimators.rbpf]", "[estimators.nope]"))
    assert main(["sweep", str(path), "--workers", "0", "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err
    assert f"{path}, line 11: estimators.nope: unknown estimator 'nope'" in err
    assert not (tmp_path / "r" / "parts").exists()


def test_command_line_runs_a_spec_writes_csv_and_summarises(tmp_path, capsys):
    path = write_spec(tmp_path, SPEC.replace("seeds = 3", "seeds = 2"))
    assert main(["sweep", str(path), "--check"]) == 0
    assert f"{N_TASKS // 3 * 2} tasks" in capsys.readouterr().out
    out = tmp_path / "r"
    command = ["sweep", str(path), "--workers", "0", "--out", str(out), "--format", "csv", "--no-progress"]
    assert main(command) == 0
    printed = capsys.readouterr().out
    assert "final_map_error" in printed and "mean_map_tv" in printed and "n_particles=10" in printed
    table = pd.read_csv(out / "results.csv")
    assert len(table) == N_TASKS // 3 * 2 and (out / "parts").is_dir()
    assert main(command) == 0
    assert f"{N_TASKS // 3 * 2} already finished" in capsys.readouterr().out
    assert main(["sweep", "--summary", str(out), "--metrics", "final_map_error"]) == 0  # a sweep's DIR
    assert "final_map_error" in capsys.readouterr().out
    (tmp_path / "file").write_text("")
    assert "a directory is expected" in _one_error_line(capsys, ["sweep", str(path), "--out", str(tmp_path / "file")])


def test_array_of_tables_errors_name_the_right_table(tmp_path):
    text = 'worlds = ["corridor:4"]\nseeds = 1\n[[estimators.online_em]]\nwindow = "max"\n' \
           '[[estimators.online_em]]\nwindow = [1, 2]\ndecay = [0.9, "high"]\n'
    with pytest.raises(om.SpecError, match=r"line 7: estimators.online_em\[1\].decay: expected float"):
        sweeps.parse_spec(text, source="s.toml")
    good = sweeps.parse_spec(text.replace(', "high"', ""))
    assert [dict(t.options) for t in good.tasks] == [{"window": "max"}, {"decay": 0.9, "window": 1},
                                                      {"decay": 0.9, "window": 2}]
    repeated = sweeps.parse_spec(text.replace(', "high"', "").replace('window = [1, 2]', 'window = [1, 2, 1]')
                                 .replace('["corridor:4"]', '["corridor:4", "corridor:4"]'))
    assert repeated.tasks == good.tasks  # a repeated world or grid value is one task, run once


def test_a_list_valued_option_is_a_list_of_lists(tmp_path):
    text = 'worlds = ["corridor:4"]\nseeds = 1\n[estimators.offline_em]\nanneal = [1.0, 0.9, 0.1]\n'
    with pytest.raises(om.SpecError, match="line 4.*list of lists"):
        sweeps.parse_spec(text)
    spec = sweeps.parse_spec(text.replace("[1.0, 0.9, 0.1]", "[[1.0, 0.9, 0.1]]"))
    assert dict(spec.tasks[0].options) == {"anneal": (1.0, 0.9, 0.1)}


def test_scripted_trip_is_the_literature_run_with_one_random_slip():
    model = om.corridor(7)
    labels = np.array([0, 1, 1, 0, 1, 0, 0])
    slips = set()
    for seed in range(40):
        run = sweeps.scripted_trip(model, labels, np.random.default_rng(seed))
        assert run.model is model and list(run.actions) == [1] * 6 + [0] * 6
        assert run.slipped.sum() == 1 and np.flatnonzero(run.slipped)[0] < 6  # one slip, on the way out
        np.testing.assert_array_equal(run.observations, labels[run.locations])  # noise-free
        slips.add(int(np.flatnonzero(run.slipped)[0]))
    assert slips == set(range(6))  # every outward move can be the one that fails
    with pytest.raises(om.SpecError, match='line 2: walk: .*needs steps = "trip"'):
        sweeps.parse_spec('worlds = ["corridor:5"]\nwalk = "scripted_trip"\nsteps = 9\n[estimators.exact]\n')
    with pytest.raises(om.SpecError, match="line 2: walk: .*static"):
        sweeps.parse_spec('worlds = ["corridor:5,p_change=0.1"]\nwalk = "scripted_trip"\nsteps = "trip"\n'
                          '[estimators.exact]\n')
    for world in ("corridor:5,footprint=cross", "corridor:5,blocking=1"):  # it writes one true label per step
        with pytest.raises(om.SpecError, match="line 2: walk: .*own cell"):
            sweeps.parse_spec(f'worlds = ["{world}"]\nwalk = "scripted_trip"\nsteps = "trip"\n[estimators.exact]\n')


# --- resuming: every task exactly once -----------------------------------------------------------
STALL_AFTER_FIVE_PARTS = """\
import sys, threading
from pathlib import Path
from onlinemap.sweeps import store
real = store.atomic_write

def stalling(path, write):  # the sixth part: its temporary file written, then the process waits to be killed
    if len(list(Path(path).parent.glob("*.npz"))) < 5:
        return real(path, write)

    def half(file):
        write(file)
        file.flush()
        Path({marker!r}).touch()
        threading.Event().wait()
    return real(path, half)

store.atomic_write = stalling
from onlinemap.cli import main
sys.exit(main({argv!r}))
"""


def test_killed_sweep_resumes_and_finishes_every_task_exactly_once(tmp_path, serial_table):
    """kill -9 in the middle of writing a part: the resumed sweep keeps the finished parts, removes
    the temporary and runs every other task once. The child stalls at a known point (after five
    parts, inside the sixth's write) instead of being killed after a guessed delay: under load the
    test process could be starved while the whole sweep finished (issue 24 item 13)."""
    spec_path = write_spec(tmp_path, SPEC.replace(
        "[estimators.exact]", "[estimators.offline_em]\nn_iter = 30\n\n[estimators.exact]"))
    spec = sweeps.load_spec(spec_path)
    out = tmp_path / "r"
    parts, marker = out / "parts", tmp_path / "stalled"
    argv = ["sweep", str(spec_path), "--workers", "0", "--out", str(out), "--no-progress"]
    with open(tmp_path / "stderr.txt", "w") as stderr:
        process = subprocess.Popen([sys.executable, "-c", STALL_AFTER_FIVE_PARTS.format(marker=str(marker), argv=argv)],
                                   stdout=subprocess.DEVNULL, stderr=stderr)
        deadline = time.monotonic() + 600  # only against a hang: the child waits for the kill
        while not marker.exists() and process.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        process.send_signal(signal.SIGKILL)  # no chance to clean up
        process.wait()
    assert marker.exists(), (tmp_path / "stderr.txt").read_text()
    kept = {p.name: p.stat().st_mtime_ns for p in parts.glob("*.npz")}
    assert len(kept) == 5 and len(list(parts.glob(".*.tmp"))) == 1  # the sixth part, half written
    table = om.sweep(spec_path, workers=0, out=out / "results.parquet", results_dir=parts, progress=False)
    assert {p.name: p.stat().st_mtime_ns for p in parts.glob("*.npz") if p.name in kept} == kept  # not rerun
    assert not list(parts.glob(".*.tmp")) and len(list(parts.glob("*.npz"))) == len(spec.tasks)
    assert len(table) == len(spec.tasks) and table["task"].is_unique
    assert set(table["task"]) == {t.key for t in spec.tasks}
    fresh = om.sweep(spec, workers=0, progress=False)
    pd.testing.assert_frame_equal(without_timing(table), without_timing(fresh))
    pd.testing.assert_frame_equal(without_timing(pd.read_parquet(out / "results.parquet")), without_timing(fresh))


def test_rerunning_a_finished_sweep_runs_nothing_and_ignores_stale_results(tmp_path, monkeypatch):
    spec = sweeps.parse_spec(SPEC)
    parts = tmp_path / "parts"
    first = om.sweep(spec, workers=0, results_dir=parts, progress=False)
    stale = sweeps.Task("corridor:5", "exact", (), 99, 15)  # e.g. from an older version of the spec
    sweeps.write_part(parts, stale, sweeps.run_task(stale))
    monkeypatch.setattr(sweeps.runner, "played_rows", lambda task: pytest.fail("a finished task ran again"))
    again = om.sweep(spec, workers=0, results_dir=parts, progress=False)
    pd.testing.assert_frame_equal(first, again)  # timings too: the same files
    assert stale.key not in set(again["task"])


def test_failed_tasks_are_reported_and_the_rest_kept(tmp_path, monkeypatch):
    spec = sweeps.parse_spec(SPEC)
    real = sweeps.runner.played_rows
    monkeypatch.setattr(sweeps.runner, "played_rows",
                        lambda task: real(task) if task.seed != 1 else (_ for _ in ()).throw(RuntimeError("boom")))
    with pytest.raises(om.SweepError, match=f"{N_TASKS // 3} of {N_TASKS} tasks failed.*boom"):
        om.sweep(spec, workers=0, results_dir=tmp_path, progress=False)
    assert len(list(tmp_path.glob("*.npz"))) == N_TASKS - N_TASKS // 3
    monkeypatch.setattr(sweeps.runner, "played_rows", real)
    assert len(om.sweep(spec, workers=0, results_dir=tmp_path, progress=False)) == N_TASKS


# --- summaries ---------------------------------------------------------------------------------
def test_mean_interval_matches_textbook_values():
    values = np.array([0.1, 0.4, 0.35, 0.2, 0.3])
    low, high = stats.t.interval(0.9, len(values) - 1, loc=values.mean(), scale=stats.sem(values))
    assert mean_interval(values, 0.9) == pytest.approx((values.mean(), low, high))
    # Wilson score interval: 0 successes in 10 at 95% gives [0, z^2 / (n + z^2)] = [0, 0.2775]
    assert mean_interval(np.zeros(10), proportion=True) == pytest.approx((0, 0, 0.27753), abs=1e-5)
    # 7 of 10: (0.3968, 0.8922) (Wilson 1927; e.g. Newcombe 1998, table I)
    ones = np.array([1] * 7 + [0] * 3)
    assert mean_interval(ones, proportion=True) == pytest.approx((0.7, 0.3968, 0.8922), abs=1e-4)


def test_summary_groups_configurations_over_seeds(serial_table, tmp_path, capsys):
    summary = om.summarize(serial_table, ["final_map_error", "failed"])
    assert set(summary["n"]) == {3}
    assert len(summary) == 2 * 4 * 2  # worlds x configurations x metrics
    one = serial_table[(serial_table["world"] == "corridor:5") & (serial_table["estimator"] == "exact")]
    row = summary[(summary["world"] == "corridor:5") & (summary["estimator"] == "exact")
                  & (summary["metric"] == "final_map_error")].iloc[0]
    assert row["mean"] == pytest.approx(one["final_map_error"].mean())
    path = tmp_path / "r.parquet"
    serial_table.to_parquet(path)
    assert main(["sweep", "--summary", str(path), "--metrics", "final_map_error,failed"]) == 0
    out = capsys.readouterr().out
    assert "n_particles=40" in out and "final_map_error" in out and "[" in out


def test_plot_against_an_option_draws_one_line_per_configuration(serial_table, tmp_path):
    import matplotlib

    matplotlib.use("Agg")
    figure = sweeps.plot_sweep(serial_table, "n_particles", ["mean_map_tv", "failed"], tmp_path / "p.png")
    assert (tmp_path / "p.png").stat().st_size > 0 and len(figure.axes) == 2
    axis = figure.axes[0]
    curves = [container.lines[0] for container in axis.containers]  # error-bar curves
    assert len(curves) == 2 and all(list(c.get_xdata()) == [10, 40] for c in curves)  # rbpf, one per world
    flat = [line for line in axis.lines if line.get_label().endswith("(no n_particles)")]
    assert len(flat) == 4  # exact and dead reckoning in each world: horizontal lines
    rbpf = serial_table[(serial_table["world"] == "corridor:5") & (serial_table["opt_n_particles"] == 40)]
    assert rbpf["mean_map_tv"].mean() in [pytest.approx(y) for c in curves for y in c.get_ydata()]
    with pytest.raises(om.OnlineMapError, match="not an option"):
        sweeps.plot_sweep(serial_table, "n_particle", ["mean_map_tv"])


def test_an_exploration_task_is_policies_explore_with_the_same_seed():
    policies = pytest.importorskip("policies")
    if not hasattr(policies, "explore"):
        pytest.skip("policies.explore not available yet")
    spec = sweeps.parse_spec('worlds = ["door,p_door=0.02"]\nseeds = [3]\nsteps = 12\nrows = "step"\n'
                             'floor_plan = 0.8\n[planners.random]\n[estimators.rbpf]\nn_particles = 20\n')
    (task,) = spec.tasks
    mine = sweeps.run_task(task)
    model, true_map = om.door_world(p_door=0.02)
    theirs = policies.explore(policies.with_floor_plan(model, true_map, 0.8), true_map, "random", "rbpf", 12, 3,
                              estimator_options={"n_particles": 20}, progress=False)
    for column in ("map_error", "location_error", "door_error"):
        np.testing.assert_allclose(mine[column], theirs[column], atol=1e-12)
    with pytest.raises(om.SpecError, match="line 5: floor_plan: door,p_door=0.02: confidence"):
        sweeps.parse_spec('worlds = ["door,p_door=0.02"]\nseeds = [3]\nsteps = 12\n\n'
                          'floor_plan = 0.1\n[planners.random]\n[estimators.rbpf]\n')


def test_a_played_task_is_timed_after_a_warm_up_play(monkeypatch):
    """Issue 24 items 16-17: ``onlinemap explore`` printed info_gain at 205 ms a step over 100 steps:
    its planner's numba kernels compiled inside the timed run. A first, shorter play comes first."""
    pytest.importorskip("policies")
    real, steps = sweeps.task_kind("explore"), []
    monkeypatch.setattr(sweeps.runner, "task_kind", lambda name: real._replace(
        play=lambda model, true_map, task: steps.append(task.steps) or real.play(model, true_map, task)))
    monkeypatch.setattr(sweeps.runner, "_WARMED_PLAYS", set())
    spec = sweeps.parse_spec('worlds = ["grid:3x3"]\nseeds = [1, 2]\nsteps = 30\n[planners.random]\n'
                             '[estimators.rbpf]\nn_particles = 5\n')
    tables = [sweeps.run_task(task) for task in spec.tasks]
    assert steps == [om.evaluate.WARM_UP_STEPS, 30, 30]  # one warm-up per configuration and process
    monkeypatch.setattr(sweeps.runner, "_WARMED_PLAYS", set())
    steps.clear()
    again = sweeps.run_task(spec.tasks[0])
    assert steps == [om.evaluate.WARM_UP_STEPS, 30]
    pd.testing.assert_frame_equal(without_timing(again), without_timing(tables[0]))  # results unchanged


def test_prefer_dask_when_the_work_left_outweighs_starting_a_cluster():
    # 0.14 s a task (after a first that compiled), 48 left, 2 CPUs: 6.7 s here, half of it saved
    # by a cluster costing 12 s: stay (issue 24 item 18: 17.2 s on dask against 7.0 s serial)
    assert not sweeps.prefer_dask([3.0, 0.14, 0.14], 48, 2, start=12.0)
    assert sweeps.prefer_dask([3.0, 2.0, 2.0], 48, 2, start=12.0)  # 96 s here, 48 s saved
    assert not sweeps.prefer_dask([30.0], 48, 2, start=12.0)  # one task: it compiled, no estimate yet
    assert not sweeps.prefer_dask([3.0, 2.0, 2.0], 48, 1, start=12.0)  # one CPU: nothing to gain
    assert not sweeps.prefer_dask([3.0, 2.0, 2.0], 1, 8, start=12.0)  # one task left
    assert sweeps.prefer_dask([3.0, 1.0], 9, 4, start=6.0) and not sweeps.prefer_dask([3.0, 1.0], 7, 4, start=6.0)


def test_the_default_engine_runs_small_sweeps_here_and_moves_big_ones_to_dask(monkeypatch):
    """Issue 24 item 18: a local cluster was started for any sweep without --workers, 2.5 times
    slower than serial for a spec of 50 small tasks."""
    pytest.importorskip("distributed")
    if (os.cpu_count() or 1) < 2:
        pytest.skip("one CPU: the default engine is always serial")
    from onlinemap.sweeps import engines
    spec = sweeps.parse_spec(SPEC)
    monkeypatch.setattr(engines, "_run_dask", lambda *args: pytest.fail("started a cluster for small tasks"))
    small = om.sweep(spec, progress=False)  # workers=None: the default
    moved = []

    def dask(rest, client, workers, record):  # stands in for the cluster: runs the rest here
        moved.append(len(rest))
        for task in rest:
            record(task, sweeps.runner.attempt(task))

    monkeypatch.setattr(engines, "_run_dask", dask)
    monkeypatch.setattr(engines, "DASK_START_SECONDS", 0.0)  # any work left pays for a cluster
    big = om.sweep(spec, progress=False)
    assert moved == [N_TASKS - 2]  # decided after two tasks ran here
    pd.testing.assert_frame_equal(without_timing(big), without_timing(small))


# --- the example specs -------------------------------------------------------------------------
@pytest.mark.parametrize("path", sorted((ROOT / "examples").glob("*.toml")), ids=lambda p: p.name)
def test_example_spec_is_valid_and_runs_in_miniature(path):
    data = tomllib.loads(path.read_text())
    missing = [name for name in data.get("estimators", {}) if name not in om.available_estimators()]
    if missing:
        pytest.skip(f"estimator {', '.join(missing)} not registered yet")
    if "planners" in data:
        policies = pytest.importorskip("policies")
        if not hasattr(policies, "explore"):
            pytest.skip("policies.explore not available yet")
    spec = sweeps.load_spec(path)
    assert len(spec.tasks) > 1
    data.update(seeds=1, worlds=data["worlds"][:1])
    if data.get("steps") != "trip":
        data["steps"] = 8
    table = om.sweep(data, workers=0, progress=False)
    assert len(table) == len(sweeps.spec_from_dict(data).tasks)
    assert table["final_map_error"].between(0, 1).all()


# --- dask ------------------------------------------------------------------------------------------
def test_local_cluster_with_two_workers_gives_the_serial_table(client, serial_table, tmp_path):
    assert len(client.scheduler_info()["workers"]) == 2
    table = om.sweep(sweeps.parse_spec(SPEC), client, results_dir=tmp_path / "a", progress=False)
    pd.testing.assert_frame_equal(without_timing(table), without_timing(serial_table))
    by_address = om.sweep(sweeps.parse_spec(SPEC), client.scheduler.address, progress=False)  # --scheduler
    pd.testing.assert_frame_equal(without_timing(by_address), without_timing(serial_table))


@pytest.mark.slow
def test_a_failed_task_on_dask_is_one_error_not_a_worker_traceback(tmp_path):
    """Regression (issue 24 item 4): a failing task printed dask's ``Compute Failed`` block and a
    traceback (logged by the worker process) before the sweep's one error line."""
    pytest.importorskip("distributed")
    spec = write_spec(tmp_path, 'worlds = ["corridor:8"]\nseeds = 1\nsteps = 60\n'
                                '[estimators.online_em]\npseudo_count = 0\n')  # an impossible observation
    done = subprocess.run([sys.executable, "-m", "onlinemap", "sweep", str(spec), "--workers", "1", "--no-progress",
                           "--out", str(tmp_path / "r")], capture_output=True, text=True, timeout=600)
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [
        "onlinemap: error: 1 of 1 tasks failed (the others are kept; rerun to retry); first: "
        "online_em(pseudo_count=0) on corridor:8, seed 0: ImpossibleObservationError: observation '1' at step 14 "
        "has probability zero under the observation matrix B in use (B starts as label_prior @ O; a learned B has "
        "no zeros when pseudo_count > 0)"], done.stderr


def test_killing_a_worker_midway_still_finishes_every_task_once(client, serial_table, tmp_path):
    spec = sweeps.parse_spec(SPEC.replace("[estimators.exact]", "[estimators.offline_em]\n\n[estimators.exact]"))
    result = {}
    runner = threading.Thread(target=lambda: result.update(
        table=om.sweep(spec, client, results_dir=tmp_path, progress=False)))
    runner.start()
    deadline = time.monotonic() + 60
    while not list(tmp_path.glob("*.npz")) and time.monotonic() < deadline:
        time.sleep(0.01)
    victim = next(iter(client.run(os.getpid).values()))
    os.kill(victim, signal.SIGKILL)
    assert len(list(tmp_path.glob("*.npz"))) < len(spec.tasks), "killed too late"
    runner.join(timeout=180)
    assert not runner.is_alive()
    table = result["table"]
    assert len(table) == len(spec.tasks) and table["task"].is_unique
    assert len(list(tmp_path.glob("*.npz"))) == len(spec.tasks)
    serial = om.sweep(spec, workers=0, progress=False)
    pd.testing.assert_frame_equal(without_timing(table), without_timing(serial))


# --- reliability (issue 14) and trustworthy tables (issue 15) ----------------------------------------
def test_a_failed_table_write_keeps_the_previous_file_and_no_temporary(tmp_path, monkeypatch):
    from onlinemap.tables import write_table

    frame = pd.DataFrame({"a": [1, 2]})
    for name in ("r.csv", "r.parquet"):
        path = write_table(frame, tmp_path / name)
        before = path.read_bytes()

        def disk_full(*args, **kwargs):
            raise OSError(28, "No space left on device")

        monkeypatch.setattr(pd.DataFrame, "to_csv", disk_full)
        monkeypatch.setattr("pyarrow.parquet.write_table", disk_full)
        with pytest.raises(OSError, match="No space"):
            write_table(pd.DataFrame({"a": [3]}), path)
        monkeypatch.undo()
        assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.csv", "r.csv.json", "r.parquet"]


def test_failed_part_writes_leave_no_temporaries_and_old_ones_are_cleaned(tmp_path, monkeypatch):
    parts = tmp_path / "parts"
    parts.mkdir()
    from estimator_cases import dead_pid

    (parts / f".abc.npz.{dead_pid()}-0a1b2c3d.tmp").write_bytes(b"half a file")  # a killed process's leftover
    real, calls = sweeps.store.atomic_write, []

    def flaky(path, write):  # every third part: the disk fills up halfway through writing it
        calls.append(path)

        def half(file):
            write(file)
            if len(calls) % 3 == 0:
                raise OSError(28, "No space left on device")
        return real(path, half)

    monkeypatch.setattr(sweeps.store, "atomic_write", flaky)
    with pytest.raises(om.SweepError, match="No space"):
        om.sweep(sweeps.parse_spec(SPEC), workers=0, results_dir=parts, progress=False)
    assert not list(parts.glob(".*")), "temporary files left behind"
    assert len(list(parts.glob("*.npz"))) == N_TASKS - N_TASKS // 3


@pytest.mark.parametrize("old, new, words", [
    ("seeds = 3", "seeds = 1000000000", "exceed the cap of 100,000"),
    ("seeds = 3", "seeds = [1, 9223372036854775808]", r"2\*\*63"),
    ("steps = 15", "steps = 1000000000000", "steps"),
    ("n_particles = [10, 40]", "n_particles = [" + ", ".join(map(str, range(1, 400))) + "]\n"
     "proposal = [\"optimal\", \"transition\"]\nresampling = [\"residual\", \"systematic\", \"stratified\", "
     "\"multinomial\"]\nresample_threshold = [" + ", ".join(str(i / 100) for i in range(1, 100)) + "]",
     "configurations exceeds the cap"),
])
def test_huge_specs_are_refused_at_once(old, new, words):
    started = time.perf_counter()
    with pytest.raises(om.SpecError, match=words):
        sweeps.parse_spec(SPEC.replace(old, new))
    assert time.perf_counter() - started < 5  # counted, not built


def test_the_task_cap_can_be_raised():
    with pytest.raises(om.SpecError, match="24 tasks exceed the cap of 10"):
        sweeps.parse_spec(SPEC, max_tasks=10)
    assert len(sweeps.parse_spec(SPEC, max_tasks=24).tasks) == N_TASKS


def _one_error_line(capsys, argv) -> str:
    try:
        status = main(argv)
    except SystemExit as exit_:  # argparse usage errors
        status = exit_.code
    err = capsys.readouterr().err.strip()
    assert status == 2 and "Traceback" not in err and len(err.splitlines()) >= 1, err
    return err.splitlines()[-1]


def test_bad_command_lines_print_one_error_line_and_exit_2(tmp_path, capsys):
    path = write_spec(tmp_path)
    table = tmp_path / "t.parquet"
    pd.DataFrame({"estimator": ["a"], "seed": [0], "final_map_error": [0.5]}).to_parquet(table)
    for value in ("2", "nan"):
        assert "confidence" in _one_error_line(capsys, ["sweep", "--summary", str(table), "--confidence", value])
    assert "--scheduler 'nonsense'" in _one_error_line(
        capsys, ["sweep", str(path), "--scheduler", "nonsense", "--out", str(tmp_path / "r")])
    bad_world = write_spec(tmp_path, SPEC.replace('"corridor:5"', '"corridor:5,p_obs=abc"'), "w.toml")
    assert "line 2: worlds: world spec 'corridor:5,p_obs=abc': p_obs must be a number" in _one_error_line(
        capsys, ["sweep", str(bad_world), "--check"])
    latin = tmp_path / "latin.toml"
    latin.write_bytes(SPEC.replace('name = "small"', 'name = "caf\xe9"').encode("latin-1"))
    assert "line 1: not UTF-8" in _one_error_line(capsys, ["sweep", str(latin), "--check"])


def test_plot_of_particle_counts_is_logarithmic_and_its_legend_is_whole(serial_table):
    """Regression (issue 24 item 17): particle counts on a linear axis, and a legend of many long
    configurations cut off at the bottom of the figure."""
    import matplotlib

    matplotlib.use("Agg")
    table = serial_table.assign(world=serial_table["world"].map(
        lambda w: w + ",a_long_description_of_the_world_that_goes_on_and_on"))
    table = pd.concat([table.assign(estimator=table["estimator"] + suffix) for suffix in ("", "_v2", "_v3")])
    figure = sweeps.plot_sweep(table, "n_particles", ["mean_map_tv", "failed"])
    assert figure.axes[0].get_xscale() == "log"  # 10 and 40 particles
    figure.canvas.draw()
    (legend,) = figure.legends
    box, page = legend.get_window_extent(), figure.bbox
    assert len(legend.get_texts()) > 10
    assert page.x0 <= box.x0 and box.x1 <= page.x1 and page.y0 <= box.y0 and box.y1 <= page.y1
    panels = [axis.get_window_extent() for axis in figure.axes]
    assert all(box.y1 <= panel.y0 for panel in panels)  # below the panels, not over them


def test_plot_when_a_configuration_failed_on_every_seed(tmp_path, capsys):
    import matplotlib

    matplotlib.use("Agg")
    table = pd.DataFrame({"task": [f"t{i}" for i in range(6)], "estimator": ["rbpf"] * 6, "seed": [0, 1, 2] * 2,
                          "opt_n_particles": [10] * 3 + [40] * 3, "failed": [True] * 3 + [False, True, False],
                          "final_map_error": [0.9, 0.8, 0.95, 0.1, 0.2, 0.0]})
    path = tmp_path / "t.parquet"
    table.to_parquet(path)
    assert main(["sweep", "--summary", str(path), "--metrics", "failed,final_map_error", "--plot",
                 str(tmp_path / "p.png"), "--x", "n_particles"]) == 0
    assert (tmp_path / "p.png").stat().st_size > 0


def test_intervals_of_bounded_metrics_stay_in_range():
    values = np.array([1.0, 0.0, 0.0, 0.0, 0.0])  # t interval: 0.2 +- 0.555
    table = pd.DataFrame({"estimator": "a", "seed": range(5), "final_map_error": values,
                          "final_log_evidence": -values})
    summary = om.summarize(table, ["final_map_error", "final_log_evidence"]).set_index("metric")
    assert summary.loc["final_map_error", "low"] == 0.0 and summary.loc["final_map_error", "high"] < 1
    assert summary.loc["final_log_evidence", "low"] < -0.75  # unbounded: the plain t interval
    low, high = stats.t.interval(0.95, 4, loc=0.2, scale=stats.sem(values))
    assert summary.loc["final_map_error", "high"] == pytest.approx(high)


def test_intervals_of_cell_counts_stay_within_the_world():
    """Regression (issue 24 item 17): wrong_cells printed 38.5 [0, 133.8] in a world of 100 cells."""
    table = pd.DataFrame({"world": ["grid:3x3"] * 4 + ["corridor:20"] * 4, "estimator": "a", "seed": list(range(4)) * 2,
                          "wrong_cells": [9, 0, 0, 0, 20, 0, 0, 0], "unsure_or_wrong": [9, 9, 0, 9] * 2})
    summary = om.summarize(table, ["wrong_cells", "unsure_or_wrong"]).set_index(["world", "metric"])
    t_high = {values: stats.t.interval(0.95, 3, loc=np.mean(values), scale=stats.sem(values))[1]
              for values in [(9, 0, 0, 0), (9, 9, 0, 9), (20, 0, 0, 0)]}
    assert t_high[(9, 0, 0, 0)] > 9 and t_high[(9, 9, 0, 9)] > 9 and t_high[(20, 0, 0, 0)] > 20  # past N
    assert summary.loc[("grid:3x3", "wrong_cells"), ["low", "high"]].tolist() == [0.0, 9.0]
    assert summary.loc[("grid:3x3", "unsure_or_wrong"), "high"] == 9.0
    assert summary.loc[("corridor:20", "wrong_cells"), "high"] == 20.0
    assert summary.loc[("corridor:20", "unsure_or_wrong"), "high"] == pytest.approx(t_high[(9, 9, 0, 9)])  # < 20


def test_option_columns_are_typed_and_parts_assemble_without_the_spec(serial_table, tmp_path):
    assert serial_table["opt_n_particles"].dtype == "Int64"  # not floats beside exact's missing values
    assert serial_table["opt_n_particles"].isna().sum() == 2 * 2 * 3
    out = tmp_path / "r.parquet"
    table = om.sweep(sweeps.parse_spec(SPEC), workers=0, out=out, progress=False)
    alone = sweeps.collect(sweeps.default_results_dir(out))  # no spec: every part in the folder
    order = ["world", "estimator", "options", "seed"]
    pd.testing.assert_frame_equal(without_timing(alone.sort_values(order)), without_timing(table.sort_values(order)))
    from onlinemap.tables import read_provenance

    meta = read_provenance(out)
    assert meta["onlinemap_version"] == om.__version__ and "n_particles" in meta["source"]
    assert "git_commit" in meta


def test_planner_options_come_from_the_registry_without_building_one(monkeypatch):
    policies = pytest.importorskip("policies")
    assert policies.planner_options("entropy_collect") == {"gamma": 0.95, "replan_every": 1}
    monkeypatch.setattr(policies.EntropyExplorer, "__init__", lambda *a, **k: pytest.fail("built a planner"))
    with pytest.raises(om.SpecError, match="planners.entropy.gama: unknown option"):
        sweeps.parse_spec('worlds = ["door"]\nseeds = 1\nsteps = 5\n[planners.entropy]\ngama = 0.9\n'
                          '[estimators.bk]\n')


def test_parquet_output_without_pyarrow_is_refused_before_any_work(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "pyarrow", None)  # import pyarrow now raises ImportError
    path = write_spec(tmp_path)
    monkeypatch.setattr(sweeps.runner, "played_rows", lambda task: pytest.fail("a task ran"))
    line = _one_error_line(capsys, ["sweep", str(path), "--workers", "0", "--out", str(tmp_path / "r"),
                                    "--format", "parquet"])
    assert "needs pyarrow" in line and not (tmp_path / "r" / "parts").exists()


WITHOUT_PYARROW = """\
import sys
sys.modules["pyarrow"] = None  # as after `pip install -e .`: pandas and onlinemap load without it
from onlinemap.cli import main
for args in {commands!r}:
    status = main(args + ["--no-progress"])
    assert status == 0, (args, status)
assert sys.modules["pyarrow"] is None
"""


@pytest.mark.slow
def test_without_pyarrow_every_out_command_keeps_its_parts_and_writes_csv(tmp_path):
    """Regression (issue 24 item 12): the part store needed pyarrow, so ``--out`` failed after a
    base install (``pip install -e .``) for sweep, compare, explore and reproduce --random (the
    last keeps its parts through the same store as compare; tests/test_reproduce.py runs its CLI)."""
    spec = write_spec(tmp_path, SPEC.replace("seeds = 3", "seeds = 1"))
    out = tmp_path / "out"
    commands = [["sweep", str(spec), "--workers", "0", "--out", str(out / "sweep")],
                ["sweep", str(spec), "--workers", "0", "--out", str(out / "sweep")],  # resumes: nothing to run
                ["compare", "--world", "corridor:4", "--runs", "1", "--steps", "4", "--particles", "5",
                 "--out", str(out / "compare")],
                ["explore", "--world", "corridor:5", "--planner", "random", "--steps", "4", "-o", "n_particles=5",
                 "--out", str(out / "explore")]]
    done = subprocess.run([sys.executable, "-c", WITHOUT_PYARROW.format(commands=commands)], capture_output=True,
                          text=True, timeout=900)
    assert done.returncode == 0, done.stderr
    assert f"{N_TASKS // 3} already finished" in done.stdout
    assert len(pd.read_csv(out / "sweep" / "results.csv")) == N_TASKS // 3
    assert len(list((out / "sweep" / "parts").glob("*.npz"))) == N_TASKS // 3
    for parts in ("compare/compare.parts", "explore/explore.parts"):
        assert list((out / parts).glob("*.npz")), parts
    assert (out / "explore" / "explore_visits.png").exists() and (out / "compare" / "compare_summary.csv").exists()


@pytest.mark.parametrize("rows", ["task", "step"])
def test_the_engines_table_is_the_assembly_of_the_tasks_frames(rows):
    """``assemble_rows`` (the engines: one frame built for every task's plain rows) gives, bit for
    bit, the table ``assemble`` makes of the tasks' frames: tasks in any order, with different
    options, labels and metric columns (door errors in one world only), and a task with columns
    whose type pandas may infer differently alone (each such task is a frame of its own)."""
    spec = sweeps.parse_spec(f'worlds = ["corridor:5", "door,p_door=0.02"]\nseeds = 2\nsteps = 6\nrows = "{rows}"\n'
                             '[estimators.bk]\nlabel = "B"\n[estimators.rbpf]\nn_particles = [5, 10]\n')
    results = [sweeps.runner.task_rows(task) for task in spec.tasks]
    results = [results[i] for i in np.random.default_rng(0).permutation(len(results))]
    results += [results[0]._replace(columns={**results[0].columns, **extra})
                for extra in [{"note": None, "big": 2 ** 64}, {"note": 1.5, "big": 5}, {"listed": [1, "x"]}]]
    table = sweeps.store.assemble_rows(results)
    expected = sweeps.assemble([result.frame() for result in results])
    pd.testing.assert_frame_equal(table, expected, check_exact=True)
    assert table.dtypes.equals(expected.dtypes) and list(table["task"]) == [
        result.columns["task"] for result in results for _ in range(result.n)]


def test_a_part_keeps_every_column_and_type(tmp_path):
    task = sweeps.Task("corridor:5", "offline_em", (("anneal", (1.0, 0.5, 0.1)), ("n_iter", 3)), 2, 6)
    frame = sweeps.run_task(task).assign(
        note=["a"], missing=[None], mixed=[[1, "x"]], flag=pd.array([pd.NA], dtype="boolean"))
    sweeps.write_part(tmp_path, task, frame)
    back = sweeps.read_part(tmp_path / f"{task.key}.npz")
    options = [c for c in frame.columns if c.startswith("opt_")]
    assert list(back.columns) == [c for c in frame.columns if c not in options] + options  # options last
    plain = [c for c in frame.columns if c not in ("missing", "mixed", "flag", "opt_anneal")]
    pd.testing.assert_frame_equal(back[plain], frame[plain])  # numbers exactly, text, booleans
    assert back["missing"].isna().all() and back["mixed"].iloc[0] == [1, "x"]
    pd.testing.assert_series_equal(back["flag"], frame["flag"])  # nullable boolean, NA kept
    assert back["opt_anneal"].iloc[0] == [1.0, 0.5, 0.1] and back["opt_n_iter"].iloc[0] == 3
    pd.testing.assert_frame_equal(sweeps.collect(tmp_path), sweeps.assemble([frame]))
    (tmp_path / f"{task.key}.npz").write_bytes(b"PK\x03\x04 not a zip")
    with pytest.raises(om.OnlineMapError, match="cannot read sweep part"):
        sweeps.collect(tmp_path)


def test_intervals_of_counts_steps_ratios_and_shares_stay_in_their_range():
    """Issue 42 item 7: intervals of counts, steps, ratios and times went below 0
    (``steps_over_oracle 12.649 [-45.951, 71.249]``). Each is clipped to its range: the t
    interval of [0, 0, 0, 40] is 10 +- 3.182 * 20 / 2 = [-21.8, 41.8] before clipping (worked by
    hand: sd 20, t(0.975, 3) = 3.182), so its low end is 0 after; a share stored as 0/1 floats
    (a table read back) stays in [0, 1]; a log evidence stays signed."""
    table = pd.DataFrame({"planner": "goto", "steps_to_goal": [0.0, 0.0, 0.0, 40.0],
                          "oracle_steps": [0.0, 0.0, 0.0, 40.0], "steps_over_oracle": [0.0, 0.0, 0.0, 40.0],
                          "objective_gap": [0.0, 0.0, 0.0, 40.0], "success": [1.0, 1.0, 1.0, 0.0],
                          "failed": [0.0, 0.0, 0.0, 1.0], "final_log_evidence": [0.0, 0.0, 0.0, 40.0]})
    summary = sweeps.summarize(table, list(table.columns[1:]), by=["planner"]).set_index("metric")
    half = stats.t.ppf(0.975, 3) * 20.0 / 2.0
    assert half == pytest.approx(31.82, abs=0.01)
    for metric in ("steps_to_goal", "oracle_steps", "steps_over_oracle", "objective_gap"):
        assert (summary.loc[metric, "low"], summary.loc[metric, "high"]) == pytest.approx((0.0, 10.0 + half)), metric
    for metric in ("success", "failed"):  # mean 0.75 / 0.25 +- 3.182 * 0.5 / 2 = 0.795: past both ends
        assert (summary.loc[metric, "low"], summary.loc[metric, "high"]) == pytest.approx((0.0, 1.0)), metric
    assert summary.loc["final_log_evidence", "low"] == pytest.approx(10.0 - half)


def test_a_summary_of_no_runs_is_an_empty_table_with_its_columns():
    """Issue 43 section 2 item 2: summarising no rows (no run where the oracle reached the goal)
    raised ``KeyError: 'n'``."""
    from onlinemap.studies.base import summary_of

    empty = pd.DataFrame({"planner": pd.Series([], dtype=object), "success": pd.Series([], dtype=bool)})
    assert list(sweeps.summarize(empty, ["success"], by=["planner"]).columns) == \
        ["planner", "metric", "n", "mean", "low", "high"]
    wide = summary_of(empty, ["success"], ["planner"])
    assert wide.empty and list(wide.columns) == ["planner", "runs", "success", "success_low", "success_high"]


def test_sweep_summary_of_a_missing_path_says_not_found(tmp_path, capsys):
    """Issue 42 item 7: ``sweep --summary nowhere`` said it needs pyarrow (the base install's
    reader of a path without .csv) instead of "not found"."""
    for missing in (tmp_path / "nowhere", tmp_path / "results.parquet", tmp_path / "results.csv"):
        assert main(["sweep", "--summary", str(missing)]) == 2
        err = capsys.readouterr().err
        assert f"--summary {missing}: not found" in err and "pyarrow" not in err, err


def test_sweep_tables_define_every_metric_they_print(tmp_path, capsys):
    """Issue 42 item 7: ``failed`` (0.8 on plain corridors) was defined nowhere a user sees. The
    table is followed by one ``NAME: definition`` line per metric it prints."""
    table = pd.DataFrame({"task": [0, 1, 2, 3], "estimator": "rbpf", "seed": [0, 1, 2, 3],
                          "final_map_error": [0.1, 0.2, 0.3, 0.2], "failed": [True, False, True, True],
                          "mean_location_tv": [0.1, 0.1, 0.2, 0.3], "ms_per_step": [1.0, 1.1, 1.2, 1.0]})
    table.to_csv(tmp_path / "results.csv", index=False)
    assert main(["sweep", "--summary", str(tmp_path / "results.csv")]) == 0
    out = capsys.readouterr().out
    printed = ["final_map_error", "failed", "mean_location_tv", "ms_per_step"]
    legend = [line.split(":")[0] for line in out.splitlines() if ": " in line and not line.startswith("mean [")]
    assert legend == printed, out
    assert "failed: share of runs that end lost (P(true cell) < 0.5) or with a visited cell's most probable " \
           "label wrong" in out
