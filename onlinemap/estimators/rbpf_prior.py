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
  particle's own map, and the weights are not changed. With the option ``context_table`` (a
  :class:`~onlinemap.label_prior.ContextTable`, :func:`pretrained_counts`) its pseudo-counts T
  join n in every context's predictive, ``(n[c_i] + T[c_i] + K pi) / (sum (n + T)[c_i] + K)``,
  from the first learning step on (right after step 0).

- ``"particle_context"`` (static grid worlds; not with ``move_window``): the same learning step
  (:func:`learn_particle_context`) on the cells most of the weight has read (per-particle
  statuses, not the mixture: a cell tilted but not read is not evidence) gives pi' (the pool
  retilted by ``pi' / pi`` as ``"learn"``) and the tempered table of ratios ``v'[c] / pi``. Each
  particle p's stored marginal of a cell i it tilted is then ``normalise(prior_i pi r_pi prod
  f)``, with ``r_pi`` the ratio of i's context in p's own map when p tilted it: before step t,
  :func:`tilt_step_cells` multiplies in ``r`` for each live particle's untouched cells of the
  footprint of the cell the action points at (numba, copy-on-write writes, logged), and
  :func:`untilt` takes them back if the step raises; after it, :func:`mark_read` carries the
  statuses (P, N) through the genealogy and marks the cells read. The weights then see the
  tilted prior: the evidence of a reading is computed against it. Cost: O(P F K + M B K) a step
  for M cells tilted (each new cell once per lineage), O(P_copied N) to carry the statuses, and
  O(P N) more per learning step; memory P N bytes. A ``context_table`` joins the learned counts
  as with ``"context"``, before the tempering.

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

import functools
from contextlib import contextmanager
from typing import NamedTuple

import numpy as np

from ..errors import InvalidOptionError
from ..kernels.rbpf_context import (TiltLog, context_mark_read, context_tilt, context_tilt_count, context_untilt,
                                    read_weight, tilt_log)
from .. import arguments
from ..buildings import building
from ..label_prior import (CONTEXT, CONTEXT_KINDS, LEARN, PARTICLE_CONTEXT, ContextState, ContextTable, LabelPrior,
                           context_table, context_weight, fresh_context, learn_context, learn_context_ratios,
                           learned_frequencies, neighbour_table, plug_in_prior, tilt)
from ..model import GridModel
from .block_pool import BlockPool

#: ``context_table`` by name: "buildings", the table of the generated 32 x 32 buildings of
#: :data:`BUILDING_TABLE_SEEDS` (:func:`named_table`), for floors of the same four labels
NAMED_TABLES = ("buildings",)
#: the generated buildings (32 x 32) the named table "buildings" is counted on: seeds no study or
#: page of the project maps (they use 0-19)
BUILDING_TABLE_SEEDS = range(20, 30)


@functools.cache
def named_table(name: str) -> ContextTable:
    """The :class:`~onlinemap.label_prior.ContextTable` a ``context_table`` name stands for:
    ``"buildings"``, :func:`~onlinemap.label_prior.context_table` of the generated 32 x 32
    buildings of :data:`BUILDING_TABLE_SEEDS` at its default strength (100): what the walls,
    rooms and doors of generated buildings look like from every side. Built once per process
    (about 0.2 s). O(16 x 10 x 1024 K)."""
    arguments.choice("context_table", name, NAMED_TABLES, error=InvalidOptionError)
    return context_table(building(32, 32, seed=seed) for seed in BUILDING_TABLE_SEEDS)


def given_table(table):
    """The ``context_table`` option as a table: a name of :data:`NAMED_TABLES` resolved by
    :func:`named_table` (an unknown one: :class:`~onlinemap.errors.InvalidOptionError`), anything
    else as given (None, a :class:`~onlinemap.label_prior.ContextTable`, or what
    :func:`prior_options` refuses). O(1) once a name is built."""
    return named_table(table) if isinstance(table, str) else table


