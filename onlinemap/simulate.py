"""Simulation of the generative model, and action generators.

Order within a step (DESIGN.md section 1): the action moves the robot, then the map changes,
then the robot observes. Step 0 has no action. Every random choice takes ``seed`` (an int,
None or a ``numpy.random.Generator``); the global random state is never used.
"""

from __future__ import annotations

from dataclasses import dataclass

from typing import TYPE_CHECKING, Iterator

import numpy as np

from . import arguments
from .arrays import read_only
from .errors import ModelError
from .model import GridModel
from .rng import SeedLike, as_generator

if TYPE_CHECKING:
    import pandas as pd
from .validation import action_index, check_map



def _frozen_int(array) -> np.ndarray:
    return read_only(np.array(array, dtype=np.int64))


@dataclass(frozen=True, eq=False)
class Run:
    """A recorded run of T steps.

    actions: (T - 1,) action at steps 1..T-1; locations: (T,) true cells; maps: (T, N) true
    labels at each step; observations: (T,) labels seen, or (T, F) readings (-1 off the grid)
    when the model's footprint has F > 1 offsets.
    """

    model: GridModel
    actions: np.ndarray
    locations: np.ndarray
    maps: np.ndarray
    observations: np.ndarray

    def __post_init__(self) -> None:
        for name in ("actions", "locations", "maps", "observations"):
            object.__setattr__(self, name, _frozen_int(getattr(self, name)))
        t = len(self.observations)
        if self.observations.shape != (t,) + self.model.observation_shape or self.locations.shape != (t,) or \
                self.actions.shape != (t - 1,) or self.maps.shape != (t, self.model.n_cells):
            raise ModelError("inconsistent run record shapes")

    @property
    def n_steps(self) -> int:
        return len(self.observations)

    def __repr__(self) -> str:
        """One line: T, the model, the shapes, where the robot went, its slips and (dynamic
        worlds) the label changes; not the arrays. O(T N)."""
        t = self.n_steps
        changes = "" if self.model.is_static else f", {int((self.maps[1:] != self.maps[:-1]).sum())} label changes"
        return (f"Run(T={t} steps, model={self.model!r}, actions {self.actions.shape}, observations "
                f"{self.observations.shape}, locations {self.locations[0]} -> {self.locations[-1]}, "
                f"{int(self.slipped.sum())} of {t - 1} moves slipped{changes})")

    @property
    def initial_map(self) -> np.ndarray:
        return self.maps[0]

    @property
    def final_map(self) -> np.ndarray:
        return self.maps[-1]

    def steps(self) -> Iterator[tuple[int | None, int | np.ndarray]]:
        """The run as a ``step`` loop takes it: ``(None, z_0)``, then ``(a_t, z_t)`` for t = 1..T-1,
        actions and labels as ints (an (F,) array of readings with a footprint)::

            for action, observation in run.steps():
                belief = est.step(action, observation)

        Cost O(T)."""
        single = self.observations.ndim == 1
        for t in range(self.n_steps):
            observation = int(self.observations[t]) if single else self.observations[t]
            yield (None if t == 0 else int(self.actions[t - 1])), observation

    @property
    def slipped(self) -> np.ndarray:
        """(T - 1,) True where the intended neighbour existed but the robot stayed."""
        before = self.locations[:-1]
        intended = self.model.neighbors[before, self.actions]
        return (intended != before) & (self.locations[1:] == before)

    def to_frame(self) -> "pd.DataFrame":
        """One row per step: t, action (name, None at t = 0), true location, true label there,
        observation, whether the move slipped, and the number of cells whose label changed."""
        names = self.model.action_names
        changed = np.concatenate([[0], (self.maps[1:] != self.maps[:-1]).sum(axis=1)])
        import pandas as pd  # lazily: ``import onlinemap`` does not load pandas

        return pd.DataFrame({
            "t": np.arange(self.n_steps),
            "action": [None] + [names[a] for a in self.actions],
            "true_location": self.locations,
            "true_label": self.maps[np.arange(self.n_steps), self.locations],
            "observation": self.observations if self.observations.ndim == 1 else list(self.observations),
            "slipped": np.concatenate([[False], self.slipped]),
            "cells_changed": changed,
        })


def sample_map(model: GridModel, seed: SeedLike = None) -> np.ndarray:
    """(N,) labels drawn from the per-cell label prior."""
    rng = as_generator(seed)
    cumulative = np.cumsum(model.label_prior, axis=1)
    u = rng.random(model.n_cells)
    return np.minimum((u[:, None] >= cumulative).sum(axis=1), model.n_labels - 1)


