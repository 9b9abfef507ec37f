"""The buffers of the footprint rollouts (:func:`policies.kernels.footprint.plan_rollouts`): the
rollout states with their particles' overlays, a filter step's scratch, the candidates' groups;
allocated in Python for the kernels (``onlinemap.kernels.aligned``), and kept by a caller
between plans (:class:`KeptBuffers`, :func:`kept_works`): a plan leaves every overlay empty, so the next one starts
from them as from new buffers, without filling C R N overlay indices and touching megabytes of
fresh pages (at 32 x 32, 8 candidates, R = 64: 3.7 ms of an 80 ms plan, measured).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from onlinemap.kernels import aligned

from .mixture import Mixture, mixture_scratch


class Overlays(NamedTuple):
    """The overlays of R particles' maps (:mod:`policies.kernels.footprint`), with a leading (S',)
    axis for S' rollout states or of one state: ``index`` (R, N) a cell's slot or -1,
    ``cell``/``stamp`` (R, W), ``val`` (R, W, K), ``n`` (R,) slots used, ``touched`` (N,) and
    ``touched_list`` (R W,) the cells some particle wrote."""

    index: np.ndarray
    cell: np.ndarray
    val: np.ndarray
    stamp: np.ndarray
    n: np.ndarray
    touched: np.ndarray
    touched_list: np.ndarray


class States(NamedTuple):
    """S' rollout states: particles ``loc``/``lw`` (S', R), the world's ``labels`` (S', N) and
    ``where`` (S',), the touched cells' counts ``n_touched`` (S',), the :class:`Overlays`."""

    loc: np.ndarray
    lw: np.ndarray
    labels: np.ndarray
    where: np.ndarray
    n_touched: np.ndarray
    overlays: Overlays


class StepScratch(NamedTuple):
    """Scratch of a filter step, row s for successor s (0 stay, 1 move): ``ids`` (2, F + 1) the
    cells it changes, ``cells`` (2, F + 1, K) their marginals, ``before`` (2, K) the cell pressed
    towards, ``lams``/``slots`` (2, F) each read's likelihood and row; ``readings`` (F,)."""

    ids: np.ndarray
    cells: np.ndarray
    before: np.ndarray
    lams: np.ndarray
    slots: np.ndarray
    readings: np.ndarray


class Groups(NamedTuple):
    """Candidate c's ``group`` (the candidates that pressed alike so far) and ``action`` (C,);
    ``parted`` (A,) the group a press parts into at one step; ``pending`` (C, 3) groups to roll
    out (group, state, first step); ``free`` (C,) states not in use, the last freed on top."""

    group: np.ndarray
    action: np.ndarray
    parted: np.ndarray
    pending: np.ndarray
    free: np.ndarray


class Work(NamedTuple):
    """Everything one thread of ``plan_rollouts`` rolls its worlds out in."""

    states: States
    step: StepScratch
    mixture: Mixture
    groups: Groups


def empty_overlays(n_states, r_count, n_cells, k, horizon, n_reads):
    """Empty :class:`Overlays` of R particles' maps for ``n_states`` rollout states (each particle
    writes at most H (F + 1) cells: W = max(H, 1) (F + 1)). O(S' R (N + W K))."""
    width = max(horizon, 1) * (n_reads + 1)
    return Overlays(aligned((n_states, r_count, n_cells), np.int32, -1),
                    aligned((n_states, r_count, width), np.int64), aligned((n_states, r_count, width, k)),
                    aligned((n_states, r_count, width), np.int64, 0),
                    aligned((n_states, r_count), np.int64, 0), aligned((n_states, n_cells), np.bool_, 0),
                    aligned((n_states, r_count * width), np.int64))


def step_scratch(n_reads, k):
    """A filter step's scratch (:class:`StepScratch`) for F = ``n_reads`` readings."""
    return StepScratch(aligned((2, n_reads + 1), np.int64), aligned((2, n_reads + 1, k)), aligned((2, k)),
                       aligned((2, n_reads)), aligned((2, n_reads), np.int64), aligned(n_reads, np.int64))


def rollout_work(particles, world, candidates, agreement, labels_dtype):
    """The buffers one thread rolls its worlds out in (:class:`Work`): C rollout states, a filter
    step's scratch, the mixture's and the groups'. O(C R (N + H F K) + R D K)."""
    r_count, n_cells, k = particles.maps.shape
    n_seq, horizon = candidates.sequences.shape
    n_reads = world.footprint_cells.shape[1]
    states = States(aligned((n_seq, r_count), np.int64), aligned((n_seq, r_count)),
                    aligned((n_seq, n_cells), labels_dtype), aligned(n_seq, np.int64),
                    aligned(n_seq, np.int64, 0), empty_overlays(n_seq, r_count, n_cells, k, horizon, n_reads))
    groups = Groups(aligned(n_seq, np.int64), aligned(n_seq, np.int64),
                    aligned(world.moves.shape[0], np.int64), aligned((n_seq, 3), np.int64),
                    aligned(n_seq, np.int64))
    return Work(states, step_scratch(n_reads, k), mixture_scratch(particles.maps, agreement.disputed), groups)


class KeptBuffers:
    """The rollout buffers a caller keeps from plan to plan (never two plans at once):
    ``works`` the threads' :class:`Work` of the last plan and ``key`` the shapes and dtype they
    were made for (:func:`kept_works`); none (``key`` None, ``works`` empty) when new or
    :meth:`clear`-ed."""

    __slots__ = ("key", "works")

    def __init__(self) -> None:
        self.key: tuple | None = None
        self.works: list[Work] = []

    def clear(self) -> None:
        """Drop the buffers (a plan cut short may leave overlays written): the next plan takes new ones."""
        self.key, self.works = None, []


def kept_works(kept, count, particles, world, candidates, agreement, labels_dtype):
    """``count`` threads' buffers (:func:`rollout_work`): those of ``kept`` (a
    :class:`KeptBuffers`, or None) while every shape is the same, with the mixture's scratch
    anew (it holds the particles' disputed cells); else new ones, then kept. Only a plan that ran
    to its end leaves the overlays empty: one cut short must ``kept.clear()``. O(R D K + N K)
    reused, O(count C R (N + H F K)) new."""
    key = (count, particles.maps.shape, world.footprint_cells.shape, world.moves.shape, candidates.sequences.shape,
           np.dtype(labels_dtype))
    if kept is not None and kept.key == key:
        works = [w._replace(mixture=mixture_scratch(particles.maps, agreement.disputed)) for w in kept.works]
    else:
        works = [rollout_work(particles, world, candidates, agreement, labels_dtype) for _ in range(count)]
    if kept is not None:
        kept.key, kept.works = key, works
    return works
