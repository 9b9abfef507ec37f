"""Invariants of every registered estimator's state, checked when a checkpoint is loaded.

A checkpoint's checksum catches damage, not a crafted file (whoever writes the file can
recompute it), so :func:`onlinemap.checkpoint.load_state_dict` checks every restored array
as the estimator's kernels require before the estimator takes it: shapes from the model and
options, index ranges, probabilities in [0, 1] summing to 1, reference counts consistent,
finite weights. No file can then make a kernel read or write outside its arrays, or an
estimator hand out an invalid belief.

Two kinds of checks, both on a read-only view of the candidate state (attribute access like
the estimator's; nothing is changed until every check has passed):

- :data:`CONSTANT`: attributes (or ``attribute.field`` of a state object) fixed by the model and
  options (tables, layouts, the options themselves); they must equal, bit for bit, those of the estimator the state is loaded into,
  which was built from the same model and options.
- :data:`STATE_CHECKS`: one function per estimator for the attributes that change as it steps.

Cost: O(state size) (one pass over every array), plus a bincount of the RBPF's table.
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np

from .belief import Belief
from .errors import CheckpointError

_ATOL = 1e-6  # probabilities must sum to 1 within this (rounding over long runs stays far below)

CONSTANT: dict[str, tuple[str, ...]] = {
    "exact": ("max_bytes", "_no_motion", "_flat"),
    "dead_reckoning": (),
    "bk": (),
    "online_em": ("window", "_window", "decay", "pseudo_count", "_prior_emission", "_sensor_inverse"),
    "offline_em": ("n_iter", "tol", "pseudo_count", "anneal", "_prior_emission", "_location_prior",
                   "_sensor_inverse"),
    "rbpf": ("n_particles", "proposal", "resampling", "resample_threshold", "lazy_dynamics", "_blocks.stamped",
             "_blocks.cell_block", "_blocks.cell_slot", "_blocks.block_members", "_blocks.powers"),
}


def fail(name: str, problem: str) -> None:
    raise CheckpointError(f"invalid state: attribute {name} {problem}")


def array(state, name: str, shape: tuple[int, ...] | None, dtype, *, ndim: int | None = None,
          written: bool = False) -> np.ndarray:
    """``state.name``: an ndarray of ``dtype`` and ``shape`` (or ``ndim``), writable if the
    estimator ``written`` into it in place. (``checkpoint`` checks every array's memory order.)"""
    value = getattr(state, name)
    if type(value) is not np.ndarray or value.dtype != np.dtype(dtype):
        fail(name, f"must be an array of {np.dtype(dtype)}, got {type(value).__name__} "
                    f"{getattr(value, 'dtype', '')}")
    if shape is not None and value.shape != tuple(shape):
        fail(name, f"must have shape {tuple(shape)}, got {value.shape}")
    if ndim is not None and value.ndim != ndim:
        fail(name, f"must have {ndim} dimensions, got {value.ndim}")
    if written and not value.flags.writeable:
        fail(name, "must be writable (the estimator updates it in place)")
    return value


def indices(name: str, values: np.ndarray, stop: int, start: int = 0) -> None:
    """Every entry in ``start .. stop - 1``."""
    if values.size and (values.min() < start or values.max() >= stop):
        fail(name, f"holds indices {values.min()}..{values.max()} outside {start}..{stop - 1}")


def probabilities(name: str, values: np.ndarray, *, rows: bool = True) -> None:
    """Finite, in [0, 1]; with ``rows``, each row (last axis) sums to 1 within 1e-6."""
    if not np.all(np.isfinite(values)) or np.any(values < 0) or np.any(values > 1 + _ATOL):
        fail(name, "must hold probabilities in [0, 1]")
    if rows and values.size and np.max(np.abs(values.sum(axis=-1) - 1)) > _ATOL:
        fail(name, "rows must sum to 1")


def integer(state, name: str, low: int, high: int) -> int:
    """``state.name``: an int (Python or numpy, not a bool) in ``low .. high``."""
    value = getattr(state, name)
    if not isinstance(value, (int, np.integer)) or isinstance(value, bool) or not low <= value <= high:
        fail(name, f"must be an int in {low}..{high}, got {value!r}")
    return value


def real(state, name: str, *, low: float = -math.inf, high: float = math.inf, nan: bool = False) -> float:
    """``state.name``: a float (Python or numpy) in [low, high] (NaN only if ``nan``)."""
    value = getattr(state, name)
    if not isinstance(value, (float, np.floating)) or not (low <= value <= high or (nan and math.isnan(value))):
        fail(name, f"must be a float in [{low}, {high}], got {value!r}")
    return value


def step_index(state) -> int:
    return integer(state, "_t", -1, 2**62)


def belief(state, *, required: bool) -> None:
    """``_belief``: None before the first step (or, unless ``required``, not built yet); else a
    Belief of step ``_t`` with valid location (N,) and map (N, K)."""
    value, t, model = state._belief, state._t, state.model
    if value is None:
        if required and t >= 0:
            fail("_belief", f"is missing after step {t}")
        return
    if type(value) is not Belief or t < 0 or value.t != t:
        fail("_belief", f"must be the Belief of step {t}")
    for field, shape in (("location", (model.n_cells,)), ("map", (model.n_cells, model.n_labels)),
                         ("observation_matrix", (model.n_cells, model.n_labels))):
        values = getattr(value, field)
        if values is None and field == "observation_matrix":
            continue
        if type(values) is not np.ndarray or values.shape != shape or values.dtype != np.float64:
            fail(f"_belief.{field}", f"must be a float64 array of shape {shape}")
        probabilities(f"_belief.{field}", values)
    if math.isinf(value.log_evidence) and value.log_evidence > 0:
        fail("_belief.log_evidence", "is +inf")


def log_evidence(state) -> None:
    """``_log_evidence``: a float, log of a probability (-inf allowed, NaN and positive values not)."""
    real(state, "_log_evidence", high=_ATOL)


# --- one function per estimator ---------------------------------------------------------------
def check_exact(state) -> None:
    model = state.model
    n, k = model.n_cells, model.n_labels
    step_index(state)
    x = array(state, "_x", (n, k**n), np.float64, written=True)
    norm = real(state, "_norm", low=np.finfo(float).tiny)
    if not np.all(np.isfinite(x)) or np.any(x < 0):
        fail("_x", "must be finite and non-negative")
    if abs(x.sum() / norm - 1) > _ATOL:
        fail("_x", f"sums to {x.sum()!r}, not to _norm = {norm!r}")
    log_evidence(state)
    belief(state, required=True)


def check_dead_reckoning(state) -> None:
    step_index(state)
    belief(state, required=True)


def check_bk(state) -> None:
    model = state.model
    step_index(state)
    probabilities("_location", array(state, "_location", (model.n_cells,), np.float64))
    probabilities("_maps", array(state, "_maps", (model.n_cells, model.n_labels), np.float64))
    log_evidence(state)
    belief(state, required=True)


def _run_record(state, steps: int) -> None:
    """``_actions`` (steps - 1 or fewer,) and ``_observations`` (steps,) or (steps, F) with a
    sensor footprint, as the EM estimators keep them."""
    model = state.model
    observations = array(state, "_observations", (steps,) + model.observation_shape, np.int64)
    actions = array(state, "_actions", (max(steps - 1, 0) if state._t < steps else steps,), np.int64)
    off_grid = bool(model.off_grid_patterns.any())  # footprint readings may be -1
    indices("_observations", observations, model.n_labels, start=-1 if off_grid else 0)
    indices("_actions", actions, model.n_actions)


def check_online_em(state) -> None:
    model = state.model
    n, k = model.n_cells, model.n_labels
    t = step_index(state)
    window = state._window
    kept = t + 1 if window is None else min(t + 1, window)
    _run_record(state, kept)
    filtered = array(state, "_filtered", (0 if window is None else kept, n), np.float64, written=True)
    probabilities("_filtered", filtered)
    probabilities("_emission", array(state, "_emission", (n, k), np.float64))
    stats = array(state, "_stats", (n, k), np.float64)
    if not np.all(np.isfinite(stats)) or np.any(stats < 0):
        fail("_stats", "must be finite and non-negative")
    log_evidence(state)
    belief(state, required=True)


def check_offline_em(state) -> None:
    _run_record(state, step_index(state) + 1)
    belief(state, required=True)


def check_rbpf(state) -> None:
    """The particles, their weights and the copy-on-write block pool (:meth:`BlockPool.check
    <onlinemap.estimators.block_pool.BlockPool.check>`)."""
    model = state.model
    n, k, p = model.n_cells, model.n_labels, state.n_particles
    t = step_index(state)
    indices("_locations", array(state, "_locations", (p,), np.int64, written=True), n)
    log_weights = array(state, "_log_weights", (p,), np.float64)
    if np.any(np.isnan(log_weights)) or np.any(log_weights == math.inf) or not np.any(np.isfinite(log_weights)):
        fail("_log_weights", "must be finite or -inf, at least one finite")
    top = float(log_weights.max())
    if abs(top + math.log(float(np.exp(log_weights - top).sum()))) > _ATOL:
        fail("_log_weights", "must be normalised (log-sum-exp 0)")
    weights = array(state, "_weights", (p,), np.float64)
    if weights.tobytes() != np.exp(log_weights).tobytes():
        fail("_weights", "must equal exp(_log_weights)")
    real(state, "_ess", low=0.0, high=float(p))
    log_evidence(state)
    if type(state._resampled) is not bool:
        fail("_resampled", "must be a bool")
    if type(state.recover_from_depletion) is not bool:
        fail("recover_from_depletion", "must be a bool")
    integer(state, "_recoveries", 0, max(t, 0))  # at most one per step, none at step 0
    if type(state._recovered) is not bool or (state._recovered and (t < 1 or state._recoveries < 1)):
        fail("_recovered", "must be a bool, True only after a step >= 1 that counted a recovery")
    state._blocks.check(p, k, t)  # the copy-on-write pool (estimators/block_pool.py); its kind was checked
    belief(state, required=False)


STATE_CHECKS: dict[str, Callable[[object], None]] = {
    "exact": check_exact, "dead_reckoning": check_dead_reckoning, "bk": check_bk,
    "online_em": check_online_em, "offline_em": check_offline_em, "rbpf": check_rbpf,
}
