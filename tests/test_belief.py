"""Everyday helpers: readable reprs, beliefs as tables (one row per cell; over time, long format)
and ``plots.plot_belief``."""

import matplotlib
import numpy as np
import pytest

import onlinemap as om

matplotlib.use("Agg")


@pytest.fixture(scope="module")
def door_run():
    model, true_map = om.door_world()
    run = om.simulate(model, true_map, om.random_walk(model, 12, 3), seed=3)
    estimator = om.make_estimator("bk", model)
    return run, estimator, om.run_estimator(estimator, run.actions, run.observations)


def test_belief_to_frame_has_one_row_per_cell_with_its_marginals(door_run):
    run, estimator, _ = door_run
    belief, model = estimator.belief, run.model
    frame = belief.to_frame(model)
    assert len(frame) == model.n_cells and (frame["t"] == belief.t).all()
    for cell in range(model.n_cells):  # every row, read back by hand
        row = frame.iloc[cell]
        assert (row["cell"], row["row"], row["col"]) == (cell, cell // model.cols, cell % model.cols)
        assert row["location"] == belief.location[cell]
        assert [row[f"map_{name}"] for name in model.label_names] == list(belief.map[cell])
        assert row["most_likely_label"] == model.label_names[int(np.argmax(belief.map[cell]))]
    bare = belief.to_frame()  # without the model: labels by index, no row/col
    assert list(bare.columns) == ["t", "cell", "location", "map_0", "map_1", "map_2", "map_3",
                                  "most_likely_label"]
    assert (bare["most_likely_label"] == belief.map_estimate).all()


def test_trajectory_to_frame_is_long_format_over_time(door_run):
    run, _, trajectory = door_run
    frame = trajectory.to_frame(run.model)
    steps, cells = trajectory.location.shape
    assert len(frame) == steps * cells
    for t, cell in [(0, 0), (5, 17), (steps - 1, cells - 1)]:
        row = frame[(frame["t"] == t) & (frame["cell"] == cell)].iloc[0]
        assert row["location"] == trajectory.location[t, cell]
        assert row["map_wall"] == trajectory.map[t, cell, 1]
    sums = frame.groupby("t")["location"].sum().to_numpy()
    np.testing.assert_allclose(sums, 1.0, atol=1e-12)
    with pytest.raises(ValueError, match="do not match"):
        om.belief.beliefs_frame(trajectory.location[:, :3], trajectory.map)


def test_reprs_name_what_matters():
    model = om.corridor(5)
    estimator = om.make_estimator("rbpf", model, n_particles=7, seed=1)
    assert repr(estimator).startswith("rbpf(t=-1, model=GridModel(1x5")
    assert "n_particles=7" in repr(estimator) and "seed=1" in repr(estimator)
    belief = estimator.step(None, 1)
    assert repr(estimator).startswith("rbpf(t=0,")
    assert repr(belief).startswith("Belief(t=0, most likely cell 0 with p=1.000, N=5, K=2")
    assert f"ess={belief.effective_sample_size:.1f}" in repr(belief)
    assert "ess=" not in repr(om.make_estimator("bk", model).step(None, 1))
    for name in om.available_estimators():
        text = repr(om.make_estimator(name, model))
        assert text.startswith(f"{name}(t=-1, model=GridModel(") and "object at 0x" not in text


def test_plot_belief_draws_a_corridor_as_bars():
    from onlinemap import plots
    run = om.scenarios.murphy_corridor()
    estimator = om.make_estimator("exact", run.model)
    om.run_estimator(estimator, run.actions, run.observations)
    belief = estimator.belief
    fig = plots.plot_belief(run.model, belief, run.final_map, run.locations[-1])
    ax_loc, ax_map = fig.axes[:2]
    np.testing.assert_allclose([p.get_height() for p in ax_loc.patches], belief.location)
    heights = np.array([p.get_height() for p in ax_map.patches]).reshape(run.model.n_labels, -1)
    np.testing.assert_allclose(heights.T, belief.map)


def test_plot_belief_draws_a_grid_as_images(door_run):
    from matplotlib.colors import to_rgb

    from onlinemap import plots
    run, estimator, _ = door_run
    belief = estimator.belief
    fig = plots.plot_belief(run.model, belief, run.final_map, run.locations[-1])
    location_image = fig.axes[0].images[0].get_array()
    np.testing.assert_allclose(location_image, belief.location.reshape(run.model.shape))
    rgb = np.asarray(fig.axes[1].images[0].get_array()).reshape(-1, 3)
    palette = np.array([to_rgb(c) for c in ("white", "#404040", "tab:green", "tab:red")])  # free, wall, doors
    unknown = np.array(to_rgb(plots.UNKNOWN_COLOUR))
    for cell in range(run.model.n_cells):  # the label's colour, blended towards blue-grey as P(label) falls to 1/K
        p = belief.map[cell]
        sure = (p.max() - 0.25) / 0.75
        np.testing.assert_allclose(rgb[cell], sure * palette[np.argmax(p)] + (1 - sure) * unknown, atol=1e-12)
    legend = [text.get_text() for text in fig.axes[1].get_legend().get_texts()]
    assert legend == [*run.model.label_names, "unknown (uniform belief)", "most likely label wrong"]
    assert [text.get_text() for text in fig.axes[0].get_legend().get_texts()] == ["true location"]
    with pytest.raises(om.ModelError, match=r"100 cells x 4 labels does not fit GridModel\(1x4.*\(4 cells x 2 labels\)"):
        plots.plot_belief(om.corridor(4), belief)


def test_dead_reckoning_log_evidence_is_undefined_and_says_so():
    """Issue 24 item 18: dead reckoning's log_evidence=nan read as a bug. It is undefined (no
    observation model); the belief's repr, the Belief docstring and the estimator's say so."""
    est = om.make_estimator("dead_reckoning", om.corridor(4))
    steps = [est.step(None, 0), est.step(1, 1), est.step(0, 0)]
    assert all(np.isnan(belief.log_evidence) for belief in steps)
    assert "log_evidence=nan (undefined)" in repr(steps[-1])
    assert "log_evidence=nan" not in repr(om.make_estimator("bk", om.corridor(4)).step(None, 0))
    assert "dead reckoning" in om.Belief.__doc__ and "undefined" in type(est).__doc__


def test_run_and_trajectory_print_short_with_shapes_and_a_few_numbers(door_run):
    """Issue 24 item 18: print(run) and print(trajectory) dumped every array."""
    run, _, trajectory = door_run
    text = str(run)
    assert text == repr(run) and "array(" not in text and "\n" not in text and len(text) < 400
    slipped = int(run.slipped.sum())
    assert text.startswith("Run(T=13 steps, model=GridModel(10x10")
    assert f"locations {run.locations[0]} -> {run.locations[-1]}, {slipped} of 12 moves slipped" in text
    assert "actions (12,), observations (13,)" in text and "label changes" not in text  # a static world
    dynamic = om.simulate(om.corridor(6, p_change=0.2), steps=5, seed=0)
    changes = int((dynamic.maps[1:] != dynamic.maps[:-1]).sum())
    assert f"{changes} label changes" in repr(dynamic)
    text = str(trajectory)
    assert text == repr(trajectory) and "array(" not in text and "\n" not in text and len(text) < 400
    best = int(np.argmax(trajectory.location[-1]))
    assert text.startswith("Trajectory(T=13 steps: location (13, 100), map (13, 100, 4), log_evidence (13,)")
    assert f"at t=12 most likely cell {best} with p={trajectory.location[-1, best]:.3f}" in text
    assert f"log_evidence={trajectory.log_evidence[-1]:.4g}" in text
    empty = om.Trajectory(np.empty((0, 3)), np.empty((0, 3, 2)), np.empty(0), 0.0)
    assert repr(empty) == "Trajectory(T=0 steps: location (0, 3), map (0, 3, 2), log_evidence (0,))"


def test_help_of_make_estimator_points_to_the_names_and_their_options():
    """Issue 24 item 18: help(om.make_estimator) said nothing of which names and options exist."""
    import pydoc

    text = pydoc.render_doc(om.make_estimator, renderer=pydoc.plaintext)
    for pointer in ("available_estimators()", "estimator_options(name)", "help(type(est))"):
        assert pointer in text
    for name in om.available_estimators():
        assert name in text


def test_trajectory_gives_the_belief_of_each_step_as_the_estimator_gave_it():
    """Issue 42 item 3: ``trajectory.belief(t)`` / ``trajectory[t]`` is the Belief the estimator
    returned at step t (recorded live here, step by step), read-only."""
    run = om.scenarios.murphy_corridor()
    live = om.make_estimator("exact", run.model)
    beliefs = [live.step(None if t == 0 else int(run.actions[t - 1]), run.observations[t])
               for t in range(run.n_steps)]
    trajectory = om.run_estimator(om.make_estimator("exact", run.model), run.actions, run.observations)
    assert trajectory.n_steps == run.n_steps == len(beliefs)
    for t in (0, 3, run.n_steps - 1, -1, -run.n_steps):
        got, want = trajectory.belief(t), beliefs[t]
        assert got.t == want.t == t % run.n_steps
        np.testing.assert_array_equal(got.location, want.location)
        np.testing.assert_array_equal(got.map, want.map)
        assert got.log_evidence == want.log_evidence
        assert not got.location.flags.writeable and not got.map.flags.writeable
        np.testing.assert_array_equal(trajectory[t].map, got.map)
    with pytest.raises(ValueError):
        trajectory.belief(0).map[0, 0] = 0.5  # read-only: the trajectory cannot be changed through it
    assert trajectory.map[0, 0, 0] == beliefs[0].map[0, 0]
    location, maps, evidence, seconds = trajectory  # still a named tuple of its four fields
    assert location is trajectory.location and len(trajectory) == 4
    for bad in (run.n_steps, -run.n_steps - 1, 1.5, "0", slice(0, 2)):
        with pytest.raises(om.errors.StepIndexError, match="step|integer"):
            trajectory.belief(bad)
        with pytest.raises(IndexError):
            trajectory[bad]
