"""policies.explore: the loop's bookkeeping against a replay through onlinemap.simulate and
run_estimator; the gymnasium-driven loop; the CLI; the notebook; and the literature's claims
(DESIGN.md section 5.3) as paired statistical comparisons over seeds."""


import numpy as np
import pandas as pd
import pytest
from scipy import stats

import onlinemap as om
from onlinemap.cli import main
from onlinemap.studies.exploration import compare_planners, summarize_planners as summarize
from policies import (COLUMNS, EntropyExplorer, door_cells, explore, explore_env, exploration_world,
                      floor_plan_prior)
from policies.explore import exploration, seed_streams
from estimator_cases import exact_trajectory

TINY = ".o.\n#c.\n"  # 2 x 3 door world: small enough for exact Bayes (4^6 maps)


@pytest.fixture(scope="module")
def tiny():
    return om.door_world(TINY, p_door=0.05)


def replay_metrics(model, true_map, frame, seed):
    """Replay the frame's actions through onlinemap.simulate with the world's random stream,
    filter with a fresh exact estimator, and compute the metrics here, by hand."""
    actions = [model.action_names.index(a) for a in frame["action"].iloc[1:]]
    world_rng, _, _ = seed_streams(seed)
    run = om.simulate(model, true_map, actions, seed=world_rng)
    trajectory = exact_trajectory(run)
    steps = np.arange(run.n_steps)
    p_true = trajectory.map[steps[:, None], np.arange(model.n_cells), run.maps]  # (T, N)
    doors = np.flatnonzero(true_map >= 2)
    location = trajectory.location
    with np.errstate(divide="ignore", invalid="ignore"):
        h_loc = -np.where(location > 0, location * np.log(location), 0).sum(1) / np.log(model.n_cells)
        h_map = -np.where(trajectory.map > 0, trajectory.map * np.log(trajectory.map), 0).sum(2) / np.log(4)
    return run, pd.DataFrame({
        "map_error": 1 - p_true.mean(1), "location_error": 1 - location[steps, run.locations],
        "location_entropy": h_loc, "map_entropy": h_map.mean(1), "door_error": 1 - p_true[:, doors].mean(1)})


@pytest.mark.parametrize("planner", ["entropy", "random", "sweep"])
def test_explore_matches_a_replay_through_simulate(tiny, planner):
    model, true_map = tiny
    frame = explore(model, true_map, planner, "exact", steps=40, seed=11, progress=False)
    assert tuple(frame.columns) == COLUMNS
    assert list(frame["t"]) == list(range(40)) and pd.isna(frame["action"].iloc[0])
    run, expected = replay_metrics(model, true_map, frame, 11)
    assert np.array_equal(frame["true_location"], run.locations)
    assert (run.maps != run.maps[0]).any()  # the doors did change (p_door = 0.05)
    for column in expected:
        np.testing.assert_allclose(frame[column], expected[column], atol=1e-9, err_msg=column)


@pytest.mark.parametrize("planner", ["random", "sweep", "entropy", "info_gain"])
def test_every_planner_explores_a_blocking_world_with_a_cross_footprint(planner):
    """(F,) observations (F = 5 readings) and blocking walls: the loop stores what the world
    emitted (a replay through onlinemap.simulate with the world's stream gives the same run), and
    info_gain plans on estimator forks (its numba rollouts model neither footprints nor blocking)."""
    model, true_map = om.door_world(blocking=True, footprint="cross")
    assert model.observation_shape == (5,) and not model.is_paper_model
    found = exploration(model, true_map, planner, "rbpf", steps=5, seed=3, progress=False,
                        estimator_options={"n_particles": 20},
                        planner_options={"hypotheses": 2} if planner == "info_gain" else None)
    assert found.run.observations.shape == (5, 5) and np.isfinite(found.frame["map_error"]).all()
    world_rng, _, _ = seed_streams(3)
    replay = om.simulate(model, true_map, found.run.actions, seed=world_rng)
    np.testing.assert_array_equal(found.run.observations, replay.observations)
    np.testing.assert_array_equal(found.run.locations, replay.locations)


def test_same_seed_same_run(tiny):
    model, true_map = tiny
    first = explore(model, true_map, "random", "exact", 30, seed=5, progress=False)
    pd.testing.assert_frame_equal(explore(model, true_map, "random", "exact", 30, seed=5, progress=False), first)
    assert not explore(model, true_map, "random", "exact", 30, seed=6, progress=False).equals(first)
    model10, map10 = exploration_world()
    a = explore(model10, map10, "entropy", "rbpf", 30, seed=1, progress=False)
    pd.testing.assert_frame_equal(explore(model10, map10, "entropy", "rbpf", 30, seed=1, progress=False), a)


