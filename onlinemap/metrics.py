"""Metrics on beliefs. All are pure and vectorised over leading axes (e.g. time)."""

from __future__ import annotations

import numpy as np


def map_error(map_belief: np.ndarray, true_map: np.ndarray) -> np.ndarray | float:
    """Expected map error: mean over cells of ``1 - P(true label)``.
    map_belief (..., N, K), true_map (..., N) -> (...)."""
    map_belief = np.asarray(map_belief)
    true_map = np.asarray(true_map)
    p_true = np.take_along_axis(map_belief, true_map[..., None], axis=-1)[..., 0]
    return 1.0 - p_true.mean(axis=-1)


def location_error(location: np.ndarray, true_location) -> np.ndarray | float:
    """``1 - P(true location)``. location (..., N), true_location (...) -> (...)."""
    location = np.asarray(location)
    true_location = np.asarray(true_location)
    return 1.0 - np.take_along_axis(location, true_location[..., None], axis=-1)[..., 0]


def total_variation(p: np.ndarray, q: np.ndarray) -> np.ndarray | float:
    """``0.5 * sum |p - q|`` over the last axis. (..., K) -> (...). For map beliefs (N, K) take
    ``.mean(-1)`` of the result to get the mean per-cell distance."""
    return 0.5 * np.abs(np.asarray(p) - np.asarray(q)).sum(axis=-1)


def normalized_entropy(p: np.ndarray) -> np.ndarray | float:
    """Entropy over the last axis divided by ``log(size)``, in [0, 1]; 0 over a single outcome
    (a one-cell world: nothing is uncertain). (..., K) -> (...)."""
    p = np.asarray(p, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        terms = np.where(p > 0, -p * np.log(p), 0.0)
    if p.shape[-1] == 1:
        return terms.sum(axis=-1) * 0.0
    return terms.sum(axis=-1) / np.log(p.shape[-1])


def map_entropy(map_belief: np.ndarray) -> np.ndarray | float:
    """Mean normalised label entropy over cells. (..., N, K) -> (...)."""
    return normalized_entropy(map_belief).mean(axis=-1)


def wrong_cells(map_belief: np.ndarray, true_map: np.ndarray, cells=None) -> int:
    """Number of cells (optionally among ``cells``) whose most likely label is not the true one."""
    wrong = np.argmax(np.asarray(map_belief), axis=-1) != np.asarray(true_map)
    return int(wrong[..., cells].sum() if cells is not None else wrong.sum())


def belief_expected_p_true(p: np.ndarray) -> np.ndarray | float:
    """What a belief expects its probability of the true value to be: ``sum_k p_k^2`` over the
    last axis, the mean of ``p_k`` under ``k ~ p``. A calibrated belief's P(true value) equals this
    on average (over data drawn from the model); a mean P(true value) below it means the belief
    claims more than it knows (overconfident). (..., K) -> (...). O(size)."""
    p = np.asarray(p, dtype=np.float64)
    return np.einsum("...k,...k->...", p, p)


class FloorDistances:
    """Distances in moves from a cell to every cell, computed when first asked for and kept:
    ``distances[cell]`` is the (N,) float row of ``cell`` (read-only), ``distances[cells]`` the
    (len(cells), N) rows of an int array of cells: the fewest moves from the cell to each cell
    entering only ``passable`` cells (``neighbors[i, a]`` is the cell a move ``a`` from ``i``
    reaches, itself where there is none). A cell that no such path reaches gets its distance on
    the grid ignoring the labels (the fewest moves with every cell passable: the Manhattan
    distance on a 4-neighbour grid); a cell the grid does not reach either gets N (more than any
    path). Unit-weight Dijkstra (:func:`scipy.sparse.csgraph.dijkstra`, one call for the cells
    new to a request): O(N A log N) per distinct cell asked for, N cells, A actions; memory
    O(N) per kept row.

    neighbors (N, A) int, passable (N,) bool."""

    def __init__(self, neighbors: np.ndarray, passable: np.ndarray) -> None:
        from scipy import sparse  # here, so that ``import onlinemap`` stays light

        neighbors = np.asarray(neighbors)
        n = neighbors.shape[0]
        source = np.repeat(np.arange(n), neighbors.shape[1])
        target = neighbors.reshape(-1)
        moves = source != target
        enters = moves & np.asarray(passable, dtype=bool)[target]
        self._floor = sparse.csr_matrix((np.ones(enters.sum()), (source[enters], target[enters])), shape=(n, n))
        self._grid = sparse.csr_matrix((np.ones(moves.sum()), (source[moves], target[moves])), shape=(n, n))
        self._slot = np.full(n, -1, dtype=np.int64)  # the row of each cell in _rows, -1 until asked for
        self._rows = np.empty((0, n))

    def __getitem__(self, cells) -> np.ndarray:
        cells = np.asarray(cells, dtype=np.int64)
        new = np.unique(cells[self._slot[cells] < 0])
        if len(new):
            from scipy.sparse.csgraph import dijkstra

            rows = np.atleast_2d(dijkstra(self._floor, indices=new, unweighted=True))
            cut_off = ~np.isfinite(rows)
            if cut_off.any():
                grid = np.atleast_2d(dijkstra(self._grid, indices=new, unweighted=True))
                rows[cut_off] = np.where(np.isfinite(grid[cut_off]), grid[cut_off], rows.shape[1])
            self._slot[new] = len(self._rows) + np.arange(len(new))
            self._rows = np.concatenate([self._rows, rows])
            self._rows.setflags(write=False)
        return self._rows[self._slot[cells]]


def location_distance(location_belief: np.ndarray, true_location, distances) -> np.ndarray | float:
    """Expected distance between the location belief and the true cell:
    ``sum_i P(L = i) d(true, i)``. "Off by one cell" scores about 1, "lost" scores the distance to
    where the belief is. location_belief (T, N) or (N,), true_location (T,) or scalar;
    ``distances[cells]`` the rows of distances from ``cells`` (an (N, N) array, or a
    :class:`FloorDistances`) -> (T,) or a float. O(T N), in blocks of steps that keep the
    gathered rows near 8 MB, plus the rows of the distinct true cells."""
    belief = np.asarray(location_belief, dtype=np.float64)
    truth = np.asarray(true_location)
    if belief.ndim == 1:
        return float(belief @ np.asarray(distances[int(truth)], dtype=np.float64))
    out = np.empty(belief.shape[0])
    block = max(1, 2**20 // max(belief.shape[1], 1))
    for start in range(0, len(out), block):
        rows = np.asarray(distances[truth[start:start + block]], dtype=np.float64)
        out[start:start + block] = np.einsum("tn,tn->t", belief[start:start + block], rows)
    return out
