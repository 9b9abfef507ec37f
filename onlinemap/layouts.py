"""Real floors read from the field's grid formats (DESIGN.md section 8), as door worlds.

- **MovingAI / MAPF benchmark** ``.map`` files (Sturtevant 2012): the header lines ``type octile``,
  ``height H``, ``width W`` (either order), ``map``, then H rows of W characters: ``.``, ``G``, ``S``
  passable, ``@``, ``O``, ``T``, ``W`` obstacles (``T`` trees, ``W`` water: a ground robot
  crosses neither). Moves stay 4-connected (north, east, south, west). A file without its
  ``type`` line (common in the field) is read with a :class:`~onlinemap.errors.FloorFileWarning`.
- **ROS** ``map_server`` **occupancy grids**: a ``.yaml`` of ``key: value`` lines, ``image`` (a PGM
  file, relative to the YAML's folder) and ``resolution`` (metres per pixel) required;
  ``occupied_thresh`` (default 0.65), ``free_thresh`` (0.196), ``negate`` (0), ``mode``
  (trinary or scale; raw is refused) and ``origin`` ([x, y, yaw], default [0, 0, 0]) read; other
  keys ignored; a key given twice is refused. A ``.pgm`` alone is read with those defaults and a
  resolution of one pixel. A pixel of value v out of maxval M is occupied with probability
  ``p = (M - v) / M`` (``v / M`` negated): free when ``p < free_thresh``; occupied or unknown
  pixels are not free. PGM images are P5 (binary, 8 or 16 bit) or P2 (ASCII), read with numpy.
  **Rows**: row 0 of the grid is the image's top row, which map_server puts at the largest y
  of the map frame; ``origin`` is the map-frame pose of the bottom-left corner of the image
  (its last row's first pixel), so pixel (row i, column j) of an H-row image covers
  ``x in [x0 + j r, x0 + (j + 1) r)``, ``y in [y0 + (H - 1 - i) r, y0 + (H - i) r)``.
  :func:`floor_frame` turns metres into cells and back (the yaw is ignored, with a warning, as
  much of ROS does).

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

**Limits**, checked before the pixels are decoded: only regular files (a FIFO, a device, a
directory is refused without being opened for reading), at most :data:`MAX_FILE_BYTES` bytes and
:data:`MAX_PIXELS` pixels, header sizes in strict ASCII digits, and at most
:data:`~onlinemap.arguments.MAX_CELLS` cells after ``region`` and ``cell_size``. Above
:data:`LARGE_FLOOR_CELLS` cells without ``cell_size`` a
:class:`~onlinemap.errors.LargeFloorWarning` gives the cost of a step; a start that reaches
less than half the free cells gives a :class:`~onlinemap.errors.SmallRegionWarning`.

Malformed files raise :class:`~onlinemap.errors.FloorFileError` naming the file and the line.
Imports numpy and the model (scipy.ndimage on the first call that picks a start).
"""

from __future__ import annotations

import dataclasses
import math
import os
import re
import stat
import warnings
from pathlib import Path
from typing import Callable, NamedTuple

import numpy as np

from . import arguments
from .errors import FloorFileError, FloorFileWarning, LargeFloorWarning, ModelError, SmallRegionWarning
from .model import FREE, OPEN_DOOR, WALL, GridModel, _footprint, door_world, passable_start

