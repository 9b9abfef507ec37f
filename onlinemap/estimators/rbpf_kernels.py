"""The RBPF's kernel sets, the model's tables as its kernels take them, and its schemes (the
options ``proposal`` and ``resampling``: :func:`scheme`, :data:`SCHEMES`).

A filter runs one of four kernel sets, fixed by its model and options: the paper's motion and
sensor (:attr:`GridModel.is_paper_model <onlinemap.model.GridModel.is_paper_model>`: a child
changes one cell, its evidence one likelihood row) or blocking labels and sensor footprints (W
cells, F readings), each serial or on threads (:mod:`onlinemap.kernels.rbpf_parallel`, the same
results). :func:`kernel_set` builds each once; the filter's every update then takes one path
through it. The threaded sets read :data:`~onlinemap.kernels.rbpf_parallel.CHUNK` when they run,
so that tests can make chunks small.

:func:`world_tables` bundles the model's motion and sensor tables (:class:`~onlinemap.kernels.rbpf.World`)
once per model. Cost: O(1) per call once built.
"""

from __future__ import annotations

import dataclasses
import functools
import weakref
from collections.abc import Callable
from typing import NamedTuple

import numba
import numpy as np

from .. import arguments
from ..arrays import read_only
from ..errors import InvalidOptionError
from ..kernels import rbpf_parallel
from ..kernels.rbpf import Pool, World
from ..kernels.rbpf_commit import (Slots, Staged, rbpf_commit_cells, rbpf_commit_children, rbpf_commit_children_cells,
                                   rbpf_pick_children)
from ..kernels.rbpf_enumerate import Children, Proposed, rbpf_enumerate, rbpf_enumerate_cells, rbpf_propose
from ..model import GridModel
from ..resampling import RESAMPLERS

PROPOSALS = ("optimal", "transition")
FEARNHEAD_CLIFFORD = "fearnhead_clifford"
RESAMPLING = (*RESAMPLERS, FEARNHEAD_CLIFFORD)
#: the filter's named schemes (the options that make each), which studies, benchmarks and figures
#: compare: the default (optimal proposal, Fearnhead-Clifford resampling), the optimal proposal
#: sampled with residual resampling, and the transition proposal with residual resampling
SCHEMES: dict[str, dict[str, str]] = {
    "FC": {"proposal": "optimal", "resampling": FEARNHEAD_CLIFFORD},
    "optimal+residual": {"proposal": "optimal", "resampling": "residual"},
    "transition+residual": {"proposal": "transition", "resampling": "residual"},
}


def scheme(proposal, resampling) -> tuple[str, str]:
    """The RBPF's options ``proposal`` and ``resampling``, checked (:class:`InvalidOptionError`
    naming them), ``resampling`` None resolved: Fearnhead-Clifford for the optimal proposal,
    residual for the transition one. O(1)."""
    error = InvalidOptionError
    proposal = arguments.choice("proposal", proposal, PROPOSALS, error)
    if resampling is None:
        resampling = FEARNHEAD_CLIFFORD if proposal == "optimal" else "residual"
    resampling = arguments.choice("resampling", resampling, RESAMPLING, error)
    if resampling == FEARNHEAD_CLIFFORD and proposal != "optimal":
        raise error(f"proposal={proposal!r} samples one successor per particle; resampling="
                    f"'{FEARNHEAD_CLIFFORD}' enumerates them all (the optimal proposal's weights): pass "
                    f"resampling='residual' (or another sampling scheme) to use it")
    return proposal, resampling


_WORLDS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def world_tables(model: GridModel) -> World:
    """The model's motion and sensor tables as the RBPF's kernels take them, built on the first call
    for ``model`` and kept while it lives (the model's own arrays, read-only: one numba type)."""
    world = _WORLDS.get(model)
    if world is None:
        world = World(float(model.p_move), model.blocking, model.has_blocking, model.press_likelihood, model.change,
                      model.footprint_cells, model.sensor, model.likelihood, model.moves, model.predecessor)
        _WORLDS[model] = world
    return world


def observed(model: GridModel, z) -> np.ndarray:
    """What the kernels take of observation ``z``: its likelihood row (K,) in the paper's model,
    the readings (F,) int64 otherwise."""
    return model.likelihood[z] if model.is_paper_model else np.atleast_1d(np.asarray(z, dtype=np.int64))


