"""Exact Bayes over the joint (location, map) (DESIGN.md section 3, ``exact``).

The belief is the full ``P(L_t, m_0..m_{N-1})``, an (N, K**N) tensor: one clique, the junction
tree of the two-slice network. Memory ``8 N K^N`` bytes per tensor (the filter keeps two; with
blocking labels or a footprint its numpy path peaks at about 8), so this is for tiny grids; a
guard (:func:`filter_bytes`, :func:`smooth_bytes`) refuses before allocating more than ``max_bytes``.

Filter step cost: static world, one fused read+write pass over the tensor (numba); dynamic
world, N + 2 passes (C applied along each map axis). Marginals cost about 4/N of a pass more.

Blocking labels or a sensor footprint (DESIGN.md section 7) take a separate numpy path (the fused
kernel of the paper's model is untouched): motion multiplies the move from ``l`` to its intended
``j`` by the passability of map axis ``j``, and the update multiplies, for each location ``l``,
the F footprint cells' axes by ``O[:, z_f]`` (zero where the off-grid readings do not fit ``l``).
Cost per step O((F + 3) N K^N) plus N passes for a dynamic world; an (N, K^N) int8 table of
labels (and, with blocking, a float table of passability) is cached per grid size.
"""

from __future__ import annotations

import math
from functools import lru_cache, reduce
from typing import NamedTuple

import numpy as np

from .. import arguments
from .. import state_checks as checks
from ..arrays import DEFAULT_MAX_BYTES, frozen, read_only
from ..belief import Belief
from ..errors import ImpossibleObservationError, InvalidOptionError, MemoryLimitError
from ..label_prior import LabelPrior, dirichlet_multinomial_prior, resolve_label_prior
from ..kernels.exact import change_every_axis, map_marginals as _map_marginals_kernel, motion_observe
from ..model import GridModel, apply_motion, apply_motion_transpose
from ..validation import check_sequence, check_step
from .base import register

_SMALLEST_NORMAL = np.finfo(np.float64).tiny  # below this a total has lost precision (subnormal)


# Peak memory in (N, K**N) float64 tensors, measured as peak RSS (tests/test_memory_guards.py)
GENERAL_FILTER_TENSORS = 9  # blocking labels or a footprint (numpy temporaries): measured 8.1
SMOOTH_EXTRA_TENSORS = 8  # smoothing keeps T tensors, plus temporaries: measured T + 7.0 ...
GENERAL_SMOOTH_EXTRA_TENSORS = 10  # ... and T + 9.3 with blocking labels or a footprint


def tensor_bytes(model: GridModel, copies: int = 1) -> int:
    """Bytes of ``copies`` float64 (N, K**N) tensors (exact Python ints: no overflow)."""
    return 8 * copies * model.n_cells * model.n_labels ** model.n_cells


def filter_bytes(model: GridModel) -> int:
    """Peak bytes of the exact filter: two tensors and the (K**N,) joint map for the paper's
    model; :data:`GENERAL_FILTER_TENSORS` tensors with blocking labels or a footprint."""
    if not model.is_paper_model:
        return tensor_bytes(model, GENERAL_FILTER_TENSORS)
    return tensor_bytes(model, 2) + 8 * model.n_labels ** model.n_cells


def smooth_bytes(model: GridModel, n_steps: int) -> int:
    """Peak bytes of :func:`exact_smooth` over ``n_steps`` steps: one tensor per step plus
    :data:`SMOOTH_EXTRA_TENSORS` (or :data:`GENERAL_SMOOTH_EXTRA_TENSORS`)."""
    extra = SMOOTH_EXTRA_TENSORS if model.is_paper_model else GENERAL_SMOOTH_EXTRA_TENSORS
    return tensor_bytes(model, n_steps + extra)


PLAUSIBLE_BYTES = 2 ** 40  # 1 TiB: beyond this, raising max_bytes is not advice anyone can follow


def largest_world(n_labels: int, copies: float, max_bytes: int | float) -> int:
    """The most cells N whose ``copies`` (N, K**N) float64 tensors fit in ``max_bytes`` (0 if none).
    O(N)."""
    n = 0
    while 8 * copies * (n + 1) * n_labels ** (n + 1) <= max_bytes:
        n += 1
    return n


