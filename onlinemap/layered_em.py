"""Layered EM: Burgard, Fox, Jans, Matenar and Thrun's two-layered maps (ICML 1999) on the grid
(DESIGN.md section 9, "two-layered maps"), a batch fitter for a recorded run.

Flat EM (:mod:`onlinemap.estimators.offline_em`) keeps one global map and places every reading
by its step's own location posterior: where the robot is unsure, the map is the evidence
convolved with the pose uncertainty, and localising in that blurred map fails. Here the run is
cut into M **stretches** of S steps; each stretch is a **local map** (its readings, and its
presses that moved or bumped, along its path relative to its first cell), and the hidden
variable is the stretch's **pose** ``x_m``: the cell it starts in.

- Within a stretch the path is a hidden sequence of **offsets** ``d_tau`` from the start
  (``d_0 = 0``), decoded exactly by forward-backward over the ``(x, d)`` pairs (the offsets the
  stretch's actions can reach: at most ``(S/2 + 1)^2``): a press from cell c moves with
  ``p_move P(target passable)``, the passability read from the other stretches' map and the
  stretch's own latest reading of the target (a cross footprint reads it before the press, so a
  bump into a wall the stretch saw stays in place); the readings of step tau are predicted by
  the other stretches' map **updated by step tau - 1's readings of the same cells**, so a slip,
  which reads again what it read, is told apart from a move into cells the map knows nothing of.
- The map is the label posterior per cell from **expected log-evidence**: stretch m adds, for
  each reading z of cell c, ``P(the reading was of c) log O[k, z]`` to cell c's label k, the
  probability from its tempered pose posterior and its offsets' posterior given the pose, and
  with blocking labels ``log P(moved | k)`` or ``log P(bumped | k)`` for each press's target (a
  failed press is evidence). ``q = softmax(log prior + sum_m E_m)``: the global map, assembled
  from the local maps at their poses (the paper's eq. 18, with probabilities in place of one
  pose). Probabilities below :data:`EVIDENCE_FLOOR` count as the floor, so a misplaced reading of
  a perfect sensor cannot make a label impossible.
- E-step: stretch m is scored against the map of the **other** stretches ``q_-m = softmax(log
  prior + E - E_m)`` (the paper's product over the other local maps, eq. 8: a stretch never
  confirms its own pose); forward-backward runs over the poses ``x_0..x_{M-1}``, the pose of
  stretch m + 1 one motion step (the model's, with the global map's passability) from the cell
  where stretch m ends. With S = 1 and a fixed map this is exactly forward-backward over
  locations; with S > 1 it is the exact posterior of the path under the emissions above.
- M-step: ``E_m`` from the tempered pose posteriors ``pi_m^(1/tau)`` (deterministic annealing,
  the paper's softmax M-step, eq. 15: tau from tau0 towards tau_min, :class:`Anneal`).
- Label prior (``label_prior="learn"``, :mod:`onlinemap.label_prior`): the prior of every cell
  is the label frequencies theta, re-estimated in every M-step as the Dirichlet posterior mean
  given the expected labels of the cells read (EM for what maps look like). Under a uniform
  prior half of every unread cell blocks and a reading of free space there is a 1-in-K event,
  so stretches are pulled onto mapped cells; the learned frequencies make unread cells as likely
  to be free as the building's cells are.
- Start: a forward sweep that localises each stretch against the map of the stretches before it
  (the Markov localization of a robot that maps as it goes: the paper's incremental alignment),
  so the first E-step does not see the prior's featureless map.

Stretch length: :func:`default_stretch`, ``S = round(1 / (2 (1 - p_move)))``, one expected slip
every two stretches (10 steps at p_move 0.95, 3 at 0.8), at most :data:`MAX_STRETCH`. Longer
stretches cost D ~ (S/2)^2 offsets per start; shorter ones leave less of the run out of each
stretch's map.

Cost per iteration, T steps, N cells, M = T / S stretches, K labels, F readings, D offsets per
stretch: O(T N F K) for the emissions under each stretch's map, O(M N K) for the maps without
each stretch, O(T N D) for forward-backward within the stretches (the forward pass twice),
O(M N) for the motion between them, and O(T F n D) for the M-step over the n poses per stretch
with tempered posterior above :data:`PRUNE_BELOW` (n << N once localised). Memory O(T N) for the
emissions, O(S N D) for one stretch's messages and O(M N K) for the local maps. Static worlds
only (the map is a parameter).
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import numpy as np

from . import arguments
from .errors import InvalidOptionError, ModelError
from .estimators.offline_em import Anneal, check_anneal, check_n_iter
from .hmm import temper
from .kernels import layered as kernels
from .label_prior import posterior_frequencies, resolve_label_prior
from .model import GridModel, apply_motion, apply_motion_transpose
from .validation import check_sequence

EVIDENCE_FLOOR = 1e-6  # the least probability a reading or a press outcome counts with
PRUNE_BELOW = 1e-9  # poses whose tempered posterior is below this add no evidence in the M-step
MAX_STRETCH = 16  # the default stretch length never exceeds this (p_move near 1); D grows as S^2
DEFAULT_ANNEAL = (1.0, 0.6, 0.05)  # tau: 1, 0.6, 0.36, ... down to 0.05 by the 7th iteration
DEFAULT_STARTS = (1.0, 0.3)  # the forward sweeps' placement temperatures EM starts from
SELECT_AFTER = 2  # iterations each start runs before the likeliest continues


class LayeredMap(NamedTuple):
    """The result of :func:`fit_layered_map` on a run of T steps cut into M stretches."""

    map: np.ndarray  # (N, K) the global map: P(m_i = k) from all local maps at their poses
    local_maps: np.ndarray  # (M, N, K) each stretch's expected log-evidence, placed by its pose posterior
    poses: np.ndarray  # (M, N) P(x_m = cell | all data; the other stretches' maps), the last E-step
    starts: np.ndarray  # (M,) the first step of each stretch
    log_likelihoods: np.ndarray  # (iterations,) log sum_x prod_m l_m(x_m) P(x) of each E-step
    frequencies: np.ndarray  # (K,) the label prior of the cells at the end (learned with label_prior="learn")

    def map_with_prior(self, label_prior: np.ndarray) -> np.ndarray:
        """(N, K) the global map with another label prior (N, K) or (K,), the local maps kept where
        the fit placed them: ``softmax(log prior + sum_m E_m)``. With ``label_prior="learn"`` and the
        model's prior here, the robot is aligned with the learned statistics and the map keeps the
        model's prior for what the readings do not say (a like-for-like map). O(M N K)."""
        with np.errstate(divide="ignore"):
            return _softmax(np.log(np.broadcast_to(label_prior, self.map.shape)) + self.local_maps.sum(axis=0))


