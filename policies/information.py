"""What a plan of :mod:`policies.info_gain` measures, and the generic way to measure it: the
uncertainty of a belief and its expectation after a sequence of actions, by forks of the live
estimator (DESIGN.md section 7).

    U(belief) = location_weight * H(L) + sum_i H(m_i)            (nats)

``H(L)`` is the entropy of the location marginal, ``H(m_i)`` that of cell i's label marginal.
The expectation is over the observations the robot would make: worlds (a location and a map)
drawn from the current belief (:func:`sample_states`), the actions simulated in each, the
simulated observations stepped through :func:`onlinemap.estimators.fork` of the estimator (the
live estimator is never touched). With ``hypotheses=None`` the expectation is exact: every
observation sequence is enumerated with its predictive probability (the ratio of the fork's
evidence before and after), Z^H forks for the Z observations of :func:`observations` (K, or up
to about 2^F K^F for a footprint of F offsets): for tiny worlds and tests. A particle filter's
plans take the numba rollouts of :mod:`policies.rollouts` instead.
"""

from __future__ import annotations

import itertools
import math

import numpy as np

from onlinemap.belief import Belief
from onlinemap.errors import ImpossibleObservationError, ModelError
from onlinemap.estimators import Estimator, fork
from onlinemap.estimators.base import SamplesStates, draw_labels
from onlinemap.model import GridModel
from onlinemap.rng import SeedLike, as_generator
from onlinemap.simulate import world_step


def entropy(p: np.ndarray) -> np.ndarray:
    """Entropy in nats over the last axis. (..., K) -> (...)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(p > 0, -p * np.log(p), 0.0).sum(axis=-1)


def uncertainty(belief: Belief, location_weight: float = 1.0) -> float:
    """``U = location_weight * H(L) + sum_i H(m_i)`` in nats, from the belief's marginals. O(N K)."""
    return float(location_weight * entropy(belief.location) + entropy(belief.map).sum())


def information_reward(belief: Belief, sensor: np.ndarray) -> np.ndarray:
    """(N,) ``R(i) = H(m_i) - sum_z P(z | i) H(m_i | z)``: the expected entropy drop of cell i's
    marginal from one observation of it (the mutual information of ``m_i`` and ``z``), with
    ``P(z | i) = sum_k m_i[k] O[k, z]``. O(N K^2)."""
    joint = belief.map[:, :, None] * sensor[None]  # (N, K, Z) P(m_i = k, z)
    p_z = joint.sum(axis=1)  # (N, Z)
    with np.errstate(divide="ignore", invalid="ignore"):
        posterior = np.where(p_z[:, None, :] > 0, joint / p_z[:, None, :], 0.0)
    after = (p_z * entropy(np.moveaxis(posterior, 1, 2))).sum(axis=1)
    return np.maximum(entropy(belief.map) - after, 0.0)


def unit_information(sensor: np.ndarray, frequencies: np.ndarray | None = None) -> float:
    """``I0``: what one observation teaches, in nats, about a cell whose label marginal is
    ``frequencies`` (K,) (None: uniform over the K labels), :func:`information_reward` of that
    one cell: ``I(m; z) = H(frequencies) - sum_z P(z) H(m | z)``. O(K^2)."""
    k = sensor.shape[0]
    row = np.full(k, 1.0 / k) if frequencies is None else np.asarray(frequencies, dtype=np.float64)
    return float(information_reward(Belief(0, np.ones(1), row[None]), sensor)[0])


def _checked_actions(model: GridModel, actions) -> np.ndarray:
    actions = np.asarray(actions, dtype=np.int64).ravel()
    if np.any(actions < 0) or np.any(actions >= model.n_actions):
        raise ModelError(f"actions must be in 0..{model.n_actions - 1}, got {actions.tolist()}")
    return actions



