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

import logging
import math
import weakref
from types import MappingProxyType

import numpy as np

from .. import arguments
from ..arrays import DEFAULT_MAX_BYTES, read_only
from ..belief import Belief
from ..errors import ImpossibleObservationError, InvalidOptionError, ModelError
from ..label_prior import DEFAULT_LEARN_EVERY, PARTICLE_CONTEXT, shown_options
from ..kernels.rbpf import in_place_ancestors
from ..kernels.rbpf_commit import Staged, rbpf_keep_children
from ..model import GridModel
from ..resampling import RESAMPLERS, effective_sample_size
from ..rng import SeedLike, as_generator
from ..validation import check_step
from .base import BooleanFlag, ParticleSnapshot, draw_labels, register
from .block_pool import BlockPool, block_layout
from .rbpf_kernels import SCHEMES  # noqa: F401 (the filter's named schemes, imported from here by studies)
from .rbpf_kernels import (FEARNHEAD_CLIFFORD, StepKit, no_moves, observed, scheme, scratch_buffers, step_kit,
                           thread_count)
from .rbpf_memory import Sizing, cells_written, check_growth, check_recovery, check_start, history_growth
from .rbpf_move import MoveCounts, PathHistory, move_options, rebuilds
from .rbpf_prior import (context_neighbours, current_tilt, learn_prior, particle_context_step, prior_options,
                         resolved_prior, start_prior)
from .rbpf_recovery import describe, impossible, logsumexp, no_particle_explains, recovery_note, relocate
from .rbpf_state import check_state, upgrade_attributes

logger = logging.getLogger(__name__)

