"""Scripted runs from the literature (DESIGN.md section 5)."""

from __future__ import annotations

import numpy as np

from .model import corridor
from .simulate import Run

MURPHY_LABELS = (0, 1, 0, 1, 0, 1, 0, 1)
MURPHY_PATH = (0, 1, 2, 3, 3, 4, 5, 6, 5, 4, 3, 2, 1, 0, 0)


def murphy_corridor(p_obs: float = 0.9, p_move: float = 0.8) -> Run:
    """The 8-cell corridor run: labels 0,1,0,1,0,1,0,1, start at cell 0, right x 7 then left x 7;
    the move at step 4 slips, so the true path is 0,1,2,3,3,4,5,6,5,4,3,2,1,0,0. Every
    observation is the true label of the true cell. Deterministic; the model uses ``p_obs`` and
    ``p_move`` (defaults 0.9, 0.8) as the robot's beliefs."""
    model = corridor(len(MURPHY_LABELS), n_labels=2, p_obs=p_obs, p_move=p_move)
    labels = np.array(MURPHY_LABELS)
    actions = np.array([1] * 7 + [0] * 7)
    path = np.array(MURPHY_PATH)
    maps = np.tile(labels, (len(path), 1))
    return Run(model, actions, path, maps, labels[path])
