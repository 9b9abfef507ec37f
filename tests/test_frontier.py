"""policies.passability and the frontier planner: shortest expected paths against Floyd-Warshall
on a dense cost matrix built here from the definition (and scipy's Dijkstra as a peer); blocked
moves against a loop over cells."""

import numpy as np
import pytest
from scipy.sparse.csgraph import dijkstra

import onlinemap as om
from onlinemap.belief import Belief
from onlinemap.errors import ModelError
from onlinemap.model import GridModel, symmetric_channel
from policies.passability import (blocked_probability, distances_from, distances_to, enter_costs,
                                  expected_passability, unblocked_actions)


def floyd_warshall(model: GridModel, passable: np.ndarray, min_passable: float) -> np.ndarray:
    """(N, N) cheapest total of 1 / (p_move passable[j]) over paths i -> j, entering only cells with
    passable >= min_passable, by Floyd-Warshall over a dense matrix."""
    n = model.n_cells
    dist = np.full((n, n), np.inf)
    np.fill_diagonal(dist, 0.0)
    for i in range(n):
        for a in range(model.n_actions):
            j = int(model.neighbors[i, a])
            if j != i and passable[j] >= min_passable and model.p_move > 0:
                dist[i, j] = min(dist[i, j], 1.0 / (model.p_move * passable[j]))
    for k in range(n):
        dist = np.minimum(dist, dist[:, k:k + 1] + dist[k:k + 1, :])
    return dist


def random_topology(seed: int) -> GridModel:
    """Each action a random permutation of the cells (fixed points: no move); not symmetric."""
    rng = np.random.default_rng(seed)
    n, a_count = int(rng.integers(2, 12)), int(rng.integers(1, 5))
    neighbors = np.stack([rng.permutation(n) for _ in range(a_count)], axis=1)
    return GridModel(rows=1, cols=n, neighbors=neighbors, p_move=float(rng.uniform(0.1, 1.0)),
                     change=np.eye(2), sensor=symmetric_channel(2, 0.9), label_prior=[0.5, 0.5], start=0,
                     action_names=tuple(f"a{k}" for k in range(a_count)), label_names=("0", "1"),
                     blocking=np.array([False, True]))


CASES = [("random", seed) for seed in range(30)] + [("grid", seed) for seed in range(10)]


@pytest.mark.parametrize("kind,seed", CASES)
def test_distances_equal_floyd_warshall(kind, seed):
    rng = np.random.default_rng(seed)
    model = random_topology(seed) if kind == "random" else om.grid_model(
        int(rng.integers(1, 6)), int(rng.integers(2, 7)), 2, p_move=float(rng.uniform(0.2, 1.0)))
    passable = rng.uniform(0, 1, model.n_cells) * (rng.random(model.n_cells) > 0.2)
    min_passable = float(rng.choice([0.05, 0.3]))
    brute = floyd_warshall(model, passable, min_passable)
    sources = rng.choice(model.n_cells, size=int(rng.integers(1, model.n_cells + 1)), replace=False)
    np.testing.assert_allclose(distances_from(model, passable, sources, min_passable), brute[sources], rtol=1e-12)
    np.testing.assert_allclose(distances_to(model, passable, sources, min_passable), brute[:, sources].min(axis=1),
                               rtol=1e-12)
    # the peer: scipy's Dijkstra on a dense matrix of the cheapest edge i -> j (0: no edge; no cost is 0)
    costs = enter_costs(model, passable, min_passable)
    graph = np.full((model.n_cells,) * 2, np.inf)
    rows, cols = np.nonzero(model.neighbors != np.arange(model.n_cells)[:, None])
    np.minimum.at(graph, (rows, model.neighbors[rows, cols]), costs[model.neighbors[rows, cols]])
    graph[np.isinf(graph)] = 0.0
    np.testing.assert_allclose(dijkstra(graph, indices=sources), brute[sources], rtol=1e-12)


def test_costs_without_blocking_are_one_over_p_move_per_step():
    model = om.grid_model(3, 4, 2, p_move=0.8)
    belief = Belief(0, model.location_prior(), model.label_prior)
    passable = expected_passability(model, belief)
    assert np.array_equal(passable, np.ones(12))
    d = distances_from(model, passable, [0])[0]
    rows, cols = np.divmod(np.arange(12), 4)
    np.testing.assert_allclose(d, (rows + cols) / 0.8)  # Manhattan distance / p_move
    assert np.array_equal(blocked_probability(model, belief), np.zeros(4))


def test_blocked_probability_equals_a_loop_over_cells():
    model, _ = om.door_world("...\n.#.\n...\n", blocking=True)
    rng = np.random.default_rng(0)
    location = rng.dirichlet(np.ones(9))
    maps = rng.dirichlet(np.ones(4), size=9)
    belief = Belief(0, location, maps.copy())
    expected = np.zeros(4)
    for cell in range(9):
        for a in range(4):
            j = model.neighbors[cell, a]
            if j != cell:
                expected[a] += location[cell] * (maps[j, 1] + maps[j, 3])  # wall or closed door
    np.testing.assert_allclose(blocked_probability(model, belief), expected, rtol=1e-12)
    np.testing.assert_allclose(expected_passability(model, belief), maps[:, 0] + maps[:, 2], rtol=1e-12)
    # certain to be in the centre's west neighbour (cell 3) facing a certain wall east (cell 4)
    maps[4] = [0, 1, 0, 0]
    belief = Belief(0, np.eye(9)[3], maps.copy())
    east = model.action_names.index("east")
    assert blocked_probability(model, belief)[east] == 1.0
    assert unblocked_actions(model, belief).tolist() == [a != east for a in range(4)]
    maps[[0, 4, 6]] = [0, 1, 0, 0]  # walled in on every side but the west edge, which is no label
    assert unblocked_actions(model, Belief(0, np.eye(9)[3], maps.copy())).tolist() == [False, False, False, True]


def test_passability_refuses_bad_input():
    model = om.grid_model(2, 3, 2)
    with pytest.raises(ModelError, match="passable"):
        distances_to(model, np.ones(5), [0])
    with pytest.raises(ModelError, match="passable"):
        distances_to(model, np.full(6, 1.5), [0])
    with pytest.raises(ModelError, match="targets"):
        distances_to(model, np.ones(6), [6])
    with pytest.raises(ModelError, match="targets"):
        distances_to(model, np.ones(6), [])
    with pytest.raises(ModelError, match="sources"):
        distances_from(model, np.ones(6), [0.5])
    with pytest.raises(ModelError, match="min_passable"):
        distances_to(model, np.ones(6), [0], min_passable=0.0)
