"""Model construction and validation."""

import dataclasses

import numpy as np
import pytest

import onlinemap as om
from oracles import grid_motion


@pytest.mark.parametrize("rows,cols", [(1, 5), (2, 3), (4, 4), (3, 1)])
def test_motion_matrix_equals_geometry(rows, cols):
    model = om.grid_model(rows, cols, 2, p_move=0.7)
    expected = grid_motion(rows, cols, 0.7)
    for a in range(model.n_actions):
        np.testing.assert_allclose(model.motion_matrix(a).toarray(), expected[a], atol=1e-15)


def test_corridor_tables():
    model = om.corridor(5, 3, p_obs=0.7, p_change=0.2)
    assert (model.n_cells, model.n_labels, model.n_actions) == (5, 3, 2)
    assert model.action_names == ("left", "right")
    np.testing.assert_allclose(model.C, [[0.8, 0.1, 0.1], [0.1, 0.8, 0.1], [0.1, 0.1, 0.8]])
    np.testing.assert_allclose(model.O, [[0.7, 0.15, 0.15], [0.15, 0.7, 0.15], [0.15, 0.15, 0.7]])
    np.testing.assert_allclose(model.label_prior, np.full((5, 3), 1 / 3))
    assert not model.is_static and om.corridor(5).is_static


def test_door_world_default_and_layout():
    model, true_map = om.door_world(p_door=0.05)
    assert model.shape == (10, 10) and true_map.shape == (100,)
    assert model.label_names == ("free", "wall", "open_door", "closed_door")
    assert true_map[model.start] == 0
    assert set(np.unique(true_map)) == {0, 1, 2, 3}
    np.testing.assert_allclose(model.C[2], [0, 0, 0.95, 0.05])
    np.testing.assert_allclose(model.C[1], [0, 1, 0, 0])
    small, small_map = om.door_world("..#\no.c\n")
    assert small.shape == (2, 3)
    np.testing.assert_array_equal(small_map, [0, 0, 1, 2, 0, 3])
    assert om.DOOR_WORLD_10X10.count("\n") == 10
    from_array, array_map = om.door_world(np.array([[0, 0, 1], [2, 0, 3]], dtype=np.uint8), start=4)
    assert from_array.shape == (2, 3) and from_array.start == 4
    np.testing.assert_array_equal(array_map, small_map)


@pytest.mark.parametrize("layout, match", [
    (np.arange(3), "2D int array"), (np.zeros((2, 2)), "float64 array"), (np.zeros((0, 3), dtype=int), "non-empty"),
    (np.array([[0, 4], [0, 0]]), "0..3"), (np.array([[0, -1], [0, 0]]), "0..3"), ([[0, 1], [1, 0]], "got list"),
])
def test_door_world_refuses_bad_label_arrays(layout, match):
    with pytest.raises(om.ModelError, match=match):
        om.door_world(layout)


@pytest.mark.parametrize("kwargs,match", [
    (dict(p_obs=1.2), "p_obs"),
    (dict(p_move=-0.1), "p_move"),
    (dict(p_change=float("nan")), "p_change"),
    (dict(n_labels=1), "n_labels"),
    (dict(start=9), "start"),
    (dict(label_prior=[0.5, 0.6]), "label_prior"),
    (dict(label_prior=[0.5, 0.5, 0.0]), "label_prior"),
])
def test_invalid_corridor_raises(kwargs, match):
    with pytest.raises(om.ModelError, match=match):
        om.corridor(4, **kwargs)


def test_invalid_tables_raise():
    with pytest.raises(om.ModelError, match="change matrix"):
        om.grid_model(2, 2, 2, change=[[0.5, 0.4], [0, 1]])
    with pytest.raises(om.ModelError, match="sensor"):
        om.grid_model(2, 2, 2, sensor=[[1.0, 0.0, 0.0], [0, 1, 0]])
    with pytest.raises(om.ModelError, match="unknown character"):
        om.door_world("..x\n...")
    with pytest.raises(om.ModelError, match="lengths"):
        om.door_world("...\n..")


def test_model_is_immutable_and_replace_revalidates():
    model = om.corridor(4)
    with pytest.raises(dataclasses.FrozenInstanceError):
        model.p_move = 0.5
    with pytest.raises(ValueError):
        model.sensor[0, 0] = 0.5
    slower = dataclasses.replace(model, p_move=0.5)
    assert slower.p_move == 0.5 and slower.self_prob[1, 0] == 0.5
    with pytest.raises(om.ModelError):
        dataclasses.replace(model, p_move=2.0)


def test_world_specs():
    from onlinemap.worlds import parse_world

    assert parse_world("corridor:6,p_change=0.1,n_labels=3").model.n_labels == 3
    assert parse_world("grid:2x3").model.shape == (2, 3)
    world = parse_world("door,p_door=0.01")
    assert world.true_map is not None and world.model.C[2, 3] == 0.01
    with pytest.raises(om.ModelError, match="unknown option"):
        parse_world("corridor:5,foo=1")
    with pytest.raises(om.ModelError, match="unknown kind"):
        parse_world("maze:5")


