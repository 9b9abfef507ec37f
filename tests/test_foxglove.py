"""Beliefs for Foxglove (issue 42 item 4): an MCAP recording read back with the ``mcap`` reader
(channels, schemas, message counts, one grid's values against the belief), and the live server
of ``track --foxglove`` started and stopped on a free port without a viewer."""

import json
import socket
import subprocess
import sys
from collections import Counter

import numpy as np
import pytest

import onlinemap as om

pytest.importorskip("foxglove")
reader = pytest.importorskip("mcap.reader")
protobuf = pytest.importorskip("mcap_protobuf.decoder")

# Foxglove's PackedElementField numeric types (https://docs.foxglove.dev/docs/visualization/message-schemas/
# numeric-type): the two the recording uses
NUMERIC = {1: "u1", 7: "<f4"}
PERIOD_NS = 100_000_000


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    from onlinemap.foxglove import record_run

    model, true_map = om.building(10, 14, seed=3)
    run = om.simulate(model, true_map, om.random_walk(model, 11, 1), seed=1)
    trajectory = om.run_estimator(om.make_estimator("rbpf", model, n_particles=30, seed=0), run.actions,
                                  run.observations)
    path = record_run(tmp_path_factory.mktemp("mcap") / "run.mcap", model, trajectory, run, goal=17)
    decoder = protobuf.DecoderFactory()
    messages = []
    with open(path, "rb") as stream:
        mcap = reader.make_reader(stream)
        summary = mcap.get_summary()
        for schema, channel, message in mcap.iter_messages():
            if channel.message_encoding == "json":
                decoded = json.loads(message.data)
            else:
                decoded = decoder.decoder_for(channel.message_encoding, schema)(message.data)
            messages.append((schema.name, channel.topic, message.log_time, decoded))
    return model, run, trajectory, summary, messages


def grid_cells(grid, rows: int) -> np.ndarray:
    """A foxglove.Grid's data as a structured (rows x columns) array in the model's row order
    (the grid is written y up: its first row is the model's last), read from its own fields."""
    dtype = np.dtype({"names": [f.name for f in grid.fields], "formats": [NUMERIC[f.type] for f in grid.fields],
                      "offsets": [f.offset for f in grid.fields], "itemsize": grid.cell_stride})
    assert grid.row_stride == grid.column_count * grid.cell_stride
    return np.frombuffer(grid.data, dtype=dtype).reshape(rows, grid.column_count)[::-1]


def test_the_recording_has_every_channel_once_per_step_with_its_schema(recorded):
    model, run, trajectory, summary, messages = recorded
    topics = {topic: name for name, topic, _, _ in messages}
    assert topics == {"/belief/map": "foxglove.Grid", "/belief/location": "foxglove.Grid",
                      "/world/map": "foxglove.Grid", "/robot/most_likely": "foxglove.PoseInFrame",
                      "/robot/true": "foxglove.PoseInFrame", "/planner/target": "foxglove.PoseInFrame",
                      "/robot": "onlinemap.Robot"}
    counts = Counter(topic for _, topic, _, _ in messages)
    assert set(counts.values()) == {trajectory.n_steps}
    assert summary.statistics.message_count == len(messages) == 7 * trajectory.n_steps
    for topic in topics:  # stamped by step: log time t x 0.1 s
        times = [time for _, name, time, _ in messages if name == topic]
        assert times == [t * PERIOD_NS for t in range(trajectory.n_steps)]


def test_a_map_grid_holds_the_belief_of_its_step(recorded):
    from matplotlib.colors import to_rgb

    from onlinemap.plots import UNKNOWN_COLOUR

    model, run, trajectory, _, messages = recorded
    t = 6
    grid = next(m for _, topic, time, m in messages if topic == "/belief/map" and time == t * PERIOD_NS)
    assert (grid.frame_id, grid.column_count, grid.cell_size.x, grid.cell_size.y) == ("map", model.cols, 1, 1)
    assert (grid.timestamp.seconds, grid.timestamp.nanos) == (0, 600_000_000)
    cells = grid_cells(grid, model.rows).reshape(-1)
    belief = trajectory.map[t]
    for k, name in enumerate(model.label_names):
        np.testing.assert_array_equal(cells[f"p_{name}"], belief[:, k].astype(np.float32))
    np.testing.assert_array_equal(cells["label"], belief.argmax(axis=1))
    palette = np.array([to_rgb(c) for c in ("white", "#404040", "tab:green", "tab:red")])
    sure = (belief.max(axis=1) - 0.25) / 0.75
    expected = sure[:, None] * palette[belief.argmax(axis=1)] + (1 - sure[:, None]) * np.array(to_rgb(UNKNOWN_COLOUR))
    rgb = np.stack([cells["red"], cells["green"], cells["blue"]], axis=1)
    np.testing.assert_allclose(rgb, 255 * expected, atol=0.51)
    assert (cells["alpha"] == 255).all()
    location = next(m for _, topic, time, m in messages if topic == "/belief/location" and time == t * PERIOD_NS)
    np.testing.assert_array_equal(grid_cells(location, model.rows).reshape(-1)["probability"],
                                  trajectory.location[t].astype(np.float32))
    world = next(m for _, topic, time, m in messages if topic == "/world/map" and time == t * PERIOD_NS)
    np.testing.assert_array_equal(grid_cells(world, model.rows).reshape(-1)["label"], run.maps[t])


