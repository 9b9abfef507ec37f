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

Blocking labels (DESIGN.md section 7): the prediction, exact from the product then projected,
moves into cell j with ``p_move * P(m_j passable)`` under ``mu_j`` (the map marginals are not
changed by motion). With blocking BK projects twice per step, after the prediction (which
correlates L with the cells it tried to enter) and after the update; a bump therefore teaches
the map nothing here (exact Bayes and the RBPF do learn from it). A footprint: ``lam_l = [off-grid readings fit l] prod_f mu_{c_f} . O[:, z_f]``
and each read cell's marginal takes the leave-one-out product of the other readings
(:func:`bk_footprint_update`). Cost O(N (K + F^2 + F K)) per step, O(N K^2) more when dynamic.

Label prior (``label_prior``, ``prior_strength``, ``learn_every``, as the RBPF's;
:mod:`onlinemap.label_prior`). In a static world every cell's marginal is
``mu_i(k) = normalise_k(prior_i(k) w(k) prod_s f_s(k))``: each update multiplies it by a factor
``q(i) O[k, z] + Z - q(i) lam_i`` (the footprint's likewise), so a frequency weight ``w`` (K,)
shared by all cells moves to ``w'`` by ``mu <- normalise(mu * w' / w)``
(:func:`~onlinemap.label_prior.tilt`), the factors kept. A fixed vector ``v``: ``w = v`` from
the start. ``"learn"`` (and None on a model whose label frequencies are unknown, in a static
world): every ``learn_every`` steps, after the update, ``w`` becomes the posterior mean of theta
given the expected label counts of the cells read (:func:`~onlinemap.label_prior.learned_frequencies`),
the plug-in (empirical Bayes) approximation the RBPF makes; the factors, computed under the
earlier ``w``, are not recomputed, nor is ``log_evidence``. Cost of a learning step O(N K).
"""

from __future__ import annotations

import math

import numpy as np

from .. import state_checks as checks
from ..arrays import read_only
from ..belief import Belief
from ..errors import ImpossibleObservationError
from ..label_prior import (DEFAULT_LEARN_EVERY, LEARN, LabelPrior, learned_frequencies, plug_in_prior, shown_options,
                           tilt)
from ..model import GridModel, apply_motion, passable_probability
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


def bk_footprint_update(model: GridModel, location: np.ndarray, maps: np.ndarray,
                        readings: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """:func:`bk_update` for a sensor footprint: the product ``location (N,) x prod_i maps[i]``
    updated by ``P(z | l, m) = prod_f O[m_{c_f(l)}, z_f]`` (0 where the -1 readings do not fit l),
    projected onto marginals. readings (F,) or an int (F = 1). Rounding is clipped: the mass of
    the locations not reading a cell is at least 0 and every marginal at most 1 (a noiseless
    sensor gave -2.4e-16 otherwise). O(N F (F + K))."""
    readings = np.atleast_1d(np.asarray(readings, dtype=np.int64))
    cells = model.footprint_cells
    fits = ((cells < 0) == (readings < 0)[None]).all(axis=1)
    read = fits[:, None] & (cells >= 0)  # (N, F) offset f of location l reads a cell
    columns = model.sensor[:, np.where(readings < 0, 0, readings)]  # (K, F) O[:, z_f]
    factor = np.ones(cells.shape)  # (N, F) mu_{c_f(l)} . O[:, z_f]
    on_l, on_f = np.nonzero(read)
    factor[on_l, on_f] = np.einsum("ik,ik->i", maps[cells[on_l, on_f]], columns[:, on_f].T)
    others = np.ones(cells.shape)  # (N, F) leave-one-out products: no division by a zero factor
    for f in range(cells.shape[1]):
        others[:, f] = np.prod(np.delete(factor, f, axis=1), axis=1)
    lam = np.where(fits, factor[:, 0] * others[:, 0], 0.0)  # (N,) P(z | L = l) under the product
    joint_loc = location * lam
    total = float(joint_loc.sum())
    if not total > 0 or not np.isfinite(total):
        return location, maps, 0.0
    weight = location[on_l] * others[on_l, on_f]  # q(l) prod_{f' != f}: how cell c_f(l) is weighted
    target = cells[on_l, on_f]
    reads_mass = np.bincount(target, weights=weight * factor[on_l, on_f], minlength=model.n_cells)
    here = np.zeros(maps.shape)
    np.add.at(here, target, weight[:, None] * columns[:, on_f].T)
    elsewhere = np.maximum(total - reads_mass, 0.0)  # >= 0 but for rounding (the products' orders differ)
    return joint_loc / total, np.minimum(maps * (here + elsewhere[:, None]) / total, 1.0), total  # rounding: <= 1


@register("bk")
class BoyenKoller:
    """Boyen-Koller filter over ``P(L) prod_i P(m_i)``. O(N K^2) per step
    (O(N (K^2 + F^2 + F K)) with a footprint of F offsets).

    Options ``label_prior``, ``prior_strength``, ``learn_every`` (the module docstring;
    :mod:`onlinemap.label_prior`): None (the default) is what the model says: on a model whose
    label frequencies are unknown (generated buildings, floors read from files) in a static world
    the filter learns them every ``learn_every`` steps (default 10); otherwise, and in a dynamic
    world, the model's prior table, every run as without the options. ``"model"``: the table
    always; a (K,) vector: every cell's prior tilted by it; ``"learn"``: learn (static worlds
    only). :attr:`label_frequencies` gives the frequencies in use (checkpointed when learned)."""

    #: attributes fixed by the model and options, checked equal on load (:mod:`onlinemap.state_checks`)
    CONSTANT_STATE = ()

    #: the learned label frequencies (K,): an attribute of a learning filter only (and of its
    #: checkpoints); None, this class default, for the others, whose state is as without the options
    _label_frequencies: np.ndarray | None = None

    def __init__(self, model: GridModel, *, label_prior=None, prior_strength=None, learn_every: int | None = None):
        prior = plug_in_prior(model, label_prior, prior_strength, learn_every)
        self.model = model
        self._t = -1
        self._location = model.location_prior()
        self._maps = np.array(model.label_prior)
        if prior.kind == "fixed":
            self._maps = tilt(self._maps, prior.frequencies)
        elif prior.kind == LEARN:  # pi_0 = alpha / A, uniform: the model's rows as they are
            self._label_frequencies = prior.alpha / prior.alpha.sum()
        self._log_evidence = 0.0
        self._belief: Belief | None = None

    @property
    def _prior(self) -> LabelPrior:
        """The label prior the options (checked when the filter was built) give. O(N K)."""
        return plug_in_prior(self.model, self.options["label_prior"], self.options["prior_strength"])

    @property
    def effective_options(self) -> dict:
        """The options as the filter runs them (:func:`~onlinemap.label_prior.shown_options`): what
        ``repr`` shows; ``options`` keeps what was given."""
        return shown_options(self.options, self._prior.kind)

    @property
    def label_frequencies(self) -> np.ndarray | None:
        """(K,) the label frequencies every cell's prior is tilted by, a read-only copy: the current
        estimate when learning, the given vector, or None (the model's own prior)."""
        if self._label_frequencies is not None:
            return read_only(self._label_frequencies.copy())
        fixed = self._prior.frequencies
        return None if fixed is None else read_only(fixed.copy())

    @staticmethod
    def check_state(state) -> None:
        """The invariants of a restored state (:mod:`onlinemap.state_checks`): the factored
        location (N,) and maps (N, K) are distributions; the belief of step ``_t``."""
        model = state.model
        checks.step_index(state)
        checks.probabilities("_location", checks.array(state, "_location", (model.n_cells,), np.float64))
        checks.probabilities("_maps", checks.array(state, "_maps", (model.n_cells, model.n_labels), np.float64))
        checks.log_evidence(state)
        checks.belief(state, required=True)
        frequencies = getattr(state, "_label_frequencies", None)  # a learning filter only
        if frequencies is not None:  # divided by at the next learning step: no zero
            frequencies = checks.array(state, "_label_frequencies", (model.n_labels,), np.float64)
            checks.probabilities("_label_frequencies", frequencies)
            if np.any(frequencies <= 0):
                checks.fail("_label_frequencies", "must be label frequencies in (0, 1]")

    def step(self, action, observation) -> Belief:
        a, z = check_step(self.model, self._t + 1, action, observation)
        location, maps = self._location, self._maps
        if a is not None:
            passable = passable_probability(self.model, maps) if self.model.has_blocking else None
            location = apply_motion(self.model, location, a, passable)
            if not self.model.is_static:
                maps = maps @ self.model.change
        if not self.model.reads_own_cell:
            location, maps, total = bk_footprint_update(self.model, location, maps, z)
            log_scale = 0.0
        else:
            likelihood, log_scale = self.model.likelihood[z], 0.0
            updated = bk_update(location, maps, likelihood)
            if not updated[2] >= _SMALLEST_NORMAL and likelihood.max() > 0:  # underflow: rescale O[:, z] by its max
                log_scale = math.log(likelihood.max())
                updated = bk_update(location, maps, likelihood / likelihood.max())
            location, maps, total = updated
        # a subnormal total (after rescaling O[:, z]) has lost its precision, and the projection's
        # maps * (Z - q lam) / Z with it: rows of cells never read came out all zeros. Refused, as
        # exact Bayes refuses (the observation's probability is below float64's range)
        if not total >= _SMALLEST_NORMAL:
            raise ImpossibleObservationError(
                f"observation {self.model.label_names[z] if self.model.reads_own_cell else np.asarray(z).tolist()!r} "
                f"has probability zero under the factored (Boyen-Koller) belief at step {self._t + 1} (or below "
                f"float64's range even after rescaling)")
        frequencies = self._label_frequencies
        if frequencies is not None and (self._t + 1) % (self.options["learn_every"] or DEFAULT_LEARN_EVERY) == 0:
            learned = learned_frequencies(maps, self.model.label_prior, frequencies, self._prior.alpha)
            maps = tilt(maps, learned / frequencies)
            self._label_frequencies = learned
        self._location, self._maps = location, maps
        self._log_evidence += math.log(total) + log_scale
        self._t += 1
        self._belief = Belief(self._t, location, maps, self._log_evidence)
        return self._belief
