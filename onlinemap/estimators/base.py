"""The estimator protocol, the registry and helpers to run an estimator over a recorded run.

Estimators are plain classes that satisfy :class:`Estimator` (no base class): they take the
model and keyword-only options in ``__init__``, and ``step(action, observation) -> Belief``.
A ``step`` that raises leaves the estimator exactly as it was.
"""

from __future__ import annotations

import copy
import functools
import inspect
import operator
import os
import time
from types import MappingProxyType
from typing import Callable, NamedTuple, Protocol, runtime_checkable

import numpy as np

from .. import checkpoint
from ..belief import Belief, beliefs_frame
from ..errors import (CheckpointError, InvalidActionError, InvalidObservationError, InvalidOptionError, ModelError,
                      OnlineMapError, StepIndexError, UnknownEstimatorError)
from ..kernels.resampling import draw_by_inversion
from ..model import GridModel

_REGISTRY: dict[str, type] = {}
#: the label-prior options (:mod:`onlinemap.label_prior`); an estimator they mean nothing to says why in
#: its ``label_prior_refusal``, and ``make_estimator`` raises InvalidOptionError with it
LABEL_PRIOR_OPTIONS = frozenset({"label_prior", "prior_strength", "learn_every", "context_weight", "context_table"})
#: the EM estimators' ``label_prior_refusal``
MAP_IS_A_PARAMETER = ("its map is a parameter (the observation matrix B, fitted by EM), not a random variable "
                      "under a prior: there are no unread cells whose prior could be learned")


@runtime_checkable
class Estimator(Protocol):
    """What every estimator offers."""

    name: str
    model: GridModel

    @property
    def t(self) -> int:
        """Index of the last step taken (-1 before the first)."""

    @property
    def belief(self) -> Belief | None:
        """The belief after the last step (None before the first)."""

    def step(self, action: int | str | None, observation: int | str) -> Belief:
        """Advance by one action (None at the first step) and one observation."""

    options: dict[str, object]  # the keyword options it was built with, defaults filled in

    def state_dict(self) -> dict:
        """Everything needed to continue bit for bit (default: :func:`onlinemap.checkpoint.state_dict`)."""

    def load_state_dict(self, state: dict, *, strict_version: bool = False, allow_newer: bool = False) -> None:
        """Restore a :meth:`state_dict` (checked against this estimator's name, model, options and
        state invariants; refused if its format is newer than this onlinemap reads, unless
        ``allow_newer``; with ``strict_version``, also against this onlinemap's version)."""


class ParticleSnapshot(NamedTuple):
    """A particle belief as the planners' rollouts take it. R particles, N cells, K labels."""

    locations: np.ndarray  # (R,) int64
    maps: np.ndarray  # (R, N, K) each particle's current map marginals
    log_weights: np.ndarray  # (R,) normalised