def test_building_world_specs():
    from onlinemap.worlds import parse_world

    world = parse_world("building:32x32,seed=3")
    model, true_map = om.building(32, 32, seed=3)
    np.testing.assert_array_equal(world.true_map, true_map)
    np.testing.assert_array_equal(world.initial_map(7), true_map)
    assert world.model.start == model.start and world.model.has_blocking and world.model.n_readings == 5
    np.testing.assert_array_equal(parse_world("building").true_map, om.building(32, 32, seed=0)[1])
    options = dict(seed=1, p_obs=0.7, p_move=0.6, p_door=0.01, extra_doors=0.5, closed_share=0.2, rooms_deep=3,
                   corridor_width=2)
    world = parse_world("building:20x40," + ",".join(f"{k}={v}" for k, v in options.items())
                        + ",blocking=0,footprint=cell")
    model, true_map = om.building(20, 40, blocking=False, footprint="cell", **options)
    np.testing.assert_array_equal(world.true_map, true_map)
    assert om.model.model_difference(world.model, model) is None
    start = int(np.flatnonzero(true_map == 0)[0])
    assert parse_world(f"building:20x40,seed=1,start={start}").model.start == start
    for spec, match in [("building:32", "RxC"), ("building:9x32", "rows must be at least 10"),
                        ("building:32x32,seed=x", "seed must be a whole number"),
                        ("building:32x32,blocking=2", "0 or 1"), ("building:32x32,start=0", "start must be a free"),
                        ("building:32x32,extra_doors=2", "extra_doors")]:
        with pytest.raises(om.ModelError, match=match):
            parse_world(spec)


def test_change_powers_are_the_matrix_powers_shared_read_only_per_content():
    from onlinemap.model import change_powers

    change = om.door_world(p_door=0.05)[0].change
    powers = change_powers(change, 40)
    assert powers.shape == (40,) + change.shape and not powers.flags.writeable
    for d in (0, 1, 7, 39):  # an independent reference: numpy's repeated squaring
        np.testing.assert_allclose(powers[d], np.linalg.matrix_power(change, d), rtol=1e-12, atol=1e-15)
    assert change_powers(change.copy(), 40) is powers  # equal contents: the same table
    assert change_powers(np.asfortranarray(change), 40) is powers  # whatever the layout
    assert change_powers(change, 41) is not powers
    skewed = np.array([[0.9, 0.1], [0.3, 0.7]])  # not symmetric: its transpose has other contents
    assert change_powers(skewed.T, 5) is not change_powers(skewed, 5)
    np.testing.assert_array_equal(change_powers(skewed.T, 5)[1], skewed.T)


def test_sensor_inverse_is_numpys_pinv_shared_read_only_per_content():
    from onlinemap.hmm import sensor_inverse
    from onlinemap.model import symmetric_channel

    for sensor in (symmetric_channel(3, 0.9), symmetric_channel(2, 0.5)):  # invertible, then singular
        inverse = sensor_inverse(sensor)
        assert inverse.tobytes() == np.linalg.pinv(sensor).tobytes() and not inverse.flags.writeable
        assert sensor_inverse(sensor.copy()) is inverse
    assert sensor_inverse(np.eye(2)) is not sensor_inverse(np.eye(2, dtype=np.float32))  # dtype is part of the key


@pytest.mark.parametrize("p_move", [0.8, 0.95])
def test_press_likelihood_is_what_a_press_says_about_the_cell_pressed_into(p_move):
    model = om.grid_model(2, 3, 5, p_move=p_move, blocking=[1, 3, 4])
    blocks = {1, 3, 4}
    # written out: P(entered | k) = p_move [k passable] (row 0 without the constant p_move),
    # P(stayed | k) = 1 - p_move [k passable]
    entered = [0.0 if k in blocks else 1.0 for k in range(5)]
    stayed = [1.0 if k in blocks else 1.0 - p_move for k in range(5)]
    table = model.press_likelihood
    np.testing.assert_array_equal(table, [entered, stayed])
    assert not table.flags.writeable and model.press_likelihood is table  # computed once, read-only
    door, _ = om.door_world(p_move=p_move, blocking=True)  # walls and closed doors block
    passable = [name in ("free", "open_door") for name in door.label_names]
    np.testing.assert_array_equal(door.press_likelihood, [passable, np.where(passable, 1.0 - p_move, 1.0)])


def test_without_blocking_labels_a_press_says_nothing_about_the_map():
    for model in (om.door_world(p_move=0.95)[0], om.grid_model(2, 2, 3), om.corridor(4)):
        k = model.n_labels
        np.testing.assert_array_equal(model.press_likelihood, [np.ones(k), np.full(k, 1.0 - model.p_move)])
