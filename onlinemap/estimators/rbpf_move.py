"""The RBPF's resample-move step (Gilks and Berzuini 2001; options ``move_window``, ``move_every``,
``move_lag`` of :class:`~onlinemap.estimators.rbpf.RaoBlackwellisedPF`): every
``move_every`` steps each live particle redraws a window of W = ``move_window`` past locations
by a Metropolis-Hastings move whose invariant law is the filter's target, the posterior over
paths; weights are unchanged.

Why: Fearnhead-Clifford's particles coalesce. In the paper's world, 1,000 particles replaying an
``info_gain`` run share one path beyond about 200 steps back, often a wrong one, and no later
evidence can mend a mistake every particle carries. A move anywhere in the past redraws an old
stretch given everything seen since; moving only the last steps does not touch it (measured:
windows in the last 300 steps keep little of the gain).

The target. Static world (C = I): given a path ``x_{0:t}`` the cells are independent, cell c's
label with the law ``prior_c(k) w(k) prod_e f_e(k)`` over its *events* e: the readings of c
(``f = O(., z)``) and, with blocking labels, the presses into c (moved in: ``[k passable]``;
stayed: ``1 - p_move [k passable]``; the motion's constant part ``p_move`` or the successor's
probability left out: ``GridModel.press_likelihood``). ``w`` is the label-prior tilt
(:mod:`onlinemap.estimators.rbpf_prior`; 1 without one). The map summed out,

    p(x_{0:t} | z_{0:t})  propto  prod_tau T0(x_{tau-1}, x_tau; a_tau)
                                  prod_c sum_k prior_c(k) w(k) prod_{e at c} f_e(k)

Particle p's window ``x_{s+1..s+W}`` (``s`` uniform in ``first_start .. t - move_lag - W``) has,
given the rest of its path, the law ``prod T0  prod_c E_{m_-(c)}[prod_{window events at c} f_e]``,
the window's events being the readings of steps ``s+1..s+W`` and the presses of steps
``s+1..s+W+1`` (the last only when ``s + W < t``, the bridge to ``x_{s+W+1}``), and ``m_-`` the
particle's map without them. The data outside the window depend on the window only through the
map, which ``m_-`` carries. ``m_-`` is built one of two ways:

- divided (no blocking labels, a sensor without zeros: the paper's worlds, bit for bit as
  before): the stored marginal with the window's readings divided out, exact since no factor
  has a zero (the tilt w stays in it);
- rebuilt (blocking labels or a sensor with zeros: a move into a cell multiplies it by
  [passable], a reading can rule a label out, and zeros cannot be divided out): at the cells the
  old window touches (its readings' cells and its presses' targets), ``normalise(prior_c w prod
  f_e)`` over the events of the particle's history outside the window (its path and every
  step's action and readings are stored), with the current w. O(t (F + 1)) per particle per move
  for t steps of history. A recovery from depletion resets cells the history does not record,
  so in such worlds moves stop after the first recovery (:meth:`PathHistory.move_due`).

The proposal q: forward filtering, backward sampling on the location chain of the window over
the cells its actions can reach from ``x_s`` (and, with a bridge, from which ``x_{s+W+1}`` can
still be reached), every event replaced by its mean under ``m_-``: emissions ``e_tau(l) = prod_f
sum_k m_-(c_f)(k) O(k, z_f)`` over the cells ``c_f`` a robot at l reads (1 for an offset off the
grid reading -1, 0 where only one of the two is off), and a press into n moves with ``p_move
P_{m_-}(n passable)``. It draws exactly from ``q(x) propto prod T0 prod E_{m_-}[f_e]``. The target
differs from it only where the window touches a cell twice (its later event sees the earlier):
``pi / q propto R(x)``, ``R(x) = prod over the window's events in order of E[f_e | m_- updated by
x's earlier events at the cell] / E_{m_-}[f_e]`` (1 at a cell's first event). An independence
Metropolis-Hastings step accepts the proposed window with probability ``min(1, R(new) /
R(old))``, which leaves pi invariant; the accepted path's cells take their marginals given it
(m_- updated by the new window's events), so every particle's map stays the exact map given its
path. Where a window enters twice a cell m_- deems a likely wall, q gives it little mass and the
chain reaches it slowly (correct, only slower). A weighted set properly weighted for pi stays so
with its weights unchanged (``E[w f(x')] = E[w (K f)(x)]`` and ``pi K = pi``): the evidence
estimate and the streaming contract are untouched (the move runs after the step's update;
``step`` returns the belief at t).

When it runs. Fearnhead-Clifford with room for every child is exact Bayes, and a move could
only add Monte-Carlo noise to it: moves wait until the filter has dropped a child (:attr:`
PathHistory.exact`; the sampling schemes are never exact). So a filter with P >= 2^T is
bit for bit the filter without moves. After a recovery from depletion (a relocation the motion
model cannot explain, and read cells reset to their prior) windows start at or after the step
that recovered (``first_start``): from there on the map is again the prior times the path's
factors, which is what the move divides by. A rebuilt m_- needs the history from step 0, so
where the move rebuilds, moves stop after a recovery.

Limits (refused with :class:`~onlinemap.errors.InvalidOptionError` naming ``move_window``,
:func:`move_refusal`): a dynamic world (a cell's marginal is then a filtered chain, which neither
a division nor the path's factors give without per-step snapshots of the maps).

State (:class:`PathHistory`, checkpointed, format 4): every particle's path as shared
copy-on-write blocks of :data:`PATH_BLOCK` steps (resampling copies a table row of C = t / B
indices, as the maps' table does), and every step's action and readings.

Cost: a move of every particle is O(P W S (F K + 1)) (S the cells a window's step can take, a
few to tens), plus O(P t (F + 1)) where it rebuilds m_- (t steps of history), every
``move_every`` steps; the history O(P_copied C + P B) per step (B =
:data:`PATH_BLOCK`) and, once moves have made the particles' pasts differ, up to 2 P t bytes (4
beyond 32,767 cells). Measured on the paper's world replay at 1,000 particles (W = 20, every 5):
3.2x the time per step of the filter without moves (the user guide's Estimators page, RBPF section).
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import numpy as np

from .. import arguments
from .. import state_checks as checks
from ..checkpoint import state_class
from ..errors import InvalidOptionError
from ..kernels.rbpf_move import MapEvidence, Paths, paths_record, rbpf_move
from ..model import GridModel
from .block_pool import BlockPool, Named, check_shared_rows, grown, grown_free_stack, rows_to_hold
from .rbpf_kernels import world_tables

PATH_BLOCK = 64  # steps per block of a particle's path
FIRST_STEPS = 64  # the steps the history holds before it first grows (it doubles)
FIRST_STEPS_BLOCKS = 4  # the table's blocks per particle before it first grows (it doubles)
MAX_WINDOW = 1000  # move_window at most (the kernel's scratch is O(W N))


class MoveCounts(NamedTuple):
    """Windows proposed by the resample-move step so far, and how many were accepted (a proposal
    equal to the old window counts as accepted)."""

    proposed: int
    accepted: int


def move_refusal(model: GridModel) -> str | None:
    """Why the resample-move step cannot run on ``model`` (None if it can)."""
    if not model.is_static:
        return ("needs a static world (change matrix C = identity): with map dynamics a cell's marginal is a "
                "filtered chain, and the map without a window cannot be built from the path's readings")
    return None


def rebuilds(model: GridModel) -> bool:
    """Whether the move rebuilds the map without the window from the path history (blocking
    labels, or a sensor with zero entries: factors with zeros, which cannot be divided out)
    rather than dividing the window's readings out of the stored marginals."""
    return model.has_blocking or bool(np.any(model.sensor == 0))