def check_memory(model: GridModel, need: int, max_bytes: int | float, what: str) -> None:
    """Raise :class:`MemoryLimitError` if ``need`` bytes exceed ``max_bytes`` (a positive int or
    ``math.inf``, capped at the machine's memory: :func:`onlinemap.arguments.byte_limit`), or
    :class:`InvalidOptionError` if ``max_bytes`` is not a limit; allocate nothing. The message
    suggests raising ``max_bytes`` only when the tensors would fit in a large machine
    (:data:`PLAUSIBLE_BYTES`); otherwise it says how large a world exact Bayes can take."""
    limit = arguments.byte_limit("max_bytes", max_bytes, InvalidOptionError)
    if need > limit:
        copies = need / tensor_bytes(model)
        if need > PLAUSIBLE_BYTES:
            binary = f" ({largest_world(2, copies, limit)} with 2)" if model.n_labels != 2 else ""
            advice = (f"exact Bayes keeps all K^N maps, so it is for small worlds: at most "
                      f"{largest_world(model.n_labels, copies, limit)} cells with K={model.n_labels} "
                      f"labels{binary} fit in max_bytes")
        elif limit == max_bytes:
            advice = f"pass max_bytes={need} or more to raise it, if this machine has the memory"
        else:
            advice = f"this machine has {limit / 1e9:.3g} GB (max_bytes={max_bytes!r} cannot raise that)"
        raise MemoryLimitError(
            f"{what} for N={model.n_cells} cells and K={model.n_labels} labels needs "
            f"{need / 1e9:.3g} GB (about {copies:.3g} x N*K^N float64) but the limit is "
            f"{limit / 1e9:.3g} GB; {advice}, or use an approximate estimator (bk, rbpf)")


def prior_tensor(model: GridModel, label_prior: LabelPrior | None = None) -> np.ndarray:
    """(N, K**N) joint prior: one-hot start cell times the map prior: the product of the cells'
    label priors (the model's, or the fixed frequencies of ``label_prior``), or, for
    ``label_prior.kind == "learn"``, the Dirichlet-multinomial over maps
    (:func:`onlinemap.label_prior.dirichlet_multinomial_prior`: the exact hierarchical prior)."""
    if label_prior is not None and label_prior.kind == "learn":
        joint = dirichlet_multinomial_prior(model.n_cells, label_prior.alpha)
    elif label_prior is not None and label_prior.kind == "fixed":
        joint = reduce(np.multiply.outer, [label_prior.frequencies] * model.n_cells).ravel()
    else:
        joint = reduce(np.multiply.outer, model.label_prior).ravel()
    x = np.zeros((model.n_cells, joint.size))
    x[model.start] = joint
    return x


def map_marginals(joint_map: np.ndarray, n_cells: int, n_labels: int) -> np.ndarray:
    """(N, K) marginals of a (K**N,) joint over maps (numba; about 2 K/(K-1) reads of it).
    Overwrites ``joint_map`` if it is a C-contiguous float64 array (it is used as scratch)."""
    out = np.empty((n_cells, n_labels))
    _map_marginals_kernel(np.ascontiguousarray(joint_map), n_cells, n_labels, out)
    return out


