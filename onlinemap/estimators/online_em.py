"""Fixed-lag online EM (DESIGN.md section 3, ``online_em``; Murphy 1999's online EM).

The map is a parameter, the observation matrix ``B[i, k] = P(Z = k | L = i)``; only the
location is hidden. At step t, with the window ``s..t`` of the last W steps
(``s = max(0, t - W + 1)``):

1. E-step: forward-backward over the window under ``B_{t-1}``, started from the filtered
   location at ``s - 1`` (as computed at that step) moved by ``a_s`` (the known start cell
   when ``s = 0``);
2. ``E_t[i, k] = sum_{tau = s..t} P(L_tau = i | z_s..t) [z_tau = k]``;
3. ``S_t = decay * S_{t-1} + E_t``;
4. M-step: ``B_t[i] = (S_t[i] + c) / (sum_k S_t[i, k] + K c)`` with ``c = pseudo_count``
   (rows with no statistics yet keep the prior's ``label_prior @ O``).

Before any data ``B`` is ``label_prior @ O``. The belief: ``location`` = the window's filtered
``P(L_t | z_s..t)`` under ``B_{t-1}``; ``map`` = ``B_t`` read through the inverted sensor
channel (clipped, renormalised); ``observation_matrix`` = ``B_t``; ``log_evidence`` = the
prequential log-likelihood ``sum_u log P(z_u | z_s(u)..u-1)``, each term under the parameters
of its time ``B_{u-1}`` (a sequential score, not the likelihood of one fixed B).

A sensor footprint makes B per cell (the probability of each reading of that cell) and the
emission a product over the F footprint cells; blocking labels move the E-step into cell j with
``p_move P(m_j passable)`` under the map read off ``B_{t-1}`` (``onlinemap.hmm``).

Cost per step: O(W (N F + E) + N K^2) time (E motion edges, sparse), O(W N) memory; with
``window="max"`` W = t + 1, so a run of T steps costs O(T^2 N F) in all.
"""

from __future__ import annotations

import numpy as np

from .. import state_checks as checks
from ..belief import Belief
from .. import arguments
from ..errors import InvalidOptionError
from ..hmm import (append_observation, emission_from_counts, expected_cell_counts, forward_backward,
                   map_from_emission, map_passability, prior_emission, sensor_inverse)
from ..model import GridModel, apply_motion
from ..validation import check_step
from .base import MAP_IS_A_PARAMETER, register


def check_pseudo_count(pseudo_count: float) -> float:
    """A finite pseudo-count >= 0, or InvalidOptionError."""
    return arguments.real("pseudo_count", pseudo_count, low=0.0, high=float("inf"), high_open=True,
                          error=InvalidOptionError)


def _check_window(window) -> int | None:
    if isinstance(window, str):
        if window != "max":
            raise InvalidOptionError(f"window must be a positive int or 'max', got {window!r}")
        return None
    return arguments.integer("window (a positive int or 'max')", window, minimum=1, error=InvalidOptionError)


@register("online_em")
class OnlineEM:
    """Fixed-lag online EM. Options: ``window`` (int >= 1, default 16, so a step costs the same
    forever; ``"max"`` for the whole history, O(t) per step), ``decay`` (lambda in (0, 1]: weight of the previous statistics), ``pseudo_count`` (c >= 0
    added to every count of the M-step)."""

    #: why the label-prior options mean nothing here (:func:`~onlinemap.estimators.base.make_estimator` says it)
    label_prior_refusal = MAP_IS_A_PARAMETER

    #: attributes fixed by the model and options, checked equal on load (:mod:`onlinemap.state_checks`)
    CONSTANT_STATE = ("window", "_window", "decay", "pseudo_count", "_prior_emission", "_sensor_inverse")

    def __init__(self, model: GridModel, *, window: int | str = 16, decay: float = 1.0,
                 pseudo_count: float = 0.1):
        self.model = model
        self.window = window
        self._window = _check_window(window)
        self.decay = arguments.real("decay", decay, low=0.0, high=1.0, low_open=True, error=InvalidOptionError)
        self.pseudo_count = check_pseudo_count(pseudo_count)
        self._prior_emission = prior_emission(model)
        self._sensor_inverse = sensor_inverse(model.sensor)
        self._emission = self._prior_emission.copy()
        self._stats = np.zeros((model.n_cells, model.n_labels))
        self._actions = np.empty(0, dtype=np.int64)  # a_u for the window's steps (and one before)
        self._observations = np.empty((0,) + model.observation_shape,
                                      dtype=np.int64)  # z_s..z_t, (W,) or (W, F)
        self._filtered = np.empty((0, model.n_cells))  # filtered location of step u in row u % W (finite W)
        self._log_evidence = 0.0
        self._t = -1
        self._belief: Belief | None = None

    @staticmethod
    def check_state(state) -> None:
        """The invariants of a restored state (:mod:`onlinemap.state_checks`): the window's
        record of actions and observations, its filtered locations, the emission table and the
        sufficient statistics (N, K); the belief of step ``_t``."""
        model = state.model
        n, k = model.n_cells, model.n_labels
        t = checks.step_index(state)
        window = state._window
        kept = t + 1 if window is None else min(t + 1, window)
        checks.run_record(state, kept)
        filtered = checks.array(state, "_filtered", (0 if window is None else kept, n), np.float64, written=True)
        checks.probabilities("_filtered", filtered)
        checks.probabilities("_emission", checks.array(state, "_emission", (n, k), np.float64))
        stats = checks.array(state, "_stats", (n, k), np.float64)
        if not np.all(np.isfinite(stats)) or np.any(stats < 0):
            checks.fail("_stats", "must be finite and non-negative")
        checks.log_evidence(state)
        checks.belief(state, required=True)

    def step(self, action, observation) -> Belief:
        a, z = check_step(self.model, self._t + 1, action, observation)
        model, t, w = self.model, self._t + 1, self._window
        observations = append_observation(self._observations, z)
        actions = self._actions if a is None else np.append(self._actions, a)
        passable = map_passability(model, self._emission, self._sensor_inverse)
        if w is not None and t + 1 > w:  # the window s..t starts after step 0
            observations, actions = observations[-w:], actions[-w:]
            prior = apply_motion(model, self._filtered[t % w], actions[0], passable)  # filtered at s - 1 = t - W
            inside = actions[1:]
        else:
            prior, inside = model.location_prior(), actions
        fit = forward_backward(model, prior, inside, observations, self._emission,
                               first_step=t + 1 - len(observations), passable=passable)
        stats = self.decay * self._stats + expected_cell_counts(model, fit.posterior, observations)
        emission = emission_from_counts(stats, self.pseudo_count, self._prior_emission)
        location = fit.filtered[-1]
        log_evidence = self._log_evidence + float(fit.log_normalizers[-1])
        belief = Belief(t, location, map_from_emission(emission, self._sensor_inverse), log_evidence,
                        observation_matrix=emission)
        # commit (everything above worked on fresh arrays)
        self._observations, self._actions = observations, actions
        if w is not None:  # the window's prior needs the filtered location W steps back
            if len(self._filtered) < w:  # grows to W rows: row = step while t < W
                self._filtered = np.concatenate([self._filtered, location[None]])
            else:  # then a ring: step u in row u % W
                self._filtered[t % w] = location
        self._stats, self._emission = stats, emission
        self._log_evidence, self._t, self._belief = log_evidence, t, belief
        return self._belief