def map_evidence(model: GridModel, frequencies: np.ndarray | None) -> MapEvidence:
    """The :class:`~onlinemap.kernels.rbpf_move.MapEvidence` of ``model`` with every cell's prior
    tilted by ``frequencies`` (K,), or each cell by its own row of (N, K) (``label_prior="context"``;
    None: the model's own prior). O(N K)."""
    prior = model.label_prior if frequencies is None else model.label_prior * frequencies
    return MapEvidence(np.ascontiguousarray(prior, dtype=np.float64), model.press_likelihood, rebuilds(model))


def move_options(model: GridModel, window, every, lag) -> tuple[int | None, int, int]:
    """The options ``move_window`` (None: no moves; else W, 1 to :data:`MAX_WINDOW`),
    ``move_every`` (>= 1) and ``move_lag`` (>= 0), validated; the window refused where the move
    cannot run (:func:`move_refusal`). Raises :class:`InvalidOptionError` naming the option."""
    error = InvalidOptionError
    every = arguments.integer("move_every", every, minimum=1, error=error)
    lag = arguments.integer("move_lag", lag, minimum=0, error=error)
    if window is None:
        return None, every, lag
    window = arguments.integer("move_window", window, minimum=1, maximum=MAX_WINDOW, error=error)
    reason = move_refusal(model)
    if reason is not None:
        raise error(f"move_window={window}: the resample-move step {reason}; leave move_window=None (the default)")
    return window, every, lag


