"""Dead reckoning: a location filter that ignores the map and the observations.

``P(L_t) = P(L_{t-1}) T[a_t]``; the map belief is the label prior pushed through the map
dynamics, ``prior C^t``. Observations are validated but carry no information here, so
``log_evidence`` is NaN. Cost O(N + N K^2) per step.
"""

from __future__ import annotations

from ..belief import Belief
from ..model import GridModel, apply_motion
from ..validation import check_step
from .base import register


@register("dead_reckoning")
class DeadReckoning:
    """Motion-only location filter; map = prior. No options."""

    def __init__(self, model: GridModel):
        self.model = model
        self._t = -1
        self._belief: Belief | None = None

    def step(self, action, observation) -> Belief:
        a, _ = check_step(self.model, self._t + 1, action, observation)
        if a is None:
            location, maps = self.model.location_prior(), self.model.label_prior
        else:
            location = apply_motion(self.model, self._belief.location, a)
            maps = self._belief.map @ self.model.change
        self._t += 1
        self._belief = Belief(self._t, location, maps)
        return self._belief
