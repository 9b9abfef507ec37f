"""Peer-library formulations of onlinemap's model, for independent checks and benchmarks
(DESIGN.md section 6). pgmpy, hmmlearn and filterpy are optional (the ``peers`` extra, ``pip
install -e '.[peers]'``): they are imported only when a function here is called.

- :func:`unrolled_network`: the model as a pgmpy ``DiscreteBayesianNetwork`` unrolled over a
  run (variables ``L_t``, ``M{i}_t``, ``Z_t``); :func:`pgmpy_filter` queries it with
  ``VariableElimination`` for the filtering marginals at every step.
- :func:`hmmlearn_categorical_hmm`: an hmmlearn ``CategoricalHMM`` that re-estimates only the
  emission matrix (``params="e", init_params=""``), for Baum-Welch on single-action runs.
- :func:`filterpy_resamplers`: filterpy's four resamplers (``filterpy.monte_carlo``) under the
  names of :data:`onlinemap.resampling.RESAMPLERS`; they draw from numpy's global random state,
  which :func:`global_numpy_seed` seeds for one block and restores after.
"""

from __future__ import annotations

import contextlib
import importlib
from typing import Callable, NamedTuple

import numpy as np

from .errors import OnlineMapError
from .model import GridModel

PEERS_HINT = ("install the peer libraries with: pip install pgmpy==1.1.2 hmmlearn==0.3.3 filterpy==2.0.0 "
              "(in a clone: pip install -e '.[peers]')")


class PeerMissingError(OnlineMapError, ImportError):
    """A peer library (pgmpy, hmmlearn, filterpy) is needed but not installed."""


def require(module: str):
    """Import and return ``module``, or raise :class:`PeerMissingError` saying how to install it."""
    try:
        return importlib.import_module(module)
    except ImportError as error:
        raise PeerMissingError(f"{module.split('.')[0]} is not installed ({error}); {PEERS_HINT}") from None


def dense_motion(model: GridModel) -> np.ndarray:
    """(A, N, N) dense motion tables ``T[a, i, j]`` from the model's sparse form."""
    return np.stack([model.motion_matrix(a).toarray() for a in range(model.n_actions)])


def sensor_columns(model: GridModel) -> np.ndarray:
    """(K, N * K**N) table ``P(Z = z | L = l, m)`` with columns ordered (l, m_0, ..., m_{N-1}),
    l slowest: the column layout of a pgmpy ``TabularCPD`` with evidence ``[L, M0, ..., M{N-1}]``."""
    n, k = model.n_cells, model.n_labels
    labels = np.array(list(np.ndindex(*(k,) * n)), dtype=np.int64).reshape(k**n, n)  # (K^N, N)
    sensor = np.asarray(model.sensor)
    return np.concatenate([sensor[labels[:, l]] for l in range(n)]).T


def unrolled_network(model: GridModel, actions, n_steps: int, motion: np.ndarray | None = None):
    """The model unrolled over ``n_steps`` slices as a pgmpy ``DiscreteBayesianNetwork``.

    Variables ``L_t`` (N states), ``M{i}_t`` (K states) and ``Z_t`` (K states) for t < n_steps;
    ``Z_t`` has parents ``L_t`` and every ``M{i}_t`` (``P(z | l, m) = O[m_l, z]``), so each slice
    holds a CPD of N * K**N columns: for tiny worlds only. ``actions`` (>= n_steps - 1,) select
    the motion table of each step. ``motion`` (A, N, N) overrides the model's motion tables (a
    test passes tables rebuilt independently of the model's own).
    """
    pgmpy_factors = require("pgmpy.factors.discrete")
    pgmpy_models = require("pgmpy.models")
    n, k = model.n_cells, model.n_labels
    motion = dense_motion(model) if motion is None else np.asarray(motion)
    change_cpd = np.array(model.change).T
    sensor_cpd = sensor_columns(model)
    edges, cpds = [], []
    for t in range(n_steps):
        for i in range(n):
            if t == 0:
                cpds.append(pgmpy_factors.TabularCPD(f"M{i}_0", k, np.array(model.label_prior[i]).reshape(k, 1)))
            else:
                edges.append((f"M{i}_{t-1}", f"M{i}_{t}"))
                cpds.append(pgmpy_factors.TabularCPD(f"M{i}_{t}", k, change_cpd,
                                                     evidence=[f"M{i}_{t-1}"], evidence_card=[k]))
        if t == 0:
            cpds.append(pgmpy_factors.TabularCPD("L_0", n, np.eye(n)[model.start].reshape(n, 1)))
        else:
            edges.append((f"L_{t-1}", f"L_{t}"))
            cpds.append(pgmpy_factors.TabularCPD(f"L_{t}", n, motion[int(actions[t - 1])].T,
                                                 evidence=[f"L_{t-1}"], evidence_card=[n]))
        parents = [f"L_{t}"] + [f"M{i}_{t}" for i in range(n)]
        edges += [(p, f"Z_{t}") for p in parents]
        cpds.append(pgmpy_factors.TabularCPD(f"Z_{t}", k, sensor_cpd, evidence=parents,
                                             evidence_card=[n] + [k] * n))
    net = pgmpy_models.DiscreteBayesianNetwork(edges)
    net.add_cpds(*cpds)
    net.check_model()
    return net


