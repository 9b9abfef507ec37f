"""The RBPF's label prior (the options ``label_prior``, ``prior_strength``, ``learn_every``;
:mod:`onlinemap.label_prior` for their meaning and the hierarchical model).

In a static world every stored cell marginal of every particle is

    b_i(k) = normalise_k( prior_i(k) w(k) prod_s l_s(k) ),

the model's prior of the cell ``prior_i`` (N, K), a frequency weight ``w`` (K,) shared by every
cell (with ``"context"`` each cell's own ``w_i``), times the likelihoods of the readings (and
failed presses) that particle's path made of the cell. Changing ``w`` to ``w'`` for every cell,
read or not, is therefore one pass over the block rows in use: ``rows <- normalise(rows * w' /
w)`` along K (:func:`retilt`; per cell, each slot of a row by its cell's ratio). A row shared
by many particles is rescaled once, which is right: it is the same marginal in each of them.
The kernels are not touched.

- A fixed vector ``v`` (K,): ``w = v``, applied once to the rows of a new filter. The prior of
  a cell is then ``normalise(prior_i * v)``: ``v`` itself when the model's prior is uniform (the
  default), a tilt of the model's per-cell prior otherwise. Sound in a dynamic world too (the
  rows are tilted at the start, before C acts).
- ``"learn"`` (also ``None`` on a model whose label frequencies are unknown, a building, where
  the filter can learn: a static world): ``w = pi_t``, the current estimate of the label frequencies, from
  ``pi_0 = alpha / A`` (uniform: the rows of a new filter as they are). Every ``learn_every``
  steps (default :data:`~onlinemap.label_prior.DEFAULT_LEARN_EVERY`), after the update, :func:`learn` takes the weighted mixture m (N, K) of the particles'
  maps, the cells *read* (those whose mixture differs from the marginal of an unread cell,
  ``normalise(prior_i * pi_t)``, by more than :data:`~onlinemap.label_prior.READ_TOLERANCE`), the expected counts
  ``c = sum of m over the read cells`` and the Dirichlet posterior mean
  ``pi' = (alpha + c) / (A + n_read)`` (:func:`~onlinemap.label_prior.posterior_frequencies`),
  and retilts the pool by ``pi' / pi_t``. This is the plug-in (empirical Bayes) approximation of
  the hierarchical model: every cell's prior is the posterior mean of theta, the particles'
  weights are not changed (the evidence of the past readings under the new prior is not
  recomputed), and a cell read by some particles only counts with its whole mixture (a slight
  pull towards pi_t). The exact filter with ``label_prior="learn"`` computes the hierarchical
  posterior exactly on tiny worlds: the reference. Static worlds only (a dynamic world's rows
  hold marginals of different ages, which one rescaling does not move consistently).

- ``"context"`` (static grid worlds; :mod:`onlinemap.label_prior` for the rule): ``w_i = v_i``,
  every cell's own tilt (N, K), from ``v_0 = pi_0`` for every cell. Every ``learn_every`` steps,
  where ``"learn"`` learns, :func:`learn_context_in_pool` takes the same mixture m, finds the cells read
  (those whose mixture differs from their own unread marginal ``normalise(prior_i * v_i)``),
  freezes the neighbour context of those read for the first time (from the cells read before
  this step), learns pi as ``"learn"`` does and every cell's tilt ``v_i' = (n[c_i] + K pi) /
  (sum n[c_i] + K)`` from the summed mixtures ``n`` of the read cells per context
  (:func:`~onlinemap.label_prior.learn_context`), and retilts the pool cell by cell by
  ``v' / v``. The same plug-in: the contexts come from the population's mixture, not each
  particle's own map, and the weights are not changed.

Limits: a recovery from depletion resets the cells it redraws to the model's prior (not the
tilted one) until the next retilt moves them with the rest. The resample-move step
(``move_window``) keeps the tilt: its map without the window is the stored marginal with the
window's readings divided out (w stays in it), or rebuilt as ``prior_i w prod f`` with the
current w (``w_i`` per cell with ``"context"``: :func:`~onlinemap.estimators.rbpf_move.map_evidence`
takes the (N, K) tilt).

Cost: a retilt is O(R_used B K) (numpy, memory speed; per cell it also gathers each row's ratios,
one more (R_used, B, K) array); a learning step adds the mixture, O(P N / B) plus one pass over
the rows in use, and O(N K) (``"context"``: a few passes over (N, K) and N codes): about the cost
of building ``belief.map`` once.
"""

from __future__ import annotations

import numpy as np

from ..errors import InvalidOptionError
from ..label_prior import (CONTEXT, LEARN, ContextState, LabelPrior, fresh_context, learn_context,
                           learned_frequencies, neighbour_table, plug_in_prior, tilt)
from ..model import GridModel
from .block_pool import BlockPool


def prior_options(model: GridModel, label_prior, prior_strength, learn_every) -> LabelPrior:
    """Check and resolve the RBPF's label-prior options (:func:`~onlinemap.label_prior.plug_in_prior`,
    ``"context"`` included; ``move_window`` goes with every one of them: the move keeps the tilt
    w). Raises :class:`~onlinemap.errors.InvalidOptionError` naming the problem. O(N K)."""
    return plug_in_prior(model, label_prior, prior_strength, learn_every, context=True)


