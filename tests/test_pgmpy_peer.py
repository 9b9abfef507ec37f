"""Exact filter against pgmpy variable elimination on the network unrolled over the run
(DESIGN.md section 6). pgmpy is pinned in the test extra."""

import numpy as np
import pytest

import onlinemap as om
from oracles import grid_motion

pgmpy = pytest.importorskip("pgmpy")
from pgmpy.factors.discrete import TabularCPD  # noqa: E402
from pgmpy.inference import VariableElimination  # noqa: E402
from pgmpy.models import DiscreteBayesianNetwork  # noqa: E402


def unrolled_network(model, actions, n_steps):
    """Variables L_t, M_i_t, Z_t for t < n_steps; CPDs from the model's scalars."""
    n, k = model.n_cells, model.n_labels
    motion = grid_motion(model.rows, model.cols, model.p_move)
    edges, cpds = [], []
    for t in range(n_steps):
        for i in range(n):
            if t == 0:
                cpds.append(TabularCPD(f"M{i}_0", k, np.array(model.label_prior[i]).reshape(k, 1)))
            else:
                edges.append((f"M{i}_{t-1}", f"M{i}_{t}"))
                cpds.append(TabularCPD(f"M{i}_{t}", k, np.array(model.change).T,
                                       evidence=[f"M{i}_{t-1}"], evidence_card=[k]))
        if t == 0:
            cpds.append(TabularCPD("L_0", n, np.eye(n)[model.start].reshape(n, 1)))
        else:
            edges.append((f"L_{t-1}", f"L_{t}"))
            cpds.append(TabularCPD(f"L_{t}", n, motion[actions[t - 1]].T, evidence=[f"L_{t-1}"], evidence_card=[n]))
        # Z_t depends on L_t and every M_i_t: P(z | l, m) = O[m_l, z]
        parents = [f"L_{t}"] + [f"M{i}_{t}" for i in range(n)]
        edges += [(p, f"Z_{t}") for p in parents]
        columns = []
        for l in range(n):
            for m in np.ndindex(*(k,) * n):
                columns.append(np.array(model.sensor)[m[l]])
        cpds.append(TabularCPD(f"Z_{t}", k, np.array(columns).T, evidence=parents, evidence_card=[n] + [k] * n))
    net = DiscreteBayesianNetwork(edges)
    net.add_cpds(*cpds)
    net.check_model()
    return net


def test_exact_filter_equals_pgmpy_variable_elimination():
    model = om.corridor(3, 2, p_obs=0.8, p_move=0.7, p_change=0.05)
    rng = np.random.default_rng(11)
    run = om.simulate(model, None, om.random_walk(model, 4, rng), rng)
    est = om.make_estimator("exact", model)
    for t in range(run.n_steps):
        belief = est.step(None if t == 0 else run.actions[t - 1], run.observations[t])
        net = unrolled_network(model, run.actions, t + 1)
        infer = VariableElimination(net)
        evidence = {f"Z_{s}": int(run.observations[s]) for s in range(t + 1)}
        loc = infer.query([f"L_{t}"], evidence=evidence, show_progress=False).values
        np.testing.assert_allclose(belief.location, loc, atol=1e-10)
        for i in range(model.n_cells):
            cell = infer.query([f"M{i}_{t}"], evidence=evidence, show_progress=False).values
            np.testing.assert_allclose(belief.map[i], cell, atol=1e-10)
