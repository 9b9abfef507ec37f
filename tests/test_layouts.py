"""Floors read from files (issue 22, item 1; DESIGN.md section 8): MovingAI ``.map`` files and ROS
map_server ``.yaml`` + ``.pgm`` occupancy grids written here, doorways, downsampling (against a
brute force over every coarse cell), the world spec ``layout:PATH``, and malformed files."""

import itertools

import numpy as np
import pytest

import onlinemap as om
from onlinemap.errors import ModelError
from onlinemap.layouts import doorway_labels, downsample, layout_labels, read_pgm
from onlinemap.worlds import parse_world

FREE, WALL, OPEN = 0, 1, 2

ROOMS = """\
@@@@@@@@@@@
@...@.....@
@.........@
@...@.....@
@@.@@@@@@@@
@.........@
@TTTT.TTTT@
@GGSG.....@
@@@@@@@@@@@
"""
# (2, 4): a gap in a wall column between two rooms; (4, 2): a gap in a wall row between a room and a
# corridor one cell high; (6, 5): a gap between the corridor and the bottom room. Row 5 is a corridor,
# none of its cells a door; (5, 5) is free above the gap.
ROOMS_DOORS = [(2, 4), (4, 2), (6, 5)]


def write_map(path, text, header=None):
    rows = text.strip("\n").splitlines()
    header = header if header is not None else f"type octile\nheight {len(rows)}\nwidth {len(rows[0])}\nmap\n"
    path.write_text(header + "\n".join(rows) + "\n")
    return path


def pgm_p5(pixels, maxval=255, comment=True):
    height, width = pixels.shape
    header = b"P5\n" + (b"# written by the test\n" if comment else b"") + b"%d %d\n%d\n" % (width, height, maxval)
    return header + pixels.astype(np.uint8 if maxval < 256 else ">u2").tobytes()


def pgm_p2(pixels, maxval=255):
    height, width = pixels.shape
    return (f"P2\n{width} {height}\n{maxval}\n" + "\n".join(" ".join(map(str, row)) for row in pixels) + "\n").encode()


def write_ros(tmp_path, pixels, name="floor", image=None, resolution=0.05, extra="", **pgm):
    (tmp_path / f"{name}.pgm").write_bytes(image if image is not None else pgm_p5(pixels, **pgm))
    yaml = tmp_path / f"{name}.yaml"
    yaml.write_text(f"image: {name}.pgm\nresolution: {resolution}\norigin: [-1.0, -2.0, 0.0]\n"
                    f"occupied_thresh: 0.65\nfree_thresh: 0.196\n{extra}")
    return yaml


def expected_doorways(free):
    """The doorway rule, cell by cell: free, walls (or the grid's edge) on two opposite sides, free on
    the other two, and on each of those sides a free diagonal neighbour."""
    rows, cols = free.shape

    def open_(r, c):
        return 0 <= r < rows and 0 <= c < cols and free[r, c]

    labels = np.where(free, FREE, WALL)
    for r, c in itertools.product(range(rows), range(cols)):
        if not free[r, c]:
            continue
        row_gap = not open_(r, c - 1) and not open_(r, c + 1) and open_(r - 1, c) and open_(r + 1, c) \
            and (open_(r - 1, c - 1) or open_(r - 1, c + 1)) and (open_(r + 1, c - 1) or open_(r + 1, c + 1))
        column_gap = not open_(r - 1, c) and not open_(r + 1, c) and open_(r, c - 1) and open_(r, c + 1) \
            and (open_(r - 1, c - 1) or open_(r + 1, c - 1)) and (open_(r - 1, c + 1) or open_(r + 1, c + 1))
        if row_gap or column_gap:
            labels[r, c] = OPEN
    return labels


def test_movingai_map_doorways_and_model(tmp_path):
    path = write_map(tmp_path / "rooms.map", ROOMS)
    model, true_map = om.read_layout(path)
    grid = true_map.reshape(model.shape)
    assert model.shape == (9, 11) and model.has_blocking and model.n_readings == 5
    assert sorted(zip(*np.nonzero(grid == OPEN))) == ROOMS_DOORS
    passable = np.array([[ch in ".GS" for ch in row] for row in ROOMS.splitlines()])
    np.testing.assert_array_equal(grid != WALL, passable)
    assert grid.flat[model.start] == FREE and model.start == 12  # the first free cell of the largest region
    plain = layout_labels(path, doorways=False)
    np.testing.assert_array_equal(plain, np.where(passable, FREE, WALL))
    other, same = om.read_layout(str(path), p_obs=0.7, p_door=0.01, blocking=False, footprint="cell", start=56)
    np.testing.assert_array_equal(same, true_map)
    assert not other.has_blocking and other.n_readings == 1 and other.start == 56 and other.C[2, 3] == 0.01


