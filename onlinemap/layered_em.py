"""Layered EM: Burgard, Fox, Jans, Matenar and Thrun's two-layered maps (ICML 1999) on the grid
(DESIGN.md section 9, "two-layered maps"), a batch fitter for a recorded run.

Flat EM (:mod:`onlinemap.estimators.offline_em`) keeps one global map and places every reading
by its step's own location posterior: where the robot is unsure, the map is the evidence
convolved with the pose uncertainty, and localising in that blurred map fails. Here the run is
cut into M **stretches** of S steps; each stretch is a **local map** (its readings, and its
presses that moved or bumped, along its path relative to its first cell), and the hidden
variable is the stretch's **pose** ``x_m``: the cell it starts in. The local map is placed
rigidly: all its readings move together with ``x_m``.

- Within a stretch the path from ``x`` is dead reckoning's most likely one, ``pos_m(x, tau)``
  (the paper neglects odometry error within a local map): a press moves when ``p_move P(target
  passable) >= 1/2``, the passability read from the other stretches' map and the stretch's own
  latest reading of the target cell (a cross footprint reads it before the press), so a bump
  into a wall the stretch saw keeps the path in place. Slips within a stretch are not modelled
  there; they are absorbed by the motion between stretches.
- The map is the label posterior per cell from **expected log-evidence**: stretch m placed at x
  with weight ``pi_m(x)`` adds ``pi_m(x) log O[k, z]`` to cell c's label k for each reading z
  of c, and with blocking labels ``log P(moved | k)`` or ``log P(bumped | k)`` to each press's
  target (a failed press is evidence). ``q = softmax(log prior + sum_m E_m)``: the global map,
  assembled from the local maps at their poses (the paper's post-processing, eq. 18, with
  probabilities in place of a single pose). Probabilities below :data:`EVIDENCE_FLOOR` count as
  the floor, so a misplaced reading of a perfect sensor cannot make a label impossible.
- E-step: the likelihood of stretch m at pose x, ``l_m(x) = prod_tau P(z_tau | pos_m(x, tau);
  q_-m) prod_presses P(outcome | q_-m)``, is computed against the map of the **other** stretches
  ``q_-m = softmax(log prior + E - E_m)`` (the paper's product over the other local maps, eq. 8:
  a stretch never confirms its own pose); then forward-backward over the poses x_0..x_{M-1}
  with the S-step motion kernel between consecutive stretch starts (the model's motion, with the
  global map's passability). With S = 1 and a fixed map this is exactly forward-backward over
  locations.
- M-step: ``E_m`` from the tempered pose posteriors ``pi_m^(1/tau)`` (deterministic annealing,
  the paper's softmax M-step, eq. 15: tau from tau0 towards tau_min, :class:`Anneal`).
- Start: a forward sweep that localises each stretch against the map of the stretches before it
  (the Markov localization of a robot that maps as it goes), so the first E-step does not see the
  prior's featureless map.

Stretch length: the rule for the default, :func:`default_stretch`, keeps the spread of dead
reckoning within a stretch about one cell: the number of slips in S presses has variance
``S p_move (1 - p_move)``, so ``S = round(1 / (p_move (1 - p_move)))`` (21 steps at p_move 0.95,
6 at 0.8), at most :data:`MAX_STRETCH`.

Cost per iteration, T steps, N cells, M = T / S stretches, K labels, F readings, E motion edges:
O(T N F) for the likelihood of every stretch at every pose, O(M N K^2) for the maps without each
stretch, O(T (N + E)) for forward-backward, and O(T F n) for the M-step over the n poses per
stretch with posterior above :data:`PRUNE_BELOW` (n << N once localised). Memory O(T N) for the
paths and O(M N K) for the local maps. Static worlds only (the map is a parameter).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from . import arguments
from .errors import InvalidOptionError, ModelError
from .estimators.offline_em import Anneal, check_anneal, check_n_iter
from .hmm import footprint_emission, temper
from .model import GridModel, apply_motion, apply_motion_transpose
from .validation import check_sequence

EVIDENCE_FLOOR = 1e-6  # the least probability a reading or a press outcome counts with
PRUNE_BELOW = 1e-9  # poses whose tempered posterior is below this add no evidence in the M-step
MAX_STRETCH = 64  # the default stretch length never exceeds this (p_move near 0 or 1)
DEFAULT_ANNEAL = (1.0, 0.6, 0.05)  # tau: 1, 0.6, 0.36, ... down to 0.05 by the 7th iteration


class LayeredMap(NamedTuple):
    """The result of :func:`fit_layered_map` on a run of T steps cut into M stretches."""

    map: np.ndarray  # (N, K) the global map: P(m_i = k) from all local maps at their poses
    local_maps: np.ndarray  # (M, N, K) each stretch's expected log-evidence, placed by its pose posterior
    poses: np.ndarray  # (M, N) P(x_m = cell | all data; the other stretches' maps), the last E-step
    starts: np.ndarray  # (M,) the first step of each stretch
    log_likelihoods: np.ndarray  # (iterations,) log sum_x prod_m l_m(x_m) P(x) of each E-step


def default_stretch(p_move: float) -> int:
    """The default stretch length: ``round(1 / (p_move (1 - p_move)))``, the number of presses
    after which the variance of the number of slips is one cell; in 1..:data:`MAX_STRETCH`
    (p_move 0 or 1: dead reckoning never errs, so :data:`MAX_STRETCH`)."""
    spread = p_move * (1.0 - p_move)
    if spread <= 1.0 / MAX_STRETCH:
        return MAX_STRETCH
    return max(1, min(MAX_STRETCH, round(1.0 / spread)))


class _Run(NamedTuple):
    """Checked inputs and constant tables of one fit."""

    actions: np.ndarray  # (T - 1,)
    readings: np.ndarray  # (T, F) int64, -1 off the grid
    starts: np.ndarray  # (M + 1,) stretch boundaries, starts[-1] = T
    log_sensor: np.ndarray  # (K, K) log max(O[k, z], floor)
    log_move: np.ndarray  # (K,) log P(a press into a cell of label k moves), floored
    log_stay: np.ndarray  # (K,) log P(it fails), floored
    log_prior: np.ndarray  # (N, K)
    passable_label: np.ndarray  # (K,) 1.0 for labels a robot can enter
    sensor: np.ndarray  # (K, K) max(O, floor): a perfect sensor's contradicted reading stays possible
    shifts: np.ndarray  # (A + 1, F) _shifted_offsets
    ahead: np.ndarray  # (A,) the footprint offset that reads the cell an action moves into, -1 if none


class _Local(NamedTuple):
    """A stretch's path from every pose and its likelihood there."""

    path: np.ndarray  # (S, N) cell at each step of the stretch, per starting cell
    log_likelihood: np.ndarray  # (N,) log l_m(x)


