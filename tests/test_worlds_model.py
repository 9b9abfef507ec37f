"""Blocking labels and sensor footprints in the model, the simulator and the observation checks
(issue 13; DESIGN.md section 7)."""

import itertools

import numpy as np
import pytest

import onlinemap as om
from estimator_cases import binomial_ok
from onlinemap.checkpoint import decode_model, encode_model
from onlinemap.errors import InvalidObservationError, ModelError
from onlinemap.model import FOOTPRINTS, model_difference
from onlinemap.validation import check_sequence, check_step


def test_defaults_are_the_papers_model():
    model = om.grid_model(3, 4)
    assert model.footprint == ((0, 0),) and model.n_readings == 1 and not model.has_blocking
    assert model.blocking.dtype == bool and model.blocking.shape == (2,) and not model.blocking.flags.writeable
    np.testing.assert_array_equal(model.footprint_cells[:, 0], np.arange(12))
    assert model_difference(model, om.grid_model(3, 4, footprint="cell", blocking=None)) is None


def test_presets_and_footprint_cells_by_geometry():
    assert FOOTPRINTS["cross"] == ((0, 0), (-1, 0), (0, 1), (1, 0), (0, -1))
    assert FOOTPRINTS["square"] == tuple(itertools.product((-1, 0, 1), repeat=2))
    model = om.grid_model(3, 4, footprint="square")
    assert model.n_readings == 9 and not model.footprint_cells.flags.writeable
    for cell, (f, (dr, dc)) in itertools.product(range(12), enumerate(model.footprint)):
        r, c = divmod(cell, 4)
        inside = 0 <= r + dr < 3 and 0 <= c + dc < 4
        assert model.footprint_cells[cell, f] == ((r + dr) * 4 + c + dc if inside else -1)


def test_blocking_labels_by_name_or_index():
    door, _ = om.door_world(blocking=True, footprint="cross")
    np.testing.assert_array_equal(door.blocking, [False, True, False, True])
    assert door.has_blocking and door.n_readings == 5
    assert not om.door_world()[0].has_blocking
    np.testing.assert_array_equal(om.grid_model(2, 3, 3, blocking=["1", 2]).blocking, [False, True, True])
    np.testing.assert_array_equal(om.corridor(6, blocking=1).blocking, [False, True])
    with pytest.raises(ModelError, match="unknown blocking label"):
        om.grid_model(2, 3, blocking=["wall"])
    with pytest.raises(ModelError, match="blocking label 5"):
        om.grid_model(2, 3, blocking=[5])
    with pytest.raises(ModelError, match="True or False"):
        om.door_world(blocking="wall")


@pytest.mark.parametrize("footprint, match", [("ring", "unknown footprint"), ([], "non-empty"),
                                              ([(0, 0), (0, 0)], "repeats"), ([(0.5, 1)], "int")])
def test_bad_footprints_raise(footprint, match):
    with pytest.raises(ModelError, match=match):
        om.grid_model(2, 3, footprint=footprint)


def test_new_fields_define_the_model_and_checkpoint():
    plain = om.grid_model(2, 3)
    assert model_difference(plain, om.grid_model(2, 3, blocking=[1])) == "blocking"
    assert model_difference(plain, om.grid_model(2, 3, footprint="cross")) == "footprint"
    both = om.grid_model(2, 3, blocking=[1], footprint="cross")
    assert model_difference(decode_model(encode_model(both)), both) is None
    old = encode_model(plain)  # a checkpoint written before the two fields existed still loads
    old["fields"] = {k: v for k, v in old["fields"].items() if k not in ("blocking", "footprint")}
    assert model_difference(decode_model(old), plain) is None


def test_defaults_simulate_bit_identically():
    model = om.corridor(8, 3, p_change=0.1)
    same = om.corridor(8, 3, p_change=0.1, footprint="cell", blocking=None)
    actions = om.random_walk(model, 300, seed=1)
    a, b = om.simulate(model, None, actions, seed=2), om.simulate(same, None, actions, seed=2)
    for name in ("locations", "maps", "observations"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))


def test_steps_draws_a_random_walk_from_the_same_seed():
    model = om.grid_model(3, 3)
    run = om.simulate(model, steps=40, seed=5)
    rng = np.random.default_rng(5)
    expected = om.simulate(model, None, om.random_walk(model, 39, rng), seed=rng)
    assert run.n_steps == 40
    np.testing.assert_array_equal(run.actions, expected.actions)
    np.testing.assert_array_equal(run.observations, expected.observations)
    with pytest.raises(ModelError, match="either actions or steps"):
        om.simulate(model, actions=[0], steps=3)
    with pytest.raises(ModelError, match="steps must be at least 1"):
        om.simulate(model, steps=0)


def test_blocking_walls_are_never_entered_and_free_moves_succeed_with_p_move():
    model, true_map = om.door_world(p_move=0.7, p_door=0.05, blocking=True)
    run = om.simulate(model, true_map, om.random_walk(model, 20000, seed=1), seed=2)
    before = run.locations[:-1]
    moved = run.locations[1:] != before
    entered = run.maps[:-1][np.arange(run.n_steps - 1), run.locations[1:]]  # label when entered
    assert not model.blocking[entered[moved]].any()  # (a door may close under a robot standing on it)
    static, true_map = om.door_world(blocking=True)
    still = om.simulate(static, true_map, om.random_walk(static, 5000, seed=1), seed=2)
    assert not static.blocking[true_map[still.locations]].any()
    intended = model.neighbors[before, run.actions]
    # passability is judged on the map before this step's change
    free = (intended != before) & ~model.blocking[run.maps[:-1][np.arange(run.n_steps - 1), intended]]
    assert binomial_ok(moved[free].sum(), free.sum(), 0.7)
    assert not moved[~free].any()
    assert (~free & (intended != before)).sum() > 500  # the walls were tried often