def prior_options(model: GridModel, label_prior, prior_strength, learn_every, weight=None,
                  move_window: int | None = None, table=None) -> LabelPrior:
    """Check and resolve the RBPF's label-prior options (:func:`~onlinemap.label_prior.plug_in_prior`,
    ``"context"`` and ``"particle_context"`` included), ``context_weight`` (``weight``, given
    only with ``"particle_context"``, :func:`~onlinemap.label_prior.context_weight`) and
    ``context_table`` (``table``, given only with a context prior: a
    :class:`~onlinemap.label_prior.ContextTable` of the model's K labels, or a name of
    :data:`NAMED_TABLES`, :func:`named_table`).
    ``move_window`` goes with every prior but ``"particle_context"`` (the move keeps one tilt w
    for every particle; that prior tilts each particle's cells its own way, which a rebuilt map
    would lose). Raises :class:`~onlinemap.errors.InvalidOptionError` naming the problem. O(N K)."""
    prior = plug_in_prior(model, label_prior, prior_strength, learn_every, context=True)
    if prior.kind == PARTICLE_CONTEXT:
        context_weight(weight)
        if move_window is not None:
            raise InvalidOptionError("move_window (resample-move) rebuilds a particle's map with one prior tilt for "
                                     "every particle; label_prior='particle_context' tilts each particle's cells by "
                                     "their context in its own map, which the rebuilt map would lose: use "
                                     "label_prior='context' or 'learn' with move_window")
    elif weight is not None:
        raise InvalidOptionError(f"context_weight is the weight of label_prior='particle_context''s context table; "
                                 f"it means nothing with label_prior={label_prior!r}")
    if table is not None:
        if prior.kind not in CONTEXT_KINDS:
            raise InvalidOptionError(f"context_table holds pseudo-counts of the neighbour contexts of "
                                     f"label_prior='context' or 'particle_context'; it means nothing with "
                                     f"label_prior={label_prior!r}")
        table = given_table(table)
        if not isinstance(table, ContextTable):
            raise InvalidOptionError(f"context_table must be a ContextTable (label_prior.context_table) or one of "
                                     f"{NAMED_TABLES}, got {type(table).__name__}")
        if table.n_labels != model.n_labels:
            raise InvalidOptionError(f"context_table counts {table.n_labels} labels, the model has {model.n_labels}")
    return prior


def context_neighbours(model: GridModel, label_prior) -> np.ndarray | None:
    """(N, 4) the grid's neighbour table (:func:`~onlinemap.label_prior.neighbour_table`) that
    ``label_prior`` (the option as given) ``"context"`` or ``"particle_context"`` reads at every
    learning step and every tilt; None with any other prior. Made once per filter, in its step kit
    (``RaoBlackwellisedPF._kit``): derived from the model, not state, so no checkpoint holds it. O(N)."""
    return neighbour_table(model) if isinstance(label_prior, str) and label_prior in CONTEXT_KINDS else None


def resolved_prior(model: GridModel, options: dict) -> LabelPrior:
    """The label prior a filter's ``options`` (checked when it was built) give. O(N K)."""
    return prior_options(model, options.get("label_prior"), options.get("prior_strength"),
                         options.get("learn_every"), options.get("context_weight"), table=options.get("context_table"))


def pretrained_counts(est) -> np.ndarray | None:
    """((K + 2)^4, K) the pseudo-counts of the RBPF ``est``'s ``context_table`` option
    (:attr:`~onlinemap.label_prior.ContextTable.counts`, read-only), None without it. O(1)."""
    table = given_table(est.options.get("context_table"))
    return None if table is None else table.counts


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
    (:func:`~onlinemap.label_prior.fresh_context`), ``"particle_context"`` with no cell of any
    particle read or tilted and no table yet. The model's prior: nothing. O(R B K + P N)."""
    if prior.kind == "fixed":
        retilt(est._blocks, prior.frequencies)
    elif prior.kind in (LEARN, CONTEXT, PARTICLE_CONTEXT):
        est._label_frequencies = prior.alpha / prior.alpha.sum()
        if prior.kind != LEARN:
            est._context_tilts, est._context_read, est._context_frozen, _ = fresh_context(
                est.model.n_cells, est._label_frequencies)
        if prior.kind == PARTICLE_CONTEXT:  # no table before the first learning step: nothing tilted
            est._context_tilts = est._context_ratios = None
            est._particle_cells = np.zeros((est.n_particles, est.model.n_cells), dtype=np.uint8)