def _softmax(log_weights: np.ndarray) -> np.ndarray:
    """Rows of exp(log_weights) normalised. (N, K) -> (N, K)."""
    shifted = np.exp(log_weights - log_weights.max(axis=1, keepdims=True))
    return shifted / shifted.sum(axis=1, keepdims=True)


def _prepare(model: GridModel, actions, observations, stretch) -> _Run:
    if not model.is_static:
        raise ModelError("layered EM treats the map as fixed: it needs a static world (C the identity)")
    a_seq, z_seq = check_sequence(model, actions, observations)
    t = len(z_seq)
    length = default_stretch(model.p_move) if stretch is None else \
        arguments.integer("stretch", stretch, minimum=1, error=InvalidOptionError)
    starts = np.append(np.arange(0, t, length), t)
    passable = (~model.blocking).astype(np.float64)
    with np.errstate(divide="ignore"):
        log_sensor = np.log(np.maximum(model.sensor, EVIDENCE_FLOOR))
        log_move = np.log(np.maximum(model.p_move * passable, EVIDENCE_FLOOR))
        log_stay = np.log(np.maximum(1.0 - model.p_move * passable, EVIDENCE_FLOOR))
        log_prior = np.log(model.label_prior)
    shifts = _shifted_offsets(model)
    # the offset f that reads the target is the one that reads the cell itself (offset (0, 0)) after the move
    own = model.footprint.index((0, 0)) if (0, 0) in model.footprint else -1
    ahead = shifts[:-1, own] if own >= 0 else np.full(model.n_actions, -1, dtype=np.int64)
    return _Run(a_seq, z_seq.reshape(t, -1), starts, log_sensor, log_move, log_stay, log_prior, passable,
                np.maximum(model.sensor, EVIDENCE_FLOOR), shifts, ahead)