@dataclasses.dataclass(frozen=True)
class KernelSet:
    """One filter's kernels, each with one signature whatever the set:

    - ``enumerate(locations, log_weights, pool, world, t, neighbors, observed, children) -> M``:
      every child with its exact weight (``rbpf_enumerate`` or ``rbpf_enumerate_cells``);
    - ``commit_children(locations, pool, world, t, slots, child_location, neighbors, observed,
      staged)``: Fearnhead-Clifford's kept children written (``staged``: the threads' staging);
    - ``commit(locations, pool, t, ancestors, staged)``: slots taken over, then the given cells
      ``staged.ids`` / ``staged.cells`` written (the sampling schemes, a recovery's children);
    - ``propose(locations, pool, world, t, ancestors, neighbors, observed, optimal, uniforms, out)
      -> (staged, log_increments)``: the sampling schemes' proposal, one successor per slot
      (``rbpf_propose``; with blocking labels or a footprint, one of the enumerated children,
      ``rbpf_pick_children``), into ``out`` (:class:`ProposalBuffers`): its writes
      (``out.staged``) and log increments (P,);
    - ``threads``: the threads they run on (1: serial)."""

    enumerate: Callable[..., int]
    commit_children: Callable[..., None]
    commit: Callable[..., None]
    propose: Callable[..., tuple[Staged, np.ndarray]]
    threads: int


@functools.cache
def kernel_set(paper: bool, threads: int) -> KernelSet:
    """The kernel set of a filter of the paper's model (``paper``) or not, on ``threads`` threads
    (1: the serial kernels). Built once per pair."""
    if threads == 1:
        enumerate_ = rbpf_enumerate if paper else rbpf_enumerate_cells
        propose = functools.partial(_propose_one_cell, rbpf_propose) if paper else \
            functools.partial(_propose_by_enumeration, enumerate_)
        return KernelSet(enumerate_, _commit_children_one_cell if paper else _commit_children_cells,
                         _commit_one_cell if paper else _commit, propose, 1)
    enumerate_ = functools.partial(_in_chunks, rbpf_parallel.rbpf_enumerate_parallel if paper else
                                   rbpf_parallel.rbpf_enumerate_cells_parallel, threads)
    stage = _stage_one_cell if paper else rbpf_parallel.rbpf_stage_children_cells_parallel
    propose = functools.partial(_propose_one_cell, functools.partial(_propose_in_threads, threads)) if paper else \
        functools.partial(_propose_by_enumeration, enumerate_)
    return KernelSet(enumerate_, functools.partial(_commit_children_in_threads, stage, threads),
                     functools.partial(_commit_in_threads, threads), propose, threads)


class ProposalBuffers(NamedTuple):
    """A sampling scheme's proposal outputs, overwritten by every step (:func:`proposal_buffers`):
    :class:`~onlinemap.kernels.rbpf_enumerate.Proposed` (locations (P,), cells (P, K) in the
    paper's model, (P, W, K) otherwise, log increments (P,)); the same writes as
    :class:`~onlinemap.kernels.rbpf_commit.Staged` (ids (P, W), cells (P, W, K): views); the terms
    (P,) of the log weights' ``logsumexp``; with blocking labels or a footprint, the enumerated
    children (2P, their cells stored) and their parents' log weights, zeros (P,) (None in the
    paper's model)."""

    proposed: Proposed
    staged: Staged
    terms: np.ndarray
    children: Children | None
    zeros: np.ndarray | None


def proposal_buffers(n_particles: int, width: int, n_labels: int, paper: bool) -> ProposalBuffers:
    """Fresh :class:`ProposalBuffers` for P = ``n_particles`` slots of W = ``width`` cells of K =
    ``n_labels`` (``paper``: one cell, the slot's location). ``8 P (K + 3)`` bytes in the paper's
    model, ``8 P (3 W K + 3 W + 12)`` otherwise (about what
    :func:`~onlinemap.estimators.rbpf_memory.state_bytes` counts as a step's buffers)."""
    p, k = n_particles, n_labels
    locations = np.empty(p, dtype=np.int64)
    if paper:
        proposed = Proposed(locations, np.empty((p, k)), np.empty(p))
        staged = Staged(locations, locations.reshape(p, 1), proposed.cells.reshape(p, 1, k), None, None)
        return ProposalBuffers(proposed, staged, np.empty(p), None, None)
    size = 2 * p
    children = Children(np.empty(size, dtype=np.int64), np.empty(size, dtype=np.int64), np.empty(size),
                        np.empty(size), np.empty((size, width), dtype=np.int64), np.empty((size, width, k)))
    proposed = Proposed(locations, np.empty((p, width, k)), np.empty(p))
    staged = Staged(locations, np.empty((p, width), dtype=np.int64), proposed.cells, None, None)
    return ProposalBuffers(proposed, staged, np.empty(p), children, np.zeros(p))


