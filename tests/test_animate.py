"""``om.plots.animate``: a run's beliefs over time as a GIF or an MP4, read back (issue 42 item 3)."""

import numpy as np
import pytest
from matplotlib.colors import to_rgb
from PIL import Image

import onlinemap as om
from onlinemap import plots
from onlinemap.errors import InvalidOptionError, MissingDependencyError, ModelError


def share_near(image: Image.Image, colour: str, tolerance: float = 10.0) -> float:
    """The share of the image's pixels within ``tolerance`` (0-255 per channel) of ``colour``."""
    pixels = np.asarray(image.convert("RGB"), dtype=float)
    return float(np.mean(np.abs(pixels - 255 * np.array(to_rgb(colour))).max(axis=2) <= tolerance))


def gif_frames(path) -> list[np.ndarray]:
    """Every frame of a GIF as (H, W, 3) RGB."""
    frames = []
    with Image.open(path) as gif:
        for index in range(gif.n_frames):
            gif.seek(index)
            frames.append(np.asarray(gif.convert("RGB")))
    return frames


@pytest.fixture(scope="module")
def learned():
    """A 6 x 8 door world whose map belief goes from uniform (t = 0) to certain walls (the last step)."""
    model = om.grid_model(6, 8, 4, label_names=("free", "wall", "open_door", "closed_door"))
    steps = 7
    location = np.full((steps, model.n_cells), 1.0 / model.n_cells)
    maps = np.full((steps, model.n_cells, 4), 0.25)
    maps[-1] = [0.0, 1.0, 0.0, 0.0]
    return model, om.Trajectory(location, maps, np.zeros(steps), 0.0)


def test_a_gif_has_one_frame_per_shown_step_and_draws_the_belief_in_the_palette(tmp_path, learned):
    model, trajectory = learned
    path = plots.animate(model, trajectory, tmp_path / "sub" / "run.gif", every=3, fps=5)
    assert path == tmp_path / "sub" / "run.gif"
    frames = plots.animation_frames(trajectory.n_steps, 3)
    np.testing.assert_array_equal(frames, [0, 3, 6])
    with Image.open(path) as gif:
        assert gif.n_frames == 3 and gif.info["duration"] == 200
        width, height = gif.size
        assert 300 <= width <= 1200 and 150 <= height <= 600
        gif.seek(0)
        first = gif.copy()
        gif.seek(2)
        last = gif.copy()
    # uniform at t = 0: the map panel is blue-grey, no cell drawn as a wall; certain walls at the end
    assert share_near(first, plots.UNKNOWN_COLOUR) > 0.15 and share_near(first, "#404040") < 0.01
    assert share_near(last, "#404040") > 0.15 and share_near(last, plots.UNKNOWN_COLOUR) < 0.01


def test_the_true_path_and_map_add_a_panel(tmp_path):
    model, true_map = om.building(12, 12, seed=3)
    run = om.simulate(model, true_map, om.random_walk(model, 9, 1), seed=1)
    trajectory = om.run_estimator(om.make_estimator("rbpf", model, n_particles=20, seed=0), run.actions,
                                  run.observations)
    bare = plots.animate(model, trajectory, tmp_path / "bare.gif")
    full = plots.animate(model, trajectory, tmp_path / "full.gif", true_locations=run.locations, true_maps=run.maps)
    with Image.open(bare) as a, Image.open(full) as b:
        assert a.n_frames == b.n_frames == 10
        assert b.size[0] > a.size[0] * 1.25  # a third panel: the true map
        b.seek(9)
        assert share_near(b, "#404040", 6) > 0.03  # its walls, certain


def test_an_mp4_is_written_where_imageio_ffmpeg_is_installed(tmp_path, learned):
    imageio = pytest.importorskip("imageio.v2")
    pytest.importorskip("imageio_ffmpeg")
    model, trajectory = learned
    path = plots.animate(model, trajectory, tmp_path / "run.mp4", fps=10)
    with imageio.get_reader(path) as reader:
        frames = [frame for frame in reader]
    assert len(frames) == trajectory.n_steps and frames[0].shape[0] % 2 == frames[0].shape[1] % 2 == 0


def test_bad_arguments_are_refused_before_anything_is_written(tmp_path, learned, monkeypatch):
    model, trajectory = learned
    for path, options, error in [(tmp_path / "run.png", {}, InvalidOptionError),
                                 (tmp_path / "run.gif", {"every": 0}, InvalidOptionError),
                                 (tmp_path / "run.gif", {"fps": 0}, InvalidOptionError),
                                 (tmp_path / "run.gif", {"true_locations": np.zeros(3, dtype=int)}, ModelError),
                                 (tmp_path / "run.gif", {"true_maps": np.full(model.n_cells, 4)}, ModelError)]:
        with pytest.raises(error):
            plots.animate(model, trajectory, path, **options)
    with pytest.raises(ModelError, match="does not fit"):
        plots.animate(om.corridor(5), trajectory, tmp_path / "run.gif")
    monkeypatch.setattr(plots, "find_spec", lambda name: None)  # no imageio here
    with pytest.raises(MissingDependencyError, match="pip install imageio imageio-ffmpeg"):
        plots.animate(model, trajectory, tmp_path / "run.mp4")
    assert not list(tmp_path.iterdir())


