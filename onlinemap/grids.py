"""What a grid model is built from, each checked: the grid's topology (:func:`grid_neighbors`: a
corridor of one row or a 4-connected grid, moves off the grid stay), the sensor's footprints
(:data:`FOOTPRINTS`, :func:`footprint_offsets`, :func:`footprint_table`), the blocking labels as a
mask (:func:`blocking_mask`) and the symmetric channel (:func:`symmetric_channel`), the default
sensor and the corridor's map dynamics. :mod:`onlinemap.model` builds a
:class:`~onlinemap.model.GridModel` of them and re-exports them.
"""

from __future__ import annotations

from typing import Iterable, Sequence

import numpy as np

from . import arguments
from .errors import ModelError

CORRIDOR_ACTIONS = ("left", "right")
GRID_ACTIONS = ("north", "east", "south", "west")

FOOTPRINTS = {
    "cell": ((0, 0),),
    "cross": ((0, 0), (-1, 0), (0, 1), (1, 0), (0, -1)),
    "square": tuple((dr, dc) for dr in (-1, 0, 1) for dc in (-1, 0, 1)),
}  # the sensor presets; "cell" is the paper's


def footprint_offsets(value) -> tuple[tuple[int, int], ...]:
    """A footprint preset name or a sequence of (drow, dcol) int pairs -> tuple of int pairs."""
    if value is None:
        return FOOTPRINTS["cell"]
    if isinstance(value, str):
        try:
            return FOOTPRINTS[value]
        except KeyError:
            raise ModelError(f"unknown footprint {value!r}; expected one of {tuple(FOOTPRINTS)} "
                             "or a sequence of (drow, dcol) pairs") from None
    try:
        array = np.asarray(value)
    except (TypeError, ValueError):
        array = np.empty(0)
    if array.ndim != 2 or array.shape[1] != 2 or array.shape[0] < 1 or array.dtype.kind not in "iu":
        raise ModelError(f"footprint must be a preset name or a non-empty sequence of (drow, dcol) int "
                         f"pairs, got {value!r}")
    pairs = tuple((int(dr), int(dc)) for dr, dc in array)
    if len(set(pairs)) != len(pairs):
        raise ModelError(f"footprint {pairs} repeats an offset")
    return pairs


def footprint_table(rows: int, cols: int, footprint) -> np.ndarray:
    """(N, F) int64: the cell read by offset f from location l, row-major, -1 off the grid. O(N F)."""
    offsets = np.array(footprint, dtype=np.int64).reshape(-1, 2)
    r, c = np.divmod(np.arange(rows * cols), cols)
    rr = r[:, None] + offsets[:, 0]
    cc = c[:, None] + offsets[:, 1]
    inside = (rr >= 0) & (rr < rows) & (cc >= 0) & (cc < cols)
    return np.where(inside, rr * cols + cc, -1)


def blocking_mask(blocking, label_names: Sequence[str]) -> np.ndarray:
    """(K,) bool mask from blocking labels given by index or name (None: nothing blocks): one
    label, or an iterable of them; anything else (a bool, a float, a bytes...) is a ModelError."""
    mask = np.zeros(len(label_names), dtype=bool)
    if blocking is None:
        return mask
    if isinstance(blocking, np.ndarray) and blocking.ndim == 0:
        blocking = blocking[()]  # the numpy scalar it holds
    if isinstance(blocking, (str, bytes)) or not isinstance(blocking, Iterable):
        blocking = [blocking]
    for label in blocking:
        if isinstance(label, (str, np.str_)):
            if str(label) not in label_names:
                raise ModelError(f"unknown blocking label {label!r}; expected one of {tuple(label_names)}")
            mask[list(label_names).index(str(label))] = True
        elif isinstance(label, (int, np.integer)) and not isinstance(label, (bool, np.bool_)) \
                and 0 <= int(label) < len(label_names):
            mask[int(label)] = True
        else:
            raise ModelError(f"blocking label {label!r} is not a label index in 0..{len(label_names) - 1} "
                             f"or a name in {tuple(label_names)}")
    return mask


def symmetric_channel(n_labels: int, p_same: float) -> np.ndarray:
    """(K, K) matrix with ``p_same`` on the diagonal and ``(1 - p_same) / (K - 1)`` elsewhere."""
    n_labels = arguments.integer("n_labels", n_labels, minimum=2, maximum=arguments.MAX_LABELS)
    p_same = arguments.probability("p_same", p_same)
    off = (1.0 - p_same) / (n_labels - 1)
    return np.full((n_labels, n_labels), off) + np.eye(n_labels) * (p_same - off)


def grid_neighbors(rows: int, cols: int) -> tuple[np.ndarray, tuple[str, ...]]:
    """Neighbour table (N, A) of a rows x cols grid: a 1-row grid is a corridor (left, right),
    anything else is 4-connected (north, east, south, west). Off-grid moves stay."""
    r, c = np.divmod(np.arange(rows * cols), cols)
    if rows == 1:
        left = np.where(c > 0, c - 1, c)
        right = np.where(c < cols - 1, c + 1, c)
        return np.stack([left, right], axis=1), CORRIDOR_ACTIONS

    def cell(rr, cc):
        return rr * cols + cc

    north = np.where(r > 0, cell(r - 1, c), cell(r, c))
    east = np.where(c < cols - 1, cell(r, c + 1), cell(r, c))
    south = np.where(r < rows - 1, cell(r + 1, c), cell(r, c))
    west = np.where(c > 0, cell(r, c - 1), cell(r, c))
    return np.stack([north, east, south, west], axis=1), GRID_ACTIONS