def _propose_one_cell(run: Callable, locations, pool, world, t, ancestors, neighbors, likelihood, optimal,
                      uniforms, out: ProposalBuffers) -> tuple[Staged, np.ndarray]:
    """The paper's model's proposal (``run``: ``rbpf_propose`` or :func:`_propose_in_threads`, in
    the signature of the first) into ``out``, its writes one cell each. O(P K^2)."""
    run(locations, world.p_move, t, ancestors, neighbors, likelihood, optimal, uniforms, *out.proposed, *pool)
    return out.staged, out.proposed.log_increments


def _propose_in_threads(threads: int, locations, p_move, t, ancestors, neighbors, likelihood, optimal, uniforms,
                        *fields) -> None:
    """:func:`~onlinemap.kernels.rbpf_parallel.rbpf_propose_parallel` in the signature of
    ``rbpf_propose`` (``*fields``: the :class:`Proposed` arrays, then the pool's fields), in chunks
    of the current :data:`~onlinemap.kernels.rbpf_parallel.CHUNK`."""
    proposed, pool = Proposed(*fields[:3]), Pool(*fields[3:])
    rbpf_parallel.rbpf_propose_parallel(locations, pool, p_move, t, ancestors, neighbors, likelihood, optimal, uniforms,
                                        proposed, rbpf_parallel.CHUNK, threads)


def _propose_by_enumeration(enumerate_: Callable, locations, pool, world, t, ancestors, neighbors, readings, optimal,
                            uniforms, out: ProposalBuffers) -> tuple[Staged, np.ndarray]:
    """The proposal with blocking labels or a footprint, into ``out``: the children ``enumerate_``
    gives (every parent's log weight 0, their cells stored), one drawn per slot
    (``rbpf_pick_children``). O(P F K^2)."""
    children, staged = out.children, out.staged
    m = enumerate_(locations, out.zeros, pool, world, t, neighbors, readings, children)
    rbpf_pick_children(ancestors, m, optimal, uniforms, staged.ids, *children, *out.proposed)
    return staged, out.proposed.log_increments


def _commit_children_one_cell(locations, pool, world, t, slots, child_location, neighbors, likelihood, staged) -> None:
    """``rbpf_commit_children`` in the :class:`KernelSet` signature."""
    rbpf_commit_children(locations, t, slots.ancestors, slots.slot_child, child_location, likelihood, *pool)


def _commit_children_cells(locations, pool, world, t, slots, child_location, neighbors, readings, staged) -> None:
    """``rbpf_commit_children_cells`` in the :class:`KernelSet` signature."""
    rbpf_commit_children_cells(locations, t, child_location, neighbors, readings, *slots, *world, *pool)


def _commit(locations, pool, t, ancestors, staged: Staged) -> None:
    """``rbpf_commit_cells`` of the staged writes (their ``target``, ``source`` unused)."""
    rbpf_commit_cells(locations, t, ancestors, staged.locations, staged.ids, staged.cells, *pool)


def _commit_one_cell(locations, pool, t, ancestors, staged: Staged) -> None:
    """:func:`_commit` in the paper's model, where a slot writes one cell, the one it moves to
    (its proposal's, or a recovery's: the cell it reads), without ``staged.ids``."""
    rbpf_commit_cells(locations, t, ancestors, staged.locations, None, staged.cells, *pool)


def _in_chunks(run: Callable, threads: int, *args):
    """``run(*args, CHUNK, threads)``: a threaded driver, in chunks of the current
    :data:`~onlinemap.kernels.rbpf_parallel.CHUNK`."""
    return run(*args, rbpf_parallel.CHUNK, threads)