def path_dtype(n_cells: int) -> np.dtype:
    """The integer type of a path's cells: int16 up to 32,767 cells, else int32."""
    return np.dtype(np.int16 if n_cells <= np.iinfo(np.int16).max else np.int32)


def map_rows_per_move(model: GridModel, window: int, n_blocks: int) -> int:
    """The most map block rows one particle's move takes: a copy of every block holding a cell its
    old or new window touches, ``min(2 (W + b) (F + b), n_blocks)`` (b = 1 with blocking labels,
    whose presses touch the cell pressed into, else 0)."""
    gated = int(model.has_blocking)
    return min(2 * (window + gated) * (model.n_readings + gated), n_blocks)


def path_rows_per_move(window: int) -> int:
    """The most history rows one particle's move takes: the blocks its window's steps span."""
    return window // PATH_BLOCK + 2


def history_bytes(n_particles: int, itemsize: int, n_readings: int, rows: int, columns: int, steps: int) -> int:
    """Bytes of a :class:`PathHistory` of ``rows`` rows (locations of ``itemsize`` bytes), a table of
    ``columns`` blocks per particle and room for ``steps`` steps (allocates nothing). O(1)."""
    row = PATH_BLOCK * itemsize + 3 * 8  # the locations, row_block, refcount, free
    return rows * row + 8 * n_particles * columns + 8 * steps * (1 + n_readings) + 8


def move_scratch_bytes(model: GridModel, window: int) -> int:
    """Bytes of one resample-move step's scratch (:class:`~onlinemap.kernels.rbpf_move.MoveScratch`
    for N cells, K labels, a window of W steps and F readings: ``8 (2 N K + 11 N + 6 (W + 1) N +
    3 (W + 1) + 2 (W + 1) (F + 1) + K)``, about 48 (W + 1) N), allocated afresh by every move: the
    memory guard counts it on the steps that may move (allocates nothing). O(1)."""
    n, k, width = model.n_cells, model.n_labels, window + 1
    return 8 * (2 * n * k + 11 * n + 6 * width * n + 3 * width + 2 * width * (model.n_readings + 1) + k)


def new_history_bytes(model: GridModel, n_particles: int) -> int:
    """Bytes of :meth:`PathHistory.new`'s history (allocates nothing). O(1)."""
    return history_bytes(n_particles, path_dtype(model.n_cells).itemsize, model.n_readings, 2 * n_particles,
                         FIRST_STEPS_BLOCKS, FIRST_STEPS)