def test_footprint_readings_off_grid_are_minus_one_and_on_grid_through_O():
    model = om.grid_model(3, 4, 3, p_obs=0.8, footprint="cross")
    run = om.simulate(model, None, om.random_walk(model, 5000, seed=3), seed=4)
    assert run.observations.shape == (run.n_steps, 5)
    cells = model.footprint_cells[run.locations]
    np.testing.assert_array_equal(run.observations == -1, cells < 0)
    on = cells >= 0
    truth = run.maps[np.repeat(np.arange(run.n_steps), 5).reshape(-1, 5), np.where(on, cells, 0)]
    assert binomial_ok((run.observations[on] == truth[on]).sum(), on.sum(), 0.8)
    assert len(run.to_frame()) == run.n_steps


def test_footprint_observations_are_validated():
    model = om.grid_model(3, 4, 2, footprint="cross", label_names=("free", "wall"))
    _, z = check_step(model, 0, None, [0, -1, "wall", 1, -1])  # cell 0: north and west off grid
    np.testing.assert_array_equal(z, [0, -1, 1, 1, -1])
    for bad, match in [([0, 1, 1], "3 readings"), (0, "sequence of 5"), ([-1, 0, 0, 0, 0], "no location"),
                       ([0, 0, 0, 0, 0, 0], "6 readings"), ([0, 0, 2, 0, 0], "out of range"),
                       ([0, -1, 0, -1, -1], "no location")]:
        with pytest.raises(InvalidObservationError, match=match):
            check_step(model, 0, None, bad)
    run = om.simulate(model, None, om.random_walk(model, 30, seed=1), seed=1)
    _, z = check_sequence(model, run.actions, run.observations)
    np.testing.assert_array_equal(z, run.observations)
    _, z = check_sequence(model, run.actions, run.observations.tolist())
    np.testing.assert_array_equal(z, run.observations)
    wrong = run.observations.copy()
    wrong[3, 0] = -1
    with pytest.raises(InvalidObservationError, match="step 3"):
        check_sequence(model, run.actions, wrong)
    assert check_step(om.grid_model(3, 4), 0, None, "1") == (None, 1)  # the paper's sensor as before


def test_world_specs_and_the_gym_env_take_blocking_and_footprints():
    from onlinemap.worlds import parse_world

    spec = parse_world("door,blocking=1,footprint=cross")
    assert spec.model.has_blocking and spec.model.n_readings == 5
    assert parse_world("grid:3x3,blocking=1,footprint=square").model.blocking.tolist() == [False, True]
    assert not parse_world("door,blocking=0").model.has_blocking
    with pytest.raises(ModelError, match="0 or 1"):
        parse_world("door,blocking=2")
    pytest.importorskip("gymnasium")
    from onlinemap.envs.door_world import DoorWorldEnv

    env = DoorWorldEnv(blocking=True, footprint="cross", p_door=0.0)
    observation, info = env.reset(seed=1)
    seen, where = [observation], [info["location"]]
    for _ in range(300):
        observation, _, _, _, info = env.step(env.action_space.sample())
        assert not env.model.blocking[info["map"][info["location"]]]
        seen.append(observation)
        where.append(info["location"])
    assert all(env.observation_space.contains(z) for z in seen)
    np.testing.assert_array_equal(np.array(seen) == -1, env.model.footprint_cells[where] < 0)



SCALARS = [np.bool_(True), 1.0, float("nan"), object(), np.array(True), b"1"]
SCALAR_IDS = ["numpy-bool", "float", "nan", "object", "0-d-bool-array", "bytes"]


@pytest.mark.parametrize("blocking", SCALARS, ids=SCALAR_IDS)
@pytest.mark.parametrize("build", [lambda b: om.grid_model(2, 3, blocking=b), lambda b: om.corridor(4, blocking=b)],
                         ids=["grid_model", "corridor"])
def test_scalar_blocking_that_is_no_label_raises_model_error(build, blocking):
    """Regression (issue 24 item 6): a scalar that is not iterable raised a raw TypeError
    (``'numpy.bool' object is not iterable``)."""
    with pytest.raises(ModelError, match="blocking label"):
        build(blocking)


@pytest.mark.parametrize("blocking", SCALARS[1:], ids=SCALAR_IDS[1:])
def test_door_world_blocking_is_a_flag(blocking):
    with pytest.raises(ModelError, match="blocking must be True or False"):
        om.door_world(blocking=blocking)
    assert om.door_world(blocking=np.bool_(True))[0].has_blocking


def test_blocking_as_a_numpy_label_or_a_0d_array():
    np.testing.assert_array_equal(om.corridor(4, blocking=np.int64(1)).blocking, [False, True])
    np.testing.assert_array_equal(om.corridor(4, blocking=np.array(1)).blocking, [False, True])
    np.testing.assert_array_equal(om.grid_model(2, 2, 3, blocking=np.array([1, 2])).blocking, [False, True, True])