def _commit_in_threads(threads: int, locations, pool, t, ancestors, staged: Staged) -> None:
    """:func:`~onlinemap.kernels.rbpf_parallel.rbpf_commit_staged_parallel` (looked up when it runs)."""
    rbpf_parallel.rbpf_commit_staged_parallel(locations, pool, t, ancestors, staged, rbpf_parallel.CHUNK, threads)


def _stage_one_cell(locations, pool, world, t, slots, child_location, neighbors, likelihood, staged, chunk,
                    threads) -> None:
    """``rbpf_stage_children_parallel`` in the signature of ``rbpf_stage_children_cells_parallel``."""
    rbpf_parallel.rbpf_stage_children_parallel(pool, t, slots, child_location, likelihood, staged, chunk, threads)


def _commit_children_in_threads(stage: Callable, threads: int, locations, pool, world, t, slots, child_location,
                                neighbors, observation, staged) -> None:
    """The kept children's writes staged from their parents' rows on the threads (``stage``), then
    committed (:func:`~onlinemap.kernels.rbpf_parallel.rbpf_commit_staged_parallel`: the serial
    commit's state)."""
    chunk = rbpf_parallel.CHUNK
    stage(locations, pool, world, t, slots, child_location, neighbors, observation, staged, chunk, threads)
    rbpf_parallel.rbpf_commit_staged_parallel(locations, pool, t, slots.ancestors, staged, chunk, threads)


class FCBuffers(NamedTuple):
    """One Fearnhead-Clifford step's working arrays (views of the filter's scratch buffers): the
    children (2P), their weights (2P,), the order their strata walk, the kept children and their
    weights (P,), and the slots (P,)."""

    children: Children
    child_weight: np.ndarray
    order: np.ndarray
    kept: np.ndarray
    kept_weights: np.ndarray
    slots: Slots


def fc_buffers(ints: np.ndarray, floats: np.ndarray, n_particles: int, width: int, n_labels: int) -> FCBuffers:
    """Views of scratch buffers ``ints`` (5, 2P) int64 and ``floats`` (3, 2P) as
    :class:`FCBuffers`; the children store no cells (W = ``width`` cells of K = ``n_labels``). O(1)."""
    p = n_particles
    children = Children(ints[0], ints[1], floats[0], *_no_cells(width, n_labels))
    return FCBuffers(children, floats[1], ints[2], ints[3, :p], floats[2, :p],
                     Slots(ints[3, p:], ints[4, :p], floats[2, p:]))


def staged_buffers(ints: np.ndarray, cells: np.ndarray, n_particles: int, width: int) -> Staged | None:
    """The threads' staging of a step's writes (P slots of W = ``width`` cells): views of scratch
    buffers ``ints`` (P (3 W + 1),) int64 and ``cells`` (P, W, K); None when they are empty (no
    threads). O(1)."""
    p = n_particles
    if not len(ints):
        return None
    new_ids, target, source = (ints[i * p * width:(i + 1) * p * width].reshape(p, width) for i in range(3))
    return Staged(ints[3 * p * width:], new_ids, cells, target, source)


class StepKit(NamedTuple):
    """What every step of one filter reads and no step changes, built once per filter
    (:func:`step_kit`): P, W (the cells a particle's step writes), the threads, the options a step
    reads (``optimal``: the optimal proposal; ``threshold``: ``resample_threshold``; ``eager``: C
    applied to every block row every step, a dynamic world with ``lazy_dynamics`` False), the
    model's :class:`~onlinemap.kernels.rbpf.World`, the serial and the threaded
    :class:`KernelSet`, ``identity`` (``arange(P)``, the ancestors of a step that does not
    resample: never written), the Fearnhead-Clifford buffers (None for the sampling schemes), the
    sampling schemes' :class:`ProposalBuffers` (None for Fearnhead-Clifford), the threads'
    staging (None on one thread) and ``neighbours``, the grid's (N, 4) neighbour table that the
    label priors ``"context"`` and ``"particle_context"`` read (None with the other priors; derived
    from the model, so never in a checkpoint). A step then reads its arrays, options and kernels
    here: no per-step lookups of options or rebuilt bundles and arrays (each some tenths of a
    microsecond to microseconds, which a step of a few hundred particles pays in full)."""

    n_particles: int
    width: int
    threads: int
    optimal: bool
    threshold: float
    eager: bool
    world: World
    serial: KernelSet
    threaded: KernelSet
    identity: np.ndarray
    fc: FCBuffers | None
    proposal: ProposalBuffers | None
    staged: Staged | None
    neighbours: np.ndarray | None

    def fc_buffers(self, n_labels: int) -> FCBuffers:
        """Fearnhead-Clifford's buffers: the filter's or, for a sampling scheme's step that
        enumerates (every draw missed), fresh arrays (such a filter keeps none)."""
        if self.fc is not None:
            return self.fc
        p = self.n_particles
        return fc_buffers(np.empty((5, 2 * p), dtype=np.int64), np.empty((3, 2 * p)), p, self.width, n_labels)

    def kernels(self) -> KernelSet:
        """The kernel set a step runs: the threaded one with threads and more particles than one
        chunk (the current :data:`~onlinemap.kernels.rbpf_parallel.CHUNK`: fewer would run on one
        thread anyway, the same results at the threads' overhead), else the serial one."""
        return self.threaded if self.threads > 1 and self.n_particles > rbpf_parallel.CHUNK else self.serial