def test_a_corridor_animates_as_one_row(tmp_path):
    run = om.scenarios.murphy_corridor()
    trajectory = om.run_estimator(om.make_estimator("exact", run.model), run.actions, run.observations)
    path = plots.animate(run.model, trajectory, tmp_path / "corridor.gif", true_locations=run.locations,
                         true_maps=run.maps)
    with Image.open(path) as gif:
        assert gif.n_frames == run.n_steps and gif.size[0] > 2 * gif.size[1]


def test_explore_and_navigate_animate_and_record_their_first_run(tmp_path, capsys):
    """``--animate FILE`` (and ``--mcap FILE``) on ``explore`` and ``navigate``: the first planner's
    run with the first seed, every step a frame (at most MAX_FRAMES), read back."""
    from onlinemap.cli import main

    gif, mcap = tmp_path / "explore.gif", tmp_path / "explore.mcap"
    assert main(["explore", "--world", "building:10x12,seed=1", "--planner", "frontier,random", "--steps", "15",
                 "--animate", str(gif), "--mcap", str(mcap)]) == 0
    assert f"wrote {gif}, {mcap}" in capsys.readouterr().out
    with Image.open(gif) as image:
        assert image.n_frames == 15
    reader = pytest.importorskip("mcap.reader")
    with open(mcap, "rb") as stream:
        counts = reader.make_reader(stream).get_summary().statistics.channel_message_counts
    assert set(counts.values()) == {15}
    goal_gif = tmp_path / "navigate.gif"
    assert main(["navigate", "--world", "door,blocking=1,footprint=cross", "--goal", "2,2", "--planner", "goto",
                 "--repeats", "1", "--steps", "30", "--animate", str(goal_gif)]) == 0
    with Image.open(goal_gif) as image:
        assert 2 <= image.n_frames <= 31


def test_the_views_are_checked_before_any_work(tmp_path, capsys):
    from onlinemap.cli import main

    for flag, name, message in (("--animate", "run.png", "must end in .gif or .mp4"),
                                ("--mcap", "run.bag", "must end in .mcap")):
        assert main(["explore", "--steps", "5", flag, str(tmp_path / name)]) == 2
        captured = capsys.readouterr()
        assert message in captured.err and "planners" not in captured.out  # refused before the run starts
    from onlinemap.cli.views import MAX_FRAMES, animation_every
    assert [animation_every(n) for n in (1, MAX_FRAMES, MAX_FRAMES + 1, 2000)] == [1, 1, 2, 14]


def test_track_animates_the_steps_of_its_stream(tmp_path):
    """``track --animate``: one frame per step this process took (after a resume, the steps since)."""
    import json
    import subprocess
    import sys

    lines = [{"observation": "free"}] + [{"action": "east", "observation": "free"}] * 4
    command = [sys.executable, "-m", "onlinemap", "track", "--world", "door", "--estimator", "bk",
               "--checkpoint", str(tmp_path / "state.npz"), "--animate", str(tmp_path / "stream.gif")]
    for part, first in ((lines[:3], 0), (lines[3:], 3)):  # the second process resumes at step 3
        done = subprocess.run(command, input="".join(json.dumps(line) + "\n" for line in part), text=True,
                              capture_output=True, timeout=300)
        assert done.returncode == 0, done.stderr
        assert [json.loads(line)["t"] for line in done.stdout.splitlines()] == list(range(first, first + len(part)))
        with Image.open(tmp_path / "stream.gif") as gif:
            assert gif.n_frames == len(part)
    with pytest.raises(InvalidOptionError, match="first_step"):
        plots.animate(om.corridor(3), om.Trajectory(np.full((1, 3), 1 / 3), np.full((1, 3, 2), 0.5), np.zeros(1), 0),
                      tmp_path / "x.gif", first_step=-1)


def test_a_resumed_explore_animates_the_same_run_played_again(tmp_path):
    """With ``--out`` a rerun resumes every task from its parts: the animated run is then played
    again in this process (seeded by its task), and it is the same run, frame for frame."""
    from onlinemap.cli import main

    frames = []
    for name in ("first.gif", "resumed.gif"):
        assert main(["explore", "--world", "building:10x12,seed=1", "--planner", "frontier", "--steps", "12",
                     "--out", str(tmp_path / "out"), "--animate", str(tmp_path / name)]) == 0
        frames.append(gif_frames(tmp_path / name))
    assert len(frames[0]) == len(frames[1]) == 12
    for first, resumed in zip(*frames):
        np.testing.assert_array_equal(first, resumed)