def test_the_default_start_is_in_the_largest_region(tmp_path):
    path = write_map(tmp_path / "pocket.map", "@@@@@@\n@.@..@\n@@@..@\n@@@..@\n@@@@@@")
    model, true_map = om.read_layout(path)
    assert model.start == 9  # (1, 3): the one-cell pocket at (1, 1) comes first but is smaller


@pytest.mark.parametrize("seed", range(5))
def test_doorways_match_the_rule_cell_by_cell(seed):
    rng = np.random.default_rng(seed)
    free = rng.random((12, 15)) < 0.6
    labels = doorway_labels(free)
    np.testing.assert_array_equal(labels, expected_doorways(free))
    assert (labels == OPEN).sum() >= 3  # the rule is exercised (5 to 11 doorways on these seeds)


def coarse_cell_free(free, i, j, k, rule, occupied_thresh=0.65):
    """The cell rules of the module's docstring, for one coarse cell, pixel by pixel."""
    def pixel(a, b):  # a pixel past the edge is padding, never free
        r, c = i * k + a, j * k + b
        return r < free.shape[0] and c < free.shape[1] and bool(free[r, c])

    grid = [[pixel(a, b) for b in range(k)] for a in range(k)]
    n_free = sum(map(sum, grid))
    if rule == "any":
        return n_free == k * k
    if rule == "threshold":
        return (k * k - n_free) / (k * k) <= occupied_thresh
    line_blocked = any(not any(row) for row in grid) or any(not any(grid[a][b] for a in range(k)) for b in range(k))
    return n_free > k * k / 2 and not line_blocked


