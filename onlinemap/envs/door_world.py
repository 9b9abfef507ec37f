"""The door world as a gymnasium environment.

The agent sees only the label of the cell it is in (``Discrete(K)``), or with a sensor footprint
of F offsets one reading per offset (``MultiDiscrete``, values -1..K-1, -1 off the grid), and
chooses among the model's moves (``Discrete(A)``); blocking labels (``blocking=True``: walls and
closed doors) cannot be entered; the world moves, changes and is observed exactly as in
:func:`onlinemap.simulate` (:func:`onlinemap.simulate.world_step`). The true location and map
are in ``info`` for evaluation, not for the agent.

Reward: 1 the first time a cell is entered in an episode, else 0 (coverage). The episode
never terminates; the registered id adds a 500-step time limit.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np

from ..arrays import read_only
from ..errors import ModelError
from ..model import DOOR_LABELS, GridModel, door_world
from ..simulate import world_step
from ..validation import action_index, check_map

# RGB per door-world label: free, wall, open door, closed door
DOOR_COLORS = np.array([[245, 245, 245], [60, 60, 60], [80, 190, 90], [170, 70, 40]], dtype=np.uint8)
ROBOT_COLOR = np.array([40, 90, 230], dtype=np.uint8)
TEXT_CHARS = ".#oc"


class DoorWorldEnv(gym.Env):
    """A door world (default layout :data:`onlinemap.DOOR_WORLD_10X10`) as a gymnasium env.

    Build it from a layout and the model parameters, or pass ``model`` and ``true_map``
    (any :class:`~onlinemap.GridModel`; its own parameters are used). ``info`` holds ``t``, ``location`` (true cell),
    ``map`` (true labels, (N,) copy) and ``visited`` (distinct cells entered so far).
    Render modes: ``rgb_array`` (``cell_pixels`` pixels per cell, robot in blue), ``ansi``.
    """

    metadata = {"render_modes": ["rgb_array", "ansi"], "render_fps": 4}

    def __init__(self, layout: str | None = None, *, p_obs: float = 0.9, p_move: float = 0.8,
                 p_door: float = 0.01, start: int | None = None, model: GridModel | None = None,
                 true_map=None, render_mode: str | None = None, cell_pixels: int = 16,
                 blocking: bool = False, footprint=None):
        if model is None:
            if true_map is not None:
                raise ModelError("true_map goes with model=...; a layout defines its own map")
            model, true_map = door_world(layout, p_obs=p_obs, p_move=p_move, p_door=p_door, start=start,
                                         blocking=blocking, footprint=footprint)
        elif layout is not None or true_map is None:
            raise ModelError("pass either a layout, or a model together with its true_map")
        initial = check_map(model, true_map)
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']} or None, got {render_mode!r}")
        self.model = model
        self.initial_map = read_only(initial)
        self.render_mode = render_mode
        self.cell_pixels = int(cell_pixels)
        off_grid = bool(model.off_grid_patterns.any())  # readings may be -1
        if model.n_readings == 1:
            self.observation_space = gym.spaces.Discrete(model.n_labels + off_grid, start=-int(off_grid))
        else:
            self.observation_space = gym.spaces.MultiDiscrete(np.full(model.n_readings, model.n_labels + 1),
                                                              start=np.full(model.n_readings, -1))
        self.action_space = gym.spaces.Discrete(model.n_actions)
        self._location: int | None = None
        self._labels = initial
        self._visited = np.zeros(model.n_cells, dtype=bool)
        self._t = 0

    def _info(self) -> dict:
        return {"t": self._t, "location": self._location, "map": self._labels.copy(),
                "visited": int(self._visited.sum())}

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self._t = 0
        self._visited[:] = False
        self._location, self._labels, observation = world_step(
            self.model, self.model.start, self.initial_map, None, self.np_random)
        self._visited[self._location] = True
        return self._observation(observation), self._info()

    def _observation(self, observation):
        return np.int64(observation) if self.model.n_readings == 1 else np.asarray(observation, dtype=np.int64)

    def step(self, action):
        if self._location is None:
            raise gym.error.ResetNeeded("call reset() before step()")
        a = action_index(self.model, action)
        self._location, self._labels, observation = world_step(
            self.model, self._location, self._labels, a, self.np_random)
        self._t += 1
        reward = 0.0 if self._visited[self._location] else 1.0
        self._visited[self._location] = True
        return self._observation(observation), reward, False, False, self._info()

    def render(self):
        if self.render_mode == "ansi":
            return self._text()
        if self.render_mode == "rgb_array":
            return self._image()
        return None

    def _colors(self) -> np.ndarray:
        if self.model.label_names == DOOR_LABELS:
            return DOOR_COLORS
        shades = np.linspace(235, 60, self.model.n_labels).astype(np.uint8)
        return np.repeat(shades[:, None], 3, axis=1)

    def _image(self) -> np.ndarray:
        """(rows * px, cols * px, 3) uint8: cells coloured by true label, the robot as a square."""
        px = self.cell_pixels
        cells = self._colors()[self._labels].reshape(self.model.rows, self.model.cols, 3)
        image = np.repeat(np.repeat(cells, px, axis=0), px, axis=1)
        if self._location is not None:
            row, col = divmod(self._location, self.model.cols)
            margin = px // 4
            image[row * px + margin:(row + 1) * px - margin, col * px + margin:(col + 1) * px - margin] = ROBOT_COLOR
        return image

    def _text(self) -> str:
        chars = np.array(list(TEXT_CHARS if self.model.label_names == DOOR_LABELS
                              else "0123456789abcdefghijklmnopqrstuvwxyz"[:self.model.n_labels]))
        grid = chars[self._labels].reshape(self.model.rows, self.model.cols)
        if self._location is not None:
            grid[divmod(self._location, self.model.cols)] = "R"
        return "\n".join("".join(row) for row in grid) + "\n"