def _shifted_offsets(model: GridModel) -> np.ndarray:
    """(A + 1, F) int64: ``g[a, f]`` the footprint offset of the cell before a move by action a
    that offset f reads after it (-1 if none); row A is "no move" (g = f). Raises ModelError if an
    action moves cells by different displacements (the local maps need a translation-invariant
    grid). O(N A + F^2 A)."""
    cells = np.arange(model.n_cells)
    offsets = np.array(model.footprint, dtype=np.int64).reshape(-1, 2)
    shifts = np.full((model.n_actions + 1, len(offsets)), -1, dtype=np.int64)
    shifts[-1] = np.arange(len(offsets))
    for a in range(model.n_actions):
        target = model.neighbors[:, a]
        movers = target != cells
        if not movers.any():
            continue
        moves = np.unique(np.stack(np.divmod(target[movers], model.cols)) - np.stack(np.divmod(cells[movers], model.cols)),
                          axis=1)
        if moves.shape[1] != 1:
            raise ModelError(f"action {model.action_names[a]!r} moves cells by different displacements; layered EM "
                             f"needs every move of an action to shift the grid the same way")
        after = offsets + moves[:, 0]  # offset f after the move is this offset from the cell before it
        same = (after[:, None, :] == offsets[None, :, :]).all(axis=2)  # (F, F')
        shifts[a] = np.where(same.any(axis=1), same.argmax(axis=1), -1)
    return shifts


def _log_predictive(model: GridModel, run: _Run, labels: np.ndarray, at: np.ndarray, shift: np.ndarray,
                    previous: np.ndarray, current: np.ndarray) -> np.ndarray:
    """(n,) log P(readings ``current`` (F,) from cells ``at`` (n,)) under ``labels`` (N, K) updated
    by the step before's readings ``previous`` (F,), of which offset ``shift[f]`` (-1: none) read
    the cell that offset f reads now: ``sum_k q_c(k) O[k, z'] O[k, z] / sum_k q_c(k) O[k, z']``,
    floored. O(N K F + n F)."""
    earlier = np.where(shift >= 0, previous[np.maximum(shift, 0)], -1)
    before = np.where(earlier >= 0, run.sensor[:, np.maximum(earlier, 0)], 1.0)  # (K, F)
    now = np.where(current >= 0, run.sensor[:, np.maximum(current, 0)], 1.0)
    cells = model.footprint_cells[at]  # (n, F)
    column = np.arange(cells.shape[1])
    index = np.maximum(cells, 0)
    predictive = (labels @ (before * now))[index, column] / (labels @ before)[index, column]
    predictive = np.where(cells < 0, 1.0, predictive) * ((cells < 0) == (current < 0)[None, :])
    return np.log(np.maximum(predictive, EVIDENCE_FLOOR)).sum(axis=1)


def stretch_likelihood(model: GridModel, run: _Run, m: int, labels: np.ndarray) -> _Local:
    """Stretch m's path and log-likelihood from every starting cell under map marginals
    ``labels`` (N, K) (the other stretches' map). The path (module docstring): a press moves
    when moving explains the step's readings better, ``p_move P(target passable) P(z_tau | target)
    >= (1 - p_move P(target passable)) P(z_tau | stay)``, both under ``labels`` updated by the
    readings of the step before (so a slip, which leaves the robot reading what it read, is
    told apart from a move). O(S N F^2 + S N F K)."""
    first, end = run.starts[m], run.starts[m + 1]
    readings = run.readings[first:end]
    n = model.n_cells
    # floored: a path gone wrong (a missed bump) can put the footprint off the grid, where the
    # readings' off-grid pattern does not fit; that is unlikely, not impossible
    log_emission = np.log(np.maximum(footprint_emission(model, labels @ model.sensor, readings),
                                     EVIDENCE_FLOOR ** model.n_readings))  # (S, N)
    passable = labels @ run.passable_label
    path = np.empty((end - first, n), dtype=np.int64)
    path[0] = np.arange(n)
    total = log_emission[0].copy()
    for tau in range(1, end - first):
        here = path[tau - 1]
        action = run.actions[first + tau - 1]
        target = model.neighbors[here, action]
        presses = target != here
        previous, current = readings[tau - 1], readings[tau]
        p_enter = np.full(n, model.p_move)
        if model.has_blocking and run.ahead[action] >= 0:  # the target's passability after its latest reading
            z = previous[run.ahead[action]]
            seen = run.sensor[:, z] if z >= 0 else np.ones(model.n_labels)
            p_enter *= (labels @ (seen * run.passable_label))[target] / (labels @ seen)[target]
        elif model.has_blocking:
            p_enter *= passable[target]
        with np.errstate(divide="ignore"):
            move = np.log(p_enter) + _log_predictive(model, run, labels, target, run.shifts[action], previous, current)
            stay = np.log(1.0 - p_enter) + _log_predictive(model, run, labels, here, run.shifts[-1], previous, current)
        moves = presses & (move >= stay)
        if model.has_blocking:
            p_global = model.p_move * passable[target]
            outcome = np.where(moves, p_global, 1.0 - p_global)
            total += np.where(presses, np.log(np.maximum(outcome, EVIDENCE_FLOOR)), 0.0)
        path[tau] = np.where(moves, target, here)
        total += log_emission[tau, path[tau]]
    return _Local(path, total)