@pytest.mark.parametrize("rule", ["any", "majority", "threshold"])
@pytest.mark.parametrize("factor, shape", [(1, (7, 9)), (2, (7, 9)), (3, (7, 9)), (4, (8, 8)), (5, (3, 4))])
def test_downsample_matches_a_brute_force(factor, shape, rule):
    rng = np.random.default_rng(factor)
    for density in (0.9, 0.6, 0.4):
        free = rng.random(shape) < density
        coarse = downsample(free, factor, rule)
        rows, cols = -(-shape[0] // factor), -(-shape[1] // factor)
        assert coarse.shape == (rows, cols)
        for i, j in itertools.product(range(rows), range(cols)):
            assert coarse[i, j] == coarse_cell_free(free, i, j, factor, rule), (density, i, j)


def test_movingai_downsampling_keeps_thin_walls(tmp_path):
    text = "\n".join(["." * 8] * 3 + ["...@...."] + ["." * 8] * 4)
    path = write_map(tmp_path / "thin.map", text)
    labels = layout_labels(path, cell_size=2, doorways=False, cell_rule="any")
    expected = np.zeros((4, 4), dtype=int)
    expected[1, 1] = WALL  # the one obstacle pixel (3, 3) walls the coarse cell (1, 1)
    np.testing.assert_array_equal(labels, expected)
    assert layout_labels(path, cell_size=3, doorways=False, cell_rule="any").shape == (3, 3)  # padded to whole cells
    np.testing.assert_array_equal(layout_labels(path, cell_size=3, doorways=False, cell_rule="any")[2], [WALL] * 3)


def ros_floor():
    """A 10 x 12 pixel floor: free 254, occupied 0, unknown 205; two rooms split by a wall two pixels
    thick with a doorway two pixels wide, unknown outside."""
    pixels = np.full((10, 12), 254)
    pixels[[0, -1], :] = 0
    pixels[:, [0, -1]] = 0
    pixels[:, 6:8] = 0
    pixels[4:6, 6:8] = 254  # the doorway
    pixels[8:10, 10:12] = 205  # unknown corner
    return pixels


def test_ros_map_downsampled_to_a_cell_size_in_metres(tmp_path):
    yaml = write_ros(tmp_path, ros_floor(), resolution=0.05)
    labels = layout_labels(yaml, cell_size=0.1)
    expected = np.array([[1, 1, 1, 1, 1, 1],
                         [1, 0, 0, 1, 0, 1],
                         [1, 0, 0, 2, 0, 1],
                         [1, 0, 0, 1, 0, 1],
                         [1, 1, 1, 1, 1, 1]])
    np.testing.assert_array_equal(labels, expected)
    model, true_map = om.read_layout(yaml, cell_size=0.1)
    np.testing.assert_array_equal(true_map.reshape(model.shape), expected)
    assert layout_labels(yaml).shape == (10, 12)  # no cell size: a pixel a cell
    np.testing.assert_array_equal(layout_labels(tmp_path / "floor.pgm", cell_size=2), expected)  # a bare .pgm
    # P2 and 16-bit P5 images of the same floor read the same
    p2 = write_ros(tmp_path, None, name="ascii", image=pgm_p2(ros_floor()))
    np.testing.assert_array_equal(layout_labels(p2, cell_size=0.1), expected)
    wide = write_ros(tmp_path, ros_floor() * 1000 // 255, name="wide", maxval=1000)
    np.testing.assert_array_equal(layout_labels(wide, cell_size=0.1), expected)


def test_ros_thresholds_and_negate(tmp_path):
    pixels = np.array([[0, 45, 100, 150, 200, 230, 255]])  # occupancy (255 - v) / 255: 1, .82, .61, .41, .22, .10, 0
    free = layout_labels(write_ros(tmp_path, np.repeat(pixels, 2, axis=0), name="a"), doorways=False)[0] == FREE
    np.testing.assert_array_equal(free, [False, False, False, False, False, True, True])  # free below 0.196
    negated = write_ros(tmp_path, np.repeat(pixels, 2, axis=0), name="b", extra="negate: 1\nmode: scale\n")
    free = layout_labels(negated, doorways=False)[0] == FREE
    np.testing.assert_array_equal(free, [True, True, False, False, False, False, False])  # v / 255 < 0.196


def test_layout_world_specs(tmp_path, monkeypatch):
    path = write_map(tmp_path / "rooms.map", ROOMS)
    world = parse_world(f"layout:{path},p_obs=0.8,p_door=0.01")
    model, true_map = om.read_layout(path, p_obs=0.8, p_door=0.01)
    np.testing.assert_array_equal(world.true_map, true_map)
    assert om.model.model_difference(world.model, model) is None
    monkeypatch.chdir(tmp_path)
    assert not parse_world("layout:rooms.map,blocking=0,footprint=cell").model.has_blocking
    yaml = write_ros(tmp_path, ros_floor())
    assert parse_world(f"layout:{yaml.name},cell_size=0.1").model.shape == (5, 6)
    for spec, match in [("layout", "layout:PATH"), ("layout:nowhere.map", "cannot read"),
                        ("layout:floor.yaml,cell_size=x", "cell_size must be a number"),
                        ("layout:floor.yaml,cell_size=0.01", "below half of"), ("layout:rooms.map,blocking=2", "0 or 1")]:
        with pytest.raises(ModelError, match=match):
            parse_world(spec)


MAP_ERRORS = [
    ("type\nheight 3\nwidth 3\nmap\n", "...\n...\n...", "line 1: expected 'type octile'"),
    ("type octile\nheight x\nwidth 3\nmap\n", "...\n...\n...", "line 2: expected 'height H'"),
    ("type octile\nheight 3\nheight 3\nmap\n", "...\n...\n...", "line 3: expected 'height H'"),
    ("type octile\nheight 3\nwidth 3\nmapp\n", "...\n...\n...", "line 4: expected 'map'"),
    ("type octile\nheight 3", "", "line 3: the header ends early"),
    (None, "...\n....\n...", "line 6: a row of 4 characters, the header says width 3"),
    (None, "...\n.x.\n...", "line 6, column 2: unknown character 'x'"),
    ("type octile\nheight 4\nwidth 3\nmap\n", "...\n...\n...", "line 7: 3 map rows, the header says height 4"),
    ("type octile\nheight 2\nwidth 3\nmap\n", "...\n...\n...", "line 7: 3 map rows, the header says height 2"),
    (None, "@@@\n@@@\n@@@", "no free cell"),
]


@pytest.mark.parametrize("header, rows, match", MAP_ERRORS)
def test_malformed_map_files_name_the_file_and_line(tmp_path, header, rows, match):
    path = tmp_path / "bad.map"
    if header is None:
        write_map(path, rows)
    else:
        path.write_text(header + rows + "\n")
    with pytest.raises(ModelError, match=match) as error:
        om.read_layout(path)
    assert str(path) in str(error.value)


PGM_ERRORS = [
    (b"P6\n3 3\n255\n" + bytes(9), "line 1: not a PGM image"),
    (b"P5\n# a comment\n3 x\n255\n" + bytes(9), "line 3: the PGM height must be a whole number"),
    (b"P5\n3 3\n0\n" + bytes(9), "line 3: the PGM maxval"),
    (b"P5\n3 3\n", "line 3: the PGM header ends early"),
    (b"P5\n3 3\n255\n" + bytes(8), "after line 3: the raster holds 8 bytes"),
    (b"P2\n3 2\n255\n0 0 0\n0 x 0\n", "line 5: pixel value 'x'"),
    (b"P2\n3 2\n255\n0 0 0\n0 0\n", "line 6: 5 pixel values"),
    (b"P2\n3 1\n255\n0 0 0 0\n", "line 4: more than 3 x 1"),
    (b"P2\n3 2\n9\n0 10 0\n0 0 0\n", "above maxval 9"),
]


@pytest.mark.parametrize("image, match", PGM_ERRORS)
def test_malformed_pgm_images_name_the_file_and_line(tmp_path, image, match):
    path = tmp_path / "bad.pgm"
    path.write_bytes(image)
    with pytest.raises(ModelError, match=match) as error:
        read_pgm(path)
    assert str(path) in str(error.value)
    with pytest.raises(ModelError, match=match):
        om.read_layout(write_ros(tmp_path, None, name="bad", image=image))


YAML_ERRORS = [
    ("resolution: 0.05\n", "no 'image:' line"),
    ("image: floor.pgm\n", "no 'resolution:' line"),
    ("image: floor.pgm\nresolution: fine\n", "line 2: resolution must be a number"),
    ("image: floor.pgm\nresolution: 0\n", r"line 2: resolution must be a number in \(0, inf\), got '0'"),
    ("image: missing.pgm\nresolution: 0.05\n", r"line 1: image .*missing.pgm: cannot read it \(No such file"),
    ("image: floor.png\nresolution: 0.05\n", "line 1: image 'floor.png' is not a .pgm"),
    ("image: floor.pgm\nresolution: 0.05\nnegate: 2\n", "line 3: negate must be a number in"),
    ("image: floor.pgm\nresolution: 0.05\nnegate: 0.5\n", "line 3: negate must be 0 or 1"),
    ("image: floor.pgm\nresolution: 0.05\nfree_thresh: 0.9\n", "free_thresh 0.9 is above occupied_thresh"),
    ("image: floor.pgm\nresolution: 0.05\nmode: raw\n", "line 3: mode 'raw' is not read"),
    ("image: floor.pgm\nresolution 0.05\n", "line 2: expected 'key: value'"),
]


@pytest.mark.parametrize("text, match", YAML_ERRORS)
def test_malformed_yaml_files_name_the_file_and_line(tmp_path, text, match):
    (tmp_path / "floor.pgm").write_bytes(pgm_p5(ros_floor()))
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(ModelError, match=match) as error:
        om.read_layout(path)
    assert str(path) in str(error.value)


def test_bad_arguments_raise_model_errors_naming_them(tmp_path):
    path = write_map(tmp_path / "rooms.map", ROOMS)
    yaml = write_ros(tmp_path, ros_floor())
    for call, match in [(lambda: om.read_layout(3), "path must be a str"),
                        (lambda: om.read_layout(tmp_path / "floor.txt"), "unknown floor format '.txt'"),
                        (lambda: om.read_layout(path, cell_size=1.5), "cell_size must be a whole number"),
                        (lambda: om.read_layout(path, cell_size=0), "cell_size must be at least 1"),
                        (lambda: om.read_layout(yaml, cell_size=0.02), "cell_size 0.02 m is below half"),
                        (lambda: om.read_layout(yaml, cell_size=-0.1), "cell_size must be in"),
                        (lambda: om.read_layout(yaml, cell_size="0.1"), "cell_size must be a number"),
                        (lambda: om.read_layout(path, doorways="yes"), "doorways must be True or False"),
                        (lambda: om.read_layout(path, start=0), "start must be a free cell"),
                        (lambda: om.read_layout(path, p_obs=1.5), "p_obs")]:
        with pytest.raises(ModelError, match=match):
            call()