def test_explore_takes_instances_and_refuses_bad_input(tiny):
    model, true_map = tiny
    estimator = om.make_estimator("exact", model)
    frame = explore(model, true_map, EntropyExplorer(model, gamma=0.9), estimator, 10, seed=0, progress=False)
    assert estimator.t == 9 and len(frame) == 10
    with pytest.raises(om.ModelError, match="already taken"):
        explore(model, true_map, "random", estimator, 10, seed=0)
    with pytest.raises(om.ModelError, match="different model"):
        explore(model, true_map, "random", om.make_estimator("exact", om.door_world(TINY)[0]), 10)
    with pytest.raises(om.ModelError, match="steps"):
        explore(model, true_map, "random", "exact", 0)
    with pytest.raises(om.ModelError, match="true_map"):
        explore(model, true_map[:-1], "random", "exact", 5)
    with pytest.raises(om.UnknownEstimatorError):
        explore(model, true_map, "random", "nope", 5)
    with pytest.raises(om.ModelError, match="unknown planner"):
        explore(model, true_map, "nope", "exact", 5)
    with pytest.raises(om.ModelError, match="planner_options"):
        explore(model, true_map, EntropyExplorer(model), "exact", 5, planner_options={"gamma": 0.5})


def test_planner_options_reach_the_named_planner(tiny):
    model, true_map = tiny
    by_name = explore(model, true_map, "entropy", "exact", 15, seed=3, progress=False,
                      planner_options={"gamma": 0.5, "replan_every": 3})
    by_instance = explore(model, true_map, EntropyExplorer(model, gamma=0.5, replan_every=3), "exact",
                          15, seed=3, progress=False)
    pd.testing.assert_frame_equal(by_name, by_instance)
    assert by_name.attrs["planner"] == by_instance.attrs["planner"] == "EntropyExplorer(gamma=0.5, " \
        "replan_every=3, reward=entropy_reward)"


def test_worlds_without_doors_report_nan_door_error():
    model = om.grid_model(2, 2, 2)
    frame = explore(model, [0, 1, 1, 0], "sweep", "exact", 12, seed=0, progress=False)
    assert frame["door_error"].isna().all() and frame["map_error"].notna().all()


def test_floor_plan_prior():
    model, true_map = om.door_world()
    prior = floor_plan_prior(model, true_map, 0.7)
    doors = door_cells(model, true_map)
    assert len(doors) == 5
    np.testing.assert_allclose(prior.sum(1), 1.0)
    np.testing.assert_allclose(prior[doors], [[0, 0, 0.5, 0.5]] * len(doors))
    others = np.setdiff1d(np.arange(100), doors)
    np.testing.assert_allclose(prior[others, true_map[others]], 0.7)
    with pytest.raises(om.ModelError):
        floor_plan_prior(model, true_map, 0.1)


def test_explore_env_drives_the_gymnasium_environment(tiny):
    gym = pytest.importorskip("gymnasium")
    from onlinemap.envs import DoorWorldEnv

    model, true_map = tiny
    env = DoorWorldEnv(model=model, true_map=true_map)
    frame = explore_env(env, "entropy", "exact", steps=30, seed=4, progress=False)
    assert tuple(frame.columns) == COLUMNS and len(frame) == 30
    pd.testing.assert_frame_equal(explore_env(env, "entropy", "exact", steps=30, seed=4, progress=False), frame)
    # replay the episode in the environment: same true locations
    world_seed, _, _ = seed_streams(4)
    _, info = env.reset(seed=int(world_seed.integers(2**31)))
    locations = [info["location"]]
    for action in frame["action"].iloc[1:]:
        locations.append(env.step(model.action_names.index(action))[4]["location"])
    assert locations == list(frame["true_location"])
    limited = gym.wrappers.TimeLimit(DoorWorldEnv(model=model, true_map=true_map), max_episode_steps=5)
    with pytest.raises(om.ModelError, match="ended the episode"):
        explore_env(limited, "random", "exact", steps=10, seed=0)


