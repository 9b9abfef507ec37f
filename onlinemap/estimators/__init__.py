"""Estimators: one module each, one protocol (:class:`Estimator`), one registry.

Importing this package registers every built-in estimator.
"""

from .base import (Estimator, Trajectory, available_estimators, estimator_class, estimator_options, fork, load,
                   make_estimator, register, run_estimator)
from . import dead_reckoning, exact  # noqa: F401  (registration)
from . import offline_em, online_em  # noqa: F401  (registration)
from . import bk, rbpf  # noqa: F401  (registration)
from .exact import SmoothResult, exact_smooth

__all__ = ["Estimator", "Trajectory", "available_estimators", "estimator_class", "estimator_options", "fork",
           "make_estimator", "register", "run_estimator", "load", "exact_smooth", "SmoothResult"]
