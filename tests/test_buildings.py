"""Generated buildings (issue 22, item 1; DESIGN.md section 8): connectivity through free cells and
open doors (a breadth-first search written here), reproducibility, labels, sizes, knobs, bad arguments."""

from collections import deque

import numpy as np
import pytest

import onlinemap as om
from onlinemap.buildings import building_layout
from onlinemap.errors import ModelError

FREE, WALL, OPEN, CLOSED = range(4)
SIZES = [(10, 10), (10, 64), (64, 10), (13, 27), (32, 32), (64, 64)]


def neighbours(rows, cols, r, c):
    return [(rr, cc) for rr, cc in ((r - 1, c), (r + 1, c), (r, c - 1), (r, c + 1)) if 0 <= rr < rows and 0 <= cc < cols]


def reachable(grid, start):
    """(rows, cols) bool: cells reached from ``start`` moving through free cells and open doors."""
    rows, cols = grid.shape
    seen = np.zeros(grid.shape, dtype=bool)
    seen[divmod(start, cols)] = True
    queue = deque([divmod(start, cols)])
    while queue:
        for rr, cc in neighbours(rows, cols, *queue.popleft()):
            if not seen[rr, cc] and grid[rr, cc] in (FREE, OPEN):
                seen[rr, cc] = True
                queue.append((rr, cc))
    return seen


def components(mask):
    """The 4-connected components of ``mask``, each as an (n, 2) array of (row, col)."""
    rows, cols = mask.shape
    left = mask.copy()
    found = []
    for r, c in zip(*np.nonzero(mask)):
        if not left[r, c]:
            continue
        left[r, c] = False
        queue, cells = deque([(r, c)]), [(r, c)]
        while queue:
            for rr, cc in neighbours(rows, cols, *queue.popleft()):
                if left[rr, cc]:
                    left[rr, cc] = False
                    queue.append((rr, cc))
                    cells.append((rr, cc))
        found.append(np.array(cells))
    return found


