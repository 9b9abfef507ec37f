"""Information-gain exploration (Stachniss, Grisetti and Burgard 2005; DESIGN.md section 7).

The paper's planner (:class:`~policies.planners.EntropyExplorer`) acts by the Q-MDP rule, which
assumes the location uncertainty vanishes after one step: it cannot value an action whose payoff
is knowing where the robot is. This planner scores *macro-actions* by what they are expected to
teach the filter about the location and the map, measured on the filter itself:

    utility(m) = U(now) - E[ U(after m) ] - step_cost * I0 * len(m),
    U(belief)  = location_weight * I0 * H(L) + sum_i H(m_i)            (nats)

``H(L)`` is the entropy of the location marginal, ``H(m_i)`` that of cell i's label marginal;
``I0`` is what one observation teaches about a cell whose label is uniformly unknown
(:func:`information_reward`: 0.95 nats in the door world at ``p_obs`` 0.9, 0.19 in a binary
world at ``p_obs`` 0.8), so ``step_cost`` and ``location_weight`` mean the same in
every world (a nat of location is worth ``location_weight`` observations of an unknown cell).
The expectation is over the observations the robot would make: a hypothetical world (a location
and a map) is drawn from the current belief, the macro-action is rolled out in it (slips, map
changes, sensor noise), the simulated observations go through a copy of the filter, and the
copy's uncertainty is measured. The same hypotheses and random numbers serve every candidate
(common random numbers), so the candidates are compared on the same futures.

Candidates (each scored at several lengths, the prefixes of one rollout):

- *press d*: press one direction ``k`` times, ``k`` in ``press_lengths`` (default 1, 2, 4, 8 and
  enough presses to cross the grid with slips). Pressing against the grid's edge is what lets a
  lost robot relocalise; pressing into the unknown is how a localised one maps.
- *plan*: a walk from the most probable location on the ``Q`` of the policy-iteration plan
  (:func:`~policies.mdp.policy_iteration`) for the per-cell information reward
  ``R(i) = H(m_i) - E_z H(m_i | z)`` (what one observation of cell i would teach a localised
  robot); see :func:`greedy_path`.

The chosen macro-action is executed for at most ``commit`` steps, then the planner re-plans.
With frontier targets (``targets``, outside the paper's world), candidates also move towards the
best frontier targets (not the cell the robot most probably stands on), and when no macro-action
pays its cost (every utility <= 0: what is left to learn lies beyond the horizon) the next
``commit`` presses are the frontier baseline's (:class:`~policies.frontier.FrontierExplorer`).
A macro-action whose first press most probably meets a wall is never chosen.

*Re-anchoring.* An expected-entropy score trusts the belief: once every particle agrees on a
wrong trajectory (P particles cannot hold the 2^T trajectories a slipping robot may have taken),
it sees nothing to learn about the location. So every ``anchor_every`` steps the planner checks
the belief against the grid itself: it presses into the corner nearest the expected location
(``press_lengths[-1]`` presses along each axis, enough to cross the grid with slips), which puts
the true robot in a known cell whatever the particles believed. Measured on the paper's world
(20 seeds, 1000 particles, 1000 steps; ``policies.studies``): anchoring every 60 steps takes the
mean location error from 0.70 to 0.50 at the same map error (0.25); every 40 steps, 0.39 but map
error 0.35; every 30, 0.27 but the robot does little else (map error 0.64).

Backends (who plays "a copy of the filter"):

- ``rbpf``: a thinned copy of the particle belief (``rollout_particles`` particles drawn by
  weight, or all of them), rolled out by a numba kernel without copying any map:
  :func:`policies.kernels.planning.rollout_uncertainty` for the paper's sensor and motion,
  :func:`policies.kernels.planning.plan_rollouts` for any footprint and blocking labels (the
  RBPF's update with its optimal proposal; it equals the exact forks on exact particle beliefs
  and Bayes' rule in expectation, ``tests/test_info_gain.py``). Cost per plan:
  O(P N K^2) to read the particles' maps, plus for each of ``hypotheses`` S worlds and each of
  the 2 A candidate rollouts of up to H steps, O(H R (H + K^2)) for the steps and O(R N K) per
  scored length, plus one warm-started policy iteration over N cells. Measured (``onlinemap
  bench planning``, P = 1000, R = 64, S = 12): 10 x 10, about 20 ms per plan, 2.7 ms per
  decision; 32 x 32, about 96 ms per plan, 13 ms per decision; with blocking and a cross
  footprint, 10 x 10: 33 ms per plan, 10.6 ms per decision.
- any other estimator: :func:`onlinemap.estimators.fork` (the live estimator is never touched)
  stepped with simulated observations; with ``hypotheses=None`` the expectation is exact: every
  observation sequence is enumerated with its predictive probability (the ratio of the fork's
  evidence before and after), Z^H forks for the Z observations of :func:`observations`
  (K, or up to about 2^F K^F for a footprint of F offsets): for tiny worlds and tests.
"""