#: each filter's :class:`~onlinemap.estimators.rbpf_kernels.StepKit` by ``id``, dropped when the filter dies:
#: beside the filter, not in it (a checkpoint stores ``vars(est)``); a ``WeakKeyDictionary`` costs 0.2-0.3 us more
_KITS: dict[int, StepKit] = {}

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
    step does not raise. A sampling step whose draws all miss first enumerates the successors as
    Fearnhead-Clifford does; when those all have weight zero too the filter *recovers*: the exact
    limit of a model in which the robot may be lifted and put down near its last cell, a cell it
    then reads redrawn from its model marginal (:mod:`onlinemap.estimators.rbpf_recovery`, the
    math and the cost). The belief has ``recovered=True``, :attr:`recoveries` counts such steps
    (checkpointed), and the logger ``onlinemap.estimators.rbpf`` warns. Only an observation
    nothing explains even so (step 0, or no cell of the grid sees it) raises
    :class:`ImpossibleObservationError`, the state unchanged. Steps that do not deplete are those
    of a filter without recovery. ``recover_from_depletion = False`` (checkpointed) makes a
    depleted step raise instead, the state unchanged: for hypothetical steps (a planner
    enumerating observations) or to stop a run rather than relocate.

    **Resample-move** (``move_window``, ``move_every``, ``move_lag``; off by default, Gilks and
    Berzuini 2001; the math in :mod:`onlinemap.estimators.rbpf_move`). With ``move_window`` = W
    (1 to 1000), every ``move_every`` steps (default 10, the best measured), after the step's update, each live
    particle redraws W consecutive past locations, the window ending at least ``move_lag`` steps
    back (default 100; 0 lets it end at t), by a Metropolis-Hastings move whose invariant law is
    the posterior over paths. Weights, the evidence and the streaming contract are unchanged
    (``step`` returns the belief at t). Moves wait until the filter is not exact
    (Fearnhead-Clifford has dropped a child), so with room for every child (P >= 2^T) the filter
    is bit for bit the filter without moves. It needs a static world: ``move_window`` is refused
    otherwise (:class:`~onlinemap.errors.InvalidOptionError` naming the reason). With blocking
    labels or a sensor with zero entries each move rebuilds its particle's map without the window
    from the path history (O(t F) a particle), and moves stop after a recovery from depletion. The filter keeps every
    particle's path and every step's action and readings: up to 2 P t bytes more, counted by
    ``max_bytes``. :attr:`moves` counts the windows proposed and accepted (checkpointed). What it
    buys: on the paper's world replay at 1,000 particles (W = 20, every 5) the final map error
    falls from 0.26 to about 0.20 for 3.2x the time per step (the user guide's Estimators page, RBPF section).

    **Label prior** (``label_prior``, ``prior_strength``, ``learn_every``; :mod:`onlinemap.label_prior`,
    the math in :mod:`onlinemap.estimators.rbpf_prior`). None (the default): what the model says,
    ``"learn"`` on a model whose label frequencies are unknown (generated buildings, floors read
    from files) in a static world, else the model's prior table (the paper's worlds: every run as
    without the option). ``"model"``: the model's table always. A (K,) vector v: every cell's
    prior is ``normalise(prior_i * v)``. ``"learn"`` (static worlds): the frequencies, under a
    Dirichlet of total pseudo-count ``prior_strength`` (default K), re-estimated every
    ``learn_every`` steps (default 10) from the expected labels of the cells read, every cell's
    prior moved to them; ``"context"`` (static grid worlds; this filter only): every cell's own
    tilt v_i, its label's predictive given its 4 neighbours' labels as read before it, backed off
    to those frequencies (:attr:`context_tilts`); ``"particle_context"`` (static grid worlds; this
    filter only; not with ``move_window``): the same table tempered by ``context_weight`` w (default
    0.5: ``w v + (1 - w) pi``), applied per particle, before each step, to the cells the step may
    read, by their context in that particle's own map (P x N cell statuses carried through
    resampling, recovery and checkpoints; a step that raises takes its tilts back). Plug-in
    (empirical Bayes) priors, one pass over the block rows in use, weights unchanged;
    :attr:`label_frequencies` gives the frequencies (checkpointed). ``context_table`` (context priors only):
    context pseudo-counts learned from known maps (:func:`~onlinemap.label_prior.context_table`).

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

    #: False: a depleted step raises instead of recovering (see above); a bool, checked when set
    recover_from_depletion = BooleanFlag()

    #: per-step buffers (:func:`~onlinemap.estimators.rbpf_kernels.step_kit` makes their views),
    #: overwritten by every step before being read: not state (a checkpoint records their dtype and shape only)
    scratch_attributes = ("_scratch_ints", "_scratch_floats", "_scratch_staged_ints", "_scratch_staged_cells")

    #: label_prior="learn"'s (and "context"'s) current label frequencies (K,); "context"'s tilts (N, K), cells read
    #: (N,) and frozen contexts (N,) (label_prior.ContextState): attributes of such filters only (and of their
    #: checkpoints); None, these class defaults, for the other filters, whose state is as without the options
    _label_frequencies: np.ndarray | None = None
    _context_tilts = _context_read = _context_frozen = None
    #: "particle_context"'s cell statuses (P, N) uint8 (kernels/rbpf_context.py), its ratios ((K + 2)^4, K)
    _particle_cells = _context_ratios = None

    #: options a checkpoint leaves out while None (checkpoint.protocol.stored_options): those without stay as they were
    checkpoint_omitted_options = ("context_table",)
    #: what the placeholder defaults run with the other defaults (estimator_options shows these)
    resolved_defaults = MappingProxyType({"resampling": FEARNHEAD_CLIFFORD})

    def __init__(self, model: GridModel, *, n_particles: int = 100, proposal: str = "optimal",
                 resampling: str | None = None, resample_threshold: float = 0.5, seed: SeedLike = None,
                 lazy_dynamics: bool = True, block_cells: int | None = None,
                 max_bytes: int = DEFAULT_MAX_BYTES, threads: int | None = 1, move_window: int | None = None,
                 move_every: int = 10, move_lag: int = 100, label_prior=None, prior_strength=None,
                 learn_every: int | None = None, context_weight: float | None = None, context_table=None):
        error = InvalidOptionError
        n_particles = arguments.integer("n_particles", n_particles, minimum=1, error=error)
        proposal, resampling = scheme(proposal, resampling)
        resample_threshold = arguments.probability("resample_threshold", resample_threshold, error)
        seed = arguments.seed("seed", seed, error)
        lazy_dynamics = arguments.flag("lazy_dynamics", lazy_dynamics, error)
        if not model.is_paper_model and not lazy_dynamics and not model.is_static:
            raise error("lazy_dynamics=False (the eager reference) does not support blocking labels or a sensor "
                        "footprint")
        if block_cells is not None:
            block_cells = arguments.integer("block_cells", block_cells, minimum=1, maximum=model.n_cells, error=error)
        max_bytes = arguments.byte_limit("max_bytes", max_bytes, error)
        threads = thread_count(threads)
        move_window, move_every, move_lag = move_options(model, move_window, move_every, move_lag)
        prior = prior_options(model, label_prior, prior_strength, learn_every, context_weight, move_window,
                              context_table)
        statuses = n_particles * model.n_cells if prior.kind == PARTICLE_CONTEXT else 0  # uint8 (P, N)
        check_start(Sizing(model, n_particles, lazy_dynamics, threads, max_bytes, statuses), block_cells, move_window)
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
        start_prior(self, prior)  # the rows tilted by a vector, or the learning state (rbpf_prior.py)
        fc = resampling == FEARNHEAD_CLIFFORD
        # the resample-move step's paths (rbpf_move.py); None without it
        self._history = None if move_window is None else PathHistory.new(model, n_particles, exact=fc)
        (self._scratch_ints, self._scratch_floats, self._scratch_staged_ints,
         self._scratch_staged_cells) = scratch_buffers(n_particles, cells_written(model), model.n_labels, fc, threads)
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
        return thread_count(self.options["threads"])

    @property
    def _kit(self) -> StepKit:
        """The filter's :class:`~onlinemap.estimators.rbpf_kernels.StepKit`: its kernels, options,
        the model's tables (the context priors' neighbour table included,
        :func:`~onlinemap.estimators.rbpf_prior.context_neighbours`) and views of its scratch buffers,
        built on first use and kept beside the filter (``_KITS``; a fork, a new filter, builds its
        own). A checkpoint's load keeps the filter's own scratch buffers and checks its model and
        options equal (``CONSTANT_STATE``), so the kit stays valid. O(1) once built."""
        kit = _KITS.get(id(self))
        if kit is None:
            kit = _KITS[id(self)] = step_kit(self.model, self.n_particles, cells_written(self.model), self.threads,
                                             self.proposal == "optimal", self.resample_threshold, self.lazy_dynamics,
                                             (self._scratch_ints, self._scratch_floats, self._scratch_staged_ints,
                                              self._scratch_staged_cells),
                                             context_neighbours(self.model, self.options.get("label_prior")))
            weakref.finalize(self, _KITS.pop, id(self), None)
        return kit

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
        estimate with ``label_prior="learn"`` or ``"context"``, the given vector, or None."""
        if self._label_frequencies is not None:
            return read_only(self._label_frequencies.copy())
        fixed = resolved_prior(self.model, self.options).frequencies
        return None if fixed is None else read_only(fixed.copy())

    @property
    def context_tilts(self) -> np.ndarray | None:
        """(N, K) each cell's tilt v_i with ``label_prior="context"``, a read-only copy; else None."""
        return None if self._context_tilts is None else read_only(self._context_tilts.copy())

    @property
    def context_ratios(self) -> np.ndarray | None:
        """((K + 2)^4, K) each neighbour context's tilt ``v'[c] / pi`` of a cell's prior with
        ``label_prior="particle_context"`` after its first learning step (rows indexed by
        :func:`~onlinemap.label_prior.context_codes`' codes), a read-only copy; else None."""
        return None if self._context_ratios is None else read_only(self._context_ratios.copy())

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
            maps = self._blocks.mixture(self._t, weights, self._kit.kernels().threads)
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

    def array_bytes(self) -> tuple[int, int]:
        """(allocated, in use): the bytes of every array the filter holds, its block pool's
        included, and the same without the pool's free rows (:attr:`BlockPool.free_bytes`). O(1)."""
        allocated = sum(value.nbytes for value in vars(self).values() if isinstance(value, np.ndarray))
        allocated += self._blocks.nbytes
        return allocated, allocated - self._blocks.free_bytes

    def step(self, action, observation) -> Belief:
        """``update`` then ``belief``."""
        self.update(action, observation)
        return self.belief

    def update(self, action, observation) -> None:
        """Advance the particles by one action (None at step 0) and observation: resample if due,
        propose, weight, update each particle's observed cells; on depletion, recover
        (:meth:`_recover`); with ``move_window``, record the step and move when due. An observation
        nothing explains (:class:`ImpossibleObservationError`) or a step beyond ``max_bytes``
        (:class:`~onlinemap.errors.MemoryLimitError`) leaves everything as it was."""
        self._step(action, observation)

    def update_with_ancestors(self, action, observation) -> np.ndarray:
        """:meth:`update`, returning the genealogy (P,), a fresh array: ``ancestors[p]``, the slot
        (before the step) particle p descends from (parent, or relocated by a recovery); traced
        back, the paths (:func:`onlinemap.hindsight.smoothed_rbpf_map`; a ``move_window`` move
        redraws them unseen)."""
        return np.array(self._step(action, observation), dtype=np.int64)  # a copy: the step's may be the kit's

    def _step(self, action, observation) -> np.ndarray:
        """:meth:`update`, returning the step's ancestors (P,): the kit's buffers or a fresh array,
        valid until the next step."""
        a, z = check_step(self.model, self._t + 1, action, observation)
        t = self._t + 1
        with particle_context_step(self, t, a) as taken:  # label_prior="particle_context"'s tilts (rbpf_prior.py)
            if self.resampling == FEARNHEAD_CLIFFORD:
                ancestors = self._update_fearnhead_clifford(a, z, t)
            else:
                ancestors = self._update_sampling(a, z, t)
            taken(ancestors)
        history = self._history
        if history is not None:  # the step is taken: its record, then the resample-move step if due
            history.record_step(t, a, z)
            if history.move_due(t, self.move_window, self.move_every, self.move_lag, rebuilds(self.model)):
                self._history, self._blocks = history.move(self._blocks, self._locations, self._log_weights,
                                                           self.model, t, self.move_window, self.move_lag, self._rng,
                                                           current_tilt(self))
        if self._label_frequencies is not None and t % (self.options["learn_every"] or DEFAULT_LEARN_EVERY) == 0:
            learn_prior(self, t, self._kit.kernels().threads)  # label_prior="learn" or "context" (rbpf_prior.py)
        return ancestors

    def _update_sampling(self, a: int | None, z, t: int) -> np.ndarray:
        """:meth:`update` with a sampling scheme (``a``, ``z`` checked): resample if due, propose,
        weight, commit; when every draw missed, :meth:`_update_fearnhead_clifford` instead."""
        model, kit = self.model, self._kit
        blocks = self._step_pool(t, a, kit)
        rng_state = self._rng.bit_generator.state
        n_particles, threshold = kit.n_particles, kit.threshold
        log_weights, ancestors = self._log_weights, kit.identity
        resample = a is not None and (threshold >= 1.0 or self._ess < threshold * n_particles)
        if resample:
            chosen = RESAMPLERS[self.resampling](self._weights, self._rng)
            ancestors = in_place_ancestors(np.bincount(chosen, minlength=n_particles))
            log_weights = np.full(n_particles, -math.log(n_particles))
        staged, log_increments = kit.kernels().propose(self._locations, blocks.arrays(), kit.world, t, ancestors,
                                                       self._neighbors(a), observed(model, z), kit.optimal,
                                                       self._rng.random(n_particles), kit.proposal)
        log_weights = np.add(log_weights, log_increments, out=log_increments)  # the kit's buffers: no allocation
        increment = logsumexp(log_weights, kit.proposal.terms)
        if increment == -math.inf:  # every draw missed: enumerate the particles' successors instead
            self._rng.bit_generator.state = rng_state
            logger.info("rbpf step %d: every particle's proposal has probability zero for observation %s; the "
                        "step enumerates the particles' successors instead (as Fearnhead-Clifford does)", t,
                        describe(model, z))
            return self._update_fearnhead_clifford(a, z, t)
        return self._commit(kit, t, blocks, ancestors, staged, log_weights, increment, increment, resample)

    def _step_pool(self, t: int, a: int | None, kit: StepKit) -> BlockPool:
        """The pool step t writes into: :meth:`_reserved`, advanced by C in a dynamic world with
        eager dynamics (every cell of every block row, a fresh array)."""
        blocks = self._reserved(t, kit.width * kit.n_particles)
        if a is not None and kit.eager:
            blocks = blocks.with_rows(blocks.rows @ self.model.change)
        return blocks

    def _neighbors(self, a: int | None) -> np.ndarray:
        """(N,) the cell action ``a`` points at from each cell (every cell itself at step 0)."""
        return no_moves(self.model.n_cells) if a is None else self.model.moves[a]

    def _reserved(self, t: int, need: int) -> BlockPool:
        """The pool with ``need`` free rows, those a step writes (:meth:`BlockPool.reserved`: this
        filter's, or a grown copy), after checking that growing it, and the path history's growth
        with ``move_window`` (:func:`~onlinemap.estimators.rbpf_memory.history_growth`), keep the
        filter within ``max_bytes`` (:class:`~onlinemap.errors.MemoryLimitError` otherwise,
        nothing changed). O(1)."""
        pool, history = self._blocks, self._history
        extra, history_bytes, history_grows = (0, None, False) if history is None else history_growth(
            self.model, history, pool, t, self.n_particles, self.move_window, self.move_every, self.move_lag)
        rows = pool.rows_to_hold(need + extra)
        if rows > len(pool.rows) or history_grows:
            check_growth(self._sizing, pool, t, rows, history_bytes, history_grows)
        return pool.reserved(need)

    def _update_fearnhead_clifford(self, a: int | None, z, t: int) -> np.ndarray:
        """Enumerate every live particle's successors with their exact weights (the kernel set's
        ``enumerate``), keep P of them by optimal resampling
        (:func:`~onlinemap.kernels.rbpf_commit.rbpf_keep_children`: none twice, unbiased; its strata
        walk the children ordered by location, which spreads the draws over the cells: measured
        1.6-2x closer to exact than index order) and write them into the slots, each kept child's
        changed cells computed from its parent's map as the enumeration defines them (the kernel
        set's ``commit_children``). O(P K^2 + N) (O(P F K^2) with a footprint of F cells); the
        resampling is O(P). Works in the filter's scratch buffers (a sampling scheme, which
        enumerates only when every draw missed, in fresh ones): no per-step allocation of size P."""
        model, kit = self.model, self._kit
        kernels = kit.kernels()
        blocks = self._step_pool(t, a, kit)
        pool, world = blocks.arrays(), kit.world
        neighbors, observation = self._neighbors(a), observed(model, z)
        buffers = kit.fc_buffers(model.n_labels)
        children, slots = buffers.children, buffers.slots
        m = kernels.enumerate(self._locations, self._log_weights, pool, world, t, neighbors, observation, children)
        if m == 0:  # depletion
            return self._recover(a, z, t, blocks)
        weights = buffers.child_weight[:m]
        increment = logsumexp(children.log_weight[:m], weights)
        np.exp(np.subtract(children.log_weight[:m], increment, out=weights), out=weights)
        threshold = rbpf_keep_children(children.parent, children.location, weights, model.n_cells, self._rng.random(),
                                       buffers.order, buffers.kept, buffers.kept_weights, slots.ancestors,
                                       slots.slot_child, slots.log_weights)
        kernels.commit_children(self._locations, pool, world, t, slots, children.location, neighbors, observation,
                                kit.staged)
        blocks.refresh(t)
        normaliser = logsumexp(slots.log_weights, buffers.kept_weights)
        return self._advance(t, blocks, slots.ancestors, slots.log_weights, normaliser, increment, threshold > 0)

    def _recover(self, a: int | None, z, t: int, blocks: BlockPool) -> np.ndarray:
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
        ancestors = self._commit(self._kit, t, blocks, relocation.ancestors, relocation.staged, relocation.log_weights,
                                 0.0, relocation.increment, relocation.resampled, recovered=True)
        self._recoveries += 1
        logger.warning(recovery_note(model, z, t, parents, relocation, self._recoveries))
        return ancestors

    @property
    def _sizing(self) -> Sizing:
        """What the memory guard needs of this filter (:mod:`~onlinemap.estimators.rbpf_memory`)."""
        statuses = self._particle_cells
        return Sizing(self.model, self.n_particles, self.lazy_dynamics, self.threads, self.max_bytes,
                      0 if statuses is None else statuses.nbytes)

    def _commit(self, kit: StepKit, t, blocks: BlockPool, ancestors, staged: Staged, log_weights, normaliser,
                increment, resampled, recovered: bool = False) -> np.ndarray:
        """Write a validated step whose changed cells are given (the sampling schemes; a recovery's
        children, :func:`~onlinemap.estimators.rbpf_recovery.relocate`): the particles' slots and
        maps into ``blocks`` (the kernel set's ``commit``; with threads, planned in the staging
        buffers' ``target`` and ``source``), then :meth:`_advance` (the log weights ``log_weights -
        normaliser``); ``recovered``: the step recovered from depletion; ``kit``: the filter's."""
        if kit.staged is not None:
            staged = staged._replace(target=kit.staged.target, source=kit.staged.source)
        kit.kernels().commit(self._locations, blocks.arrays(), t, ancestors, staged)
        blocks.refresh(t)
        return self._advance(t, blocks, ancestors, log_weights, normaliser, increment, resampled, recovered)

    def _advance(self, t, blocks: BlockPool, ancestors, log_weights, normaliser, increment, resampled,
                 recovered: bool = False) -> np.ndarray:
        """Take the committed step: keep ``blocks`` (this filter's pool, or its grown copy), the log
        weights ``log_weights - normaliser`` (normalised; written into the filter's own arrays), the
        evidence ``increment`` and whether the step ``recovered`` from depletion; with a path
        history, each slot's path: its ancestor's (``ancestors`` (P,), the commit's), then its
        location (:meth:`PathHistory.record_paths`; :meth:`_reserved` checked the memory). Returns
        ``ancestors``."""
        self._blocks = blocks
        n_particles = len(ancestors)
        if self._history is not None:
            self._history = self._history.reserved(t, n_particles)
            self._history.record_paths(t, ancestors, self._locations, resampled, recovered)
        np.subtract(log_weights, normaliser, out=self._log_weights)
        self._log_evidence += increment
        np.exp(self._log_weights, out=self._weights)
        self._ess = min(float(n_particles), effective_sample_size(self._weights))  # rounding: <= P
        self._resampled = resampled
        self._recovered = recovered
        self._t = t
        self._belief = None
        return ancestors

    def sample_states(self, size: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """``size`` states drawn from the belief: a particle by weight (one ``rng.choice``), then each
        cell's label from that particle's map marginals (:func:`~onlinemap.estimators.base.draw_labels`).
        Locations (S,) and label maps (S, N), int64. O(P + S N K^2)."""
        weights = np.exp(self._log_weights)
        chosen = rng.choice(len(weights), size=size, p=weights / weights.sum())
        return self._locations[chosen], draw_labels(self.particle_maps(chosen), rng)

    def particle_snapshot(self, size: int | None = None, rng: np.random.Generator | None = None):
        """The particles as a :class:`~onlinemap.estimators.base.ParticleSnapshot` (copies): all
        of them, weights kept, if ``size`` is None or not below P; else ``size`` of them drawn by
        weight (systematic sampling: one uniform of ``rng``) and equally weighted. Reads
        :meth:`particle_maps` of the kept particles only: O(P + M N K^2) for M kept."""
        log_weights = self._log_weights
        if size is None or size >= len(log_weights):
            return ParticleSnapshot(self._locations.copy(), self.particle_maps(), log_weights.copy())
        weights = np.exp(log_weights)
        cdf = np.cumsum(weights / weights.sum())
        positions = (rng.random() + np.arange(size)) / size
        chosen = np.minimum(np.searchsorted(cdf, positions, side="right"), len(weights) - 1)
        return ParticleSnapshot(self._locations[chosen], self.particle_maps(chosen), np.full(size, -math.log(size)))
