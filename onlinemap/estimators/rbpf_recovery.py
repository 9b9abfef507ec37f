"""The RBPF's recovery from particle depletion (:class:`~onlinemap.estimators.rbpf.RaoBlackwellisedPF`):
the relocated children of the live particles, P of them kept by optimal resampling and placed in
the slots with the cells they carry, and the messages of the steps nothing explains.

When no particle explains an observation the model allows (every trajectory that did was dropped; in
a blocking world with a footprint, the off-grid readings -1 rule particles out exactly), the filter
*recovers*: it takes the exact limit of an augmented model. In it the robot, with probability eps,
is lifted and put down on a passable cell l drawn from ``K(l | l') = exp(-d(l, l') / s) / Z(l')``
instead of following T (d the fewest moves from its last cell l', labels ignored; ``s =
RELOCATION_SCALE`` = 3 cells; Z sums over the cells reachable from l'); and, after such a relocation
only, each cell it then reads is, with probability delta, redrawn from its model marginal
``label_prior C^t``. Given the particle set (weights w_p, cells l_p, maps m_p) the posterior is ``(1
- eps) R + eps sum_r delta^r S_r`` (up to factors ``1 - delta`` that tend to 1): R the regular
children, S_r the relocated ones with r read cells redrawn. R = 0 here, so as eps, delta -> 0 it
tends to S_r for the smallest r with S_r > 0: children (p, l) weighted ``w_p K(l | l_p) P(z, m_l
passable | l, m_p)`` where each read cell keeps m_p's marginal unless that marginal rules out its
reading (then it takes the model marginal: r such cells). P of these children (N P at most) are kept
by optimal resampling, as Fearnhead-Clifford keeps its children. The recovered belief is thus the
filter's best account of the data given that the robot was somewhere other than its particles say:
it approximates ``P(L_t, M_t | data)`` under the augmented model, with the particles before the step
standing in for the past; it is not the model's posterior (which the lost trajectories carried).
``log_evidence`` adds the log of the children's total weight, the evidence given the relocation (the
vanishing ``log eps`` left out). The step's belief has ``recovered=True``, :attr:`recoveries` counts
such steps (checkpointed), and a warning on the logger ``onlinemap.estimators.rbpf`` names the step
and what was done.

Cost: O(P N U K^2 + min(P, N) N A) time (U <= W the cells a child touches, A the actions), at
most 32 P N bytes (:func:`~onlinemap.estimators.rbpf_memory.recovery_bytes`).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ..kernels.rbpf_commit import Staged
from ..kernels.rbpf_recovery import rbpf_place_children, rbpf_relocated_children, rbpf_relocation_weights
from ..model import GridModel
from ..resampling import optimal_keep
from .rbpf_kernels import world_tables
from .rbpf_memory import cells_written

RELOCATION_SCALE = 3.0  # cells: the length scale of the recovery's relocation kernel exp(-d / scale)


class Relocation(NamedTuple):
    """A recovering step's slots: each slot's ``ancestors`` (P,), its writes (``staged``: the
    relocated location and the cells it carries), its normalised ``log_weights`` (P,); the
    evidence ``increment``, whether a child was dropped (``resampled``), the fewest read cells
    reset (``resets``) and the children kept (``kept``)."""

    ancestors: np.ndarray
    staged: Staged
    log_weights: np.ndarray
    increment: float
    resampled: bool
    resets: int
    kept: int


def logsumexp(x: np.ndarray, scratch: np.ndarray | None = None) -> float:
    """``log sum exp(x)`` (-inf if every entry is); ``scratch`` (len(x),), if given, holds the
    terms instead of a fresh array."""
    top = float(np.max(x))
    if top == -math.inf:
        return -math.inf
    terms = np.subtract(x, top, out=scratch)
    return top + math.log(float(np.exp(terms, out=terms).sum()))


def recovery_note(model: GridModel, z, t: int, parents: int, relocation: Relocation, count: int) -> str:
    """The warning a filter logs for step t, which recovered from depletion (observation ``z``,
    ``parents`` live particles relocated, ``relocation``: :func:`relocate`'s; recovery ``count`` of
    the filter)."""
    resets = f" and resetting {relocation.resets} read cell(s) to their prior" if relocation.resets else ""
    return (f"rbpf step {t}: no particle explains observation {describe(model, z)} (particle depletion); recovered "
            f"by relocating the {parents} live particles near their last cells (kernel exp(-d / {RELOCATION_SCALE:g}),"
            f" d in moves){resets}; {relocation.kept} children kept (recovery {count} of this filter)")


def relocate(model: GridModel, pool, locations: np.ndarray, log_weights: np.ndarray, t: int, z,
             rng: np.random.Generator) -> Relocation | None:
    """The recovery of step t from the particles (``locations``, ``log_weights`` (P,), maps
    ``pool``): every live particle p and cell l make a child weighted ``w_p K(l | l_p) P(z, l
    passable | l, map_p)``, with the fewest read cells reset to their model marginal ``label_prior
    C^t`` that make it possible (:func:`~onlinemap.kernels.rbpf_recovery.rbpf_relocation_weights`);
    P of them are kept by optimal resampling with one uniform of ``rng`` (the strata walk them by
    location, as Fearnhead-Clifford's do), their maps built
    (:func:`~onlinemap.kernels.rbpf_recovery.rbpf_relocated_children`) and placed in the slots
    (:func:`~onlinemap.kernels.rbpf_recovery.rbpf_place_children`). None, drawing nothing, when no
    child is possible."""
    n_particles = len(locations)
    readings = np.atleast_1d(np.asarray(z, dtype=np.int64))
    prior = np.array(model.label_prior if model.is_static else  # a writable copy: one kernel compile
                     model.label_prior @ np.linalg.matrix_power(model.change, t), order="C")
    child_log_weight = np.empty((model.n_cells, n_particles))
    world = world_tables(model)
    fewest = rbpf_relocation_weights(locations, log_weights, pool, world, t, RELOCATION_SCALE, readings, prior,
                                     child_log_weight)
    if fewest < 0:
        return None
    weights = child_log_weight.ravel()  # children ordered by location, then parent
    increment = logsumexp(weights)
    weights -= increment
    np.exp(weights, out=weights)  # in place: N P floats are the recovery's largest array
    kept, kept_weights, threshold = optimal_keep(weights, n_particles, rng.random(), np.arange(len(weights)))
    width, k = cells_written(model), model.n_labels
    child_location, child_parent = np.divmod(kept, n_particles)
    child_ids = np.empty((len(kept), width), dtype=np.int64)
    child_cells = np.empty((len(kept), width, k))
    rbpf_relocated_children(child_parent, child_location, pool, world, t, readings, prior, child_ids, child_cells)
    ancestors = np.empty(n_particles, dtype=np.int64)
    staged = Staged(np.empty(n_particles, dtype=np.int64), np.empty((n_particles, width), dtype=np.int64),
                    np.empty((n_particles, width, k)), None, None)
    slot_log_weights = np.empty(n_particles)
    rbpf_place_children(child_parent, child_location, child_ids, child_cells, np.arange(len(kept)), kept_weights,
                        ancestors, staged.locations, staged.ids, staged.cells, slot_log_weights)
    return Relocation(ancestors, staged, slot_log_weights - logsumexp(slot_log_weights), increment, threshold > 0,
                      fewest, len(kept))


def no_particle_explains(model: GridModel, z, t: int, n_particles: int) -> str:
    """The message of a depleted step with recovery off: the filter cannot tell an observation
    impossible under the model from one only its lost trajectories explained."""
    return (f"observation {describe(model, z)} has probability zero for every one of the {n_particles} "
            f"particles at step {t}: either it is impossible under the model given the past, or the particles "
            f"have lost every trajectory that explains it (particle depletion; recover_from_depletion is False). "
            f"The filter is unchanged")


def impossible(model: GridModel, z, t: int, n_particles: int) -> str:
    """The message of an observation nothing explains, even relocated (:func:`relocate`)."""
    where = ("at the start cell (step 0: no motion yet)" if t == 0 else
             "and no cell the robot could be relocated to explains it with labels the model allows at that step")
    return (f"observation {describe(model, z)} has probability zero for every one of the {n_particles} "
            f"particles at step {t}, {where}: it is impossible under the model. The filter is unchanged")


def describe(model: GridModel, z) -> str:
    """An observation for an error message: a label name, or the readings of a footprint."""
    if np.ndim(z) == 0 and 0 <= int(z) < model.n_labels:
        return repr(model.label_names[int(z)])
    return str([model.label_names[int(r)] if r >= 0 else -1 for r in np.atleast_1d(z)])