from __future__ import annotations

import itertools
import math
from typing import NamedTuple

import numpy as np

from onlinemap import arguments
from onlinemap.belief import Belief
from onlinemap.errors import ImpossibleObservationError, InvalidOptionError, ModelError
from onlinemap.estimators import Estimator, fork
from onlinemap.estimators.base import HoldsParticles, ParticleSnapshot, SamplesStates, draw_labels
from .kernels.planning import plan_rollouts, rollout_uncertainty
from onlinemap.model import GridModel, change_powers
from onlinemap.rng import SeedLike, as_generator
from onlinemap.simulate import world_step

from .frontier import FrontierExplorer, FrontierPlan
from .mdp import PolicyIterationResult, policy_iteration
from .passability import (PressMemory, distances_to, expected_passability, move_chances, steps_after_press,
                          unblocked_actions)


def _entropy(p: np.ndarray) -> np.ndarray:
    """Entropy in nats over the last axis. (..., K) -> (...)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(p > 0, -p * np.log(p), 0.0).sum(axis=-1)


def uncertainty(belief: Belief, location_weight: float = 1.0) -> float:
    """``U = location_weight * H(L) + sum_i H(m_i)`` in nats, from the belief's marginals. O(N K)."""
    return float(location_weight * _entropy(belief.location) + _entropy(belief.map).sum())


def information_reward(belief: Belief, sensor: np.ndarray) -> np.ndarray:
    """(N,) ``R(i) = H(m_i) - sum_z P(z | i) H(m_i | z)``: the expected entropy drop of cell i's
    marginal from one observation of it (the mutual information of ``m_i`` and ``z``), with
    ``P(z | i) = sum_k m_i[k] O[k, z]``. O(N K^2)."""
    joint = belief.map[:, :, None] * sensor[None]  # (N, K, Z) P(m_i = k, z)
    p_z = joint.sum(axis=1)  # (N, Z)
    with np.errstate(divide="ignore", invalid="ignore"):
        posterior = np.where(p_z[:, None, :] > 0, joint / p_z[:, None, :], 0.0)
    after = (p_z * _entropy(np.moveaxis(posterior, 1, 2))).sum(axis=1)
    return np.maximum(_entropy(belief.map) - after, 0.0)


def _checked_actions(model: GridModel, actions) -> np.ndarray:
    actions = np.asarray(actions, dtype=np.int64).ravel()
    if np.any(actions < 0) or np.any(actions >= model.n_actions):
        raise ModelError(f"actions must be in 0..{model.n_actions - 1}, got {actions.tolist()}")
    return actions


# --- the generic backend: forks of the live estimator -------------------------------------------
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


# --- the particle backend: thinned particle beliefs, rolled out in numba -----------------------
class RolloutTables(NamedTuple):
    """The model's tables as the kernel takes them, for horizons up to H."""

    sensor_cdf: np.ndarray  # (K, K)
    change_cdf: np.ndarray  # (K, K)
    powers: np.ndarray  # (H + 1, K, K) C^d


def rollout_tables(model: GridModel, horizon: int) -> RolloutTables:
    """Cumulative sensor and change rows and the powers of C up to ``horizon``. O(H K^3)."""
    return RolloutTables(np.cumsum(model.sensor, axis=1), np.cumsum(model.change, axis=1),
                         change_powers(model.change, horizon + 1).copy())  # writable: the kernels' one signature