MOVINGAI_PASSABLE, MOVINGAI_OBSTACLES = ".GS", "@OTW"
ROS_DEFAULTS = {"occupied_thresh": 0.65, "free_thresh": 0.196, "negate": 0}  # map_server's
CELL_RULES = ("majority", "any", "threshold")
MAX_FILE_BYTES = 2**28  # 256 MiB: a 16-bit P5 image of 8192 x 16384 pixels
MAX_PIXELS = 2**28  # pixels of a file before region and cell_size (a bool array of 256 MiB)
LARGE_FLOOR_CELLS = 2**14  # 128 x 128: above it, a floor read without cell_size warns
BK_SECONDS_PER_CELL = 6e-6  # a BK step on a read floor (blocking walls, cross footprint): 28 ms at 5929 cells,
# 0.26 s at 36864, 0.88 s at 147456 (tb3_world at 0.25 m, 0.1 m, 0.05 m; 2-core Xeon)
_WHITESPACE = b" \t\r\n\v\f"
_BOM = b"\xef\xbb\xbf"
_KINDS = ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISCHR, "a character device"),
          (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"))


def _path(path) -> Path:
    if not isinstance(path, (str, os.PathLike)):
        raise FloorFileError(f"path must be a str or path-like file name, got {type(path).__name__}")
    return Path(path)


def _read(path: Path, what: str) -> bytes:
    """The bytes of a regular file, at most :data:`MAX_FILE_BYTES`. Opened without blocking and
    checked with fstat, so a FIFO is refused instead of waited on and a device is never read."""
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except OSError as error:
        raise FloorFileError(f"{what} {path}: cannot read it ({error.strerror or error})") from None
    try:
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):
            kind = next((name for test, name in _KINDS if test(mode)), "not a regular file")
            raise FloorFileError(f"{what} {path} is {kind}, not a regular file")
        chunks, size = [], 0
        while chunk := os.read(fd, min(1 << 20, MAX_FILE_BYTES + 1 - size)):
            chunks.append(chunk)
            size += len(chunk)
            if size > MAX_FILE_BYTES:
                raise FloorFileError(f"{what} {path} is larger than {MAX_FILE_BYTES} bytes, the limit of a floor file")
    except OSError as error:
        raise FloorFileError(f"{what} {path}: cannot read it ({error.strerror or error})") from None
    finally:
        os.close(fd)
    data = b"".join(chunks)
    return data[len(_BOM):] if data.startswith(_BOM) else data


def _whole(token: str | bytes, high: int) -> int | None:
    """``token`` as an int in 0..high when it is ASCII decimal digits only (``str.isdigit`` also
    accepts ``²``), else None; never converts more than 12 digits."""
    if isinstance(token, str):
        if not token.isascii():
            return None
        token = token.encode()
    digits = token.lstrip(b"0") or b"0"
    if not token.isdigit() or len(digits) > 12:
        return None
    value = int(digits)
    return value if value <= high else None


def _check_pixels(path: Path, line: int, height: int, width: int) -> None:
    if height * width > MAX_PIXELS:
        raise FloorFileError(f"{path}, line {line}: {height} x {width} = {height * width} pixels, above the limit of "
                             f"{MAX_PIXELS} a floor file may hold")


class _Source(NamedTuple):
    """A floor file with its header read and its pixels not yet decoded."""
    path: Path
    shape: tuple[int, int]  # (rows, cols) of pixels
    resolution: float | None  # metres per pixel; None for a .map or a bare .pgm
    origin: tuple[float, float, float] | None  # map frame pose of the bottom-left corner (x, y, yaw)
    occupied_thresh: float
    decode: Callable[[], np.ndarray]  # () -> (rows, cols) bool, True where free


