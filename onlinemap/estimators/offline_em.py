"""Offline EM: Baum-Welch over a whole run (DESIGN.md section 3, ``offline_em``).

Same HMM as online EM (hidden location, known sparse motion, observation matrix ``B`` as the
parameter), but every iteration runs forward-backward over all T steps from the start cell:

- E-step: ``gamma_t = P(L_t | z_0..T-1; B)``; with annealing, ``gamma_t^(1/tau)`` renormalised
  (deterministic annealing, the softmax M-step of the layered-EM paper), ``tau_j =
  max(tau_min, tau0 * rate^j)`` at iteration j, so tau shrinks from tau0 towards tau_min;
- M-step: ``B[i] = (sum_t gamma_t(i) [z_t = .] + c) / (sum_t gamma_t(i) + K c)``.

Without annealing this is EM for the MAP of B under a Dirichlet(c + 1) prior per row, so the
objective ``log P(z | B) + c sum log B`` never decreases. Iterations stop when it rises by
less than ``tol`` (and tau has reached tau_min) or after ``n_iter`` (at most
:data:`MAX_ITERATIONS`). EM starts from
``B0 = label_prior @ O``. Cost: O(T (N F + E) + N K^2) per iteration, O(T N) memory.

With a sensor footprint of F offsets B is per cell and the M-step counts every reading of each
cell (the textbook's grid EM); with blocking labels the E-step uses the passability of the map
read off the current B (a generalised EM step: the objective may then fall; see ``onlinemap.hmm``).
"""

from __future__ import annotations

import warnings
from typing import NamedTuple

import numpy as np

from .. import state_checks as checks
from ..arrays import read_only
from ..belief import Belief
from .. import arguments
from ..errors import InvalidOptionError, ModelError, PerformanceWarning
from ..hmm import (append_observation, emission_from_counts, expected_cell_counts, forward_backward,
                   log_dirichlet_prior, map_from_emission, map_passability, prior_emission, sensor_inverse,
                   temper)
from ..model import GridModel
from ..validation import check_sequence, check_step
from .base import MAP_IS_A_PARAMETER, register
from .online_em import check_pseudo_count


class Anneal(NamedTuple):
    """Deterministic annealing schedule: ``tau_j = max(tau_min, tau0 * rate**j)``."""

    tau0: float
    rate: float
    tau_min: float

    def tau(self, iteration: int) -> float:
        return max(self.tau_min, self.tau0 * self.rate**iteration)


def check_anneal(anneal) -> Anneal | None:
    """None, or a valid ``(tau0, rate, tau_min)`` with tau0 >= tau_min > 0 and rate in (0, 1]."""
    if anneal is None:
        return None
    if isinstance(anneal, (str, bytes)) or not isinstance(anneal, (tuple, list, np.ndarray)) or len(anneal) != 3:
        raise InvalidOptionError(f"anneal must be None or (tau0, rate, tau_min), got {anneal!r}")
    schedule = Anneal(*(arguments.real(f"anneal[{i}]", x, error=InvalidOptionError) for i, x in enumerate(anneal)))
    if not (np.isfinite(schedule).all() and schedule.tau0 >= schedule.tau_min > 0 and 0 < schedule.rate <= 1):
        raise InvalidOptionError(f"anneal (tau0, rate, tau_min) needs tau0 >= tau_min > 0 and 0 < rate <= 1, got {anneal!r}")
    return schedule


MAX_ITERATIONS = 10**4  # EM that has not converged in 10,000 iterations will not (the default is 200)


def check_n_iter(n_iter) -> int:
    """An iteration count in 1..:data:`MAX_ITERATIONS`, or InvalidOptionError (with ``tol=0`` EM
    runs every one of them: an unbounded count never returned)."""
    return arguments.integer("n_iter", n_iter, minimum=1, maximum=MAX_ITERATIONS, error=InvalidOptionError)


def check_tol(tol) -> float:
    """A finite tolerance >= 0 (NaN or a negative tol would never stop EM early), or InvalidOptionError."""
    return arguments.real("tol", tol, low=0.0, high=float("inf"), high_open=True, error=InvalidOptionError)


class EMFit(NamedTuple):
    """The result of Baum-Welch on a run of T steps."""

    location: np.ndarray  # (T, N) smoothed P(L_t | z_0..T-1; B) under the final B
    map: np.ndarray  # (N, K) B read through the inverted sensor channel
    observation_matrix: np.ndarray  # (N, K) the final B
    log_likelihood: float  # log P(z_0..T-1 | a; B) under the final B
    objectives: np.ndarray  # (iterations,) log likelihood + c sum log B of each iteration's input B
    converged: bool


def baum_welch(model: GridModel, actions, observations, *, n_iter: int = 200, tol: float = 1e-8,
               pseudo_count: float = 0.1, anneal=None, initial: np.ndarray | None = None) -> EMFit:
    """Fit B to a recorded run (actions (T - 1,), observations (T,), by index or name).

    ``initial`` (N, K) overrides the starting B. Each iteration is one E-step and one M-step;
    after the last, one more E-step gives the returned location posteriors and likelihood.
    Raises ImpossibleObservationError if an observation has probability zero under some B.
    Cost O(iterations T (N + E)).
    """
    a_seq, z_seq = check_sequence(model, actions, observations)
    fallback = prior_emission(model)
    emission = fallback if initial is None else np.array(initial, dtype=np.float64)
    if emission.shape != fallback.shape:
        raise ModelError(f"initial B must have shape {fallback.shape}, got {emission.shape}")
    return _baum_welch(model, a_seq, z_seq, emission, fallback, model.location_prior(),
                       sensor_inverse(model.sensor), n_iter=check_n_iter(n_iter), tol=check_tol(tol),
                       pseudo_count=check_pseudo_count(pseudo_count), schedule=check_anneal(anneal))