def scratch_buffers(n_particles: int, width: int, n_labels: int, fc: bool, threads: int) -> tuple[np.ndarray, ...]:
    """A filter's four scratch buffers, zeroed: ``ints`` (5, 2P) and ``floats`` (3, 2P) of
    :func:`fc_buffers` (0 rows without Fearnhead-Clifford, ``fc``), and the staging's ``ints``
    (P (3 W + 1),) and ``cells`` (P, W, K) of :func:`staged_buffers` (empty on one thread)."""
    staged = n_particles if threads > 1 else 0
    return (np.zeros((5 if fc else 0, 2 * n_particles), dtype=np.int64), np.zeros((3 if fc else 0, 2 * n_particles)),
            np.zeros(staged * (3 * width + 1), dtype=np.int64), np.zeros((staged, width, n_labels)))


def step_kit(model: GridModel, n_particles: int, width: int, threads: int, optimal: bool, threshold: float,
             lazy_dynamics: bool, scratch: tuple[np.ndarray, ...], neighbours: np.ndarray | None) -> StepKit:
    """A filter's :class:`StepKit` from its model, P, W, threads, options (``optimal``: the optimal
    proposal; ``threshold``: ``resample_threshold``; ``lazy_dynamics``), its four scratch
    buffers (``ints``, ``floats`` of :func:`fc_buffers`, empty for a sampling scheme, which gets
    :func:`proposal_buffers` instead; the staging's ``ints`` and ``cells`` of
    :func:`staged_buffers`) and its label prior's ``neighbours`` (N, 4) or None. O(P), or O(P W K)
    for a sampling scheme's proposal buffers."""
    ints, floats, staged_ints, staged_cells = scratch
    paper = model.is_paper_model
    fc = fc_buffers(ints, floats, n_particles, width, model.n_labels) if len(ints) else None
    proposal = None if fc is not None else proposal_buffers(n_particles, width, model.n_labels, paper)
    eager = not model.is_static and not lazy_dynamics
    return StepKit(n_particles, width, threads, optimal, threshold, eager, world_tables(model), kernel_set(paper, 1),
                   kernel_set(paper, threads), np.arange(n_particles), fc, proposal,
                   staged_buffers(staged_ints, staged_cells, n_particles, width), neighbours)


@functools.cache
def _no_cells(width: int, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Empty (log motion, ids (0, W), cells (0, W, K)) of :class:`~onlinemap.kernels.rbpf_enumerate.Children`
    that store no child's cells (never written: 0 rows), made once per shape."""
    return np.empty(0), np.empty((0, width), dtype=np.int64), np.empty((0, width, k))


def thread_count(threads) -> int:
    """The ``threads`` option as a count, 1 to ``NUMBA_NUM_THREADS`` (None: all of them)."""
    most = numba.config.NUMBA_NUM_THREADS
    if threads is None:
        return most
    if type(threads) is int and 1 <= threads <= most:  # a valid count, as checked below
        return threads
    return arguments.integer(f"threads (at most NUMBA_NUM_THREADS={most}: the cores numba counts, or that "
                             "environment variable set before numba starts)", threads, minimum=1, maximum=most,
                             error=InvalidOptionError)


def no_moves(n: int) -> np.ndarray:
    """Read-only ``arange(n)``, the neighbours at step 0 (every cell stays): the same numba type as
    a row of ``model.moves``, so each kernel is compiled once for both."""
    return read_only(np.arange(n))
