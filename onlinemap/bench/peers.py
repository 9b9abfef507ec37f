"""``onlinemap bench peers``: the same work done by onlinemap and by a peer library in one
process; ratio = onlinemap's time / the peer's time, and ``max_abs_diff`` beside it checks
that the answers agree.

- exact filtering vs pgmpy ``VariableElimination`` on the network unrolled over the run: the
  filtering location marginal at every step of a random-walk run on a binary corridor (pgmpy:
  the network built once, one query per step with the evidence so far; onlinemap: fresh
  estimators, one filter pass, which also yields the map marginals). Target: >= 100x faster
  on 8 cells (ratio <= 0.01).
  ``max_abs_diff`` covers the location at every step and the map marginals at the last step.
- Baum-Welch vs hmmlearn ``CategoricalHMM(params="e", init_params="")`` (hmmlearn's
  ``scaling`` implementation) on a single-action run: ms per iteration. Target: no slower
  (ratio <= 1). Both start from the same random B, no pseudo-count (hmmlearn's default
  Dirichlet prior of 1 adds nothing), 10 iterations per call; onlinemap's ``baum_welch`` also
  runs one more forward-backward after the last M-step (for the returned posteriors), which is
  counted against it. ``max_abs_diff`` compares the emission matrices after 10 iterations.
- each resampling scheme vs filterpy's (``filterpy.monte_carlo``): ms per call on P = 1000
  random weights (no target), and the mean copy shares of the weights [.5, .3, .15, .05] (P = 4,
  DESIGN.md section 6) over many draws: ``max_abs_diff`` between filterpy's and ours beside
  ``tolerance``, 5 standard deviations of that difference. The unbiased schemes agree within it;
  filterpy's residual resampling does not (its shares are near [.69, .31, 0, 0]: ``copy_shares``).

pgmpy, hmmlearn and filterpy come with the ``peers`` extra (``pip install -e '.[peers]'``); without them this
benchmark stops with :class:`onlinemap.peers.PeerMissingError`.
"""

from __future__ import annotations

import time
import warnings

import numpy as np

from ..estimators import make_estimator, run_estimator
from ..model import corridor
from ..peers import (dense_motion, filterpy_resamplers, global_numpy_seed, hmmlearn_categorical_hmm, pgmpy_filter,
                     require)
from ..resampling import RESAMPLERS
from ..simulate import random_walk, simulate
from . import benchmark, seconds_per_call


def _pgmpy_rows(quick: bool) -> list[dict]:
    rows = []
    cases = ((8, 0.0),) if quick else ((6, 0.0), (8, 0.0), (8, 0.01), (10, 0.0))
    n_steps = 6 if quick else 20
    pgmpy_filter(corridor(3), [0], [0, 0])  # first-call costs (imports, caches) out of the timings
    for n, p_change in cases:
        model = corridor(n, p_change=p_change)
        run = simulate(model, None, random_walk(model, n_steps - 1, seed=3), seed=4)
        mine = run_estimator(make_estimator("exact", model), run.actions, run.observations)  # compiles
        ms = 1e3 * seconds_per_call(
            lambda: run_estimator(make_estimator("exact", model), run.actions, run.observations),
            min_seconds=0.2)
        start = time.perf_counter()
        peer = pgmpy_filter(model, run.actions, run.observations, map_steps=())
        peer_ms = 1e3 * (time.perf_counter() - start)
        last_map = pgmpy_filter(model, run.actions, run.observations, map_steps=(-1,),  # untimed
                                location_steps=()).map[-1]
        diff = max(np.abs(mine.location - peer.location).max(), np.abs(mine.map[-1] - last_map).max())
        kind = "static" if p_change == 0 else "dynamic"
        rows.append({"case": f"filter corridor:{n} {kind}, {n_steps} steps", "ms": ms,
                     "reference": "pgmpy VariableElimination", "reference_ms": peer_ms,
                     "target": 0.01 if n == 8 else np.nan, "max_abs_diff": diff})
    return rows