def resolved_prior(model: GridModel, options: dict) -> LabelPrior:
    """The label prior a filter's ``options`` (checked when it was built) give. O(N K)."""
    return prior_options(model, options.get("label_prior"), options.get("prior_strength"),
                         options.get("learn_every"))


def retilt(pool: BlockPool, ratio: np.ndarray) -> None:
    """Multiply every slot of the block rows in use by ``ratio`` and renormalise along K, in
    place: the pool's maps with every cell's prior frequencies changed by that ratio (the module
    docstring); ``ratio`` (K,) for every cell alike, or (N, K) each cell's own (``"context"``: a
    row of block b takes the ratios of its cells ``pool.block_members[b]``, padding slots 1).
    Free rows are left alone (they may hold zeros; nothing reads them). O(R_used B K) (+ O(N K)
    for a per-cell ratio)."""
    used = np.flatnonzero(pool.refcount > 0)
    if ratio.ndim == 2:
        members = pool.block_members  # (blocks, B) cells, -1 padding
        per_block = np.where(members[..., None] >= 0, ratio[np.maximum(members, 0)], 1.0)  # (blocks, B, K)
        ratio = per_block[pool.row_block[used]]
    pool.rows[used] = tilt(pool.rows[used], ratio)


def _mixture_map(pool: BlockPool, t: int, weights: np.ndarray, threads: int) -> np.ndarray:
    """(N, K) the particles' mixture map at step ``t`` (``weights`` (P,), normalised), rows
    normalised. O(P N / B) plus one pass over the rows in use."""
    mixture = pool.mixture(t, weights, threads)
    return mixture / mixture.sum(axis=1, keepdims=True)


def learn(pool: BlockPool, model: GridModel, t: int, weights: np.ndarray, frequencies: np.ndarray,
          alpha: np.ndarray, threads: int = 1) -> np.ndarray:
    """One learning step of ``label_prior="learn"`` (the module docstring): the new frequencies
    pi' (K,) from the particles' mixture at step ``t`` (``weights`` (P,), normalised) and the
    current ``frequencies`` pi_t (K,); retilts ``pool`` by ``pi' / pi_t`` in place. Returns pi'.
    O(P N / B + R_used B K + N K)."""
    mixture = _mixture_map(pool, t, weights, threads)
    updated = learned_frequencies(mixture, model.label_prior, frequencies, alpha)
    retilt(pool, updated / frequencies)
    return updated


def start_prior(est, prior: LabelPrior) -> None:
    """Set up the label prior of a new RBPF ``est`` (its pool holds the model's prior): a fixed
    vector retilts the rows once; ``"learn"`` and ``"context"`` start from ``pi_0 = alpha / A``
    (uniform: the rows as they are), ``"context"`` with every cell's tilt pi_0 and nothing read
    (:func:`~onlinemap.label_prior.fresh_context`). The model's prior: nothing. O(R B K)."""
    if prior.kind == "fixed":
        retilt(est._blocks, prior.frequencies)
    elif prior.kind in (LEARN, CONTEXT):
        est._label_frequencies = prior.alpha / prior.alpha.sum()
        if prior.kind == CONTEXT:
            est._context_tilts, est._context_read, est._context_frozen, _ = fresh_context(
                est.model.n_cells, est._label_frequencies)


def current_tilt(est) -> np.ndarray | None:
    """The tilt every stored marginal of the RBPF ``est`` carries (the resample-move's prior): its
    per-cell tilts (N, K) with ``"context"``, its frequencies (K,) with ``"learn"`` or a vector,
    None without a label prior. O(K)."""
    return est.label_frequencies if est._context_tilts is None else est._context_tilts


def learn_prior(est, t: int, threads: int = 1) -> None:
    """The learning step at step ``t`` of the RBPF ``est`` with ``label_prior="learn"``
    (:func:`learn`) or ``"context"`` (:func:`learn_context_in_pool`): its pool retilted and its label
    prior state replaced, in place. O(P N / B + R_used B K + N K)."""
    pool, model, weights = est._blocks, est.model, est._weights / est._weights.sum()
    alpha = resolved_prior(model, est.options).alpha
    if est._context_tilts is None:
        est._label_frequencies = learn(pool, model, t, weights, est._label_frequencies, alpha, threads)
        return
    context = ContextState(est._context_tilts, est._context_read, est._context_frozen, est._label_frequencies)
    est._context_tilts, est._context_read, est._context_frozen, est._label_frequencies = learn_context_in_pool(
        pool, model, t, weights, context, neighbour_table(model), alpha, threads)


def learn_context_in_pool(pool: BlockPool, model: GridModel, t: int, weights: np.ndarray, state: ContextState,
                          table: np.ndarray, alpha: np.ndarray, threads: int = 1) -> ContextState:
    """One learning step of ``label_prior="context"`` (the module docstring): the new state
    (:func:`~onlinemap.label_prior.learn_context`) from the particles' mixture at step ``t``
    (``weights`` (P,), normalised), the current ``state``, the neighbours ``table`` (N, 4) and
    ``alpha`` (K,); retilts ``pool`` cell by cell by ``v' / v`` in place. Returns the new state.
    O(P N / B + R_used B K + N K)."""
    mixture = _mixture_map(pool, t, weights, threads)
    updated = learn_context(mixture, model.label_prior, state, table, alpha)
    retilt(pool, updated.tilts / state.tilts)
    return updated
