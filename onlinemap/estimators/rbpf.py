"""Rao-Blackwellised particle filter (DESIGN.md section 3, ``rbpf``).

Each of P particles holds one trajectory of the robot and the exact map marginals given it.
Given a trajectory the cells are independent (each is a hidden Markov chain with transition C,
observed through O only at the steps the robot read it), so a particle's map is N marginals of
K labels: only the read cells change by the sensor (and, with blocking labels, the cell a move
tried to enter); all cells drift by C, applied lazily (``C^dt`` for the ``dt`` steps since the
cell was last brought up to date, when it is next read), so a dynamic world costs the same per
step as a static one. The trajectories are chosen by Fearnhead-Clifford's enumeration (the
default) or sampled from a proposal (the class docstring).

State (plain attributes): locations (P,), normalised log weights (P,), the particles' maps as
shared copy-on-write blocks of B cells (``_blocks``, a
:class:`~onlinemap.estimators.block_pool.BlockPool`, with its invariants), a
``numpy.random.Generator``. Each step also refreshes a few block rows in turn (the same values,
brought up to date), so that no stamp is more than ``REFRESH_STEPS`` old and the table of powers
of C stays bounded: O(R_used B K^2 / REFRESH_STEPS) per step. The kernels a filter runs are
chosen once by its model and threads (:mod:`onlinemap.estimators.rbpf_kernels`).

Cost per step: O(P K^2) for the proposal and weighting (a particle reads its cell and the
intended neighbour; O(P F K^2) for a footprint of F cells) plus O(P B K) at most for
copy-on-write of shared blocks (O(P W B K), W = F + 1 cells written); a resampling step adds
O(P_dropped N / B) (table rows copied, not maps); Fearnhead-Clifford adds O(P + N) to keep P of
its 2P children. ``belief.location`` is O(P + N); ``belief.map`` (the weighted mixture) is
O(P N / B) plus one pass over the block rows in use (K^2 flops per out-of-date cell in a dynamic
world), built on first access of ``belief`` (:meth:`RaoBlackwellisedPF.update` does not build
it). Memory: the block rows in use (at most ``8 P N (K + 1)`` bytes), ``8 P N / B`` for the
table, ``32 K^2 REFRESH_STEPS`` for the powers of C and the step's buffers
(:mod:`onlinemap.estimators.rbpf_memory`, the guard ``max_bytes``). Measured (``onlinemap bench
rbpf``, rows ``per particle``): an update 0.26-0.35 us of CPU per particle at 10^4-10^5 particles
on the 10 x 10 door world, the belief 0.07. With ``threads`` the drivers of
:mod:`onlinemap.kernels.rbpf_parallel` run the same kernels on runs of particles at once (the
same results). A recovery from depletion weighs N P children
(:mod:`onlinemap.estimators.rbpf_recovery`); resample-move costs O(P W S (F K + 1)) every
``move_every`` steps and a path history of up to 2 P t bytes (:mod:`onlinemap.estimators.rbpf_move`).
"""

from __future__ import annotations

import functools
import logging
import math
from types import MappingProxyType
from typing import NamedTuple

import numba
import numpy as np

from .. import arguments
from ..arrays import DEFAULT_MAX_BYTES, read_only
from ..belief import Belief
from ..errors import ImpossibleObservationError, InvalidOptionError, ModelError
from ..label_prior import DEFAULT_LEARN_EVERY, LEARN, shown_options
from ..kernels import rbpf_parallel
from ..kernels.rbpf import in_place_ancestors
from ..kernels.rbpf_commit import Slots, Staged, rbpf_keep_children
from ..kernels.rbpf_enumerate import Children
from ..model import GridModel
from ..resampling import RESAMPLERS, effective_sample_size
from ..rng import SeedLike, as_generator
from ..validation import check_step
from .base import BooleanFlag, register
from .block_pool import BlockPool, block_layout
from .rbpf_kernels import KernelSet, kernel_set, observed, world_tables
from .rbpf_memory import Sizing, cells_written, check_growth, check_recovery, check_start
from .rbpf_move import (MoveCounts, PathHistory, map_rows_per_move, move_options, move_scratch_bytes,
                        path_rows_per_move)
from .rbpf_prior import learn, prior_options, resolved_prior, retilt
from .rbpf_recovery import RELOCATION_SCALE, describe, impossible, logsumexp, no_particle_explains, relocate
from .rbpf_state import check_state, upgrade_attributes

logger = logging.getLogger(__name__)

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