def particle_expected_uncertainty(model: GridModel, particles: ParticleSnapshot, sequences: np.ndarray,
                                  checkpoints: np.ndarray, worlds: tuple[np.ndarray, np.ndarray],
                                  rng: np.random.Generator, location_weight: float = 1.0,
                                  tables: RolloutTables | None = None) -> np.ndarray:
    """(C, H + 1) expected uncertainty of each action sequence ``sequences`` (C, H) after each
    prefix length h with ``checkpoints[h]`` (other entries 0), averaged over the worlds
    ``(locations (S,), labels (S, N))``; every sequence sees the same worlds and random numbers.
    Cost O(S C (H R (H + K^2) + n_checkpoints R N K)), the uncertainty now (O(R N K)) once."""
    n_seq, horizon = sequences.shape
    tables = rollout_tables(model, horizon) if tables is None else tables
    dynamic = not model.is_static
    checkpoints = np.asarray(checkpoints, dtype=np.bool_)
    total = np.zeros((n_seq, horizon + 1))
    out = np.zeros(horizon + 1)
    r_count = len(particles.locations)
    arrays = (particles.locations, particles.maps, particles.log_weights, model.moves, model.p_move, model.likelihood,
              tables.sensor_cdf, tables.change_cdf, tables.powers, dynamic)
    now = 0.0  # the uncertainty now, the same in every world: one rollout of no step
    if checkpoints[0]:
        rollout_uncertainty(*arrays, sequences[0, :0], int(worlds[0][0]), worlds[1][0], np.empty((0, 2)),
                            np.empty((0, model.n_cells if dynamic else 0)), np.empty((0, r_count)),
                            float(location_weight), checkpoints[:1], out)
        now = out[0]
    later = np.concatenate([[False], checkpoints[1:]])  # the rollouts score the steps after now
    for location, labels in zip(*worlds):
        world_u = rng.random((horizon, 2))
        change_u = rng.random((horizon, model.n_cells if dynamic else 0))
        proposal_u = rng.random((horizon, r_count))
        for c in range(n_seq):
            out[:] = 0.0
            out[0] = now
            rollout_uncertainty(*arrays, sequences[c], int(location), labels, world_u, change_u, proposal_u,
                                float(location_weight), later, out)
            total[c] += out
    return total / len(worlds[0])


def agreement(model: GridModel, particles: ParticleSnapshot, horizon: int,
              tables: RolloutTables) -> tuple[np.ndarray, np.ndarray]:
    """The cells whose marginals differ between the particles (D,) sorted, and (H + 1,) the summed
    entropy at step h of the other cells' common marginal (brought forward by ``C^h``): the part
    of ``sum_i H(M_i)`` no reweighting changes. O(R N K + H N K^2) (O(R N K) in a static world)."""
    maps = particles.maps
    disputed = np.flatnonzero(np.any(maps != maps[:1], axis=(0, 2)))
    agree = np.ones(model.n_cells, dtype=bool)
    agree[disputed] = False
    common = maps[0, agree]
    if model.is_static:
        return disputed, np.full(horizon + 1, _entropy(common).sum())
    return disputed, np.array([_entropy(common @ tables.powers[h]).sum() for h in range(horizon + 1)])


def footprint_expected_uncertainty(model: GridModel, particles: ParticleSnapshot, sequences: np.ndarray,
                                   checkpoints: np.ndarray, worlds: tuple[np.ndarray, np.ndarray],
                                   rng: np.random.Generator, location_weight: float = 1.0,
                                   tables: RolloutTables | None = None, distances: np.ndarray | None = None,
                                   go: np.ndarray | None = None) -> np.ndarray:
    """(C, H + 1) :func:`particle_expected_uncertainty` for any sensor footprint and blocking
    labels (:func:`policies.kernels.planning.plan_rollouts`): ``sequences`` (C, H) actions, -1
    where the action is chosen in closed loop towards candidate c's target by ``distances`` (C, N)
    and ``go`` (N, A) (the chance each press moves). Every sequence sees the same worlds and random
    numbers. Cost O(S C (H R (F + 1) K^2 + n_checkpoints R (D + H F) K)), D the disputed cells."""
    sequences = np.ascontiguousarray(sequences, dtype=np.int64)
    n_seq, horizon = sequences.shape
    tables = rollout_tables(model, horizon) if tables is None else tables
    n_worlds, r_count = len(worlds[0]), len(particles.locations)
    world_u = rng.random((n_worlds, horizon, 1 + model.n_readings))
    change_u = rng.random((n_worlds, horizon, 0 if model.is_static else model.n_cells))
    proposal_u = rng.random((n_worlds, horizon, r_count))
    disputed, agree_entropy = agreement(model, particles, horizon, tables)
    if distances is None:
        distances = np.zeros((n_seq, model.n_cells))
        go = np.zeros((model.n_cells, model.n_actions))
    total = np.zeros((n_seq, horizon + 1))
    plan_rollouts(particles.locations, np.ascontiguousarray(particles.maps), particles.log_weights, model.moves,
                  model.p_move, model.blocking, model.footprint_cells, model.sensor, tables.sensor_cdf, model.change,
                  tables.change_cdf, tables.powers, not model.is_static, sequences, np.ascontiguousarray(distances),
                  np.ascontiguousarray(go, dtype=np.float64), worlds[0].astype(np.int64),
                  np.ascontiguousarray(worlds[1], dtype=np.int64), world_u, change_u, proposal_u,
                  float(location_weight), np.asarray(checkpoints, dtype=np.bool_), disputed, agree_entropy, total)
    return total / n_worlds


