"""Exceptions raised by onlinemap, and the one warning it issues.

Every error is a ``ValueError`` subclass (``MemoryLimitError`` is also a ``MemoryError``) so
callers can catch broadly, or precisely by type. An estimator that raises one of these from
``step`` has left its state exactly as it was before the call.
"""

from __future__ import annotations


class OnlineMapError(ValueError):
    """Base class of every onlinemap error."""


class ModelError(OnlineMapError):
    """A model's tables or parameters are invalid (shapes, NaN, probabilities, rows not summing to 1)."""


class InvalidOptionError(ModelError):
    """An estimator option is of the wrong type or out of range (a :class:`ModelError` too, as
    option errors were before this class existed)."""


class InvalidActionError(OnlineMapError):
    """An action is out of range, of the wrong type, unknown by name, or given at the wrong step."""


class StepIndexError(OnlineMapError, IndexError):
    """A step asked of a :class:`~onlinemap.estimators.Trajectory` is not an integer in ``-T..T-1``."""


class InvalidObservationError(OnlineMapError):
    """An observation is out of range, of the wrong type, NaN or unknown by name."""


class ImpossibleObservationError(OnlineMapError):
    """An observation has probability zero under the model given everything seen so far."""


class MemoryLimitError(OnlineMapError, MemoryError):
    """An estimator would need more memory than its limit allows; nothing was allocated."""


class CheckpointError(OnlineMapError):
    """A checkpoint file is truncated, tampered with, of another version, or does not match the
    estimator or model it is loaded into; or an estimator's state cannot be checkpointed."""


class MissingDependencyError(OnlineMapError):
    """An optional package a feature needs is not installed (the message says how to install it)."""


class UnknownEstimatorError(OnlineMapError, KeyError):
    """``make_estimator`` was given a name that is not in the registry, or an unknown option."""

    __str__ = ValueError.__str__


class PerformanceWarning(UserWarning):
    """An estimator is used in a way that costs far more than another way to the same answer
    (``offline_em`` stepped through a recorded run re-fits on all data at every step; its
    ``fit`` fits once). Silence it with ``warnings.simplefilter("ignore", PerformanceWarning)``."""
