"""Real map files as robotics users have them (issue 42, item 6) and the reading rules no test caught
(issue 43, section 3): the cell rules on floors small enough to work out by hand, ``region`` in
cells and in metres, the ROS origin and row order (:class:`FloorFrame`), a cell size that is not a
whole number of pixels, ``doorways``/``cell_rule``/``region`` and quoted paths in world specs,
and the warnings (no ``type`` line, a start cut off from most of the floor, a large floor)."""

import warnings

import numpy as np
import pytest

import onlinemap as om
from onlinemap.errors import FloorFileError, FloorFileWarning, LargeFloorWarning, ModelError, SmallRegionWarning
from onlinemap.layouts import floor_frame, layout_labels
from onlinemap.worlds import parse_world
from test_layouts import ROOMS, pgm_p5, write_map, write_ros

FREE, WALL, OPEN = 0, 1, 2

# a wall one pixel thick at column 4 with a doorway one pixel wide at row 2
DOORWAY = "\n".join("........" if r == 2 else "....@..." for r in range(8))


def test_the_cell_rules_on_a_doorway_worked_by_hand(tmp_path):
    path = write_map(tmp_path / "door.map", DOORWAY)
    # cell_size 2: the cell (1, 2) holds pixels (2, 4) free, (2, 5) free, (3, 4) wall, (3, 5) free
    majority = [[0, 0, 1, 0],
                [0, 0, 2, 0],  # 3 of 4 free, no blocked line: free, and a doorway between two open sides
                [0, 0, 1, 0],  # pixel column 4 wholly wall inside the cell: wall
                [0, 0, 1, 0]]
    np.testing.assert_array_equal(layout_labels(path, cell_size=2), majority)
    any_ = [[0, 0, 1, 0]] * 4  # a wall pixel in every cell of column 2: the doorway is sealed
    np.testing.assert_array_equal(layout_labels(path, cell_size=2, cell_rule="any"), any_)
    # threshold: a wall cell has 2 of 4 pixels not free, 0.5 <= 0.65: free, the thin wall vanishes
    np.testing.assert_array_equal(layout_labels(path, cell_size=2, cell_rule="threshold"), np.zeros((4, 4)))
    with pytest.raises(FloorFileError, match="cell_rule must be one of"):
        layout_labels(path, cell_size=2, cell_rule="all")


def test_majority_keeps_a_straight_thin_wall_at_any_cell_size(tmp_path):
    # 9 x 9, a wall at column 4 from top to bottom: at cell_size 3 the middle column of cells holds
    # 6 free pixels of 9 (a majority) but a whole pixel column of wall, so it stays a wall
    path = write_map(tmp_path / "wall.map", "\n".join(["....@...."] * 9))
    np.testing.assert_array_equal(layout_labels(path, cell_size=3, doorways=False), [[0, 1, 0]] * 3)
    np.testing.assert_array_equal(layout_labels(path, cell_size=3, cell_rule="threshold", doorways=False),
                                  np.zeros((3, 3)))


def rooms_map(rooms=3, side=7):
    """rooms x rooms rooms of side x side cells, walls one cell thick, one doorway one cell wide in
    the middle of every inner wall (the shape of MovingAI's room-64-64-8 with 3 x 3 rooms)."""
    n = rooms * (side + 1) + 1
    grid = np.full((n, n), ".")
    grid[::side + 1, :] = "@"
    grid[:, ::side + 1] = "@"
    middle = side // 2 + 1
    for i in range(rooms):
        for j in range(1, rooms):
            grid[i * (side + 1) + middle, j * (side + 1)] = "."  # a door in a wall column
            grid[j * (side + 1), i * (side + 1) + middle] = "."  # a door in a wall row
    return "\n".join("".join(row) for row in grid)