def default_stretch(p_move: float) -> int:
    """The default stretch length: ``round(1 / (2 (1 - p_move)))`` (halves rounded up), one
    expected slip in two stretches; in 1..:data:`MAX_STRETCH` (p_move 1: dead reckoning never
    errs, so :data:`MAX_STRETCH`)."""
    if 1.0 - p_move <= 1.0 / (2 * MAX_STRETCH):
        return MAX_STRETCH
    return max(1, min(MAX_STRETCH, int(0.5 + 1.0 / (2.0 * (1.0 - p_move)))))


class _Run(NamedTuple):
    """Checked inputs and constant tables of one fit."""

    actions: np.ndarray  # (T - 1,)
    readings: np.ndarray  # (T, F) int64, -1 off the grid
    starts: np.ndarray  # (M + 1,) stretch boundaries, starts[-1] = T
    log_sensor: np.ndarray  # (K, K) log max(O[k, z], floor)
    log_move: np.ndarray  # (K,) log P(a press into a cell of label k moves), floored
    log_stay: np.ndarray  # (K,) log P(it fails), floored
    passable_label: np.ndarray  # (K,) 1.0 for labels a robot can enter
    displacement: np.ndarray  # (A, 2) rows and columns an action moves by (0, 0) if it never moves
    grid: kernels.Grid  # the model's tables the stretch kernels read; its sensor max(O, floor): a perfect
    #                     sensor's contradicted reading stays possible


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
        arguments.integer("stretch", stretch, minimum=1, maximum=MAX_STRETCH, error=InvalidOptionError)
    starts = np.append(np.arange(0, t, length), t)
    passable = (~model.blocking).astype(np.float64)
    with np.errstate(divide="ignore"):
        log_sensor = np.log(np.maximum(model.sensor, EVIDENCE_FLOOR))
        log_move = np.log(np.maximum(model.p_move * passable, EVIDENCE_FLOOR))
        log_stay = np.log(np.maximum(1.0 - model.p_move * passable, EVIDENCE_FLOOR))
    shifts, displacement = _shifted_offsets(model)
    # the offset f that reads the target is the one that reads the cell itself (offset (0, 0)) after the move
    own = model.footprint.index((0, 0)) if (0, 0) in model.footprint else -1
    ahead = shifts[:-1, own] if own >= 0 else np.full(model.n_actions, -1, dtype=np.int64)
    grid = kernels.Grid(np.maximum(model.sensor, EVIDENCE_FLOOR), passable, model.footprint_cells, model.neighbors,
                        model.predecessor, shifts, np.ascontiguousarray(ahead, dtype=np.int64), float(model.p_move),
                        bool(model.has_blocking), EVIDENCE_FLOOR)
    return _Run(np.asarray(a_seq, dtype=np.int64), np.ascontiguousarray(z_seq.reshape(t, -1), dtype=np.int64),
                starts, log_sensor, log_move, log_stay, passable, displacement, grid)


