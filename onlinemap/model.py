"""The generative model: a known grid topology plus four probability tables (DESIGN.md section 1).

A :class:`GridModel` says what the world is; estimators (``onlinemap.estimators``) say how to
infer it. Cells are numbered row-major, ``0..N-1``. The robot knows the topology; it does not
know the map ``m`` (one label in ``0..K-1`` per cell), which may change over time.

Tables (all float64, read-only):

- motion ``T[a, i, j] = P(L_t = j | L_{t-1} = i, a)``: the neighbour ``neighbors[i, a]`` with
  ``p_move``, stay with ``1 - p_move``; where the neighbour does not exist
  (``neighbors[i, a] == i``) stay with 1. Kept sparse: ``self_prob[a, j] = T[a, j, j]`` and
  ``predecessor[a, j]``, the one cell that moves into ``j`` under ``a`` (or -1).
- map dynamics ``C[k, k'] = P(m_{i,t} = k' | m_{i,t-1} = k)``, the same for every cell.
- sensor ``O[k, z] = P(Z_t = z | m_{L_t} = k)``.
- label prior ``label_prior[i, k] = P(m_{i,0} = k)``, cells independent; start cell ``start``.
  With ``unknown_label_frequencies`` (off by default; on for generated buildings and floors read
  from files) the world says its label frequencies theta are unknown: the cells are i.i.d. given
  theta ~ Dirichlet (:mod:`onlinemap.label_prior`), the table being the fixed prior a robot falls
  back to. Estimators' ``label_prior=None`` follows it (they learn theta where they can);
  ``label_prior="model"`` asks for the table instead.

Two options (DESIGN.md section 7), both off by default (the paper's model, bit for bit):

- ``blocking`` (K,) bool: labels a robot cannot enter. From ``i`` with action ``a`` the intended
  ``j = neighbors[i, a]`` is reached with ``p_move * [not blocking[m_j]]``, the label judged before
  this step's map change; otherwise the robot stays. Motion then depends on the map.
- ``footprint``: ``F`` offsets ``(drow, dcol)`` read at every step (``"cell"``, ``"cross"``,
  ``"square"`` or explicit pairs). Offset ``f`` from location ``l`` reads cell
  ``footprint_cells[l, f]`` through ``O`` (independently of the other readings), or -1 with
  probability 1 when that cell is off the grid. An observation is an int when ``F == 1`` and an
  (F,) int array otherwise.

The parts a model is built of, each checked, live in :mod:`onlinemap.grids` (topology, footprints,
blocking masks, the symmetric channel) and :mod:`onlinemap.door_layouts` (the door world's labels
and layouts); their names are importable from here too.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import Sequence

import numpy as np

from . import arguments
from .arrays import cached_by_content, read_only
# The parts a model is built of live in grids and door_layouts; their names are importable from here too.
from .door_layouts import (CLOSED_DOOR, DOOR_CHARS, DOOR_LABELS, DOOR_WORLD_10X10, FREE, OPEN_DOOR,
                           WALL, door_cells, door_change, layout_grid, parse_layout, passable_start)
from .errors import ModelError
from .grids import (CORRIDOR_ACTIONS, FOOTPRINTS, GRID_ACTIONS, blocking_mask, footprint_offsets,
                    footprint_table, grid_neighbors, symmetric_channel)

_ATOL = 1e-9


def _probability(name: str, value: float) -> float:
    return arguments.probability(name, value)


def _table(name: str, values, dtype=np.float64) -> np.ndarray:
    """A fresh array of numbers (not bools, strings or objects), or ModelError naming ``name``."""
    if isinstance(values, np.ndarray) and values.dtype.kind in "iuf":  # the common case, vectorised
        return np.array(values, dtype=dtype)
    try:
        array = np.array(values, dtype=object)
        if array.dtype == object and array.size and not all(
                isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_))
                for v in array.flat):
            raise TypeError("entries must be numbers")
        return np.array(array.tolist() if array.ndim else values, dtype=dtype)
    except (TypeError, ValueError, OverflowError) as error:
        raise ModelError(f"{name} must be a rectangular table of numbers: {error}") from None


def _grid_size(rows, cols) -> tuple[int, int]:
    """Validated ``(rows, cols)``: whole numbers >= 1 with at most ``arguments.MAX_CELLS`` cells."""
    rows = arguments.integer("rows", rows, minimum=1, maximum=arguments.MAX_CELLS)
    cols = arguments.integer("cols", cols, minimum=1, maximum=arguments.MAX_CELLS)
    if rows * cols > arguments.MAX_CELLS:
        raise ModelError(f"a {rows} x {cols} grid has {rows * cols} cells; at most {arguments.MAX_CELLS} are supported")
    return rows, cols


def _stochastic(name: str, matrix, shape: tuple[int, ...]) -> np.ndarray:
    """Validate a row-stochastic array of the given shape; return a read-only float64 copy."""
    array = _table(name, matrix)
    if array.shape != shape:
        raise ModelError(f"{name} must have shape {shape}, got {array.shape}")
    if not np.all(np.isfinite(array)):
        raise ModelError(f"{name} contains NaN or infinite entries")
    if np.any(array < 0) or np.any(array > 1):
        raise ModelError(f"{name} has entries outside [0, 1]")
    sums = array.sum(axis=-1)
    if not np.allclose(sums, 1.0, rtol=0, atol=_ATOL):
        worst = np.unravel_index(np.argmax(np.abs(sums - 1)), sums.shape)
        raise ModelError(f"{name} rows must sum to 1; row {tuple(int(i) for i in worst)} sums to {sums[worst]!r}")
    return read_only(array)


def change_powers(change: np.ndarray, count: int) -> np.ndarray:
    """(count, K, K) ``C^d`` for d < count, each the last times ``change`` C (K, K): read-only and
    shared per matrix and count (:func:`~onlinemap.arrays.cached_by_content`; copy it to hand a
    kernel a writable array). The RBPF's pool keeps 1025 of them for every dynamic filter built
    (1-3 ms of products in Python), the rollouts H + 1 per planner. O(count K^3) the first time."""
    return _change_powers(np.asarray(change, dtype=np.float64), int(count))


@cached_by_content
def _change_powers(change: np.ndarray, count: int) -> np.ndarray:
    powers = np.empty((count,) + change.shape)
    powers[0] = np.eye(change.shape[0])
    for d in range(1, count):
        powers[d] = powers[d - 1] @ change
    return powers


def _motion_tables(n: int, neighbors, action_names) -> tuple[np.ndarray, tuple[str, ...], np.ndarray]:
    """A model's checked motion: (N, A) int64 neighbours (whole cell indices in range), the A
    action names and the (A, N) predecessor of each cell under each action (-1: none), refused
    when an action moves two cells into one. O(N A)."""
    table = _table("neighbors", neighbors, np.float64)
    if np.any(table != np.round(table)):
        raise ModelError("neighbors must hold whole cell indices")
    if table.ndim != 2 or table.shape[0] != n:
        raise ModelError(f"neighbors must have shape ({n}, n_actions), got {table.shape}")
    if np.any(table < 0) or np.any(table >= n):
        raise ModelError("neighbors contains a cell index out of range")
    table = table.astype(np.int64)
    n_actions = table.shape[1]
    names = arguments.names("action_names", action_names, n_actions)
    predecessor = np.full((n_actions, n), -1, dtype=np.int64)
    for a in range(n_actions):
        movers = np.flatnonzero(table[:, a] != np.arange(n))
        targets = table[movers, a]
        if len(np.unique(targets)) != len(targets):
            raise ModelError(f"action {action_names[a]!r} moves two cells into the same cell")
        predecessor[a, targets] = movers
    return table, names, predecessor


def _label_tables(n: int, change, sensor, label_prior) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A model's checked label tables, read-only float64: C and O (K, K) row-stochastic with
    2 <= K <= ``MAX_LABELS``, and the label prior broadcast to (N, K). O(N K + K^2)."""
    change = _table("change matrix C", change)
    k = change.shape[0] if change.ndim == 2 else -1
    if not 2 <= k <= arguments.MAX_LABELS:
        raise ModelError(f"change matrix C must be K x K with 2 <= K <= {arguments.MAX_LABELS}, "
                         f"got shape {change.shape}")
    change = _stochastic("change matrix C", change, (k, k))
    sensor = _stochastic("sensor matrix O", sensor, (k, k))
    prior = _table("label_prior", label_prior)
    if prior.shape == (k,):
        prior = np.broadcast_to(prior, (n, k))
    return change, sensor, _stochastic("label_prior", prior, (n, k))


