"""The read-only answer every estimator gives after each step."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .arrays import read_only


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
    log_evidence: ``log P(z_0:t | a_1:t)`` under the estimator's model (NaN where undefined)
    observation_matrix: (N, K) ``B[i, k] = P(Z = k | L = i)``, for estimators that learn it
    effective_sample_size: for particle filters, after the step's weighting

    Arrays are read-only copies; an estimator never hands out its own buffers.
    """

    t: int
    location: np.ndarray
    map: np.ndarray
    log_evidence: float = float("nan")
    observation_matrix: np.ndarray | None = None
    effective_sample_size: float | None = None

    def __post_init__(self) -> None:
        for name in ("location", "map", "observation_matrix"):
            object.__setattr__(self, name, _frozen(getattr(self, name)))
        object.__setattr__(self, "t", int(self.t))
        object.__setattr__(self, "log_evidence", float(self.log_evidence))

    @property
    def n_cells(self) -> int:
        return self.location.shape[0]

    @property
    def n_labels(self) -> int:
        return self.map.shape[1]

    @property
    def most_likely_location(self) -> int:
        return int(np.argmax(self.location))

    @property
    def map_estimate(self) -> np.ndarray:
        """(N,) the most likely label of every cell."""
        return np.argmax(self.map, axis=1)

    def __repr__(self) -> str:
        where = self.most_likely_location
        return (f"Belief(t={self.t}, most likely cell {where} with p={self.location[where]:.3f}, "
                f"N={self.n_cells}, K={self.n_labels}, log_evidence={self.log_evidence:.4g})")
