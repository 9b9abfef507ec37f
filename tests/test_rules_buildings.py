"""The rules of generated buildings (onlinemap/buildings.py's docstring, the README's "Buildings"
section), each checked on several seeds and sizes by a check written here (issue 43 section 3):
scipy.ndimage's connected components and small loops over the grid, never the module's own
regions, candidates or reachability.

Rules: the outer wall; the start (a corridor cell by default; a given start must be a free cell
or an open door); every free cell and open door reachable from the start through free cells and
open doors, every closed door between two reachable cells of different regions (a detour);
rooms full rectangles walled off from everything else, sides within ``room_size``; corridors
exactly ``corridor_width`` across and one network; doors in wall cells with two different
regions on opposite sides and wall on the other two, never two doors of one pair side by side;
with ``extra_doors`` 0 the open doors are a spanning tree of the regions; every room that
touches a corridor opens onto it (corridor joins first); the unmappable cells of the README
(wall cells read by no cross footprint of a reachable cell) and their counts over 30 seeds.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

import onlinemap as om
from onlinemap.buildings import building_layout
from onlinemap.errors import ModelError

FREE, WALL, OPEN, CLOSED = range(4)  # the door world's labels, in its order
CROSS = ((0, 0), (-1, 0), (1, 0), (0, -1), (0, 1))
STEPS = ((-1, 0), (1, 0), (0, -1), (0, 1))
CASES = [  # (rows, cols, options)
    (10, 10, {}), (13, 27, {}), (32, 32, {}), (64, 64, {}), (64, 10, {}),
    (40, 50, dict(room_size=(1, 2))), (40, 50, dict(room_size=(3, 7))), (30, 30, dict(room_size=(2, 4))),
    (40, 40, dict(corridor_width=2)), (48, 48, dict(corridor_width=3, room_size=(2, 5))),
    (32, 32, dict(extra_doors=1.0, closed_share=1.0)), (32, 32, dict(extra_doors=1.0, closed_share=0.0)),
    (40, 40, dict(rooms_deep=1)), (40, 40, dict(rooms_deep=4)),
]
SEEDS = range(4)


def case_id(case):
    rows, cols, options = case
    return f"{rows}x{cols}" + "".join(f",{k}={v}" for k, v in options.items())


def on_grid(grid, r, c):
    return 0 <= r < grid.shape[0] and 0 <= c < grid.shape[1]


def reachable_from(grid, start):
    """(rows, cols) bool: the 4-connected component of free cells and open doors holding ``start``."""
    components, _ = ndimage.label((grid == FREE) | (grid == OPEN))  # 4-connectivity by default
    return components == components.flat[start]


def regions_of(grid, corridor):
    """(rows, cols) int: 0 on the corridor network, 1.. on each room (the 4-connected components of
    the free cells off the corridor), -1 elsewhere (walls and doors)."""
    rooms, count = ndimage.label((grid == FREE) & ~corridor)
    region = np.where(rooms > 0, rooms, -1)
    region[corridor] = 0
    return region, count


def doors_and_sides(grid, region):
    """[(r, c, a, b)]: every door cell with the regions a < b on its two opposite non-wall sides,
    after checking the door rule: two different regions on opposite sides, wall on the other two."""
    found = []
    for r, c in zip(*np.nonzero((grid == OPEN) | (grid == CLOSED))):
        pairs = [((r - 1, c), (r + 1, c), (r, c - 1), (r, c + 1)), ((r, c - 1), (r, c + 1), (r - 1, c), (r + 1, c))]
        fits = [(one, other) for one, other, w1, w2 in pairs
                if all(on_grid(grid, *x) for x in (one, other, w1, w2))
                and region[one] >= 0 and region[other] >= 0 and region[one] != region[other]
                and grid[w1] == WALL and grid[w2] == WALL]
        assert len(fits) == 1, f"door ({r}, {c}) lacks two regions on opposite sides and wall on the other two"
        a, b = sorted((int(region[fits[0][0]]), int(region[fits[0][1]])))
        found.append((int(r), int(c), a, b))
    return found


@pytest.fixture(scope="module", params=CASES, ids=case_id)
def floors(request):
    """(rows, cols, options, [(model, true map grid, corridor)] per seed): ``building`` and
    ``building_layout`` of one seed draw the same floor (the layout's corridor mask is the model's)."""
    rows, cols, options = request.param
    out = []
    for seed in SEEDS:
        model, true_map = om.building(rows, cols, seed=seed, **options)
        grid, corridor = building_layout(rows, cols, seed=seed, **options)
        np.testing.assert_array_equal(true_map.reshape(rows, cols), grid)
        out.append((model, grid, corridor))
    return rows, cols, options, out


def test_the_outer_wall_and_the_start_on_a_corridor(floors):
    rows, cols, _, found = floors
    for model, grid, corridor in found:
        assert (grid[0] == WALL).all() and (grid[-1] == WALL).all()
        assert (grid[:, 0] == WALL).all() and (grid[:, -1] == WALL).all()
        assert corridor.flat[model.start] and grid.flat[model.start] == FREE


def test_every_free_cell_and_open_door_is_reachable_and_closed_doors_are_detours(floors):
    _, _, _, found = floors
    for model, grid, corridor in found:
        seen = reachable_from(grid, model.start)
        np.testing.assert_array_equal(seen, (grid == FREE) | (grid == OPEN))
        region, _ = regions_of(grid, corridor)
        for r, c, a, b in doors_and_sides(grid, region):
            if grid[r, c] == CLOSED:  # both sides reachable without it
                sides = [(r - 1, c), (r + 1, c)] if region[r - 1, c] >= 0 and region[r + 1, c] >= 0 else \
                    [(r, c - 1), (r, c + 1)]
                assert all(seen[x] for x in sides)


def test_rooms_are_walled_rectangles_with_sides_in_room_size(floors):
    """Every room is a full rectangle whose every outside neighbour is a wall or a door (rooms touch
    neither the corridor nor each other), its sides within ``room_size`` (default 2..6)."""
    _, _, options, found = floors
    low, high = options.get("room_size", (2, 6))
    for _, grid, corridor in found:
        region, count = regions_of(grid, corridor)
        assert count >= 2
        for room in range(1, count + 1):
            r, c = np.nonzero(region == room)
            height, width = r.max() - r.min() + 1, c.max() - c.min() + 1
            assert height * width == len(r), "not a full rectangle"
            assert low <= min(height, width) and max(height, width) <= high, (height, width)
            ring = np.zeros_like(corridor)
            ring[r.min() - 1:r.max() + 2, c.min() - 1:c.max() + 2] = True
            ring[r.min():r.max() + 1, c.min():c.max() + 1] = False
            assert np.isin(grid[ring], (WALL, OPEN, CLOSED)).all()


def test_corridors_are_corridor_width_across_and_one_network(floors):
    """Every corridor cell lies in a w x w square of corridor cells and no (w + 1) x (w + 1) square of
    corridor cells exists (w = ``corridor_width``, 1 by default): exactly w across, at junctions too."""
    _, _, options, found = floors
    w = options.get("corridor_width", 1)
    for _, grid, corridor in found:
        assert (grid[corridor] == FREE).all()
        assert ndimage.label(corridor)[1] == 1
        rows, cols = corridor.shape
        covered = np.zeros_like(corridor)
        for r in range(rows - w + 1):
            for c in range(cols - w + 1):
                if corridor[r:r + w, c:c + w].all():
                    covered[r:r + w, c:c + w] = True
                assert not corridor[r:r + w + 1, c:c + w + 1].all() or r + w >= rows or c + w >= cols
        np.testing.assert_array_equal(covered, corridor)


def test_doors_join_two_regions_and_never_stand_side_by_side(floors):
    """The door rule (two regions on opposite sides, wall on the other two) for every door, and two
    doors of the same pair of regions are never neighbours, diagonally included."""
    _, _, _, found = floors
    for _, grid, corridor in found:
        region, _ = regions_of(grid, corridor)
        doors = doors_and_sides(grid, region)
        for i, (r, c, a, b) in enumerate(doors):
            for r2, c2, a2, b2 in doors[i + 1:]:
                if (a, b) == (a2, b2):
                    assert max(abs(r - r2), abs(c - c2)) > 1, ((r, c), (r2, c2))


def test_every_room_that_touches_a_corridor_opens_onto_it(floors):
    """A room with a wall cell between it and the corridor that could hold a door (room and corridor
    on opposite sides, wall on the other two) has an open door onto the corridor: the spanning tree
    joins the corridor first."""
    _, _, _, found = floors
    for _, grid, corridor in found:
        region, count = regions_of(grid, corridor)
        opens = {b for r, c, a, b in doors_and_sides(grid, region) if a == 0 and grid[r, c] == OPEN}
        for r, c in zip(*np.nonzero(grid == WALL)):
            for (r1, c1), (r2, c2), w1, w2 in ((((r - 1, c), (r + 1, c), (r, c - 1), (r, c + 1))),
                                                (((r, c - 1), (r, c + 1), (r - 1, c), (r + 1, c)))):
                if not all(on_grid(grid, *x) for x in ((r1, c1), (r2, c2), w1, w2)):
                    continue
                pair = sorted((region[r1, c1], region[r2, c2]))
                if pair[0] == 0 and pair[1] > 0 and grid[w1] == WALL and grid[w2] == WALL:
                    assert pair[1] in opens, f"room {pair[1]} touches the corridor at ({r}, {c}) but has no door onto it"


def blocks_of(grid, corridor):
    """The blocks (parts between corridors, each cut into rooms): the 4-connected components of the
    interior cells more than one cell (Chebyshev) from every corridor cell, i.e. without the
    corridors and the wall lines along them; each as (r0, r1, c0, c1, sides), interior
    ``[r0, r1) x [c0, c1)`` after checking it is a full rectangle, ``sides`` the subset of "NESW"
    where a corridor runs beyond the wall line."""
    rows, cols = grid.shape
    near = ndimage.binary_dilation(corridor, structure=np.ones((3, 3), dtype=bool))
    inside = np.zeros_like(corridor)
    inside[1:-1, 1:-1] = True
    labels, count = ndimage.label(inside & ~near)
    found = []
    for block in range(1, count + 1):
        r, c = np.nonzero(labels == block)
        r0, r1, c0, c1 = r.min(), r.max() + 1, c.min(), c.max() + 1
        assert (r1 - r0) * (c1 - c0) == len(r), "a block is not a rectangle"
        sides = set()
        if r0 >= 2 and corridor[r0 - 2, c0:c1].all():
            sides.add("N")
        if r1 + 1 < rows and corridor[r1 + 1, c0:c1].all():
            sides.add("S")
        if c0 >= 2 and corridor[r0:r1, c0 - 2].all():
            sides.add("W")
        if c1 + 1 < cols and corridor[r0:r1, c1 + 1].all():
            sides.add("E")
        found.append((r0, r1, c0, c1, sides))
    return found


def test_no_block_is_left_deeper_than_rooms_deep_where_a_corridor_fits(floors):
    """A part is cut by a corridor while it is more than ``rooms_deep`` rooms deep, ``rooms_deep
    (room_max + 1) - 1`` cells, a corridor fits (two parts at least ``room_min`` wide, the corridor
    and its two wall lines: ``2 room_min + corridor_width + 2`` cells) and the new corridor's ends
    meet a corridor: a block more than that deep across its rows has no corridor on its west or
    east side, and across its columns none on its north or south side. And every block borders a
    corridor (the corridors reach every part of the floor)."""
    _, _, options, found = floors
    low, high = options.get("room_size", (2, 6))
    width, rooms_deep = options.get("corridor_width", 1), options.get("rooms_deep", 2)
    deep, fits = rooms_deep * (high + 1) - 1, 2 * low + width + 2
    for _, grid, corridor in found:
        blocks = blocks_of(grid, corridor)
        assert blocks
        for r0, r1, c0, c1, sides in blocks:
            assert sides, (r0, r1, c0, c1)
            if r1 - r0 >= fits and r1 - r0 > deep:
                assert not sides & {"W", "E"}, (r0, r1, c0, c1, sides)
            if c1 - c0 >= fits and c1 - c0 > deep:
                assert not sides & {"N", "S"}, (r0, r1, c0, c1, sides)


def test_rooms_are_cut_so_that_both_stay_on_the_corridor(floors):
    """When both sides of a part are longer than ``room_max`` the cut that keeps both rooms on a
    corridor is taken: in a block whose corridors run only along its north or south side, the walls
    between rooms side by side are cut first, so each runs across the whole block (every cell of its
    column in the block a wall or a door); likewise across rows for a block with corridors only on
    its west or east side. (Such blocks arise in narrow floors: 13 x 27 and 64 x 10 have some.)"""
    rows, cols, _, found = floors
    checked = 0
    for _, grid, corridor in found:
        room = (grid == FREE) & ~corridor
        for r0, r1, c0, c1, sides in blocks_of(grid, corridor):
            if sides <= {"N", "S"}:
                part, lines = grid[r0:r1, c0:c1], room[r0:r1, c0:c1]
            elif sides <= {"W", "E"}:
                part, lines = grid[r0:r1, c0:c1].T, room[r0:r1, c0:c1].T
            else:
                continue
            for r, c in zip(*np.nonzero(~lines[:, 1:-1])):  # a wall or door with rooms on both sides
                if lines[r, c] and lines[r, c + 2]:
                    assert not lines[:, c + 1].any(), (r0, r1, c0, c1, sides)
                    checked += 1
    assert checked or (rows, cols) not in ((13, 27), (64, 10))


@pytest.mark.parametrize("rows, cols", [(20, 20), (32, 32)])
def test_without_extra_doors_the_open_doors_are_a_spanning_tree(rows, cols):
    """extra_doors 0: no closed door, and the open doors, as edges between regions, form a tree:
    regions - 1 of them, joining every region (union-find written here)."""
    for seed in range(5):
        grid, corridor = building_layout(rows, cols, seed=seed, extra_doors=0.0)
        region, count = regions_of(grid, corridor)
        doors = doors_and_sides(grid, region)
        assert not (grid == CLOSED).any() and len(doors) == count
        parent = list(range(count + 1))

        def root(x):
            while parent[x] != x:
                x = parent[x]
            return x
        for _, _, a, b in doors:
            assert root(a) != root(b), "a cycle: not a tree"
            parent[root(a)] = root(b)
        assert len({root(x) for x in range(count + 1)}) == 1


def test_a_given_start_must_be_a_free_cell_or_an_open_door():
    grid, _ = building_layout(16, 16, seed=0)
    door = int(np.flatnonzero(grid == OPEN)[0])
    assert om.building(16, 16, seed=0, start=door)[0].start == door
    room = int(np.flatnonzero(grid == FREE)[-1])
    assert om.building(16, 16, seed=0, start=room)[0].start == room
    closed_grid, _ = building_layout(32, 32, seed=0, extra_doors=1.0, closed_share=1.0)
    closed = int(np.flatnonzero(closed_grid == CLOSED)[0])
    with pytest.raises(ModelError, match="start"):
        om.building(32, 32, seed=0, extra_doors=1.0, closed_share=1.0, start=closed)
    with pytest.raises(ModelError, match="start"):
        om.building(16, 16, seed=0, start=0)  # the outer wall's corner


# --- the cells no robot can map (README "Buildings") --------------------------------------------
def unmappable(model, grid):
    """The cells read by no cross footprint of a cell reachable from the start."""
    seen = reachable_from(grid, model.start)
    read = np.zeros_like(seen)
    for r, c in zip(*np.nonzero(seen)):
        for dr, dc in CROSS:
            if on_grid(grid, r + dr, c + dc):
                read[r + dr, c + dc] = True
    return ~read


@pytest.mark.parametrize("size, low, high, floor", [(10, 6, 10, 0.06), (32, 22, 33, 0.02), (64, 47, 66, 0.01)])
def test_the_unmappable_cells_are_wall_junctions_and_corners_as_many_as_the_readme_says(size, low, high, floor):
    """README: with a cross footprint no reachable cell reads the four corners nor the wall cells
    where wall lines meet the outer wall or cross; over 30 seeds 6-10 cells of a 10 x 10 building,
    22-33 of 32 x 32, 47-66 of 64 x 64, so the map error over all cells under a uniform prior (0.75
    on each such cell) cannot fall below about 0.06, 0.02, 0.01. Each unmappable cell is a wall all
    of whose neighbours on the grid are walls or closed doors (a junction or a corner)."""
    counts = []
    for seed in range(30):
        model, true_map = om.building(size, size, seed=seed)
        grid = true_map.reshape(size, size)
        cells = unmappable(model, grid)
        for corner in ((0, 0), (0, size - 1), (size - 1, 0), (size - 1, size - 1)):
            assert cells[corner]
        for r, c in zip(*np.nonzero(cells)):
            assert grid[r, c] == WALL
            assert all(grid[r + dr, c + dc] in (WALL, CLOSED) for dr, dc in STEPS if on_grid(grid, r + dr, c + dc))
        counts.append(int(cells.sum()))
    assert min(counts) == low and max(counts) == high
    assert round(0.75 * np.mean(counts) / size ** 2, 2) == floor