@register("rbpf")
class RaoBlackwellisedPF:
    """RBPF over trajectories with exact per-cell map marginals.

    Options: ``n_particles`` (P); ``resampling``:

    - ``"fearnhead_clifford"`` (Fearnhead and Clifford 2003; the default with the optimal
      proposal): every step enumerates each particle's successors (stay, move) with their exact
      weights and keeps P of them by optimal resampling, none twice. It starts from one particle
      and keeps every child while there are at most P (so with P >= 2^T it is exact Bayes).
      Measured (``onlinemap bench rbpf``): 0.23-0.39x the TV to exact of the optimal proposal
      with residual resampling at equal particles, for 1.05-1.5x the time per step.
    - ``"residual"``, ``"systematic"``, ``"stratified"``, ``"multinomial"``: sample one
      successor per particle from ``proposal`` — ``"optimal"`` (given the observation; lower
      weight variance) or ``"transition"`` (the motion model) — and resample by that scheme
      before a step when the effective sample size is below ``resample_threshold`` times P
      (1.0 = every step, 0.0 = never). ``None`` picks ``"residual"`` for the transition proposal.

    ``seed`` (int, None or Generator);
    ``lazy_dynamics`` (False applies C to every cell of every particle every step: O(P N K^2),
    the reference the lazy scheme is tested against); ``block_cells`` B, the cells per shared
    map block (:func:`~onlinemap.estimators.block_pool.block_shape`; default about sqrt(N / K));
    ``max_bytes``, the guard on the filter's memory (:mod:`onlinemap.estimators.rbpf_memory`),
    checked when it starts, whenever the pool of map blocks must grow (particles share fewer
    blocks as their trajectories part) and before a recovery: a step that would take the filter
    beyond it raises :class:`~onlinemap.errors.MemoryLimitError` and leaves the filter as it was;
    raise ``est.max_bytes`` to continue.

    **Recovery from depletion.** When no particle explains an observation the model allows, the
    step does not raise. A sampling step whose draws all miss first enumerates the particles'
    successors as Fearnhead-Clifford does; when those all have weight zero too (with
    Fearnhead-Clifford, when its enumeration is empty) the filter *recovers*: it takes the exact
    limit of a model in which the robot may be lifted and put down near its last cell, and a cell
    it then reads redrawn from its model marginal (:mod:`onlinemap.estimators.rbpf_recovery`, the
    math and the cost; ``RELOCATION_SCALE`` = 3 cells). The step's belief has ``recovered=True``,
    :attr:`recoveries` counts such steps (checkpointed), and a warning on the logger
    ``onlinemap.estimators.rbpf`` names the step and what was done. Only an observation nothing
    explains even so (step 0, where there is no motion; or no cell of the grid, with labels the
    model allows at step t, sees it) raises :class:`ImpossibleObservationError`, the state
    unchanged. Steps that do not deplete take the same numbers and random draws as a filter
    without recovery. Setting the attribute ``recover_from_depletion = False`` (checkpointed with
    the state) makes a depleted step raise :class:`ImpossibleObservationError` instead, the state
    unchanged: for hypothetical steps (a planner enumerating observations gives those the
    particles rule out probability zero) or to stop a run rather than relocate.

    **Resample-move** (``move_window``, ``move_every``, ``move_lag``; off by default, Gilks and
    Berzuini 2001; the math in :mod:`onlinemap.estimators.rbpf_move`). With ``move_window`` = W
    (1 to 1000), every ``move_every`` steps (default 10, the best measured), after the step's update, each live
    particle redraws W consecutive past locations, the window ending at least ``move_lag`` steps
    back (default 100; 0 lets it end at t), by a Metropolis-Hastings move whose invariant law is
    the posterior over paths. Weights, the evidence and the streaming contract are unchanged
    (``step`` returns the belief at t). Moves wait until the filter is not exact
    (Fearnhead-Clifford has dropped a child), so with room for every child (P >= 2^T) the filter
    is bit for bit the filter without moves. It needs a static world, no blocking labels and a
    sensor without zero entries: ``move_window`` is refused otherwise
    (:class:`~onlinemap.errors.InvalidOptionError` naming the reason). The filter keeps every
    particle's path and every step's action and readings: up to 2 P t bytes more, counted by
    ``max_bytes``. :attr:`moves` counts the windows proposed and accepted (checkpointed). What it
    buys: on the paper's world replay at 1,000 particles (W = 20, every 5) the final map error
    falls from 0.26 to about 0.20 for 3.2x the time per step (the user guide's Estimators page, RBPF section).

    **Label prior** (``label_prior``, ``prior_strength``, ``learn_every``; :mod:`onlinemap.label_prior`,
    the math in :mod:`onlinemap.estimators.rbpf_prior`). None (the default): what the model says,
    ``"learn"`` on a model whose label frequencies are unknown (generated buildings, floors read
    from files) in a static world without ``move_window``, the model's prior table otherwise
    (the paper's worlds: every run as without the option). ``"model"``: the model's table
    always. A (K,) frequency vector: every cell's prior is the model's
    tilted by it, ``normalise(prior_i * v)`` (``v`` itself under the default uniform prior).
    ``"learn"`` (static worlds only): the frequencies, under a Dirichlet of total pseudo-count
    ``prior_strength`` (default K), are re-estimated every ``learn_every`` steps (default 10) from
    the expected labels of the cells read so far, and every cell's prior is moved to them (one
    pass over the block rows in use): the plug-in (empirical Bayes) approximation of the
    hierarchical model the exact filter computes exactly; particle weights are not changed.
    :attr:`label_frequencies` gives the current frequencies (checkpointed). Refused with
    ``move_window``.

    ``threads``: how many threads the update and the belief use, at most ``NUMBA_NUM_THREADS``
    (None: all; Python threads on numba kernels that release the GIL,
    :mod:`onlinemap.kernels.rbpf_parallel`), the results the same bit for bit whatever the number.
    The default, 1, runs the serial kernels: threads pay from about 10^4 particles and only on
    cores nothing else uses.
    """

    #: attributes fixed by the model and options, checked equal on load (:mod:`onlinemap.state_checks`)
    CONSTANT_STATE = ("n_particles", "proposal", "resampling", "resample_threshold", "lazy_dynamics", "move_window",
                      "move_every", "move_lag",
                      "_blocks.stamped", "_blocks.cell_block", "_blocks.cell_slot", "_blocks.block_members",
                      "_blocks.powers")

    #: per-step buffers (:meth:`_fc_buffers`, :meth:`_staged_buffers`), overwritten by every step
    #: before being read: not state (a checkpoint records their dtype and shape only)
    #: False: a depleted step raises instead of recovering (see above); a bool, checked when set
    recover_from_depletion = BooleanFlag()

    scratch_attributes = ("_scratch_ints", "_scratch_floats", "_scratch_staged_ints", "_scratch_staged_cells")

    #: label_prior="learn"'s current label frequencies (K,): an attribute of such a filter only (and
    #: of its checkpoints); None, this class default, for the other filters, whose state is as without the option
    _label_frequencies: np.ndarray | None = None

    #: what the placeholder defaults run with the other defaults (estimator_options shows these)
    resolved_defaults = MappingProxyType({"resampling": FEARNHEAD_CLIFFORD})

    def __init__(self, model: GridModel, *, n_particles: int = 100, proposal: str = "optimal",
                 resampling: str | None = None, resample_threshold: float = 0.5, seed: SeedLike = None,
                 lazy_dynamics: bool = True, block_cells: int | None = None,
                 max_bytes: int = DEFAULT_MAX_BYTES, threads: int | None = 1, move_window: int | None = None,
                 move_every: int = 10, move_lag: int = 100, label_prior=None, prior_strength=None,
                 learn_every: int | None = None):
        error = InvalidOptionError
        n_particles = arguments.integer("n_particles", n_particles, minimum=1, error=error)
        proposal, resampling = _scheme(proposal, resampling)
        resample_threshold = arguments.probability("resample_threshold", resample_threshold, error)
        seed = arguments.seed("seed", seed, error)
        lazy_dynamics = arguments.flag("lazy_dynamics", lazy_dynamics, error)
        if not model.is_paper_model and not lazy_dynamics and not model.is_static:
            raise error("lazy_dynamics=False (the eager reference) does not support blocking labels or a sensor "
                        "footprint")
        if block_cells is not None:
            block_cells = arguments.integer("block_cells", block_cells, minimum=1, maximum=model.n_cells, error=error)
        max_bytes = arguments.byte_limit("max_bytes", max_bytes, error)
        threads = _thread_count(threads)
        move_window, move_every, move_lag = move_options(model, move_window, move_every, move_lag)
        prior = prior_options(model, label_prior, prior_strength, learn_every, move_window)
        check_start(Sizing(model, n_particles, lazy_dynamics, threads, max_bytes), block_cells, move_window)
        layout = block_layout(model, block_cells)
        self.model = model
        self.n_particles = n_particles
        self.proposal = proposal
        self.resampling = resampling
        self.resample_threshold = float(resample_threshold)
        self.lazy_dynamics = bool(lazy_dynamics)
        self.move_window, self.move_every, self.move_lag = move_window, move_every, move_lag
        self._rng = as_generator(seed)
        self._locations = np.full(n_particles, model.start, dtype=np.int64)
        self._log_weights = np.full(n_particles, -math.log(n_particles))
        if resampling == FEARNHEAD_CLIFFORD:  # one particle: the others would enumerate the same children
            self._log_weights[:] = -math.inf
            self._log_weights[0] = 0.0
        self._weights = np.exp(self._log_weights)  # exp(_log_weights), kept beside them
        self._blocks = BlockPool.new(model, layout, n_particles, not model.is_static and self.lazy_dynamics)
        if prior.kind == "fixed":  # every cell's prior tilted by the vector (rbpf_prior.py)
            retilt(self._blocks, prior.frequencies)
        elif prior.kind == LEARN:  # pi_0 = alpha / A, uniform: the rows as they are
            self._label_frequencies = prior.alpha / prior.alpha.sum()
        fc = resampling == FEARNHEAD_CLIFFORD
        # the resample-move step's paths (rbpf_move.py); None without it
        self._history = None if move_window is None else PathHistory.new(model, n_particles, exact=fc)
        self._scratch_ints = np.zeros((5 if fc else 0, 2 * n_particles), dtype=np.int64)
        self._scratch_floats = np.zeros((3 if fc else 0, 2 * n_particles))
        staged = n_particles if threads > 1 else 0  # the parallel commit's staging
        width = cells_written(model)
        self._scratch_staged_ints = np.zeros(staged * (3 * width + 1), dtype=np.int64)
        self._scratch_staged_cells = np.zeros((staged, width, model.n_labels))
        self._log_evidence = 0.0
        self._ess = float(n_particles)
        self._resampled = False
        self.recover_from_depletion = True  # False: raise on depletion (see the class docstring)
        self._recoveries = 0
        self._recovered = False
        self._t = -1
        self._belief: Belief | None = None

    #: a checkpoint's attributes of an older format as the current one has them, and the
    #: invariants of a restored state (:mod:`onlinemap.estimators.rbpf_state`)
    upgrade_attributes = staticmethod(upgrade_attributes)
    check_state = staticmethod(check_state)

    @property
    def threads(self) -> int:
        """The number of threads the update and the belief use (the ``threads`` option; with None,
        ``NUMBA_NUM_THREADS``)."""
        return _thread_count(self.options["threads"])

    @property
    def _parallel(self) -> bool:
        """Whether a step runs the parallel kernels: with threads, and more particles than one
        chunk (:data:`~onlinemap.kernels.rbpf_parallel.CHUNK`; fewer would run on one thread
        anyway, the same results at the threads' overhead)."""
        return self.threads > 1 and self.n_particles > rbpf_parallel.CHUNK

    @property
    def max_bytes(self) -> int | float:
        """The guard on the filter's memory (the ``max_bytes`` option). Setting it (to continue
        after a :class:`~onlinemap.errors.MemoryLimitError`) changes the option: a checkpoint then
        records the new value."""
        return self.options["max_bytes"]

    @max_bytes.setter
    def max_bytes(self, value) -> None:
        self.options["max_bytes"] = arguments.byte_limit("max_bytes", value, InvalidOptionError)

    @property
    def resampled(self) -> bool:
        """Whether the last step resampled before proposing."""
        return self._resampled

    @property
    def effective_options(self) -> dict:
        """The options as the filter runs them: ``resampling`` resolved (None picks
        Fearnhead-Clifford for the optimal proposal, residual for the transition one), and no
        ``resample_threshold`` under Fearnhead-Clifford, which resamples every step whatever it
        says, and no resample-move options without moves (``move_window`` None). What ``repr``
        and ``onlinemap track``'s start event show; ``options`` keeps what was given (checkpoints
        compare it)."""
        options = {**self.options, "resampling": self.resampling}
        if self.resampling == FEARNHEAD_CLIFFORD:
            options.pop("resample_threshold", None)
        if self.move_window is None:
            for name in ("move_window", "move_every", "move_lag"):
                options.pop(name, None)
        return shown_options(options, resolved_prior(self.model, self.options).kind)

    @property
    def particles(self) -> np.ndarray:
        """(P,) every particle's location, a read-only copy (filterpy's and ``particles``' name).
        Under Fearnhead-Clifford the filter starts from one particle: the others have weight 0
        until there are children enough for every slot."""
        return read_only(self._locations.copy())

    @property
    def weights(self) -> np.ndarray:
        """(P,) the particles' normalised weights, a read-only copy."""
        return read_only(self._weights / self._weights.sum())

    @property
    def label_frequencies(self) -> np.ndarray | None:
        """(K,) the label frequencies every cell's prior is tilted by, a read-only copy: the current
        estimate with ``label_prior="learn"``, the given vector, or None (the model's own prior)."""
        if self._label_frequencies is not None:
            return read_only(self._label_frequencies.copy())
        fixed = resolved_prior(self.model, self.options).frequencies
        return None if fixed is None else read_only(fixed.copy())

    @property
    def recoveries(self) -> int:
        """How many steps so far recovered from depletion (see the class docstring)."""
        return self._recoveries

    @property
    def moves(self) -> MoveCounts:
        """The resample-move step's windows proposed and accepted so far (zeros without
        ``move_window``; see the class docstring)."""
        history = self._history
        return MoveCounts(0, 0) if history is None else MoveCounts(history.proposed, history.accepted)

    @property
    def belief(self) -> Belief | None:
        """The weighted mixture after the last step, built on first access and cached (cost: see
        the module docstring; at most one pass over P N K floats)."""
        if self._belief is None and self._t >= 0:
            weights = self._weights / self._weights.sum()
            location = np.bincount(self._locations, weights=weights, minlength=self.model.n_cells)
            location /= location.sum()  # rounding: keep every probability <= 1
            maps = self._blocks.mixture(self._t, weights, self.threads if self._parallel else 1)
            maps /= maps.sum(axis=1, keepdims=True)
            live = self._locations[self._weights > 0]
            distinct = int(np.count_nonzero(np.bincount(live, minlength=self.model.n_cells)))
            self._belief = Belief(self._t, location, maps, self._log_evidence, effective_sample_size=self._ess,
                                  recovered=self._recovered, distinct_locations=distinct)
        return self._belief

    def particle_maps(self, which=None) -> np.ndarray:
        """(M, N, K) the current map marginals of particles ``which`` (M,) (indices into
        :attr:`particles`; None: all P of them), a fresh array. O(M N K^2)."""
        if which is not None:
            indices = np.asarray(which)
            if indices.ndim != 1 or indices.dtype.kind not in "iu" or \
                    (indices.size and not 0 <= indices.min() <= indices.max() < self.n_particles):
                raise ModelError(f"which must be a 1-d array of particle indices in 0..{self.n_particles - 1}, "
                                 f"got {which!r}")
            which = indices.astype(np.int64)
        return self._blocks.particle_maps(max(self._t, 0), which)

    def step(self, action, observation) -> Belief:
        """``update`` then ``belief``."""
        self.update(action, observation)
        return self.belief

    def update(self, action, observation) -> None:
        """Advance the particles by one action (None at step 0) and observation: resample first if
        due, then propose, weight and update each particle's observed cells; on depletion, recover
        (:meth:`_recover`). An observation nothing explains (:class:`ImpossibleObservationError`)
        or a step beyond ``max_bytes`` (:class:`~onlinemap.errors.MemoryLimitError`) leaves
        everything (particles, weights, random generator) as it was. With ``move_window``, the step
        is then recorded in the path history and, when due, followed by the resample-move step."""
        a, z = check_step(self.model, self._t + 1, action, observation)
        t = self._t + 1
        if self.resampling == FEARNHEAD_CLIFFORD:
            self._update_fearnhead_clifford(a, z, t)
        else:
            self._update_sampling(a, z, t)
        history = self._history
        if history is not None:  # the step is taken: its record, then the resample-move step if due
            history.record_step(t, a, z)
            if history.move_due(t, self.move_window, self.move_every, self.move_lag):
                self._history, self._blocks = history.move(self._blocks, self._locations, self._log_weights,
                                                           self.model, t, self.move_window, self.move_lag, self._rng)
        frequencies = self._label_frequencies
        if frequencies is not None and t % (self.options["learn_every"] or DEFAULT_LEARN_EVERY) == 0:
            alpha = resolved_prior(self.model, self.options).alpha
            self._label_frequencies = learn(self._blocks, self.model, t, self._weights / self._weights.sum(),
                                            frequencies, alpha, self.threads if self._parallel else 1)

    def _update_sampling(self, a: int | None, z, t: int) -> None:
        """:meth:`update` with a sampling scheme (``a``, ``z`` checked): resample if due, propose,
        weight, commit; when every draw missed, :meth:`_update_fearnhead_clifford` instead."""
        model = self.model
        blocks = self._step_pool(t, a)
        rng_state = self._rng.bit_generator.state
        n_particles = self.n_particles
        log_weights = self._log_weights
        ancestors = np.arange(n_particles)
        resample = a is not None and (self.resample_threshold >= 1.0 or
                                      self._ess < self.resample_threshold * n_particles)
        if resample:
            chosen = RESAMPLERS[self.resampling](self._weights, self._rng)
            ancestors = in_place_ancestors(np.bincount(chosen, minlength=n_particles))
            log_weights = np.full(n_particles, -math.log(n_particles))
        staged, log_increments = self._kernels.propose(self._locations, blocks.arrays(), world_tables(model), t,
                                                       ancestors, self._neighbors(a), observed(model, z),
                                                       self.proposal == "optimal", self._rng.random(n_particles))
        log_weights = log_weights + log_increments
        increment = logsumexp(log_weights)
        if increment == -math.inf:  # every draw missed: enumerate the particles' successors instead
            self._rng.bit_generator.state = rng_state
            logger.info("rbpf step %d: every particle's proposal has probability zero for observation %s; the "
                        "step enumerates the particles' successors instead (as Fearnhead-Clifford does)", t,
                        describe(model, z))
            self._update_fearnhead_clifford(a, z, t)
            return
        self._commit(t, blocks, ancestors, staged, log_weights - increment, increment, resample)

    @property
    def _kernels(self) -> KernelSet:
        """The filter's kernel set (:func:`~onlinemap.estimators.rbpf_kernels.kernel_set`): fixed by
        the model and the options (looked up, not stored: a checkpoint holds state, not code)."""
        return kernel_set(self.model.is_paper_model, self.threads if self._parallel else 1)

    def _step_pool(self, t: int, a: int | None) -> BlockPool:
        """The pool step t writes into: :meth:`_reserved`, advanced by C in a dynamic world with
        eager dynamics (every cell of every block row, a fresh array)."""
        blocks = self._reserved(t)
        if a is not None and not self.model.is_static and not self.lazy_dynamics:
            blocks = blocks.with_rows(blocks.rows @ self.model.change)
        return blocks

    def _neighbors(self, a: int | None) -> np.ndarray:
        """(N,) the cell action ``a`` points at from each cell (every cell itself at step 0)."""
        return _no_moves(self.model.n_cells) if a is None else self.model.moves[a]

    def _reserved(self, t: int) -> BlockPool:
        """The pool with the free rows a step writes (:meth:`BlockPool.reserved`: this filter's, or a
        grown copy), after checking that growing it keeps the filter within ``max_bytes``
        (:class:`~onlinemap.errors.MemoryLimitError` otherwise, nothing changed). With a path
        history (``move_window``) the check counts its growth for the step and, on a step that may
        move (:meth:`PathHistory.move_due`, whether the filter is still exact aside), the move's
        worst case: P times :func:`map_rows_per_move` more map rows and
        :func:`path_rows_per_move` more history rows (the pools grow by doubling as the move
        needs, never beyond that). O(1)."""
        pool, model, p = self._blocks, self.model, self.n_particles
        need = cells_written(model) * p
        extra, history_bytes, history_grows = 0, None, False
        if self._history is not None:
            window = self.move_window
            moving = self._history.move_due(t, window, self.move_every, self.move_lag, exact=False)
            extra = p * map_rows_per_move(model, window, pool.table.shape[1]) if moving else 0
            history_bytes, history_grows = self._history.bytes_to_hold(
                t, p * (1 + (path_rows_per_move(window) if moving else 0)))
            if moving:  # the move allocates its scratch after the step is taken: counted, and checked, before
                history_bytes, history_grows = history_bytes + move_scratch_bytes(model, window), True
        check_growth(self._sizing, pool, t, pool.rows_to_hold(need + extra), history_bytes, history_grows)
        return pool.reserved(need)

    def _fc_buffers(self) -> _FCBuffers:
        """Views of the filter's scratch buffers for one Fearnhead-Clifford step (2P children, P
        slots); every step writes them before reading them. A sampling scheme owns none: it
        enumerates only when every draw missed (:meth:`update`), into fresh arrays."""
        ints, floats, p = self._scratch_ints, self._scratch_floats, self.n_particles
        if not len(ints):
            ints, floats = np.empty((5, 2 * p), dtype=np.int64), np.empty((3, 2 * p))
        children = Children(ints[0], ints[1], floats[0], *_no_cells(cells_written(self.model), self.model.n_labels))
        return _FCBuffers(children, floats[1], ints[2], ints[3, :p], floats[2, :p],
                          Slots(ints[3, p:], ints[4, :p], floats[2, p:]))

    def _update_fearnhead_clifford(self, a: int | None, z, t: int) -> None:
        """Enumerate every live particle's successors with their exact weights (the kernel set's
        ``enumerate``), keep P of them by optimal resampling
        (:func:`~onlinemap.kernels.rbpf_commit.rbpf_keep_children`: none twice, unbiased; its strata
        walk the children ordered by location, which spreads the draws over the cells: measured
        1.6-2x closer to exact than index order) and write them into the slots, each kept child's
        changed cells computed from its parent's map as the enumeration defines them (the kernel
        set's ``commit_children``). O(P K^2 + N) (O(P F K^2) with a footprint of F cells); the
        resampling is O(P). Works in the filter's scratch buffers: no per-step allocation of size P."""
        model, kernels = self.model, self._kernels
        blocks = self._step_pool(t, a)
        pool, world = blocks.arrays(), world_tables(model)
        neighbors, observation = self._neighbors(a), observed(model, z)
        buffers = self._fc_buffers()
        children, slots = buffers.children, buffers.slots
        m = kernels.enumerate(self._locations, self._log_weights, pool, world, t, neighbors, observation, children)
        if m == 0:  # depletion
            self._recover(a, z, t, blocks)
            return
        weights = buffers.child_weight[:m]
        increment = logsumexp(children.log_weight[:m], weights)
        np.exp(np.subtract(children.log_weight[:m], increment, out=weights), out=weights)
        threshold = rbpf_keep_children(children.parent, children.location, weights, model.n_cells, self._rng.random(),
                                       buffers.order, buffers.kept, buffers.kept_weights, slots.ancestors,
                                       slots.slot_child, slots.log_weights)
        kernels.commit_children(self._locations, pool, world, t, slots, children.location, neighbors, observation,
                                self._staged_buffers())
        blocks.refresh(t)
        self._advance(t, blocks, slots.ancestors, slots.log_weights, logsumexp(slots.log_weights,
                                                                                buffers.kept_weights),
                      increment, threshold > 0)

    def _recover(self, a: int | None, z, t: int, blocks: BlockPool) -> None:
        """The step when no particle explains ``z`` (depletion): the exact limit of the augmented
        model of the class docstring from the particles before the step
        (:func:`~onlinemap.estimators.rbpf_recovery.relocate`), committed with the cells its
        children carry (:meth:`_commit`: a relocated child's cells do not follow from its parent's
        map at its location, as Fearnhead-Clifford's children's do). Raises
        :class:`ImpossibleObservationError`, changing nothing, at step 0 (no motion, no
        relocation), when no child is possible, or when ``recover_from_depletion`` is False; and
        :class:`~onlinemap.errors.MemoryLimitError`, changing nothing, when the recovery's bytes
        would take the filter beyond ``max_bytes``
        (:func:`~onlinemap.estimators.rbpf_memory.check_recovery`). ``blocks``: the step's pool
        (reserved for P W writes; advanced by C with eager dynamics)."""
        model, n_particles = self.model, self.n_particles
        if not self.recover_from_depletion:
            raise ImpossibleObservationError(no_particle_explains(model, z, t, n_particles))
        if a is None:
            raise ImpossibleObservationError(impossible(model, z, t, n_particles))
        check_recovery(self._sizing, t, blocks, len(self._blocks.rows),
                       0 if self._history is None else self._history.nbytes)
        relocation = relocate(model, blocks.arrays(), self._locations, self._log_weights, t, z, self._rng)
        if relocation is None:
            raise ImpossibleObservationError(impossible(model, z, t, n_particles))
        parents = int(np.count_nonzero(self._weights))
        self._commit(t, blocks, relocation.ancestors, relocation.staged, relocation.log_weights, relocation.increment,
                     relocation.resampled, recovered=True)
        self._recoveries += 1
        logger.warning("rbpf step %d: no particle explains observation %s (particle depletion); recovered by "
                       "relocating the %d live particles near their last cells (kernel exp(-d / %g), d in moves)%s; "
                       "%d children kept (recovery %d of this filter)", t, describe(model, z), parents,
                       RELOCATION_SCALE, f" and resetting {relocation.resets} read cell(s) to their prior"
                       if relocation.resets else "", relocation.kept, self._recoveries)

    @property
    def _sizing(self) -> Sizing:
        """What the memory guard needs of this filter (:mod:`~onlinemap.estimators.rbpf_memory`)."""
        return Sizing(self.model, self.n_particles, self.lazy_dynamics, self.threads, self.max_bytes)

    def _staged_buffers(self) -> Staged | None:
        """The threads' staging of a step's writes (:class:`~onlinemap.kernels.rbpf_commit.Staged`:
        views of the filter's scratch buffers, P slots of W cells), None without threads."""
        p, width = self.n_particles, cells_written(self.model)
        ints = self._scratch_staged_ints
        if not len(ints):
            return None
        new_ids, target, source = (ints[i * p * width:(i + 1) * p * width].reshape(p, width) for i in range(3))
        return Staged(ints[3 * p * width:], new_ids, self._scratch_staged_cells, target, source)

    def _commit(self, t, blocks: BlockPool, ancestors, staged: Staged, log_weights, increment, resampled,
                recovered: bool = False) -> None:
        """Write a validated step whose changed cells are given (the sampling schemes; a recovery's
        children, :func:`~onlinemap.estimators.rbpf_recovery.relocate`): the particles' slots and
        maps into ``blocks`` (the kernel set's ``commit``; with threads, planned in the staging
        buffers' ``target`` and ``source``), then :meth:`_advance`; ``recovered``: the step
        recovered from depletion."""
        plan = self._staged_buffers()
        if plan is not None:
            staged = staged._replace(target=plan.target, source=plan.source)
        self._kernels.commit(self._locations, blocks.arrays(), t, ancestors, staged)
        blocks.refresh(t)
        self._advance(t, blocks, ancestors, log_weights, 0.0, increment, resampled, recovered)

    def _advance(self, t, blocks: BlockPool, ancestors, log_weights, normaliser, increment, resampled,
                 recovered: bool = False) -> None:
        """Take the committed step: keep ``blocks`` (this filter's pool, or its grown copy), the log
        weights ``log_weights - normaliser`` (normalised; written into the filter's own arrays), the
        evidence ``increment`` and whether the step ``recovered`` from depletion; with a path
        history, each slot's path: its ancestor's (``ancestors`` (P,), the commit's), then its
        location (:meth:`PathHistory.record_paths`; :meth:`_reserved` checked the memory)."""
        self._blocks = blocks
        if self._history is not None:
            self._history = self._history.reserved(t, self.n_particles)
            self._history.record_paths(t, ancestors, self._locations, resampled, recovered)
        np.subtract(log_weights, normaliser, out=self._log_weights)
        self._log_evidence += increment
        np.exp(self._log_weights, out=self._weights)
        self._ess = min(float(self.n_particles), effective_sample_size(self._weights))  # rounding: <= P
        self._resampled = resampled
        self._recovered = recovered
        self._t = t
        self._belief = None

    def sample_states(self, size: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """``size`` states drawn from the belief: a particle by weight (one ``rng.choice``), then each
        cell's label from that particle's map marginals (:func:`~onlinemap.estimators.base.draw_labels`).
        Locations (S,) and label maps (S, N), int64. O(P + S N K^2)."""
        from .base import draw_labels

        weights = np.exp(self._log_weights)
        chosen = rng.choice(len(weights), size=size, p=weights / weights.sum())
        return self._locations[chosen], draw_labels(self.particle_maps(chosen), rng)

    def particle_snapshot(self, size: int | None = None, rng: np.random.Generator | None = None):
        """The particles as a :class:`~onlinemap.estimators.base.ParticleSnapshot` (copies): all
        of them, weights kept, if ``size`` is None or not below P; else ``size`` of them drawn by
        weight (systematic sampling: one uniform of ``rng``) and equally weighted. Reads
        :meth:`particle_maps` of the kept particles only: O(P + M N K^2) for M kept."""
        from .base import ParticleSnapshot

        log_weights = self._log_weights
        if size is None or size >= len(log_weights):
            return ParticleSnapshot(self._locations.copy(), self.particle_maps(), log_weights.copy())
        weights = np.exp(log_weights)
        cdf = np.cumsum(weights / weights.sum())
        positions = (rng.random() + np.arange(size)) / size
        chosen = np.minimum(np.searchsorted(cdf, positions, side="right"), len(weights) - 1)
        return ParticleSnapshot(self._locations[chosen], self.particle_maps(chosen), np.full(size, -math.log(size)))


class _FCBuffers(NamedTuple):
    """One Fearnhead-Clifford step's working arrays (views of the filter's scratch buffers): the
    children (2P), their weights (2P,), the order their strata walk, the kept children and their
    weights (P,), and the slots (P,)."""

    children: Children
    child_weight: np.ndarray
    order: np.ndarray
    kept: np.ndarray
    kept_weights: np.ndarray
    slots: Slots


def _scheme(proposal, resampling) -> tuple[str, str]:
    """The options ``proposal`` and ``resampling``, checked (:class:`InvalidOptionError` naming
    them), ``resampling`` None resolved: Fearnhead-Clifford for the optimal proposal, residual
    for the transition one."""
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


def _thread_count(threads) -> int:
    """The ``threads`` option as a count, 1 to ``NUMBA_NUM_THREADS`` (None: all of them)."""
    most = numba.config.NUMBA_NUM_THREADS
    if threads is None:
        return most
    if type(threads) is int and 1 <= threads <= most:  # a valid count, as checked below (read 3 times a step)
        return threads
    return arguments.integer(f"threads (at most NUMBA_NUM_THREADS={most}: the cores numba counts, or that "
                             "environment variable set before numba starts)", threads, minimum=1, maximum=most,
                             error=InvalidOptionError)


@functools.cache
def _no_cells(width: int, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Empty (log motion, ids (0, W), cells (0, W, K)) of :class:`~onlinemap.kernels.rbpf_enumerate.Children`
    that store no child's cells (never written: 0 rows), made once per shape."""
    return np.empty(0), np.empty((0, width), dtype=np.int64), np.empty((0, width, k))


def _no_moves(n: int) -> np.ndarray:
    """Read-only ``arange(n)`` (every cell stays): the same numba type as a row of ``model.moves``,
    so rbpf_propose is compiled once."""
    return read_only(np.arange(n))
