"""Scripted runs from the literature (DESIGN.md section 5)."""

from __future__ import annotations

import numpy as np

from .model import corridor
from .simulate import Run

MURPHY_LABELS = (0, 1, 0, 1, 0, 1, 0, 1)
MURPHY_PATH = (0, 1, 2, 3, 3, 4, 5, 6, 5, 4, 3, 2, 1, 0, 0)


def scripted_corridor(labels, slips=(), p_obs: float = 0.9, p_move: float = 0.8) -> Run:
    """A static corridor with the given (N,) labels: start at cell 0, press right N - 1 times then
    left N - 1 times; the moves at the steps in ``slips`` (1 = the first move) fail, every other
    move succeeds unless blocked by the wall. Every observation is the true label of the true
    cell. The model (binary or K = max label + 1 labels) uses ``p_obs`` and ``p_move`` as the
    robot's beliefs. Deterministic. O(N)."""
    labels = np.asarray(labels, dtype=np.int64)
    n = len(labels)
    model = corridor(n, n_labels=max(2, int(labels.max()) + 1), p_obs=p_obs, p_move=p_move)
    actions = np.array([1] * (n - 1) + [0] * (n - 1), dtype=np.int64)
    path = [model.start]
    for t, a in enumerate(actions, start=1):
        path.append(path[-1] if t in slips else int(model.neighbors[path[-1], a]))
    path = np.array(path)
    return Run(model, actions, path, np.tile(labels, (len(path), 1)), labels[path])


def murphy_corridor(p_obs: float = 0.9, p_move: float = 0.8) -> Run:
    """The 8-cell corridor run: labels 0,1,0,1,0,1,0,1, start at cell 0, right x 7 then left x 7;
    the move at step 4 slips, so the true path is 0,1,2,3,3,4,5,6,5,4,3,2,1,0,0. Every
    observation is the true label of the true cell. Deterministic; the model uses ``p_obs`` and
    ``p_move`` (defaults 0.9, 0.8) as the robot's beliefs."""
    return scripted_corridor(MURPHY_LABELS, slips=(4,), p_obs=p_obs, p_move=p_move)