def test_rooms_stay_joined_at_cell_size_2_and_any_warns(tmp_path):
    path = write_map(tmp_path / "rooms.map", rooms_map())
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        model, true_map = om.read_layout(path, cell_size=2)
    # 25 x 25 pixels -> 13 x 13 cells: each room 3 x 3 cells (pixels 1..6 of 7; pixel 7 shares a cell
    # with the wall), 9 rooms = 81 cells, plus the 12 doorways, all joined
    assert model.shape == (13, 13)
    assert (true_map != WALL).sum() == 81 + 12 and (true_map == OPEN).sum() == 12
    with pytest.warns(SmallRegionWarning, match=r"reaches 9 of the 81 free cells \(11%; 9 separate regions"):
        model, true_map = om.read_layout(path, cell_size=2, cell_rule="any")
    assert (true_map != WALL).sum() == 81


def test_a_start_in_a_small_region_warns(tmp_path):
    path = write_map(tmp_path / "door.map", DOORWAY)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        om.read_layout(path, cell_size=2, cell_rule="any")  # the start in the left half: 8 of 12 cells
    with pytest.warns(SmallRegionWarning, match=r"start \(row 0, col 3\) reaches 4 of the 12 free cells"):
        om.read_layout(path, cell_size=2, cell_rule="any", start=3)


def test_no_free_cell_says_why(tmp_path):
    maze = "\n".join(["@" * 9] + ["@..@..@.."] * 2 + ["@" * 9] + ["@..@..@.."] * 2 + ["@" * 9] + ["@..@..@.."] * 2)
    path = write_map(tmp_path / "maze.map", maze)
    with pytest.raises(FloorFileError, match="no free cell at cell_size 3 with cell_rule 'any'; passages narrower"):
        layout_labels(path, cell_size=3, cell_rule="any")


def test_a_region_in_cells_is_a_slice(tmp_path):
    path = write_map(tmp_path / "rooms.map", ROOMS)
    passable = np.array([[ch in ".GS" for ch in row] for row in ROOMS.splitlines()])
    labels = layout_labels(path, region=((1, 4), (1, 8)), doorways=False)
    np.testing.assert_array_equal(labels, np.where(passable[1:4, 1:8], FREE, WALL))
    model, _ = om.read_layout(path, region=[[4, 9], [0, 11]])
    assert model.shape == (5, 11)
    for region, match in [(((0, 10), (0, 11)), "not inside"), (((3, 3), (0, 11)), "low < high"),
                          (((0, 1.5), (0, 11)), "whole number"), ((0, 9), "must be a pair"), ("0:9x0:11", "region must be")]:
        with pytest.raises(FloorFileError, match=match):
            layout_labels(path, region=region)


def asymmetric_floor():
    """6 x 8 pixels, not symmetric top to bottom: the top two rows free, the rest occupied but for
    the bottom-left 2 x 2 pixels (free) and the column of pixel 7 in rows 2..3 (free)."""
    pixels = np.zeros((6, 8), dtype=int)
    pixels[0:2, :] = 254
    pixels[4:6, 0:2] = 254
    pixels[2:4, 7] = 254
    return pixels


def test_ros_rows_run_from_the_image_top_and_the_origin_is_its_bottom_left(tmp_path):
    # origin (-1, -2) at 0.05 m: the image spans x in [-1, -0.6], y in [-2, -1.7]; its top row is y near -1.7
    yaml = write_ros(tmp_path, asymmetric_floor(), resolution=0.05)
    labels = layout_labels(yaml, doorways=False)
    assert (labels[0] == FREE).all() and labels[5, 0] == FREE and labels[5, 7] == WALL and labels[3, 7] == FREE
    frame = floor_frame(yaml)
    assert frame.cell(-0.975, -1.975) == 5 * 8 + 0  # the bottom-left pixel: row 5, column 0
    assert frame.cell(-0.625, -1.725) == 0 * 8 + 7  # the top-right pixel: row 0, column 7
    assert frame.cell(-1.0, -2.0) == 40  # a pixel's west and south edges belong to it
    assert frame.point(40) == pytest.approx((-0.975, -1.975))
    assert frame.point(7) == pytest.approx((-0.625, -1.725))
    assert frame.bounds() == (pytest.approx((-1.0, -0.6)), pytest.approx((-2.0, -1.7)))
    for x, y in [(-1.001, -1.9), (-0.6, -1.9), (-0.8, -1.7), (-0.8, -2.01)]:
        with pytest.raises(FloorFileError, match="is off the part"):
            frame.cell(x, y)
    # at 0.1 m a cell: cell (2, 0) holds pixel rows 4..5, columns 0..1, centred at (-0.95, -1.95)
    coarse = floor_frame(yaml, cell_size=0.1)
    assert coarse.shape == (3, 4) and coarse.cell(-0.96, -1.99) == 8 and coarse.point(8) == pytest.approx((-0.95, -1.95))
    assert layout_labels(yaml, cell_size=0.1, doorways=False)[2, 0] == FREE


