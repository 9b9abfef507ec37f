"""Exceptions raised by onlinemap, and the warnings it issues.

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


class FloorFileError(ModelError):
    """A floor file (a MovingAI ``.map``, a ROS ``.yaml`` or a ``.pgm``) cannot be read: not a
    regular file, too large, malformed, or too many cells at the cell size asked for. Raised
    before the pixels are read wherever the header already says so."""


class MissingDependencyError(OnlineMapError):
    """An optional package a feature needs is not installed (the message says how to install it)."""


class UnknownEstimatorError(OnlineMapError, KeyError):
    """``make_estimator`` was given a name that is not in the registry, or an unknown option."""

    __str__ = ValueError.__str__


class PerformanceWarning(UserWarning):
    """An estimator is used in a way that costs far more than another way to the same answer
    (``offline_em`` stepped through a recorded run re-fits on all data at every step; its
    ``fit`` fits once). Silence it with ``warnings.simplefilter("ignore", PerformanceWarning)``."""


class FloorFileWarning(UserWarning):
    """A floor file was read, with something the user should know: a ``.map`` without its
    ``type octile`` line, a ``cell_size`` that is not a whole number of pixels, an ``origin``
    yaw that is ignored."""


class SmallRegionWarning(FloorFileWarning):
    """The start of a floor read from a file reaches only a small part of its free cells (the
    cell size or cell rule closed its doorways, or the start is in a closet)."""


class LargeFloorWarning(FloorFileWarning):
    """A floor read from a file without ``cell_size`` has so many cells that every estimator
    step and plan is slow; the message gives the cell count and the cost of a step."""
