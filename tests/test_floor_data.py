"""The real floors shipped as test data (tests/data/floors): every file is named in SOURCES.md with
its source and licence, matches the checksum written there, stays small, and reads as a floor of
14-40 cells a side whose start reaches most of its free cells."""

from __future__ import annotations

import hashlib
import re
import warnings
from pathlib import Path

import numpy as np
import pytest

from onlinemap.layouts import floor_frame
from onlinemap.model import WALL
from onlinemap.studies.floors import REAL_FLOORS, real_floor_specs
from onlinemap.worlds import parse_world

FLOORS = Path(__file__).resolve().parent / "data" / "floors"
SOURCES = (FLOORS / "SOURCES.md").read_text()


def shipped_files() -> list[Path]:
    return sorted(p for p in FLOORS.rglob("*") if p.is_file() and p.name != "SOURCES.md")


def test_every_file_has_its_checksum_and_source():
    written = dict(re.findall(r"\| `([\w./-]+)` \| `([0-9a-f]{64})` \|", SOURCES))
    files = {str(p.relative_to(FLOORS)): p for p in shipped_files()}
    assert set(written) == set(files)
    for name, path in files.items():
        assert hashlib.sha256(path.read_bytes()).hexdigest() == written[name], name
        assert path.stat().st_size < 40_000, name  # test data stays tiny


def test_every_floor_is_in_the_sources_table_with_a_licence():
    for name, spec in REAL_FLOORS.items():
        path = spec.split(",")[0]
        row = next(line for line in SOURCES.splitlines() if line.startswith(f"| `{path}`"))
        assert re.search(r"MIT|Apache-2\.0|same", row), name
        assert re.search(r"[0-9a-f]{40}|same commit", row), name


@pytest.mark.parametrize("name", sorted(REAL_FLOORS))
def test_each_floor_reads_at_a_study_size(name):
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no SmallRegionWarning: the start reaches most of the floor
        world = parse_world(real_floor_specs(FLOORS)[name])
    assert 14 <= world.model.rows <= 40 and 14 <= world.model.cols <= 40
    labels = np.asarray(world.true_map)
    assert 0.1 < np.mean(labels == WALL) < 0.5  # a floor, not a solid block nor an open field
    row = next(line for line in SOURCES.splitlines() if line.startswith(f"| `{REAL_FLOORS[name].split(',')[0]}`"))
    assert row.rstrip(" |").endswith(f"{world.model.rows} x {world.model.cols}")


def test_ros_crops_keep_the_map_frame():
    """The crop's origin is its bottom-left corner in the original frame: the metres SOURCES.md
    names are the crop's bounds."""
    tb3 = floor_frame(FLOORS / "tb3_world" / "map.yaml")
    np.testing.assert_allclose(tb3.bounds(), ((-3.2, 2.8), (-2.8, 2.8)), atol=1e-9)
    depot = floor_frame(FLOORS / "nav2_depot" / "depot.yaml")
    np.testing.assert_allclose(depot.bounds(), ((13.5, 23.5), (0.0, 8.0)), atol=1e-9)