@pytest.mark.parametrize("rows, cols", SIZES)
@pytest.mark.parametrize("seed", range(6))
def test_every_cell_is_reachable_through_free_cells_and_open_doors(rows, cols, seed):
    model, true_map = om.building(rows, cols, seed=seed, rooms_deep=1 + seed % 3, corridor_width=1 + seed // 4)
    grid = true_map.reshape(rows, cols)
    assert model.shape == (rows, cols) and true_map.shape == (rows * cols,) and not true_map.flags.writeable
    assert set(np.unique(grid)) <= {FREE, WALL, OPEN, CLOSED}
    assert (grid[[0, -1], :] == WALL).all() and (grid[:, [0, -1]] == WALL).all()  # the outer wall
    assert grid.flat[model.start] == FREE
    seen = reachable(grid, model.start)
    np.testing.assert_array_equal(seen, (grid == FREE) | (grid == OPEN))
    for r, c in zip(*np.nonzero(grid == CLOSED)):  # a closed door joins two reachable cells: a detour
        assert (seen[r - 1, c] and seen[r + 1, c]) or (seen[r, c - 1] and seen[r, c + 1])


def test_defaults_and_model_options_pass_through():
    model, true_map = om.building(20, 30, seed=1)
    assert model.label_names == om.model.DOOR_LABELS and model.has_blocking and model.n_readings == 5
    np.testing.assert_array_equal(model.blocking, [False, True, False, True])
    assert model.p_move == 0.8 and model.is_static
    prior = np.array([0.4, 0.4, 0.1, 0.1])
    other, same_map = om.building(20, 30, seed=1, p_obs=0.7, p_move=0.6, p_door=0.02, label_prior=prior,
                                  blocking=False, footprint="cell", start=int(np.flatnonzero(true_map == FREE)[-1]))
    np.testing.assert_array_equal(same_map, true_map)
    assert not other.has_blocking and other.n_readings == 1 and other.p_move == 0.6
    assert other.O[0, 0] == 0.7 and other.C[OPEN, CLOSED] == 0.02
    np.testing.assert_array_equal(other.label_prior[5], prior)
    assert other.start == np.flatnonzero(true_map == FREE)[-1]


def test_same_seed_same_building_and_different_seeds_differ():
    model, true_map = om.building(32, 32, seed=3)
    again, same = om.building(32, 32, seed=3)
    from_generator, by_generator = om.building(32, 32, seed=np.random.default_rng(3))
    np.testing.assert_array_equal(true_map, same)
    np.testing.assert_array_equal(true_map, by_generator)
    assert model.start == again.start == from_generator.start
    maps = {om.building(32, 32, seed=seed)[1].tobytes() for seed in range(20)}
    assert len(maps) == 20
    assert len({om.building(10, 10, seed=seed)[1].tobytes() for seed in range(20)}) > 10


def test_the_global_random_state_is_neither_used_nor_moved():
    np.random.seed(0)
    before = np.random.get_state()[1].copy()
    om.building(32, 32, seed=5)
    np.testing.assert_array_equal(np.random.get_state()[1], before)


def test_all_four_labels_appear_in_a_32_by_32_building():
    for seed in range(5):
        assert set(np.unique(om.building(32, 32, seed=seed)[1])) == {FREE, WALL, OPEN, CLOSED}


@pytest.mark.parametrize("room_size", [(2, 6), (3, 7), (1, 2), (4, 12)])
def test_rooms_are_rectangles_within_the_room_size_and_corridors_are_free(room_size):
    for seed in range(4):
        grid, corridor = building_layout(40, 50, seed=seed, room_size=room_size)
        assert (grid[corridor] == FREE).all() and corridor.any()
        rooms = components((grid == FREE) & ~corridor)
        assert rooms
        for cells in rooms:
            height, width = np.ptp(cells, axis=0) + 1
            assert height * width == len(cells)  # a full rectangle: walls and doors around it
            assert room_size[0] <= min(height, width) and max(height, width) <= room_size[1]
        # every corridor cell is one network
        assert len(components(corridor)) == 1


def test_door_knobs():
    for seed in range(5):
        grid, corridor = building_layout(32, 32, seed=seed, extra_doors=0.0)
        regions = len(components((grid == FREE) & ~corridor)) + 1  # the rooms and the corridor network
        assert (grid == OPEN).sum() == regions - 1 and not (grid == CLOSED).any()  # a spanning tree
        grid, corridor = building_layout(32, 32, seed=seed, extra_doors=1.0, closed_share=1.0)
        assert (grid == OPEN).sum() == regions - 1 and (grid == CLOSED).any()  # the extra doors, all closed
        grid, _ = building_layout(32, 32, seed=seed, extra_doors=1.0, closed_share=0.0)
        assert (grid == OPEN).sum() > regions - 1 and not (grid == CLOSED).any()
    grid, corridor = building_layout(40, 40, seed=0, corridor_width=2)
    rows, cols = np.nonzero(corridor & (grid == FREE))
    assert all(corridor[r - 1:r + 2, c - 1:c + 2].sum() >= 4 for r, c in zip(rows, cols))  # two cells across
    # the corridor layout: fewer corridors as more rooms may stand back to back (shares 0.24, 0.14, 0.09, 0.05)
    shares = [np.mean([building_layout(40, 40, seed=s, rooms_deep=deep)[1].mean() for s in range(6)])
              for deep in (1, 2, 3, 5)]
    assert shares == sorted(shares, reverse=True) and shares[0] > 3 * shares[-1]
    model, true_map = om.building(40, 40, seed=0, corridor_width=2)
    np.testing.assert_array_equal(reachable(true_map.reshape(40, 40), model.start), (grid == FREE) | (grid == OPEN))


@pytest.mark.parametrize("kwargs, match", [
    (dict(rows=9), "rows must be at least 10"), (dict(cols=65), "cols must be at most 64"),
    (dict(rows=-3), "rows"), (dict(cols=10.5), "cols must be a whole number"), (dict(rows=True), "rows must be an integer"),
    (dict(cols="32"), "cols must be an integer"), (dict(seed=None), "seed is required"), (dict(seed=-1), "seed"),
    (dict(seed="a"), "seed"), (dict(room_size=(3, 5)), "room_size"), (dict(room_size=3), "room_size"),
    (dict(room_size=(0, 4)), "room_size's min"), (dict(room_size=(2, 4.5)), "room_size's max"),
    (dict(corridor_width=0), "corridor_width"), (dict(rooms_deep=0), "rooms_deep must be at least 1"), (dict(rows=10, cols=10, corridor_width=3), "corridor_width"),
    (dict(rows=10, cols=10, room_size=(4, 8)), "room_size"),
    (dict(extra_doors=1.5), "extra_doors"), (dict(closed_share=float("nan")), "closed_share"),
    (dict(start=0), "start must be a free cell"), (dict(start=10**6), "start"), (dict(start=1.5), "start"),
    (dict(blocking="yes"), "blocking"), (dict(footprint="ring"), "footprint"), (dict(p_obs=2), "p_obs"),
])
def test_bad_arguments_raise_model_errors_naming_them(kwargs, match):
    arguments = dict(rows=16, cols=16, seed=0) | kwargs
    with pytest.raises(ModelError, match=match):
        om.building(arguments.pop("rows"), arguments.pop("cols"), **arguments)


def test_plot_building_draws_the_labels_with_a_legend():
    from matplotlib.colors import to_rgb
    from matplotlib.figure import Figure

    from onlinemap import plots

    model, true_map = om.building(12, 20, seed=2, extra_doors=1.0)
    fig = plots.plot_building(model, true_map, title="a building")
    assert isinstance(fig, Figure)
    (ax,) = fig.axes
    image = np.asarray(ax.images[0].get_array())
    palette = {FREE: "white", WALL: "#404040", OPEN: "tab:green", CLOSED: "tab:red"}
    expected = np.array([[to_rgb(palette[label]) for label in row] for row in true_map.reshape(12, 20)])
    np.testing.assert_allclose(image, expected)
    legend = [text.get_text() for text in ax.get_legend().get_texts()]
    assert legend == ["free", "wall", "open_door", "closed_door", "start"]
    (star,) = ax.lines
    assert (star.get_xdata()[0], star.get_ydata()[0]) == divmod(model.start, 20)[::-1]
    assert ax.get_title() == "a building"
    without_start = plots.plot_building(model, true_map.reshape(12, 20), start=False).axes[0]
    assert not without_start.lines
    grid = om.grid_model(3, 4, 3)  # another label set: matplotlib's cycle colours
    image = np.asarray(plots.plot_building(grid, np.arange(12) % 3).axes[0].images[0].get_array())
    np.testing.assert_allclose(image[0, :3], [to_rgb("C0"), to_rgb("C1"), to_rgb("C2")])
    for bad in (true_map[:-1], true_map + 4, true_map.astype(float)):
        with pytest.raises(ValueError, match="plot_building draws a 2D map"):
            plots.plot_building(model, bad)