def _movingai(path: Path) -> _Source:
    """A MovingAI ``.map``'s header checked against the file's size; its rows decoded later."""
    lines = _read(path, "map file").decode("latin-1").splitlines()
    first = lines[0].split() if lines else []
    typed = not first or first[0] not in ("height", "width")
    if not typed:
        warnings.warn(f"{path}: no 'type octile' line; read as a MovingAI map of type octile", FloorFileWarning,
                      stacklevel=4)
    expected = ("type", "height or width", "height or width", "map")[0 if typed else 1:]
    header: dict[str, int] = {}
    for number, what in enumerate(expected, 1):
        if number > len(lines):
            raise FloorFileError(f"{path}, line {number}: the header ends early; expected a {what!r} line")
        text = lines[number - 1]
        words = text.split()
        key = words[0] if words else ""
        if what == "type" and (key != "type" or len(words) != 2):
            raise FloorFileError(f"{path}, line 1: expected 'type octile', got {text!r}")
        if what == "height or width":
            value = _whole(words[1], 2**31) if len(words) == 2 else None
            if key not in ("height", "width") or key in header or not value:
                raise FloorFileError(f"{path}, line {number}: expected 'height H' and 'width W' (whole numbers >= 1 "
                                     f"in ASCII digits, each once), got {text!r}")
            header[key] = value
        if what == "map" and words != ["map"]:
            raise FloorFileError(f"{path}, line {number}: expected 'map', got {text!r}")
    height, width = header["height"], header["width"]
    top = len(expected)  # lines before the first row
    _check_pixels(path, top - 1, height, width)
    rows = [line.rstrip() for line in lines[top:]]  # checked against the header before any array is made
    while rows and not rows[-1]:
        rows.pop()
    if len(rows) != height:
        raise FloorFileError(f"{path}, line {top + len(rows)}: {len(rows)} map rows, the header says height {height}")
    for r, row in enumerate(rows):
        if len(row) != width:
            raise FloorFileError(f"{path}, line {top + 1 + r}: a row of {len(row)} characters, the header says "
                                 f"width {width}")

    def decode() -> np.ndarray:
        codes = np.frombuffer("".join(rows).encode("latin-1"), dtype=np.uint8)
        kind = np.full(256, 2, dtype=np.uint8)  # 0 obstacle, 1 passable, 2 unknown character
        kind[np.frombuffer(MOVINGAI_PASSABLE.encode(), np.uint8)] = 1
        kind[np.frombuffer(MOVINGAI_OBSTACLES.encode(), np.uint8)] = 0
        cells = kind[codes]
        if (cells == 2).any():
            r, c = divmod(int(np.argmax(cells == 2)), width)
            raise FloorFileError(f"{path}, line {top + 1 + r}, column {c + 1}: unknown character {rows[r][c]!r} "
                                 f"(passable: {' '.join(MOVINGAI_PASSABLE)}; obstacles: {' '.join(MOVINGAI_OBSTACLES)})")
        return (cells == 1).reshape(height, width)

    return _Source(path, (height, width), None, None, ROS_DEFAULTS["occupied_thresh"], decode)


def read_movingai(path) -> np.ndarray:
    """A MovingAI ``.map`` file -> (H, W) bool, True where passable. O(H W)."""
    return _movingai(_path(path)).decode()


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
            raise FloorFileError(f"{path}, line {line}: the PGM header ends early; expected the magic number (P5 or "
                                 "P2), width, height and maxval")
        end = pos
        while end < len(data) and data[end] not in _WHITESPACE and data[end] != ord("#"):
            end += 1
        tokens.append((data[pos:end], line))
        pos = end
    return tokens, pos


def _pgm(path: Path, what: str = "image") -> tuple[tuple[int, int], int, Callable[[], np.ndarray]]:
    """A PGM image's header checked against the file's size -> ((height, width), maxval, a
    function giving the (H, W) uint8 or uint16 pixels)."""
    data = _read(path, what)
    tokens, pos = _pgm_tokens(path, data, 4)
    (magic, magic_line), *sizes = tokens
    if magic not in (b"P5", b"P2"):
        raise FloorFileError(f"{path}, line {magic_line}: not a PGM image: magic number {magic[:8]!r}, expected P5 "
                             "(binary) or P2 (ASCII)")
    values = []
    for (token, line), name, high in zip(sizes, ("width", "height", "maxval"), (2**24, 2**24, 65535)):
        value = _whole(token, high)
        if not value:
            raise FloorFileError(f"{path}, line {line}: the PGM {name} must be a whole number in 1..{high} in ASCII "
                                 f"digits, got {token[:12]!r}")
        values.append(value)
    width, height, maxval = values
    last_line = sizes[-1][1]
    _check_pixels(path, last_line, height, width)
    dtype = np.dtype(np.uint8) if maxval < 256 else np.dtype(">u2")
    if magic == b"P5":
        raster = memoryview(data)[pos + 1:]  # one whitespace byte ends the header
        need = width * height * dtype.itemsize
        if len(raster) < need:
            raise FloorFileError(f"{path}, after line {last_line}: the raster holds {len(raster)} bytes, a {width} x "
                                 f"{height} image of maxval {maxval} needs {need}")

        def pixels() -> np.ndarray:
            return np.frombuffer(raster, dtype=dtype, count=width * height).astype(dtype.newbyteorder("="))
    else:
        text = data[pos:]  # its tokens are counted before any array of width x height is made

        def line_of(index: int) -> int:
            match = next(m for i, m in enumerate(re.finditer(rb"\S+", stripped)) if i == index)
            return last_line + stripped.count(b"\n", 0, match.start())

        stripped = re.sub(rb"#[^\n]*", b"", text)
        words = stripped.split()
        if len(words) > width * height:
            raise FloorFileError(f"{path}, line {line_of(width * height)}: more than {width} x {height} pixel values "
                                 f"({len(words)})")
        if len(words) < width * height:
            line = last_line + stripped.count(b"\n")
            raise FloorFileError(f"{path}, line {line}: {len(words)} pixel values, a "
                                 f"{width} x {height} image needs {width * height}")
        bad = next((i for i, word in enumerate(words) if _whole(word, 65535) is None), None)
        if bad is not None:
            raise FloorFileError(f"{path}, line {line_of(bad)}: pixel value {words[bad][:12].decode('latin-1')!r} is not a whole number "
                                 f"in 0..{maxval} in ASCII digits")

        def pixels() -> np.ndarray:
            return np.array(words).astype(np.uint16)

    def checked() -> np.ndarray:
        image = pixels()
        if image.max() > maxval:
            index = int(np.argmax(image > maxval))
            raise FloorFileError(f"{path}: pixel {divmod(index, width)} (row, column) is {image.flat[index]}, above "
                                 f"maxval {maxval}")
        return image.reshape(height, width)

    return (height, width), maxval, checked