@register("exact")
class ExactFilter:
    """Exact filtering of ``P(L_t, M_t | z_0:t, a_1:t)``. Options: ``max_bytes`` (memory guard);
    ``label_prior`` and ``prior_strength`` (:mod:`onlinemap.label_prior`): None is what the model
    says (``"learn"`` when its label frequencies are unknown, in any world: the hierarchical prior
    is exact before the map dynamics act; its prior table otherwise); ``"model"`` the table; a (K,) vector gives every cell those frequencies; ``"learn"`` puts the frequencies
    under a Dirichlet (total pseudo-count ``prior_strength``, default K) and filters the exact
    posterior of that hierarchical model (its map prior the Dirichlet-multinomial): the reference
    for the approximate filters that learn the label prior."""

    scratch_attributes = ("_scratch", "_joint_map")  # overwritten by every step: not checkpointed
    #: attributes fixed by the model and options, checked equal on load (:mod:`onlinemap.state_checks`)
    CONSTANT_STATE = ("max_bytes", "_no_motion", "_flat")

    def __init__(self, model: GridModel, *, max_bytes: int = DEFAULT_MAX_BYTES, label_prior=None,
                 prior_strength=None):
        max_bytes = arguments.requested_bytes("max_bytes", max_bytes, InvalidOptionError)
        prior = resolve_label_prior(model.n_labels, label_prior, prior_strength,
                                    model_learns=model.unknown_label_frequencies)
        check_memory(model, filter_bytes(model), max_bytes, "the exact filter")
        self.model = model
        self.max_bytes = max_bytes
        n, k = model.n_cells, model.n_labels
        self._x = prior_tensor(model, prior)  # current belief, unnormalised by the factor 1/_norm
        self._scratch = np.empty_like(self._x)
        self._joint_map = np.empty(k**n)
        self._norm = 1.0
        self._log_evidence = 0.0
        self._t = -1
        self._belief: Belief | None = None
        self._no_motion = (np.ones(n), np.full(n, -1, dtype=np.int64))
        self._flat = np.ones(k)  # the likelihood of "no observation" (dynamic steps)

    @staticmethod
    def check_state(state) -> None:
        """The invariants of a restored state (:mod:`onlinemap.state_checks`): the joint ``_x``
        (N, K**N) finite, non-negative, summing to ``_norm``; the belief of step ``_t``."""
        model = state.model
        n, k = model.n_cells, model.n_labels
        checks.step_index(state)
        x = checks.array(state, "_x", (n, k**n), np.float64, written=True)
        norm = checks.real(state, "_norm", low=np.finfo(float).tiny)
        if not np.all(np.isfinite(x)) or np.any(x < 0):
            checks.fail("_x", "must be finite and non-negative")
        if abs(x.sum() / norm - 1) > checks.ATOL:
            checks.fail("_x", f"sums to {x.sum()!r}, not to _norm = {norm!r}")
        checks.log_evidence(state)
        checks.belief(state, required=True)

    def step(self, action, observation) -> Belief:
        a, z = check_step(self.model, self._t + 1, action, observation)
        if not self.model.is_paper_model:
            return self._general_step(a, z)
        model = self.model
        likelihood = model.likelihood[z]
        location = np.empty(model.n_cells)
        out = self._scratch
        total = self._predict_observe(a, likelihood, 0, out, location)
        log_scale = 0.0
        if not _SMALLEST_NORMAL <= total < math.inf:  # underflow: the rare branch
            total, log_scale = self._rescaled(a, likelihood, out, location)
        if not total > 0 or not np.isfinite(total):
            raise ImpossibleObservationError(
                f"observation {model.label_names[z]!r} has probability zero under the exact belief at step "
                f"{self._t + 1} (or below float64's range even after rescaling)")
        self._x, self._scratch = out, self._x
        self._norm = total
        self._log_evidence += math.log(total) + log_scale
        self._t += 1
        maps = np.minimum(map_marginals(self._joint_map, model.n_cells, model.n_labels) / total, 1.0)  # rounding
        self._belief = Belief(self._t, location / total, maps, self._log_evidence)
        return self._belief

    def _predict_observe(self, a, likelihood: np.ndarray, exponent: int, out: np.ndarray,
                         location: np.ndarray) -> float:
        """``out`` <- the belief moved by ``a`` (None: no motion), its map changed by C, weighted by
        ``likelihood`` and scaled by ``2**exponent / _norm``; fills ``location`` and the joint map.
        Returns the total. One fused pass (static), N + 2 passes (dynamic)."""
        model, inv = self.model, 1.0 / self._norm
        likelihood = frozen(likelihood)  # the kernels' constant inputs in one form: one compilation
        no_motion = tuple(map(frozen, self._no_motion))
        if a is None:
            motion_observe(self._x, out, *no_motion, 0.0, math.ldexp(inv, exponent), likelihood,
                           self._joint_map, location)
        elif model.is_static:
            motion_observe(self._x, out, frozen(model.self_prob[a]), frozen(model.predecessor[a]), model.p_move,
                           math.ldexp(inv, exponent), likelihood, self._joint_map, location)
        else:
            motion_observe(self._x, out, frozen(model.self_prob[a]), frozen(model.predecessor[a]), model.p_move,
                           inv, frozen(self._flat), self._joint_map, location)
            change_every_axis(out, frozen(model.change))
            motion_observe(out, out, *no_motion, 0.0, math.ldexp(1.0, exponent), likelihood, self._joint_map,
                           location)
        return location.sum()

    def _rescaled(self, a, likelihood: np.ndarray, out: np.ndarray, location: np.ndarray) -> tuple[float, float]:
        """The step redone when its total is not a normal float (an observation of probability near
        or below 1e-308): the likelihood divided by its maximum, then, if the total is still
        subnormal, the belief scaled by a power of two that brings it near 1. Returns
        ``(total, log of the factor taken out)``; total 0 when even that underflows or when that
        power of two (with the ``1 / _norm`` it multiplies) is beyond float64's range. Costs one
        or two more passes, only on this branch."""
        top = float(likelihood.max())
        if not top > 0:
            return 0.0, 0.0
        likelihood = likelihood / top
        total = self._predict_observe(a, likelihood, 0, out, location)
        exponent = -math.frexp(total)[1] if 0 < total < _SMALLEST_NORMAL else 0
        if exponent:
            try:
                total = self._predict_observe(a, likelihood, exponent, out, location)
            except OverflowError:  # 2**exponent / _norm beyond float64 (math.ldexp raises, never gives inf)
                return 0.0, 0.0
        return total, math.log(top) - exponent * math.log(2.0)

    def _general_step(self, a: int | None, z) -> Belief:
        """The step with blocking labels or a footprint (numpy, fresh arrays). O((F + 3) N K^N)."""
        model = self.model
        x = self._x / self._norm
        if a is not None:
            x = blocking_motion(model, x, a)
            if not model.is_static:
                change_every_axis(x, frozen(model.change))
        x *= footprint_likelihood(model, z)
        location = x.sum(axis=1)
        total = location.sum()
        if not total > 0 or not np.isfinite(total):
            raise ImpossibleObservationError(
                f"observation {np.asarray(z).tolist()!r} has probability zero under the exact belief at step "
                f"{self._t + 1}")
        self._x = x
        self._norm = total
        self._log_evidence += math.log(total)
        self._t += 1
        maps = np.minimum(map_marginals(x.sum(axis=0), model.n_cells, model.n_labels) / total, 1.0)  # rounding
        self._belief = Belief(self._t, location / total, maps, self._log_evidence)
        return self._belief

    def joint(self) -> np.ndarray:
        """A normalised copy of the joint belief, shape (N, K, ..., K) (N + 1 axes)."""
        shape = (self.model.n_cells,) + (self.model.n_labels,) * self.model.n_cells
        return (self._x / self._norm).reshape(shape)

    def sample_states(self, size: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """``size`` states drawn from the joint belief (one ``rng.choice`` over its N K^N entries):
        locations (S,) and label maps (S, N), int64. O(N K^N + S N)."""
        n, k = self.model.n_cells, self.model.n_labels
        joint = self.joint().ravel()
        flat = rng.choice(joint.size, size=size, p=joint / joint.sum())
        index = np.stack(np.unravel_index(flat, (n,) + (k,) * n), axis=1)
        return index[:, 0].astype(np.int64), index[:, 1:].astype(np.int64)


# --- blocking and footprints (numpy; DESIGN.md section 7) ---------------------------------
@lru_cache(maxsize=4)
def map_labels(n_cells: int, n_labels: int) -> np.ndarray:
    """(N, K**N) int8, read-only and cached: label of cell i in the map of flat index m (cell 0
    the leading axis)."""
    index = np.arange(n_labels**n_cells)
    powers = n_labels ** np.arange(n_cells - 1, -1, -1)
    return read_only(((index[None, :] // powers[:, None]) % n_labels).astype(np.int8))


def passable_tensor(model: GridModel) -> np.ndarray:
    """(N, K**N) float, read-only and cached per (N, K, blocking labels): 1 where cell j's label
    in map m does not block, else 0. O(N K^N) the first time."""
    return _passable(model.n_cells, model.n_labels, model.blocking.tobytes())


@lru_cache(maxsize=4)
def _passable(n_cells: int, n_labels: int, blocking: bytes) -> np.ndarray:
    mask = np.frombuffer(blocking, dtype=bool)
    return read_only((~mask[map_labels(n_cells, n_labels)]).astype(np.float64))


def blocking_motion(model: GridModel, x: np.ndarray, action: int, transpose: bool = False,
                    passable: np.ndarray | None = None) -> np.ndarray:
    """Map-dependent motion along axis 0 of x (N, K**N): from ``l`` the intended ``j`` is reached
    with ``p_move [m_j passable]``, else stay. ``transpose`` for the backward pass
    (``out[l] = sum_j T(l -> j | m) x[j]``). Fresh array; O(N K^N)."""
    n = model.n_cells
    if passable is None:
        passable = passable_tensor(model) if model.has_blocking else np.ones((n, 1))
    target = model.neighbors[:, action]
    movers = np.flatnonzero(target != np.arange(n))
    go = np.zeros((n, passable.shape[1]))
    go[movers] = model.p_move * passable[target[movers]]  # (N, M) P(move | l, m)
    out = (1.0 - go) * x
    if transpose:
        out[movers] += go[movers] * x[target[movers]]
    else:
        out[target[movers]] += go[movers] * x[movers]
    return out


def footprint_likelihood(model: GridModel, z) -> np.ndarray:
    """(N, K**N) ``P(z | L = l, m)``: the product over offsets f of ``O[m_{c_f(l)}, z_f]`` for
    on-grid cells, 0 where the observation's -1 readings are not exactly l's off-grid offsets.
    z: an int (F = 1) or (F,) readings. O(F N K^N)."""
    n, k = model.n_cells, model.n_labels
    readings = np.atleast_1d(np.asarray(z, dtype=np.int64))
    labels = map_labels(n, k)
    cells = model.footprint_cells
    out = np.ones((n, k**n))
    fits = ((cells < 0) == (readings < 0)[None]).all(axis=1)
    out[~fits] = 0.0
    for f, reading in enumerate(readings):
        if reading < 0:
            continue
        on = np.flatnonzero(fits & (cells[:, f] >= 0))
        out[on] *= model.sensor[labels[cells[on, f]], reading]
    return out


# --- smoothing (numpy; tiny grids, offline) ---------------------------------------------
def observe_tensor(model: GridModel, x: np.ndarray, z: int) -> np.ndarray:
    """(N, K**N) -> same: slice ``l`` multiplied by ``O[m_l, z]`` along map axis ``l``."""
    n, k = model.n_cells, model.n_labels
    out = np.empty_like(x)
    likelihood = model.likelihood[z]
    for l in range(n):
        view = x[l].reshape(k**l, k, -1)
        out[l] = (view * likelihood[None, :, None]).ravel()
    return out


def change_tensor(model: GridModel, x: np.ndarray, transpose: bool = False) -> np.ndarray:
    """Apply ``C`` (or, for the backward pass, ``C`` from the other side) along every map axis."""
    n, k = model.n_cells, model.n_labels
    matrix = model.change.T if transpose else model.change
    y = x.reshape((n,) + (k,) * n)
    for axis in range(1, n + 1):
        y = np.moveaxis(np.tensordot(y, matrix, axes=([axis], [0])), -1, axis)
    return np.ascontiguousarray(y).reshape(x.shape)


class SmoothResult(NamedTuple):
    """Exact smoothed marginals over a run of T steps."""

    location: np.ndarray  # (T, N) P(L_t | z_0:T-1)
    map: np.ndarray  # (T, N, K) P(m_{i,t} | z_0:T-1)
    log_evidence: float  # log P(z_0:T-1 | a)


def exact_smooth(model: GridModel, actions, observations, *, max_bytes: int = DEFAULT_MAX_BYTES) -> SmoothResult:
    """Forward filter and backward pass over a recorded run.

    ``actions`` (T - 1,) (or (T,) with a leading None), ``observations`` (T,) (or (T, F) with a
    footprint), by index or name. Memory: about T + 8 tensors of (N, K**N) float64
    (:func:`smooth_bytes`); time
    O(T N K^N (N K + F)).
    """
    a_seq, z_seq = check_sequence(model, actions, observations)
    n_steps = len(z_seq)
    check_memory(model, smooth_bytes(model, n_steps), max_bytes, f"exact smoothing over {n_steps} steps")
    n, k = model.n_cells, model.n_labels
    alphas = np.empty((n_steps, n, k**n))
    log_evidence = 0.0
    scales = np.empty(n_steps)
    general = not model.is_paper_model
    passable = passable_tensor(model) if model.has_blocking else None

    def move(x, a, transpose=False):
        if general:
            return blocking_motion(model, x, a, transpose, passable)
        return (apply_motion_transpose if transpose else apply_motion)(model, x, a)

    def observe(x, z):
        return x * footprint_likelihood(model, z) if general else observe_tensor(model, x, z)

    x = prior_tensor(model)
    for t in range(n_steps):
        if t > 0:
            x = move(x, a_seq[t - 1])
            x = change_tensor(model, x)
        x = observe(x, z_seq[t])
        total = x.sum()
        if not total > 0:
            raise ImpossibleObservationError(f"observation at step {t} has probability zero under the model")
        scales[t] = total
        log_evidence += math.log(total)
        x = x / total
        alphas[t] = x
    location = np.empty((n_steps, n))
    maps = np.empty((n_steps, n, k))
    beta = np.ones((n, k**n))
    for t in range(n_steps - 1, -1, -1):
        post = alphas[t] * beta
        post /= post.sum()
        location[t] = np.minimum(post.sum(axis=1), 1.0)  # rounding
        maps[t] = np.minimum(map_marginals(post.sum(axis=0), n, k), 1.0)
        if t > 0:
            beta = observe(beta, z_seq[t])
            beta = change_tensor(model, beta, transpose=True)
            beta = move(beta, a_seq[t - 1], transpose=True) / scales[t]
    return SmoothResult(location, maps, log_evidence)
