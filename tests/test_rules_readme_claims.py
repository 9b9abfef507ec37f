"""README measured claims re-checked at a small size (issue 43 section 3), with a margin derived
from the claim's own spread. The claims checked elsewhere: the unmappable cells of buildings
(tests/test_rules_buildings.py), I0 (tests/test_rules_planners.py); resample-move's map-error gain
and the planners' ms per decision are benchmark rows (``onlinemap bench rbpf``'s ``replay ...``
rows, ``onlinemap bench planning``), not unit tests.

The exploration table ("Exploring ... the 10 x 10 door world with blocking walls and doors and a
cross footprint", RBPF 1000 particles, seeds 0-19): at 200 steps `frontier` has mean map error
0.038 and `random` 0.52. Here: its first 4 seeds, 200 steps, 300 particles. Random's map error
over 200 steps hardly depends on the filter (the walk does not read the belief): every seed above
0.25 and their mean within 0.15 of the table's 0.52 (runs of 200 random steps spread by about
0.12 here, seeds 0-3 giving 0.33-0.58: three standard errors of a 4-run mean are 0.18). Frontier
maps the floor in about one pass (100-130 presses), so after 200 steps every seed is below 0.1
(the table's mean 0.038, 0.017 at 250 steps) and at most a quarter of random's.
"""

from __future__ import annotations

import numpy as np
import pytest

import onlinemap as om
import policies


@pytest.fixture(scope="module")
def explored():
    model, true_map = om.door_world(blocking=True, footprint="cross", p_move=0.8, p_obs=0.9)
    out = {}
    for planner in ("frontier", "random"):
        for seed in range(4):
            frame = policies.explore(model, true_map, planner, "rbpf", steps=201, seed=seed,
                                     estimator_options={"n_particles": 300}, progress=False)
            out[planner, seed] = float(frame["map_error"].iloc[200])
    return out


def test_frontier_maps_the_blocking_door_world_far_faster_than_random(explored):
    for seed in range(4):
        assert explored["random", seed] > 0.25, explored
        assert explored["frontier", seed] < 0.1, explored
        assert explored["frontier", seed] < 0.25 * explored["random", seed], explored
    assert abs(np.mean([explored["random", seed] for seed in range(4)]) - 0.52) < 0.15, explored
