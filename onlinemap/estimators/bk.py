"""Boyen-Koller factored filtering (DESIGN.md section 3, ``bk``).

The belief is kept as a product of marginals ``q(L) prod_i mu_i(m_i)``. One step:

- predict, exact for a product: ``q <- q T[a]`` (motion ignores the map) and
  ``mu_i <- mu_i C`` (cells change independently);
- update by ``O[m_L, z]``, exact from the product prior, then project back onto marginals.
  With ``lam_l = sum_k mu_l(k) O[k, z]`` and ``Z = sum_l q(l) lam_l``:

      q'(l)     = q(l) lam_l / Z
      mu_i'(k)  = mu_i(k) (q(i) O[k, z] + Z - q(i) lam_i) / Z

The projection forgets the correlation between the location and the cells (and between
cells), which is exactly what map learning with an uncertain location needs: BK is cheap
(O(N K) per step, O(N K^2) with map dynamics) and, on the corridor, poor.
``log_evidence`` sums ``log Z``: the evidence of the factored model, not of the true one.
"""

from __future__ import annotations

import math

import numpy as np

from ..belief import Belief
from ..errors import ImpossibleObservationError
from ..model import GridModel, apply_motion
from ..validation import check_step
from .base import register

_SMALLEST_NORMAL = np.finfo(np.float64).tiny


def bk_update(location: np.ndarray, maps: np.ndarray, likelihood: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Exact observation update of the product ``location (N,) x prod_i maps[i] (N, K)`` by
    ``likelihood (K,) = O[:, z]`` at the robot's cell, projected onto marginals.
    Returns ``(location', maps', Z)`` with ``Z`` the predictive probability of ``z``. O(N K)."""
    lam = maps @ likelihood  # (N,) P(z | L = l) under the product
    joint_loc = location * lam
    total = float(joint_loc.sum())
    if not total > 0 or not np.isfinite(total):
        return location, maps, 0.0
    here = location[:, None] * likelihood[None, :]  # robot in cell i: label weighted by O[k, z]
    elsewhere = (total - joint_loc)[:, None]  # robot elsewhere: cell i's label untouched
    return joint_loc / total, np.minimum(maps * (here + elsewhere) / total, 1.0), total  # rounding: <= 1


@register("bk")
class BoyenKoller:
    """Boyen-Koller filter over ``P(L) prod_i P(m_i)``. No options. O(N K^2) per step."""

    def __init__(self, model: GridModel):
        self.model = model
        self._t = -1
        self._location = model.location_prior()
        self._maps = np.array(model.label_prior)
        self._log_evidence = 0.0
        self._belief: Belief | None = None

    def step(self, action, observation) -> Belief:
        a, z = check_step(self.model, self._t + 1, action, observation)
        location, maps = self._location, self._maps
        if a is not None:
            location = apply_motion(self.model, location, a)
            if not self.model.is_static:
                maps = maps @ self.model.change
        likelihood, log_scale = self.model.likelihood[z], 0.0
        updated = bk_update(location, maps, likelihood)
        if not updated[2] >= _SMALLEST_NORMAL and likelihood.max() > 0:  # underflow: rescale O[:, z] by its max
            log_scale = math.log(likelihood.max())
            updated = bk_update(location, maps, likelihood / likelihood.max())
        location, maps, total = updated
        if total == 0.0:
            raise ImpossibleObservationError(
                f"observation {self.model.label_names[z]!r} has probability zero under the factored "
                f"(Boyen-Koller) belief at step {self._t + 1}")
        self._location, self._maps = location, maps
        self._log_evidence += math.log(total) + log_scale
        self._t += 1
        self._belief = Belief(self._t, location, maps, self._log_evidence)
        return self._belief
