"""Scripted runs from the literature (DESIGN.md section 5)."""

from __future__ import annotations

import numpy as np

from .errors import ModelError
from .model import GridModel, corridor
from .simulate import Run, there_and_back

MURPHY_LABELS = (0, 1, 0, 1, 0, 1, 0, 1)


def scripted_corridor(labels, slips=(), p_obs: float = 0.9, p_move: float = 0.8,
                      model: GridModel | None = None) -> Run:
    """A static corridor with the given (N,) labels: start at cell 0, press right N - 1 times then
    left N - 1 times; the moves at the steps in ``slips`` (1 = the first move) fail, every other
    move succeeds unless blocked by the wall. Every observation is the true label of the true
    cell. The model (binary or K = max label + 1 labels) uses ``p_obs`` and ``p_move`` as the
    robot's beliefs; or pass the robot's ``model`` (an N-cell corridor; its start cell is the
    run's). Deterministic. O(N)."""
    labels = np.asarray(labels, dtype=np.int64)
    n = len(labels)
    if model is None:
        model = corridor(n, n_labels=max(2, int(labels.max()) + 1), p_obs=p_obs, p_move=p_move)
    elif model.action_names != ("left", "right") or model.n_cells != n:
        raise ModelError(f"scripted_corridor: model must be a corridor of {n} cells")
    actions = there_and_back(model)
    path = [model.start]
    for t, a in enumerate(actions, start=1):
        path.append(path[-1] if t in slips else int(model.neighbors[path[-1], a]))
    path = np.array(path)
    return Run(model, actions, path, np.tile(labels, (len(path), 1)), labels[path])


def one_slip_corridor(labels, rng: np.random.Generator, p_obs: float = 0.9, p_move: float = 0.8,
                      model: GridModel | None = None) -> tuple[Run, int]:
    """:func:`scripted_corridor` with exactly one slip, at an outward move drawn uniformly in
    1..N-1 with ``rng``; returns (the run, the slip)."""
    slip = int(rng.integers(1, len(labels)))
    return scripted_corridor(labels, slips=(slip,), p_obs=p_obs, p_move=p_move, model=model), slip


def murphy_corridor(p_obs: float = 0.9, p_move: float = 0.8) -> Run:
    """The 8-cell corridor run: labels 0,1,0,1,0,1,0,1, start at cell 0, right x 7 then left x 7;
    the move at step 4 slips, so the true path is 0,1,2,3,3,4,5,6,5,4,3,2,1,0,0. Every
    observation is the true label of the true cell. Deterministic; the model uses ``p_obs`` and
    ``p_move`` (defaults 0.9, 0.8) as the robot's beliefs."""
    return scripted_corridor(MURPHY_LABELS, slips=(4,), p_obs=p_obs, p_move=p_move)
