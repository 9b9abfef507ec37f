"""Checks of step inputs, shared by every estimator.

They turn an action or observation given by index or by name into an index, or raise the
specific error naming the problem. They never touch an estimator's state.
"""

from __future__ import annotations

import math
import numbers

import numpy as np

from .errors import InvalidActionError, InvalidObservationError, ModelError
from .model import GridModel


_INTS = (int, np.int64, np.int32)


def _index(value, names: tuple[str, ...], what: str, error: type[Exception]) -> int:
    if type(value) in _INTS and 0 <= value < len(names):  # the common case, checked first
        return int(value)
    if isinstance(value, (str, np.str_)):
        try:
            return names.index(str(value))
        except ValueError:
            raise error(f"unknown {what} name {value!r}; expected one of {names}") from None
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise error(f"{what} must be an int index or a name, got {type(value).__name__} {value!r}")
    if isinstance(value, numbers.Integral):
        index = int(value)
    else:
        if not math.isfinite(value):
            raise error(f"{what} is {value!r}; expected an int index in 0..{len(names) - 1}")
        if value != int(value):  # exact for floats and Fractions alike
            raise error(f"{what} {value!r} is not a whole number")
        index = int(value)
    if not 0 <= index < len(names):
        raise error(f"{what} {index} is out of range 0..{len(names) - 1} ({names})")
    return index


def action_index(model: GridModel, action) -> int:
    """Index of an action given as an int (or integral float) or a name in ``model.action_names``."""
    return _index(action, model.action_names, "action", InvalidActionError)


def observation_index(model: GridModel, observation) -> int:
    """Index of an observation given as an int or a label name in ``model.label_names``."""
    return _index(observation, model.label_names, "observation", InvalidObservationError)


def observation_value(model: GridModel, observation):
    """An observation as the estimators take it: an int label (footprint of one offset that never
    leaves the grid, the paper's sensor: exactly :func:`observation_index`), or else an int (F = 1)
    or a fresh (F,) int64 array of readings, each a label (index or name) where the offset's cell
    exists and -1 where it is off the grid. A wrong length, or -1 readings that match no location's
    off-grid offsets (a -1 where a cell exists, a label where none exists), raise
    :class:`InvalidObservationError`. Cost O(F U), U the number of distinct off-grid patterns."""
    if model.reads_own_cell:
        if isinstance(observation, (list, tuple)) or isinstance(observation, np.ndarray) and observation.ndim:
            raise InvalidObservationError(
                f"observation must be an int index or a label name, got {type(observation).__name__} "
                f"{_short(observation)}: this sensor reads one cell (footprint {model.footprint}); a list of "
                "readings needs a model with a sensor footprint (footprint=cross or square in a world spec, "
                "grid_model(..., footprint=...))")
        return observation_index(model, observation)
    single = model.n_readings == 1
    if single:
        readings = [observation]
    else:
        if isinstance(observation, (str, bytes, np.str_)) or not hasattr(observation, "__len__"):
            raise InvalidObservationError(
                f"the footprint reads {model.n_readings} cells; an observation is a sequence of "
                f"{model.n_readings} labels (-1 off the grid), got {observation!r}")
        if isinstance(observation, np.ndarray) and observation.ndim != 1:  # as a nested list is refused
            raise InvalidObservationError(f"an observation is ({model.n_readings},) readings, got an array of "
                                          f"shape {observation.shape}")
        readings = list(observation)
        if len(readings) != model.n_readings:
            raise InvalidObservationError(f"observation has {len(readings)} readings; the footprint "
                                          f"{model.footprint} reads {model.n_readings}")
    values = np.array([-1 if _is_off_grid(r) else observation_index(model, r) for r in readings], dtype=np.int64)
    _check_off_grid(model, values[None])
    return int(values[0]) if single else values


def _short(value, limit: int = 80) -> str:
    """``repr(value)``, cut to ``limit`` characters (a value may be megabytes long)."""
    text = repr(value)
    return text if len(text) <= limit else f"{text[:limit]}..."


def _is_off_grid(reading) -> bool:
    return type(reading) in _INTS and reading == -1 or \
        isinstance(reading, numbers.Real) and not isinstance(reading, (bool, np.bool_)) and reading == -1


