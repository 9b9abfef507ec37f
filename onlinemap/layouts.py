"""Real floors read from the field's grid formats (DESIGN.md section 8), as door worlds.

- **MovingAI / MAPF benchmark** ``.map`` files (Sturtevant 2012): the header lines ``type octile``,
  ``height H``, ``width W`` (either order), ``map``, then H rows of W characters: ``.``, ``G``, ``S``
  passable, ``@``, ``O``, ``T``, ``W`` obstacles. Moves stay 4-connected (north, east, south, west).
- **ROS** ``map_server`` **occupancy grids**: a ``.yaml`` of ``key: value`` lines, ``image`` (a PGM
  file, relative to the YAML's folder) and ``resolution`` (metres per pixel) required;
  ``occupied_thresh`` (default 0.65), ``free_thresh`` (0.196), ``negate`` (0) and ``mode``
  (trinary or scale; raw is refused) read; ``origin`` and other keys ignored. A ``.pgm`` alone is
  read with those defaults and a resolution of one pixel. A pixel of value v out of maxval M is
  occupied with probability ``p = (M - v) / M`` (``v / M`` negated): free when
  ``p < free_thresh``, occupied when ``p > occupied_thresh``, unknown in between. PGM images are
  P5 (binary, 8 or 16 bit) or P2 (ASCII), read with numpy.

**Downsampling** to ``cell_size`` (cells of the ``.map``, metres of a ROS map, pixels of a bare
``.pgm``): a coarse cell of k x k pixels is free only when every one of its pixels is free; any
occupied or unknown pixel makes it a wall. Walls one pixel thin survive every cell size (a robot
never crosses them), at the price of closing passages narrower than about two cells. The grid
is padded with wall to whole cells on the right and bottom.

**Doorways**: a free cell in a one-cell gap of a wall line (wall on its two sides along the line,
free on its two sides across it) becomes an open door when, on both sides across the line, a
diagonal neighbour is free too: the gap joins two open spaces, so a cell inside a corridor one
cell wide (walls at all four diagonals) or a passage through a thick wall is not a door. Cells
off the grid count as wall. Doors in a read layout are open (the files do not say which are
closed).

Malformed files raise :class:`~onlinemap.errors.ModelError` naming the file and the line.
Imports numpy and the model (scipy.ndimage on the first call that picks a start).
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from . import arguments
from .errors import ModelError
from .model import FREE, OPEN_DOOR, WALL, GridModel, door_world, passable_start

MOVINGAI_PASSABLE, MOVINGAI_OBSTACLES = ".GS", "@OTW"
ROS_DEFAULTS = {"occupied_thresh": 0.65, "free_thresh": 0.196, "negate": 0}  # map_server's
_WHITESPACE = b" \t\r\n\v\f"


def _path(path) -> Path:
    if not isinstance(path, (str, os.PathLike)):
        raise ModelError(f"path must be a str or path-like file name, got {type(path).__name__}")
    return Path(path)


def _read(path: Path, what: str) -> bytes:
    try:
        return path.read_bytes()
    except OSError as error:
        raise ModelError(f"{what} {path}: cannot read it ({error.strerror or error})") from None


def read_movingai(path) -> np.ndarray:
    """A MovingAI ``.map`` file -> (H, W) bool, True where passable. O(H W)."""
    path = _path(path)
    lines = _read(path, "map file").decode("latin-1").splitlines()
    header: dict[str, int] = {}
    for number, expected in enumerate(("type", "height or width", "height or width", "map"), 1):
        if number > len(lines):
            raise ModelError(f"{path}, line {number}: the header ends early; expected a {expected!r} line")
        words = lines[number - 1].split()
        key = words[0] if words else ""
        if number == 1 and (key != "type" or len(words) != 2):
            raise ModelError(f"{path}, line 1: expected 'type octile', got {lines[0]!r}")
        if number in (2, 3):
            if key not in ("height", "width") or key in header or len(words) != 2 or not words[1].isdigit() \
                    or int(words[1]) < 1:
                raise ModelError(f"{path}, line {number}: expected 'height H' and 'width W' (whole numbers >= 1, "
                                 f"each once), got {lines[number - 1]!r}")
            header[key] = int(words[1])
        if number == 4 and words != ["map"]:
            raise ModelError(f"{path}, line 4: expected 'map', got {lines[3]!r}")
    height, width = header["height"], header["width"]
    rows = [line.rstrip() for line in lines[4:]]
    while rows and not rows[-1]:
        rows.pop()
    if len(rows) != height:
        raise ModelError(f"{path}, line {4 + len(rows)}: {len(rows)} map rows, the header says height {height}")
    passable = np.zeros((height, width), dtype=bool)
    for r, row in enumerate(rows):
        if len(row) != width:
            raise ModelError(f"{path}, line {5 + r}: a row of {len(row)} characters, the header says width {width}")
        bad = next((c for c, ch in enumerate(row) if ch not in MOVINGAI_PASSABLE + MOVINGAI_OBSTACLES), None)
        if bad is not None:
            raise ModelError(f"{path}, line {5 + r}, column {bad + 1}: unknown character {row[bad]!r} (passable: "
                             f"{' '.join(MOVINGAI_PASSABLE)}; obstacles: {' '.join(MOVINGAI_OBSTACLES)})")
        passable[r] = [ch in MOVINGAI_PASSABLE for ch in row]
    return passable


def _pgm_tokens(path: Path, data: bytes, count: int) -> tuple[list[tuple[bytes, int]], int]:
    """The first ``count`` header tokens of a PGM file with their line numbers (``#`` comments
    skipped), and the position just after the last one."""
    tokens, pos, line = [], 0, 1
    while len(tokens) < count:
        while pos < len(data) and (data[pos] in _WHITESPACE or data[pos] == ord("#")):
            if data[pos] == ord("#"):
                while pos < len(data) and data[pos] != ord("\n"):
                    pos += 1
            else:
                line += data[pos] == ord("\n")
                pos += 1
        if pos >= len(data):
            raise ModelError(f"{path}, line {line}: the PGM header ends early; expected the magic number (P5 or "
                             "P2), width, height and maxval")
        end = pos
        while end < len(data) and data[end] not in _WHITESPACE and data[end] != ord("#"):
            end += 1
        tokens.append((data[pos:end], line))
        pos = end
    return tokens, pos


def read_pgm(path) -> tuple[np.ndarray, int]:
    """A PGM image (P5 binary or P2 ASCII) -> ((H, W) int64 pixel values, maxval). O(H W)."""
    path = _path(path)
    data = _read(path, "image")
    tokens, pos = _pgm_tokens(path, data, 4)
    (magic, magic_line), *sizes = tokens
    if magic not in (b"P5", b"P2"):
        raise ModelError(f"{path}, line {magic_line}: not a PGM image: magic number {magic[:8]!r}, expected P5 "
                         "(binary) or P2 (ASCII)")
    values = []
    for (token, line), name, high in zip(sizes, ("width", "height", "maxval"), (2**24, 2**24, 65535)):
        if not token.isdigit() or not 1 <= int(token) <= high:
            raise ModelError(f"{path}, line {line}: the PGM {name} must be a whole number in 1..{high}, "
                             f"got {token[:12]!r}")
        values.append(int(token))
    width, height, maxval = values
    last_line = sizes[-1][1]
    if magic == b"P5":
        dtype = np.dtype(np.uint8) if maxval < 256 else np.dtype(">u2")
        raster = data[pos + 1:]  # one whitespace byte ends the header
        need = width * height * dtype.itemsize
        if len(raster) < need:
            raise ModelError(f"{path}, after line {last_line}: the raster holds {len(raster)} bytes, a {width} x "
                             f"{height} image of maxval {maxval} needs {need}")
        pixels = np.frombuffer(raster, dtype=dtype, count=width * height).astype(np.int64)
    else:
        pixels = np.empty(width * height, dtype=np.int64)
        filled, line = 0, last_line
        for line, text in enumerate(data[pos:].decode("latin-1").split("\n"), last_line):
            for token in text.split("#", 1)[0].split():
                if not token.isdigit():
                    raise ModelError(f"{path}, line {line}: pixel value {token[:12]!r} is not a whole number")
                if filled == pixels.size:
                    raise ModelError(f"{path}, line {line}: more than {width} x {height} pixel values")
                pixels[filled] = int(token)
                filled += 1
        if filled < pixels.size:
            raise ModelError(f"{path}, line {line}: {filled} pixel values, a {width} x {height} image needs "
                             f"{pixels.size}")
    if pixels.max() > maxval:
        index = int(np.argmax(pixels > maxval))
        raise ModelError(f"{path}: pixel {divmod(index, width)} (row, column) is {pixels[index]}, above maxval "
                         f"{maxval}")
    return pixels.reshape(height, width), maxval


def _yaml_entries(path: Path) -> dict[str, tuple[str, int]]:
    """The ``key: value`` lines of a map_server YAML: {key: (value text, line number)}."""
    entries = {}
    for number, raw in enumerate(_read(path, "map file").decode("latin-1").splitlines(), 1):
        text = raw.split("#", 1)[0].strip()
        if not text:
            continue
        key, colon, value = text.partition(":")
        if not colon or not key.strip():
            raise ModelError(f"{path}, line {number}: expected 'key: value', got {raw!r}")
        entries[key.strip()] = (value.strip().strip("\"'"), number)
    return entries


def read_ros_map(path) -> tuple[np.ndarray, float | None]:
    """A map_server ``.yaml`` and its PGM image (or a ``.pgm`` alone) -> ((H, W) bool, True where
    free; the resolution in metres per pixel, None for a bare ``.pgm``). O(H W)."""
    path = _path(path)
    if path.suffix.lower() == ".pgm":
        settings, resolution, image = dict(ROS_DEFAULTS), None, path
    else:
        entries = _yaml_entries(path)
        for key in ("image", "resolution"):
            if key not in entries:
                raise ModelError(f"{path}: no '{key}:' line (map_server needs image and resolution)")

        def number(key: str, low: float, high: float, default: float | None = None) -> float:
            if key not in entries:
                return default
            text, line = entries[key]
            try:
                return arguments.real(key, float(text), low=low, high=high)
            except (ValueError, ModelError):
                raise ModelError(f"{path}, line {line}: {key} must be a number in [{low:g}, {high:g}], "
                                 f"got {text!r}") from None

        resolution = number("resolution", 0.0, math.inf)
        if resolution <= 0 or not math.isfinite(resolution):
            raise ModelError(f"{path}, line {entries['resolution'][1]}: resolution must be a positive number of "
                             f"metres per pixel, got {entries['resolution'][0]!r}")
        settings = {key: number(key, 0.0, 1.0, default) for key, default in ROS_DEFAULTS.items()}
        if settings["negate"] not in (0.0, 1.0):
            raise ModelError(f"{path}, line {entries['negate'][1]}: negate must be 0 or 1")
        mode, mode_line = entries.get("mode", ("trinary", 0))
        if mode not in ("trinary", "scale"):
            raise ModelError(f"{path}, line {mode_line}: mode {mode!r} is not read (trinary or scale)")
        text, line = entries["image"]
        image = path.parent / text
        if image.suffix.lower() != ".pgm":
            raise ModelError(f"{path}, line {line}: image {text!r} is not a .pgm (only PGM images are read)")
        if not image.is_file():
            raise ModelError(f"{path}, line {line}: image {text!r} not found (looked for {image})")
        if settings["free_thresh"] > settings["occupied_thresh"]:
            raise ModelError(f"{path}: free_thresh {settings['free_thresh']} is above occupied_thresh "
                             f"{settings['occupied_thresh']}")
    pixels, maxval = read_pgm(image)
    occupancy = (pixels if settings["negate"] else maxval - pixels) / maxval
    return occupancy < settings["free_thresh"], resolution


def downsample(free: np.ndarray, factor: int) -> np.ndarray:
    """(H, W) bool -> (ceil(H / k), ceil(W / k)) bool: a coarse cell is free when all its k x k
    pixels are (the grid padded with non-free pixels). O(H W)."""
    height, width = free.shape
    rows, cols = -(-height // factor), -(-width // factor)
    padded = np.zeros((rows * factor, cols * factor), dtype=bool)
    padded[:height, :width] = free
    return padded.reshape(rows, factor, cols, factor).all(axis=(1, 3))


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


def _factor(path: Path, cell_size, resolution: float | None) -> int:
    """Pixels per coarse cell for ``cell_size`` in metres (``resolution`` metres a pixel), or in
    pixels when ``resolution`` is None."""
    if cell_size is None:
        return 1
    if resolution is None:
        return arguments.integer("cell_size", cell_size, minimum=1)
    size = arguments.real("cell_size", cell_size, low=0.0, high=math.inf, low_open=True, high_open=True)
    factor = round(size / resolution)
    if factor < 1 or abs(factor * resolution - size) > 1e-6 * size:
        raise ModelError(f"cell_size {size} m is not a whole multiple of {path}'s resolution {resolution} m")
    return factor


def layout_labels(path, *, cell_size=None, doorways: bool = True) -> np.ndarray:
    """The (rows, cols) int64 door labels of a floor file (the module's docstring): a ``.map``,
    a map_server ``.yaml`` or a ``.pgm``, downsampled to ``cell_size`` (None: one pixel a cell),
    doorways marked as open doors unless ``doorways=False``. O(pixels)."""
    path = _path(path)
    doorways = arguments.flag("doorways", doorways)
    suffix = path.suffix.lower()
    if suffix == ".map":
        free, resolution = read_movingai(path), None
    elif suffix in (".yaml", ".yml", ".pgm"):
        free, resolution = read_ros_map(path)
    else:
        raise ModelError(f"{path}: unknown floor format {suffix or '(no suffix)'!r}; read are .map (MovingAI), "
                         ".yaml (ROS map_server) and .pgm")
    free = downsample(free, _factor(path, cell_size, resolution))
    if not free.any():
        raise ModelError(f"{path}: no free cell" + ("" if cell_size is None else f" at cell_size {cell_size}"))
    return doorway_labels(free) if doorways else np.where(free, FREE, WALL).astype(np.int64)


def largest_region_start(labels: np.ndarray) -> int:
    """The first free cell, row-major, of the largest 4-connected region of free cells and open
    doors (ties: the region met first). labels (rows, cols). O(rows cols)."""
    from scipy import ndimage  # 0.4 s to import: only here, so that ``import onlinemap`` stays light

    regions, _ = ndimage.label(labels != WALL)
    sizes = np.bincount(regions.ravel())
    sizes[0] = 0
    return int(np.flatnonzero((regions.ravel() == np.argmax(sizes)) & (labels.ravel() == FREE))[0])


def read_layout(path, *, cell_size=None, doorways: bool = True, p_obs: float = 0.9, p_move: float = 0.8,
                p_door: float = 0.0, start: int | None = None, label_prior=None, blocking: bool = True,
                footprint="cross") -> tuple[GridModel, np.ndarray]:
    """A floor read from a file (:func:`layout_labels`) as a door world: ``(model, true_map)``, as
    :func:`onlinemap.building` gives one (walls and closed doors block, the sensor reads a cross,
    by default; the model options go to :func:`~onlinemap.model.door_world`). ``start``: a free
    cell or open door, by default :func:`largest_region_start`. true_map (N,) read-only; the labels are
    ``true_map.reshape(model.shape)``. Cost O(pixels) to read, then the model's O(N F)."""
    labels = layout_labels(path, cell_size=cell_size, doorways=doorways)
    start = largest_region_start(labels) if start is None else passable_start(labels, start)
    return door_world(labels, p_obs=p_obs, p_move=p_move, p_door=p_door, start=start, label_prior=label_prior,
                      blocking=blocking, footprint=footprint)


__all__ = ["read_layout", "layout_labels", "read_movingai", "read_ros_map", "read_pgm", "downsample",
           "doorway_labels", "largest_region_start", "MOVINGAI_PASSABLE", "MOVINGAI_OBSTACLES", "ROS_DEFAULTS"]
