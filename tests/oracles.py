"""Independent references written from DESIGN.md section 1, by brute-force enumeration.

Nothing here uses onlinemap's tables or kernels: the grid geometry, motion, map dynamics and
sensor are rebuilt from the model's scalar parameters, and every (location, map) pair is
enumerated with itertools.product.
"""

from __future__ import annotations

import itertools
import math

import numpy as np


def grid_motion(rows: int, cols: int, p_move: float) -> np.ndarray:
    """(A, N, N) motion tables: corridor actions (left, right) for one row, else N, E, S, W."""
    n = rows * cols
    if rows == 1:
        moves = [(0, -1), (0, 1)]
    else:
        moves = [(-1, 0), (0, 1), (1, 0), (0, -1)]
    table = np.zeros((len(moves), n, n))
    for a, (dr, dc) in enumerate(moves):
        for r, c in itertools.product(range(rows), range(cols)):
            i = r * cols + c
            rr, cc = r + dr, c + dc
            if 0 <= rr < rows and 0 <= cc < cols:
                table[a, i, rr * cols + cc] += p_move
                table[a, i, i] += 1 - p_move
            else:
                table[a, i, i] = 1.0
    return table


def grid_targets(rows: int, cols: int) -> np.ndarray:
    """(A, N) intended cell of each action from each cell, -1 off the grid."""
    moves = [(0, -1), (0, 1)] if rows == 1 else [(-1, 0), (0, 1), (1, 0), (0, -1)]
    table = np.full((len(moves), rows * cols), -1)
    for a, (dr, dc) in enumerate(moves):
        for r, c in itertools.product(range(rows), range(cols)):
            if 0 <= r + dr < rows and 0 <= c + dc < cols:
                table[a, r * cols + c] = (r + dr) * cols + c + dc
    return table


def footprint_reads(rows: int, cols: int, offsets) -> list[list[int | None]]:
    """reads[l][f]: the cell offset f reads from location l, None off the grid."""
    out = []
    for r, c in itertools.product(range(rows), range(cols)):
        out.append([(r + dr) * cols + c + dc if 0 <= r + dr < rows and 0 <= c + dc < cols else None
                    for dr, dc in offsets])
    return out


class BruteForce:
    """Enumerates the state space S = {(l, m)}: N * K**N states, dense transition (S, S).

    With ``blocking`` (labels a robot cannot enter) the move from l to its intended cell j
    succeeds with p_move only when m_j does not block (judged before the map changes); with
    ``offsets`` (a sensor footprint) an observation is a tuple of readings, each O[m_c, z_f] for
    an on-grid cell c and -1 with probability 1 off the grid."""

    def __init__(self, rows, cols, n_labels, motion, change, sensor, label_prior, start,
                 blocking=(), offsets=((0, 0),)):
        self.n = rows * cols
        self.k = n_labels
        self.targets = grid_targets(rows, cols)
        self.blocking = set(blocking)
        self.reads = footprint_reads(rows, cols, offsets)
        self.single = tuple(offsets) == ((0, 0),)
        self.states = [(l, m) for l in range(self.n) for m in itertools.product(range(n_labels), repeat=self.n)]
        self.motion, self.change, self.sensor = motion, change, sensor
        movers = [(a, l) for a in range(len(self.targets)) for l in range(self.n) if self.targets[a, l] >= 0]
        self.p_move = float(motion[movers[0][0], movers[0][1], self.targets[movers[0]]]) if movers else 0.0
        prior = np.zeros(len(self.states))
        for s, (l, m) in enumerate(self.states):
            if l == start:
                prior[s] = np.prod([label_prior[i][m[i]] for i in range(self.n)])
        self.prior = prior
        self._trans = {}

    @classmethod
    def of(cls, model):
        """Built from the model's public scalars and small tables only (motion rebuilt)."""
        return cls(model.rows, model.cols, model.n_labels, grid_motion(model.rows, model.cols, model.p_move),
                   np.array(model.change), np.array(model.sensor), np.array(model.label_prior), model.start,
                   blocking=[k for k in range(model.n_labels) if model.blocking[k]], offsets=model.footprint)

    def move(self, a: int, l: int, m: tuple, l2: int) -> float:
        """P(L' = l2 | L = l, a, m)."""
        if not self.blocking:
            return self.motion[a, l, l2]
        j = self.targets[a, l]
        p = 0.0 if j < 0 or m[j] in self.blocking else self.p_move
        return (p if l2 == j else 0.0) + (1 - p if l2 == l else 0.0)

    def map_change(self) -> np.ndarray:
        """(K**N, K**N) P(m' | m) = prod_i C[m_i, m'_i], maps in the order of ``self.states``."""
        if not hasattr(self, "_map_change"):
            maps = list(itertools.product(range(self.k), repeat=self.n))
            change = self.change.tolist()  # Python floats: a product per pair without numpy's overhead
            self._map_change = np.array([[math.prod(change[m[i]][m2[i]] for i in range(self.n))
                                          for m2 in maps] for m in maps])
        return self._map_change

    def transition(self, a: int) -> np.ndarray:
        if a not in self._trans:
            size, n_maps = len(self.states), self.k ** self.n
            change = self.map_change()
            t = np.zeros((size, size))
            for s, (l, m) in enumerate(self.states):
                for l2 in range(self.n):
                    p = self.move(a, l, m, l2)
                    if p:  # states are ordered (l, m) with m fastest
                        t[s, l2 * n_maps:(l2 + 1) * n_maps] = p * change[s % n_maps]
            self._trans[a] = t
        return self._trans[a]

    def likelihood(self, z) -> np.ndarray:
        if self.single:
            return np.array([self.sensor[m[l], z] for l, m in self.states])
        readings = np.atleast_1d(z)
        out = np.ones(len(self.states))
        for s, (l, m) in enumerate(self.states):
            for cell, reading in zip(self.reads[l], readings):
                if cell is None:
                    out[s] *= float(reading == -1)
                else:
                    out[s] *= 0.0 if reading == -1 else self.sensor[m[cell], reading]
        return out

    def marginals(self, p: np.ndarray):
        loc = np.zeros(self.n)
        maps = np.zeros((self.n, self.k))
        for s, (l, m) in enumerate(self.states):
            loc[l] += p[s]
            for i in range(self.n):
                maps[i, m[i]] += p[s]
        return loc, maps

    def filter(self, actions, observations):
        """Per-step filtered (location (N,), map (N, K), log evidence)."""
        out = []
        p = self.prior.copy()
        log_ev = 0.0
        for t, z in enumerate(observations):
            if t > 0:
                p = p @ self.transition(actions[t - 1])
            p = p * self.likelihood(z)
            log_ev += np.log(p.sum())
            p /= p.sum()
            out.append((*self.marginals(p), log_ev))
        return out

    def smooth(self, actions, observations):
        """Per-step smoothed (location, map) by summing the joint over whole state paths' messages."""
        alphas = []
        p = self.prior.copy()
        for t, z in enumerate(observations):
            if t > 0:
                p = p @ self.transition(actions[t - 1])
            p = p * self.likelihood(z)
            p /= p.sum()
            alphas.append(p)
        beta = np.ones(len(self.states))
        out = [None] * len(observations)
        for t in range(len(observations) - 1, -1, -1):
            post = alphas[t] * beta
            out[t] = self.marginals(post / post.sum())
            if t > 0:
                beta = self.transition(actions[t - 1]) @ (self.likelihood(observations[t]) * beta)
                beta /= beta.sum()
        return out
