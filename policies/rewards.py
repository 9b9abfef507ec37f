"""Per-cell rewards computed from a belief (DESIGN.md section 4).

A reward is an (N,) array, ``R(i)`` = the reward for *being in* cell ``i`` (paid after a move
lands there; see :func:`policies.mdp.policy_iteration` for the convention). Any function
``belief -> (N,)`` can be used where a reward function is expected.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from onlinemap.belief import Belief
from onlinemap.metrics import normalized_entropy

RewardFunction = Callable[[Belief], np.ndarray]


def entropy_reward(belief: Belief) -> np.ndarray:
    """The entropy reward ``R(i) = H(L) (1 - H(m_i)) + (1 - H(L)) H(m_i)``, (N,) in [0, 1].

    ``H(L)`` is the entropy of ``belief.location`` divided by ``log N``, ``H(m_i)`` that of
    ``belief.map[i]`` divided by ``log K``. A lost robot (``H(L)`` near 1) is paid to visit
    cells whose labels it knows, to relocalise; a localised one to visit uncertain cells, to
    learn them. Cost O(N K).
    """
    n_cells = belief.location.shape[0]
    lost = float(normalized_entropy(belief.location)) if n_cells > 1 else 0.0
    unknown = normalized_entropy(belief.map)
    return lost * (1.0 - unknown) + (1.0 - lost) * unknown


def collected_entropy_reward(belief: Belief) -> np.ndarray:
    """``entropy_reward(belief) * (1 - P(L = i))``: the reward of the cell the robot is in counts
    as collected by the observation it has just made.

    With :func:`entropy_reward` a robot torn between two neighbouring cells can stay put forever:
    the map marginal of its cell stays uncertain (half the hypotheses place it elsewhere),
    staying keeps paying, and repeating the same observation never resolves the ambiguity.
    Here staying where the robot believes it is earns little, so it moves on. Cost O(N K).
    """
    return entropy_reward(belief) * (1.0 - belief.location)
