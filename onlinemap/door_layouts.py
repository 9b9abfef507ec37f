"""The door world's labels and layouts: the four door labels (:data:`DOOR_LABELS`; free and wall
never change, doors swap open and closed: :func:`door_change`), a layout as text (``.`` free,
``#`` wall, ``o`` open door, ``c`` closed door: :func:`parse_layout`) or as an array of labels
(:func:`layout_grid`), the default 10 x 10 world (:data:`DOOR_WORLD_10X10`), the check of a start
cell (:func:`passable_start`) and the door cells of a map (:func:`door_cells`).
:func:`onlinemap.model.door_world` builds the model of a layout; :mod:`onlinemap.model`
re-exports these names.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from . import arguments
from .errors import ModelError

if TYPE_CHECKING:
    from .model import GridModel

DOOR_LABELS = ("free", "wall", "open_door", "closed_door")
DOOR_CHARS = {".": 0, "#": 1, "o": 2, "c": 3}
FREE, WALL, OPEN_DOOR, CLOSED_DOOR = range(4)


def door_cells(model: GridModel, labels: np.ndarray) -> np.ndarray:
    """Indices of the door cells (label open or closed) of a door-world map; empty otherwise."""
    if model.label_names != DOOR_LABELS:
        return np.empty(0, dtype=np.int64)
    labels = np.asarray(labels)
    return np.flatnonzero((labels == OPEN_DOOR) | (labels == CLOSED_DOOR))


DOOR_WORLD_10X10 = """\
.....#....
.....o....
.....#....
##c###..##
.......#..
.......o..
###o####..
.......c..
..#....#..
..#....#..
"""


def parse_layout(layout: str) -> np.ndarray:
    """Text grid (``.`` free, ``#`` wall, ``o`` open door, ``c`` closed door) -> (rows, cols) labels."""
    if not isinstance(layout, str):
        raise ModelError(f"the layout must be a str of . # o c rows, got {type(layout).__name__}")
    lines = [line.strip() for line in layout.strip().splitlines() if line.strip()]
    if not lines:
        raise ModelError("the layout is empty")
    widths = {len(line) for line in lines}
    if len(widths) != 1:
        raise ModelError(f"layout rows have different lengths: {sorted(widths)}")
    for r, line in enumerate(lines):
        for c, ch in enumerate(line):
            if ch not in DOOR_CHARS:
                raise ModelError(f"layout row {r}, column {c}: unknown character {ch!r} (use . # o c)")
    return np.array([[DOOR_CHARS[ch] for ch in line] for line in lines], dtype=np.int64)


def layout_grid(layout) -> np.ndarray:
    """A door-world layout -> (rows, cols) int64 labels: a text layout (:func:`parse_layout`) or a
    2D integer array of door labels in 0..3 (:data:`DOOR_LABELS`), copied."""
    if isinstance(layout, str):
        return parse_layout(layout)
    if isinstance(layout, np.ndarray) and layout.ndim == 2 and layout.size and layout.dtype.kind in "iu":
        if layout.min() < 0 or layout.max() >= len(DOOR_LABELS):
            raise ModelError(f"layout labels must lie in 0..{len(DOOR_LABELS) - 1} {DOOR_LABELS}, "
                             f"got {layout.min()}..{layout.max()}")
        return layout.astype(np.int64)
    described = f"{layout.dtype} array of shape {layout.shape}" if isinstance(layout, np.ndarray) \
        else type(layout).__name__
    raise ModelError(f"the layout must be a str of . # o c rows or a non-empty 2D int array of door labels "
                     f"0..3, got {described}")


def door_change(p_door: float) -> np.ndarray:
    """(4, 4) door-world dynamics: doors swap open/closed with ``p_door``; free and wall never change."""
    p_door = arguments.probability("p_door", p_door)
    change = np.eye(4)
    change[OPEN_DOOR] = [0, 0, 1 - p_door, p_door]
    change[CLOSED_DOOR] = [0, 0, p_door, 1 - p_door]
    return change


def passable_start(labels: np.ndarray, start) -> int:
    """``start`` checked against a door-world layout (rows, cols): a cell index, free or an open door."""
    start = arguments.integer("start", start, minimum=0, maximum=labels.size - 1)
    if labels.flat[start] not in (FREE, OPEN_DOOR):
        raise ModelError(f"start must be a free cell or an open door, cell {start} is "
                         f"{DOOR_LABELS[labels.flat[start]]}")
    return start
