"""Floor files read safely (DESIGN.md section 8): the field's grid formats checked on their headers,
their pixels decoded only when asked for (:class:`FloorSource`), so that the sizes a caller asks
for are refused before any array of the header's size is made.

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

**Limits**, checked before the pixels are decoded: only regular files (a FIFO, a device, a
directory is refused without being opened for reading), at most :data:`MAX_FILE_BYTES` bytes and
:data:`MAX_PIXELS` pixels, header sizes in strict ASCII digits. Malformed files raise
:class:`~onlinemap.errors.FloorFileError` naming the file and the line. Imports numpy only.
"""

from __future__ import annotations

import math
import os
import re
import stat
import warnings
from pathlib import Path
from typing import Callable, NamedTuple

import numpy as np

from . import arguments
from .errors import FloorFileError, FloorFileWarning, ModelError

MOVINGAI_PASSABLE, MOVINGAI_OBSTACLES = ".GS", "@OTW"
ROS_DEFAULTS = {"occupied_thresh": 0.65, "free_thresh": 0.196, "negate": 0}  # map_server's
MAX_FILE_BYTES = 2**28  # 256 MiB: a 16-bit P5 image of 8192 x 16384 pixels
MAX_PIXELS = 2**28  # pixels of a file before region and cell_size (a bool array of 256 MiB)
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


class FloorSource(NamedTuple):
    """A floor file with its header read and its pixels not yet decoded."""
    path: Path
    shape: tuple[int, int]  # (rows, cols) of pixels
    resolution: float | None  # metres per pixel; None for a .map or a bare .pgm
    origin: tuple[float, float, float] | None  # map frame pose of the bottom-left corner (x, y, yaw)
    occupied_thresh: float
    decode: Callable[[], np.ndarray]  # () -> (rows, cols) bool, True where free


def _movingai(path: Path) -> FloorSource:
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

    return FloorSource(path, (height, width), None, None, ROS_DEFAULTS["occupied_thresh"], decode)


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
        pixels = _ascii_raster(path, data[pos:], (height, width), maxval, last_line)

    def checked() -> np.ndarray:
        image = pixels()
        if image.max() > maxval:
            index = int(np.argmax(image > maxval))
            raise FloorFileError(f"{path}: pixel {divmod(index, width)} (row, column) is {image.flat[index]}, above "
                                 f"maxval {maxval}")
        return image.reshape(height, width)

    return (height, width), maxval, checked


def _ascii_raster(path: Path, text: bytes, shape: tuple[int, int], maxval: int,
                  last_line: int) -> Callable[[], np.ndarray]:
    """The pixel values of a P2 image, ``text`` the bytes after its header (which ends on
    ``last_line``), counted and checked as ASCII digits before any array of the image's size is
    made -> a function giving them, a flat uint16 array of H W values. O(len(text))."""
    height, width = shape

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
        raise FloorFileError(f"{path}, line {line_of(bad)}: pixel value {words[bad][:12].decode('latin-1')!r} is not a "
                             f"whole number in 0..{maxval} in ASCII digits")

    def pixels() -> np.ndarray:
        return np.array(words).astype(np.uint16)

    return pixels


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


def _ros(path: Path) -> FloorSource:
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

    return FloorSource(path, shape, resolution, origin, settings["occupied_thresh"], decode)


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


def floor_source(path) -> FloorSource:
    """The :class:`FloorSource` of a floor file (``.map``, ``.yaml``, ``.yml`` or ``.pgm``, by its
    suffix): its header read and checked, its pixels not yet decoded. O(header), plus the bytes
    read (at most :data:`MAX_FILE_BYTES`)."""
    path = _path(path)
    suffix = path.suffix.lower()
    if suffix == ".map":
        return _movingai(path)
    if suffix in (".yaml", ".yml", ".pgm"):
        return _ros(path)
    raise FloorFileError(f"{path}: unknown floor format {suffix or '(no suffix)'!r}; read are .map (MovingAI), "
                         ".yaml (ROS map_server) and .pgm")


__all__ = ["floor_source", "FloorSource", "read_movingai", "read_ros_map", "read_pgm", "MOVINGAI_PASSABLE",
           "MOVINGAI_OBSTACLES", "ROS_DEFAULTS", "MAX_FILE_BYTES", "MAX_PIXELS"]