def test_a_region_in_metres_crops_the_pixels_it_overlaps(tmp_path):
    yaml = write_ros(tmp_path, asymmetric_floor(), resolution=0.05)
    # x -1..-0.85: columns (-1 + 1) / 0.05 = 0 to (-0.85 + 1) / 0.05 = 3; y -2..-1.85: rows 0..3 from the
    # bottom, image rows 6 - 3 = 3 .. 6 - 0 = 6; pixels [3:6, 0:3]: row 3 occupied, rows 4-5 free at columns 0-1
    labels = layout_labels(yaml, region=((-1.0, -0.85), (-2.0, -1.85)), doorways=False)
    np.testing.assert_array_equal(labels, [[1, 1, 1], [0, 0, 1], [0, 0, 1]])
    # x -0.9..-0.7, y -1.95..-1.8: image rows 2..5, columns 2..6, all occupied
    with pytest.raises(FloorFileError, match="no free cell"):
        layout_labels(yaml, region=((-0.9, -0.7), (-1.95, -1.8)))
    frame = floor_frame(yaml, region=((-1.0, -0.8), (-1.8, -1.7)))  # image rows 0..2, columns 0..4
    assert frame.shape == (2, 4) and frame.cell(-0.975, -1.725) == 0 and frame.cell(-0.825, -1.775) == 7
    with pytest.raises(FloorFileError, match=r"not inside .*x in \[-1, -0.6\], y in \[-2, -1.7\]"):
        layout_labels(yaml, region=((-1.1, -0.8), (-1.8, -1.7)))


def test_a_map_has_no_metric_frame(tmp_path):
    frame = floor_frame(write_map(tmp_path / "rooms.map", ROOMS), cell_size=2)
    assert frame.shape == (5, 6) and frame.factor == 2
    with pytest.raises(FloorFileError, match="no map frame"):
        frame.cell(0.0, 0.0)


def test_a_cell_size_is_rounded_to_whole_pixels(tmp_path):
    yaml = write_ros(tmp_path, asymmetric_floor(), resolution=0.05)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        # 0.15 / 0.05 is 2.9999999999999996 in floating point: 3 pixels a cell, exactly, no warning
        assert floor_frame(yaml, cell_size=0.15).factor == 3
        assert layout_labels(yaml, cell_size=0.15, cell_rule="threshold").shape == (2, 3)
    with pytest.warns(FloorFileWarning, match=r"cell_size 0.12 m is 2.4 pixels of 0.05 m: read as 2 pixels, 0.1 m"):
        assert layout_labels(yaml, cell_size=0.12).shape == (3, 4)
    with pytest.warns(FloorFileWarning, match=r"2.6 pixels of 0.05 m: read as 3 pixels"):  # rounded, not cut
        assert floor_frame(yaml, cell_size=0.13).factor == 3
    with pytest.raises(FloorFileError, match="below half of"):
        layout_labels(yaml, cell_size=0.02)


def test_an_origin_yaw_is_ignored_with_a_warning(tmp_path):
    (tmp_path / "floor.pgm").write_bytes(pgm_p5(asymmetric_floor()))
    yaml = tmp_path / "floor.yaml"
    yaml.write_text("image: floor.pgm\nresolution: 0.05\norigin: [0.0, 0.0, 0.5]\n")
    with pytest.warns(FloorFileWarning, match="origin yaw 0.5 is ignored"):
        assert floor_frame(yaml).cell(0.01, 0.01) == 40


