"""Floor files as an attacker or a careless user gives them (issue 43, section 2, items 4, 5 and the
floor-file messages of 14): what is not a regular file, headers that ask for more than the file or
the caps hold, numbers that are not ASCII digits, and messages that say what went wrong. Each case
is refused with a :class:`FloorFileError` naming the problem, before any array of the header's size
is made (checked with tracemalloc), and ``layout:`` world specs keep the class."""

import os
import signal
import tracemalloc

import numpy as np
import pytest

import onlinemap as om
from onlinemap import layouts
from onlinemap.errors import FloorFileError, ModelError
from onlinemap.layouts import layout_labels, read_pgm
from onlinemap.worlds import parse_world
from test_layouts import ROOMS, pgm_p5, ros_floor, write_map, write_ros

FREE, WALL = 0, 1


@pytest.fixture
def alarm():
    """Fail instead of hanging: a read that blocks (a FIFO opened for reading) is interrupted."""
    def interrupted(*_):
        raise TimeoutError("the read blocked")

    previous = signal.signal(signal.SIGALRM, interrupted)
    signal.alarm(10)
    yield
    signal.alarm(0)
    signal.signal(signal.SIGALRM, previous)


def refused(call, match, peak_bytes=8 * 2**20):
    """``call`` raises FloorFileError matching ``match`` with at most ``peak_bytes`` allocated."""
    tracemalloc.start()
    try:
        with pytest.raises(FloorFileError, match=match):
            call()
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < peak_bytes, f"{peak} bytes allocated before refusing"


def test_a_fifo_is_refused_without_blocking(tmp_path, alarm):
    fifo = tmp_path / "floor.map"
    os.mkfifo(fifo)
    with pytest.raises(FloorFileError, match=r"floor.map is a FIFO \(named pipe\), not a regular file"):
        om.read_layout(fifo)
    with pytest.raises(FloorFileError, match="is a FIFO"):
        parse_world(f"layout:{fifo}")


def test_a_link_to_a_device_is_refused_unread(tmp_path):
    link = tmp_path / "floor.pgm"
    link.symlink_to("/dev/zero")
    refused(lambda: om.read_layout(link), "floor.pgm is a character device, not a regular file")


def test_a_directory_is_refused(tmp_path):
    (tmp_path / "floor.map").mkdir()
    with pytest.raises(FloorFileError, match="floor.map is a directory, not a regular file"):
        om.read_layout(tmp_path / "floor.map")


@pytest.mark.parametrize("make, kind", [(os.mkfifo, "a FIFO"), (os.mkdir, "a directory")])
def test_a_yaml_image_that_is_not_a_file_says_what_it_is(tmp_path, alarm, make, kind):
    yaml = write_ros(tmp_path, ros_floor())
    (tmp_path / "floor.pgm").unlink()
    make(tmp_path / "floor.pgm")
    with pytest.raises(FloorFileError, match=f"floor.yaml, line 1: image .*floor.pgm is {kind}"):
        om.read_layout(yaml)


def test_the_bytes_read_are_bounded(tmp_path, monkeypatch):
    path = write_map(tmp_path / "rooms.map", ROOMS)
    monkeypatch.setattr(layouts, "MAX_FILE_BYTES", 50)
    with pytest.raises(FloorFileError, match="is larger than 50 bytes"):
        om.read_layout(path)


MAP_HEADERS = [
    ("type octile\nheight 3\nwidth 1000000000\nmap\n...\n", "3 x 1000000000 = 3000000000 pixels, above the limit"),
    ("type octile\nheight \u00b2\nwidth 3\nmap\n...\n", "line 2: expected 'height H' and 'width W' .*ASCII digits"),
    ("type octile\nheight \u0663\nwidth 3\nmap\n...\n", "line 2: expected 'height H'"),  # an Arabic-Indic 3
    ("type octile\nheight " + "9" * 5000 + "\nwidth 3\nmap\n...\n", "line 2: expected 'height H'"),
    ("type octile\nheight 0\nwidth 3\nmap\n", "line 2: expected 'height H'"),
]


