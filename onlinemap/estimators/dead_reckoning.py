"""Dead reckoning: a location filter that ignores the map and the observations.

``P(L_t) = P(L_{t-1}) T[a_t]``; the map belief is the label prior pushed through the map
dynamics, ``prior C^t``. Observations are validated but carry no information here, so
``log_evidence`` is NaN: undefined, as dead reckoning has no observation model. With blocking
labels the move into cell j succeeds with ``p_move * P(m_j passable)`` under that map belief
(the label prior pushed through C). Cost O(N + N K^2) per step, for any footprint.
"""

from __future__ import annotations

import math

from .. import state_checks as checks
from ..belief import Belief
from ..model import GridModel, apply_motion, passable_probability
from ..validation import check_step
from .base import register


@register("dead_reckoning")
class DeadReckoning:
    """Motion-only location filter; map = prior. No options.

    ``belief.log_evidence`` is NaN at every step: undefined, not an error. Dead reckoning has no
    observation model (it never weighs an observation), so it gives the observations no
    probability; leave it out when comparing estimators' evidence.
    """

    #: attributes fixed by the model and options, checked equal on load (:mod:`onlinemap.state_checks`)
    CONSTANT_STATE = ()

    def __init__(self, model: GridModel):
        self.model = model
        self._t = -1
        self._belief: Belief | None = None

    @staticmethod
    def check_state(state) -> None:
        """The invariants of a restored state (:mod:`onlinemap.state_checks`): the belief of step ``_t``."""
        checks.step_index(state)
        checks.belief(state, required=True)

    def step(self, action, observation) -> Belief:
        a, _ = check_step(self.model, self._t + 1, action, observation)
        if a is None:
            location, maps = self.model.location_prior(), self.model.label_prior
        else:
            passable = passable_probability(self.model, self._belief.map) if self.model.has_blocking else None
            location = apply_motion(self.model, self._belief.location, a, passable)
            maps = self._belief.map @ self.model.change
        self._t += 1
        self._belief = Belief(self._t, location, maps, log_evidence=math.nan)  # undefined: no observation model
        return self._belief