def read_pgm(path) -> tuple[np.ndarray, int]:
    """A PGM image (P5 binary or P2 ASCII) -> ((H, W) int64 pixel values, maxval). O(H W)."""
    _, maxval, pixels = _pgm(_path(path))
    return pixels().astype(np.int64), maxval


def _yaml_entries(path: Path) -> dict[str, tuple[str, int]]:
    """The ``key: value`` lines of a map_server YAML: {key: (value text, line number)}; a key
    given twice is refused (YAML parsers differ on which wins)."""
    try:
        text = _read(path, "map file").decode("utf-8")
    except UnicodeDecodeError as error:
        raise FloorFileError(f"{path}: not UTF-8 text (byte {error.start})") from None
    entries = {}
    for number, raw in enumerate(text.splitlines(), 1):
        text = raw.split("#", 1)[0].strip()
        if not text:
            continue
        key, colon, value = text.partition(":")
        key = key.strip()
        if not colon or not key:
            raise FloorFileError(f"{path}, line {number}: expected 'key: value', got {raw!r}")
        if key in entries:
            raise FloorFileError(f"{path}, line {number}: key {key!r} given twice (first on line {entries[key][1]})")
        entries[key] = (value.strip().strip("\"'"), number)
    return entries


def _ros(path: Path) -> _Source:
    """A map_server ``.yaml`` (or a ``.pgm`` alone): settings read, image header checked."""
    if path.suffix.lower() == ".pgm":
        settings, resolution, origin, image, where = dict(ROS_DEFAULTS), None, None, path, ""
    else:
        entries = _yaml_entries(path)
        for key in ("image", "resolution"):
            if key not in entries:
                raise FloorFileError(f"{path}: no '{key}:' line (map_server needs image and resolution)")

        def number(key: str, low: float, high: float, low_open: bool = False) -> float:
            text, line = entries[key]
            try:
                return arguments.real(key, float(text), low=low, high=high, low_open=low_open, high_open=low_open)
            except (ValueError, ModelError):
                interval = f"({low:g}, {high:g})" if low_open else f"[{low:g}, {high:g}]"
                raise FloorFileError(f"{path}, line {line}: {key} must be a number in {interval}, got {text!r}") from None

        resolution = number("resolution", 0.0, math.inf, low_open=True)
        settings = {key: number(key, 0.0, 1.0) if key in entries else default for key, default in ROS_DEFAULTS.items()}
        if settings["negate"] not in (0.0, 1.0):
            raise FloorFileError(f"{path}, line {entries['negate'][1]}: negate must be 0 or 1")
        mode, mode_line = entries.get("mode", ("trinary", 0))
        if mode not in ("trinary", "scale"):
            raise FloorFileError(f"{path}, line {mode_line}: mode {mode!r} is not read (trinary or scale)")
        origin = _origin(path, *entries["origin"]) if "origin" in entries else (0.0, 0.0, 0.0)
        text, line = entries["image"]
        image, where = path.parent / text, f"{path}, line {line}: "
        if image.suffix.lower() != ".pgm":
            raise FloorFileError(f"{where}image {text!r} is not a .pgm (only PGM images are read)")
        if settings["free_thresh"] > settings["occupied_thresh"]:
            raise FloorFileError(f"{path}: free_thresh {settings['free_thresh']} is above occupied_thresh "
                                 f"{settings['occupied_thresh']}")
    try:
        shape, maxval, pixels = _pgm(image)
    except FloorFileError as error:
        raise FloorFileError(f"{where}{error}") from None

    def decode() -> np.ndarray:
        values = np.arange(maxval + 1)  # occupancy per value, then a table: as exact as per pixel, O(maxval)
        occupancy = (values if settings["negate"] else maxval - values) / maxval
        return (occupancy < settings["free_thresh"])[pixels()]

    return _Source(path, shape, resolution, origin, settings["occupied_thresh"], decode)