@dataclass(frozen=True, eq=False)
class GridModel:
    """An immutable, validated grid model. Build one with :func:`corridor`, :func:`door_world`
    or :func:`grid_model`; ``dataclasses.replace(model, p_move=...)`` re-validates."""

    rows: int
    cols: int
    neighbors: np.ndarray  # (N, A) int64: cell reached by a successful move (itself if none)
    p_move: float
    change: np.ndarray  # (K, K) C
    sensor: np.ndarray  # (K, K) O
    label_prior: np.ndarray  # (N, K)
    start: int
    action_names: tuple[str, ...]
    label_names: tuple[str, ...]
    blocking: np.ndarray | None = None  # (K,) bool: labels a robot cannot enter; None = none
    footprint: tuple[tuple[int, int], ...] | str | None = FOOTPRINTS["cell"]  # offsets read each step
    unknown_label_frequencies: bool = False  # theta ~ Dirichlet: estimators learn the label frequencies
    footprint_cells: np.ndarray = field(init=False, repr=False)  # (N, F) cell read by offset f, -1 off grid
    self_prob: np.ndarray = field(init=False, repr=False)  # (A, N) T[a, j, j]
    predecessor: np.ndarray = field(init=False, repr=False)  # (A, N) cell moving into j, or -1
    likelihood: np.ndarray = field(init=False, repr=False)  # (K, K) contiguous O.T: row z = O[:, z]
    moves: np.ndarray = field(init=False, repr=False)  # (A, N) contiguous neighbors.T: row a = neighbors[:, a]

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        rows, cols = _grid_size(self.rows, self.cols)
        set_(self, "rows", rows)
        set_(self, "cols", cols)
        n = self.rows * self.cols
        neighbors, action_names, predecessor = _motion_tables(n, self.neighbors, self.action_names)
        set_(self, "neighbors", neighbors)
        p_move = _probability("p_move", self.p_move)
        set_(self, "p_move", p_move)
        change, sensor, prior = _label_tables(n, self.change, self.sensor, self.label_prior)
        k = change.shape[0]
        set_(self, "change", change)
        set_(self, "sensor", sensor)
        set_(self, "label_prior", prior)
        set_(self, "action_names", action_names)
        set_(self, "label_names", arguments.names("label_names", self.label_names, k))
        start = arguments.integer("start", self.start)
        if not 0 <= start < n:
            raise ModelError(f"start cell {start} is outside 0..{n - 1}")
        set_(self, "start", start)
        blocking = np.zeros(k, dtype=bool) if self.blocking is None else np.array(self.blocking)
        if blocking.shape != (k,) or blocking.dtype != bool:
            raise ModelError(f"blocking must be a ({k},) bool array (one flag per label), got "
                             f"{blocking.dtype} {blocking.shape}; grid_model(blocking=...) takes labels")
        set_(self, "blocking", read_only(blocking))
        set_(self, "unknown_label_frequencies", _flag("unknown_label_frequencies", self.unknown_label_frequencies))
        footprint = footprint_offsets(self.footprint)
        if n * len(footprint) > arguments.MAX_CELLS:  # before the (N, F) tables are built
            raise ModelError(f"a footprint of {len(footprint)} offsets on {n} cells reads {n * len(footprint)} "
                             f"cells per map; at most {arguments.MAX_CELLS} are supported (cells x offsets)")
        set_(self, "footprint", footprint)
        set_(self, "footprint_cells", read_only(footprint_table(self.rows, self.cols, footprint)))
        stays = neighbors.T == np.arange(n)
        self_prob = np.where(stays, 1.0, 1.0 - p_move)
        likelihood = np.ascontiguousarray(self.sensor.T)
        moves = np.ascontiguousarray(neighbors.T)
        for array in (neighbors, predecessor, self_prob, likelihood, moves):
            read_only(array)
        set_(self, "self_prob", self_prob)
        set_(self, "predecessor", predecessor)
        set_(self, "likelihood", likelihood)
        set_(self, "moves", moves)

    # --- sizes and aliases -------------------------------------------------------------
    @property
    def n_cells(self) -> int:
        return self.rows * self.cols

    @property
    def n_labels(self) -> int:
        return self.change.shape[0]

    @property
    def n_actions(self) -> int:
        return self.neighbors.shape[1]

    @property
    def n_readings(self) -> int:
        """F, the number of readings per observation (footprint offsets)."""
        return len(self.footprint)

    @property
    def observation_shape(self) -> tuple[int, ...]:
        """() when an observation is one label (F = 1), (F,) otherwise."""
        return () if self.n_readings == 1 else (self.n_readings,)

    @cached_property
    def has_blocking(self) -> bool:
        """True when some label blocks motion (motion then depends on the map). Computed once
        (every EM step asks)."""
        return bool(self.blocking.any())

    @cached_property
    def press_likelihood(self) -> np.ndarray:
        """(2, K) read-only: what a press says about the label k of the cell j it was made towards
        (a move attempted from cell i towards its neighbour j != i; DESIGN.md section 7)::

            row 0, entered:  [k passable]              (P(entered | m_j = k) = p_move [k passable])
            row 1, stayed:   1 - p_move [k passable]   (P(stayed  | m_j = k))

        Row 0 leaves out the constant p_move, which is the motion's: the RBPF's move counts it in
        the path's motion probability, and a cell's posterior given a path normalises it away.
        Without blocking labels both rows are constant in k (1 and 1 - p_move): a press says nothing
        about the map. Computed once, O(K)."""
        passable = (~self.blocking).astype(np.float64)
        return read_only(np.stack([passable, 1.0 - self.p_move * passable]))

    @cached_property
    def reads_own_cell(self) -> bool:
        """True for the paper's sensor: one reading, of the robot's own cell (an observation is
        then one label, never -1). The one answer to "what does the sensor read?": anything else
        reads a footprint (``footprint_cells``), with -1 where an offset leaves the grid.
        Computed once (every EM step asks several times)."""
        return self.footprint == FOOTPRINTS["cell"]

    @cached_property
    def is_paper_model(self) -> bool:
        """True for the paper's motion and sensor (DESIGN.md section 1): no label blocks motion and
        the robot reads only its own cell. The one spelling of that test: the estimators and planners
        take their fast paths on it. Computed once."""
        return self.reads_own_cell and not self.has_blocking

    @property
    def learns_label_frequencies(self) -> bool:
        """True where the approximate filters, and the maps made given a path, learn the label
        frequencies by default (:mod:`onlinemap.label_prior`): the model says they are unknown
        and the world is static (a dynamic world's marginals mix readings of different ages)."""
        return self.unknown_label_frequencies and self.is_static

    @cached_property
    def off_grid_patterns(self) -> np.ndarray:
        """(U, F) bool: the distinct off-grid masks ``footprint_cells[l] < 0`` over locations l."""
        return read_only(np.unique(self.footprint_cells < 0, axis=0))

    @property
    def shape(self) -> tuple[int, int]:
        return (self.rows, self.cols)

    @property
    def C(self) -> np.ndarray:
        """Map dynamics, (K, K)."""
        return self.change

    @property
    def O(self) -> np.ndarray:  # noqa: E743 - the design's name
        """Sensor, (K, K)."""
        return self.sensor

    @cached_property
    def is_static(self) -> bool:
        """True when C is the identity (labels never change). Computed once."""
        return bool(np.array_equal(self.change, np.eye(self.n_labels)))

    def __repr__(self) -> str:
        kind = "static" if self.is_static else "dynamic"
        extra = ""
        if self.has_blocking:
            extra += f", blocking={tuple(n for n, b in zip(self.label_names, self.blocking) if b)}"
        if self.n_readings > 1:
            preset = next((name for name, fp in FOOTPRINTS.items() if fp == self.footprint), self.footprint)
            extra += f", footprint={preset}"
        if self.unknown_label_frequencies:
            extra += ", label frequencies unknown"
        return (f"GridModel({self.rows}x{self.cols}, K={self.n_labels} {self.label_names}, "
                f"actions={self.action_names}, p_move={self.p_move}, {kind}, start={self.start}{extra})")

    # --- motion ------------------------------------------------------------------------
    def motion_matrix(self, action: int) -> "scipy.sparse.csr_array":
        """Sparse (N, N) ``T[action]``, rows = from, columns = to; with blocking labels, the motion
        of a map where no cell blocks. (SciPy is imported here, not with the package: a process
        that never asks for a sparse matrix, such as ``onlinemap track``, starts 0.2 s sooner.)"""
        import scipy.sparse as sp

        n = self.n_cells
        cells = np.arange(n)
        nb = self.neighbors[:, action]
        movers = nb != cells
        rows = np.concatenate([cells, cells[movers]])
        cols = np.concatenate([cells, nb[movers]])
        vals = np.concatenate([self.self_prob[action], np.full(movers.sum(), self.p_move)])
        return sp.csr_array((vals, (rows, cols)), shape=(n, n))

    def location_prior(self) -> np.ndarray:
        """(N,) one-hot at the start cell."""
        prior = np.zeros(self.n_cells)
        prior[self.start] = 1.0
        return prior


