"""Threaded drivers of the RBPF's kernels (``onlinemap/kernels/rbpf.py``), for ``threads > 1``.

Each driver splits the work into fixed chunks (``chunk`` particles, :data:`CHUNK` for the filter,
or :data:`BLOCK_GROUP` map blocks), gives each of ``threads`` threads one contiguous run of chunks
and calls on each run, at once, the range kernel the serial kernel calls on everything (a
:data:`~onlinemap.kernels.thread_kernel`, which releases the GIL: ``rbpf_enumerate`` is
``enumerate_run`` over every parent); the serial steps between them run on the calling thread. No
run reads what another writes, and every sum is taken in the order the serial kernel takes it,
so the results are the serial kernels' bit for bit, whatever the number of threads or chunks:

- :func:`rbpf_enumerate_parallel` / :func:`rbpf_enumerate_cells_parallel`: each run of parents
  writes its children from index ``2 * start`` on; the runs are then moved together in order
  (:func:`_gather_children`: one pass over the children; none when no child was left out);
- :func:`rbpf_propose_parallel`: particles are independent;
- :func:`rbpf_stage_children_parallel` / :func:`rbpf_stage_children_cells_parallel` then
  :func:`rbpf_commit_staged_parallel`: the commit in three passes. First every kept child's
  changed cells are computed from its parent's rows (nothing written yet); then the take-over
  and the bookkeeping of copy-on-write run serially, in the serial commit's order, so every
  write gets the row the serial commit gives it; then all block copies are made (each reads a
  row that no write has changed yet) and, after them, all writes (each into a row only its
  particle uses). The sampling schemes' commit is the same last step on their proposals;
- :func:`rbpf_map_mixture_parallel`: the weight of a row is summed over the particles in order by
  the run of blocks holding it; then each run of blocks adds its rows, in row order, into its own
  cells.

Threads: the calling thread runs the first run and a pool of Python threads the others
(:func:`in_threads`; the pool is made on first use, with ``NUMBA_NUM_THREADS - 1`` threads, and
anew in a forked child); a phase ends when every run has, then the first exception of any run
is raised. Cost: as the serial kernels, plus one pass to move the children together, a scan of
the rows' weights and blocks per run in the mixture, and some 40-75 us per phase to hand the
runs to the threads (measured: a pool thread wakes and takes the GIL to enter its kernel); the
serial parts (take-over, copy-on-write bookkeeping, Fearnhead-Clifford's selection) stay
serial. No kernel compiles with ``parallel=True``. The enumeration's range kernels are the
serial entry points' own; the proposal's and the row weights' are compiled once more for the
threads (the serial kernels call them with literal bounds, which numba compiles apart), and the
staged commit, the gather and the mixture's runs of blocks are the threads' alone: about 10 CPU
seconds in all with a cold cache (``parallel=True`` kernels took 50: none here).
"""

from __future__ import annotations

import concurrent.futures
import functools
import os
from collections.abc import Callable

import numba
import numpy as np

from . import loop_kernel
from .rbpf import mixture_blocks, row_weights, ordered_sum, take_over_slots
from .rbpf_commit import copy_planned, plan_writes, stage_children, stage_children_cells, write_planned
from .rbpf_enumerate import enumerate_run, enumerate_cells_run, propose_run, footprint_scratch

CHUNK = 1024  # particles per chunk (the drivers' ``chunk``), fixed: the chunks do not depend on the threads
BLOCK_GROUP = 8  # map blocks per chunk of the row weights: one cache line of a particle's table row

_executor: concurrent.futures.ThreadPoolExecutor | None = None


def _pool() -> concurrent.futures.ThreadPoolExecutor:
    """The threads that run the runs after the first (made on first use)."""
    global _executor
    if _executor is None:
        _executor = concurrent.futures.ThreadPoolExecutor(max(1, numba.config.NUMBA_NUM_THREADS - 1),
                                                          thread_name_prefix="onlinemap-rbpf")
    return _executor


def _forget_pool() -> None:
    """In a forked child: the parent's pool threads are gone, so the next call makes a new pool."""
    global _executor
    _executor = None