def _shifted_offsets(model: GridModel) -> tuple[np.ndarray, np.ndarray]:
    """``(g, displacement)``: g (A + 1, F) int64, ``g[a, f]`` the footprint offset of the cell
    before a move by action a that offset f reads after it (-1 if none), row A "no move" (g = f);
    displacement (A, 2) the (row, column) move of each action. Raises ModelError if an action
    moves cells by different displacements (the local maps need a translation-invariant grid).
    O(N A + F^2 A)."""
    cells = np.arange(model.n_cells)
    offsets = np.array(model.footprint, dtype=np.int64).reshape(-1, 2)
    shifts = np.full((model.n_actions + 1, len(offsets)), -1, dtype=np.int64)
    shifts[-1] = np.arange(len(offsets))
    displacement = np.zeros((model.n_actions, 2), dtype=np.int64)
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
        displacement[a] = moves[:, 0]
        after = offsets + moves[:, 0]  # offset f after the move is this offset from the cell before it
        same = (after[:, None, :] == offsets[None, :, :]).all(axis=2)  # (F, F')
        shifts[a] = np.where(same.any(axis=1), same.argmax(axis=1), -1)
    return shifts, displacement


def _stretch(model: GridModel, run: _Run, m: int) -> kernels.Stretch:
    """Stretch m's readings and actions, and the box of offsets its actions reach: each axis from
    the sum of the actions' negative moves to the sum of their positive ones. O(S + D)."""
    first, end = run.starts[m], run.starts[m + 1]
    moves = run.displacement[run.actions[first:end - 1]].reshape(-1, 2)
    low = np.minimum(moves, 0).sum(axis=0)
    high = np.maximum(moves, 0).sum(axis=0)
    height, width = high - low + 1
    rows, cols = np.divmod(np.arange(height * width), width)
    cell_shift = (rows + low[0]) * model.cols + cols + low[1]
    delta = run.displacement[:, 0] * width + run.displacement[:, 1]
    return kernels.Stretch(run.readings[first:end], run.actions[first:end - 1], cell_shift.astype(np.int64),
                           delta.astype(np.int64), int(-low[0] * width - low[1]))


def _tables(model: GridModel, run: _Run, stretch: kernels.Stretch, labels: np.ndarray,
            ratio: np.ndarray | None) -> kernels.Emissions:
    """A stretch's emissions and move probabilities under map marginals ``labels`` (N, K) and,
    unless None, the adjacent labels' ratio (K, K) for the cells a move reads first: the module
    docstring's, by :func:`onlinemap.kernels.layered.stretch_tables`. O(S N F K^2)."""
    length, n = len(stretch.readings), model.n_cells
    tables = kernels.Emissions(np.empty(n), np.ones((length, n)), np.ones((length, n)), np.zeros((length, n)))
    kernels.stretch_tables(np.ascontiguousarray(labels),
                           np.ones((model.n_labels, model.n_labels)) if ratio is None else ratio, ratio is not None,
                           *run.grid, *stretch, *tables)
    return tables