def _widened(table: np.ndarray, columns: int) -> np.ndarray:
    """``table`` (P, C) with -1 columns appended up to ``columns``."""
    out = np.full((table.shape[0], columns), -1, dtype=table.dtype)
    out[:, :table.shape[1]] = table
    return out


@state_class
@dataclasses.dataclass(eq=False)
class PathHistory:
    """Every particle's path and every step's action and readings: what the resample-move step
    reads. R rows of B = :data:`PATH_BLOCK` steps, P particles, F readings per step.

    - ``rows (R, B)`` (int16, or int32 beyond 32,767 cells): the locations at B consecutive steps;
      ``row_block (R,)``: the block of steps a row holds (block b: steps ``b B .. b B + B - 1``);
      ``refcount (R,)``; ``free (R,)`` with ``free_top (1,)``: a stack of the unused rows;
    - ``table (P, C)``: the row holding block b of particle p's path, -1 for blocks no step has
      reached (the same for every particle);
    - ``actions (T,)``: the action before each step (-1 at step 0); ``readings (T, F)``;
    - ``first_start``: the earliest left end of a window (0, or the last step that recovered from
      depletion: a relocation the motion model cannot explain); ``exact``: no child dropped yet
      (Fearnhead-Clifford with room for every child is exact Bayes: moves wait until it is not;
      the sampling schemes start inexact); ``proposed``, ``accepted``: the moves' counts.

    Invariants between two steps (:meth:`check`): those of rows shared copy-on-write
    (:func:`~onlinemap.estimators.block_pool.check_shared_rows`) over the table's first ``t // B
    + 1`` columns, -1 beyond; ``R >= 2 P``, ``T > t``; every location up to step t a cell, step
    t's the particle's location; the actions of steps 1..t actions, the readings labels (-1 where
    the footprint leaves the grid); the counts and ``first_start`` in range.
    """

    rows: np.ndarray
    row_block: np.ndarray
    refcount: np.ndarray
    free: np.ndarray
    free_top: np.ndarray
    table: np.ndarray
    actions: np.ndarray
    readings: np.ndarray
    first_start: int = 0
    exact: bool = True
    proposed: int = 0
    accepted: int = 0

    @classmethod
    def new(cls, model: GridModel, n_particles: int, exact: bool) -> PathHistory:
        """An empty history (no step yet) with 2 P rows. O(P B)."""
        size = 2 * n_particles
        return cls(np.zeros((size, PATH_BLOCK), dtype=path_dtype(model.n_cells)), np.zeros(size, dtype=np.int64),
                   np.zeros(size, dtype=np.int64), np.arange(size - 1, -1, -1), np.array([size]),
                   np.full((n_particles, FIRST_STEPS_BLOCKS), -1, dtype=np.int64),
                   np.full(FIRST_STEPS, -1, dtype=np.int64),
                   np.full((FIRST_STEPS, model.n_readings), -1, dtype=np.int64), 0, bool(exact))

    def _sizes(self, t: int, need: int) -> tuple[int, int, int]:
        """(rows, table columns, steps) of this history once it holds step t and ``need`` free rows."""
        size = rows_to_hold(len(self.rows), int(self.free_top[0]), need)
        columns = self.table.shape[1]
        while t // PATH_BLOCK >= columns:
            columns *= 2
        steps = len(self.actions)
        while t >= steps:
            steps *= 2
        return size, columns, steps

    def reserved(self, t: int, need: int) -> PathHistory:
        """This history, or a grown copy (by doubling), with room for step t and ``need`` free rows
        (the caller keeps the copy). O(1), or O(the history's bytes) to grow."""
        size, columns, steps = self._sizes(t, need)
        if (size, columns, steps) == (len(self.rows), self.table.shape[1], len(self.actions)):
            return self
        have, top = len(self.rows), int(self.free_top[0])
        actions = np.full(steps, -1, dtype=np.int64)
        actions[:len(self.actions)] = self.actions
        return dataclasses.replace(
            self, rows=grown(self.rows, size), row_block=grown(self.row_block, size),
            refcount=grown(self.refcount, size), free=grown_free_stack(self.free, top, have, size),
            free_top=np.array([top + size - have]), table=_widened(self.table, columns), actions=actions,
            readings=grown(self.readings, steps))

    def bytes_to_hold(self, t: int, need: int) -> tuple[int, bool]:
        """(bytes, grows): the bytes of this history once :meth:`reserved` has given it room for
        step t and ``need`` free rows (with the old arrays, alive while they are copied), and
        whether it must grow. Allocates nothing. O(1)."""
        size, columns, steps = self._sizes(t, need)
        after = history_bytes(self.table.shape[0], self.rows.itemsize, self.readings.shape[1], size, columns, steps)
        grows = (size, columns, steps) != (len(self.rows), self.table.shape[1], len(self.actions))
        return after + (self.nbytes if grows else 0), grows

    def arrays(self) -> Paths:
        """The history's arrays as the kernels take them (:class:`~onlinemap.kernels.rbpf_move.Paths`):
        views, not copies. O(1)."""
        return Paths(self.rows, self.row_block, self.refcount, self.free, self.free_top, self.table, self.actions,
                     self.readings)

    @property
    def nbytes(self) -> int:
        """The bytes of the history's arrays."""
        return sum(getattr(self, f.name).nbytes for f in dataclasses.fields(self)
                   if isinstance(getattr(self, f.name), np.ndarray))

    def record_paths(self, t: int, ancestors: np.ndarray, locations: np.ndarray, resampled: bool,
                     recovered: bool) -> None:
        """Step t's paths, in place (:func:`~onlinemap.kernels.rbpf_move.paths_record`: slot p takes
        over ``ancestors[p]``'s path, then every slot's location goes to step t; needs room,
        :meth:`reserved` with P rows); a step that dropped a child (``resampled``) or
        ``recovered`` ends exactness, and windows then start at or after a recovery. O(P_copied C
        + P B)."""
        paths_record(self.arrays(), ancestors, locations, t)
        self.exact = self.exact and not resampled and not recovered
        if recovered:
            self.first_start = t

    def record_step(self, t: int, action: int | None, readings) -> None:
        """Step t's action (None at step 0) and readings, in place (room: :meth:`reserved`). O(F)."""
        self.actions[t] = -1 if action is None else action
        self.readings[t] = np.atleast_1d(readings)

    def paths(self, t: int) -> np.ndarray:
        """(P, t + 1) every particle's path up to step t (a fresh array). O(P t)."""
        steps = np.arange(t + 1)
        return self.rows[self.table[:, steps // PATH_BLOCK], steps % PATH_BLOCK].astype(np.int64)

    def move_due(self, t: int, window: int, every: int, lag: int, rebuild: bool, exact: bool | None = None) -> bool:
        """Whether step t moves: every ``every`` steps once the filter is not exact (``exact``
        stands in for :attr:`exact` where given), when a window ending ``lag`` steps back fits
        after :attr:`first_start`; never after a recovery where the move rebuilds maps from the
        history (``rebuild``, :func:`rebuilds`: a recovery resets cells the history does not
        record)."""
        exact = self.exact if exact is None else exact
        if rebuild and self.first_start > 0:
            return False
        return not exact and t % every == 0 and t - lag - window >= self.first_start

    def move(self, blocks: BlockPool, locations: np.ndarray, log_weights: np.ndarray, model: GridModel, t: int,
             window: int, lag: int, rng: np.random.Generator,
             frequencies: np.ndarray | None = None) -> tuple[PathHistory, BlockPool]:
        """One resample-move step at step t (the module docstring;
        :func:`~onlinemap.kernels.rbpf_move.rbpf_move`): every slot draws its window's left end s
        uniformly in ``first_start .. t - lag - W`` (``rng.integers``, P of them), then P (W + 2)
        uniforms (``rng.random``), in that order, dead slots too; the live ones are moved in slot
        order, in place, growing the map pool and the history when they run out of free rows
        (the memory guard allowed for P times :func:`map_rows_per_move` and
        :func:`path_rows_per_move` rows before the step). ``frequencies`` (K,) or (N, K): the
        label-prior tilt w every stored marginal carries (None: none). Returns the history and the pool (each
        this one or a grown copy). Cost: see the module docstring."""
        n_particles = len(locations)
        starts = rng.integers(self.first_start, t - lag - window + 1, size=n_particles)
        uniforms = rng.random((n_particles, window + 2))
        counts = np.zeros(2, dtype=np.int64)
        need_map = map_rows_per_move(model, window, blocks.table.shape[1])
        history, first = self, 0
        evidence = map_evidence(model, frequencies)
        while True:
            first = rbpf_move(locations, log_weights, blocks.arrays(), history.arrays(), world_tables(model), evidence,
                              t, first, starts, window, uniforms, counts)
            if first == n_particles:
                break
            blocks = blocks.reserved(need_map)
            history = history.reserved(t, path_rows_per_move(window))
        history.proposed += int(counts[0])
        history.accepted += int(counts[1])
        return history, blocks

    def check(self, model: GridModel, locations: np.ndarray, t: int, name: str = "_history") -> None:
        """Raise :class:`~onlinemap.errors.CheckpointError` naming the first broken invariant (the
        class docstring) of a history at step t (-1 before the first) whose particles stand at
        ``locations`` (P,). O(R B + P t)."""
        fields, at = Named(self, name), f"{name}."
        n_particles = len(locations)
        for field in dataclasses.fields(self):
            value = getattr(self, field.name)
            if type(value) is np.ndarray and not value.flags.c_contiguous:
                checks.fail(at + field.name, "must be a C-contiguous array (the kernels' layout)")
        rows = checks.array(fields, at + "rows", None, path_dtype(model.n_cells), ndim=2, written=True)
        size = rows.shape[0]
        if rows.shape[1] != PATH_BLOCK or size < 2 * n_particles:
            checks.fail(at + "rows", f"must have shape (R >= {2 * n_particles}, {PATH_BLOCK}), got {rows.shape}")
        table = checks.array(fields, at + "table", None, np.int64, ndim=2, written=True)
        used = t // PATH_BLOCK + 1 if t >= 0 else 0
        if table.shape[0] != n_particles or table.shape[1] < max(used, 1):
            checks.fail(at + "table", f"must have shape ({n_particles}, C >= {max(used, 1)}), got {table.shape}")
        if np.any(table[:, used:] != -1):
            checks.fail(at + "table", "must be -1 for the blocks no step has reached")
        check_shared_rows(fields, at, np.ascontiguousarray(table[:, :used]), size)
        actions = checks.array(fields, at + "actions", None, np.int64, ndim=1, written=True)
        readings = checks.array(fields, at + "readings", (len(actions), model.n_readings), np.int64, written=True)
        if len(actions) <= t:
            checks.fail(at + "actions", f"must hold the steps 0..{t}, got {len(actions)}")
        if t >= 0:
            paths = self.paths(t)
            checks.indices(at + "rows", paths, model.n_cells)
            if np.any(paths[:, t] != locations):
                checks.fail(at + "rows", "must end every path at its particle's location")
            checks.indices(at + "actions", actions[1:t + 1], model.n_actions)
            checks.indices(at + "readings", readings[:t + 1], model.n_labels, start=-1)
        checks.integer(fields, at + "first_start", 0, max(t, 0))
        if type(self.exact) is not bool:
            checks.fail(at + "exact", "must be a bool")
        checks.integer(fields, at + "proposed", 0, np.iinfo(np.int64).max)
        checks.integer(fields, at + "accepted", 0, self.proposed)
