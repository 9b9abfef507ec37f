"""The read-only answer every estimator gives after each step."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .arguments import integer
from .arrays import read_only
from .errors import InvalidOptionError

if TYPE_CHECKING:
    import pandas as pd

    from .model import GridModel


def _frozen(array: np.ndarray | None) -> np.ndarray | None:
    if array is None:
        return None
    array = np.asarray(array, dtype=np.float64)
    if array.flags.writeable and array.base is not None:
        array = array.copy()
    return read_only(array)


@dataclass(frozen=True, eq=False)
class Belief:
    """Marginal beliefs after step ``t`` (0 = the first observation).

    location: (N,) ``P(L_t = i | z_0:t, a_1:t)``
    map: (N, K) ``P(m_{i,t} = k | z_0:t, a_1:t)``
    log_evidence: ``log P(z_0:t | a_1:t)`` under the estimator's model; NaN where undefined:
    dead reckoning has no observation model (it never weighs an observation), so it gives the
    observations no probability
    observation_matrix: (N, K) ``B[i, k] = P(Z = k | L = i)``, for estimators that learn it
    effective_sample_size: for particle filters, ``1 / sum w_i^2`` after the step's weighting (the
    Monte-Carlo sample size of the weighted particles). A health signal for the sampling schemes
    (near P the weights are even, near 1 one particle carries them), but not under
    Fearnhead-Clifford resampling, whose kept children carry unequal weights by design and which
    starts from one particle: 1.2 of 100 at t = 1, while the filter is still exact Bayes
    distinct_locations: for particle filters, the number of distinct cells the particles of
    positive weight stand in: how many location hypotheses the filter still holds, the signal to
    read under Fearnhead-Clifford
    recovered: True when a particle filter recovered from depletion at this step (no particle
    explained the observation; see the RBPF's class docstring for what the belief then is)

    Arrays are read-only copies; an estimator never hands out its own buffers.
    """

    t: int
    location: np.ndarray
    map: np.ndarray
    log_evidence: float = float("nan")
    observation_matrix: np.ndarray | None = None
    effective_sample_size: float | None = None
    recovered: bool = False
    distinct_locations: int | None = None

    def __post_init__(self) -> None:
        for name in ("location", "map", "observation_matrix"):
            object.__setattr__(self, name, _frozen(getattr(self, name)))
        object.__setattr__(self, "t", int(self.t))
        object.__setattr__(self, "log_evidence", float(self.log_evidence))
        object.__setattr__(self, "recovered", bool(self.recovered))

    @property
    def n_cells(self) -> int:
        return self.location.shape[0]

    @property
    def n_labels(self) -> int:
        return self.map.shape[1]

    @property
    def most_likely_location(self) -> int:
        """The cell ``argmax_i P(L_t = i)`` (the lowest index on ties)."""
        return int(np.argmax(self.location))

    @property
    def map_estimate(self) -> np.ndarray:
        """(N,) the most likely label of every cell, ``argmax_k P(m_i = k)`` (marginal by marginal:
        not necessarily the most likely map as a whole)."""
        return np.argmax(self.map, axis=1)

    def to_frame(self, model: GridModel | None = None) -> pd.DataFrame:
        """One row per cell: ``t``, ``cell`` (with ``row``, ``col`` given the model), ``location`` =
        P(L_t = cell), one column ``map_LABEL`` per label = P(m_cell = LABEL), and
        ``most_likely_label``. Labels are named by ``model`` (else 0..K-1). Cost O(N K)."""
        return beliefs_frame(self.location[None], self.map[None], model, t=np.array([self.t]))

    def __repr__(self) -> str:
        where = self.most_likely_location
        extra = "" if self.effective_sample_size is None else f", ess={self.effective_sample_size:.1f}"
        extra += "" if self.distinct_locations is None else f", {self.distinct_locations} distinct particle locations"
        undefined = " (undefined)" if math.isnan(self.log_evidence) else ""
        extra += ", recovered from depletion" if self.recovered else ""
        return (f"Belief(t={self.t}, most likely cell {where} with p={self.location[where]:.3f}, "
                f"N={self.n_cells}, K={self.n_labels}, log_evidence={self.log_evidence:.4g}{undefined}{extra})")


STALL_AFTER = 50  # a closed loop whose belief has not moved for this many presses has stalled


def same_belief(one: Belief, other: Belief) -> bool:
    """Whether two beliefs have the same location and map marginals (to 1e-12 each). O(N K)."""
    return (one.location.shape == other.location.shape and one.map.shape == other.map.shape
            and np.allclose(one.location, other.location, rtol=0, atol=1e-12)
            and np.allclose(one.map, other.map, rtol=0, atol=1e-12))


class StallWatch:
    """Stall detection for a closed loop: ``after`` presses in a row after each of which the
    belief equals the one before it (:func:`same_belief`) are a stall. Give :meth:`update` each
    step's belief; it returns True at the step the stall is declared (once per stall: the count
    starts again when the belief moves). ``after`` None: never. O(N K) per step."""

    def __init__(self, after: int | None = STALL_AFTER):
        self.after = None if after is None else integer("stall_after", after, minimum=1, error=InvalidOptionError)
        self.unchanged = 0  # presses in a row that left the belief as it was
        self.stalled_at: int | None = None  # the step of the first stall declared
        self._last: Belief | None = None

    def update(self, belief: Belief) -> bool:
        unchanged = self._last is not None and same_belief(belief, self._last)
        self._last = belief
        self.unchanged = self.unchanged + 1 if unchanged else 0
        if self.after is None or self.unchanged != self.after:
            return False
        if self.stalled_at is None:
            self.stalled_at = belief.t
        return True


def beliefs_frame(location: np.ndarray, maps: np.ndarray, model: GridModel | None = None,
                  t: np.ndarray | None = None) -> pd.DataFrame:
    """Beliefs over time in long format (for pandas / seaborn): one row per step and cell.

    location (T, N), maps (T, N, K), t (T,) step indices (default 0..T-1). Columns: ``t``,
    ``cell``, ``row`` and ``col`` (with a model), ``location``, ``map_LABEL`` per label (named
    by the model, else 0..K-1), ``most_likely_label`` (a name with a model, else an index).
    Cost O(T N K) time and memory.
    """
    import pandas as pd

    location, maps = np.asarray(location, dtype=float), np.asarray(maps, dtype=float)
    steps, cells, labels = maps.shape
    if location.shape != (steps, cells):
        raise ValueError(f"location {location.shape} and maps {maps.shape} do not match: (T, N) and (T, N, K)")
    names = model.label_names if model is not None else tuple(str(k) for k in range(labels))
    best = np.argmax(maps, axis=2).ravel()
    columns = {"t": np.repeat(np.arange(steps) if t is None else np.asarray(t), cells),
               "cell": np.tile(np.arange(cells), steps)}
    if model is not None:
        columns["row"], columns["col"] = np.divmod(columns["cell"], model.cols)
    columns["location"] = location.ravel()
    columns.update({f"map_{name}": maps[:, :, k].ravel() for k, name in enumerate(names)})
    columns["most_likely_label"] = np.asarray(names, dtype=object)[best] if model is not None else best
    return pd.DataFrame(columns)
