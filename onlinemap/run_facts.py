"""What the metrics need of a run alone, whatever the beliefs scored on it: the cells visited, read
and ever readable, the floor distances of the honest metrics, the way back of a there-and-back
run, the yardstick of a robot told its true location at every step (:func:`told_location`) and
its mirror, the location of a robot told the true map (:func:`told_map_location`).
:func:`run_facts` computes them once per run for the last few runs, as a sweep scores every
estimator of a run one after the other. :mod:`onlinemap.evaluate` scores beliefs against them.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import numpy as np

from . import metrics
from .arrays import read_only
from .errors import ImpossibleObservationError, ModelError
from .hmm import forward_filter
from .label_prior import fixed_point_frequencies, resolve_label_prior
from .metric_names import CONFIDENT
from .model import GridModel, apply_motion
from .simulate import Run


class CellCounts(NamedTuple):
    """Three readings of "wrong cells" of a map belief (N, K) against the true labels (N,)."""

    wrong: int  # the most probable label is not the true one (ties: the lowest label wins)
    unsure_or_wrong: int  # not (the true label is the most probable, with probability >= confident)
    confidently_wrong: int  # the most probable label is wrong and has probability >= confident


def cell_counts(map_belief: np.ndarray, true_map: np.ndarray, confident: float = CONFIDENT) -> CellCounts:
    """The peer's rule ("count a cell wrong when its most probable label, with probability >=
    0.55, is wrong") read both ways: ``confidently_wrong`` leaves an unsure cell out, so a robot
    that learns nothing scores 0; ``unsure_or_wrong`` counts it, so a cell never seen counts
    as wrong. O(N K)."""
    true_map = np.asarray(true_map)
    guess = np.argmax(map_belief, axis=1)
    sure = map_belief[np.arange(len(true_map)), guess] >= confident
    wrong = guess != true_map
    return CellCounts(int(wrong.sum()), int(np.sum(wrong | ~sure)), int(np.sum(wrong & sure)))


def read_cells(run: Run) -> np.ndarray:
    """The cells the sensor read at least once during the run (sorted; with the paper's sensor,
    the visited cells). O(T F)."""
    cells = run.model.footprint_cells[run.locations]
    return np.unique(cells[cells >= 0])


class ToldLocation(NamedTuple):
    """The map of a robot told its true location at every step (:func:`told_location`)."""

    map: np.ndarray  # (N, K) its belief after the last step
    map_error: np.ndarray  # (T,) its map error at each step t, against the true map at t


def told_location_map(model: GridModel, run: Run) -> np.ndarray:
    """(N, K) the map belief of a robot told its true location at every step of ``run``, from the
    same observations: :func:`told_location`'s ``map``. What the data of a run could teach at
    best, the yardstick of the peer's "a robot told its location would get about 8 wrong"."""
    return told_location(model, run).map


def told_location(model: GridModel, run: Run) -> ToldLocation:
    """The map of a robot told its true path: given the path the cells are independent hidden
    Markov chains, each filtered exactly, and its map error at every step.

    Per cell i: prior ``label_prior[i]``; at step t >= 1, first the press (judged on the labels
    before this step's change, DESIGN.md section 7): with blocking labels, a press from ``L_{t-1}``
    towards an in-grid cell j that moved the robot says ``m_j`` is passable (likelihood
    ``p_move [m_j passable]``, the constant dropped), and one that left it where it was says
    ``P(stay | m_j) = 1`` if ``m_j`` blocks, ``1 - p_move`` otherwise; without blocking labels
    motion ignores the map and says nothing. Then the change C (dynamic worlds), then each cell
    the sensor read, weighed by its column of O. In a static world the evidence of a cell
    multiplies in any order (kept as log sums). On a model whose label frequencies are unknown
    (``model.unknown_label_frequencies``: generated buildings, read floors, where the filters
    learn them by default) the robot told its path learns them too: the prior of every cell is
    the frequencies theta of :func:`~onlinemap.label_prior.fixed_point_frequencies` given the
    cells read so far, at every step (as :func:`onlinemap.hindsight.path_map` at the end), so
    the anchor has the robot's own prior. Cost: O(T (F + 1) K + T N) in a static world,
    O(T iterations N K) learning, O(T N K^2) in a dynamic one; memory O(N K)."""
    cells = model.footprint_cells[run.locations]  # (T, F)
    readings = np.asarray(run.observations).reshape(cells.shape)
    read = (cells >= 0) & (readings >= 0)
    presses = _presses(model, run)
    if model.learns_label_frequencies:
        return _learning_told_location(model, run, cells, readings, read, presses)
    n, every = model.n_cells, np.arange(model.n_cells)
    errors = np.empty(run.n_steps)
    belief = np.array(np.broadcast_to(model.label_prior, (n, model.n_labels)))
    if model.is_static:  # every reading of a cell multiplies its belief by a column of O, in any order
        truth = run.maps[0]
        with np.errstate(divide="ignore"):
            log_belief = np.log(belief)
        p_true = belief[every, truth]
        for t, touched, pressed in _static_evidence(model, presses, cells, readings, read, log_belief):
            if pressed >= 0:
                touched = np.append(touched, pressed)
            p_true[touched] = _normalised(log_belief[touched])[np.arange(len(touched)), truth[touched]]
            errors[t] = 1.0 - p_true.mean()
        return ToldLocation(_normalised(log_belief), errors)
    for t in range(run.n_steps):
        if t > 0:
            if presses.cell[t] >= 0:
                belief[presses.cell[t]] *= model.press_likelihood[presses.kind[t]]
                belief[presses.cell[t]] /= belief[presses.cell[t]].sum()
            belief = belief @ model.change
        for cell, z in zip(cells[t][read[t]], readings[t][read[t]]):
            belief[cell] *= model.sensor[:, z]
            belief[cell] /= belief[cell].sum()
        errors[t] = 1.0 - belief[every, run.maps[t]].mean()
    return ToldLocation(belief, errors)