def _origin(path: Path, text: str, line: int) -> tuple[float, float, float]:
    parts = text.strip().removeprefix("[").removesuffix("]").split(",")
    try:
        values = tuple(float(part) for part in parts)
    except ValueError:
        values = ()
    if len(values) != 3 or not all(map(math.isfinite, values)):
        raise FloorFileError(f"{path}, line {line}: origin must be [x, y, yaw], three finite numbers, got {text!r}")
    if values[2] != 0.0:
        warnings.warn(f"{path}, line {line}: origin yaw {values[2]} is ignored (rows run along y, columns along x)",
                      FloorFileWarning, stacklevel=5)
    return values


def read_ros_map(path) -> tuple[np.ndarray, float | None]:
    """A map_server ``.yaml`` and its PGM image (or a ``.pgm`` alone) -> ((H, W) bool, True where
    free; the resolution in metres per pixel, None for a bare ``.pgm``). O(H W)."""
    source = _ros(_path(path))
    return source.decode(), source.resolution


def _source(path: Path) -> _Source:
    suffix = path.suffix.lower()
    if suffix == ".map":
        return _movingai(path)
    if suffix in (".yaml", ".yml", ".pgm"):
        return _ros(path)
    raise FloorFileError(f"{path}: unknown floor format {suffix or '(no suffix)'!r}; read are .map (MovingAI), "
                         ".yaml (ROS map_server) and .pgm")


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


def _factor(source: _Source, cell_size) -> int:
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


def _region(source: _Source, region) -> tuple[int, int, int, int]:
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


def _frame(source: _Source, cell_size, region, footprint=None) -> FloorFrame:
    """The frame of ``source`` read at ``cell_size`` over ``region``, refused when its cells
    times the footprint's offsets (as the model counts them) are above the cell cap."""
    factor = _factor(source, cell_size)
    top, bottom, left, right = _region(source, region)
    shape = (-(-(bottom - top) // factor), -(-(right - left) // factor))
    cells, offsets = shape[0] * shape[1], len(_footprint(footprint))
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
    return _frame(_source(_path(path)), cell_size, region)


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
    source = _source(_path(path))
    return _labels(source, _frame(source, cell_size, region), cell_size, doorways, cell_rule)


def _labels(source: _Source, frame: FloorFrame, cell_size, doorways, cell_rule) -> np.ndarray:
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
    by default; the model options go to :func:`~onlinemap.model.door_world`). ``start``: a free
    cell or open door, by default :func:`largest_region_start`; a start whose region holds less
    than half the free cells and open doors warns (:class:`~onlinemap.errors.SmallRegionWarning`).
    true_map (N,) read-only; the labels are ``true_map.reshape(model.shape)``. Cost O(pixels) to
    read, then the model's O(N F)."""
    source = _source(_path(path))
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
                      blocking=blocking, footprint=footprint)


__all__ = ["read_layout", "layout_labels", "floor_frame", "FloorFrame", "read_movingai", "read_ros_map", "read_pgm",
           "downsample", "doorway_labels", "largest_region_start", "MOVINGAI_PASSABLE", "MOVINGAI_OBSTACLES",
           "ROS_DEFAULTS", "CELL_RULES", "MAX_FILE_BYTES", "MAX_PIXELS", "LARGE_FLOOR_CELLS"]