def local_evidence(model: GridModel, run: _Run, m: int, local: _Local, weights: np.ndarray) -> np.ndarray:
    """(N, K) stretch m's expected log-evidence ``E_m`` with pose weights (N,) (tempered
    posterior): its readings and, with blocking labels, its presses' outcomes at every pose with
    weight above :data:`PRUNE_BELOW`. O(S F n) for n such poses."""
    n, k = model.n_cells, model.n_labels
    poses = np.flatnonzero(weights > PRUNE_BELOW)
    w = weights[poses]
    path = local.path[:, poses]  # (S, n)
    readings = run.readings[run.starts[m]:run.starts[m + 1]]
    cells = model.footprint_cells[path]  # (S, n, F)
    z = np.broadcast_to(readings[:, None, :], cells.shape)
    valid = (cells >= 0) & (z >= 0)
    counts = np.bincount((cells * k + z)[valid], weights=np.broadcast_to(w[None, :, None], cells.shape)[valid],
                         minlength=n * k).reshape(n, k)
    evidence = counts @ run.log_sensor.T  # counts[c, z] log O[k, z] summed over z
    if model.has_blocking and len(path) > 1:
        actions = run.actions[run.starts[m]:run.starts[m + 1] - 1]
        target = model.neighbors[path[:-1], actions[:, None]]  # (S - 1, n)
        presses = target != path[:-1]
        moved = path[1:] != path[:-1]
        ww = np.broadcast_to(w[None, :], target.shape)
        entered = np.bincount(target[moved], weights=ww[moved], minlength=n)
        bumped = np.bincount(target[presses & ~moved], weights=ww[presses & ~moved], minlength=n)
        evidence += entered[:, None] * run.log_move + bumped[:, None] * run.log_stay
    return evidence


def _motion(model: GridModel, run: _Run, m: int, belief: np.ndarray, passable, backward: bool) -> np.ndarray:
    """The S-step motion kernel from stretch m's start to stretch m + 1's (forward: predict a
    distribution over cells; backward: pull a message back). O(S (N + E))."""
    actions = run.actions[run.starts[m]:run.starts[m + 1]]
    if backward:
        for a in actions[::-1]:
            belief = apply_motion_transpose(model, belief, int(a), passable)
    else:
        for a in actions:
            belief = apply_motion(model, belief, int(a), passable)
    return belief


def pose_posteriors(model: GridModel, run: _Run, log_likelihood: np.ndarray,
                    passable: np.ndarray | None) -> tuple[np.ndarray, float]:
    """Forward-backward over the stretch poses: (M, N) ``P(x_m | data)`` and the log evidence
    ``log sum_x P(x_0..x_M-1) prod_m l_m(x_m)``, from the log-likelihoods (M, N), the start cell
    prior and the S-step motion with ``passable`` (N,) (None: the paper's motion). Raises ModelError
    when no pose sequence has positive probability. O(T (N + E))."""
    n_stretch, n = log_likelihood.shape
    likelihood = np.empty((n_stretch, n))
    filtered = np.empty((n_stretch, n))
    log_evidence = 0.0
    predicted = model.location_prior()
    for m in range(n_stretch):
        if m > 0:
            predicted = _motion(model, run, m - 1, filtered[m - 1], passable, backward=False)
        # scaled by the best pose the motion allows: another pose may be e^-1000 likelier than all of those
        shift = log_likelihood[m][predicted > 0].max()
        if not np.isfinite(shift):
            raise ModelError(f"stretch {m} (from step {run.starts[m]}) has probability zero at every pose reachable "
                             f"from the start")
        np.exp(log_likelihood[m] - shift, out=likelihood[m])
        joint = predicted * likelihood[m]
        total = joint.sum()
        filtered[m] = joint / total
        log_evidence += float(np.log(total)) + float(shift)
    posterior = np.empty_like(filtered)
    posterior[-1] = filtered[-1]
    beta = np.ones(n)
    for m in range(n_stretch - 2, -1, -1):
        beta = _motion(model, run, m, beta * likelihood[m + 1], passable, backward=True)
        beta /= beta.max()
        joint = filtered[m] * beta
        posterior[m] = joint / joint.sum()
    return posterior, log_evidence