if hasattr(os, "register_at_fork"):  # POSIX
    os.register_at_fork(after_in_child=_forget_pool)


def in_threads(calls: list[Callable[[], object]]) -> list:
    """The results of ``calls``, the first run on this thread and the others at once on the pool;
    returns (or raises the first exception, in call order) once every call has finished."""
    futures = [_pool().submit(call) for call in calls[1:]]
    try:
        first = calls[0]()
    finally:
        concurrent.futures.wait(futures)
    return [first] + [future.result() for future in futures]


def thread_runs(n: int, chunk: int, threads: int) -> list[tuple[int, int]]:
    """``[start, stop)`` of each of up to ``threads`` contiguous runs of the chunks of ``chunk``
    items covering ``n`` (``n >= 1``), as even in chunks as can be."""
    n_chunks = -(-n // chunk)
    count = min(threads, n_chunks)
    bounds = [i * n_chunks // count * chunk for i in range(count + 1)]
    return [(bounds[i], min(n, bounds[i + 1])) for i in range(count)]


@loop_kernel
def _gather_children(counts, firsts, children):
    """Move run i's ``counts[i]`` children from index ``firsts[i]`` (increasing, each at or after
    the previous run's children) to follow the previous runs' (the stored ids, cells and log
    motion too when ``children.cells`` has rows); returns M. O(M)."""
    child_parent, child_location, child_log_weight = children.parent, children.location, children.log_weight
    child_log_motion, child_ids, child_cells = children.log_motion, children.ids, children.cells
    m = 0
    for i in range(counts.shape[0]):
        first = firsts[i]
        if m != first:  # m < first: copying upwards never overwrites a child not yet moved
            for c in range(counts[i]):
                child_parent[m + c] = child_parent[first + c]
                child_location[m + c] = child_location[first + c]
                child_log_weight[m + c] = child_log_weight[first + c]
                if child_cells.shape[0] > 0:
                    child_log_motion[m + c] = child_log_motion[first + c]
                    for w in range(child_ids.shape[1]):
                        child_ids[m + c, w] = child_ids[first + c, w]
                        for b in range(child_cells.shape[2]):
                            child_cells[m + c, w, b] = child_cells[first + c, w, b]
        m += counts[i]
    return m


def _gathered(counts: list[int], runs: list[tuple[int, int]], children) -> int:
    """M, once the ``counts`` children each run of parents wrote from index ``2 * start`` on are
    moved together (:func:`_gather_children`)."""
    firsts = np.array([2 * start for start, _ in runs], dtype=np.int64)
    return _gather_children(np.array(counts, dtype=np.int64), firsts, children)


def rbpf_enumerate_parallel(locations: np.ndarray, log_weights: np.ndarray, pool, world, t: int, neighbors: np.ndarray,
                            likelihood: np.ndarray, children, chunk: int, threads: int) -> int:
    """:func:`~onlinemap.kernels.rbpf_enumerate.rbpf_enumerate` (the same children, in the same
    order)."""
    runs = thread_runs(len(locations), chunk, threads)
    counts = in_threads([functools.partial(enumerate_run, locations, log_weights, world.p_move, t, neighbors,
                                            likelihood, start, stop, 2 * start, np.empty(1), *children[:3], *pool)
                          for start, stop in runs])
    return _gathered(counts, runs, children)


def rbpf_enumerate_cells_parallel(locations: np.ndarray, log_weights: np.ndarray, pool, world, t: int,
                                  neighbors: np.ndarray, readings: np.ndarray, children, chunk: int,
                                  threads: int) -> int:
    """:func:`~onlinemap.kernels.rbpf_enumerate.rbpf_enumerate_cells` (the same children, in the
    same order)."""
    sizes = (world.sensor.shape[0], world.footprint_cells.shape[1], children.ids.shape[1])
    runs = thread_runs(len(locations), chunk, threads)
    counts = in_threads([functools.partial(enumerate_cells_run, locations, log_weights, t, neighbors, readings, start,
                                            stop, 2 * start, *children, *footprint_scratch(*sizes), *world, *pool)
                          for start, stop in runs])
    return _gathered(counts, runs, children)


def rbpf_propose_parallel(locations: np.ndarray, pool, p_move: float, t: int, ancestors: np.ndarray,
                          neighbors: np.ndarray, likelihood: np.ndarray, optimal: bool, uniforms: np.ndarray, proposed,
                          chunk: int, threads: int) -> None:
    """:func:`~onlinemap.kernels.rbpf_enumerate.rbpf_propose`."""
    in_threads([functools.partial(propose_run, locations, pool, p_move, t, ancestors, neighbors, likelihood, optimal,
                                   uniforms, proposed, start, stop)
                 for start, stop in thread_runs(len(ancestors), chunk, threads)])


def rbpf_stage_children_parallel(pool, t: int, slots, child_location: np.ndarray, likelihood: np.ndarray, staged,
                                 chunk: int, threads: int) -> None:
    """Fearnhead-Clifford's kept children's writes
    (:func:`~onlinemap.kernels.rbpf_commit.stage_children`), staged from the parents' rows for
    :func:`rbpf_commit_staged_parallel`; writes only ``staged``."""
    in_threads([functools.partial(stage_children, pool, t, slots, child_location, likelihood, staged, start, stop)
                 for start, stop in thread_runs(len(slots.slot_child), chunk, threads)])


def rbpf_stage_children_cells_parallel(locations: np.ndarray, pool, world, t: int, slots, child_location: np.ndarray,
                                       neighbors: np.ndarray, readings: np.ndarray, staged, chunk: int,
                                       threads: int) -> None:
    """:func:`rbpf_stage_children_parallel` for blocking labels and sensor footprints
    (:func:`~onlinemap.kernels.rbpf_commit.stage_children_cells`); writes only ``staged``."""
    sizes = (world.sensor.shape[0], world.footprint_cells.shape[1], staged.ids.shape[1])
    in_threads([functools.partial(stage_children_cells, locations, pool, world, t, slots, child_location, neighbors,
                                   readings, staged, start, stop, footprint_scratch(*sizes))
                 for start, stop in thread_runs(len(slots.slot_child), chunk, threads)])


def rbpf_commit_staged_parallel(locations: np.ndarray, pool, t: int, ancestors: np.ndarray, staged, chunk: int,
                                threads: int) -> None:
    """:func:`~onlinemap.kernels.rbpf_commit.rbpf_commit_cells`, bit for bit: the take-over and the
    copy-on-write bookkeeping (:func:`~onlinemap.kernels.rbpf_commit.plan_writes`, into
    ``staged.target`` and ``staged.source``) serially, then every block copy, then every write and
    the locations. Needs ``free_top[0] >= W P``."""
    take_over_slots(pool, ancestors)
    plan_writes(pool, staged)
    runs = thread_runs(len(staged.locations), chunk, threads)
    in_threads([functools.partial(copy_planned, pool, t, staged, start, stop) for start, stop in runs])
    in_threads([functools.partial(write_planned, pool, t, staged, locations, start, stop) for start, stop in runs])


def rbpf_map_mixture_parallel(pool, t: int, weights: np.ndarray, out: np.ndarray, threads: int) -> None:
    """:func:`~onlinemap.kernels.rbpf.rbpf_map_mixture`, the same sums, on runs of chunks of
    ``BLOCK_GROUP`` blocks: first the row weights (a row holds one block, and each row's weight
    adds its particles in order), then each run's rows, in row order, into its own cells
    (:func:`~onlinemap.kernels.rbpf.mixture_blocks`: every run scans the rows, O(R) each)."""
    n_blocks = pool.table.shape[1]
    runs = thread_runs(n_blocks, BLOCK_GROUP, threads)
    row_weight = np.zeros(len(pool.rows))
    total = ordered_sum(weights)
    in_threads([functools.partial(row_weights, pool.table, pool.refcount, weights, total, row_weight, first, last,
                                   np.empty(last - first, dtype=np.int64), np.empty(last - first, dtype=np.int64),
                                   np.empty(last - first)) for first, last in runs])
    out[:] = 0.0
    in_threads([functools.partial(mixture_blocks, pool, t, row_weight, first, last, out) for first, last in runs])
