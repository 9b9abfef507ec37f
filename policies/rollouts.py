"""The particle backend of :mod:`policies.info_gain`: the expected uncertainty of action
sequences measured on a thinned copy of a particle belief (``rollout_particles`` particles drawn
by weight, or all of them; :meth:`~onlinemap.estimators.rbpf.RaoBlackwellisedPF.particle_snapshot`),
rolled out by a numba kernel without copying any map:
:func:`policies.kernels.planning.rollout_uncertainty` for the paper's sensor and motion,
:func:`policies.kernels.footprint.plan_rollouts` for any footprint and blocking labels (the RBPF's
update with its optimal proposal; it equals the exact forks on exact particle beliefs and Bayes'
rule in expectation, ``tests/test_info_gain.py``).

Cost per plan: O(P N K^2) to read the particles' maps, plus for each of ``hypotheses`` S worlds
and each of the 2 A candidate rollouts of up to H steps, O(H R (H + K^2)) for the steps and
O(R N K) per scored length, plus one warm-started policy iteration over N cells. Measured
(``onlinemap bench planning``, P = 1000, R = 64, S = 12): 10 x 10, about 20 ms per plan, 2.7 ms
per decision; 32 x 32, about 96 ms per plan, 13 ms per decision; with blocking and a cross
footprint, 10 x 10: 33 ms per plan, 10.6 ms per decision.
"""

from __future__ import annotations

import numpy as np

from onlinemap.estimators.base import ParticleSnapshot
from onlinemap.estimators.rbpf_kernels import world_tables
from onlinemap.model import GridModel, change_powers

from .information import entropy
from .kernels.footprint import Agreement, Candidates, plan_rollouts
from .kernels.mixture import disputed_cells
from .kernels.planning import Hypotheses, RolloutTables, Scoring, rollout_uncertainty
from .kernels.rollout_buffers import KeptBuffers


def rollout_tables(model: GridModel, horizon: int) -> RolloutTables:
    """Cumulative sensor and change rows and the powers of C up to ``horizon``. O(H K^3)."""
    return RolloutTables(np.cumsum(model.sensor, axis=1), np.cumsum(model.change, axis=1),
                         change_powers(model.change, horizon + 1).copy(),  # writable: the kernels' one signature
                         not model.is_static)


def draw_hypotheses(model: GridModel, worlds: tuple[np.ndarray, np.ndarray], horizon: int, r_count: int,
               rng: np.random.Generator, per_world: bool) -> Hypotheses:
    """The worlds ``(locations (S,), labels (S, N))`` with the random numbers of their steps:
    ``world_u`` (S, H, 1 + F), ``change_u`` (S, H, N) (N = 0 in a static world), ``proposal_u``
    (S, H, R), drawn from ``rng`` world by world (``per_world``: the three of world s, then those
    of world s + 1) or each for all worlds at once. O(S H (F + N + R))."""
    n_worlds, n_change = len(worlds[0]), 0 if model.is_static else model.n_cells
    shapes = ((horizon, 1 + model.n_readings), (horizon, n_change), (horizon, r_count))
    if per_world:
        drawn = [[rng.random(shape) for shape in shapes] for _ in range(n_worlds)]
        world_u, change_u, proposal_u = (np.array([d[i] for d in drawn]).reshape((n_worlds,) + shapes[i])
                                         for i in range(3))
    else:
        world_u, change_u, proposal_u = (rng.random((n_worlds,) + shape) for shape in shapes)
    return Hypotheses(np.asarray(worlds[0], dtype=np.int64), np.ascontiguousarray(worlds[1], dtype=np.int64),
                      world_u, change_u, proposal_u)


def particle_expected_uncertainty(model: GridModel, particles: ParticleSnapshot, sequences: np.ndarray,
                                  checkpoints: np.ndarray, worlds: tuple[np.ndarray, np.ndarray],
                                  rng: np.random.Generator, location_weight: float = 1.0,
                                  tables: RolloutTables | None = None) -> np.ndarray:
    """(C, H + 1) expected uncertainty of each action sequence ``sequences`` (C, H) after each
    prefix length h with ``checkpoints[h]`` (other entries 0), averaged over the worlds
    ``(locations (S,), labels (S, N))``; every sequence sees the same worlds and random numbers.
    Cost O(S C (H R (H + K^2) + n_checkpoints R N K)), the uncertainty now (O(R N K)) once."""
    sequences = np.ascontiguousarray(sequences, dtype=np.int64)
    n_seq, horizon = sequences.shape
    tables = rollout_tables(model, horizon) if tables is None else tables
    total = np.zeros((n_seq, horizon + 1))
    rollout_uncertainty(particles, world_tables(model), tables, sequences,
                        draw_hypotheses(model, worlds, horizon, len(particles.locations), rng, per_world=True),
                        Scoring(float(location_weight), np.asarray(checkpoints, dtype=np.bool_)), total)
    return total / len(worlds[0])