# --- the planner ------------------------------------------------------------------------------
MAX_PLAN_FORKS = 10**5  # an exact enumeration forking the estimator more often than this is refused


def rollout_operations(model: GridModel, hypotheses: int, candidates: int, horizon: int, lengths: int,
                       particles: int) -> int:
    """The estimated floating-point operations of one plan of the particle backend:
    ``S C (H R (F + 1) K^2 + L R N K)`` for S worlds, C candidates of H steps, L scored lengths,
    R particles, F footprint offsets (exact Python ints)."""
    k = model.n_labels
    return hypotheses * candidates * (horizon * particles * (model.n_readings + 1) * k * k
                                      + lengths * particles * model.n_cells * k)


def _lengths(value) -> np.ndarray:
    """``press_lengths``: a non-empty sequence of whole numbers >= 1, sorted and unique."""
    if isinstance(value, (str, bytes)) or not hasattr(value, "__iter__"):
        raise InvalidOptionError(f"press_lengths must be a sequence of whole numbers >= 1, got {value!r}")
    lengths = [arguments.integer(f"press_lengths[{i}]", v, minimum=1, error=InvalidOptionError)
               for i, v in enumerate(value)]
    if not lengths:
        raise InvalidOptionError("press_lengths must not be empty")
    return np.unique(np.asarray(lengths, dtype=np.int64))


def greedy_path(model: GridModel, q: np.ndarray, start: int, length: int) -> np.ndarray:
    """(length,) actions of a walk from ``start`` that takes, at each cell, the action of highest
    ``q`` (N, A) among those reaching a cell not yet on the walk (any moving action if none does).
    With a per-cell reward that is not used up, the policy-iteration policy may stay on a
    rewarding cell forever (press into a wall); the walk never stands still. O(length A)."""
    path = np.empty(length, dtype=np.int64)
    seen, cell = {start}, start
    for h in range(length):
        targets = model.neighbors[cell]
        moving = targets != cell
        fresh = moving & ~np.isin(targets, list(seen))
        allowed = fresh if fresh.any() else moving if moving.any() else np.ones_like(moving)
        path[h] = int(np.argmax(np.where(allowed, q[cell], -np.inf)))
        cell = int(targets[path[h]])
        seen.add(cell)
    return path


def anchor_actions(model: GridModel, belief: Belief, presses: int) -> np.ndarray:
    """(2 presses,) actions that press into the grid corner nearest the belief's expected location:
    ``presses`` times towards the nearer of the two column edges, then as many towards the nearer
    row edge. An action "goes towards" an edge when it moves every cell off that edge and keeps
    the edge's cells in place (found from ``model.neighbors``, so any 4-connected grid works).
    O(N A)."""
    rows, cols = np.divmod(np.arange(model.n_cells), model.cols)
    expected = (belief.location @ rows, belief.location @ cols)
    sequence = []
    for axis, coordinate, size in ((1, cols, model.cols), (0, rows, model.rows)):
        if size == 1:  # a corridor has no second axis to anchor
            continue
        edge = 0 if expected[axis] <= (size - 1) / 2 else size - 1
        on_edge = coordinate == edge
        towards = [a for a in range(model.n_actions)
                   if np.all(model.neighbors[on_edge, a] == np.flatnonzero(on_edge))
                   and np.all(np.abs(coordinate[model.neighbors[~on_edge, a]] - edge)
                              < np.abs(coordinate[~on_edge] - edge))]
        if not towards:
            raise ModelError("anchor_actions needs a grid whose actions move along its rows and columns")
        sequence += [towards[0]] * presses
    return np.asarray(sequence, dtype=np.int64)


class MacroScore(NamedTuple):
    """The scores of one plan. C candidate sequences, H their common length."""

    names: tuple[str, ...]  # (C,) e.g. "press east", "plan"
    sequences: np.ndarray  # (C, H) actions
    lengths: np.ndarray  # (L,) the prefix lengths scored
    gain: np.ndarray  # (C, L) expected uncertainty drop U(now) - E[U(after k steps)], nats
    utility: np.ndarray  # (C, L) gain - step_cost * I0 * k
    chosen: tuple[int, int]  # (candidate, length index) of the best utility
    targets: np.ndarray  # (C,) the target cell of a move towards one (sequence -1), -1 for fixed presses
    pays: bool = True  # some macro-action's utility is positive (else, with targets, the frontier leads)