@runtime_checkable
class SamplesStates(Protocol):
    """An estimator that draws whole states (a location and a map) from its own belief, not from
    the product of its marginals (``exact``: the joint; ``rbpf``: a particle, then its map)."""

    def sample_states(self, size: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """``size`` states drawn from the belief: locations (S,) and label maps (S, N), int64."""


@runtime_checkable
class HoldsParticles(Protocol):
    """A particle filter whose particles a planner may roll out (copies; the filter is untouched)."""

    n_particles: int

    def particle_snapshot(self, size: int | None = None,
                          rng: np.random.Generator | None = None) -> ParticleSnapshot:
        """The particles, all of them or ``size`` drawn by weight."""


def draw_labels(marginals: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(S, N, K) per-cell label marginals -> (S, N) int64 labels, drawn independently per cell by
    inversion (one uniform each, scaled by the row's total, so rows need not sum to 1 exactly;
    :func:`onlinemap.kernels.resampling.draw_by_inversion`). O(S N K)."""
    labels = np.empty(marginals.shape[:-1], dtype=np.int64)
    draw_by_inversion(marginals, rng.random(marginals.shape[:-1]), labels)
    return labels


class _InstanceOption:
    """A descriptor for an estimator attribute kept in the instance's ``__dict__`` under its own
    name (so checkpoints, which store ``vars(est)``, see a plain attribute) and checked when set."""

    def __set_name__(self, owner: type, name: str) -> None:
        self.name = name

    def __get__(self, obj, owner=None):
        if obj is None:
            return self
        try:
            return obj.__dict__[self.name]
        except KeyError:
            raise AttributeError(self.name) from None


class FixedAfterBuild(_InstanceOption):
    """An estimator option fixed when the estimator is built (it sizes or defines the state):
    assigning it again raises :class:`~onlinemap.errors.InvalidOptionError` and leaves the
    estimator as it was. O(1)."""

    def __set__(self, obj, value) -> None:
        if self.name in obj.__dict__:
            raise InvalidOptionError(f"{self.name} is fixed when the {type(obj).name} estimator is built (it sizes or "
                                     f"defines its state); build a new one with {self.name}={value!r}")
        obj.__dict__[self.name] = value


class BooleanFlag(_InstanceOption):
    """A boolean switch of an estimator that may change between steps (e.g. the RBPF's
    ``recover_from_depletion``): anything but a bool is refused with
    :class:`~onlinemap.errors.InvalidOptionError` (a checkpoint of a non-bool would not load). O(1)."""

    def __set__(self, obj, value) -> None:
        if not isinstance(value, (bool, np.bool_)):
            raise InvalidOptionError(f"{self.name} must be True or False, got {value!r}")
        obj.__dict__[self.name] = bool(value)


def register(name: str) -> Callable[[type], type]:
    """Class decorator: make an estimator available to :func:`make_estimator` under ``name``.

    It also records the keyword options every instance is built with as ``est.options``
    (defaults filled in) and, unless the class defines its own, gives it the read-only
    properties ``t`` (from ``self._t``) and ``belief`` (from ``self._belief``), the generic
    checkpoint methods ``state_dict()`` / ``load_state_dict(state, ...)`` of
    :mod:`onlinemap.checkpoint`, and a ``repr`` naming the estimator, its model, options and t.
    The public attributes its ``CONSTANT_STATE`` names (the options that size or define the state,
    checked equal on load) become :class:`FixedAfterBuild`: set once in ``__init__``, refused after,
    so that no assignment makes a checkpoint that cannot be loaded.
    """

    def decorate(cls: type) -> type:
        if name in _REGISTRY and _REGISTRY[name] is not cls:
            raise ValueError(f"an estimator named {name!r} is already registered")
        cls.name = name
        _record_options(cls)
        for member, default in (("t", _step_index), ("belief", _last_belief),
                                ("state_dict", checkpoint.state_dict),
                                ("load_state_dict", checkpoint.load_state_dict),
                                ("__repr__", _estimator_repr)):
            if member not in vars(cls):
                setattr(cls, member, default)
        for attribute in getattr(cls, "CONSTANT_STATE", ()):
            if not attribute.startswith("_") and "." not in attribute and attribute not in vars(cls):
                fixed = FixedAfterBuild()
                fixed.__set_name__(cls, attribute)
                setattr(cls, attribute, fixed)
        _REGISTRY[name] = cls
        return cls

    return decorate


def _estimator_repr(self) -> str:
    """``rbpf(t=3, model=GridModel(...), n_particles=100, ...)``: registry name, last step, model,
    options (as the estimator runs them, ``effective_options``, where it resolves some)."""
    shown = getattr(self, "effective_options", None)
    shown = getattr(self, "options", {}) if shown is None else shown
    options = ", ".join(f"{key}={value!r}" for key, value in shown.items())
    return f"{self.name}(t={self.t}, model={self.model!r}{', ' + options if options else ''})"


_step_index = property(lambda self: self._t, doc="Index of the last step taken (-1 before the first).")
_last_belief = property(lambda self: self._belief, doc="The belief after the last step (None before the first).")


def _record_options(cls: type) -> None:
    """Wrap ``cls.__init__`` so that every instance gets ``options``: its keyword options with the
    defaults filled in (the signature seen by :func:`inspect.signature` is unchanged)."""
    init = cls.__init__
    params = inspect.signature(init).parameters.values()
    defaults = {p.name: p.default for p in params
                if p.kind is inspect.Parameter.KEYWORD_ONLY and p.default is not inspect.Parameter.empty}

    @functools.wraps(init)
    def __init__(self, model, *args, **options):
        init(self, model, *args, **options)
        self.options = {**defaults, **options}

    cls.__init__ = __init__


def available_estimators() -> tuple[str, ...]:
    """Names accepted by :func:`make_estimator`."""
    return tuple(_REGISTRY)


def estimator_options(name: str) -> dict[str, object]:
    """The keyword options of an estimator and their effective defaults (a fresh dict): the
    signature's, except where a placeholder default is resolved when the estimator is built with
    the other defaults (the class's ``resolved_defaults``: e.g. rbpf's ``resampling=None`` runs
    ``fearnhead_clifford`` with the default optimal proposal). Building with this dict runs as
    building with no option does."""
    cls = estimator_class(name)
    return {**_keyword_options(cls), **getattr(cls, "resolved_defaults", {})}


@functools.cache
def _keyword_options(cls: type) -> MappingProxyType:
    """The keyword options of ``cls.__init__`` and their defaults, read-only. Read off its
    signature once per class: :func:`inspect.signature` costs about 0.1 ms, and a sweep asks
    twice per task."""
    params = inspect.signature(cls.__init__).parameters.values()
    return MappingProxyType({p.name: p.default for p in params if p.kind is inspect.Parameter.KEYWORD_ONLY})


def estimator_class(name: str) -> type:
    """The class registered as ``name`` (its options' annotations are the sweep spec's and the
    CLI's type checks); :class:`UnknownEstimatorError` listing the known names otherwise."""
    try:
        return _REGISTRY[name]
    except (KeyError, TypeError):  # TypeError: an unhashable name
        raise UnknownEstimatorError(
            f"unknown estimator {name!r}; available: {', '.join(_REGISTRY)}") from None


def make_estimator(name: str, model: GridModel, **options) -> Estimator:
    """Build the estimator registered as ``name`` for ``model`` with keyword ``options``.

    ``available_estimators()`` lists the names: ``exact``, ``dead_reckoning``, ``online_em``,
    ``offline_em``, ``bk``, ``rbpf``. ``estimator_options(name)`` gives an estimator's options
    with their defaults, and ``help(type(est))`` (the class's docstring) what each one means.
    An unknown name or option raises :class:`UnknownEstimatorError` (listing the known ones), a
    bad value :class:`InvalidOptionError`. Example:
    ``make_estimator("rbpf", model, n_particles=500, seed=0)``.
    """
    cls = estimator_class(name)
    if not isinstance(model, GridModel):
        raise ModelError(f"model must be a GridModel, got {type(model).__name__}")
    known = _keyword_options(cls)
    unknown = sorted(set(options) - set(known))
    refusal = getattr(cls, "label_prior_refusal", None)
    if refusal is not None and set(unknown) & LABEL_PRIOR_OPTIONS:
        raise InvalidOptionError(f"estimator {name!r} takes no {', '.join(sorted(set(unknown) & LABEL_PRIOR_OPTIONS))}: "
                                 f"{refusal}")
    if unknown:
        raise UnknownEstimatorError(
            f"estimator {name!r} has no option {', '.join(map(repr, unknown))}; "
            f"its options are: {', '.join(known) or 'none'}")
    return cls(model, **options)


class Trajectory(NamedTuple):
    """Beliefs of one estimator over a run, stacked. T = number of steps (:attr:`n_steps`).

    ``trajectory.belief(t)``, or ``trajectory[t]``, is the :class:`~onlinemap.belief.Belief` after
    step ``t`` (negative ``t`` counts from the end). Iterating or unpacking gives the four fields,
    as for any named tuple (``len(trajectory)`` is 4; the steps are :attr:`n_steps`).
    """

    location: np.ndarray  # (T, N)
    map: np.ndarray  # (T, N, K)
    log_evidence: np.ndarray  # (T,)
    seconds_per_step: float

    @property
    def n_steps(self) -> int:
        """T, the number of steps stacked."""
        return len(self.location)

    def belief(self, t: int) -> Belief:
        """The read-only :class:`~onlinemap.belief.Belief` after step ``t`` (0..T-1, or -T..-1 from the
        end): copies of ``location[t]`` (N,) and ``map[t]`` (N, K) and ``log_evidence[t]``. A particle
        filter's per-step health signals (effective sample size, distinct locations, recovery) are not
        stacked, so they are absent. Raises :class:`~onlinemap.errors.StepIndexError` for ``t`` out of
        range or not an integer. Cost O(N K)."""
        steps = self.n_steps
        try:
            index = operator.index(t)
        except TypeError:
            raise StepIndexError(f"a step of a trajectory is an integer, got {type(t).__name__} {t!r}") from None
        if not -steps <= index < steps:
            raise StepIndexError(f"step {index} is not in a trajectory of {steps} steps (0..{steps - 1}, "
                                 f"or -{steps}..-1 from the end)")
        index %= steps
        return Belief(index, self.location[index], self.map[index], self.log_evidence[index])

    def __getitem__(self, t: int) -> Belief:
        """``trajectory[t]`` is :meth:`belief` ``(t)``, not the tuple's ``t``-th field (use the field names)."""
        return self.belief(t)

    def __repr__(self) -> str:
        """One line: T, the arrays' shapes and the last step's most likely cell and log evidence."""
        text = (f"Trajectory(T={len(self.location)} steps: location {self.location.shape}, map {self.map.shape}, "
                f"log_evidence {self.log_evidence.shape}")
        if not len(self.location):
            return text + ")"
        last = self.location[-1]
        best = int(np.argmax(last))
        return (f"{text}; at t={len(self.location) - 1} most likely cell {best} with p={last[best]:.3f}, "
                f"log_evidence={self.log_evidence[-1]:.4g}; {1e3 * self.seconds_per_step:.3g} ms per step)")

    def to_frame(self, model: GridModel | None = None):
        """The beliefs over time in long format, one row per step and cell (see
        :func:`onlinemap.belief.beliefs_frame`), for pandas / seaborn. Cost O(T N K)."""
        return beliefs_frame(self.location, self.map, model)


def run_estimator(estimator: Estimator, actions, observations) -> Trajectory:
    """Feed a recorded run (``actions`` (T - 1,), ``observations`` (T,)) through ``step``.

    Lengths that do not fit raise :class:`InvalidObservationError` (no observations, or no
    sequence) or :class:`InvalidActionError` (not T - 1 actions) before any step.
    Cost: T calls of ``step``; memory O(T N K) for the stacked marginals.
    """
    n_steps = _length("observations", observations, InvalidObservationError)
    n_actions = _length("actions", actions, InvalidActionError)
    if n_steps == 0:
        raise InvalidObservationError("a run needs at least one observation")
    if n_actions != n_steps - 1:
        raise InvalidActionError(f"{n_steps} observations need {n_steps - 1} actions, got {n_actions}")
    model = estimator.model
    location = np.empty((n_steps, model.n_cells))
    maps = np.empty((n_steps, model.n_cells, model.n_labels))
    evidence = np.empty(n_steps)
    start = time.perf_counter()
    for t in range(n_steps):
        belief = estimator.step(None if t == 0 else actions[t - 1], observations[t])
        location[t], maps[t], evidence[t] = belief.location, belief.map, belief.log_evidence
    seconds = (time.perf_counter() - start) / n_steps
    return Trajectory(location, maps, evidence, seconds)


def _length(name: str, values, error: type[OnlineMapError]) -> int:
    try:
        return len(values)
    except TypeError:  # a generator, a number...
        raise error(f"{name} must be a sequence (a list, tuple or array), got {type(values).__name__}") from None


def fork(estimator: Estimator) -> Estimator:
    """An independent copy of ``estimator`` for planning: stepping the copy (and drawing from its
    generator) never touches the original, and the copy continues exactly as the original would.

    The estimator's own ``fork()`` method is used if its class defines one (a faster copy);
    otherwise every instance attribute is deep-copied (arrays, the ``numpy.random.Generator``
    with its state, containers) while the read-only model, read-only arrays and the cached,
    immutable :class:`~onlinemap.belief.Belief` are shared. Cost: one copy of the state, O(state
    size) (RBPF: the block pool and the (P, N / B) table; exact: the (N, K**N) tensors).
    """
    own = getattr(type(estimator), "fork", None)
    if own is not None:
        return own(estimator)
    memo = {id(estimator.model): estimator.model}
    for value in vars(estimator).values():
        if isinstance(value, Belief) or (isinstance(value, np.ndarray) and not value.flags.writeable):
            memo[id(value)] = value
    return copy.deepcopy(estimator, memo)


def load(path: str | os.PathLike, *, strict_version: bool = False, allow_newer: bool = False):
    """Build the estimator saved in ``path`` (same name, model and options) and restore its state;
    the next ``step`` continues exactly where the saved one left off. Refuses (with
    :class:`CheckpointError`) a file of a newer format unless ``allow_newer``, and, with
    ``strict_version``, one written by another onlinemap version."""
    state = checkpoint.read(path)  # the file and its checksum verified
    checkpoint.check_header(state, strict_version=strict_version, allow_newer=allow_newer)
    try:
        model = checkpoint.decode_model(state["model"])
    except CheckpointError as error:
        raise CheckpointError(f"{path}: {error}") from None
    try:
        options = checkpoint.decode_options(state["options"])
    except CheckpointError as error:
        raise CheckpointError(f"{path}: {error}") from None
    try:
        est = make_estimator(str(state["estimator"]), model, **options)
    except OnlineMapError as error:  # an unknown estimator or option, an invalid option value
        raise CheckpointError(f"{path}: {error}") from None
    try:
        est.load_state_dict(state, strict_version=strict_version, allow_newer=allow_newer)
    except CheckpointError as error:
        raise CheckpointError(f"{path}: {error}") from None
    return est
