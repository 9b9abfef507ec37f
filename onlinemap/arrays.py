"""Small array helpers shared by the model, the simulator and the estimators. Imports numpy only."""

from __future__ import annotations

import numpy as np

DEFAULT_MAX_BYTES = 2 * 1024**3  # memory guard of the estimators that can grow large (exact, rbpf)


def read_only(array: np.ndarray) -> np.ndarray:
    """Mark ``array`` read-only in place and return it (for arrays handed out or shared)."""
    array.setflags(write=False)
    return array