class Candidates(NamedTuple):
    """The macro-actions of one plan. C candidates, H steps, N cells, A actions."""

    names: tuple[str, ...]  # (C,)
    sequences: np.ndarray  # (C, H) actions; -1: chosen in closed loop towards the target
    targets: np.ndarray  # (C,) target cells, -1 for fixed sequences
    distances: np.ndarray | None  # (C, N) expected steps to each candidate's target (None: no targets)
    go: np.ndarray | None  # (N, A) the chance each press moves (move_chances)


DEFAULT_TARGETS = 4  # frontier targets among the candidates, outside the paper's world
STEP_COST = 0.05  # step_cost "auto" in the paper's world (chosen on 8 seeds of it)
# step_cost "auto" with frontier targets: tuned on the blocking + cross door world, 1000 particles,
# 300 steps, mean steps to map error 0.1 over 8 seeds: seeds 0-7, 0.05 -> 142, 0.2 -> 131,
# 0.35 -> 117, 0.6 -> 112, 1.0 -> 133 (frontier 142); seeds 8-15, 0.45 -> 126, 0.6 -> 115,
# 0.75 -> 117 (frontier 131). Measured apart from these seeds, on seeds 20-39 (README).
TARGETS_STEP_COST = 0.6


def _finite(distance: np.ndarray, penalty: float) -> np.ndarray:
    """``distance`` with the unreachable (inf) at ``penalty``."""
    return np.where(np.isfinite(distance), distance, penalty)


def frontier_targets(model: GridModel, plan: FrontierPlan, count: int, spacing: int = 3,
                     skip: np.ndarray | None = None) -> np.ndarray:
    """Up to ``count`` target cells from a frontier plan: the highest ``plan.score`` first, each
    at least ``spacing`` cells (grid distance, rows plus columns) from those already taken, so
    the candidates go to different places; none where ``skip`` (N,) bool is set (the cell the
    robot most probably stands on: a move there is no move). O(N log N + count N)."""
    order = np.argsort(-plan.score, kind="stable")
    order = order[np.isfinite(plan.score[order])]
    if skip is not None:
        order = order[~skip[order]]
    chosen: list[int] = []
    places: list[tuple[int, int]] = []  # (row, col) of the chosen cells
    for cell in order:
        if len(chosen) == count:
            break
        row, col = divmod(int(cell), model.cols)
        if all(abs(row - r) + abs(col - c) >= spacing for r, c in places):
            chosen.append(int(cell))
            places.append((row, col))
    return np.asarray(chosen, dtype=np.int64)


def descent(model: GridModel, go: np.ndarray, distance: np.ndarray, start: int, length: int) -> np.ndarray:
    """(length,) the presses of a robot that never slips, from ``start``, each the one of least
    expected steps to the target after it (``steps_after_press`` with ``go`` (N, A) and
    ``distance`` (N,)), moving to the intended cell. O(length A)."""
    path = np.empty(length, dtype=np.int64)
    cell = start
    for h in range(length):
        cost = 1.0 + go[cell] * distance[model.neighbors[cell]] + (1.0 - go[cell]) * distance[cell]
        path[h] = int(np.argmin(cost))
        if go[cell, path[h]] > 0:
            cell = int(model.neighbors[cell, path[h]])
    return path