def test_cli_explore_runs_on_the_sweep_engine_and_writes_only_under_out(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    out = tmp_path / "out"
    code = main(["explore", "--world", "grid:2x3", "--estimator", "exact", "--steps", "25", "--repeats", "2",
                 "--out", str(out)])
    assert code == 0
    printed = capsys.readouterr().out
    assert "final_map_error" in printed and "wrong_cells" in printed and "sweep" in printed and "[" in printed
    steps = pd.read_csv(out / "explore_steps.csv")
    assert {"planner", "seed", "t", "true_location", "map_error", "location_error"} <= set(steps.columns)
    assert len(steps) == 4 * 2 * 25  # the default planners: info_gain, entropy, random, sweep
    runs = pd.read_csv(out / "explore_runs.csv")
    assert len(runs) == 4 * 2
    # the one scorer's definitions, recomputed here from the per-step table
    last = steps.sort_values("t").groupby(["planner", "seed"]).tail(1).set_index(["planner", "seed"])
    for (planner, seed), row in runs.set_index(["planner", "seed"]).iterrows():
        assert row["final_map_error"] == pytest.approx(last.loc[(planner, seed), "map_error"])
        assert row["wrong_cells"] == last.loc[(planner, seed), "wrong_cells"]
    for name in ("explore_errors.png", "explore_visits.png"):
        assert (out / name).stat().st_size > 10_000
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # nothing outside --out
    assert main(["explore", "--steps", "5"]) == 0 and "late_door_error" in capsys.readouterr().out
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]
    assert main(["explore", "--planner", "greedy"]) == 2
    assert main(["explore", "--floor-plan", "2", "--steps", "5"]) == 2
    assert main(["explore", "--world", "door", "--estimator", "dead_reckoning", "--steps", "20",
                 "-o", "bogus=1"]) == 2


def test_summary_counts_time_at_doors():
    model, true_map = om.door_world()
    doors = door_cells(model, true_map)
    table = pd.DataFrame({"planner": "p", "seed": 0, "t": np.arange(4), "map_error": [.4, .3, .2, .1],
                          "door_error": [.5, .5, .4, .2], "location_error": 0.0,
                          "true_location": [0, doors[0], doors[1], 0], "seconds_per_step": 0.001})
    row = summarize(table, model, true_map).iloc[0]
    assert row["time_at_doors"] == 0.5 and row["cells_visited"] == 3 and row["final_map_error"] == 0.1
    assert row["late_door_error"] == pytest.approx((0.5 + 0.4 + 0.2) / 3)


# --- the literature's claims, paired over seeds ------------------------------------------------
# Seeds from the power wanted. One-sided paired t-test at alpha = 0.05 with power 0.95
# (z_a = z_b = 1.645): n = ((z_a + z_b) / d)^2 + z_a^2 / 2 (the second term corrects the normal
# approximation for the t), d = mean / sd of the per-seed difference, measured on 64 pilot seeds
# (1000-1063, disjoint from the tests' 0..n-1), with the tests' settings:
# - static, final map error, entropy - random: mean -0.057, sd 0.048, d = 1.20:
#   n = (3.29 / 1.20)^2 + 1.35 = 8.9 (the noncentral t gives 10): 10 seeds;
# - dynamic, late door error: mean -0.030, sd 0.071, d = 0.43: n = (3.29 / 0.43)^2 + 1.35 = 60.7: 61 seeds;
# - dynamic, share of steps at doors: mean +0.025, sd 0.054, d = 0.46: n = 53.4, so the 61 shared runs
#   give it power 0.97.
STATIC_SEEDS = range(10)
DYNAMIC_SEEDS = range(61)


def paired(p_door: float, steps: int, planners, seeds) -> pd.DataFrame:
    if "rbpf" not in om.available_estimators():
        pytest.skip("needs the rbpf estimator")
    # exploration_world(p_door) as a world spec: the 10 x 10 door world, p_move 0.9, floor plan 0.8
    return compare_planners(f"door,p_door={p_door},p_move=0.9", planners, "rbpf", steps, seeds, floor_plan=0.8,
                            progress=False)


def one_sided_p(better: pd.Series, worse: pd.Series) -> float:
    """Paired t-test p-value for mean(better - worse) < 0 (the same seeds for both)."""
    return stats.ttest_rel(better, worse, alternative="less").pvalue


@pytest.fixture(scope="module")
def static_runs():
    return paired(0.0, 250, ["entropy", "random"], STATIC_SEEDS)


@pytest.fixture(scope="module")  # built once: the test command runs a file on one worker (conftest)
def dynamic_runs():
    return paired(0.01, 300, ["entropy", "random"], DYNAMIC_SEEDS)


@pytest.mark.slow
def test_static_door_world_entropy_planner_learns_the_map_faster_than_a_random_walk(static_runs):
    final = static_runs.groupby(["planner", "seed"])["map_error"].last().unstack(0)
    p = one_sided_p(final["entropy"], final["random"])
    assert p < 0.05, (p, final.round(3).to_dict())


@pytest.mark.slow
def test_dynamic_door_world_entropy_planner_keeps_doors_up_to_date(dynamic_runs):
    late = dynamic_runs[dynamic_runs["t"] >= 100].groupby(["planner", "seed"])["door_error"].mean().unstack(0)
    p = one_sided_p(late["entropy"], late["random"])
    assert p < 0.05, (p, late.round(3).to_dict())


