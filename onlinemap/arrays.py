"""Small array helpers shared by the model, the simulator and the estimators. Imports numpy only."""

from __future__ import annotations

import functools

import numpy as np

DEFAULT_MAX_BYTES = 2 * 1024**3  # memory guard of the estimators that can grow large (exact, rbpf)


def read_only(array: np.ndarray) -> np.ndarray:
    """Mark ``array`` read-only in place and return it (for arrays handed out or shared)."""
    array.setflags(write=False)
    return array


def frozen(array: np.ndarray) -> np.ndarray:
    """A read-only, C-contiguous view of ``array`` (a copy only where it is not C-contiguous):
    the one form in which a numba kernel's constant inputs are passed, so that the kernel is
    compiled once rather than once per write flag and memory layout its callers happen to have.
    About 0.5 us (``setflags`` is a quarter faster than setting ``flags.writeable``)."""
    return read_only(np.ascontiguousarray(array).view())


def cached_by_content(function):
    """``function(array, *args)`` cached by the array's contents (bytes, shape and dtype) and the
    hashable ``args``, for the last 64 distinct calls; ``function`` gets a fresh C-contiguous copy
    of the array, and its result is returned read-only and shared (copy it to write). For small
    tables derived again and again from equal arrays (every EM estimator built needs its sensor's
    pseudo-inverse, every dynamic RBPF the powers of its change matrix). O(size) to look up."""
    @functools.lru_cache(maxsize=64)
    def cached(data: bytes, shape: tuple[int, ...], dtype: str, *args):
        return read_only(function(np.frombuffer(data, dtype=dtype).reshape(shape).copy(), *args))

    @functools.wraps(function)
    def by_content(array, *args):
        array = np.ascontiguousarray(array)
        return cached(array.tobytes(), array.shape, array.dtype.str, *args)

    return by_content