DEFINING_FIELDS = ("rows", "cols", "neighbors", "p_move", "change", "sensor", "label_prior", "start",
                   "action_names", "label_names", "blocking",
                   "footprint", "unknown_label_frequencies")  # what makes two models the same; the rest is derived
# defining fields with a default (older checkpoints lack them)
OPTIONAL_FIELDS = ("blocking", "footprint", "unknown_label_frequencies")
#: optional fields a checkpoint leaves out at these values: its bytes stay those of an older onlinemap
OMITTED_AT_DEFAULT = {"unknown_label_frequencies": False}


def model_difference(a: GridModel, b: GridModel) -> str | None:
    """Name of the first defining field in which two models differ (bitwise), or None if equal."""
    for name in DEFINING_FIELDS:
        x, y = getattr(a, name), getattr(b, name)
        if isinstance(x, np.ndarray):
            if x.shape != y.shape or x.dtype != y.dtype or x.tobytes() != y.tobytes():
                return name
        elif x != y:
            return name
    return None


def _move_probability(model: GridModel, action: int, passable: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(movers, P(move)) from each moving cell l: ``p_move * passable[neighbors[l, a]]``."""
    target = model.neighbors[:, action]
    movers = np.flatnonzero(target != np.arange(model.n_cells))
    go = np.zeros(model.n_cells)
    go[movers] = model.p_move * np.asarray(passable, dtype=np.float64)[target[movers]]
    return movers, go


def apply_motion(model: GridModel, x: np.ndarray, action: int, passable: np.ndarray | None = None) -> np.ndarray:
    """Predict along axis 0: ``out[j, ...] = sum_i T[a, i, j] x[i, ...]``. x: (N, ...). O(x.size).

    ``passable`` (N,): the probability that each cell can be entered (blocking labels, judged
    on a map belief); the move from i to its neighbour j then succeeds with ``p_move passable[j]``.
    None: the paper's motion (every cell enterable)."""
    if passable is not None:
        movers, go = _move_probability(model, action, passable)
        shape = (-1,) + (1,) * (x.ndim - 1)
        out = (1.0 - go).reshape(shape) * x
        out[model.neighbors[movers, action]] += go[movers].reshape(shape) * x[movers]
        return out
    out = model.self_prob[action].reshape((-1,) + (1,) * (x.ndim - 1)) * x
    pred = model.predecessor[action]
    into = pred >= 0
    out[into] += model.p_move * x[pred[into]]
    return out


def apply_motion_transpose(model: GridModel, b: np.ndarray, action: int,
                           passable: np.ndarray | None = None) -> np.ndarray:
    """Backward along axis 0: ``out[i, ...] = sum_j T[a, i, j] b[j, ...]``. b: (N, ...). O(b.size).
    ``passable`` as in :func:`apply_motion`."""
    if passable is not None:
        movers, go = _move_probability(model, action, passable)
        shape = (-1,) + (1,) * (b.ndim - 1)
        out = (1.0 - go).reshape(shape) * b
        out[movers] += go[movers].reshape(shape) * b[model.neighbors[movers, action]]
        return out
    out = model.self_prob[action].reshape((-1,) + (1,) * (b.ndim - 1)) * b
    nb = model.neighbors[:, action]
    movers = nb != np.arange(model.n_cells)
    out[movers] += model.p_move * b[nb[movers]]
    return out


def passable_probability(model: GridModel, maps: np.ndarray) -> np.ndarray:
    """(N,) probability that each cell can be entered under independent map marginals (N, K). O(N K)."""
    return maps @ (~model.blocking).astype(np.float64)


# --- constructors ----------------------------------------------------------------------
def grid_model(rows: int, cols: int, n_labels: int = 2, *, p_obs: float = 0.9, p_move: float = 0.8,
               change=None, sensor=None, label_prior=None, start: int = 0,
               label_names: Sequence[str] | None = None, blocking=None, footprint=None,
               unknown_label_frequencies: bool = False) -> GridModel:
    """A general grid model.

    ``change`` (K, K) defaults to the identity (static world); ``sensor`` (K, K) defaults to the
    symmetric channel with ``p_obs``; ``label_prior`` is (K,) or (N, K), uniform by default.
    ``blocking``: labels (indices or names) a robot cannot enter (None: none, the paper's motion);
    ``footprint``: ``"cell"`` (default, the paper's sensor), ``"cross"``, ``"square"`` or a
    sequence of (drow, dcol) offsets. ``unknown_label_frequencies``: the label frequencies are
    unknown (theta ~ Dirichlet, :mod:`onlinemap.label_prior`): estimators learn them by default.
    """
    n_labels = arguments.integer("n_labels", n_labels, minimum=2, maximum=arguments.MAX_LABELS)
    rows, cols = _grid_size(rows, cols)
    if rows * cols * n_labels > arguments.MAX_CELLS:
        raise ModelError(f"{rows * cols} cells x {n_labels} labels: at most {arguments.MAX_CELLS} cell labels "
                         "are supported")
    neighbors, action_names = grid_neighbors(rows, cols)
    if sensor is None:
        sensor = symmetric_channel(n_labels, _probability("p_obs", p_obs))
    if change is None:
        change = np.eye(n_labels)
    if label_prior is None:
        label_prior = np.full(n_labels, 1.0 / n_labels)
    if label_names is None:
        label_names = tuple(str(k) for k in range(n_labels))
    label_names = tuple(label_names)
    return GridModel(rows=rows, cols=cols, neighbors=neighbors, p_move=p_move, change=change,
                     sensor=sensor, label_prior=label_prior, start=start,
                     action_names=action_names, label_names=label_names,
                     blocking=blocking_mask(blocking, label_names), footprint=footprint_offsets(footprint),
                     unknown_label_frequencies=unknown_label_frequencies)


def corridor(n_cells: int, n_labels: int = 2, p_obs: float = 0.9, p_move: float = 0.8,
             p_change: float = 0.0, start: int = 0, label_prior=None, *, blocking=None,
             footprint=None) -> GridModel:
    """A 1D corridor of ``n_cells`` (actions left=0, right=1). With ``p_change`` a cell's label
    becomes one of the other ``K - 1`` labels, uniformly, at every step. ``blocking`` and
    ``footprint`` as in :func:`grid_model` (a corridor's footprint offsets have drow = 0 to read
    anything: cells of other rows are off the grid)."""
    p_change = _probability("p_change", p_change)
    n_labels = arguments.integer("n_labels", n_labels, minimum=2, maximum=arguments.MAX_LABELS)
    n_cells = arguments.integer("n_cells", n_cells, minimum=1, maximum=arguments.MAX_CELLS)
    change = symmetric_channel(n_labels, 1.0 - p_change)
    return grid_model(1, n_cells, n_labels, p_obs=p_obs, p_move=p_move, change=change,
                      label_prior=label_prior, start=start, blocking=blocking, footprint=footprint)


def _flag(name: str, value) -> bool:
    if not isinstance(value, (bool, np.bool_)):
        raise ModelError(f"{name} must be True or False, got {value!r}")
    return bool(value)


def door_world(layout: str | np.ndarray | None = None, p_obs: float = 0.9, p_move: float = 0.8,
               p_door: float = 0.0, start: int | None = None,
               label_prior=None, *, blocking: bool = False,
               footprint=None, unknown_label_frequencies: bool = False) -> tuple[GridModel, np.ndarray]:
    """A 2D door world from a layout: a text layout (default :data:`DOOR_WORLD_10X10`) or a
    (rows, cols) int array of door labels (:func:`layout_grid`).

    Returns ``(model, true_map)``, the map (N,) read from the layout. ``start`` defaults to the
    first free cell in row-major order. ``blocking=True``: walls and closed doors block motion;
    ``footprint`` and ``unknown_label_frequencies`` as in :func:`grid_model`.
    """
    grid = layout_grid(DOOR_WORLD_10X10 if layout is None else layout)
    true_map = grid.ravel()
    if start is None:
        free = np.flatnonzero(true_map == FREE)
        start = int(free[0]) if len(free) else 0
    model = grid_model(grid.shape[0], grid.shape[1], 4, p_obs=p_obs, p_move=p_move,
                       change=door_change(p_door), label_prior=label_prior, start=start,
                       label_names=DOOR_LABELS, footprint=footprint,
                       blocking=("wall", "closed_door") if _flag("blocking", blocking) else None,
                       unknown_label_frequencies=unknown_label_frequencies)
    if model.rows == 1:
        raise ModelError("a door world needs at least two rows (use corridor() for 1D worlds)")
    return model, read_only(true_map)


__all__ = [
    "GridModel", "grid_model", "corridor", "door_world", "parse_layout", "layout_grid", "door_change",
    "symmetric_channel", "apply_motion", "apply_motion_transpose", "grid_neighbors",
    "DOOR_WORLD_10X10", "DOOR_LABELS", "CORRIDOR_ACTIONS", "GRID_ACTIONS", "door_cells",
    "passable_start", "FOOTPRINTS", "footprint_table", "blocking_mask", "passable_probability",
    "footprint_offsets", "DOOR_CHARS", "FREE", "WALL", "OPEN_DOOR", "CLOSED_DOOR",
]
