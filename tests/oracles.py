"""Independent references written from DESIGN.md section 1, by brute-force enumeration.

Nothing here uses onlinemap's tables or kernels: the grid geometry, motion, map dynamics and
sensor are rebuilt from the model's scalar parameters, and every (location, map) pair is
enumerated with itertools.product.
"""

from __future__ import annotations

import itertools

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


class BruteForce:
    """Enumerates the state space S = {(l, m)}: N * K**N states, dense transition (S, S)."""

    def __init__(self, rows, cols, n_labels, motion, change, sensor, label_prior, start):
        self.n = rows * cols
        self.k = n_labels
        self.states = [(l, m) for l in range(self.n) for m in itertools.product(range(n_labels), repeat=self.n)]
        self.motion, self.change, self.sensor = motion, change, sensor
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
                   np.array(model.change), np.array(model.sensor), np.array(model.label_prior), model.start)

    def transition(self, a: int) -> np.ndarray:
        if a not in self._trans:
            size = len(self.states)
            t = np.zeros((size, size))
            for s, (l, m) in enumerate(self.states):
                for s2, (l2, m2) in enumerate(self.states):
                    p = self.motion[a, l, l2]
                    if p:
                        t[s, s2] = p * np.prod([self.change[m[i], m2[i]] for i in range(self.n)])
            self._trans[a] = t
        return self._trans[a]

    def likelihood(self, z: int) -> np.ndarray:
        return np.array([self.sensor[m[l], z] for l, m in self.states])

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
