"""onlinemap: learning grid maps online with a robot that does not know where it is.

>>> import onlinemap as om
>>> model = om.corridor(8, p_obs=0.9, p_move=0.8)
>>> est = om.make_estimator("exact", model)
>>> belief = est.step(None, 0)
"""

from __future__ import annotations

from ._version import __version__

import importlib

from . import checkpoint, errors, metrics, scenarios
from .belief import Belief
from .buildings import building
from .checkpoint import save
from .errors import (CheckpointError, ImpossibleObservationError, InvalidActionError, InvalidObservationError,
                     InvalidOptionError, MemoryLimitError, ModelError, OnlineMapError, PerformanceWarning,
                     UnknownEstimatorError)
from .estimators import (Estimator, SmoothResult, Trajectory, available_estimators,
                         estimator_options, exact_smooth, load, make_estimator, register, run_estimator)
from .layouts import read_layout
from .model import DOOR_WORLD_10X10, GridModel, corridor, door_world, grid_model
from .simulate import Run, random_walk, sample_map, simulate, there_and_back

# Heavy parts (sweeps: pandas I/O, dask, matplotlib; plots) load on first use, so that
# ``import onlinemap`` stays fast and never imports matplotlib, dask, the CLI or ``policies``.
_LAZY = {"sweep": "sweeps", "load_spec": "sweeps", "summarize": "sweeps", "SpecError": "sweeps",
         "SweepError": "sweeps", "sweeps": None, "plots": None, "studies": None,
         "peers": None, "bench": None, "cli": None, "envs": None,
         "fit_layered_map": "layered_em", "LayeredMap": "layered_em", "layered_em": None,
         "hindsight_map": "hindsight", "HindsightMap": "hindsight", "hindsight": None}
#: modules that moved into the studies layer: the error says where
MOVED = {"compare": "onlinemap.studies.accuracy", "reproduce": "onlinemap.studies.corridor",
         "mapping_studies": "onlinemap.studies.mapping"}


def __getattr__(name: str):
    if name in MOVED:
        raise AttributeError(f"onlinemap.{name} moved to {MOVED[name]} (every study lives in onlinemap.studies)")
    if name not in _LAZY:
        raise AttributeError(f"module 'onlinemap' has no attribute {name!r}")
    module = importlib.import_module(f".{_LAZY[name] or name}", __name__)
    value = module if _LAZY[name] is None else getattr(module, name)
    globals()[name] = value
    return value

__all__ = [
    "Belief", "Estimator", "GridModel", "Run", "SmoothResult", "Trajectory",
    "corridor", "door_world", "grid_model", "DOOR_WORLD_10X10", "building", "read_layout",
    "simulate", "random_walk", "there_and_back", "sample_map",
    "make_estimator", "register", "available_estimators", "estimator_options", "run_estimator",
    "exact_smooth", "metrics", "scenarios", "errors", "checkpoint", "save", "load",
    "OnlineMapError", "CheckpointError", "ModelError", "InvalidActionError", "InvalidObservationError",
    "ImpossibleObservationError", "InvalidOptionError", "MemoryLimitError", "UnknownEstimatorError",
    "PerformanceWarning",
    "sweep", "load_spec", "summarize", "SpecError", "SweepError", "fit_layered_map", "LayeredMap",
    "hindsight_map", "HindsightMap",
]