def _static_evidence(model: GridModel, presses, cells, readings, read, log_belief: np.ndarray):
    """In a static world, step by step: add step t's press outcome and readings to ``log_belief``
    (N, K), the cells' summed log-likelihoods, in place, and yield ``t``, the cells read at t and
    the cell pressed into (-1: none). O(F K) a step."""
    with np.errstate(divide="ignore"):
        log_reading = np.log(model.sensor.T)  # row z: log O[:, z]
        log_press = np.log(model.press_likelihood)
    for t in range(len(cells)):
        touched = cells[t][read[t]]  # distinct: one footprint offset per cell
        if presses.cell[t] >= 0:
            log_belief[presses.cell[t]] += log_press[presses.kind[t]]
        log_belief[touched] += log_reading[readings[t][read[t]]]
        yield t, touched, presses.cell[t]


def _learning_told_location(model: GridModel, run: Run, cells, readings, read, presses) -> ToldLocation:
    """:func:`told_location` in a static world whose label frequencies are learned: each cell's
    summed log-likelihoods (readings, presses) as without learning, then at every step the
    frequencies of the cells read (:func:`~onlinemap.label_prior.fixed_point_frequencies`, warm
    started from the step before) as the prior of every cell. O(T iterations N K)."""
    n, k = model.n_cells, model.n_labels
    alpha = resolve_label_prior(k, None, model_learns=True).alpha
    log_evidence, seen = np.zeros((n, k)), np.zeros(n)
    truth, every, errors = run.maps[0], np.arange(n), np.empty(run.n_steps)
    theta = None
    for t, touched, _ in _static_evidence(model, presses, cells, readings, read, log_evidence):
        seen[touched] = 1.0
        theta = fixed_point_frequencies(alpha, log_evidence, seen, theta)
        belief = _normalised(np.log(theta) + log_evidence)
        errors[t] = 1.0 - belief[every, truth].mean()
    return ToldLocation(belief, errors)


def _normalised(log_belief: np.ndarray) -> np.ndarray:
    """Rows of log-probabilities (up to a constant each) -> probabilities. O(size)."""
    log_belief = log_belief - log_belief.max(axis=1, keepdims=True)
    belief = np.exp(log_belief)
    return belief / belief.sum(axis=1, keepdims=True)


class _Presses(NamedTuple):
    """What the moves of a run say about the cells pressed towards (:func:`_presses`)."""

    cell: np.ndarray  # (T,) the in-grid cell pressed towards at step t, or -1 (t = 0, an edge, no blocking labels)
    kind: np.ndarray  # (T,) 0: the robot entered it, 1: it stayed (the row of ``GridModel.press_likelihood``)


