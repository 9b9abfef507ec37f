"""Seeds and random generators: every random choice in onlinemap takes a ``seed`` (an int, None
for fresh entropy, or a ``numpy.random.Generator``); numpy's global random state is never used.
Imports numpy only."""

from __future__ import annotations

import numpy as np

SeedLike = int | np.random.Generator | None


def as_generator(seed: SeedLike) -> np.random.Generator:
    """A Generator from an int seed, None (fresh entropy) or an existing Generator (returned as is)."""
    return seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
