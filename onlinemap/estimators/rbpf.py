"""Rao-Blackwellised particle filter (DESIGN.md section 3, ``rbpf``).

Each of P particles holds one trajectory of the robot and the exact map marginals given it.
Given a trajectory the cells are independent (each is a hidden Markov chain with transition C,
observed through O only at the steps the robot read it), so a particle's map is N marginals of
K labels: only the read cells change by the sensor (and, with blocking labels, the cell a move
tried to enter); all cells drift by C, which is applied lazily (``C^dt`` for the ``dt`` steps
since the cell was last brought up to date, when it is next read). A dynamic world therefore
costs the same per step as a static one.

Two ways to choose the trajectories: by default (Fearnhead and Clifford 2003) every step
enumerates each particle's successors with their exact weights and keeps P of them by optimal
resampling (:func:`onlinemap.resampling.optimal_resampling`), none twice; or each particle
samples one successor from a proposal and the population is resampled when the effective
sample size drops (residual, systematic, stratified or multinomial).

State (plain attributes): locations (P,), normalised log weights (P,), the particles' map
marginals as shared copy-on-write blocks of B cells (see ``onlinemap/kernels/rbpf.py``: a pool
of (B, K) block rows with reference counts and a (P, N / B) table of row indices; stamps per
cell for lazy dynamics), the powers of C, a ``numpy.random.Generator``. To keep the table of
powers bounded however long the run, each step also refreshes a few block rows in turn (brings
them up to date: the same values), so that no stamp is more than ``REFRESH_STEPS`` old:
O(R_used B K^2 / REFRESH_STEPS) per step.

Cost per step: O(P K^2) for the proposal and weighting (a particle reads its cell and the
intended neighbour; O(P F K^2) for a footprint of F cells) plus O(P B K) at most for
copy-on-write of shared blocks (O(P W B K), W = F + 1 cells written); a resampling step adds
O(P_dropped N / B) (table rows copied, not maps). Fearnhead-Clifford resamples every step (its
2P children to P, O(P) plus O(N) to order them by location). ``belief.location`` is O(P + N);
``belief.map`` (the weighted mixture) is O(P N / B) plus one pass over the block rows in use
(at most P N K floats, far fewer while particles share blocks; K^2 flops per out-of-date cell
in a dynamic world). :meth:`RaoBlackwellisedPF.update` advances without building the belief;
the ``belief`` property builds it on first access (then caches it), and :meth:`step` is
``update`` followed by ``belief``. Memory: the block rows in use (at most ``8 P N (K + 1)``
bytes), ``8 P N / B`` for the table, ``32 K^2 REFRESH_STEPS`` for the powers of C.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from .. import arguments
from ..arrays import DEFAULT_MAX_BYTES, read_only
from ..belief import Belief
from ..errors import ImpossibleObservationError, InvalidOptionError, MemoryLimitError, ModelError
from ..kernels.rbpf import (children_by_location, in_place_ancestors, particle_maps, rbpf_commit, rbpf_commit_cells,
                             rbpf_enumerate, rbpf_enumerate_cells, rbpf_map_mixture, rbpf_pick_children,
                             rbpf_place_children, rbpf_propose, rbpf_refresh)
from ..resampling import RESAMPLERS, effective_sample_size, optimal_keep
from ..rng import SeedLike, as_generator
from ..model import GridModel
from ..validation import check_step
from .base import register

PROPOSALS = ("optimal", "transition")
FEARNHEAD_CLIFFORD = "fearnhead_clifford"
RESAMPLING = (*RESAMPLERS, FEARNHEAD_CLIFFORD)
REFRESH_STEPS = 256  # every block row is brought up to date at least this often (lazy dynamics)


def _logsumexp(x: np.ndarray) -> float:
    top = float(np.max(x))
    if top == -math.inf:
        return -math.inf
    return top + math.log(float(np.exp(x - top).sum()))


class BlockLayout(NamedTuple):
    """How cells are grouped into the shared map blocks of the RBPF."""

    cell_block: np.ndarray  # (N,) block of each cell
    cell_slot: np.ndarray  # (N,) position of each cell in its block
    members: np.ndarray  # (n_blocks, B) cells of each block, -1 for padding


def block_layout(model: GridModel, block_cells: int | None = None) -> BlockLayout:
    """Runs of ``block_cells`` consecutive cells in a corridor; square tiles of side
    ``floor(sqrt(block_cells))`` in a 2D grid (a robot crosses a tile's edge less often than a
    row's). Default ``block_cells`` about ``sqrt(N / K)``, which balances the copy of one block
    (B K floats, on a write into a shared block) against the table row of a particle (N / B
    indices, on resampling)."""
    n = model.n_cells
    if block_cells is None:
        block_cells = max(1, round(math.sqrt(n / model.n_labels)))
    if isinstance(block_cells, bool) or int(block_cells) != block_cells or block_cells < 1:
        raise ModelError(f"block_cells must be a positive integer, got {block_cells!r}")
    cells = np.arange(n)
    if model.rows == 1:
        size = min(int(block_cells), n)
        cell_block, cell_slot = np.divmod(cells, size)
    else:
        side = max(1, math.isqrt(int(block_cells)))
        row, col = np.divmod(cells, model.cols)
        tiles_across = -(-model.cols // side)
        cell_block = (row // side) * tiles_across + col // side
        cell_slot = (row % side) * side + col % side
        size = side * side
    members = np.full((int(cell_block.max()) + 1, size), -1, dtype=np.int64)
    members[cell_block, cell_slot] = cells
    return BlockLayout(cell_block, cell_slot, members)


def peak_bytes(model: GridModel, n_particles: int, block_cells: int | None = None, lazy_dynamics: bool = True) -> int:
    """Worst-case peak memory of the filter's state, in bytes (exact Python ints; allocates
    nothing): every particle owning every one of its map blocks, the block pool grown by doubling
    to hold them plus P free rows (old and new pool alive together while it grows), a fresh
    copy of the pool for eager dynamics, the table, the powers of C and per-step temporaries."""
    n, k, p = model.n_cells, model.n_labels, n_particles
    block_cells = block_cells or max(1, round(math.sqrt(n / k)))  # block_layout's default
    if model.rows == 1:
        size = min(block_cells, n)
        n_blocks = -(-n // size)
    else:
        side = max(1, math.isqrt(block_cells))
        size, n_blocks = side * side, -(-model.rows // side) * -(-model.cols // side)
    stamped = lazy_dynamics and not model.is_static
    writes = cells_written(model) * p  # free rows a step may need
    rows = n_blocks + 2 * p
    while rows - writes < n_blocks * p:  # doubled until every particle can own every block, rows to spare
        rows *= 2
    row_bytes = 8 * (size * k + (size if stamped else 0) + 3)  # pool, stamps, row_block / refcount / free
    pool = rows * row_bytes + rows // 2 * row_bytes  # the grown pool and the one it replaced
    eager = 0 if lazy_dynamics or model.is_static else rows * size * k * 8
    powers = 8 * k * k * (4 * REFRESH_STEPS + 1 if stamped else 1)
    per_step = 8 * p * (cells_written(model) * (k + 1) * 3 + k + 8) + 8 * n * k  # children, weights, the belief
    return pool + eager + 8 * p * n_blocks + powers + per_step


def reads_one_cell(model: GridModel) -> bool:
    """The paper's motion and sensor: no blocking labels, the robot reads only its own cell."""
    return not model.has_blocking and model.n_readings == 1 and not model.off_grid_patterns.any()