def _presses(model: GridModel, run: Run) -> _Presses:
    """The moves' evidence about the map: with blocking labels, step t >= 1 pressed from
    ``L_{t-1}`` towards ``j = neighbors[L_{t-1}, a_t]``; if j is another cell, the robot entered it
    (``[m_j passable]``) or stayed (1 if ``m_j`` blocks, else ``1 - p_move``). O(T)."""
    cell = np.full(run.n_steps, -1, dtype=np.int64)
    kind = np.zeros(run.n_steps, dtype=np.int64)
    if model.has_blocking and run.n_steps > 1:
        before = run.locations[:-1]
        target = model.neighbors[before, run.actions]
        pressed = target != before
        cell[1:] = np.where(pressed, target, -1)
        kind[1:] = run.locations[1:] == before
    return _Presses(cell, kind)


STRETCH = 256  # steps per forward pass of told_map_location: bounds the pass's (W, N) arrays


def told_map_location(model: GridModel, run: Run) -> np.ndarray:
    """(T, N) the location belief of a robot told the true map at every step of ``run``, from the
    same actions and readings: ``P(L_t | a_1..t, z_0..t, m_0..m_t)``, filtered exactly. The mirror
    of :func:`told_location`: what the readings allow for the location (wheels slip, a sensor
    reading one cell leaves places alike), the anchor of the location metrics.

    Forward filter from the one-hot start cell (as every estimator starts): at step t >= 1 the
    move ``x'_j = sum_i T[a_t, i, j | m_{t-1}] x_i`` (blocking labels: the intended neighbour j is
    reached with ``p_move [m_{t-1, j} passable]``, the labels before this step's change, as the
    world moves; otherwise the paper's map-free motion), then the readings at the labels after the
    change, ``x_l *= prod_f O[m_t(c_f(l)), z_tf]`` (0 where the off-grid readings -1 do not fit l),
    then normalise. The map's own changes do not depend on the location, so they drop out. Over
    each stretch of steps whose true map stays the same this is the EM estimators' location HMM
    (:func:`onlinemap.hmm.forward_filter`, forward-backward's filtered rows) with ``B = O[m]`` (the true map read
    through the sensor) and a 0/1 passability; a stretch starts where the map changed, its prior
    the last belief moved under the map before the change. Raises ModelError when ``run``'s
    shapes are not ``model``'s and ImpossibleObservationError when the readings have probability
    zero under ``model`` (a run of another model). Cost O(T (N F + E)) time (plus O(N K) per
    stretch), O(T N) memory for the result."""
    if run.maps.shape[1] != model.n_cells or run.observations.shape[1:] != model.observation_shape:
        raise ModelError(f"told_map_location: the run has {run.maps.shape[1]} cells and readings of shape "
                         f"{run.observations.shape[1:]}, the model {model.n_cells} and {model.observation_shape}")
    t_steps = run.n_steps
    changed = np.flatnonzero((run.maps[1:] != run.maps[:-1]).any(axis=1)) + 1
    starts = np.union1d(np.arange(0, t_steps, STRETCH), changed)
    beliefs = np.empty((t_steps, model.n_cells))
    prior = model.location_prior()
    for s, e in zip(starts, np.append(starts[1:], t_steps)):
        if s > 0:
            prior = apply_motion(model, beliefs[s - 1], int(run.actions[s - 1]), _passable(model, run.maps[s - 1]))
        labels = run.maps[s]
        try:
            fit = forward_filter(model, prior, run.actions[s:e - 1], run.observations[s:e], model.sensor[labels],
                                 first_step=int(s), passable=_passable(model, labels))
        except ImpossibleObservationError as error:
            raise ImpossibleObservationError(f"told_map_location: given the true map, {error} (a run of "
                                             f"another model?)") from None
        beliefs[s:e] = fit.filtered
    return beliefs


def _passable(model: GridModel, labels: np.ndarray) -> np.ndarray | None:
    """(N,) 1.0 where ``labels`` lets the robot in, 0.0 where it blocks; None without blocking labels."""
    return (~model.blocking[labels]).astype(np.float64) if model.has_blocking else None


def observable_cells(model: GridModel, true_map: np.ndarray) -> np.ndarray:
    """The cells a robot could ever read (sorted): those its footprint covers from some cell
    reachable from the start through cells ``true_map`` does not block (every cell without
    blocking labels). A wall read from no reachable cell stays at its prior whatever the
    explorer does. O(N A + N F)."""
    passable = ~model.blocking[np.asarray(true_map)]
    reached = np.zeros(model.n_cells, dtype=bool)
    reached[model.start] = True
    frontier = [model.start]
    while frontier:
        cell = frontier.pop()
        for target in model.neighbors[cell]:
            if passable[target] and not reached[target]:
                reached[target] = True
                frontier.append(int(target))
    cells = model.footprint_cells[reached]
    return np.unique(cells[cells >= 0])


