"""Generated buildings (DESIGN.md section 8): floors of rooms off corridors, in the door world's
labels (free, wall, open_door, closed_door), for exploration studies.

A building is drawn in two binary space partitions of the floor inside its outer wall, with walls
one cell thick:

1. **Corridors.** The interior is cut by a corridor (``corridor_width`` free rows or columns
   between two wall lines) across its longer side, at a uniformly drawn place, and each part is
   cut again while it is more than ``rooms_deep`` rooms deep (``rooms_deep (room_max + 1) - 1``
   cells; the corridor layout: 1 puts nearly every room on a corridor, more leaves suites of
   rooms reached through other rooms and fewer corridors) and a cut fits. The
   first cut always happens (the start is a corridor cell). A corridor runs from side to side of
   its part and opens (free cells through the wall line) into the corridors at its ends; a part
   is only cut by a corridor whose end meets a corridor, so the corridors form one network.
2. **Rooms.** Each part left between corridors (a block) is cut by wall lines while a side is
   longer than ``room_max``, at a uniformly drawn place leaving both rooms at least
   ``room_min`` wide; when both sides are too long, the cut that keeps both rooms on a corridor
   is taken (otherwise either, at random). Every room side lies in ``[room_min, room_max]``.

**Doors** sit in wall cells with a region (a room, or the corridor network) on two opposite sides
and wall on the other two. A random spanning tree of the regions, corridor joins first (so every
room that touches a corridor opens onto it), gets one open door per join; then every pair of
adjacent regions gets one more door with probability ``extra_doors`` (never next to a door of the
same pair), closed with probability ``closed_share``. So closed doors only add connections:
every free cell and open door is reachable from the start through free cells and open doors,
and every closed door lies between two reachable cells (a closed door is a detour, never a dead
end). Walls where wall lines meet the outer wall or cross, and the four corners, are read by no
cross footprint of a reachable cell: a robot cannot map them.

Randomness comes only from ``seed`` (an int, a sequence of ints or a ``numpy.random.Generator``).
Imports numpy and the model.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from . import arguments
from .errors import ModelError
from .model import CLOSED_DOOR, FREE, OPEN_DOOR, WALL, GridModel, door_world, passable_start

MIN_SIDE, MAX_SIDE = 10, 64  # a building's rows and cols
ROOM_SIZE = (2, 6)  # default (min, max) interior side of a room, in cells
_CORRIDOR = 0  # region id of the corridor network; rooms are 1, 2, ...
_ENDS = {"h": frozenset("WE"), "v": frozenset("NS")}  # sides a corridor along the rows / columns ends on


def _room_size(value) -> tuple[int, int]:
    if not isinstance(value, (tuple, list)) or len(value) != 2:
        raise ModelError(f"room_size must be a pair (min, max) of room sides in cells, got {value!r}")
    low = arguments.integer("room_size's min", value[0], minimum=1)
    high = arguments.integer("room_size's max", value[1], minimum=1)
    if high < 2 * low:
        raise ModelError(f"room_size (min, max) needs max >= 2 min, so that a side longer than max splits into "
                         f"two rooms of at least min, got {tuple(value)!r}")
    return low, high


def _seed(value) -> np.random.Generator:
    if value is None:
        raise ModelError("seed is required (an int or a numpy.random.Generator): a building is reproducible")
    value = arguments.seed("seed", value)
    return value if isinstance(value, np.random.Generator) else np.random.default_rng(value)


def _corridors(rows: int, cols: int, rng: np.random.Generator, room_min: int, room_max: int, width: int,
               rooms_deep: int, labels: np.ndarray,
               region: np.ndarray) -> list[tuple[int, int, int, int, frozenset]]:
    """Cut the interior by corridors (step 1 of the module's docstring), writing them into ``labels``
    and ``region``; returns the blocks ``(r0, r1, c0, c1, sides)``: interior cells ``[r0, r1) x
    [c0, c1)``, ``sides`` the subset of ``"NESW"`` bordered by a corridor."""
    deep, fits = rooms_deep * (room_max + 1) - 1, 2 * room_min + width + 2  # a cut leaves two parts >= room_min
    blocks = []
    stack = [(1, rows - 1, 1, cols - 1, frozenset())]
    while stack:
        r0, r1, c0, c1, sides = stack.pop()
        root = not sides
        cuts = [(extent, axis) for extent, axis in ((r1 - r0, "h"), (c1 - c0, "v"))
                if extent >= fits and (root or (extent > deep and sides & _ENDS[axis]))]
        if not cuts:
            if root:
                raise ModelError(f"a {rows} x {cols} building has no room for a corridor of width {width} "
                                 f"between rooms at least {room_min} wide: lower room_size's min or corridor_width")
            blocks.append((r0, r1, c0, c1, sides))
            continue
        longest = max(extent for extent, _ in cuts)
        longer = [axis for extent, axis in cuts if extent == longest]
        axis = longer[int(rng.integers(len(longer)))]
        if axis == "h":
            p = int(rng.integers(r0 + room_min + 1, r1 - room_min - width))  # corridor rows [p, p + width)
            band = np.s_[p:p + width, c0 - ("W" in sides):c1 + ("E" in sides)]  # opened into corridors at the ends
            stack += [(r0, p - 1, c0, c1, sides | {"S"}), (p + width + 1, r1, c0, c1, sides | {"N"})]
        else:
            p = int(rng.integers(c0 + room_min + 1, c1 - room_min - width))
            band = np.s_[r0 - ("N" in sides):r1 + ("S" in sides), p:p + width]
            stack += [(r0, r1, c0, p - 1, sides | {"E"}), (r0, r1, p + width + 1, c1, sides | {"W"})]
        labels[band] = FREE
        region[band] = _CORRIDOR
    return blocks


def _rooms(blocks, rng: np.random.Generator, room_min: int, room_max: int, labels: np.ndarray,
           region: np.ndarray) -> None:
    """Cut every block into rooms (step 2 of the module's docstring), numbered 1, 2, ... in ``region``."""
    keeps = {"h": frozenset("EW"), "v": frozenset("NS")}  # the corridor sides both parts of a cut keep
    count = 0
    for block in blocks:
        stack = [block]
        while stack:
            r0, r1, c0, c1, sides = stack.pop()
            cuts = [axis for extent, axis in ((r1 - r0, "h"), (c1 - c0, "v")) if extent > room_max]
            if not cuts:
                count += 1
                labels[r0:r1, c0:c1] = FREE
                region[r0:r1, c0:c1] = count
                continue
            if len(cuts) == 2:
                kept = [axis for axis in cuts if sides & keeps[axis]]
                cuts = kept if len(kept) == 1 else cuts
                axis = cuts[int(rng.integers(len(cuts)))]
            else:
                axis = cuts[0]
            if axis == "h":  # a wall row p
                p = int(rng.integers(r0 + room_min, r1 - room_min))
                stack += [(r0, p, c0, c1, sides - {"S"}), (p + 1, r1, c0, c1, sides - {"N"})]
            else:
                p = int(rng.integers(c0 + room_min, c1 - room_min))
                stack += [(r0, r1, c0, p, sides - {"E"}), (r0, r1, p + 1, c1, sides - {"W"})]


def _door_candidates(labels: np.ndarray, region: np.ndarray) -> dict[tuple[int, int], np.ndarray]:
    """Wall cells with two different regions on opposite sides and wall on the other two, per
    pair of regions ``(a, b)``, a < b: {pair: (D,) flat cell indices, ascending}. O(N)."""
    cols = labels.shape[1]
    wall = labels == WALL
    inner = wall[1:-1, 1:-1]
    found = []
    for one, other, side, side2 in ((region[:-2, 1:-1], region[2:, 1:-1], wall[1:-1, :-2], wall[1:-1, 2:]),
                                    (region[1:-1, :-2], region[1:-1, 2:], wall[:-2, 1:-1], wall[2:, 1:-1])):
        r, c = np.nonzero(inner & side & side2 & (one >= 0) & (other >= 0) & (one != other))
        a, b = one[r, c], other[r, c]
        found.append(np.stack([np.minimum(a, b), np.maximum(a, b), (r + 1) * cols + c + 1], axis=1))
    table = np.concatenate(found)
    table = table[np.lexsort((table[:, 2], table[:, 1], table[:, 0]))]
    pairs, first = np.unique(table[:, :2], axis=0, return_index=True)
    return {(int(a), int(b)): cells for (a, b), cells in zip(pairs, np.split(table[:, 2], first[1:]))}


def _doors(candidates: dict[tuple[int, int], np.ndarray], n_regions: int, rng: np.random.Generator,
           extra_doors: float, closed_share: float, cols: int) -> tuple[list[int], list[int]]:
    """(open door cells, closed door cells): one open door per join of a random spanning tree
    (corridor joins first), then one more door per pair with ``extra_doors``."""
    pairs = list(candidates)
    order = np.lexsort((rng.random(len(pairs)), [a != _CORRIDOR for a, _ in pairs]))
    parent = list(range(n_regions))

    def root(x: int) -> int:
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    opened, closed = [], []
    doors: dict[tuple[int, int], int] = {}
    for index in order:
        a, b = pairs[index]
        if root(a) != root(b):
            parent[root(a)] = root(b)
            cells = candidates[pairs[index]]
            doors[pairs[index]] = int(cells[rng.integers(len(cells))])
            opened.append(doors[pairs[index]])
    for pair in pairs:
        if rng.random() >= extra_doors:
            continue
        cells = candidates[pair]
        if pair in doors:  # not beside the pair's door (a door two cells wide)
            r, c = divmod(doors[pair], cols)
            cells = cells[np.maximum(np.abs(cells // cols - r), np.abs(cells % cols - c)) > 1]
        if len(cells):
            cell = int(cells[rng.integers(len(cells))])
            (closed if rng.random() < closed_share else opened).append(cell)
    return opened, closed


def building_layout(rows: int, cols: int, *, seed, room_size: Sequence[int] = ROOM_SIZE, corridor_width: int = 1,
                    rooms_deep: int = 2, extra_doors: float = 0.3,
                    closed_share: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """A generated floor (the module's docstring): ``(labels, corridor)``, (rows, cols) int64 door
    labels and a (rows, cols) bool mask of the corridor cells (free). Options as in :func:`building`.
    Cost O(N) array work plus O(R) Python steps for R rooms (R <= N / (room_min + 1)^2)."""
    rows = arguments.integer("rows", rows, minimum=MIN_SIDE, maximum=MAX_SIDE)
    cols = arguments.integer("cols", cols, minimum=MIN_SIDE, maximum=MAX_SIDE)
    room_min, room_max = _room_size(room_size)
    width = arguments.integer("corridor_width", corridor_width, minimum=1)
    rooms_deep = arguments.integer("rooms_deep", rooms_deep, minimum=1, maximum=MAX_SIDE)
    extra_doors = arguments.probability("extra_doors", extra_doors)
    closed_share = arguments.probability("closed_share", closed_share)
    rng = _seed(seed)
    labels = np.full((rows, cols), WALL, dtype=np.int64)
    region = np.full((rows, cols), -1, dtype=np.int64)  # -1 wall, 0 corridor network, 1.. rooms
    blocks = _corridors(rows, cols, rng, room_min, room_max, width, rooms_deep, labels, region)
    _rooms(blocks, rng, room_min, room_max, labels, region)
    opened, closed = _doors(_door_candidates(labels, region), int(region.max()) + 1, rng, extra_doors,
                            closed_share, cols)
    labels.flat[opened] = OPEN_DOOR
    labels.flat[closed] = CLOSED_DOOR
    return labels, region == _CORRIDOR


def building(rows: int, cols: int, *, seed, room_size: Sequence[int] = ROOM_SIZE, corridor_width: int = 1,
             rooms_deep: int = 2, extra_doors: float = 0.3, closed_share: float = 0.5, p_obs: float = 0.9,
             p_move: float = 0.8, p_door: float = 0.0, start: int | None = None, label_prior=None,
             blocking: bool = True, footprint="cross") -> tuple[GridModel, np.ndarray]:
    """A generated building (the module's docstring) as a door world: ``(model, true_map)``.

    ``rows``, ``cols``: 10..64. ``seed``: an int (or sequence of ints) or a ``numpy.random.Generator``,
    required; the same seed gives the same building. ``room_size``: (min, max) interior side of a
    room in cells, max >= 2 min; ``corridor_width``: cells across a corridor; ``rooms_deep``: the
    most rooms back to back between corridors where a corridor fits; ``extra_doors``: the
    probability that a pair of adjacent regions gets a door beyond the spanning tree's;
    ``closed_share``: the probability that such an extra door is closed. ``start``: a free cell or
    open door (default: a corridor cell drawn after the floor). The model options go to
    :func:`~onlinemap.model.door_world`: walls and closed doors block and the sensor reads a cross
    by default. Without ``label_prior`` the building's label frequencies are unknown
    (``model.unknown_label_frequencies``: estimators learn them, :mod:`onlinemap.label_prior`);
    a ``label_prior`` table states them. true_map (N,) read-only.

    Cost: the floor O(N) array work and O(R) Python steps for R rooms (R <= N / (room_min + 1)^2),
    about 1 ms at 10 x 10, 2-4 ms at 32 x 32 and 10 ms at 64 x 64; then the model, O(N F) for F
    footprint offsets (15 ms at 64 x 64).
    """
    rng = _seed(seed)
    labels, corridor = building_layout(rows, cols, seed=rng, room_size=room_size, corridor_width=corridor_width,
                                       rooms_deep=rooms_deep, extra_doors=extra_doors, closed_share=closed_share)
    if start is None:
        cells = np.flatnonzero(corridor)
        start = int(cells[rng.integers(len(cells))])
    else:
        start = passable_start(labels, start)
    return door_world(labels, p_obs=p_obs, p_move=p_move, p_door=p_door, start=start, label_prior=label_prior,
                      blocking=blocking, footprint=footprint, unknown_label_frequencies=label_prior is None)


__all__ = ["building", "building_layout", "MIN_SIDE", "MAX_SIDE", "ROOM_SIZE"]