@pytest.mark.parametrize("text, match", MAP_HEADERS)
def test_malformed_map_headers_are_refused_before_allocating(tmp_path, text, match):
    path = tmp_path / "bad.map"
    path.write_text(text, encoding="utf-8")
    refused(lambda: om.read_layout(path), match)
    with pytest.raises(FloorFileError, match="world spec"):
        parse_world(f"layout:{path}")


PGM_HEADERS = [
    (b"P2\n3 2\n255\n0 0 0\n0 100000000000000000000 0\n", "line 5: pixel value '100000000000' is not a whole number"),
    (b"P2\n3 2\n255\n0 0 0\n0 " + b"7" * 5000 + b" 0\n", "line 5: pixel value '777777777777' is not a whole number"),
    (b"P2\n65536 65536\n255\n0 0\n", "65536 x 65536 = 4294967296 pixels, above the limit"),
    (b"P2\n4096 4096\n255\n0 0\n", "line 5: 2 pixel values, a 4096 x 4096 image needs 16777216"),
    (b"P5\n4096 4096\n255\n" + bytes(2), "the raster holds 2 bytes"),
    (b"P5\n\xc2\xb2 3\n255\n" + bytes(9), "the PGM width must be a whole number in 1..16777216 in ASCII digits"),
    (b"P2\n3 2\n255\n0 0 0\n0 \xc2\xb2 0\n", "line 5: pixel value"),
]


@pytest.mark.parametrize("image, match", PGM_HEADERS)
def test_malformed_pgm_images_are_refused_before_allocating(tmp_path, image, match):
    path = tmp_path / "bad.pgm"
    path.write_bytes(image)
    refused(lambda: read_pgm(path), match)
    refused(lambda: om.read_layout(write_ros(tmp_path, None, name="bad2", image=image)), match)
    with pytest.raises(FloorFileError, match="world spec"):
        parse_world(f"layout:{path}")


@pytest.mark.parametrize("cell_size", [100000, 10**30, 1e300])
def test_a_cell_size_above_the_map_is_refused(tmp_path, cell_size):
    path = write_map(tmp_path / "rooms.map", ROOMS)
    refused(lambda: om.read_layout(path, cell_size=cell_size), r"is larger than .*rooms.map \(9 x 11 pixels\)")
    yaml = write_ros(tmp_path, ros_floor())
    refused(lambda: om.read_layout(yaml, cell_size=float(cell_size)), r"is larger than .*floor.yaml \(10 x 12")


@pytest.mark.parametrize("resolution", ["1e-300", "1e-320"])
def test_a_tiny_resolution_is_refused_at_any_cell_size(tmp_path, resolution):
    yaml = write_ros(tmp_path, ros_floor(), resolution=resolution)
    refused(lambda: om.read_layout(yaml, cell_size=1.0), "is larger than")
    with pytest.raises(FloorFileError, match="world spec .*is larger than"):
        parse_world(f"layout:{yaml},cell_size=1.0")


def test_the_cell_cap_is_checked_after_cell_size_before_decoding(tmp_path, monkeypatch):
    path = write_map(tmp_path / "big.map", "\n".join(["." * 20] * 20))
    monkeypatch.setattr(om.arguments, "MAX_CELLS", 100)
    decoded = []
    source = layouts._movingai
    monkeypatch.setattr(layouts, "_movingai", lambda p: source(p)._replace(decode=lambda: decoded.append(1)))
    with pytest.raises(FloorFileError, match=r"20 x 20 = 400 cells at cell_size None, above the limit of 100"):
        layout_labels(path)
    assert decoded == []  # refused on the header alone
    monkeypatch.setattr(layouts, "_movingai", source)
    assert layout_labels(path, cell_size=2).shape == (10, 10)  # 100 cells: within the cap
    # the model reads a cross of 5 cells a step: 100 cells x 5 offsets is above the cap, refused on the header
    monkeypatch.setattr(layouts, "_movingai", lambda p: source(p)._replace(decode=lambda: decoded.append(1)))
    with pytest.raises(FloorFileError, match=r"10 x 10 = 100 cells x 5 cells read a step at cell_size 2, above"):
        om.read_layout(path, cell_size=2)
    assert decoded == []
    monkeypatch.setattr(layouts, "_movingai", source)
    assert om.read_layout(path, cell_size=5)[0].shape == (4, 4)  # 16 cells x 5 offsets