class _Forward(NamedTuple):
    """Stretch m's forward messages and its likelihood at every start."""

    f: np.ndarray  # (S, N, D) scaled per start
    log_f: np.ndarray  # (S, N)
    log_likelihood: np.ndarray  # (N,) log l_m(x)


def _forward(run: _Run, stretch: kernels.Stretch, tables: kernels.Emissions) -> _Forward:
    """The forward pass within a stretch for every start. O(S N D)."""
    length, n = len(stretch.readings), len(tables.first)
    f = np.empty((length, n, len(stretch.cell_shift)))
    log_f = np.empty((length, n))
    kernels.stretch_forward(f, log_f, *run.grid, *stretch, *tables)
    return _Forward(f, log_f, log_f[-1] + np.log(f[-1].sum(axis=1)))


def _end_cells(model: GridModel, run: _Run, m: int, stretch: kernels.Stretch, forward: _Forward,
               weight: np.ndarray, passable) -> tuple[np.ndarray, float]:
    """The distribution of stretch m + 1's start given start weights (N,) of stretch m (before its
    data), and the log of its normaliser, ``log sum_x weight[x] l_m(x)``: where stretch m ends,
    then the press across the boundary. O(N D)."""
    reachable = weight > 0
    shift = forward.log_f[-1][reachable].max()
    scaled = np.where(reachable, weight * np.exp(forward.log_f[-1] - shift), 0.0)
    ends = np.empty(model.n_cells)
    kernels.collapse(forward.f[-1], stretch.cell_shift, scaled, ends)
    total = ends.sum()
    if total <= 0 or not np.isfinite(total):
        raise ModelError(f"stretch {m} (from step {run.starts[m]}) has probability zero at every pose reachable "
                         f"from the start")
    ends /= total
    if m + 1 < len(run.starts) - 1:
        ends = apply_motion(model, ends, int(run.actions[run.starts[m + 1] - 1]), passable)
    return ends, float(np.log(total) + shift)


