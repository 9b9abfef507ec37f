"""The RBPF's checkpointed state (:class:`~onlinemap.estimators.rbpf.RaoBlackwellisedPF`): older
formats' attributes upgraded to the current one, and the invariants a restored state must hold
(:mod:`onlinemap.state_checks`). O(the state's size).
"""

from __future__ import annotations

import math

import numpy as np

from .. import state_checks as checks
from ..checkpoint import state_class, state_node
from ..kernels.rbpf_context import READ
from ..label_prior import CONTEXT, CONTEXT_KINDS, PARTICLE_CONTEXT, ContextTable, n_context_codes
from .block_pool import FORMAT_1_ATTRIBUTES, BlockPool
from .rbpf_move import PathHistory

# the option context_table is checkpointed field by field, rebuilt through its checks (a bad one: CheckpointError)
state_class(ContextTable)


def upgrade_attributes(attributes: dict, version: int) -> dict:
    """A checkpoint's encoded attributes of format ``version`` as the current format has them:
    version 1 kept the block pool as 13 loose attributes (``_pool``, ``_table``...), gathered
    here into ``_blocks`` (the checks on load then validate it as any other); versions 1 and 2
    had no recovery from depletion (a filter that never recovered, with recovery on:
    ``_recoveries`` 0, ``_recovered`` False, ``recover_from_depletion`` True); versions 1 to 3
    had no resample-move step (``_history`` None: its option ``move_window`` takes its
    default, None, on load). O(1)."""
    if version == 1 and all(name in attributes for name in FORMAT_1_ATTRIBUTES):
        fields = {field: attributes.pop(name) for name, field in FORMAT_1_ATTRIBUTES.items()}
        attributes["_blocks"] = state_node(BlockPool, fields)
    if version <= 2:
        attributes.setdefault("recover_from_depletion", True)
        attributes.setdefault("_recoveries", 0)
        attributes.setdefault("_recovered", False)
    if version <= 3:
        attributes.setdefault("_history", None)
        attributes.setdefault("move_window", None)
        attributes.setdefault("move_every", 10)
        attributes.setdefault("move_lag", 100)
    return attributes

def check_state(state) -> None:
    """The invariants of a restored state (:mod:`onlinemap.state_checks`): the particles, their
    weights, the copy-on-write block pool (:meth:`BlockPool.check
    <onlinemap.estimators.block_pool.BlockPool.check>`) and, with ``label_prior="learn"``, the
    label frequencies (positive, summing to 1: a Dirichlet posterior mean); with ``"context"`` or
    ``"particle_context"`` (:func:`check_context`) the frequencies and the context state."""
    model = state.model
    n, k, p = model.n_cells, model.n_labels, state.n_particles
    t = checks.step_index(state)
    checks.indices("_locations", checks.array(state, "_locations", (p,), np.int64, written=True), n)
    log_weights = checks.array(state, "_log_weights", (p,), np.float64)
    if np.any(np.isnan(log_weights)) or np.any(log_weights == math.inf) or not np.any(np.isfinite(log_weights)):
        checks.fail("_log_weights", "must be finite or -inf, at least one finite")
    top = float(log_weights.max())
    if abs(top + math.log(float(np.exp(log_weights - top).sum()))) > checks.ATOL:
        checks.fail("_log_weights", "must be normalised (log-sum-exp 0)")
    weights = checks.array(state, "_weights", (p,), np.float64)
    if weights.tobytes() != np.exp(log_weights).tobytes():
        checks.fail("_weights", "must equal exp(_log_weights)")
    checks.real(state, "_ess", low=0.0, high=float(p))
    checks.log_evidence(state)
    if type(state._resampled) is not bool:
        checks.fail("_resampled", "must be a bool")
    if type(state.recover_from_depletion) is not bool:
        checks.fail("recover_from_depletion", "must be a bool")
    checks.integer(state, "_recoveries", 0, max(t, 0))  # at most one per step, none at step 0
    if type(state._recovered) is not bool or (state._recovered and (t < 1 or state._recoveries < 1)):
        checks.fail("_recovered", "must be a bool, True only after a step >= 1 that counted a recovery")
    state._blocks.check(p, k, t)  # the copy-on-write pool (estimators/block_pool.py); its kind was checked
    moving = state.move_window is not None  # CONSTANT_STATE: what the options give
    if moving != isinstance(state._history, PathHistory):
        checks.fail("_history", f"must be {'a PathHistory' if moving else 'None'} with move_window="
                                f"{state.move_window!r}")
    if moving:
        state._history.check(model, state._locations, t)  # estimators/rbpf_move.py
    frequencies = getattr(state, "_label_frequencies", None)  # label_prior="learn" only (rbpf_prior.py)
    if frequencies is not None:
        frequencies = checks.array(state, "_label_frequencies", (k,), np.float64)
        if not np.all(np.isfinite(frequencies)) or np.any(frequencies <= 0) or np.any(frequencies > 1) \
                or abs(frequencies.sum() - 1) > checks.ATOL:
            checks.fail("_label_frequencies", "must be label frequencies in (0, 1] summing to 1")
    check_context(state, n, k)
    checks.belief(state, required=False)