def test_a_one_row_floor_is_not_told_to_use_corridor(tmp_path):
    path = write_map(tmp_path / "row.map", "........")
    with pytest.raises(FloorFileError, match="one cell high .*give a smaller cell_size or a taller region") as error:
        om.read_layout(path)
    assert "corridor" not in str(error.value)
    tall = write_map(tmp_path / "tall.map", "....\n....\n....")
    with pytest.raises(FloorFileError, match="one cell high at cell_size 3"):
        om.read_layout(tall, cell_size=3)


def test_a_byte_order_mark_is_skipped(tmp_path):
    plain = write_map(tmp_path / "rooms.map", ROOMS)
    marked = tmp_path / "marked.map"
    marked.write_bytes(b"\xef\xbb\xbf" + plain.read_bytes())
    np.testing.assert_array_equal(layout_labels(marked), layout_labels(plain))
    yaml = write_ros(tmp_path, ros_floor())
    marked_yaml = tmp_path / "marked.yaml"
    marked_yaml.write_bytes(b"\xef\xbb\xbf" + yaml.read_bytes())
    np.testing.assert_array_equal(layout_labels(marked_yaml, cell_size=0.1), layout_labels(yaml, cell_size=0.1))


def test_duplicate_yaml_keys_are_refused(tmp_path):
    yaml = write_ros(tmp_path, ros_floor(), extra="resolution: 0.1\n")
    with pytest.raises(FloorFileError, match=r"line 6: key 'resolution' given twice \(first on line 2\)"):
        om.read_layout(yaml)


def test_a_yaml_that_is_not_utf8_is_refused(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_bytes(b"image: \xff.pgm\nresolution: 0.05\n")
    with pytest.raises(FloorFileError, match="not UTF-8 text"):
        om.read_layout(path)


@pytest.mark.parametrize("origin, match", [("[1, 2]", "origin must be \\[x, y, yaw\\]"),
                                           ("[a, 0, 0]", "origin must be"), ("[nan, 0, 0]", "origin must be")])
def test_a_malformed_origin_is_refused(tmp_path, origin, match):
    (tmp_path / "floor.pgm").write_bytes(pgm_p5(ros_floor()))
    yaml = tmp_path / "floor.yaml"
    yaml.write_text(f"image: floor.pgm\nresolution: 0.05\norigin: {origin}\n")
    with pytest.raises(FloorFileError, match=f"line 3: {match}"):
        om.read_layout(yaml)


def test_floor_file_errors_are_model_errors(tmp_path):
    assert issubclass(FloorFileError, ModelError)  # callers catching ModelError keep working


def test_layout_errors_on_the_command_line_are_one_line(tmp_path):
    from test_cli import assert_one_line_error, cli
    path = tmp_path / "bad.map"
    path.write_text("type octile\nheight 3\nwidth 1000000000\nmap\n...\n")
    code, _, err = cli(["run", "--world", f"layout:{path}", "--steps", "5"])
    assert_one_line_error(code, err, "above the limit")
    (tmp_path / "floor.map").mkdir()
    code, _, err = cli(["run", "--world", f"layout:{tmp_path / 'floor.map'}", "--steps", "5"])
    assert_one_line_error(code, err, "is a directory")
