"""What maps look like: the label prior of cells the robot has not read (DESIGN.md section 9).

The model's prior makes the cells independent with fixed frequencies (uniform by default). A
building is not a draw from that prior (about 56% free, 39% wall, 5% doors), and a uniform prior
says that half of every unseen cell blocks. The hierarchical model this module serves puts the
frequencies theta themselves under a Dirichlet,

    theta ~ Dirichlet(alpha),    m_i | theta ~ Categorical(theta) i.i.d.,

so that, integrated over theta, the map prior is the Dirichlet-multinomial

    P(m) = Gamma(A) / Gamma(A + N) prod_k Gamma(alpha_k + n_k(m)) / Gamma(alpha_k),

with ``A = sum_k alpha_k`` and ``n_k(m)`` the cells of label k: cells are exchangeable, no longer
independent, and what the robot reads of some cells tells it about the others. The predictive of
a cell given the labels of n others is ``(alpha + counts) / (A + n)``. Estimators take the
option ``label_prior``:

- ``None`` (the default): what the model says. A model whose label frequencies are unknown
  (``model.unknown_label_frequencies``: generated buildings and floors read from files) means
  ``"learn"``; any other model (the paper's worlds) its own prior table, every result as
  without the option. The approximate filters (RBPF, BK) learn by default only where they can
  learn at all: in a static world (C = I); elsewhere
  ``None`` is the model's table (:func:`plug_in_prior`; an explicit ``"learn"`` is refused there);
- ``"model"``: the model's own prior table, whatever the model says of its frequencies (the
  uniform baseline on a building);
- a (K,) frequency vector: that fixed prior for every cell;
- ``"learn"``: the hierarchical prior above with ``alpha = prior_strength / K`` per label
  (``prior_strength`` defaults to K: Laplace's uniform Dirichlet). The exact filter computes its
  posterior exactly (the Dirichlet-multinomial joint); approximate filters plug in the posterior
  mean of theta given the expected label counts of the cells they have read (empirical Bayes),
  every ``learn_every`` steps (default :data:`DEFAULT_LEARN_EVERY`).
- ``"context"`` (the RBPF only, static grid worlds): every cell gets its own tilt, the
  predictive of its label given the labels of its 4 grid neighbours as they were read before it
  (walls come in lines, doors sit in walls), learned online from the cells read and backed off to
  the learned frequencies above (the same ``alpha``, ``prior_strength``, ``learn_every``). The
  neighbour *states* are 0 (off the grid), 1 (not read) or ``2 + argmax m_j`` (a read neighbour
  j, m the filter's mixture map); a cell's *context* is the base-(K + 2) number of its north,
  south, west and east states, :func:`context_codes`, frozen at the cell's first read. With
  ``n[c, k]`` the summed marginals of the read cells of context c and ``pi`` the learned
  frequencies, a cell of context c has the prior tilt

      v_i = (n[c_i, :] + S pi) / (sum_k n[c_i, k] + S),    S = K,

  (:func:`learn_context`): a Dirichlet-multinomial predictive per context with mean pi and
  total pseudo-count K, so a context seen n times weighs its counts n / (n + K). A population
  plug-in (empirical Bayes): the contexts come from the particles' mixture, not each particle's
  own map.
- ``"particle_context"`` (the RBPF only, static grid worlds): the same table learned the same
  way (from the cells most of the particles' weight has read, :func:`learn_context_ratios`),
  applied per particle: before a step, each particle tilts the prior of every cell the step may
  read that it has neither read nor tilted, by the ratio ``v'[c] / pi`` of the cell's context c
  *in that particle's own map* (its neighbours read by that particle's path, their labels that
  particle's most probable), frozen then. The table is tempered, ``v'[c] = w v[c] + (1 - w) pi``
  with ``w = context_weight`` (default :data:`DEFAULT_CONTEXT_WEIGHT`): a particle whose map is
  wrong reads its own errors back as context, and the untempered table lost more runs (measured:
  the user guide's Results page).

A robot new to a floor has read little, so early on its context counts are nearly empty and every
cell's prior is close to pi. The RBPF's option ``context_table`` (with either context prior) adds
pseudo-counts ``T[c, k]`` learned beforehand from known maps (:func:`context_table`, a
:class:`ContextTable`) to the learned counts wherever a context's predictive is formed:

    v_i = (n[c_i] + T[c_i] + S pi) / (sum_k (n[c_i, k] + T[c_i, k]) + S),

(``"particle_context"``: ``backed_off(n + T, pi)`` before the tempering). The table applies from
the first learning step, which runs right after step 0 (t = 0 is a multiple of ``learn_every``);
at step 0 itself every particle stands at the start and reads the same cells, so the prior of
that step changes no weight. Measured (``examples/slip_bias.py``, exact posteriors): in an
unmapped corridor after 8 presses, ``"context"`` leans 1.9 cells towards "the robot stayed";
with a table from generated buildings 20-29 (strength 100), 0.6 cells.

The hindsight fits of a recorded run (:func:`onlinemap.hindsight.told_location`,
:func:`onlinemap.layered_em.fit_layered_map`) take the same option but read None as the model's
table on every model: their learning is asked for explicitly.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from scipy.special import gammaln

from . import arguments
from .errors import InvalidOptionError

CONTEXT = "context"
PARTICLE_CONTEXT = "particle_context"
#: the priors that tilt each cell by its neighbours' labels (the RBPF's only)
CONTEXT_KINDS = (CONTEXT, PARTICLE_CONTEXT)
#: ``"particle_context"``'s default weight of the context table against the frequencies it backs off to
DEFAULT_CONTEXT_WEIGHT = 0.5
LEARN = "learn"
MAX_PRIOR_ITERATIONS = 1000  # fixed_point_frequencies: a contraction, settled long before
MODEL = "model"
#: how often (steps) the approximate filters re-estimate the frequencies by default: the RBPF at 32 x 32
#: with 1000 particles takes 17.9 ms a step without learning, 54.9 learning every step and 20.6 every 10
#: steps, with map and location errors equal within noise
DEFAULT_LEARN_EVERY = 10
#: a cell whose marginal differs from an unread cell's by more than this (max over labels) counts as
#: read: far above the rounding of repeated retilts (~1e-15 a step), far below any reading's effect
READ_TOLERANCE = 1e-9
#: the grid neighbours a ``"context"`` prior conditions on, in the order of its code's digits
CONTEXT_DIRECTIONS = ("north", "south", "west", "east")
#: the neighbour state of an off-grid neighbour, and of one not read yet (a read one: 2 + its label)
OFF_GRID, NOT_READ = 0, 1


class LabelPrior(NamedTuple):
    """A resolved ``label_prior`` option: ``kind`` is ``"model"`` (the model's own prior),
    ``"fixed"`` (``frequencies`` (K,) for every cell), ``"learn"`` (a Dirichlet with
    concentrations ``alpha`` (K,) over the label frequencies), ``"context"`` or
    ``"particle_context"`` (the same ``alpha`` for the frequencies the neighbour contexts back
    off to)."""

    kind: str
    frequencies: np.ndarray | None
    alpha: np.ndarray | None


def resolve_label_prior(n_labels: int, label_prior, prior_strength=None, *, model_learns: bool = False,
                        context: bool = False) -> LabelPrior:
    """Check and resolve the ``label_prior`` / ``prior_strength`` options of an estimator for K =
    ``n_labels`` labels; ``model_learns``: None means ``"learn"`` (the model's label frequencies
    are unknown and the estimator can learn them); ``context``: the estimator takes
    ``"context"`` and ``"particle_context"`` (the RBPF). Raises
    :class:`~onlinemap.errors.InvalidOptionError` naming the problem: an unknown string, a context
    prior where it is not taken, a vector of the wrong length or not a probability vector (entries
    in [0, 1] summing to 1), a ``prior_strength`` that is not a positive finite number or given
    where nothing is learned. O(K)."""
    named = label_prior if isinstance(label_prior, str) else None
    if named in CONTEXT_KINDS and not context:
        raise InvalidOptionError(f"label_prior={named!r} is the RBPF's only (its neighbour-context tilt of the "
                                 "block pool); this estimator or fit takes None, 'model', 'learn' or a vector")
    learns = named in (LEARN, *CONTEXT_KINDS) or (label_prior is None and model_learns)
    if prior_strength is not None and not learns:
        raise InvalidOptionError("prior_strength is the Dirichlet's total pseudo-count of label_prior='learn'; "
                                 f"it means nothing with label_prior={label_prior!r}"
                                 + (" on a model whose label frequencies are known" if label_prior is None else ""))
    if (label_prior is None and not learns) or named == MODEL:
        return LabelPrior("model", None, None)
    if learns:
        strength = float(n_labels) if prior_strength is None else prior_strength
        if isinstance(strength, bool) or not isinstance(strength, (int, float, np.integer, np.floating)) \
                or not 0 < float(strength) < math.inf:
            raise InvalidOptionError(f"prior_strength must be a positive finite number, got {prior_strength!r}")
        return LabelPrior(named if named in CONTEXT_KINDS else LEARN, None,
                          np.full(n_labels, float(strength) / n_labels))
    if named is not None:
        learned = "'learn', 'context', 'particle_context'" if context else "'learn'"
        raise InvalidOptionError(f"label_prior must be None (what the model says), 'model' (the model's prior "
                                 f"table), {learned} or a vector of {n_labels} label frequencies, got {label_prior!r}")
    try:
        freq = np.array(label_prior, dtype=np.float64)
    except (TypeError, ValueError):
        raise InvalidOptionError(f"label_prior must be None, 'model', 'learn' or a vector of {n_labels} label "
                                 f"frequencies, got {label_prior!r}") from None
    if freq.shape != (n_labels,):
        raise InvalidOptionError(f"label_prior must have one frequency per label ({n_labels}), got shape "
                                 f"{freq.shape}")
    if not np.all(np.isfinite(freq)) or np.any(freq < 0) or np.any(freq > 1) or abs(freq.sum() - 1) > 1e-9:
        raise InvalidOptionError(f"label_prior must be label frequencies in [0, 1] summing to 1, got "
                                 f"{freq.tolist()}")
    freq.setflags(write=False)
    return LabelPrior("fixed", freq, None)


def map_counts(n_cells: int, n_labels: int) -> np.ndarray:
    """(K**N, K) the number of cells of each label in every map, maps in the exact filter's order
    (row-major over the cells: cell 0 the slowest digit). O(K**N N)."""
    maps = np.arange(n_labels ** n_cells)
    counts = np.zeros((maps.size, n_labels), dtype=np.int64)
    for _ in range(n_cells):
        maps, digit = np.divmod(maps, n_labels)
        counts[np.arange(counts.shape[0]), digit] += 1
    return counts


def dirichlet_multinomial_prior(n_cells: int, alpha: np.ndarray) -> np.ndarray:
    """(K**N,) the joint prior of every map under the Dirichlet-multinomial with concentrations
    ``alpha`` (K,), maps in the exact filter's order (:func:`map_counts`). Sums to 1.
    O(K**N (N + K)) time, 8 K**N (K + 1) bytes."""
    alpha = np.asarray(alpha, dtype=np.float64)
    counts = map_counts(n_cells, len(alpha))
    total = alpha.sum()
    log_p = (gammaln(total) - gammaln(total + n_cells)
             + (gammaln(alpha + counts) - gammaln(alpha)).sum(axis=1))
    return np.exp(log_p)


def posterior_frequencies(alpha: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """(K,) the posterior mean of the label frequencies, ``(alpha + counts) / (A + sum counts)``,
    given the (expected) label counts (K,) of the cells read. O(K)."""
    post = np.asarray(alpha, dtype=np.float64) + np.asarray(counts, dtype=np.float64)
    return post / post.sum()


def fixed_point_frequencies(alpha: np.ndarray, log_evidence: np.ndarray, seen: np.ndarray,
                            start: np.ndarray | None = None) -> np.ndarray:
    """(K,) the label frequencies of a robot that knows where every reading was taken (the
    told-location map, a path's map): the fixed point of ``theta = posterior_frequencies(alpha,
    sum_i seen_i normalise(log theta + log_evidence_i))``, with ``log_evidence`` (N, K) each cell's
    summed log-likelihoods and ``seen`` (N,) 1 for the cells read; iterated from ``start``
    (default the Dirichlet mean) until it moves less than 1e-12 (a contraction: a warm start from
    the last step's settles in a few iterations). O(iterations N K)."""
    theta = alpha / alpha.sum() if start is None else start
    for _ in range(MAX_PRIOR_ITERATIONS):
        log_belief = np.log(theta) + log_evidence
        belief = np.exp(log_belief - log_belief.max(axis=1, keepdims=True))
        belief /= belief.sum(axis=1, keepdims=True)
        updated = posterior_frequencies(alpha, seen @ belief)
        if np.abs(updated - theta).max() < 1e-12:
            return updated
        theta = updated
    return theta


def plug_in_prior(model, label_prior, prior_strength=None, learn_every=None, *, context: bool = False) -> LabelPrior:
    """Check and resolve the label-prior options of an approximate (plug-in) filter for
    ``model`` (a :class:`~onlinemap.model.GridModel`): :func:`resolve_label_prior` (``context``:
    the filter takes ``"context"``, which also needs a grid, :func:`neighbour_table`), and
    ``learn_every`` (a positive integer, given only where the filter learns). The model's
    default learning (``label_prior=None`` with ``model.unknown_label_frequencies``) applies
    where the filter can learn: a static world (C = I); elsewhere None is the model's table. Raises
    :class:`~onlinemap.errors.InvalidOptionError`: an explicit ``"learn"`` in a dynamic world
    (a cell's marginal then mixes readings of different ages, which one rescaling of the prior
    does not move consistently; ``"context"`` likewise), a fixed vector giving probability zero to
    every label a cell's model prior allows, a bad ``learn_every``. O(N K)."""
    prior = resolve_label_prior(model.n_labels, label_prior, prior_strength,
                                model_learns=model.learns_label_frequencies, context=context)
    if prior.kind == "fixed" and np.any((model.label_prior * prior.frequencies).sum(axis=1) == 0):
        raise InvalidOptionError(f"label_prior {prior.frequencies.tolist()} gives probability zero to every label "
                                 "some cell's model prior allows")
    if learn_every is not None:
        if prior.kind not in (LEARN, *CONTEXT_KINDS):
            raise InvalidOptionError(f"learn_every is how often label_prior='learn' updates its frequencies; it "
                                     f"means nothing with label_prior={label_prior!r}")
        if isinstance(learn_every, (bool, np.bool_)) or not isinstance(learn_every, (int, np.integer)) \
                or learn_every < 1:
            raise InvalidOptionError(f"learn_every must be a whole number of steps >= 1, got {learn_every!r}")
    if prior.kind in (LEARN, *CONTEXT_KINDS) and not model.is_static:
        raise InvalidOptionError(f"label_prior={prior.kind!r} needs a static world (the change matrix C = I): in a "
                                 "dynamic world a cell's marginal mixes readings of different ages, which one "
                                 "rescaling of the prior does not move consistently")
    if prior.kind in CONTEXT_KINDS:
        neighbour_table(model)  # refuses a model that is not a grid
    return prior


def unread_marginals(prior: np.ndarray, frequencies: np.ndarray) -> np.ndarray:
    """(N, K) the marginal of a cell no reading touched, ``normalise(prior_i * frequencies)``,
    from the model's prior table (N, K) and the frequencies (K,) it is tilted by (or every cell's
    own tilt (N, K): ``"context"``). O(N K)."""
    tilted = prior * frequencies
    return tilted / tilted.sum(axis=1, keepdims=True)


def tilt(rows: np.ndarray, ratio: np.ndarray) -> np.ndarray:
    """``normalise(rows * ratio)`` along the last axis: marginals (..., K) whose prior frequencies
    are changed by ``ratio`` (K,), the readings' likelihoods kept. A fresh array. O(rows.size)."""
    tilted = rows * ratio
    tilted /= tilted.sum(axis=-1, keepdims=True)
    return tilted


def learned_frequencies(marginals: np.ndarray, prior: np.ndarray, frequencies: np.ndarray,
                        alpha: np.ndarray) -> np.ndarray:
    """(K,) one empirical-Bayes step: the posterior mean of theta ``(alpha + c) / (A + n)``, with
    ``c`` the expected label counts, the sum of the map ``marginals`` (N, K) over the n cells read
    (those differing from :func:`unread_marginals` of ``prior`` (N, K) at the current
    ``frequencies`` (K,) by more than :data:`READ_TOLERANCE`). O(N K)."""
    read = np.abs(marginals - unread_marginals(prior, frequencies)).max(axis=1) > READ_TOLERANCE
    return posterior_frequencies(alpha, marginals[read].sum(axis=0))


class ContextState(NamedTuple):
    """``label_prior="context"``'s state (:func:`learn_context`): ``tilts`` (N, K) every cell's
    prior tilt v_i (rows summing to 1), ``read`` (N,) bool the cells read so far, ``frozen`` (N,)
    int64 each read cell's context code at its first read (-1 for the unread), ``frequencies`` (K,)
    the learned frequencies pi the contexts back off to."""

    tilts: np.ndarray
    read: np.ndarray
    frozen: np.ndarray
    frequencies: np.ndarray


def fresh_context(n_cells: int, frequencies: np.ndarray) -> ContextState:
    """The :class:`ContextState` of a filter that has read nothing: every cell's tilt the
    ``frequencies`` (K,), no cell read, no context frozen. O(N K)."""
    return ContextState(np.tile(frequencies, (n_cells, 1)), np.zeros(n_cells, dtype=bool),
                        np.full(n_cells, -1, dtype=np.int64), frequencies)


def neighbour_table(model) -> np.ndarray:
    """(N, 4) int64 each cell's north, south, west and east neighbour (:data:`CONTEXT_DIRECTIONS`)
    in ``model`` (a :class:`~onlinemap.model.GridModel`), -1 off the grid: the grid's moves
    ``model.neighbors[:, a]``, a move that stays (``== i``) meaning no neighbour. Raises
    :class:`~onlinemap.errors.InvalidOptionError` for a model whose actions are not the four grid
    directions (a corridor). O(N)."""
    names = tuple(model.action_names)
    if not set(CONTEXT_DIRECTIONS) <= set(names):
        raise InvalidOptionError(f"label_prior='context' conditions on a cell's 4 grid neighbours; this model's "
                                 f"actions are {names}, not the grid's {CONTEXT_DIRECTIONS}")
    table = model.neighbors[:, [names.index(name) for name in CONTEXT_DIRECTIONS]].astype(np.int64)
    return np.where(table == np.arange(model.n_cells)[:, None], -1, table)


def n_context_codes(n_labels: int) -> int:
    """The number of context codes, (K + 2)^4: every combination of 4 neighbour states. O(1)."""
    return (n_labels + 2) ** len(CONTEXT_DIRECTIONS)


def neighbour_states(mixture: np.ndarray, read: np.ndarray) -> np.ndarray:
    """(N,) int64 each cell's state as a neighbour: :data:`NOT_READ` if not ``read`` (N,), else 2
    + its most probable label under ``mixture`` (N, K) (the first of ties). O(N K)."""
    return np.where(read, 2 + np.argmax(mixture, axis=1), NOT_READ)


def context_codes(states: np.ndarray, table: np.ndarray, n_labels: int) -> np.ndarray:
    """(N,) int64 every cell's context: the base-(K + 2) number whose digits are the ``states``
    (N,) of its neighbours in ``table`` (N, 4) (:func:`neighbour_table`; :data:`OFF_GRID` where
    -1), the north neighbour's the most significant. O(N)."""
    base = n_labels + 2
    digits = np.where(table < 0, OFF_GRID, states[np.maximum(table, 0)])
    codes = np.zeros(len(table), dtype=np.int64)
    for column in digits.T:
        codes = codes * base + column
    return codes


def context_counts(mixture: np.ndarray, read: np.ndarray, codes: np.ndarray, n_codes: int) -> np.ndarray:
    """(n_codes, K) ``n[c, k]``, the summed ``mixture`` (N, K) over the ``read`` (N,) cells whose
    context ``codes`` (N,) is c (codes in 0 .. n_codes - 1). O(N K + n_codes K)."""
    counts = np.zeros((n_codes, mixture.shape[1]))
    for k in range(mixture.shape[1]):
        counts[:, k] = np.bincount(codes[read], weights=mixture[read, k], minlength=n_codes)
    return counts


def backed_off(counts: np.ndarray, frequencies: np.ndarray) -> np.ndarray:
    """(C, K) the predictive of each context from its counts (C, K): ``(n[c] + S pi) / (sum_k
    n[c, k] + S)``, S = K, backed off to the ``frequencies`` pi (K,). Rows sum to 1. O(C K)."""
    strength = float(counts.shape[1])
    return (counts + strength * frequencies) / (counts.sum(axis=1)[:, None] + strength)


@dataclass(frozen=True, eq=False, repr=False)
class ContextTable:
    """Pseudo-counts of the context priors learned beforehand (the module docstring; the RBPF's
    option ``context_table``): ``counts`` ((K + 2)^4, K) float64, read-only, ``T[c, k]`` added to
    the learned counts of context c (rows indexed by :func:`context_codes`' codes). Built by
    :func:`context_table`; a hand-built one is checked: a 2-d array of (K + 2)^4 rows of K >= 1
    finite, non-negative numbers, else :class:`~onlinemap.errors.InvalidOptionError`. Immutable:
    a copy of the filter shares it. O((K + 2)^4 K)."""

    counts: np.ndarray

    def __post_init__(self) -> None:
        try:
            counts = np.array(self.counts, dtype=np.float64)
        except (TypeError, ValueError):
            raise InvalidOptionError(f"ContextTable counts must be an array of numbers, got {self.counts!r}") from None
        if counts.ndim != 2 or counts.shape[1] < 1 or counts.shape[0] != n_context_codes(counts.shape[1]):
            raise InvalidOptionError(f"ContextTable counts must have shape ((K + 2)^4, K), one row per context code, "
                                     f"got {counts.shape}")
        if not np.all(np.isfinite(counts)) or np.any(counts < 0):
            raise InvalidOptionError("ContextTable counts must be finite and non-negative")
        counts.setflags(write=False)
        object.__setattr__(self, "counts", counts)

    @property
    def n_labels(self) -> int:
        """K, the labels the table counts."""
        return self.counts.shape[1]

    def __repr__(self) -> str:
        return f"ContextTable(n_labels={self.n_labels}, total={self.counts.sum():g})"

    def __deepcopy__(self, memo) -> ContextTable:
        return self  # immutable: a forked filter shares it


def context_table(maps: Iterable, strength: float = 100.0) -> ContextTable:
    """The :class:`ContextTable` of known maps: ``maps`` an iterable of ``(model, labels)`` pairs,
    each a grid :class:`~onlinemap.model.GridModel` and its (N,) true labels (what
    :func:`onlinemap.building` returns). For every cell i of every map and every one of the 16
    read/unread masks of its 4 neighbours, the cell's label is counted in the context whose
    digits are :data:`OFF_GRID` off the grid, :data:`NOT_READ` for a masked neighbour, else 2 +
    its label (:func:`context_codes`): a robot meets a cell with any subset of its neighbours
    read. Each context's row ``m[c]`` (total ``n_c``) is then scaled to the total min(n_c,
    ``strength``), ``T[c] = m[c] min(n_c, S') / n_c`` (empty rows stay 0): the known maps say
    what a context predicts, worth at most ``strength`` cells of this floor's own readings.
    Raises :class:`~onlinemap.errors.InvalidOptionError` naming the problem: no maps, a model that
    is not a grid (:func:`neighbour_table`), maps of different label counts, labels not of
    shape (N,) or outside 0 .. K - 1, a ``strength`` not positive and finite.
    O(16 sum_maps N K + (K + 2)^4 K) time, 8 (K + 2)^4 K bytes."""
    strength = arguments.real("strength", strength, low=0.0, low_open=True, high=math.inf, high_open=True,
                              error=InvalidOptionError)
    counts = None
    for index, (model, labels) in enumerate(maps):
        table, n_labels = neighbour_table(model), model.n_labels
        labels = np.asarray(labels)
        if counts is not None and n_labels != counts.shape[1]:
            raise InvalidOptionError(f"context_table: map {index} has {n_labels} labels, the maps before it "
                                     f"{counts.shape[1]}")
        if labels.shape != (model.n_cells,) or labels.dtype.kind not in "iu" or \
                (labels.size and not 0 <= labels.min() <= labels.max() < n_labels):
            raise InvalidOptionError(f"context_table: map {index}'s labels must be {model.n_cells} integers in "
                                     f"0..{n_labels - 1}")
        masked_counts = _masked_context_counts(table, labels, n_labels)
        counts = masked_counts if counts is None else counts + masked_counts
    if counts is None:
        raise InvalidOptionError("context_table needs at least one (model, labels) map")
    totals = counts.sum(axis=1, keepdims=True)
    return ContextTable(counts * (np.minimum(totals, strength) / np.maximum(totals, 1.0)))


def _masked_context_counts(table: np.ndarray, labels: np.ndarray, n_labels: int) -> np.ndarray:
    """((K + 2)^4, K) the label counts of one map (``labels`` (N,), neighbours ``table`` (N, 4))
    per context, over the 16 masks of :func:`context_table`: a masked neighbour points at an extra
    cell N whose state is :data:`NOT_READ` (an off-grid one stays off the grid). O(16 N K)."""
    n_cells = len(labels)
    states = np.append(2 + labels.astype(np.int64), NOT_READ)
    one_hot = np.eye(n_labels)[labels]
    every = np.ones(n_cells, dtype=bool)
    counts = np.zeros((n_context_codes(n_labels), n_labels))
    for mask in range(2 ** len(CONTEXT_DIRECTIONS)):
        hidden = (mask >> np.arange(len(CONTEXT_DIRECTIONS)) & 1).astype(bool)  # (4,) by direction
        masked = np.where(hidden & (table >= 0), n_cells, table)
        counts += context_counts(one_hot, every, context_codes(states, masked, n_labels), len(counts))
    return counts


def context_tilts(mixture: np.ndarray, read: np.ndarray, codes: np.ndarray, frequencies: np.ndarray,
                  pretrained: np.ndarray | None = None) -> np.ndarray:
    """(N, K) every cell's tilt ``v_i = (n[c_i] + S pi) / (sum_k n[c_i, k] + S)``, S = K, with
    ``n[c, k]`` the summed ``mixture`` (N, K) over the ``read`` (N,) cells of context ``c``, plus
    the ``pretrained`` pseudo-counts ``T[c, k]`` ((K + 2)^4, K; :attr:`ContextTable.counts`) if
    given, ``codes`` (N,) each cell's context and ``frequencies`` pi (K,). Rows sum to 1. O(N K)."""
    contexts, which = np.unique(codes, return_inverse=True)  # only the contexts in use: (K + 2)^4 may be large
    counts = context_counts(mixture, read, which, len(contexts))
    if pretrained is not None:
        counts += pretrained[contexts]
    return backed_off(counts, frequencies)[which]


def freeze_contexts(mixture: np.ndarray, state: ContextState, now: np.ndarray,
                    table: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(read, frozen), (N,) each: the cells read so far once those read ``now`` (N,) are added to
    ``state.read``, and their contexts, the newly read ones frozen from the neighbour states
    before this step (:func:`neighbour_states` of ``mixture`` (N, K) over ``state.read``: cells
    read at the same step do not see each other), ``table`` (N, 4) the neighbours. O(N K)."""
    first = now & ~state.read
    before = context_codes(neighbour_states(mixture, state.read), table, mixture.shape[1])
    return state.read | now, np.where(first, before, state.frozen)


def learn_context(mixture: np.ndarray, prior: np.ndarray, state: ContextState, table: np.ndarray,
                  alpha: np.ndarray, pretrained: np.ndarray | None = None) -> ContextState:
    """One learning step of ``label_prior="context"`` (the module docstring) from the mixture map
    (N, K) (rows summing to 1), the model's prior table (N, K), the current ``state``, the
    neighbours ``table`` (N, 4) and the Dirichlet ``alpha`` (K,). The cells read now are those
    whose mixture differs from their unread marginal ``normalise(prior_i * v_i)`` by more than
    :data:`READ_TOLERANCE`; those read for the first time freeze their context
    (:func:`freeze_contexts`); the unread take theirs from the states after it. Then pi =
    ``(alpha + sum of the mixture over the read cells) / (A + n_read)`` and the tilts
    (:func:`context_tilts`, with the ``pretrained`` pseudo-counts ((K + 2)^4, K) if given). A
    fresh state; ``state`` is not changed. O(N K)."""
    n_labels = mixture.shape[1]
    now = np.abs(mixture - unread_marginals(prior, state.tilts)).max(axis=1) > READ_TOLERANCE
    read, frozen = freeze_contexts(mixture, state, now, table)
    after = context_codes(neighbour_states(mixture, read), table, n_labels)
    frequencies = posterior_frequencies(alpha, mixture[read].sum(axis=0))
    tilts = context_tilts(mixture, read, np.where(read, frozen, after), frequencies, pretrained)
    return ContextState(tilts, read, frozen, frequencies)


def learn_context_ratios(mixture: np.ndarray, state: ContextState, now: np.ndarray, table: np.ndarray,
                         alpha: np.ndarray, weight: float,
                         pretrained: np.ndarray | None = None) -> tuple[ContextState, np.ndarray]:
    """One learning step of ``label_prior="particle_context"`` (the module docstring): the cells
    read ``now`` (N,) (most of the particles' weight read them) join the read ones, their contexts
    frozen (:func:`freeze_contexts`); pi = ``(alpha + sum of the mixture (N, K) over the read
    cells) / (A + n_read)``; every context's predictive ``v[c]`` (:func:`backed_off` of the
    :func:`context_counts` of the read cells, plus the ``pretrained`` pseudo-counts ((K + 2)^4,
    K) if given) tempered, ``v'[c] = weight v[c] + (1 - weight) pi``. Returns the new state (its
    ``tilts`` are the state's, unused by this prior) and the ratios ``v' / pi`` ((K + 2)^4, K),
    each context's tilt of a cell's prior. O(N K + (K + 2)^4 K)."""
    read, frozen = freeze_contexts(mixture, state, now, table)
    frequencies = posterior_frequencies(alpha, mixture[read].sum(axis=0))
    counts = context_counts(mixture, read, frozen, n_context_codes(mixture.shape[1]))
    predictive = backed_off(counts if pretrained is None else counts + pretrained, frequencies)
    ratios = (weight * predictive + (1.0 - weight) * frequencies) / frequencies
    return ContextState(state.tilts, read, frozen, frequencies), ratios


def shown_options(options: dict, kind: str) -> dict:
    """An estimator's ``options`` (a fresh dict) as its filter runs them, for ``repr`` and the
    run logs: without the label-prior options when it uses the model's table (``kind`` of the
    resolved :class:`LabelPrior` ``"model"``: every repr as without the options), with
    ``label_prior="learn"`` when it learns because the model says so, ``context_weight`` only
    with ``"particle_context"`` (its default filled in), ``context_table`` only when given.
    O(len(options))."""
    options = dict(options)
    if kind == "model":
        for name in ("label_prior", "prior_strength", "learn_every"):
            options.pop(name, None)
    elif options.get("label_prior") is None:
        options["label_prior"] = LEARN
    if kind == PARTICLE_CONTEXT:
        options["context_weight"] = context_weight(options.get("context_weight"))
    else:
        options.pop("context_weight", None)
    if options.get("context_table") is None:
        options.pop("context_table", None)
    return options


def context_weight(value) -> float:
    """``label_prior="particle_context"``'s option ``context_weight`` checked, None the default
    :data:`DEFAULT_CONTEXT_WEIGHT`: the weight w in (0, 1] of the context table against the
    frequencies (the module docstring). Raises :class:`~onlinemap.errors.InvalidOptionError`
    otherwise (:func:`~onlinemap.arguments.real`). O(1)."""
    if value is None:
        return DEFAULT_CONTEXT_WEIGHT
    return arguments.real("context_weight", value, low=0.0, high=1.0, low_open=True, error=InvalidOptionError)