@pytest.mark.slow
def test_dynamic_door_world_entropy_planner_spends_more_time_at_doors(dynamic_runs):
    model, true_map = exploration_world(p_door=0.01)
    doors = door_cells(model, true_map)
    share = dynamic_runs.assign(at_door=np.isin(dynamic_runs["true_location"], doors)) \
        .groupby(["planner", "seed"])["at_door"].mean().unstack(0)
    assert one_sided_p(-share["entropy"], -share["random"]) < 0.05, share.round(3).to_dict()


@pytest.mark.slow
def test_cli_explore_on_dask_keeps_stderr_free_of_dask_logs(tmp_path):
    """dask's scheduler runs in the CLI's process and used to log 30 INFO lines (starts, stops,
    worker registrations) through the CLI's one-line log handler; and one planner alone used to
    fail in the summary (no configuration column varied, so nothing to group by)."""
    import subprocess
    import sys

    done = subprocess.run([sys.executable, "-m", "onlinemap", "explore", "--planner", "random", "--repeats", "2",
                           "--steps", "10", "--workers", "1", "--no-progress"], capture_output=True, text=True,
                          cwd=tmp_path, timeout=300)
    assert done.returncode == 0, done.stderr
    assert "random" in done.stdout and "INFO" not in done.stderr, done.stderr


def test_visits_share_one_colour_scale_show_unvisited_cells_and_name_doors():
    """Regression (issue 24 item 17): each panel had its own colour scale, cells never visited were
    white like the page, and nothing said what the red squares and grey cells were."""
    import matplotlib.colors as colors
    from policies import plot_visits

    model, true_map = om.door_world()
    table = pd.DataFrame({"planner": ["a"] * 3 + ["b"] * 40, "true_location": [0, 0, 1] + [0] * 40})
    figure = plot_visits(model, true_map, table)
    images = [image for axis in figure.axes for image in axis.images]
    assert len(images) == 2 and {image.norm.vmax for image in images} == {40}  # one scale: b's 40 visits
    unvisited = images[0].cmap.get_bad()
    assert unvisited[3] == 1 and not np.allclose(unvisited[:3], 1)  # opaque, not white
    assert np.ma.is_masked(images[0].get_array()[5, 5])  # a cell nobody visited takes that colour
    (legend,) = figure.legends
    assert [text.get_text() for text in legend.get_texts()] == ["never visited", "wall", "open_door", "closed_door"]
    # each door outlined in its label's colour of the one palette (open green, closed red)
    outlines = {(round(p.get_x() + 0.45), round(p.get_y() + 0.45)): colors.to_hex(p.get_edgecolor())
                for p in figure.axes[0].patches if p.get_linewidth() == 2}
    palette = {om.model.OPEN_DOOR: colors.to_hex("tab:green"), om.model.CLOSED_DOOR: colors.to_hex("tab:red")}
    assert outlines == {(col, row): palette[true_map[row * model.cols + col]]
                        for row, col in zip(*np.nonzero(np.isin(true_map.reshape(model.shape), list(palette))))}
    assert len(figure.axes) == 3  # two panels and one colour bar
    assert colors.to_hex(unvisited) != colors.to_hex("white")


class _North:
    """A planner that presses north for ever."""

    def choose(self, belief):
        return 0


def test_stall_watch_counts_presses_in_a_row_that_leave_the_belief_as_it_was():
    from onlinemap.belief import Belief, StallWatch
    a, b = (Belief(t, np.array([p, 1 - p]), np.full((2, 2), 0.5)) for t, p in ((0, 0.3), (0, 0.3 + 1e-9)))
    watch = StallWatch(2)
    steps = [a, a, b, b, b, b, a]  # unchanged: -, 1, 0, 1, 2 (stall), 3, 0
    assert [watch.update(x) for x in steps] == [False, False, False, False, True, False, False]
    never = StallWatch(None)
    assert not any(never.update(a) for _ in range(100))
    with pytest.raises(om.errors.InvalidOptionError, match="stall_after"):
        StallWatch(0)


def test_a_closed_loop_whose_belief_stops_moving_ends_and_reports_the_stall(caplog):
    # dead reckoning at the top-left corner pressing north: the robot and its belief stay as they are,
    # so presses 1..5 each leave the belief unchanged and the fifth (step 5) declares the stall
    model = om.grid_model(3, 3, 2)
    true_map = np.zeros(9, dtype=int)
    with caplog.at_level("WARNING", logger="policies.explore"):
        found = exploration(model, true_map, _North(), "dead_reckoning", steps=100, seed=0, stall_after=5)
    assert found.stalled_at == 5 and len(found.frame) == 6 and found.frame.attrs["stalled_at"] == 5
    assert any("stalled at step 5" in r.getMessage() for r in caplog.records)
    unwatched = exploration(model, true_map, _North(), "dead_reckoning", steps=30, seed=0, stall_after=None)
    assert unwatched.stalled_at is None and len(unwatched.frame) == 30