def test_the_robots_cells_are_at_their_centres(recorded):
    model, run, trajectory, _, messages = recorded

    def cell(pose) -> int:  # x along the columns, y up from the bottom row
        col, row = pose.position.x - 0.5, model.rows - 0.5 - pose.position.y
        assert col == int(col) and row == int(row)
        return int(row) * model.cols + int(col)

    for topic, expected in (("/robot/most_likely", trajectory.location.argmax(axis=1)),
                            ("/robot/true", run.locations), ("/planner/target", np.full(run.n_steps, 17))):
        assert [cell(m.pose) for _, name, _, m in messages if name == topic] == list(expected)
    robot = [m for _, topic, _, m in messages if topic == "/robot"]
    assert [r["true_cell"] for r in robot] == list(run.locations) and robot[3]["t"] == 3
    assert robot[3]["p_most_likely"] == trajectory.location[3].max()


def test_track_serves_live_on_a_free_port_and_records(tmp_path):
    """``track --foxglove 0`` starts the server on a free port (named in an event), which accepts a
    connection while the stream runs and is gone at its end; ``--mcap`` records the stream."""
    record = tmp_path / "live.mcap"
    process = subprocess.Popen([sys.executable, "-m", "onlinemap", "track", "--world", "door", "--estimator", "bk",
                                "--planner", "goto", "--goal", "9,9", "--foxglove", "0", "--mcap", str(record)],
                               stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        events = []
        while not events or events[-1].get("event") != "foxglove":
            line = process.stderr.readline()
            assert line, process.stderr.read()
            events.append(json.loads(line))
        port = events[-1]["port"]
        assert port > 0 and events[-1]["url"] == f"ws://localhost:{port}"
        socket.create_connection(("127.0.0.1", port), timeout=10).close()  # a viewer could connect
        lines = [{"observation": "free"}, {"action": "east", "observation": "free"},
                 {"action": "south", "observation": "wall"}]
        out, err = process.communicate("\n".join(json.dumps(line) for line in lines) + "\n", timeout=120)
    finally:
        process.kill() if process.poll() is None else None
    assert process.returncode == 0, err
    assert len(out.splitlines()) == 3
    with pytest.raises(OSError):  # stopped: nothing listens there any more
        socket.create_connection(("127.0.0.1", port), timeout=2).close()
    assert {"event": "written", "path": str(record)} in [json.loads(line) for line in err.splitlines()], err
    with open(record, "rb") as stream:
        mcap = reader.make_reader(stream)
        topics = {channel.topic: n for channel_id, n in mcap.get_summary().statistics.channel_message_counts.items()
                  for channel in [mcap.get_summary().channels[channel_id]]}
    # a live stream has no true cell or map; goto's target and path are there
    assert topics == {"/belief/map": 3, "/belief/location": 3, "/robot/most_likely": 3, "/planner/target": 3,
                      "/planner/path": 3, "/robot": 3}


def test_import_onlinemap_does_not_import_foxglove():
    code = "import sys, onlinemap, onlinemap.plots; print('foxglove' in sys.modules, 'mcap' in sys.modules)"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.stdout.split() == ["False", "False"], done.stderr


def test_a_goal_plans_path_walks_down_its_value_to_the_goal():
    from onlinemap.foxglove import descent_path
    from policies import make_planner

    model, true_map = om.door_world(blocking=True)
    planner = make_planner("goto", model, goal=(9, 9))
    belief = om.make_estimator("bk", model).step(None, int(true_map[model.start]))
    planner.choose(belief)
    value = planner.plan.value
    path = descent_path(model, value, model.start)
    assert path[0] == model.start and path[-1] == planner.goal
    for here, there in zip(path, path[1:]):
        assert there in model.neighbors[here] and value[there] < value[here]
    assert descent_path(model, value, planner.goal) == [planner.goal]
    assert len(descent_path(model, value, model.start, limit=3)) == 3
    stuck = np.full(model.n_cells, np.inf)
    stuck[planner.goal] = 0.0
    assert descent_path(model, stuck, model.start) == [model.start]


def test_the_planner_view_is_a_goal_planners_goal_and_path_or_a_frontier_target():
    from onlinemap.cli.views import planner_view
    from policies import make_planner

    model, true_map = om.door_world()
    belief = om.make_estimator("bk", model).step(None, int(true_map[model.start]))
    assert planner_view(model, None, belief) == (None, None)
    frontier = make_planner("frontier", model, seed=0)
    frontier.choose(belief)
    assert planner_view(model, frontier, belief) == (int(frontier.last_plan.targets[0]), None)
    goto = make_planner("goto", model, goal=(9, 9))
    goto.choose(belief)
    target, path = planner_view(model, goto, belief)
    assert target == 99 and path[0] == belief.most_likely_location and path[-1] == 99
    assert planner_view(model, make_planner("random", model, seed=0), belief) == (None, None)