def _check_off_grid(model: GridModel, values: np.ndarray) -> None:
    """values (T, F): every row's -1 mask must be the off-grid mask of some location. O(T F U)."""
    masks = values < 0
    fits = (masks[:, None, :] == model.off_grid_patterns[None]).all(axis=2).any(axis=1)
    if not fits.all():
        t = int(np.argmin(fits))
        raise InvalidObservationError(
            f"observation {values[t].tolist()}{f' (step {t})' if len(values) > 1 else ''}: its -1 readings "
            f"(offsets {np.flatnonzero(masks[t]).tolist()}) match the off-grid offsets of no location; "
            f"a reading is -1 exactly where its offset {model.footprint} leaves the grid")


def check_map(model: GridModel, true_map) -> np.ndarray:
    """A true map as a fresh (N,) int64 array of labels in 0..K - 1, or :class:`ModelError`."""
    labels = np.array(true_map, dtype=np.int64)
    if labels.shape != (model.n_cells,):
        raise ModelError(f"true_map must be ({model.n_cells},) labels in 0..{model.n_labels - 1}, "
                         f"got shape {labels.shape}")
    if labels.size and (labels.min() < 0 or labels.max() >= model.n_labels):
        raise ModelError(f"true_map must be ({model.n_cells},) labels in 0..{model.n_labels - 1}, "
                         f"got labels {labels.min()}..{labels.max()}")
    return labels


def check_step(model: GridModel, t: int, action, observation) -> tuple[int | None, int]:
    """Validate the inputs of step number ``t`` (0 for the first): ``action`` must be None at
    t = 0 and a valid action afterwards. Returns ``(action index or None, observation)``, the
    observation as :func:`observation_value` gives it (an int, or an (F,) array for a footprint)."""
    if t == 0:
        if action is not None:
            raise InvalidActionError(f"the first step takes no action (got {action!r}); call step(None, z0)")
        a = None
    else:
        if action is None:
            raise InvalidActionError(f"step {t} needs an action; None is only for the first step")
        a = action_index(model, action)
    return a, observation_value(model, observation)


def check_sequence(model: GridModel, actions, observations) -> tuple[np.ndarray, np.ndarray]:
    """Validate a whole run: ``observations`` (T,), ``actions`` (T - 1,) or (T,) with a leading
    None / -1 placeholder. Returns int arrays ``(actions (T - 1,), observations (T,))``, the
    observations (T, F) when the footprint reads F > 1 cells."""
    if not model.reads_own_cell:
        observations = _footprint_observations(model, observations)
    else:
        observations = _as_sequence(observations)
    actions = _as_sequence(actions)
    if len(observations) == 0:
        raise InvalidObservationError("a run needs at least one observation")
    if len(actions) == len(observations) and (actions[0] is None or actions[0] == -1):
        actions = actions[1:]
    if len(actions) != len(observations) - 1:
        raise InvalidActionError(f"{len(observations)} observations need {len(observations) - 1} actions, "
                                 f"got {len(actions)}")
    a = _indices(actions, model.action_names)
    if a is None:
        a = np.array([action_index(model, x) for x in actions], dtype=np.int64)
    z = observations if not model.reads_own_cell else \
        _indices(observations, model.label_names)
    if z is None:
        z = np.array([observation_index(model, x) for x in observations], dtype=np.int64)
    return a, z


def _footprint_observations(model: GridModel, observations) -> np.ndarray:
    """(T,) or (T, F) int64 readings of a footprint model, checked as :func:`observation_value`."""
    shape = model.observation_shape
    if type(observations) is np.ndarray and observations.dtype.kind in "iu" and \
            observations.shape[1:] == shape and observations.ndim == 1 + len(shape):
        values = observations.astype(np.int64)
        if values.size and (values.min() < -1 or values.max() >= model.n_labels):
            bad = values[(values < -1) | (values >= model.n_labels)][0]
            raise InvalidObservationError(f"observation reading {int(bad)} is out of range -1..{model.n_labels - 1}")
        _check_off_grid(model, values.reshape(len(values), -1))
        return values
    return np.array([observation_value(model, z) for z in observations], dtype=np.int64).reshape((-1,) + shape)


def _as_sequence(values):
    """A 1-d integer array as it is (for the vectorised check), anything else as a list."""
    if type(values) is np.ndarray and values.ndim == 1 and values.dtype.kind in "iu":
        return values
    return list(values)


def _indices(values, names: tuple[str, ...]) -> np.ndarray | None:
    """A fresh int64 copy of a 1-d integer array whose entries all lie in 0..len(names) - 1 (one
    vectorised range check); None otherwise (the caller then checks entry by entry and raises)."""
    if type(values) is not np.ndarray:
        return None
    if values.size and not (values.min() >= 0 and values.max() < len(names)):
        return None
    return values.astype(np.int64)