def current_tilt(est) -> np.ndarray | None:
    """The tilt every stored marginal of the RBPF ``est`` carries (the resample-move's prior): its
    per-cell tilts (N, K) with ``"context"``, its frequencies (K,) with ``"learn"`` or a vector,
    None without a label prior. O(K)."""
    return est.label_frequencies if est._context_tilts is None else est._context_tilts


def learn_prior(est, t: int, threads: int = 1) -> None:
    """The learning step at step ``t`` of the RBPF ``est`` with ``label_prior="learn"``
    (:func:`learn`), ``"context"`` (:func:`learn_context_in_pool`) or ``"particle_context"``
    (:func:`learn_particle_context`): its pool retilted and its label prior state replaced, in
    place. O(P N / B + R_used B K + N K) (+ O(P N) for ``"particle_context"``)."""
    pool, model, weights = est._blocks, est.model, est._weights / est._weights.sum()
    alpha = resolved_prior(model, est.options).alpha
    if est._particle_cells is not None:
        learn_particle_context(est, t, weights, alpha, threads)
        return
    if est._context_tilts is None:
        est._label_frequencies = learn(pool, model, t, weights, est._label_frequencies, alpha, threads)
        return
    context = ContextState(est._context_tilts, est._context_read, est._context_frozen, est._label_frequencies)
    est._context_tilts, est._context_read, est._context_frozen, est._label_frequencies = learn_context_in_pool(
        pool, model, t, weights, context, est._kit.neighbours, alpha, threads, pretrained_counts(est))


def learn_context_in_pool(pool: BlockPool, model: GridModel, t: int, weights: np.ndarray, state: ContextState,
                          table: np.ndarray, alpha: np.ndarray, threads: int = 1,
                          pretrained: np.ndarray | None = None) -> ContextState:
    """One learning step of ``label_prior="context"`` (the module docstring): the new state
    (:func:`~onlinemap.label_prior.learn_context`) from the particles' mixture at step ``t``
    (``weights`` (P,), normalised), the current ``state``, the neighbours ``table`` (N, 4),
    ``alpha`` (K,) and the ``context_table``'s ``pretrained`` counts (or None); retilts ``pool``
    cell by cell by ``v' / v`` in place. Returns the new state. O(P N / B + R_used B K + N K)."""
    mixture = _mixture_map(pool, t, weights, threads)
    updated = learn_context(mixture, model.label_prior, state, table, alpha, pretrained)
    retilt(pool, updated.tilts / state.tilts)
    return updated


def learn_particle_context(est, t: int, weights: np.ndarray, alpha: np.ndarray, threads: int = 1) -> None:
    """One learning step of ``label_prior="particle_context"`` at step ``t`` (the module
    docstring), in place: the cells read by most of the weight (``weights`` (P,), normalised)
    join the population's read cells, the frequencies pi' and the tempered table of ratios are
    learned from the mixture (:func:`~onlinemap.label_prior.learn_context_ratios`), and the pool is
    retilted by ``pi' / pi`` (every cell, tilted or not: a tilted cell keeps its ratio).
    O(P N + P N / B + R_used B K + N K + (K + 2)^4 K)."""
    pool, model = est._blocks, est.model
    mixture = _mixture_map(pool, t, weights, threads)
    read = np.zeros(model.n_cells)
    read_weight(est._particle_cells, weights, read)
    state = ContextState(None, est._context_read, est._context_frozen, est._label_frequencies)
    state, est._context_ratios = learn_context_ratios(mixture, state, read > 0.5, est._kit.neighbours, alpha,
                                                      context_weight(est.options.get("context_weight")),
                                                      pretrained_counts(est))
    retilt(pool, state.frequencies / est._label_frequencies)
    est._context_read, est._context_frozen, est._label_frequencies = state.read, state.frozen, state.frequencies