class InfoGainExplorer:
    """Information-gain exploration with macro-actions (see the module docstring).

    Options: ``hypotheses`` S worlds drawn per plan (None: exact enumeration of the observations,
    generic backend only); ``rollout_particles`` R particles of an rbpf belief used for rollouts
    (None: all); ``press_lengths`` the prefix lengths scored (default 1, 2, 4, 8 and
    ``ceil((max(rows, cols) - 1) / p_move) + 1``); ``step_cost`` the cost of a step, in units of
    the information one observation gives about a cell of unknown label (``I0`` above;
    ``"auto"``: 0.05 without frontier targets, 0.6 with them, :data:`TARGETS_STEP_COST`);
    ``location_weight`` the weight of ``H(L)`` in ``U``, also in units of ``I0``; ``commit`` the most steps of a chosen
    macro-action executed before re-planning; ``anchor_every`` the steps from the start of one press into
    the nearest corner to the start of the next (None: never; ``"auto"``: twice the anchor's
    presses plus 8, 60 in the 10 x 10 world; see the module docstring); ``gamma`` the discount of the
    policy-iteration plan; ``seed`` (int, None or Generator) the planner's own random stream.

    The planner rolls hypotheses out on copies of the live estimator, so it must see it:
    :func:`policies.explore` calls :meth:`bind` before the first decision. Planning never
    changes the live estimator (its arrays and random generator).
    """

    def __init__(self, model: GridModel, seed: SeedLike = None, *, hypotheses: int | None = 12,
                 rollout_particles: int | None = 64, press_lengths=None, step_cost: float | str = "auto",
                 location_weight: float = 4.0, commit: int = 8, anchor_every: int | str | None = "auto",
                 gamma: float = 0.95, targets: int | str = "auto"):
        self.model = model
        self.hypotheses = None if hypotheses is None else arguments.integer("hypotheses", hypotheses, minimum=1,
                                                                            error=InvalidOptionError)
        self.rollout_particles = None if rollout_particles is None else arguments.integer(
            "rollout_particles", rollout_particles, minimum=1, error=InvalidOptionError)
        self.location_weight = arguments.real("location_weight", location_weight, low=0.0, high=math.inf,
                                              high_open=True, error=InvalidOptionError)
        self.commit = arguments.integer("commit", commit, minimum=1, error=InvalidOptionError)
        self.gamma = arguments.real("gamma", gamma, low=0.0, high=1.0, high_open=True, error=InvalidOptionError)
        if press_lengths is None:
            longest = math.ceil((max(model.rows, model.cols) - 1) / max(model.p_move, 0.05)) + 1
            press_lengths = sorted({k for k in (1, 2, 4, 8) if k < longest} | {longest})
        self.press_lengths = _lengths(press_lengths)
        paper = model.is_paper_model
        if isinstance(targets, str):
            arguments.choice("targets", targets, ("auto",), error=InvalidOptionError)
            targets = 0 if paper or model.p_move == 0 else DEFAULT_TARGETS
        self.targets = arguments.integer("targets", targets, minimum=0, error=InvalidOptionError)
        if isinstance(step_cost, str):
            arguments.choice("step_cost", step_cost, ("auto",), error=InvalidOptionError)
            step_cost = STEP_COST if self.targets == 0 else TARGETS_STEP_COST
        self.step_cost = arguments.real("step_cost", step_cost, low=0.0, high=math.inf, high_open=True,
                                        error=InvalidOptionError)
        self._check_cost(self.rollout_particles)
        anchor_length = int(self.press_lengths[-1]) * ((model.rows > 1) + (model.cols > 1))
        if isinstance(anchor_every, str):
            arguments.choice("anchor_every", anchor_every, ("auto",), error=InvalidOptionError)
            # 60 in the 10 x 10 world: under half the steps anchoring; no corner to press into in a building
            anchor_every = 2 * anchor_length + 8 if self.targets == 0 else None
        if anchor_every is not None:
            anchor_every = arguments.integer("anchor_every", anchor_every, error=InvalidOptionError)
            if anchor_every <= anchor_length:
                raise InvalidOptionError(f"anchor_every must be 'auto', None or longer than the {anchor_length} presses "
                                         f"of an anchor (the robot would do nothing else), got {anchor_every!r}")
        self.anchor_every = anchor_every
        self.rng = as_generator(arguments.seed("seed", seed, error=InvalidOptionError))
        self.estimator: Estimator | None = None
        self.last_plan: MacroScore | None = None
        self._queue: list[int] = []
        self._since_anchor = 0
        self._pi: PolicyIterationResult | None = None
        self._tables = rollout_tables(model, int(self.press_lengths[-1]))
        self.frontier = FrontierExplorer(model) if self.targets else None  # where the unknown is
        self.presses = PressMemory(model)  # blocked and futile presses, for the moves towards a target
        self._target, self._target_steps = -1, 0
        uniform = np.full((1, model.n_labels), 1.0 / model.n_labels)
        nats = float(information_reward(Belief(0, np.ones(1), uniform), model.sensor)[0])  # I0
        self._nats_per_step = self.step_cost * nats
        self._location_nats = self.location_weight * nats

    def _check_cost(self, particles: int | None) -> None:
        """Refuse (InvalidOptionError naming the options, with the estimate) a plan of more than
        :data:`onlinemap.arguments.MAX_OPERATIONS` operations or, enumerating, :data:`MAX_PLAN_FORKS` forks.
        ``particles``: the R particles a rollout carries (None: not known yet, checked at bind)."""
        model, horizon = self.model, int(self.press_lengths[-1])
        candidates = model.n_actions + max(self.targets, 1)
        if self.hypotheses is None:
            outcomes = observation_count(model)
            forks, level = 0, 1
            for _ in range(horizon):
                level *= outcomes
                forks += candidates * level
                if forks > MAX_PLAN_FORKS:
                    raise InvalidOptionError(
                        f"info_gain with hypotheses=None enumerates every observation ({outcomes} a step) over "
                        f"press_lengths up to {horizon}: more than {MAX_PLAN_FORKS:.0e} estimator forks a plan "
                        f"(at least {forks:.3g}); give hypotheses (worlds sampled) or shorter press_lengths")
            return
        if particles is None:
            return
        work = rollout_operations(model, self.hypotheses, candidates, horizon, len(self.press_lengths), particles)
        arguments.bounded_work(
            f"a plan of info_gain (hypotheses={self.hypotheses} worlds x {candidates} candidates x press_lengths up "
            f"to {horizon} steps x {particles} particles)", work,
            "lower hypotheses, rollout_particles or press_lengths", error=InvalidOptionError)

    def bind(self, estimator: Estimator) -> None:
        """Plan on copies of ``estimator`` (the live filter of the exploration loop)."""
        if estimator.model is not self.model:
            raise ModelError("the estimator was built for a different model than the planner")
        if self.rollout_particles is None and isinstance(estimator, HoldsParticles):
            self._check_cost(estimator.n_particles)
        self.estimator = estimator
        self._queue = []
        self._since_anchor = 0
        self._target, self._target_steps = -1, 0

    def choose(self, belief: Belief) -> int:
        if self.estimator is None:
            raise ModelError("info_gain plans on the live estimator: call planner.bind(estimator) first "
                             "(policies.explore does)")
        if self._queue and self.model.has_blocking and not unblocked_actions(self.model, belief)[self._queue[0]]:
            self._queue = []  # the belief now says the next press blocks: re-plan
        if self._target_steps and self._target >= 0 and belief.location[self._target] > 0.5:
            self._target_steps = 0  # most probably there: re-plan
        if not self._queue and not self._target_steps:
            if self.anchor_every is not None and self._since_anchor >= self.anchor_every:
                self._queue = anchor_actions(self.model, belief, int(self.press_lengths[-1])).tolist()
                self._since_anchor = 0
            else:
                plan = self.plan(belief)
                c, j = plan.chosen
                steps = min(int(plan.lengths[j]), self.commit)
                if not plan.pays and self.frontier is not None:  # the frontier baseline's presses
                    self._target, self._target_steps = -1, steps
                elif plan.targets[c] >= 0:
                    self._target, self._target_steps = int(plan.targets[c]), steps
                else:
                    self._queue = plan.sequences[c, :steps].tolist()
        self._since_anchor += 1
        if self._target_steps:
            self._target_steps -= 1
            action = self.toward(belief, self._target) if self._target >= 0 else self.frontier.choose(belief)
        else:
            action = int(self._queue.pop(0))
        self.presses.pressed(belief, action)
        return action

    def toward(self, belief: Belief, target: int) -> int:
        """The press that brings the robot closest to ``target`` in expected steps, averaged over
        the location belief (the frontier's rule, :func:`~policies.passability.steps_after_press`
        on the belief's passability), among the presses :class:`~policies.passability.PressMemory`
        allows. O(N A log(N A)) (one Dijkstra)."""
        frontier = self.frontier  # a target comes from it: set whenever targets > 0
        passable = expected_passability(self.model, belief)
        distance = _finite(distances_to(self.model, passable, [target], frontier.min_passable), frontier.penalty)
        cost = belief.location @ steps_after_press(self.model, passable, distance, frontier.min_passable)
        return int(np.argmin(np.where(self.presses.allowed(belief), cost, np.inf)))

    def candidates(self, belief: Belief) -> Candidates:
        """Press each direction H times; then, with ``targets`` 0, the :func:`greedy_path` on the
        policy-iteration ``Q`` of :func:`information_reward` from the most probable location (with
        blocking labels, on the belief's expected passability; one warm-started policy iteration
        over N cells); with ``targets`` T > 0, the moves towards each of the best T frontier
        targets (:func:`frontier_targets`), in closed loop (sequence -1: each press chosen on the
        rollout's belief by :func:`~policies.passability.steps_after_press`; O(T N A log(N A)))."""
        model, horizon = self.model, int(self.press_lengths[-1])
        names = [f"press {name}" for name in model.action_names]
        sequences = [np.full(horizon, a, dtype=np.int64) for a in range(model.n_actions)]
        targets = [-1] * len(names)
        passable = expected_passability(model, belief) if model.has_blocking else None
        if self.targets == 0:
            reward = information_reward(belief, model.sensor)
            self._pi = policy_iteration(model, reward, self.gamma, passable=passable,
                                        initial_policy=None if self._pi is None else self._pi.policy)
            path = greedy_path(model, self._pi.q, int(np.argmax(belief.location)), horizon)
            if not any(np.array_equal(path, s) for s in sequences):
                names.append("plan")
                sequences.append(path)
                targets.append(-1)
            return Candidates(tuple(names), np.stack(sequences), np.asarray(targets), None, None)
        passable = expected_passability(model, belief) if passable is None else passable
        frontier = self.frontier
        chosen = frontier_targets(model, frontier.plan(belief), self.targets, skip=belief.location > 0.5)
        distances = [np.zeros(model.n_cells)] * len(names)
        for cell in chosen:
            names.append(f"to {divmod(int(cell), model.cols)}")
            sequences.append(np.full(horizon, -1, dtype=np.int64))
            targets.append(int(cell))
            distances.append(_finite(distances_to(model, passable, [cell], frontier.min_passable), frontier.penalty))
        return Candidates(tuple(names), np.stack(sequences), np.asarray(targets), np.stack(distances),
                          move_chances(model, passable, frontier.min_passable))

    def plan(self, belief: Belief) -> MacroScore:
        """Score every candidate at every length in ``press_lengths`` and pick the best utility
        (ties: the shorter, then the earlier candidate), leaving out macro-actions whose first
        action leaves the robot in place with probability >= 1/2 (pressing into a wall it is
        known to stand against; otherwise, when nothing pays its cost, such a press costs least
        and the robot would stand still); with blocking labels, also those whose first press the
        belief says blocks (:func:`~policies.passability.unblocked_actions`), and a queued press it
        says blocks ends the queue.
        Never changes the live estimator."""
        est = self.estimator
        names, sequences, targets, distances, go = self.candidates(belief)
        horizon = sequences.shape[1]
        lengths = self.press_lengths
        checkpoints = np.zeros(horizon + 1, dtype=np.bool_)
        checkpoints[0] = True
        checkpoints[lengths] = True
        if self.hypotheses is not None and isinstance(est, HoldsParticles):
            worlds = sample_states(est, self.hypotheses, self.rng)
            particles = est.particle_snapshot(self.rollout_particles, self.rng)
            if self.model.is_paper_model and distances is None:
                expected = particle_expected_uncertainty(self.model, particles, sequences, checkpoints, worlds,
                                                         self.rng, self._location_nats, self._tables)
            else:
                expected = footprint_expected_uncertainty(self.model, particles, sequences, checkpoints, worlds,
                                                          self.rng, self._location_nats, self._tables, distances, go)
        else:  # forks take fixed actions: a move towards a target is its walk from the most probable cell
            start = int(np.argmax(belief.location))
            fixed = [s if t < 0 else descent(self.model, go, distances[c], start, horizon)
                     for c, (s, t) in enumerate(zip(sequences, targets))]
            expected = np.stack([expected_uncertainty(est, s, hypotheses=self.hypotheses, seed=self.rng,
                                                      location_weight=self._location_nats) for s in fixed])
        gain = expected[:, :1] - expected[:, lengths]
        utility = gain - self._nats_per_step * lengths[None, :]
        # a macro-action whose first press most probably hits a wall only re-reads the same cell
        first = np.maximum(sequences[:, 0], 0)  # a move towards a target chooses its presses as it goes
        stays = belief.location @ (self.model.neighbors[:, first] == np.arange(self.model.n_cells)[:, None])
        through = (stays < 0.5) | np.all(stays >= 0.5) | (targets >= 0)
        if self.model.has_blocking:  # nor one whose first press the belief says blocks
            through &= unblocked_actions(self.model, belief)[first] | (targets >= 0)
            through = through if through.any() else np.ones_like(through)
        allowed = np.where(through[:, None], utility, -np.inf)
        best = np.flatnonzero(allowed.T.ravel() == allowed.max())[0]  # length-major: shorter first
        j, c = divmod(int(best), len(names))
        self.last_plan = MacroScore(names, sequences, lengths, gain, utility, (c, j), targets, allowed.max() > 0.0)
        return self.last_plan

    def __repr__(self) -> str:
        return (f"InfoGainExplorer(hypotheses={self.hypotheses}, rollout_particles={self.rollout_particles}, "
                f"press_lengths={self.press_lengths.tolist()}, step_cost={self.step_cost}, "
                f"location_weight={self.location_weight}, commit={self.commit}, anchor_every={self.anchor_every}, "
                f"targets={self.targets})")
