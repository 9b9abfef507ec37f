"""Exact filter against pgmpy variable elimination on the network unrolled over the run
(DESIGN.md section 6). pgmpy is pinned in the test extra. The network builder lives in
``onlinemap.peers`` (shared with ``onlinemap bench peers``); the motion tables passed to it
are rebuilt here from the model's scalars, independently of the model's own."""

import numpy as np
import pytest

import onlinemap as om
from estimator_cases import beliefs
from oracles import grid_motion

pytest.importorskip("pgmpy")
from onlinemap.peers import pgmpy_filter, sensor_columns  # noqa: E402


def test_sensor_columns_follow_pgmpy_evidence_order():
    model = om.corridor(3, 2, p_obs=0.8)
    columns = sensor_columns(model)
    sensor = np.array(model.sensor)
    for column, (l, *m) in enumerate(np.ndindex(3, 2, 2, 2)):  # L slowest, then M0, M1, M2
        np.testing.assert_array_equal(columns[:, column], sensor[m[l]])


def test_exact_filter_equals_pgmpy_variable_elimination():
    model = om.corridor(3, 2, p_obs=0.8, p_move=0.7, p_change=0.05)
    rng = np.random.default_rng(11)
    run = om.simulate(model, None, om.random_walk(model, 4, rng), rng)
    est = om.make_estimator("exact", model)
    peer = pgmpy_filter(model, run.actions, run.observations,
                        motion=grid_motion(model.rows, model.cols, model.p_move))
    for t, belief in enumerate(beliefs(est, run)):
        np.testing.assert_allclose(belief.location, peer.location[t], atol=1e-10)
        np.testing.assert_allclose(belief.map, peer.map[t], atol=1e-10)
