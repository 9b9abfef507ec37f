"""The RBPF's memory guard (option ``max_bytes`` of :class:`~onlinemap.estimators.rbpf.RaoBlackwellisedPF`):
what the filter takes, in bytes, counted without allocating, and the checks that refuse a start,
a step that grows the pools or a recovery beyond the limit with
:class:`~onlinemap.errors.MemoryLimitError` (the filter then unchanged).

Measured: 580-710 bytes per particle on the 10 x 10 door world, 2.8 KB on 64 x 64. Every
function here is O(1).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..errors import MemoryLimitError
from ..model import GridModel
from .block_pool import BlockPool, block_shape, pool_bytes
from .rbpf_move import (PathHistory, map_rows_per_move, move_scratch_bytes, new_history_bytes, path_rows_per_move,
                        rebuilds)


class Sizing(NamedTuple):
    """What the guard needs of a filter: its model, P, ``lazy_dynamics``, threads, ``max_bytes``
    and ``fixed_bytes``, what it holds beside its pool whatever the step (``label_prior=
    "particle_context"``'s P N cell statuses)."""

    model: GridModel
    n_particles: int
    lazy_dynamics: bool
    threads: int
    max_bytes: int | float
    fixed_bytes: int = 0


def cells_written(model: GridModel) -> int:
    """W, the most cells one particle's map changes in a step: the F read cells, plus the intended
    cell of a move with blocking labels (its success or failure tells about it)."""
    return model.n_readings + int(model.has_blocking)


def recovery_bytes(model: GridModel, n_particles: int) -> int:
    """Bytes a step that recovers from depletion takes on top of the filter's: the N P children's
    weights, the order the optimal resampling walks them and, at worst, its sort (32 N P)."""
    return 32 * model.n_cells * n_particles


def state_bytes(model: GridModel, n_particles: int, block_size: int, n_blocks: int, rows: int, old_rows: int = 0,
                lazy_dynamics: bool = True, threads: int = 1) -> int:
    """Bytes of the filter with a pool of ``rows`` block rows of ``block_size`` cells (``old_rows``
    more while a smaller pool is copied into it): the pool (:func:`~onlinemap.estimators.block_pool.pool_bytes`),
    a fresh copy of the rows for eager dynamics, and a step's buffers (children, weights, the
    parallel commit's staging, the belief)."""
    n, k, p = model.n_cells, model.n_labels, n_particles
    stamped = lazy_dynamics and not model.is_static
    eager = 0 if lazy_dynamics or model.is_static else rows * block_size * k * 8
    width = cells_written(model)
    per_step = 8 * p * (width * (k + 1) * 3 + k + 8) + 8 * n * k + 8 * rows  # children, weights, belief, row weights
    staged = 8 * p * (3 * width + 1 + width * k) if threads > 1 else 0
    return pool_bytes(model, p, block_size, n_blocks, rows + old_rows, stamped) + eager + per_step + staged


def peak_bytes(model: GridModel, n_particles: int, block_cells: int | None = None, lazy_dynamics: bool = True,
               threads: int = 1) -> int:
    """Worst-case peak memory of the filter, in bytes (exact Python ints; allocates nothing): every
    particle owning every one of its map blocks, the block pool grown by doubling to hold them
    plus the rows a step writes (old and new pool alive together while it grows), a fresh copy
    of the pool for eager dynamics, the table, the powers of C and a step's buffers
    (:func:`state_bytes`), and the N P children of a step that recovers from depletion
    (:func:`recovery_bytes`). Particles share most blocks (measured: 1.2-5 rows per particle,
    against ``n_blocks`` here), so runs stay far below it; the filter's guard (``max_bytes``)
    checks the memory it actually takes instead, when it starts, whenever its pool grows and
    before a recovery."""
    size, n_blocks = block_shape(model, block_cells)
    rows = n_blocks + 2 * n_particles
    while rows - cells_written(model) * n_particles < n_blocks * n_particles:  # doubled until every particle
        rows *= 2  # can own every block, with the rows a step writes to spare
    return (state_bytes(model, n_particles, size, n_blocks, rows, rows // 2, lazy_dynamics, threads)
            + recovery_bytes(model, n_particles))


def check_start(sizing: Sizing, block_cells: int | None, move_window: int | None) -> None:
    """Refuse a filter whose first pool (every particle sharing one row per block, 2P rows to
    spare), buffers and, with ``move_window``, path history and a move's scratch exceed
    ``max_bytes``."""
    model, p, lazy, threads, limit, fixed = sizing
    size, n_blocks = block_shape(model, block_cells)
    need = state_bytes(model, p, size, n_blocks, n_blocks + 2 * p, 0, lazy, threads) + fixed
    need += 0 if move_window is None else new_history_bytes(model, p) + move_scratch_bytes(model, move_window)
    if need > limit:
        raise MemoryLimitError(
            f"rbpf with {p} particles on N={model.n_cells} cells, K={model.n_labels} labels needs "
            f"{need / 1e9:.3g} GB to start (its pool of map blocks, the particle table, a step's buffers"
            f"{'' if move_window is None else ', the path history of move_window'}) but the limit is "
            f"{limit / 1e9:.3g} GB; pass max_bytes=... to raise it (a run may need up to "
            f"{peak_bytes(model, p, block_cells, lazy, threads) / 1e9:.3g} GB, if every "
            f"particle came to own every map block)")


def check_growth(sizing: Sizing, pool: BlockPool, t: int, rows: int, history_bytes: int | None,
                 history_grows: bool) -> None:
    """Refuse step t when the pool must grow from its rows to ``rows`` or the path history must grow
    (to ``history_bytes`` in all; None: no history) and the filter would then exceed
    ``max_bytes``."""
    model, p, lazy, threads, limit, fixed = sizing
    have = len(pool.rows)
    if rows <= have and not history_grows:
        return
    n_blocks, size = pool.block_members.shape
    total = (history_bytes or 0) + fixed + state_bytes(model, p, size, n_blocks, rows, have if rows > have else 0,
                                                       lazy, threads)
    if total > limit:
        paths = "" if history_bytes is None else f", the path history of move_window {history_bytes / 1e9:.3g} GB"
        raise MemoryLimitError(
            f"step {t}: the particles' maps use {np.count_nonzero(pool.refcount)} block rows (particles "
            f"share fewer blocks as their trajectories part: {p} x {n_blocks} if they shared none) and the "
            f"step needs the pool grown from {have} to {rows} rows{paths}, {total / 1e9:.3g} GB in all, "
            f"over max_bytes = {limit / 1e9:.3g} GB. The filter is unchanged: raise est.max_bytes "
            f"to continue, or use fewer particles")


def history_growth(model: GridModel, history: PathHistory, pool: BlockPool, t: int, n_particles: int, window: int,
                   every: int, lag: int) -> tuple[int, int, bool]:
    """(extra map rows, history bytes, whether the history grows) for step t of a filter with a
    path history (``move_window`` = ``window``, ``move_every``, ``move_lag``): its growth for the
    step and, on a step that may move (:meth:`PathHistory.move_due
    <onlinemap.estimators.rbpf_move.PathHistory.move_due>`, whether the filter is still exact
    aside), the move's worst case: P times
    :func:`~onlinemap.estimators.rbpf_move.map_rows_per_move` more map rows,
    :func:`~onlinemap.estimators.rbpf_move.path_rows_per_move` more history rows (the pools grow
    by doubling as the move needs, never beyond that) and its scratch, which the move allocates
    after the step is taken: counted, and checked, before."""
    moving = history.move_due(t, window, every, lag, rebuilds(model), exact=False)
    extra = n_particles * map_rows_per_move(model, window, pool.table.shape[1]) if moving else 0
    history_bytes, grows = history.bytes_to_hold(t, n_particles * (1 + (path_rows_per_move(window) if moving else 0)))
    if moving:
        return extra, history_bytes + move_scratch_bytes(model, window), True
    return extra, history_bytes, grows


def check_recovery(sizing: Sizing, t: int, blocks: BlockPool, own_rows: int, history_bytes: int) -> None:
    """Refuse a recovery at step t when the filter, with the step's pool ``blocks`` (and its own of
    ``own_rows`` rows while the step grew it) and its path history, plus :func:`recovery_bytes`
    would exceed ``max_bytes``."""
    model, p, lazy, threads, limit, fixed = sizing
    n_blocks, size = blocks.block_members.shape
    rows = len(blocks.rows)
    held = state_bytes(model, p, size, n_blocks, rows, own_rows if rows != own_rows else 0, lazy,
                       threads) + history_bytes + fixed
    extra = recovery_bytes(model, p)
    if held + extra > limit:
        raise MemoryLimitError(
            f"step {t}: no particle explains the observation (particle depletion), and recovering weighs "
            f"N P = {model.n_cells * p} children, {extra / 1e9:.3g} GB on top of the filter's {held / 1e9:.3g} "
            f"GB, over max_bytes = {limit / 1e9:.3g} GB. The filter is unchanged: raise "
            f"est.max_bytes to continue, or use fewer particles")