class PeerFilter(NamedTuple):
    """Filtering marginals from pgmpy: location (T, N) and map (T, N, K), NaN where not queried."""

    location: np.ndarray
    map: np.ndarray


def pgmpy_filter(model: GridModel, actions, observations, map_steps=None,
                 motion: np.ndarray | None = None, location_steps=None) -> PeerFilter:
    """``P(L_t | z_0:t)`` for t in ``location_steps`` and ``P(m_i,t | z_0:t)`` for t in
    ``map_steps`` (each: None for every step, ``()`` for none, negative steps count from the
    end), by pgmpy variable elimination on the network unrolled over the whole run, queried
    with the evidence up to t (pgmpy prunes the later, unobserved slices).

    Cost: one network of T slices, each O(N K**N); one query per located step (N more where the
    map is queried), each over the first t + 1 slices, so O(T^2) slices eliminated in all.
    """
    inference = require("pgmpy.inference")
    n_steps = len(observations)
    n, k = model.n_cells, model.n_labels
    location = np.full((n_steps, n), np.nan)
    maps = np.full((n_steps, n, k), np.nan)
    map_steps = set(range(n_steps) if map_steps is None else (t % n_steps for t in map_steps))
    location_steps = set(range(n_steps) if location_steps is None else (t % n_steps for t in location_steps))
    engine = inference.VariableElimination(unrolled_network(model, actions, n_steps, motion))
    for t in range(n_steps):
        evidence = {f"Z_{s}": int(observations[s]) for s in range(t + 1)}
        if t in location_steps:
            location[t] = engine.query([f"L_{t}"], evidence=evidence, show_progress=False).values
        if t in map_steps:
            for i in range(n):
                maps[t, i] = engine.query([f"M{i}_{t}"], evidence=evidence, show_progress=False).values
    return PeerFilter(location, maps)


def hmmlearn_categorical_hmm(start: np.ndarray, transition: np.ndarray, emission: np.ndarray,
                             n_iter: int = 1, implementation: str = "scaling"):
    """An hmmlearn ``CategoricalHMM`` with start (N,), transition (N, N) and emission (N, K) set by
    hand, re-estimating the emission matrix only (``params="e", init_params=""``), for exactly
    ``n_iter`` Baum-Welch iterations (``tol = -inf``: no early stop); ``implementation`` is
    hmmlearn's ("scaling", its faster one, or "log")."""
    hmm = require("hmmlearn.hmm")
    n, k = np.shape(emission)
    peer = hmm.CategoricalHMM(n_components=n, n_features=k, params="e", init_params="",
                              n_iter=n_iter, tol=-np.inf, implementation=implementation)
    peer.startprob_ = np.asarray(start, dtype=np.float64)
    peer.transmat_ = np.asarray(transition, dtype=np.float64)
    peer.emissionprob_ = np.asarray(emission, dtype=np.float64)
    return peer


def filterpy_resamplers() -> dict[str, Callable[[np.ndarray], np.ndarray]]:
    """filterpy 2.0.0's resamplers, ``weights (P,) -> indices (P,)``, by the names of
    :data:`onlinemap.resampling.RESAMPLERS`. They take no generator: they draw from numpy's
    global random state (call them inside :func:`global_numpy_seed`), and ``residual_resample``
    is biased (it takes the residuals as ``w - floor(P w)`` instead of ``P w - floor(P w)``)."""
    monte_carlo = require("filterpy.monte_carlo")
    return {"residual": monte_carlo.residual_resample, "systematic": monte_carlo.systematic_resample,
            "stratified": monte_carlo.stratified_resample, "multinomial": monte_carlo.multinomial_resample}


@contextlib.contextmanager
def global_numpy_seed(seed: int):
    """Seed numpy's global random state (``np.random.seed``) for the block, and restore the state
    it had after it: for peers that draw from it (filterpy), never for onlinemap's own code."""
    saved = np.random.get_state()
    np.random.seed(seed)
    try:
        yield
    finally:
        np.random.set_state(saved)
