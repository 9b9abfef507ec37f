"""Real floors read from the field's grid formats (DESIGN.md section 8), as door worlds: a floor
file (MovingAI ``.map``, ROS ``map_server`` ``.yaml`` + ``.pgm``, or a bare ``.pgm``; the formats
and the file limits: :mod:`onlinemap.floor_files`) cropped to a region, downsampled to a cell
size and its doorways marked as doors.

**Region** (``region=``): the part of the file to read, before downsampling, in the file's units:
``((row0, row1), (col0, col1))`` cells of a ``.map`` or pixels of a ``.pgm`` (half-open, as a
slice), ``((x0, x1), (y0, y1))`` metres of a ROS map in its frame (every pixel that overlaps the
rectangle).

**Downsampling** to ``cell_size`` (cells of the ``.map``, metres of a ROS map, pixels of a bare
``.pgm``): a ROS cell size becomes ``k = round(cell_size / resolution)`` pixels (a warning when
that is not exact). Coarse cells of k x k pixels start at the region's top-left corner; the
grid is padded with non-free pixels to whole cells on the right and bottom. ``cell_rule`` says
which coarse cells are free (s = the share of a cell's k^2 pixels that are not free):

- ``"majority"`` (default): free when more than half its pixels are free (s < 1/2) and no
  whole row or column of its pixels is non-free. A passage one pixel wide stays open (a
  doorway in a wall one pixel thick leaves 3 of 4 pixels free at k = 2), and a straight wall
  one pixel thin still walls every cell it crosses; a diagonal wall one pixel thin may leak.
- ``"any"``: free only when every pixel is free (s = 0): walls survive every cell size, at the
  price of closing passages narrower than about two cells.
- ``"threshold"``: free unless ``s > occupied_thresh`` (the file's, map_server's 0.65 for a
  ``.map`` or a bare ``.pgm``): the trinary rule applied to the coarse cell; thin walls vanish.

**Doorways**: a free cell in a one-cell gap of a wall line (wall on its two sides along the line,
free on its two sides across it) becomes an open door when, on both sides across the line, a
diagonal neighbour is free too: the gap joins two open spaces, so a cell inside a corridor one
cell wide (walls at all four diagonals) or a passage through a thick wall is not a door. Cells
off the grid count as wall. Doors in a read layout are open (the files do not say which are
closed). ``doorways=False`` keeps every free cell free.

**Limits**, checked before the pixels are decoded: the file's (:mod:`onlinemap.floor_files`), and at
most :data:`~onlinemap.arguments.MAX_CELLS` cells after ``region`` and ``cell_size``. Above
:data:`LARGE_FLOOR_CELLS` cells without ``cell_size`` a
:class:`~onlinemap.errors.LargeFloorWarning` gives the cost of a step; a start that reaches
less than half the free cells gives a :class:`~onlinemap.errors.SmallRegionWarning`.

Malformed files raise :class:`~onlinemap.errors.FloorFileError` naming the file and the line.
Imports numpy and the model (scipy.ndimage on the first call that picks a start).
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from pathlib import Path

import numpy as np

from . import arguments
from .door_layouts import FREE, OPEN_DOOR, WALL, passable_start
from .errors import FloorFileError, FloorFileWarning, LargeFloorWarning, SmallRegionWarning
# The file readers live in floor_files; their public names are importable from here too.
from .floor_files import (MAX_FILE_BYTES, MAX_PIXELS, MOVINGAI_OBSTACLES, MOVINGAI_PASSABLE,
                          ROS_DEFAULTS, FloorSource, floor_source, read_movingai, read_pgm, read_ros_map)
from .grids import footprint_offsets
from .model import GridModel, door_world

CELL_RULES = ("majority", "any", "threshold")
LARGE_FLOOR_CELLS = 2**14  # 128 x 128: above it, a floor read without cell_size warns
BK_SECONDS_PER_CELL = 6e-6  # a BK step on a read floor (blocking walls, cross footprint): 28 ms at 5929 cells,
# 0.26 s at 36864, 0.88 s at 147456 (tb3_world at 0.25 m, 0.1 m, 0.05 m; 2-core Xeon)


def downsample(free: np.ndarray, factor: int, rule: str = "majority", occupied_thresh: float = 0.65) -> np.ndarray:
    """(H, W) bool -> (ceil(H / k), ceil(W / k)) bool, the coarse cells free under ``rule`` (the
    module's docstring; pixels past the edge count as not free). O(H W) time, O(H W / k) memory
    (no padded copy)."""
    rule = arguments.choice("cell_rule", rule, CELL_RULES)
    k = arguments.integer("factor", factor, minimum=1)
    if k == 1:  # every rule keeps a pixel as it is
        return free.copy()
    height, width = free.shape
    row_starts, col_starts = np.arange(0, height, k), np.arange(0, width, k)
    by_row = np.add.reduceat(free, col_starts, axis=1, dtype=np.int32)  # (H, C): free pixels per row of a cell
    count = np.add.reduceat(by_row, row_starts, axis=0)  # (R, C)
    if rule == "any":
        return count == k * k
    if rule == "threshold":
        return (k * k - count) <= occupied_thresh * k * k
    blocked_row = np.logical_or.reduceat(by_row == 0, row_starts, axis=0)
    blocked_col = np.logical_or.reduceat(np.add.reduceat(free, row_starts, axis=0, dtype=np.int32) == 0,
                                         col_starts, axis=1)
    if height % k:
        blocked_row[-1] = True  # a padded row is wholly non-free
    if width % k:
        blocked_col[:, -1] = True
    return (2 * count > k * k) & ~blocked_row & ~blocked_col


def doorway_labels(free: np.ndarray) -> np.ndarray:
    """(R, C) bool free cells -> (R, C) int64 door labels, the doorways (module docstring) open
    doors, the rest free or wall. O(R C)."""
    p = np.pad(free, 1, constant_values=False)
    north, south, west, east = p[:-2, 1:-1], p[2:, 1:-1], p[1:-1, :-2], p[1:-1, 2:]
    nw, ne, sw, se = p[:-2, :-2], p[:-2, 2:], p[2:, :-2], p[2:, 2:]
    in_wall_row = ~west & ~east & north & south & (nw | ne) & (sw | se)  # passage north-south
    in_wall_column = ~north & ~south & west & east & (nw | sw) & (ne | se)  # passage west-east
    labels = np.where(free, FREE, WALL).astype(np.int64)
    labels[free & (in_wall_row | in_wall_column)] = OPEN_DOOR
    return labels


def _snap(value: float) -> float:
    """``value`` rounded to a whole number when within 1e-9 of one: 0.15 / 0.05 is 2.9999999999999996."""
    nearest = round(value)
    return float(nearest) if abs(value - nearest) <= 1e-9 * max(1.0, abs(value)) else value


def _factor(source: FloorSource, cell_size) -> int:
    """Pixels per coarse cell: ``cell_size`` in metres (a ROS map) or in pixels, at most the
    map's longer side."""
    if cell_size is None:
        return 1
    longest = max(source.shape)
    if source.resolution is None:
        factor = arguments.integer("cell_size", cell_size, minimum=1, error=FloorFileError)
        unit = ""
    else:
        size = arguments.real("cell_size", cell_size, low=0.0, high=math.inf, low_open=True, high_open=True,
                              error=FloorFileError)
        ratio = size / source.resolution
        if not ratio <= longest + 0.5:  # also inf: resolution 1e-320
            factor = math.inf
        else:
            factor = round(_snap(ratio))
            if factor < 1:
                raise FloorFileError(f"cell_size {size} m is below half of {source.path}'s resolution "
                                     f"{source.resolution} m")
            if factor != _snap(ratio):
                warnings.warn(f"cell_size {size} m is {ratio:.4g} pixels of {source.resolution} m: read as {factor} "
                              f"pixels, {factor * source.resolution:.6g} m", FloorFileWarning, stacklevel=4)
        unit = f" m ({ratio:.3g} pixels)"
    if factor > longest:
        raise FloorFileError(f"cell_size {cell_size}{unit} is larger than {source.path} ({source.shape[0]} x "
                             f"{source.shape[1]} pixels)")
    return factor


@dataclasses.dataclass(frozen=True)
class FloorFrame:
    """Where the cells of a floor read with :func:`layout_labels` lie in the file and in the map
    frame. ``pixels`` the file's (rows, cols); ``top``, ``left`` the region's first pixel row
    and column; ``factor`` pixels per cell; ``shape`` the grid's (rows, cols); ``resolution``
    metres per pixel and ``origin`` (x, y, yaw) of a ROS map (None otherwise)."""
    path: Path
    pixels: tuple[int, int]
    rows: tuple[int, int]  # the region's pixel rows, half-open
    cols: tuple[int, int]  # and columns
    factor: int
    shape: tuple[int, int]
    resolution: float | None
    origin: tuple[float, float, float] | None

    def _metric(self) -> tuple[float, float, float]:
        if self.resolution is None:
            raise FloorFileError(f"{self.path} has no map frame (no resolution and origin): a .map or a bare .pgm "
                                 "is addressed in cells")
        return self.resolution, self.origin[0], self.origin[1]

    def cell(self, x: float, y: float) -> int:
        """The index (row-major) of the cell holding the point (x, y) metres of the map frame;
        a point on a pixel edge belongs to the pixel east or north of it. O(1)."""
        resolution, x0, y0 = self._metric()
        x = arguments.real("x", x, error=FloorFileError)
        y = arguments.real("y", y, error=FloorFileError)
        col = math.floor(_snap((x - x0) / resolution))
        row = self.pixels[0] - 1 - math.floor(_snap((y - y0) / resolution))  # row 0 is the image's top
        if not (self.rows[0] <= row < self.rows[1] and self.cols[0] <= col < self.cols[1]):
            (xa, xb), (ya, yb) = self.bounds()
            raise FloorFileError(f"point ({x:g}, {y:g}) m is off the part of {self.path} read: x in [{xa:g}, {xb:g}), "
                                 f"y in [{ya:g}, {yb:g})")
        return int((row - self.rows[0]) // self.factor * self.shape[1] + (col - self.cols[0]) // self.factor)

    def point(self, cell) -> tuple[float, float]:
        """The map-frame centre (x, y) in metres of a cell (index row-major). O(1)."""
        resolution, x0, y0 = self._metric()
        cell = arguments.integer("cell", cell, minimum=0, maximum=self.shape[0] * self.shape[1] - 1,
                                 error=FloorFileError)
        r, c = divmod(cell, self.shape[1])
        row = self.rows[0] + (r + 0.5) * self.factor  # in pixels from the image's top edge
        col = self.cols[0] + (c + 0.5) * self.factor
        return x0 + col * resolution, y0 + (self.pixels[0] - row) * resolution

    def bounds(self) -> tuple[tuple[float, float], tuple[float, float]]:
        """((x_min, x_max), (y_min, y_max)) metres of the region read (the padding of the last
        row and column of cells excluded)."""
        resolution, x0, y0 = self._metric()
        height = self.pixels[0]
        return ((x0 + self.cols[0] * resolution, x0 + self.cols[1] * resolution),
                (y0 + (height - self.rows[1]) * resolution, y0 + (height - self.rows[0]) * resolution))


def _pair(name: str, value) -> tuple[float, float]:
    if not isinstance(value, (tuple, list)) or len(value) != 2:
        raise FloorFileError(f"region's {name} must be a pair (low, high), got {value!r}")
    low, high = (arguments.real(f"region's {name}", v, error=FloorFileError) for v in value)
    if not low < high:
        raise FloorFileError(f"region's {name} must have low < high, got {value!r}")
    return low, high


def _region(source: FloorSource, region) -> tuple[int, int, int, int]:
    """The pixel rectangle (top, bottom, left, right), half-open, of ``region`` (module docstring)."""
    height, width = source.shape
    if region is None:
        return 0, height, 0, width
    if not isinstance(region, (tuple, list)) or len(region) != 2:
        raise FloorFileError(f"region must be ((row0, row1), (col0, col1)) cells, or ((x0, x1), (y0, y1)) metres of a "
                             f"ROS map, got {region!r}")
    if source.resolution is None:
        (top, bottom), (left, right) = (
            tuple(arguments.integer(f"region's {name}", v, error=FloorFileError) for v in _pair(name, pair))
            for name, pair in zip(("rows", "cols"), region))
        if not (0 <= top and bottom <= height and 0 <= left and right <= width):
            raise FloorFileError(f"region rows {top}..{bottom}, cols {left}..{right} is not inside {source.path}'s "
                                 f"{height} x {width} cells (rows 0..{height}, cols 0..{width})")
        return top, bottom, left, right
    (xa, xb), (ya, yb) = (_pair(name, pair) for name, pair in zip(("x", "y"), region))
    resolution, (x0, y0, _) = source.resolution, source.origin
    left, right = math.floor(_snap((xa - x0) / resolution)), math.ceil(_snap((xb - x0) / resolution))
    top = height - math.ceil(_snap((yb - y0) / resolution))
    bottom = height - math.floor(_snap((ya - y0) / resolution))
    if not (0 <= top and bottom <= height and 0 <= left and right <= width):
        raise FloorFileError(f"region x {xa:g}..{xb:g} m, y {ya:g}..{yb:g} m is not inside {source.path}'s map: x in "
                             f"[{x0:g}, {x0 + width * resolution:g}], y in [{y0:g}, {y0 + height * resolution:g}]")
    return top, bottom, left, right


def _frame(source: FloorSource, cell_size, region, footprint=None) -> FloorFrame:
    """The frame of ``source`` read at ``cell_size`` over ``region``, refused when its cells
    times the footprint's offsets (as the model counts them) are above the cell cap."""
    factor = _factor(source, cell_size)
    top, bottom, left, right = _region(source, region)
    shape = (-(-(bottom - top) // factor), -(-(right - left) // factor))
    cells, offsets = shape[0] * shape[1], len(footprint_offsets(footprint))
    if cells * offsets > arguments.MAX_CELLS:
        read = f"x {offsets} cells read a step " if offsets > 1 else ""
        raise FloorFileError(f"{source.path}: {shape[0]} x {shape[1]} = {cells} cells {read}at cell_size {cell_size}, "
                             f"above the limit of {arguments.MAX_CELLS}; give a larger cell_size or a region")
    if shape[0] < 2:
        raise FloorFileError(f"{source.path}: the floor is one cell high at cell_size {cell_size} (a door world "
                             "needs two rows or more); give a smaller cell_size or a taller region")
    return FloorFrame(source.path, source.shape, (top, bottom), (left, right), factor, shape, source.resolution,
                      source.origin)


def floor_frame(path, *, cell_size=None, region=None) -> FloorFrame:
    """The :class:`FloorFrame` of ``layout_labels(path, cell_size=..., region=...)``: reads the
    header only. ``frame.cell(x, y)`` gives a goal or start given in metres of a ROS map's frame,
    ``frame.point(cell)`` the centre of a cell in metres."""
    return _frame(floor_source(path), cell_size, region)


def _large_floor_warning(frame: FloorFrame) -> None:
    cells = frame.shape[0] * frame.shape[1]
    factor = math.ceil(math.sqrt(cells / LARGE_FLOOR_CELLS))
    advice = f"cell_size={factor * frame.resolution:g}" if frame.resolution else f"cell_size={factor}"
    warnings.warn(f"{frame.path}: {frame.shape[0]} x {frame.shape[1]} = {cells} cells at one pixel a cell: a BK step "
                  f"takes about {cells * BK_SECONDS_PER_CELL:.2g} s (O(N) at about {BK_SECONDS_PER_CELL * 1e6:g} us a "
                  f"cell, measured) and every plan solves an MDP over {cells} cells; give {advice} or a region to read at most {LARGE_FLOOR_CELLS} cells",
                  LargeFloorWarning, stacklevel=3)


def layout_labels(path, *, cell_size=None, doorways: bool = True, cell_rule: str = "majority",
                  region=None) -> np.ndarray:
    """The (rows, cols) int64 door labels of a floor file (the module's docstring): a ``.map``,
    a map_server ``.yaml`` or a ``.pgm``, cropped to ``region``, downsampled to ``cell_size``
    (None: one pixel a cell) under ``cell_rule``, doorways marked as open doors unless
    ``doorways=False``. Sizes are checked against the limits before the pixels are decoded.
    O(pixels)."""
    source = floor_source(path)
    return _labels(source, _frame(source, cell_size, region), cell_size, doorways, cell_rule)


def _labels(source: FloorSource, frame: FloorFrame, cell_size, doorways, cell_rule) -> np.ndarray:
    """:func:`layout_labels` of a file whose header and frame are checked."""
    path = source.path
    doorways = arguments.flag("doorways", doorways, error=FloorFileError)
    cell_rule = arguments.choice("cell_rule", cell_rule, CELL_RULES, error=FloorFileError)
    if cell_size is None and frame.shape[0] * frame.shape[1] > LARGE_FLOOR_CELLS:
        _large_floor_warning(frame)
    (top, bottom), (left, right) = frame.rows, frame.cols
    free = downsample(source.decode()[top:bottom, left:right], frame.factor, cell_rule, source.occupied_thresh)
    if not free.any():
        size = "" if cell_size is None else f" at cell_size {cell_size} with cell_rule {cell_rule!r}"
        hint = "" if cell_size is None or cell_rule == "threshold" else (
            "; passages narrower than the cell size close: try a smaller cell_size or cell_rule='threshold'")
        raise FloorFileError(f"{path}: no free cell{size}{hint}")
    return doorway_labels(free) if doorways else np.where(free, FREE, WALL).astype(np.int64)


def _regions(labels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """4-connected regions of free cells and open doors: (region id per cell (rows, cols), 0 for
    walls; cells per region id, 0 for id 0)."""
    from scipy import ndimage  # 0.4 s to import: only here, so that ``import onlinemap`` stays light

    regions, _ = ndimage.label(labels != WALL)
    sizes = np.bincount(regions.ravel())
    sizes[0] = 0
    return regions, sizes


def largest_region_start(labels: np.ndarray) -> int:
    """The first free cell, row-major, of the largest 4-connected region of free cells and open
    doors (ties: the region met first). labels (rows, cols). O(rows cols)."""
    regions, sizes = _regions(labels)
    return int(np.flatnonzero((regions.ravel() == np.argmax(sizes)) & (labels.ravel() == FREE))[0])


def read_layout(path, *, cell_size=None, doorways: bool = True, cell_rule: str = "majority", region=None,
                p_obs: float = 0.9, p_move: float = 0.8, p_door: float = 0.0, start: int | None = None,
                label_prior=None, blocking: bool = True, footprint="cross") -> tuple[GridModel, np.ndarray]:
    """A floor read from a file (:func:`layout_labels`) as a door world: ``(model, true_map)``, as
    :func:`onlinemap.building` gives one (walls and closed doors block, the sensor reads a cross,
    by default; the model options go to :func:`~onlinemap.model.door_world`; without ``label_prior``
    the floor's label frequencies are unknown and estimators learn them). ``start``: a free
    cell or open door, by default :func:`largest_region_start`; a start whose region holds less
    than half the free cells and open doors warns (:class:`~onlinemap.errors.SmallRegionWarning`).
    true_map (N,) read-only; the labels are ``true_map.reshape(model.shape)``. Cost O(pixels) to
    read, then the model's O(N F)."""
    source = floor_source(path)
    frame = _frame(source, cell_size, region, footprint)  # the model's cap, checked on the header
    labels = _labels(source, frame, cell_size, doorways, cell_rule)
    start = largest_region_start(labels) if start is None else passable_start(labels, start)
    regions, sizes = _regions(labels)
    reached, total = int(sizes[regions.flat[start]]), int(sizes.sum())
    if 2 * reached < total:
        row, col = divmod(start, labels.shape[1])
        read = f"cell_rule {cell_rule!r}" + ("" if cell_size is None else f" at cell_size {cell_size}")
        warnings.warn(f"{path}: the start (row {row}, col {col}) reaches {reached} of the {total} free cells "
                      f"({reached / total:.0%}; {int((sizes > 0).sum())} separate regions, {read}): the robot "
                      "cannot visit the rest", SmallRegionWarning, stacklevel=2)
    return door_world(labels, p_obs=p_obs, p_move=p_move, p_door=p_door, start=start, label_prior=label_prior,
                      blocking=blocking, footprint=footprint, unknown_label_frequencies=label_prior is None)


__all__ = ["read_layout", "layout_labels", "floor_frame", "FloorFrame", "read_movingai", "read_ros_map", "read_pgm",
           "downsample", "doorway_labels", "largest_region_start", "MOVINGAI_PASSABLE", "MOVINGAI_OBSTACLES",
           "ROS_DEFAULTS", "CELL_RULES", "MAX_FILE_BYTES", "MAX_PIXELS", "LARGE_FLOOR_CELLS"]