def sample_states(estimator: Estimator, size: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """``size`` hypothetical worlds drawn from the estimator's belief: locations (S,) and label maps
    (S, N). An estimator that draws whole states (:class:`~onlinemap.estimators.base.SamplesStates`:
    ``exact`` from its joint, ``rbpf`` a particle and then its map) draws them; any other from the
    product of its marginals (which is its belief for ``bk`` and ``dead_reckoning``): O(S N K)."""
    if isinstance(estimator, SamplesStates):
        return estimator.sample_states(size, rng)
    model = estimator.model
    n, k = model.n_cells, model.n_labels
    belief = estimator.belief
    locations = rng.choice(n, size=size, p=belief.location / belief.location.sum())
    return locations.astype(np.int64), draw_labels(np.broadcast_to(belief.map, (size, n, k)), rng)


def expected_uncertainty(estimator: Estimator, actions, *, hypotheses: int | None = None,
                         seed: SeedLike = None, location_weight: float = 1.0) -> np.ndarray:
    """(H + 1,) the expected :func:`uncertainty` after each prefix of ``actions`` (H,), entry 0 now.

    ``hypotheses=None``: exact expectation over every observation sequence (Z^H forks of the
    estimator for the Z :func:`observations`, each outcome weighted by its predictive probability ``exp(log_evidence after -
    log_evidence before)``). An integer S: the mean over S worlds drawn by :func:`sample_states`
    and simulated with :func:`onlinemap.simulate.world_step` (S forks, S H steps). A world whose
    simulated readings the fork cannot explain (an approximate belief, e.g. a particle filter that
    lost the world's trajectory, gives them probability zero) is left out of the mean: by the
    fork's own belief it has probability zero. If every world is left out the expectation is
    ``U(now)`` at every length (nothing to be learnt that the fork can hold). Planning never
    raises for it: the live filter is not at fault.
    The estimator itself (state and random generator) is left exactly as it was.
    """
    if estimator.belief is None:
        raise ModelError("the estimator has no belief yet: step it with the first observation first")
    model = estimator.model
    actions = _checked_actions(model, actions)
    out = np.zeros(len(actions) + 1)
    out[0] = uncertainty(estimator.belief, location_weight)
    if hypotheses is None:
        _enumerate(estimator, actions, 0, 1.0, out, location_weight)
        return out
    rng = as_generator(seed)
    locations, maps = sample_states(estimator, int(hypotheses), rng)
    total, explained = np.zeros(len(actions)), 0
    row = np.empty(len(actions))
    for location, labels in zip(locations, maps):
        copy = fork(estimator)
        try:
            for h, a in enumerate(actions):
                location, labels, z = world_step(model, int(location), labels, int(a), rng)
                row[h] = uncertainty(copy.step(int(a), z), location_weight)
        except ImpossibleObservationError:  # the fork cannot explain this world: probability zero to it
            continue
        total += row
        explained += 1
    out[1:] = total / explained if explained else out[0]
    return out


def observations(model: GridModel) -> list:
    """Every observation the sensor can return: a label (the robot's own cell), or (F,) readings
    with -1 exactly at the offsets that leave the grid from some location (one of
    ``model.off_grid_patterns``) and a label at every other offset. O(their number,
    :func:`observation_count`)."""
    out = []
    for off in model.off_grid_patterns:
        for labels in itertools.product(range(model.n_labels), repeat=int((~off).sum())):
            z = np.full(model.n_readings, -1, dtype=np.int64)
            z[~off] = labels
            out.append(z)
    return [int(z[0]) for z in out] if model.observation_shape == () else out


def observation_count(model: GridModel) -> int:
    """``len(observations(model))`` without building them: ``sum over patterns K^(on-grid
    offsets)``. O(N F)."""
    return sum(model.n_labels ** int((~off).sum()) for off in model.off_grid_patterns)


def _enumerate(node: Estimator, actions: np.ndarray, depth: int, probability: float, out: np.ndarray,
               location_weight: float) -> None:
    if depth == len(actions) or probability == 0.0:
        return
    before = node.belief.log_evidence
    model = node.model
    for z in observations(model):
        child = fork(node)
        if hasattr(child, "recover_from_depletion"):  # an RBPF: an outcome its particles rule out has
            child.recover_from_depletion = False  # probability zero here, not a relocation
        try:
            belief = child.step(int(actions[depth]), z)
        except ImpossibleObservationError:
            continue
        p = probability * math.exp(belief.log_evidence - before)
        out[depth + 1] += p * uncertainty(belief, location_weight)
        _enumerate(child, actions, depth + 1, p, out, location_weight)


def expected_information_gain(estimator: Estimator, actions, *, hypotheses: int | None = None,
                              seed: SeedLike = None, location_weight: float = 1.0) -> float:
    """``U(now) - E[U(after actions)]`` (nats), by :func:`expected_uncertainty`."""
    u = expected_uncertainty(estimator, actions, hypotheses=hypotheses, seed=seed,
                             location_weight=location_weight)
    return float(u[0] - u[-1])
