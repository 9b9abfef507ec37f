"""onlinemap.envs.DoorWorldEnv: gymnasium's own checker, reproducibility, the model's statistics,
rendering, and the optional-dependency error."""

import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

gym = pytest.importorskip("gymnasium")
from gymnasium.utils.env_checker import check_env  # noqa: E402

import onlinemap as om  # noqa: E402
from onlinemap.envs import DOOR_WORLD_ID, DoorWorldEnv  # noqa: E402
from onlinemap.envs.door_world import DOOR_COLORS, ROBOT_COLOR  # noqa: E402
from estimator_cases import binomial_ok  # noqa: E402


@pytest.mark.parametrize("render_mode", ["rgb_array", "ansi", None])
def test_passes_check_env(render_mode):
    env = gym.make(DOOR_WORLD_ID, render_mode=render_mode)
    check_env(env.unwrapped)
    assert env.spec.max_episode_steps == 500
    assert env.unwrapped.model.C[2, 3] == pytest.approx(0.01)


def test_module_prefixed_id_imports_and_registers():
    env = gym.make(f"onlinemap.envs:{DOOR_WORLD_ID}")
    assert isinstance(env.unwrapped, DoorWorldEnv)


def episode(env, seed, n_steps=120):
    obs, info = env.reset(seed=seed)
    record = [(int(obs), info["location"], tuple(info["map"]), 0.0)]
    actions = np.random.default_rng(99).integers(env.action_space.n, size=n_steps)
    for a in actions:
        obs, reward, terminated, truncated, info = env.step(a)
        assert not terminated and not truncated
        record.append((int(obs), info["location"], tuple(info["map"]), reward))
    return record


def test_same_seed_same_episode_different_seed_different_episode():
    env = DoorWorldEnv(p_door=0.05)
    first = episode(env, 7)
    assert episode(env, 7) == first
    assert episode(DoorWorldEnv(p_door=0.05), 7) == first
    assert episode(env, 8) != first


def test_time_limit_truncates_the_registered_env():
    env = gym.make(DOOR_WORLD_ID)
    env.reset(seed=0)
    for t in range(500):
        *_, terminated, truncated, _ = env.step(1)
    assert truncated and not terminated


def test_dynamics_have_the_model_statistics():
    """Slips, sensor errors and door flips happen at the model's rates (binomial tolerances)."""
    p_move, p_obs, p_door = 0.8, 0.9, 0.05
    env = DoorWorldEnv(p_move=p_move, p_obs=p_obs, p_door=p_door)
    model = env.unwrapped.model
    _, info = env.reset(seed=1)
    rng = np.random.default_rng(2)
    moves = stays = correct = seen = flips = door_steps = 0
    doors = np.flatnonzero(info["map"] >= 2)
    for _ in range(6000):
        before, labels = info["location"], info["map"]
        a = int(rng.integers(4))
        obs, reward, _, _, info = env.step(a)
        if model.neighbors[before, a] != before:
            moved = info["location"] != before
            moves, stays = moves + moved, stays + (not moved)
        correct += obs == info["map"][info["location"]]
        seen += 1
        flips += int((info["map"][doors] != labels[doors]).sum())
        door_steps += len(doors)
        assert np.array_equal(info["map"] >= 2, labels >= 2)  # doors stay doors; walls stay walls
    for hits, n, p in ((moves, moves + stays, p_move), (correct, seen, p_obs), (flips, door_steps, p_door)):
        assert binomial_ok(hits, n, p), (hits, n, p)


def test_reward_counts_first_visits():
    env = DoorWorldEnv(p_move=1.0)
    _, info = env.reset(seed=0)
    total = 0.0
    for a in [1, 1, 3, 3, 2]:  # east, east, west, west, south
        _, reward, *_, info = env.step(a)
        total += reward
    assert total == 3.0 and info["visited"] == 4


def test_render_shows_the_map_and_the_robot():
    env = DoorWorldEnv(render_mode="rgb_array", cell_pixels=8)
    _, info = env.reset(seed=0)
    image = env.render()
    assert image.shape == (80, 80, 3) and image.dtype == np.uint8
    row, col = divmod(info["location"], 10)
    assert np.array_equal(image[row * 8 + 4, col * 8 + 4], ROBOT_COLOR)
    labels = info["map"].reshape(10, 10)
    assert np.array_equal(image[3 * 8, 2 * 8], DOOR_COLORS[labels[3, 2]])
    text = DoorWorldEnv(render_mode="ansi")
    text.reset(seed=0)
    lines = text.render().splitlines()
    assert lines[0][0] == "R" and lines[3] == "##c###..##"


def test_bad_use_is_refused():
    env = DoorWorldEnv()
    with pytest.raises(gym.error.ResetNeeded):
        env.step(0)
    env.reset(seed=0)
    with pytest.raises(om.InvalidActionError):
        env.step(4)
    with pytest.raises(om.ModelError):
        DoorWorldEnv(model=om.corridor(4))  # a model needs its true map
    with pytest.raises(om.ModelError):
        DoorWorldEnv(true_map=np.zeros(100, dtype=int))  # a layout has its own map
    with pytest.raises(ValueError, match="render_mode"):
        DoorWorldEnv(render_mode="human")


def test_any_grid_model_works():
    model = om.grid_model(2, 3, 3, change=om.model.symmetric_channel(3, 0.9))
    env = DoorWorldEnv(model=model, true_map=[0, 1, 2, 0, 1, 2], render_mode="ansi")
    check_env(env, skip_render_check=True)
    env.reset(seed=0)
    assert env.render().splitlines()[1] == "012"


def test_onlinemap_imports_without_gymnasium_and_envs_says_how_to_install():
    code = textwrap.dedent("""
        import sys
        sys.modules["gymnasium"] = None  # make it unimportable
        import onlinemap, policies
        try:
            import onlinemap.envs
        except ImportError as error:
            print(error)
        else:
            print("imported")
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         env={**os.environ, "MPLBACKEND": "Agg"})
    assert "pip install gymnasium" in out.stdout