def _passability(model: GridModel, run: _Run, labels: np.ndarray) -> np.ndarray | None:
    return labels @ run.passable_label if model.has_blocking else None


def localize_stretches(model: GridModel, actions, observations, labels, *, stretch: int | None = None
                       ) -> tuple[np.ndarray, float]:
    """The E-step in a given map: (M, N) ``P(x_m | data; labels)`` for the stretches of a run and
    the log evidence of the stretch likelihoods, every stretch scored against the same map marginals
    ``labels`` (N, K) (no stretch left out). With ``stretch=1`` this is forward-backward over the
    locations of the location HMM with observation matrix ``labels @ O``. Cost O(T N F + T (N + E))."""
    run = _prepare(model, actions, observations, stretch)
    labels = np.asarray(labels, dtype=np.float64)
    if labels.shape != (model.n_cells, model.n_labels):
        raise ModelError(f"labels must have shape {(model.n_cells, model.n_labels)}, got {labels.shape}")
    log_likelihood = np.array([stretch_likelihood(model, run, m, labels).log_likelihood
                               for m in range(len(run.starts) - 1)])
    return pose_posteriors(model, run, log_likelihood, _passability(model, run, labels))


def _initial_evidence(model: GridModel, run: _Run, schedule: Anneal | None) -> list[np.ndarray]:
    """The forward sweep's local maps: stretch m localised (filtered) against the map of stretches
    0..m-1 and placed by its tempered filtered posterior. O(T N F + M N K)."""
    tau = 1.0 if schedule is None else schedule.tau(0)
    total = np.zeros((model.n_cells, model.n_labels))
    evidence = []
    predicted = model.location_prior()
    for m in range(len(run.starts) - 1):
        labels = _softmax(run.log_prior + total)
        if m > 0:
            predicted = _motion(model, run, m - 1, filtered, _passability(model, run, labels), backward=False)
        local = stretch_likelihood(model, run, m, labels)
        shift = local.log_likelihood[predicted > 0].max()
        if not np.isfinite(shift):
            raise ModelError(f"stretch {m} (from step {run.starts[m]}) has probability zero at every pose reachable "
                             f"from the start")
        joint = predicted * np.exp(local.log_likelihood - shift)
        filtered = joint / joint.sum()
        evidence.append(local_evidence(model, run, m, local, temper(filtered, tau)))
        total += evidence[-1]
    return evidence


def fit_layered_map(model: GridModel, actions, observations, *, stretch: int | None = None, n_iter: int = 8,
                    anneal=DEFAULT_ANNEAL) -> LayeredMap:
    """Layered EM on a recorded run (actions (T - 1,), observations (T,) or (T, F), by index or
    name): the module docstring's algorithm, ``n_iter`` E- and M-steps after the forward sweep.

    ``stretch``: steps per local map (None: :func:`default_stretch` of the model's p_move);
    ``anneal``: None or ``(tau0, rate, tau_min)`` as offline EM's (:class:`Anneal`), iteration 0
    at tau0. Raises InvalidOptionError for bad options and ModelError for a dynamic world.
    Cost: the module docstring's, per iteration.
    """
    run = _prepare(model, actions, observations, stretch)
    n_iter = check_n_iter(n_iter)
    schedule = check_anneal(anneal)
    evidence = _initial_evidence(model, run, schedule)
    total = np.sum(evidence, axis=0)
    log_likelihoods = []
    for iteration in range(n_iter):
        passable = _passability(model, run, _softmax(run.log_prior + total))
        locals_ = [stretch_likelihood(model, run, m, _softmax(run.log_prior + total - evidence[m]))
                   for m in range(len(evidence))]
        posterior, log_evidence = pose_posteriors(model, run, np.array([loc.log_likelihood for loc in locals_]),
                                                  passable)
        log_likelihoods.append(log_evidence)
        tau = 1.0 if schedule is None else schedule.tau(iteration + 1)
        evidence = [local_evidence(model, run, m, locals_[m], temper(posterior[m], tau)) for m in range(len(locals_))]
        total = np.sum(evidence, axis=0)
    return LayeredMap(_softmax(run.log_prior + total), np.array(evidence), posterior, run.starts[:-1].copy(),
                      np.array(log_likelihoods))