def cells_written(model: GridModel) -> int:
    """W, the most cells one particle's map changes in a step: the F read cells, plus the intended
    cell of a move with blocking labels (its success or failure tells about it)."""
    return model.n_readings + int(model.has_blocking)


def _grown(array: np.ndarray, rows: int) -> np.ndarray:
    """``array`` with zero rows appended up to ``rows`` along axis 0."""
    out = np.zeros((rows, *array.shape[1:]), dtype=array.dtype)
    out[:len(array)] = array
    return out


@register("rbpf")
class RaoBlackwellisedPF:
    """RBPF over trajectories with exact per-cell map marginals.

    Options: ``n_particles`` (P); ``resampling``:

    - ``"fearnhead_clifford"`` (Fearnhead and Clifford 2003; the default with the optimal
      proposal): every step enumerates each particle's successors (stay, move) with their exact
      weights and keeps P of them by optimal resampling, none twice. It starts from one particle
      and keeps every child while there are at most P (so with P >= 2^T it is exact Bayes).
      Measured (``onlinemap bench rbpf``): 0.23-0.39x the TV to exact of the optimal proposal
      with residual resampling at equal particles, for 1.05-1.5x the time per step.
    - ``"residual"``, ``"systematic"``, ``"stratified"``, ``"multinomial"``: sample one
      successor per particle from ``proposal`` — ``"optimal"`` (given the observation; lower
      weight variance) or ``"transition"`` (the motion model) — and resample by that scheme
      before a step when the effective sample size is below ``resample_threshold`` times P
      (1.0 = every step, 0.0 = never). ``None`` picks ``"residual"`` for the transition proposal.

    ``seed`` (int, None or Generator);
    ``lazy_dynamics`` (False applies C to every cell of every particle every step: O(P N K^2),
    the reference the lazy scheme is tested against); ``block_cells`` B, the cells per shared
    map block (see :func:`block_layout`; default about sqrt(N / K)); ``max_bytes`` guard on
    the particle maps (worst case: every particle owning all its blocks).
    """

    def __init__(self, model: GridModel, *, n_particles: int = 100, proposal: str = "optimal",
                 resampling: str | None = None, resample_threshold: float = 0.5, seed: SeedLike = None,
                 lazy_dynamics: bool = True, block_cells: int | None = None,
                 max_bytes: int = DEFAULT_MAX_BYTES):
        error = InvalidOptionError
        n_particles = arguments.integer("n_particles", n_particles, minimum=1, error=error)
        proposal = arguments.choice("proposal", proposal, PROPOSALS, error)
        if resampling is None:
            resampling = FEARNHEAD_CLIFFORD if proposal == "optimal" else "residual"
        resampling = arguments.choice("resampling", resampling, RESAMPLING, error)
        if resampling == FEARNHEAD_CLIFFORD and proposal != "optimal":
            raise error(f"proposal={proposal!r} samples one successor per particle; resampling="
                        f"'{FEARNHEAD_CLIFFORD}' enumerates them all (the optimal proposal's weights): pass "
                        f"resampling='residual' (or another sampling scheme) to use it")
        resample_threshold = arguments.probability("resample_threshold", resample_threshold, error)
        seed = arguments.seed("seed", seed, error)
        lazy_dynamics = arguments.flag("lazy_dynamics", lazy_dynamics, error)
        if not reads_one_cell(model) and not lazy_dynamics and not model.is_static:
            raise error("lazy_dynamics=False (the eager reference) does not support blocking labels or a sensor "
                        "footprint")
        if block_cells is not None:
            block_cells = arguments.integer("block_cells", block_cells, minimum=1, maximum=model.n_cells, error=error)
        max_bytes = arguments.byte_limit("max_bytes", max_bytes, error)
        n, k = model.n_cells, model.n_labels
        need = peak_bytes(model, n_particles, block_cells, lazy_dynamics)
        if need > max_bytes:
            raise MemoryLimitError(
                f"rbpf with {n_particles} particles on N={n} cells, K={k} labels may need {need / 1e9:.3g} GB "
                f"(every particle owning every map block) but the limit is {max_bytes / 1e9:.3g} GB; pass "
                f"max_bytes=... to raise it")
        layout = block_layout(model, block_cells)
        self.model = model
        self.n_particles = n_particles
        self.proposal = proposal
        self.resampling = resampling
        self.resample_threshold = float(resample_threshold)
        self.lazy_dynamics = bool(lazy_dynamics)
        self._rng = as_generator(seed)
        self._locations = np.full(n_particles, model.start, dtype=np.int64)
        self._log_weights = np.full(n_particles, -math.log(n_particles))
        if resampling == FEARNHEAD_CLIFFORD:  # one particle: the others would enumerate the same children
            self._log_weights[:] = -math.inf
            self._log_weights[0] = 0.0
        self._weights = np.exp(self._log_weights)  # exp(_log_weights), kept beside them
        self._stamped = not model.is_static and self.lazy_dynamics
        self._cell_block, self._cell_slot, self._block_members = layout
        n_blocks, block = layout.members.shape
        self._pool = np.zeros((n_blocks + 2 * n_particles, block, k))
        self._pool[:n_blocks] = 1.0 / k  # padding slots, never read
        self._pool[layout.cell_block, layout.cell_slot] = model.label_prior  # every particle shares the prior
        self._pool_stamps = np.zeros((len(self._pool), block if self._stamped else 0), dtype=np.int64)
        self._row_block = np.zeros(len(self._pool), dtype=np.int64)
        self._row_block[:n_blocks] = np.arange(n_blocks)
        self._refcount = np.zeros(len(self._pool), dtype=np.int64)
        self._refcount[:n_blocks] = n_particles
        unused = np.arange(len(self._pool) - 1, n_blocks - 1, -1)  # a stack, the lowest row on top
        self._free = np.zeros(len(self._pool), dtype=np.int64)
        self._free[:len(unused)] = unused
        self._free_top = np.array([len(unused)])
        self._table = np.tile(np.arange(n_blocks), (n_particles, 1))
        self._powers = np.eye(k)[None].copy()  # powers[d] = C^d for every age d a stamp can have
        if self._stamped:
            self._powers = np.empty((4 * REFRESH_STEPS + 1, k, k))  # ages stay <= 2 REFRESH_STEPS + 1
            self._powers[0] = np.eye(k)
            for d in range(1, len(self._powers)):
                self._powers[d] = self._powers[d - 1] @ model.change
        self._refresh_cursor = 0
        self._log_evidence = 0.0
        self._ess = float(n_particles)
        self._resampled = False
        self._t = -1
        self._belief: Belief | None = None

    @property
    def resampled(self) -> bool:
        """Whether the last step resampled before proposing."""
        return self._resampled

    @property
    def belief(self) -> Belief | None:
        """The weighted mixture after the last step, built on first access and cached (cost: see
        the module docstring; at most one pass over P N K floats)."""
        if self._belief is None and self._t >= 0:
            weights = self._weights / self._weights.sum()
            n, k = self.model.n_cells, self.model.n_labels
            location = np.bincount(self._locations, weights=weights, minlength=n)
            location /= location.sum()  # rounding: keep every probability <= 1
            maps = np.empty((n, k))
            rbpf_map_mixture(self._pool, self._pool_stamps, self._row_block, self._table, self._block_members,
                             self._powers, self._stamped, self._t, weights, maps)
            maps /= maps.sum(axis=1, keepdims=True)
            self._belief = Belief(self._t, location, maps, self._log_evidence,
                                  effective_sample_size=self._ess)
        return self._belief

    def particle_maps(self) -> np.ndarray:
        """(P, N, K) every particle's current map marginals (a fresh array; O(P N K^2))."""
        out = np.empty((self.n_particles, self.model.n_cells, self.model.n_labels))
        particle_maps(self._pool, self._pool_stamps, self._table, self._cell_block, self._cell_slot, self._powers,
                      self._stamped, max(self._t, 0), out)
        return out

    def step(self, action, observation) -> Belief:
        """``update`` then ``belief``."""
        self.update(action, observation)
        return self.belief

    def _reserved_rows(self, need: int | None = None) -> tuple[np.ndarray, ...]:
        """(pool, pool_stamps, row_block, refcount, free, free_top): the current block pool, or a
        copy grown by doubling if fewer than ``need`` rows (default P; a commit may need one per
        cell it writes) are free. Contents unchanged; the caller stores it once the step is
        committed."""
        rows = (self._pool, self._pool_stamps, self._row_block, self._refcount, self._free, self._free_top)
        top = int(self._free_top[0])
        need = self.n_particles if need is None else need
        if top >= need:
            return rows
        have = len(self._pool)
        size = 2 * have
        while size - have + top < need:
            size *= 2
        free = np.zeros(size, dtype=np.int64)
        added = np.arange(size - 1, have - 1, -1)  # new rows, the lowest on top of the stack
        free[:top] = self._free[:top]
        free[top:top + len(added)] = added
        return (*(_grown(x, size) for x in rows[:4]), free, np.array([top + len(added)]))

    def update(self, action, observation) -> None:
        """Advance the particles by one action (None at step 0) and observation.

        Resample first if the effective sample size is below ``resample_threshold * P``; then
        propose, weight and update each particle's observed cell. If the observation has
        probability zero for every particle, raise :class:`ImpossibleObservationError` and
        leave everything (particles, weights, random generator) as it was.
        """
        model = self.model
        a, z = check_step(model, self._t + 1, action, observation)
        t = self._t + 1
        if self.resampling == FEARNHEAD_CLIFFORD:
            self._update_fearnhead_clifford(a, z, t)
            return
        rng_state = self._rng.bit_generator.state
        n_particles = self.n_particles
        log_weights = self._log_weights
        ancestors = np.arange(n_particles)
        resample = a is not None and (self.resample_threshold >= 1.0 or
                                      self._ess < self.resample_threshold * n_particles)
        if resample:
            chosen = RESAMPLERS[self.resampling](self._weights, self._rng)
            ancestors = in_place_ancestors(np.bincount(chosen, minlength=n_particles))
            log_weights = np.full(n_particles, -math.log(n_particles))
        one_cell = reads_one_cell(model)
        pool, pool_stamps, row_block, refcount, free, free_top = self._reserved_rows(
            n_particles * cells_written(model))
        if a is not None and not model.is_static and not self.lazy_dynamics:
            pool = pool @ model.change  # eager: every cell of every block row, fresh array
        neighbors = _no_moves(model.n_cells) if a is None else model.moves[a]
        new_locations = np.empty(n_particles, dtype=np.int64)
        log_increments = np.empty(n_particles)
        new_ids = None
        if one_cell:
            new_cells = np.empty((n_particles, model.n_labels))
            rbpf_propose(self._locations, pool, pool_stamps, self._table, self._cell_block, self._cell_slot,
                         self._powers, self._stamped, t, ancestors, neighbors,
                         model.p_move, model.likelihood[z], self.proposal == "optimal",
                         self._rng.random(n_particles), new_locations, new_cells, log_increments)
        else:  # the same children Fearnhead-Clifford enumerates, one drawn per particle
            m, children = self._enumerate_cells(pool, pool_stamps, t, neighbors, z, np.zeros(n_particles))
            width = cells_written(model)
            new_ids = np.empty((n_particles, width), dtype=np.int64)
            new_cells = np.empty((n_particles, width, model.n_labels))
            rbpf_pick_children(ancestors, *children, m, self.proposal == "optimal", self._rng.random(n_particles),
                               new_locations, new_ids, new_cells, log_increments)
        log_weights = log_weights + log_increments
        increment = _logsumexp(log_weights)
        if increment == -math.inf:
            self._rng.bit_generator.state = rng_state
            raise ImpossibleObservationError(
                f"observation {_describe(model, z)} has probability zero for every particle at step {t}")
        self._commit(t, (pool, pool_stamps, row_block, refcount, free, free_top), ancestors, new_locations, new_cells,
                     log_weights - increment, increment, resample, new_ids)

    def _enumerate_cells(self, pool, pool_stamps, t, neighbors, z, log_weights):
        """(M, (parent, location, log weight, log motion, ids, cells)): :func:`rbpf_enumerate_cells`
        on the current particles with ``log_weights``, the observation ``z`` an int or (F,)."""
        model = self.model
        size, width = 2 * self.n_particles, cells_written(model)
        children = (np.empty(size, dtype=np.int64), np.empty(size, dtype=np.int64), np.empty(size), np.empty(size),
                    np.empty((size, width), dtype=np.int64), np.empty((size, width, model.n_labels)))
        m = rbpf_enumerate_cells(self._locations, log_weights, pool, pool_stamps, self._table, self._cell_block,
                                 self._cell_slot, self._powers, self._stamped, t, neighbors, model.p_move,
                                 model.blocking, model.change, model.footprint_cells, model.sensor,
                                 np.atleast_1d(np.asarray(z, dtype=np.int64)), *children)
        return m, children

    def _update_fearnhead_clifford(self, a: int | None, z, t: int) -> None:
        """Enumerate every live particle's successors with their exact weights
        (:func:`rbpf_enumerate`; :func:`rbpf_enumerate_cells` with blocking labels or a sensor
        footprint), keep P of them by optimal resampling
        (:func:`~onlinemap.resampling.optimal_resampling`: none twice, unbiased; its strata walk
        the children ordered by location, :func:`children_by_location`, which spreads the draws
        over the cells: measured 1.6-2x closer to exact than index order) and write them into the
        slots. O(P K^2 + N) (O(P F K^2) with a footprint of F cells); the resampling is O(P)."""
        model = self.model
        n_particles = self.n_particles
        width = cells_written(model)
        rows = self._reserved_rows(width * n_particles)
        pool, pool_stamps = rows[:2]
        if a is not None and not model.is_static and not self.lazy_dynamics:
            pool = pool @ model.change
            rows = (pool, *rows[1:])
        neighbors = _no_moves(model.n_cells) if a is None else model.moves[a]
        if reads_one_cell(model):
            child_parent = np.empty(2 * n_particles, dtype=np.int64)
            child_location = np.empty(2 * n_particles, dtype=np.int64)
            child_log_weight = np.empty(2 * n_particles)
            child_cells = np.empty((2 * n_particles, 1, model.n_labels))
            child_ids = child_location.reshape(-1, 1)  # the one cell a child changes is where it stands
            m = rbpf_enumerate(self._locations, self._log_weights, pool, pool_stamps, self._table, self._cell_block,
                               self._cell_slot, self._powers, self._stamped, t, neighbors, model.p_move,
                               model.likelihood[z], child_parent, child_location, child_log_weight,
                               child_cells.reshape(2 * n_particles, model.n_labels))
        else:
            m, (child_parent, child_location, child_log_weight, _, child_ids, child_cells) = self._enumerate_cells(
                pool, pool_stamps, t, neighbors, z, self._log_weights)
        if m == 0:
            raise ImpossibleObservationError(
                f"observation {_describe(model, z)} has probability zero for every particle at step {t}")
        increment = _logsumexp(child_log_weight[:m])
        kept, kept_weights, threshold = optimal_keep(np.exp(child_log_weight[:m] - increment), n_particles,
                                                     self._rng.random(),
                                                     children_by_location(child_location[:m], model.n_cells))
        ancestors = np.empty(n_particles, dtype=np.int64)
        new_locations = np.empty(n_particles, dtype=np.int64)
        new_ids = np.empty((n_particles, width), dtype=np.int64)
        new_cells = np.empty((n_particles, width, model.n_labels))
        log_weights = np.empty(n_particles)
        rbpf_place_children(child_parent, child_location, child_ids, child_cells, kept, kept_weights, ancestors,
                            new_locations, new_ids, new_cells, log_weights)
        self._commit(t, rows, ancestors, new_locations, new_cells, log_weights - _logsumexp(log_weights), increment,
                     threshold > 0, new_ids)

    def _commit(self, t, rows, ancestors, new_locations, new_cells, log_weights, increment, resampled,
                new_ids=None) -> None:
        """Write a validated step: the particles' slots (:func:`rbpf_commit`, or
        :func:`rbpf_commit_cells` for the cells ``new_ids``), the block pool ``rows`` (possibly
        grown), the normalised ``log_weights`` and the evidence ``increment``."""
        pool, pool_stamps, row_block, refcount, free, free_top = rows
        if new_ids is None:
            rbpf_commit(self._locations, pool, pool_stamps, row_block, refcount, free, free_top, self._table,
                        self._cell_block, self._cell_slot, self._stamped, self._powers, REFRESH_STEPS, t, ancestors,
                        new_locations, new_cells)
        else:
            rbpf_commit_cells(self._locations, pool, pool_stamps, row_block, refcount, free, free_top, self._table,
                              self._cell_block, self._cell_slot, self._stamped, self._powers, REFRESH_STEPS, t,
                              ancestors, new_locations, new_ids, new_cells)
        self._pool, self._pool_stamps, self._row_block, self._refcount = pool, pool_stamps, row_block, refcount
        self._free, self._free_top = free, free_top
        if self._stamped:
            count = -(-len(pool) // REFRESH_STEPS)
            rbpf_refresh(pool, pool_stamps, refcount, self._powers, t, self._refresh_cursor, count)
            self._refresh_cursor = (self._refresh_cursor + count) % len(pool)
        self._log_weights = log_weights
        self._log_evidence += increment
        self._weights = np.exp(self._log_weights)
        self._ess = min(float(self.n_particles), effective_sample_size(self._weights))  # rounding: <= P
        self._resampled = resampled
        self._t = t
        self._belief = None


def _describe(model: GridModel, z) -> str:
    """An observation for an error message: a label name, or the readings of a footprint."""
    if np.ndim(z) == 0 and 0 <= int(z) < model.n_labels:
        return repr(model.label_names[int(z)])
    return str([model.label_names[int(r)] if r >= 0 else -1 for r in np.atleast_1d(z)])


def _no_moves(n: int) -> np.ndarray:
    """Read-only ``arange(n)`` (every cell stays): the same numba type as a row of ``model.moves``,
    so rbpf_propose is compiled once."""
    return read_only(np.arange(n))
