"""Seeds and random generators: every random choice in onlinemap takes a ``seed`` (an int, None
for fresh entropy, or a ``numpy.random.Generator``); numpy's global random state is never used.
Imports numpy only."""

from __future__ import annotations

import numpy as np

SeedLike = int | np.random.Generator | None


def as_generator(seed: SeedLike) -> np.random.Generator:
    """A Generator from an int seed, None (fresh entropy) or an existing Generator (returned as is)."""
    return seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)


ESTIMATOR_STREAM = 1  # the stream of a run's seed that seeds its estimators (run and sweep agree)


def derived_seed(seed: int, stream: int) -> int:
    """An independent 32-bit seed for stream ``stream`` of a run's ``seed`` (``SeedSequence([seed,
    stream])``); ``onlinemap run --seed S`` seeds its estimators with ``derived_seed(S, ESTIMATOR_STREAM)``,
    as a sweep task with seed S does."""
    return int(np.random.SeedSequence([int(seed), int(stream)]).generate_state(1)[0])