def _baum_welch_rows(quick: bool) -> list[dict]:
    from ..estimators.offline_em import baum_welch

    rows = []
    n_iter = 10
    cases = ((8, 200), (32, 1000)) if quick else ((8, 200), (32, 1000), (128, 2000))
    for n, n_steps in cases:
        model = corridor(n)
        right = model.action_names.index("right")
        run = simulate(model, None, [right] * (n_steps - 1), seed=5)
        initial = np.random.default_rng(6).dirichlet(np.ones(model.n_labels), size=n)  # (N, K)
        peer = hmmlearn_categorical_hmm(model.location_prior(), dense_motion(model)[right], initial, n_iter)
        symbols = run.observations.reshape(-1, 1)

        def mine():
            return baum_welch(model, run.actions, run.observations, n_iter=n_iter, tol=0.0,
                              pseudo_count=0.0, initial=initial)

        def theirs():
            peer.emissionprob_ = initial.copy()
            return peer.fit(symbols)

        diff = np.abs(mine().observation_matrix - theirs().emissionprob_).max()  # also compiles
        ms = 1e3 * seconds_per_call(mine) / n_iter
        peer_ms = 1e3 * seconds_per_call(theirs) / n_iter
        rows.append({"case": f"Baum-Welch corridor:{n}, {n_steps} steps, ms/iteration", "ms": ms,
                     "reference": "hmmlearn CategoricalHMM", "reference_ms": peer_ms,
                     "target": 1.0, "max_abs_diff": diff})
    return rows


DESIGN_WEIGHTS = np.array([0.5, 0.3, 0.15, 0.05])  # DESIGN.md section 6: filterpy's residual bias shows on them


def _copy_shares(draw, n: int, draws: int) -> np.ndarray:
    """(n,) each particle's mean share of the copies over ``draws`` calls of ``draw()`` (n indices each)."""
    return np.bincount(np.concatenate([draw() for _ in range(draws)]), minlength=n) / (draws * n)


def _filterpy_rows(quick: bool) -> list[dict]:
    theirs = filterpy_resamplers()
    draws = 400 if quick else 1000
    w, p = DESIGN_WEIGHTS, len(DESIGN_WEIGHTS)
    # per draw, the copies of particle i vary by at most P w (1 - w) + 1/2 (multinomial, plus a
    # stratum-edge allowance, as tests/test_resampling.py derives); the shares of two independent
    # runs of ``draws`` draws then differ by at most 5 standard deviations of sqrt(2 that / draws) / P
    tolerance = float(np.max(5 * np.sqrt(2 * (p * w * (1 - w) + 0.5) / draws) / p))
    timed = np.random.default_rng(8).dirichlet(np.ones(1000))
    rows = []
    for scheme, ours in RESAMPLERS.items():
        peer = theirs[scheme]
        rng = np.random.default_rng(9)
        our_shares = _copy_shares(lambda: ours(w, rng), p, draws)  # also compiles
        ms = 1e3 * seconds_per_call(lambda: ours(timed, rng), min_seconds=0.02)
        with global_numpy_seed(9):  # filterpy draws from numpy's global state: seeded here only, then restored
            their_shares = _copy_shares(lambda: peer(w), p, draws)
            peer_ms = 1e3 * seconds_per_call(lambda: peer(timed), min_seconds=0.02)
        rows.append({"case": f"{scheme} resampling P=1000, ms/call; copy shares of [.5, .3, .15, .05], {draws} draws",
                     "ms": ms, "reference": "filterpy monte_carlo", "reference_ms": peer_ms, "target": np.nan,
                     "max_abs_diff": float(np.abs(their_shares - our_shares).max()), "tolerance": tolerance,
                     "copy_shares": f"filterpy {np.round(their_shares, 2).tolist()}, "
                                    f"ours {np.round(our_shares, 2).tolist()}"})
    return rows


@benchmark("peers")
def bench_peers(quick: bool) -> list[dict]:
    require("pgmpy")
    require("hmmlearn")
    require("filterpy")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FutureWarning)  # pgmpy's deprecation notices on import
        return _pgmpy_rows(quick) + _baum_welch_rows(quick) + _filterpy_rows(quick)