class ContextUndo(NamedTuple):
    """What :func:`tilt_step_cells` wrote, to take it back (:func:`untilt`): its writes logged in
    ``log`` (:class:`~onlinemap.kernels.rbpf_context.TiltLog`), ``pool`` the pool written (the
    filter's, or its grown copy) and ``previous`` the filter's pool before."""

    log: TiltLog
    pool: BlockPool
    previous: BlockPool


@contextmanager
def particle_context_step(est, t: int, action: int | None):
    """Around step ``t`` of the RBPF ``est``: with ``label_prior="particle_context"``, tilt the
    cells the step may read first (:func:`tilt_step_cells`), take the tilts back if the step
    raises (:func:`untilt`: the filter as it was), and mark the cells read once it is taken
    (:func:`mark_read`). Yields the function the step calls with its ancestors (P,). Without that
    prior: nothing. O(P F K + M B K + P_copied N)."""
    if est._particle_cells is None:
        yield _taken
        return
    undo = None if action is None else tilt_step_cells(est, t, action, est._kit.width * est.n_particles)
    parents, taken = est._locations.copy(), []
    try:
        yield taken.append
    except BaseException:
        if undo is not None:  # the step changed nothing else
            untilt(est, undo)
        raise
    mark_read(est, taken[0], parents, action)


def _taken(ancestors: np.ndarray) -> None:
    """A step's ancestors, where nothing needs them."""


def tilt_step_cells(est, t: int, action: int, need: int) -> ContextUndo | None:
    """Before step ``t`` of the RBPF ``est`` with ``label_prior="particle_context"`` (and a table,
    after its first learning step): tilt every live particle's untouched cells the step may read
    (the footprint of the cell ``action`` points at) by their context in the particle's map
    (:func:`~onlinemap.kernels.rbpf_context.context_tilt`). The pool is first reserved for the
    writes and the step's ``need`` rows (``est._reserved``: a
    :class:`~onlinemap.errors.MemoryLimitError` there changes nothing). Returns the undo, or None
    when nothing was written. O(P F K + M B K) for M writes."""
    status, ratios, model = est._particle_cells, est._context_ratios, est.model
    if ratios is None:
        return None
    targets, footprint = model.moves[action], model.footprint_cells
    count = context_tilt_count(est._locations, est._weights, targets, footprint, status)
    if count == 0:
        return None
    previous = est._blocks
    blocks = est._reserved(t, count + need)
    log = tilt_log(count, model.n_labels)
    context_tilt(t, est._locations, est._weights, targets, footprint, est._kit.neighbours, status, ratios,
                 np.empty(model.n_labels), *log, *blocks.arrays())
    est._blocks = blocks
    return ContextUndo(log, blocks, previous)


def untilt(est, undo: ContextUndo) -> None:
    """Take back :func:`tilt_step_cells`'s writes (a step that raised after them): the pool's rows
    in use, table and counts and the particles' cell statuses as before, the filter's pool the
    one it had. O(M K)."""
    context_untilt(len(undo.log.particle), est._particle_cells, *undo.log, *undo.pool.arrays())
    est._blocks = undo.previous


def mark_read(est, ancestors: np.ndarray, parents: np.ndarray, action: int | None) -> None:
    """After a step of the RBPF ``est`` with ``label_prior="particle_context"``: each slot takes its
    ancestor's cell statuses (``ancestors`` (P,), sources keeping their own slot), then marks
    :data:`~onlinemap.kernels.rbpf_context.READ` the footprint of its location and, with
    blocking labels, the cell its parent's move pressed into (``parents`` (P,), the locations
    before the step; not after a recovery, whose relocated children pressed nothing)
    (:func:`~onlinemap.kernels.rbpf_context.context_mark_read`). O(P F + P_copied N)."""
    model = est.model
    if model.has_blocking and action is not None and not est._recovered:
        pressed = model.moves[action][parents[ancestors]]
    else:
        pressed = np.full(len(ancestors), -1, dtype=np.int64)
    context_mark_read(est._particle_cells, ancestors, est._locations, model.footprint_cells, pressed)