def _backward(run: _Run, stretch: kernels.Stretch, tables: kernels.Emissions, forward: _Forward,
              end: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The backward pass within a stretch from ``end`` (N,), the message of the cell it ends in:
    ``(b (S, N, D), log B (N,))`` with ``B(x) = P(stretch m's data and the rest | x_m = x)`` up
    to one constant. O(S N D)."""
    b = np.empty_like(forward.f)
    log_b = np.empty_like(forward.log_f)
    kernels.stretch_backward(forward.f, end, b, log_b, *run.grid, *stretch, *tables)
    with np.errstate(divide="ignore"):
        return b, np.log(tables.first * b[0, :, stretch.origin]) + log_b[0]


def _evidence(model: GridModel, run: _Run, stretch: kernels.Stretch, tables: kernels.Emissions, forward: _Forward,
              b: np.ndarray, weight: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A stretch's expected log-evidence ``E_m`` (N, K) with start weights (N,) (the tempered
    pose posterior) and the expected number of readings of each cell (N,). O(S F n D)."""
    n, k = model.n_cells, model.n_labels
    counts = kernels.Counts(np.zeros((n, k)), np.zeros(n), np.zeros(n))
    kernels.stretch_counts(forward.f, b, weight, PRUNE_BELOW, *run.grid, *stretch, *tables, *counts)
    evidence = counts.counts @ run.log_sensor.T  # counts[c, z] log O[k, z] summed over z
    if model.has_blocking:
        evidence += counts.entered[:, None] * run.log_move + counts.bumped[:, None] * run.log_stay
    return evidence, counts.counts.sum(axis=1)


def _passability(model: GridModel, run: _Run, labels: np.ndarray) -> np.ndarray | None:
    return labels @ run.passable_label if model.has_blocking else None


class _EStep(NamedTuple):
    posterior: np.ndarray  # (M, N)
    log_evidence: float
    evidence: list  # M arrays (N, K), the M-step's E_m
    reads: list  # M arrays (N,)


def _smooth(model: GridModel, run: _Run, labels_of: Callable[[int], np.ndarray], passable, tau: float,
            ratio: np.ndarray | None = None) -> _EStep:
    """Forward-backward over the stretch poses, stretch m scored under ``labels_of(m)`` (N, K)
    (and the adjacent labels' ``ratio`` (K, K) for cells first read, unless None),
    the motion across boundaries with ``passable`` (N,) (None: the paper's motion); then each
    stretch's evidence with its pose posterior tempered by ``tau``. Raises ModelError when no
    pose sequence has positive probability. Cost: the module docstring's, per iteration."""
    n_stretch = len(run.starts) - 1
    stretches = [_stretch(model, run, m) for m in range(n_stretch)]
    tables = [_tables(model, run, stretches[m], labels_of(m), ratio) for m in range(n_stretch)]
    predicted = np.empty((n_stretch, model.n_cells))
    predicted[0] = model.location_prior()
    log_evidence = 0.0
    for m in range(n_stretch):
        forward = _forward(run, stretches[m], tables[m])
        ends, log_total = _end_cells(model, run, m, stretches[m], forward, predicted[m], passable)
        log_evidence += log_total
        if m + 1 < n_stretch:
            predicted[m + 1] = ends
    posterior = np.empty_like(predicted)
    evidence, reads = [None] * n_stretch, [None] * n_stretch
    end = np.ones(model.n_cells)
    for m in range(n_stretch - 1, -1, -1):
        forward = _forward(run, stretches[m], tables[m])
        b, log_back = _backward(run, stretches[m], tables[m], forward, end)
        posterior[m] = _normalised(predicted[m], log_back)
        evidence[m], reads[m] = _evidence(model, run, stretches[m], tables[m], forward, b, temper(posterior[m], tau))
        if m > 0:
            message = np.exp(log_back - log_back[np.isfinite(log_back)].max())
            end = apply_motion_transpose(model, message, int(run.actions[run.starts[m] - 1]), passable)
    return _EStep(posterior, log_evidence, evidence, reads)


def _normalised(weight: np.ndarray, log_likelihood: np.ndarray) -> np.ndarray:
    """``weight * exp(log_likelihood)`` normalised (N,), scaled by the best weighted entry."""
    reachable = (weight > 0) & np.isfinite(log_likelihood)
    joint = np.where(reachable, weight * np.exp(log_likelihood - log_likelihood[reachable].max()), 0.0)
    return joint / joint.sum()


def localize_stretches(model: GridModel, actions, observations, labels, *, stretch: int | None = None
                       ) -> tuple[np.ndarray, float]:
    """The E-step in a given map: (M, N) ``P(x_m | data; labels)`` for the stretches of a run and
    the log evidence ``log P(data; labels)`` under the module docstring's emissions, every stretch
    scored against the same map marginals ``labels`` (N, K) (no stretch left out). With
    ``stretch=1`` this is forward-backward over the locations of the location HMM with
    observation matrix ``labels @ O``. Cost O(T N F K + T N D)."""
    run = _prepare(model, actions, observations, stretch)
    labels = np.asarray(labels, dtype=np.float64)
    if labels.shape != (model.n_cells, model.n_labels):
        raise ModelError(f"labels must have shape {(model.n_cells, model.n_labels)}, got {labels.shape}")
    fit = _smooth(model, run, lambda m: labels, _passability(model, run, labels), 1.0)
    return fit.posterior, fit.log_evidence


class _Prior(NamedTuple):
    """The label prior of a fit: fixed log frequencies, or a Dirichlet's concentrations to learn them."""

    log_prior: np.ndarray  # (N, K) the prior now
    alpha: np.ndarray | None  # (K,) with label_prior="learn"
    ratio: np.ndarray | None  # (K, K) P(l, k) / (P(l) P(k)) of adjacent cells' labels, learned with "learn"

    def update(self, model: GridModel, evidence: np.ndarray, reads: np.ndarray) -> "_Prior":
        """With ``"learn"``, from the map q under the current prior and the total evidence (N, K),
        and w_c = min(1, reads_c), reads (N,) the expected readings per cell: theta, the Dirichlet
        posterior mean given the expected labels of the cells read, ``sum_c w_c q_c``; and the
        adjacent labels' ratio from the pairs' expected counts ``sum_(c, c') w_c w_c' q_c q_c'^T``
        over neighbouring cells, with the Dirichlet's concentrations spread over the K^2 pairs
        (A / K each) as pseudo-counts. O(N A K^2) for A actions."""
        if self.alpha is None:
            return self
        labels = _softmax(self.log_prior + evidence)
        weight = np.minimum(reads, 1.0)
        theta = posterior_frequencies(self.alpha, weight @ labels)
        weighted = weight[:, None] * labels
        pairs = np.zeros((model.n_labels, model.n_labels))
        cells = np.arange(model.n_cells)
        for a in range(model.n_actions):
            moves = model.neighbors[:, a] != cells
            pairs += weighted[moves].T @ weighted[model.neighbors[moves, a]]
        pairs = pairs + pairs.T + np.add.outer(self.alpha, self.alpha) / (2 * model.n_labels)
        joint = pairs / pairs.sum()
        marginal = joint.sum(axis=1)
        return _Prior(np.broadcast_to(np.log(theta), self.log_prior.shape), self.alpha,
                      joint / np.outer(marginal, marginal))


def _label_prior(model: GridModel, label_prior, prior_strength) -> _Prior:
    resolved = resolve_label_prior(model.n_labels, label_prior, prior_strength)
    shape = (model.n_cells, model.n_labels)
    with np.errstate(divide="ignore"):
        if resolved.kind == "model":
            return _Prior(np.log(model.label_prior), None, None)
        if resolved.kind == "fixed":
            return _Prior(np.broadcast_to(np.log(resolved.frequencies), shape), None, None)
    return _Prior(np.broadcast_to(np.log(resolved.alpha / resolved.alpha.sum()), shape), resolved.alpha, None)


def _sweep(model: GridModel, run: _Run, prior: _Prior, tau: float, learn: bool) -> tuple[list, list, _Prior]:
    """The forward sweep's local maps: stretch m localised (filtered, and smoothed within the
    stretch) against the map of stretches 0..m-1 and placed by its tempered filtered posterior;
    with ``learn`` the learned prior re-estimated after each stretch, else held. O(T N F K^2 + T N D)."""
    total, read = np.zeros((model.n_cells, model.n_labels)), np.zeros(model.n_cells)
    evidence, reads = [], []
    predicted = model.location_prior()
    ones = np.ones(model.n_cells)
    for m in range(len(run.starts) - 1):
        labels = _softmax(prior.log_prior + total)
        stretch = _stretch(model, run, m)
        tables = _tables(model, run, stretch, labels, prior.ratio)
        forward = _forward(run, stretch, tables)
        filtered = _normalised(predicted, forward.log_likelihood)
        b, _ = _backward(run, stretch, tables, forward, ones)
        local, count = _evidence(model, run, stretch, tables, forward, b, temper(filtered, tau))
        evidence.append(local)
        reads.append(count)
        total += local
        read += count
        if learn:
            prior = prior.update(model, total, read)
        predicted, _ = _end_cells(model, run, m, stretch, forward, predicted,
                                  _passability(model, run, _softmax(prior.log_prior + total)))
    return evidence, reads, prior


class _Fit(NamedTuple):
    """One EM fit in progress."""

    evidence: list  # M arrays (N, K)
    reads: list  # M arrays (N,)
    prior: _Prior
    log_likelihoods: list  # float per E-step so far
    posterior: np.ndarray | None  # (M, N) the last E-step's


def _iterate(model: GridModel, run: _Run, fit: _Fit, schedule: Anneal | None, first: int, last: int) -> _Fit:
    """EM iterations ``first .. last - 1`` (the annealing schedule's temperatures 1 + iteration)."""
    evidence, reads, prior = fit.evidence, fit.reads, fit.prior
    log_likelihoods, posterior = list(fit.log_likelihoods), fit.posterior
    total = np.sum(evidence, axis=0)
    for iteration in range(first, last):
        passable = _passability(model, run, _softmax(prior.log_prior + total))
        step = _smooth(model, run, lambda m: _softmax(prior.log_prior + total - evidence[m]), passable,
                       1.0 if schedule is None else schedule.tau(iteration + 1), prior.ratio)
        log_likelihoods.append(step.log_evidence)
        evidence, reads, posterior = step.evidence, step.reads, step.posterior
        total = np.sum(evidence, axis=0)
        prior = prior.update(model, total, np.sum(reads, axis=0))
    return _Fit(evidence, reads, prior, log_likelihoods, posterior)


def _check_starts(starts) -> tuple[float, ...]:
    if isinstance(starts, (str, bytes)) or not isinstance(starts, (tuple, list, np.ndarray)) or len(starts) == 0:
        raise InvalidOptionError(f"starts must be a non-empty sequence of sweep temperatures, got {starts!r}")
    values = tuple(arguments.real(f"starts[{i}]", x, error=InvalidOptionError) for i, x in enumerate(starts))
    if not all(0 < x <= 1 for x in values):
        raise InvalidOptionError(f"starts are sweep temperatures in (0, 1], got {starts!r}")
    return values


def fit_layered_map(model: GridModel, actions, observations, *, stretch: int | None = None, n_iter: int = 8,
                    anneal=DEFAULT_ANNEAL, label_prior=None, prior_strength=None,
                    starts=DEFAULT_STARTS) -> LayeredMap:
    """Layered EM on a recorded run (actions (T - 1,), observations (T,) or (T, F), by index or
    name): the module docstring's algorithm, ``n_iter`` E- and M-steps after the forward sweep.

    ``stretch``: steps per local map, 1..:data:`MAX_STRETCH` (None: :func:`default_stretch` of
    the model's p_move); ``anneal``: None or ``(tau0, rate, tau_min)`` as offline EM's
    (:class:`Anneal`), the E-step of iteration i at tau(i + 1); ``label_prior``,
    ``prior_strength``: as the estimators' (:mod:`onlinemap.label_prior`): None the model's
    prior, a (K,) vector, or ``"learn"`` (learned from a first sweep at ``starts[0]``, then in
    every M-step). ``starts``: the temperatures in (0, 1] of the forward sweeps EM starts from
    (each stretch placed by its filtered pose posterior to the power 1/t: 1 spreads it, small t
    places it at its most likely pose); each start runs :data:`SELECT_AFTER` iterations, and the
    one with the highest log-likelihood continues (a start that loses the robot explains the
    readings worse). Raises InvalidOptionError for bad options and ModelError for a dynamic
    world. Cost: the module docstring's per iteration, ``len(starts) (1 + SELECT_AFTER) +
    n_iter - SELECT_AFTER`` iterations (one more with ``"learn"``).
    """
    run = _prepare(model, actions, observations, stretch)
    n_iter = check_n_iter(n_iter)
    schedule = check_anneal(anneal)
    starts = _check_starts(starts)
    prior = _label_prior(model, label_prior, prior_strength)
    if prior.alpha is not None:  # what a first sweep learns of the labels, from the start of the run on
        _, _, prior = _sweep(model, run, prior, starts[0], True)
    selected = min(n_iter, SELECT_AFTER)
    fits = [_iterate(model, run, _Fit(*_sweep(model, run, prior, tau, False)[:2], prior, [], None), schedule, 0,
                     selected) for tau in starts]
    best = _iterate(model, run, max(fits, key=lambda fit: fit.log_likelihoods[-1]), schedule, selected, n_iter)
    labels = _softmax(best.prior.log_prior + np.sum(best.evidence, axis=0))
    return LayeredMap(labels, np.array(best.evidence), best.posterior, run.starts[:-1].copy(),
                      np.array(best.log_likelihoods), np.exp(best.prior.log_prior).mean(axis=0))
