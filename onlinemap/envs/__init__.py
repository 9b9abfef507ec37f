"""Gymnasium environments (optional: ``pip install gymnasium``, in a clone ``pip install -e '.[gym]'``).

Importing this package registers ``onlinemap/DoorWorld-v0`` (the dynamic 10 x 10 door world,
``p_door = 0.01``, 500 steps per episode)::

    import gymnasium as gym
    env = gym.make("onlinemap.envs:onlinemap/DoorWorld-v0", render_mode="rgb_array")

``import onlinemap`` never imports gymnasium; only this package does.
"""

try:
    import gymnasium
except ImportError as error:  # pragma: no cover - exercised in a subprocess by the tests
    raise ImportError("onlinemap.envs needs gymnasium, an optional dependency: "
                      "pip install gymnasium (in a clone: pip install -e '.[gym]')") from error

from .door_world import DoorWorldEnv

DOOR_WORLD_ID = "onlinemap/DoorWorld-v0"

if DOOR_WORLD_ID not in gymnasium.registry:
    gymnasium.register(DOOR_WORLD_ID, entry_point="onlinemap.envs.door_world:DoorWorldEnv",
                       max_episode_steps=500, kwargs={"p_door": 0.01})

__all__ = ["DoorWorldEnv", "DOOR_WORLD_ID"]