def _baum_welch(model: GridModel, a_seq: np.ndarray, z_seq: np.ndarray, emission: np.ndarray,
                fallback: np.ndarray, prior: np.ndarray, inverse: np.ndarray, *, n_iter: int, tol: float,
                pseudo_count: float, schedule: Anneal | None) -> EMFit:
    """:func:`baum_welch` on checked int64 arrays and options, with the starting B ``emission``
    (not modified), the M-step's ``fallback`` rows, the location ``prior`` and the sensor's
    pseudo-inverse ``inverse`` given."""
    objectives = []
    converged = False
    fit = None
    for iteration in range(n_iter):
        fit = forward_backward(model, prior, a_seq, z_seq, emission, out=fit,
                               passable=map_passability(model, emission, inverse))
        objectives.append(fit.log_likelihood + log_dirichlet_prior(emission, pseudo_count))
        tau = 1.0 if schedule is None else schedule.tau(iteration)
        if iteration > 0 and tau == (1.0 if schedule is None else schedule.tau_min) \
                and abs(objectives[-1] - objectives[-2]) < tol:
            converged = True
            break
        counts = expected_cell_counts(model, temper(fit.posterior, tau), z_seq)
        emission = emission_from_counts(counts, pseudo_count, emission)
    else:
        fit = forward_backward(model, prior, a_seq, z_seq, emission, out=fit,
                               passable=map_passability(model, emission, inverse))
    return EMFit(fit.posterior, map_from_emission(emission, inverse), emission, fit.log_likelihood,
                 np.array(objectives), converged)


@register("offline_em")
class OfflineEM:
    """Baum-Welch on all data so far. Options: ``n_iter`` (most iterations), ``tol`` (stop when
    the objective rises by less), ``pseudo_count`` (c >= 0), ``anneal`` (None or
    ``(tau0, rate, tau_min)``).

    ``step`` re-fits from scratch on z_0..z_t (a cold start, so the belief at t is exactly what
    :meth:`fit` gives on that prefix): O(iterations t (N + E)) per step, O(T^2) over a run. Its
    first step warns so (:class:`~onlinemap.errors.PerformanceWarning`): a recorded run is
    fitted once by :meth:`fit`.
    Belief: ``location`` = P(L_t | z_0..t; B_t) (smoothing and filtering agree at the last
    step), ``map`` = B_t through the inverted sensor channel, ``observation_matrix`` = B_t,
    ``log_evidence`` = log P(z_0..t | a; B_t), the likelihood of the fitted B.
    """

    #: why the label-prior options mean nothing here (:func:`~onlinemap.estimators.base.make_estimator` says it)
    label_prior_refusal = MAP_IS_A_PARAMETER

    #: attributes fixed by the model and options, checked equal on load (:mod:`onlinemap.state_checks`)
    CONSTANT_STATE = ("n_iter", "tol", "pseudo_count", "anneal", "_prior_emission", "_location_prior",
                      "_sensor_inverse")

    def __init__(self, model: GridModel, *, n_iter: int = 200, tol: float = 1e-8, pseudo_count: float = 0.1,
                 anneal: tuple[float, float, float] | None = None):
        self.model = model
        self.n_iter = check_n_iter(n_iter)
        self.tol = check_tol(tol)
        self.pseudo_count = check_pseudo_count(pseudo_count)
        schedule = check_anneal(anneal)
        self.anneal = None if schedule is None else tuple(schedule)  # plain data (checkpoints)
        # constant tables of every step's fit, computed once (read-only arrays: checkpointable)
        self._prior_emission = read_only(prior_emission(model))
        self._location_prior = read_only(model.location_prior())
        self._sensor_inverse = sensor_inverse(model.sensor)
        self._actions = np.empty(0, dtype=np.int64)
        self._observations = np.empty((0,) + model.observation_shape,
                                      dtype=np.int64)
        self._t = -1
        self._belief: Belief | None = None

    @staticmethod
    def check_state(state) -> None:
        """The invariants of a restored state (:mod:`onlinemap.state_checks`): the record of
        every action and observation so far; the belief of step ``_t``."""
        checks.run_record(state, checks.step_index(state) + 1)
        checks.belief(state, required=True)

    def fit(self, actions, observations) -> EMFit:
        """Batch use: Baum-Welch on a whole run with this estimator's options (state untouched)."""
        return baum_welch(self.model, actions, observations, n_iter=self.n_iter, tol=self.tol,
                          pseudo_count=self.pseudo_count, anneal=self.anneal)

    def step(self, action, observation) -> Belief:
        a, z = check_step(self.model, self._t + 1, action, observation)
        actions = self._actions if a is None else np.append(self._actions, a)
        observations = append_observation(self._observations, z)
        fit = _baum_welch(self.model, actions, observations, self._prior_emission, self._prior_emission,
                          self._location_prior, self._sensor_inverse, n_iter=self.n_iter, tol=self.tol,
                          pseudo_count=self.pseudo_count,
                          schedule=None if self.anneal is None else Anneal(*self.anneal))
        if a is None:  # the first step (taken): once per estimator
            warnings.warn("offline_em re-fits Baum-Welch on all the data so far at every step (O(t) per step, "
                          "O(T^2) over a run); for a recorded run, est.fit(actions, observations) fits once",
                          PerformanceWarning, stacklevel=2)
        self._actions, self._observations = actions, observations
        self._t += 1
        self._belief = Belief(self._t, fit.location[-1], fit.map, fit.log_likelihood,
                              observation_matrix=fit.observation_matrix)
        return self._belief