def test_movingai_water_and_trees_are_walls(tmp_path):
    path = write_map(tmp_path / "lake.map", "..W..\n.TGS.\n@.O..")
    np.testing.assert_array_equal(layout_labels(path, doorways=False), [[0, 0, 1, 0, 0],
                                                                       [0, 1, 0, 0, 0],
                                                                       [1, 0, 1, 0, 0]])


def test_a_map_without_its_type_line_is_read_with_a_warning(tmp_path):
    typed = write_map(tmp_path / "typed.map", ROOMS)
    bare = tmp_path / "bare.map"
    bare.write_text(typed.read_text().split("\n", 1)[1])
    with pytest.warns(FloorFileWarning, match="no 'type octile' line"):
        labels = layout_labels(bare)
    np.testing.assert_array_equal(labels, layout_labels(typed))
    bad = tmp_path / "bad.map"
    bad.write_text("height 3\nwidth 3\nmapp\n...\n...\n...\n")
    with pytest.warns(FloorFileWarning), pytest.raises(FloorFileError, match="line 3: expected 'map'"):
        layout_labels(bad)


def test_a_large_floor_without_cell_size_warns_with_its_cost(tmp_path):
    path = write_map(tmp_path / "hall.map", "\n".join(["." * 130] * 130))
    # 16900 cells at 6 us a cell: 0.1014 s a BK step; cell_size 2 reads 65 x 65 = 4225 cells, within 16384
    with pytest.warns(LargeFloorWarning, match=r"130 x 130 = 16900 cells .* takes about 0.1 s .*cell_size=2"):
        layout_labels(path)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert layout_labels(path, cell_size=2).shape == (65, 65)
        assert layout_labels(path, region=((0, 100), (0, 100))).shape == (100, 100)


def test_world_specs_take_doorways_cell_rule_and_region(tmp_path, monkeypatch):
    path = write_map(tmp_path / "door.map", DOORWAY)
    world = parse_world(f"layout:{path},cell_size=2,doorways=0")
    np.testing.assert_array_equal(world.true_map.reshape(4, 4), layout_labels(path, cell_size=2, doorways=False))
    assert (world.true_map == OPEN).sum() == 0
    assert (parse_world(f"layout:{path},cell_size=2").true_map == OPEN).sum() == 1
    world = parse_world(f"layout:{path},cell_size=2,cell_rule=any,region=0:8x0:6,start=0")
    np.testing.assert_array_equal(world.true_map.reshape(4, 3), [[0, 0, 1]] * 4)
    yaml = write_ros(tmp_path, asymmetric_floor(), resolution=0.05)
    assert parse_world(f"layout:{yaml},region=-1:-0.8x-1.8:-1.7").model.shape == (2, 4)
    for spec, match in [(f"layout:{path},doorways=2", "doorways is 0 or 1"),
                        (f"layout:{path},region=0:8", "region is A:BxC:D"),
                        (f"layout:{path},region=0:8x0:z", "region is A:BxC:D"),
                        (f"layout:{path},cell_size=2,cell_rule=all", "cell_rule must be one of")]:
        with pytest.raises(ModelError, match=match):
            parse_world(spec)


def test_a_layout_path_with_a_comma(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    write_map(tmp_path / "a,b.map", ROOMS)
    world = parse_world('layout:"a,b.map",p_obs=0.8')
    np.testing.assert_array_equal(world.true_map, om.read_layout("a,b.map")[1])
    assert parse_world('layout:"a,b.map"').model.shape == (9, 11)
    with pytest.raises(ModelError, match=r"expected key=value, got 'b.map'; a layout path with a comma goes in "
                                         r"double quotes: layout:\"a,b.map\""):
        parse_world("layout:a,b.map")
    for spec, match in [('layout:"a,b.map', "closing double quote"), ('layout:"a,b.map"x', "comma after the quoted")]:
        with pytest.raises(ModelError, match=match):
            parse_world(spec)
