"""The RBPF's particle maps: copy-on-write blocks of cells shared between particles.

P particles each carry N cell marginals of K labels, but they descend from few ancestors and
share most of them. :class:`BlockPool` stores the maps as blocks of B cells (a run of a
corridor, a square tile of a grid: :func:`block_layout`) in a pool of block rows; a table maps
(particle, block) to the row holding it, and a row is shared by every particle whose table
names it. Resampling copies table rows (N / B indices), not maps; a particle writing a cell of
a shared block first copies that block (B K floats). The numba kernels of
``onlinemap/kernels/rbpf.py`` read and write the pool's arrays; this class owns them, grows the
pool, keeps the table of powers of C for lazy dynamics and states (and checks) what must hold
between two steps.

Cost: memory O(R B K) for R block rows in use (at most P N / B rows: P N K floats, far fewer
while particles share), O(P N / B) for the table, O(K^2 REFRESH_STEPS) for the powers of C.
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import numpy as np

from .. import state_checks as checks
from ..checkpoint import state_class
from ..errors import ModelError
from ..kernels.rbpf import Pool, particle_maps, rbpf_map_mixture, rbpf_refresh
from ..kernels.rbpf_parallel import rbpf_map_mixture_parallel
from ..model import GridModel, change_powers

REFRESH_STEPS = 256  # every block row is brought up to date at least this often (lazy dynamics)


class BlockLayout(NamedTuple):
    """How cells are grouped into the shared map blocks of the RBPF."""

    cell_block: np.ndarray  # (N,) block of each cell
    cell_slot: np.ndarray  # (N,) position of each cell in its block
    members: np.ndarray  # (n_blocks, B) cells of each block, -1 for padding


def block_shape(model: GridModel, block_cells: int | None = None) -> tuple[int, int]:
    """(B, n_blocks): the cells per block and the number of blocks of :func:`block_layout`, without
    building it. Runs of ``block_cells`` consecutive cells in a corridor; square tiles of side
    ``floor(sqrt(block_cells))`` in a 2D grid (a robot crosses a tile's edge less often than a
    row's). Default ``block_cells`` about ``sqrt(N / K)``, which balances the copy of one block
    (B K floats, on a write into a shared block) against the table row of a particle (N / B
    indices, on resampling). Raises :class:`~onlinemap.errors.ModelError` for a ``block_cells``
    that is not a positive integer. O(1)."""
    n = model.n_cells
    if block_cells is None:
        block_cells = max(1, round(math.sqrt(n / model.n_labels)))
    if isinstance(block_cells, bool) or int(block_cells) != block_cells or block_cells < 1:
        raise ModelError(f"block_cells must be a positive integer, got {block_cells!r}")
    if model.rows == 1:
        size = min(int(block_cells), n)
        return size, -(-n // size)
    side = max(1, math.isqrt(int(block_cells)))
    return side * side, -(-model.rows // side) * -(-model.cols // side)


def block_layout(model: GridModel, block_cells: int | None = None) -> BlockLayout:
    """Which block and slot each cell takes: blocks of :func:`block_shape`. O(N)."""
    size, _ = block_shape(model, block_cells)
    cells = np.arange(model.n_cells)
    if model.rows == 1:
        cell_block, cell_slot = np.divmod(cells, size)
    else:
        side = math.isqrt(size)
        row, col = np.divmod(cells, model.cols)
        tiles_across = -(-model.cols // side)
        cell_block = (row // side) * tiles_across + col // side
        cell_slot = (row % side) * side + col % side
    members = np.full((int(cell_block.max()) + 1, size), -1, dtype=np.int64)
    members[cell_block, cell_slot] = cells
    return BlockLayout(cell_block, cell_slot, members)


def pool_bytes(model: GridModel, n_particles: int, block_size: int, n_blocks: int, rows: int, stamped: bool) -> int:
    """Bytes of a :class:`BlockPool` of ``rows`` block rows of ``block_size`` cells (allocates
    nothing): the rows, their stamps when ``stamped``, row_block / refcount / free, the particle
    table (P n_blocks) and the powers of C. O(1)."""
    k = model.n_labels
    row_bytes = 8 * (block_size * k + (block_size if stamped else 0) + 3)
    powers = 8 * k * k * (4 * REFRESH_STEPS + 1 if stamped else 1)
    return rows * row_bytes + 8 * n_particles * n_blocks + powers


def grown(array: np.ndarray, rows: int) -> np.ndarray:
    """``array`` with zero rows appended up to ``rows`` along axis 0."""
    out = np.zeros((rows, *array.shape[1:]), dtype=array.dtype)
    out[:len(array)] = array
    return out


def rows_to_hold(size: int, top: int, need: int) -> int:
    """The number of rows a pool of ``size`` rows, ``top`` of them free, has once it holds ``need``
    free rows: ``size``, or ``size`` doubled until the rows added and the free ones make ``need``
    (a pool grows by doubling). O(log need)."""
    if top >= need:
        return size
    grown_size = 2 * size
    while grown_size - size + top < need:
        grown_size *= 2
    return grown_size


def grown_free_stack(free: np.ndarray, top: int, have: int, size: int) -> np.ndarray:
    """The free stack (``size``,) of a pool grown from ``have`` to ``size`` rows: the rows added
    pushed under the ``top`` free ones already there, the lowest on top. O(size)."""
    out = np.zeros(size, dtype=np.int64)
    added = np.arange(size - 1, have - 1, -1)
    out[:top] = free[:top]
    out[top:top + len(added)] = added
    return out


@state_class
@dataclasses.dataclass(eq=False)
class BlockPool:
    """The particles' maps as shared copy-on-write blocks. R block rows, P particles, N cells in
    ``n_blocks`` blocks of B slots, K labels.

    Block rows (the pool grows by doubling; :meth:`reserved`):

    - ``rows (R, B, K)``: each row's slot marginals;
    - ``stamps (R, B)``: the step at which each slot was last brought up to date (lazy dynamics;
      ``(R, 0)`` and never read when not ``stamped``): the marginal at step t is
      ``rows[r, j] @ powers[t - stamps[r, j]]``;
    - ``row_block (R,)``: which block of the map a row holds;
    - ``refcount (R,)``: how many table entries name the row;
    - ``free (R,)``, ``free_top (1,)``: a stack of the rows no particle uses, ``free[:free_top[0]]``.

    ``table (P, n_blocks)``: the row holding block b of particle p's map, so cell i of particle
    p is ``rows[table[p, cell_block[i]], cell_slot[i]]``. The layout (``cell_block (N,)``,
    ``cell_slot (N,)``, ``block_members (n_blocks, B)``, -1 padding), ``powers (D, K, K)``
    (``C^d``) and ``stamped`` are fixed by the model and options; ``refresh_cursor`` is the next
    row :meth:`refresh` brings up to date.

    Invariants between two steps (:meth:`check`): the shapes above, with ``R >= n_blocks + P``;
    every table entry a row index, and the row holds that entry's block
    (``row_block[table[p, b]] == b``); ``refcount`` equals the number of table entries naming
    each row; the free stack holds exactly the rows with ``refcount == 0``, once each; the rows
    in use hold probabilities (each slot's marginal in [0, 1], summing to 1); with stamps, every
    in-use slot's age at this step and the next indexes ``powers``; ``0 <= refresh_cursor < R``.
    """

    rows: np.ndarray
    stamps: np.ndarray
    row_block: np.ndarray
    refcount: np.ndarray
    free: np.ndarray
    free_top: np.ndarray
    table: np.ndarray
    cell_block: np.ndarray
    cell_slot: np.ndarray
    block_members: np.ndarray
    powers: np.ndarray
    stamped: bool
    refresh_cursor: int = 0

    #: the fields fixed by the model and options (checked bit for bit against a fresh filter's)
    CONSTANT = ("cell_block", "cell_slot", "block_members", "powers", "stamped")

    def __post_init__(self) -> None:
        # the kernels' bundle, made once: a pool's arrays are never rebound (a grown pool is a new
        # BlockPool); not a field, so checkpoints do not store it
        self._arrays = Pool(self.rows, self.stamps, self.row_block, self.refcount, self.free, self.free_top,
                            self.table, self.cell_block, self.cell_slot, self.block_members, self.powers,
                            self.stamped, REFRESH_STEPS)

    @classmethod
    def new(cls, model: GridModel, layout: BlockLayout, n_particles: int, stamped: bool) -> BlockPool:
        """Every particle shares one row per block holding the label prior; P free rows to spare
        and P more (a step writes at most one block per particle before the pool grows).
        ``stamped``: lazy dynamics in a dynamic world (powers of C up to 4 REFRESH_STEPS).
        O((n_blocks + P) B K + P n_blocks)."""
        k = model.n_labels
        n_blocks, block = layout.members.shape
        rows = np.zeros((n_blocks + 2 * n_particles, block, k))
        rows[:n_blocks] = 1.0 / k  # padding slots, never read
        rows[layout.cell_block, layout.cell_slot] = model.label_prior  # every particle shares the prior
        row_block = np.zeros(len(rows), dtype=np.int64)
        row_block[:n_blocks] = np.arange(n_blocks)
        refcount = np.zeros(len(rows), dtype=np.int64)
        refcount[:n_blocks] = n_particles
        unused = np.arange(len(rows) - 1, n_blocks - 1, -1)  # a stack, the lowest row on top
        free = np.zeros(len(rows), dtype=np.int64)
        free[:len(unused)] = unused
        powers = np.eye(k)[None].copy()  # powers[d] = C^d for every age d a stamp can have
        if stamped:  # ages stay <= 2 REFRESH_STEPS + 1
            powers = change_powers(model.change, 4 * REFRESH_STEPS + 1).copy()
        return cls(rows, np.zeros((len(rows), block if stamped else 0), dtype=np.int64), row_block, refcount, free,
                   np.array([len(unused)]), np.tile(np.arange(n_blocks), (n_particles, 1)), layout.cell_block,
                   layout.cell_slot, layout.members, powers, bool(stamped))

    def reserved(self, need: int) -> BlockPool:
        """A pool with at least ``need`` free rows: this one, or a copy whose row arrays are grown
        by doubling (the contents unchanged; the table, layout and powers shared). The caller
        keeps the copy only once its step is committed. O(1), or O(R B K) to grow."""
        top = int(self.free_top[0])
        if top >= need:
            return self
        have, size = len(self.rows), self.rows_to_hold(need)
        return dataclasses.replace(self, rows=grown(self.rows, size), stamps=grown(self.stamps, size),
                                   row_block=grown(self.row_block, size), refcount=grown(self.refcount, size),
                                   free=grown_free_stack(self.free, top, have, size),
                                   free_top=np.array([top + size - have]))

    def rows_to_hold(self, need: int) -> int:
        """The number of rows :meth:`reserved` gives a pool with ``need`` free rows
        (:func:`rows_to_hold`). O(1)."""
        return rows_to_hold(len(self.rows), int(self.free_top[0]), need)

    def with_rows(self, rows: np.ndarray) -> BlockPool:
        """This pool with new row contents (R, B, K) (eager dynamics: ``rows @ C``). O(1)."""
        return dataclasses.replace(self, rows=rows)

    def arrays(self) -> Pool:
        """The pool's arrays as the kernels take them (:class:`~onlinemap.kernels.rbpf.Pool`, with
        ``max_age`` = :data:`REFRESH_STEPS`): the arrays themselves, not copies, bundled once. O(1)."""
        return self._arrays

    @property
    def nbytes(self) -> int:
        """The bytes of the pool's arrays."""
        return sum(getattr(self, f.name).nbytes for f in dataclasses.fields(self)
                   if isinstance(getattr(self, f.name), np.ndarray))

    @property
    def free_bytes(self) -> int:
        """The bytes of the free rows: their marginals, stamps, ``row_block``, ``refcount`` and ``free`` entries."""
        return int(self.free_top[0]) * (self.rows.strides[0] + self.stamps.strides[0] + 3 * 8)

    def refresh(self, t: int) -> None:
        """Bring the next ``ceil(R / REFRESH_STEPS)`` rows up to date (the same values, stamped
        ``t``), so that no stamp is more than ``REFRESH_STEPS`` old and ``powers`` stays bounded
        however long the run. O(R B K^2 / REFRESH_STEPS); nothing without stamps."""
        if not self.stamped:
            return
        count = -(-len(self.rows) // REFRESH_STEPS)
        rbpf_refresh(t, self.refresh_cursor, count, *self.arrays())
        self.refresh_cursor = (self.refresh_cursor + count) % len(self.rows)

    def mixture(self, t: int, weights: np.ndarray, threads: int = 1) -> np.ndarray:
        """(N, K) ``sum_p weights[p] * map_p`` at step t (unnormalised); on ``threads`` threads from 2
        (:func:`~onlinemap.kernels.rbpf_parallel.rbpf_map_mixture_parallel`, the same numbers).
        O(P n_blocks) plus one pass over the rows in use (K^2 flops per out-of-date slot)."""
        out = np.empty((len(self.cell_block), self.rows.shape[2]))
        if threads > 1:
            rbpf_map_mixture_parallel(self.arrays(), t, weights, out, threads)
        else:
            rbpf_map_mixture(t, weights, out, *self.arrays())
        return out

    def particle_maps(self, t: int, which: np.ndarray | None = None) -> np.ndarray:
        """(M, N, K) the map marginals at step t of particles ``which`` (M,) int64 (None: all P of
        them), a fresh array. O(M N K^2)."""
        which = np.arange(len(self.table)) if which is None else which
        out = np.empty((len(which), len(self.cell_block), self.rows.shape[2]))
        particle_maps(t, which, out, *self.arrays())
        return out

    def check(self, n_particles: int, n_labels: int, t: int, name: str = "_blocks") -> None:
        """Raise :class:`~onlinemap.errors.CheckpointError` naming the first broken invariant (see
        the class docstring) of a pool at step ``t`` (-1 before the first); ``name`` prefixes the
        fields in the message. O(R B K + P n_blocks)."""
        if type(self.stamped) is not bool:
            checks.fail(f"{name}.stamped", "must be a bool")
        for field in dataclasses.fields(self):
            value = getattr(self, field.name)
            if type(value) is np.ndarray and not value.flags.c_contiguous:
                checks.fail(f"{name}.{field.name}", "must be a C-contiguous array (the kernels' layout)")
        fields, at = Named(self, name), f"{name}."
        members = checks.array(fields, at + "block_members", None, np.int64, ndim=2)
        n_blocks, block = members.shape
        p, k = n_particles, n_labels
        rows = checks.array(fields, at + "rows", None, np.float64, ndim=3, written=True)
        r = rows.shape[0]
        if rows.shape[1:] != (block, k) or r < n_blocks + p:
            checks.fail(at + "rows", f"must have shape (R >= {n_blocks + p}, {block}, {k}), got {rows.shape}")
        table = checks.array(fields, at + "table", (p, n_blocks), np.int64, written=True)
        used = check_shared_rows(fields, at, table, r) > 0
        checks.probabilities(at + "rows", rows[used])
        stamps = checks.array(fields, at + "stamps", (r, block if self.stamped else 0), np.int64, written=True)
        if self.stamped:  # ages at this step and the next index the table of powers of C
            checks.indices(at + "stamps", stamps[used], max(t, 0) + 1, start=t + 2 - len(self.powers))
        checks.integer(fields, at + "refresh_cursor", 0, r - 1)


def check_shared_rows(fields, at: str, table: np.ndarray, n_rows: int) -> np.ndarray:
    """The bookkeeping of rows shared copy-on-write (a :class:`BlockPool`'s, or the RBPF's path
    history's): every entry of ``table`` (P, n) a row index below ``n_rows``; ``row_block``
    naming the column (block) each entry's row holds; ``refcount`` counting the entries naming
    each row; the free stack (``free``, ``free_top``) listing exactly the rows none names. Reads
    the fields ``at + name`` of ``fields``; raises :class:`~onlinemap.errors.CheckpointError`
    naming the first broken one; returns ``refcount``. O(n_rows + P n)."""
    n_blocks = table.shape[1]
    checks.indices(at + "table", table, n_rows)
    row_block = checks.array(fields, at + "row_block", (n_rows,), np.int64, written=True)
    checks.indices(at + "row_block", row_block, max(n_blocks, 1))
    if np.any(row_block[table] != np.arange(n_blocks)):
        checks.fail(at + "row_block", "must name the block each table entry's row holds")
    refcount = checks.array(fields, at + "refcount", (n_rows,), np.int64, written=True)
    if np.any(refcount != np.bincount(table.ravel(), minlength=n_rows)):
        checks.fail(at + "refcount", "must count the table's references to every row")
    free = checks.array(fields, at + "free", (n_rows,), np.int64, written=True)
    free_top = checks.array(fields, at + "free_top", (1,), np.int64, written=True)
    unused = np.flatnonzero(refcount == 0)
    if not 0 <= free_top[0] <= n_rows or not np.array_equal(np.sort(free[:free_top[0]]), unused):
        checks.fail(at + "free", "must list exactly the rows no particle uses")
    return refcount


class Named:
    """Attribute access to a state object's fields (a :class:`BlockPool`'s, the RBPF's path
    history's) under the names ``NAME.field`` (for the messages of :mod:`onlinemap.state_checks`)."""

    def __init__(self, pool, name: str):
        self._pool, self._name = pool, name

    def __getattr__(self, attribute: str):
        prefix = self._name + "."
        return getattr(self._pool, attribute.removeprefix(prefix))


#: version-1 checkpoints kept the pool as loose RBPF attributes: attribute -> BlockPool field
FORMAT_1_ATTRIBUTES = {"_pool": "rows", "_pool_stamps": "stamps", "_row_block": "row_block", "_refcount": "refcount",
                       "_free": "free", "_free_top": "free_top", "_table": "table", "_cell_block": "cell_block",
                       "_cell_slot": "cell_slot", "_block_members": "block_members", "_powers": "powers",
                       "_stamped": "stamped", "_refresh_cursor": "refresh_cursor"}