def way_back(run: Run) -> np.ndarray:
    """(T,) True at the steps after the robot turned (after its first action that differs
    from the first action); all False if it never turns."""
    turns = np.flatnonzero(run.actions != run.actions[0])
    mask = np.zeros(run.n_steps, dtype=bool)
    if len(turns):
        mask[turns[0] + 1:] = True
    return mask


class RunFacts(NamedTuple):
    """What the metrics need of a run alone, whatever the beliefs scored on it (:func:`run_facts`)."""

    visited: np.ndarray  # the cells the robot stood on, sorted
    read: np.ndarray  # the cells the sensor read (read_cells)
    observable: np.ndarray  # the cells a robot could ever read in the initial map (observable_cells)
    first_read: np.ndarray  # (N,) the first step at which the sensor read each cell (T if never)
    distances: metrics.FloorDistances  # moves on the true floor (floor_distances)
    told_map_error: np.ndarray  # (T,) the told-location map's error at each step (told_location)
    told: tuple[tuple[str, float | int], ...]  # the told_location_* metrics by name
    told_map_location_error: np.ndarray  # (T,) 1 - P(true cell) of the told-map robot (told_map_location)
    told_map_location_distance: np.ndarray  # (T,) its expected moves on the true floor to the true cell


def floor_distances(run: Run) -> metrics.FloorDistances:
    """The distances of :func:`onlinemap.metrics.location_distance` for ``run``: the fewest moves
    on the true floor, the cells whose label does not block at some step of the run (a door that
    is open at some step is a passage; every cell without blocking labels); a cell no such path
    reaches (a wall, a closed-off room) gets its grid distance, labels ignored
    (:class:`~onlinemap.metrics.FloorDistances`). O(T N) here, then O(N A log N) per distinct
    true cell asked for."""
    model = run.model
    passable = (~model.blocking[run.maps]).any(axis=0) if model.has_blocking else np.ones(model.n_cells, bool)
    return metrics.FloorDistances(model.neighbors, passable)


def first_read(run: Run) -> np.ndarray:
    """(N,) the first step at which the sensor read each cell (T where never). O(T F + N)."""
    cells = run.model.footprint_cells[run.locations]  # (T, F)
    steps = np.broadcast_to(np.arange(run.n_steps)[:, None], cells.shape)
    first = np.full(run.model.n_cells, run.n_steps, dtype=np.int64)
    np.minimum.at(first, cells[cells >= 0], steps[cells >= 0])
    return first


@functools.lru_cache(maxsize=4)
def run_facts(run: Run) -> RunFacts:
    """The :class:`RunFacts` of ``run``, read-only, computed once per run (a Run is immutable and
    hashed by identity) for the last few runs: a sweep scores every estimator of a run one after
    the other (25 in the corridor study), each then at the cost of its beliefs only. Cost, the
    first time: that of :func:`told_location`, :func:`told_map_location` (its (T, N) beliefs
    read at the true cells and against the floor distances, then let go) and
    :func:`observable_cells` (about 0.15 ms on a corridor of 12 cells; for 2000 steps on a building
    that learns its label frequencies about 0.9 s on 32 x 32 and 4 s on 64 x 64, mostly the
    told-location map; the told-map location adds about 0.1 s / 0.3 s there); then O(1)
    (the floor distances are computed as they are asked for)."""
    model = run.model
    told_map, told_error = told_location(model, run)
    distances = floor_distances(run)
    told_beliefs = told_map_location(model, run)
    told_p_true = told_beliefs[np.arange(run.n_steps), run.locations]
    told_distance = metrics.location_distance(told_beliefs, run.locations, distances)
    del told_beliefs
    counts = cell_counts(told_map, run.final_map)
    told = (("told_location_map_error", float(metrics.map_error(told_map, run.final_map))),
            ("told_location_wrong", counts.wrong), ("told_location_unsure_or_wrong", counts.unsure_or_wrong),
            ("told_location_confidently_wrong", counts.confidently_wrong))
    return RunFacts(read_only(np.unique(run.locations)), read_only(read_cells(run)),
                     read_only(observable_cells(model, run.initial_map)), read_only(first_read(run)),
                     distances, read_only(told_error), told, read_only(1.0 - told_p_true), read_only(told_distance))

