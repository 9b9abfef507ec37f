"""The README's exploration table for ``info_gain`` ("Exploring a building": the 10 x 10 door world
with blocking walls and doors and a cross footprint, RBPF 1000 particles, seeds 20-39) re-checked
at a small size (issue 43 section 3): every one of its 20 runs reached map error 0.1, the slowest
after 159 steps (99-159). Here its first seed with 300 particles: it must reach 0.1 within
200 steps (the slowest measured run plus a quarter, for the smaller filter). A planner that
stopped valuing information (or never handed over to the frontier when nothing pays) wanders like
``random``, which is at 0.49 after 200 steps."""

from __future__ import annotations

import numpy as np
import onlinemap as om
import policies


def test_info_gain_maps_the_blocking_door_world_within_the_readmes_steps():
    model, true_map = om.door_world(blocking=True, footprint="cross", p_move=0.8, p_obs=0.9)
    frame = policies.explore(model, true_map, "info_gain", "rbpf", steps=201, seed=20,
                             estimator_options={"n_particles": 300}, progress=False)
    reached = np.flatnonzero(frame["map_error"].to_numpy() <= 0.1)
    assert len(reached) and reached[0] <= 200, frame["map_error"].iloc[[50, 100, 150, 200]].tolist()