def categorical(rng: np.random.Generator, rows: np.ndarray) -> np.ndarray:
    """(R,) one draw per row of a (R, K) stochastic matrix, by inversion of one uniform each (the
    world's map changes and readings; a paired world draws its changes from its own stream with
    it). O(R K)."""
    u = rng.random(rows.shape[0])
    return np.minimum((u[:, None] >= np.cumsum(rows, axis=1)).sum(axis=1), rows.shape[1] - 1)


def simulate(model: GridModel, true_map=None, actions=(), seed: SeedLike = None, *,
             steps: int | None = None) -> Run:
    """Simulate a run: ``len(actions) + 1`` steps starting at ``model.start``.

    true_map: (N,) initial labels (drawn from the prior when None); actions: indices or names.
    ``steps=T`` without actions: a run of T steps under a uniform random walk, its T - 1 actions
    drawn first from the same generator (``random_walk(model, T - 1, rng)``).
    Cost O(T (N + F)) for a dynamic world (every cell may change each step), O(T F) for a static
    one, F the footprint size.
    """
    rng = as_generator(seed)
    if steps is not None:
        if len(actions):
            raise ModelError("give either actions or steps, not both")
        steps = arguments.step_count("steps", steps, minimum=1, bytes_per_step=run_bytes_per_step(model))
        actions = random_walk(model, steps - 1, rng)
    n = model.n_cells
    current = sample_map(model, rng) if true_map is None else check_map(model, true_map)
    action_ids = np.array([action_index(model, a) for a in actions], dtype=np.int64)
    n_steps = arguments.step_count("the run's steps (actions + 1)", len(action_ids) + 1, minimum=1,
                                   bytes_per_step=run_bytes_per_step(model))
    locations = np.empty(n_steps, dtype=np.int64)
    maps = np.empty((n_steps, n), dtype=np.int64)
    observations = np.empty((n_steps,) + model.observation_shape, dtype=np.int64)
    location = model.start
    for t in range(n_steps):
        location, current, observations[t] = world_step(
            model, location, current, None if t == 0 else action_ids[t - 1], rng)
        locations[t] = location
        maps[t] = current
    return Run(model, action_ids, locations, maps, observations)


def world_step(model: GridModel, location: int, labels: np.ndarray, action: int | None,
               rng: np.random.Generator) -> tuple[int, np.ndarray, int | np.ndarray]:
    """One step of the true world: the action moves the robot (skipped when ``action`` is None,
    step 0), then the map changes, then the robot observes. ``labels`` (N,) is not modified;
    returns ``(location, labels, observation)``, the observation an int (F = 1) or an (F,) array
    of readings, -1 off the grid. A move into a cell whose label blocks fails (the robot stays);
    the draws are the same either way. Cost O(N + F) in a dynamic world, O(F) in a static one."""
    if action is not None:
        if rng.random() < model.p_move:
            target = int(model.neighbors[location, action])
            if not model.blocking[labels[target]]:
                location = target
        if not model.is_static:
            labels = categorical(rng, model.change[labels])
    if model.n_readings == 1:
        cell = location if model.reads_own_cell else int(model.footprint_cells[location, 0])
        if cell < 0:
            return location, labels, -1
        return location, labels, int(categorical(rng, model.sensor[labels[cell]][None])[0])
    cells = model.footprint_cells[location]
    on_grid = cells >= 0
    observation = np.full(model.n_readings, -1, dtype=np.int64)
    observation[on_grid] = categorical(rng, model.sensor[labels[cells[on_grid]]])
    return location, labels, observation


# --- action generators -------------------------------------------------------------------
def random_walk(model: GridModel, n_actions: int, seed: SeedLike = None) -> np.ndarray:
    """(n_actions,) actions drawn uniformly. ``n_actions``: a whole number >= 0 whose int64
    actions fit in memory (:func:`onlinemap.arguments.step_count`)."""
    n_actions = arguments.step_count("n_actions", n_actions, minimum=0, bytes_per_step=8)
    return as_generator(seed).integers(0, model.n_actions, size=n_actions)


def run_bytes_per_step(model: GridModel) -> int:
    """Bytes a simulated :class:`Run` holds per step: its action, location, map and readings
    (int64)."""
    return 8 * (2 + model.n_cells + model.n_readings)


def there_and_back(model: GridModel, trips: int = 1) -> np.ndarray:
    """Corridor only: ``right`` x (N - 1) then ``left`` x (N - 1), ``trips`` times."""
    if model.action_names != ("left", "right"):
        raise ModelError("there_and_back is for corridors (actions left, right)")
    one = [1] * (model.n_cells - 1) + [0] * (model.n_cells - 1)
    return np.array(one * int(trips), dtype=np.int64)