def agreement(model: GridModel, particles: ParticleSnapshot, horizon: int,
              tables: RolloutTables) -> tuple[np.ndarray, np.ndarray]:
    """The cells whose marginals differ between the particles (D,) sorted, and (H + 1,) the summed
    entropy at step h of the other cells' common marginal (brought forward by ``C^h``): the part
    of ``sum_i H(M_i)`` no reweighting changes (the cells by :func:`~policies.kernels.mixture.disputed_cells`:
    1 ms at 64 x 64, R = 64, 5.8 ms by numpy's compare-and-reduce). O(R N K + H N K^2) (O(R N K) in a
    static world)."""
    maps = particles.maps
    disputed = disputed_cells(np.ascontiguousarray(maps))
    agree = np.ones(model.n_cells, dtype=bool)
    agree[disputed] = False
    common = maps[0, agree]
    if model.is_static:
        return disputed, np.full(horizon + 1, entropy(common).sum())
    return disputed, np.array([entropy(common @ tables.powers[h]).sum() for h in range(horizon + 1)])


def footprint_expected_uncertainty(model: GridModel, particles: ParticleSnapshot, sequences: np.ndarray,
                                   checkpoints: np.ndarray, worlds: tuple[np.ndarray, np.ndarray],
                                   rng: np.random.Generator, location_weight: float = 1.0,
                                   tables: RolloutTables | None = None, distances: np.ndarray | None = None,
                                   go: np.ndarray | None = None, threads: int = 1, *,
                                   kept: KeptBuffers | None = None) -> np.ndarray:
    """(C, H + 1) :func:`particle_expected_uncertainty` for any sensor footprint and blocking
    labels (:func:`policies.kernels.footprint.plan_rollouts`): ``sequences`` (C, H) actions, -1
    where the action is chosen in closed loop towards candidate c's target by ``distances`` (C, N)
    and ``go`` (N, A) (the chance each press moves). Every sequence sees the same worlds and random
    numbers. Cost O(S C (H R (F + 1) K^2 + n_checkpoints R (D + H F) K)), D the disputed cells,
    the worlds split over ``threads`` threads (the same result for any count); ``kept``: the
    :class:`~policies.kernels.rollout_buffers.KeptBuffers` the caller keeps to reuse the rollout
    buffers from plan to plan (the same result)."""
    sequences = np.ascontiguousarray(sequences, dtype=np.int64)
    n_seq, horizon = sequences.shape
    tables = rollout_tables(model, horizon) if tables is None else tables
    drawn = draw_hypotheses(model, worlds, horizon, len(particles.locations), rng, per_world=False)
    if distances is None:
        distances = np.zeros((n_seq, model.n_cells))
        go = np.zeros((model.n_cells, model.n_actions))
    total = np.zeros((n_seq, horizon + 1))
    plan_rollouts(particles._replace(maps=np.ascontiguousarray(particles.maps)), world_tables(model), tables,
                  Candidates(sequences, np.ascontiguousarray(distances), np.ascontiguousarray(go, dtype=np.float64)),
                  drawn, Scoring(float(location_weight), np.asarray(checkpoints, dtype=np.bool_)),
                  Agreement(*agreement(model, particles, horizon, tables)), total, threads, kept)
    return total / len(drawn.locations)


def rollout_operations(model: GridModel, hypotheses: int, candidates: int, horizon: int, lengths: int,
                       particles: int) -> int:
    """The estimated floating-point operations of one plan of the particle backend:
    ``S C (H R (F + 1) K^2 + L R N K)`` for S worlds, C candidates of H steps, L scored lengths,
    R particles, F footprint offsets (exact Python ints)."""
    k = model.n_labels
    return hypotheses * candidates * (horizon * particles * (model.n_readings + 1) * k * k
                                      + lengths * particles * model.n_cells * k)