def check_context(state, n: int, k: int) -> None:
    """The invariants of ``label_prior="context"``'s state (:class:`~onlinemap.label_prior.ContextState`)
    in a filter of N = ``n`` cells and K = ``k`` labels: present exactly when the options ask for
    it (with the learned frequencies), every cell's tilt (N, K) positive rows summing to 1 (the
    retilt divides by them), the cells read (N,) bool, their frozen contexts (N,) -1 exactly
    where not read and a context code (0 .. (K + 2)^4 - 1) where read. ``"particle_context"``:
    the cells read and frozen contexts likewise, no per-cell tilts, the particles' cell statuses
    (P, N) uint8 in {0, 1, 2} and the table of ratios, None or ((K + 2)^4, K) positive and finite
    (:func:`check_particle_context`). O(N K + P N)."""
    label_prior = state.options.get("label_prior")
    named = label_prior if isinstance(label_prior, str) else None
    wanted = {"_context_tilts": named == CONTEXT, "_context_read": named in CONTEXT_KINDS,
              "_context_frozen": named in CONTEXT_KINDS, "_particle_cells": named == PARTICLE_CONTEXT}
    for name, there in wanted.items():
        if (getattr(state, name, None) is not None) != there:
            checks.fail(name, f"must be {'an array' if there else 'None'} with label_prior={label_prior!r}")
    if named not in CONTEXT_KINDS:
        if getattr(state, "_context_ratios", None) is not None:
            checks.fail("_context_ratios", f"must be None with label_prior={label_prior!r}")
        return
    if getattr(state, "_label_frequencies", None) is None:
        checks.fail("_label_frequencies", f"must be the learned frequencies with label_prior={named!r}")
    if named == CONTEXT:
        tilts = checks.array(state, "_context_tilts", (n, k), np.float64)
        checks.probabilities("_context_tilts", tilts)
        if np.any(tilts <= 0):
            checks.fail("_context_tilts", "must be positive (a backed-off predictive)")
    read = checks.array(state, "_context_read", (n,), np.bool_)
    frozen = checks.array(state, "_context_frozen", (n,), np.int64)
    if np.any(frozen[~read] != -1):
        checks.fail("_context_frozen", "must be -1 at every cell not read")
    checks.indices("_context_frozen", frozen[read], n_context_codes(k))
    if named == PARTICLE_CONTEXT:
        check_particle_context(state, n, k)


def check_particle_context(state, n: int, k: int) -> None:
    """``label_prior="particle_context"``'s own state: the cell statuses (P, N) uint8, each
    untouched, tilted or read (``kernels/rbpf_context.py``), and the table of ratios ``v' / pi``,
    None before the first learning step or ((K + 2)^4, K) positive and finite. O(P N)."""
    status = checks.array(state, "_particle_cells", (state.n_particles, n), np.uint8)
    if np.any(status > READ):
        checks.fail("_particle_cells", f"must hold cell statuses 0 (untouched), 1 (tilted) or {READ} (read)")
    ratios = getattr(state, "_context_ratios", None)
    if ratios is not None:
        ratios = checks.array(state, "_context_ratios", (n_context_codes(k), k), np.float64)
        if not np.all(np.isfinite(ratios)) or np.any(ratios <= 0):
            checks.fail("_context_ratios", "must be positive and finite (tilts of a cell's prior)")
