"""Exploration runs: act, observe, update the estimator, re-plan (DESIGN.md section 4).

:func:`explore` simulates the true world with :func:`onlinemap.simulate.world_step` (the same
dynamics as :func:`onlinemap.simulate`); :func:`explore_env` drives a gymnasium
:class:`onlinemap.envs.DoorWorldEnv` instead. Both return one row per step.
"""

from __future__ import annotations

import logging
import time
from typing import Callable, NamedTuple

import numpy as np
import pandas as pd

from onlinemap import arguments
from onlinemap.errors import InvalidOptionError, ModelError
from onlinemap.belief import STALL_AFTER, StallWatch
from onlinemap.estimators import Estimator, Trajectory, estimator_options, make_estimator
from onlinemap.evaluate import step_metrics
from onlinemap.model import GridModel
from onlinemap.progress import tqdm
from onlinemap.rng import SeedLike
from onlinemap.simulate import Run, world_step
from onlinemap.validation import check_map

from .planners import PLANNERS, Planner, make_planner

logger = logging.getLogger(__name__)

COLUMNS = ("t", "action", "true_location", "map_error", "location_error", "location_entropy",
           "map_entropy", "door_error")

# (observation: an int, or (F,) readings for a footprint model; true location; true labels (N,))
WorldState = tuple[int | np.ndarray, int, np.ndarray]


def _observation(model: GridModel, observation) -> int | np.ndarray:
    """An environment's observation as the estimators take it: an int, or ``model.observation_shape``."""
    if model.observation_shape == ():
        return int(observation)
    return np.asarray(observation, dtype=np.int64).reshape(model.observation_shape)


def seed_streams(seed: SeedLike) -> tuple[np.random.Generator, np.random.Generator, int]:
    """Independent streams for the world, the planner and the estimator, from one seed: every
    closed loop (:func:`exploration`, :func:`explore_env`, :func:`policies.navigate`, the oracle)
    splits its seed this way, so one seed fixes a whole run."""
    if isinstance(seed, np.random.Generator):
        world, planner = seed.spawn(2)
        return world, planner, int(seed.integers(2**63))
    world, planner, estimator = np.random.SeedSequence(seed).spawn(3)
    return (np.random.default_rng(world), np.random.default_rng(planner),
            int(estimator.generate_state(1, np.uint64)[0]))


def loop_estimator(model: GridModel, estimator: str | Estimator, options: dict | None, seed: int) -> Estimator:
    """The estimator a closed loop runs: a registry name built with ``options`` (and ``seed`` if it
    takes one), or a fresh instance for ``model`` taken as it is (ModelError otherwise)."""
    if isinstance(estimator, str):
        options = dict(options or {})
        if "seed" in estimator_options(estimator):
            options.setdefault("seed", seed)
        return make_estimator(estimator, model, **options)
    if options:
        raise InvalidOptionError("estimator_options are for an estimator given by name")
    if estimator.t != -1:
        raise ModelError(f"the estimator has already taken {estimator.t + 1} steps; pass a fresh one")
    if estimator.model is not model:
        raise ModelError("the estimator was built for a different model")
    return estimator


def loop_planner(model: GridModel, planner: str | Planner, options: dict | None,
                 rng: np.random.Generator) -> Planner:
    """The planner a closed loop runs: a registry name built with ``options`` and the planner
    stream ``rng``, or an instance taken as it is (InvalidOptionError if options come with it)."""
    if isinstance(planner, str):
        return make_planner(planner, model, seed=rng, **(options or {}))
    if not callable(getattr(planner, "choose", None)):
        raise ModelError(f"planner must be a registered name ({', '.join(PLANNERS)}) or an object with a "
                         f"choose(belief) method, got {type(planner).__name__} {planner!r}"[:300])
    if options:
        raise InvalidOptionError("planner_options are for a planner given by name")
    return planner


class Exploration(NamedTuple):
    """One exploration run: the per-step table, the true run and the estimator's beliefs."""

    frame: pd.DataFrame  # one row per step: COLUMNS
    run: Run  # the actions the planner chose, true locations, maps and observations
    trajectory: Trajectory  # the estimator's stacked beliefs; seconds_per_step: estimator + planner
    stalled_at: int | None = None  # the step at which the run stalled and ended (StallWatch), None if it did not


def closed_loop(model: GridModel, reset: Callable[[], WorldState], advance: Callable[[int], WorldState],
                planner: Planner, estimator: Estimator, steps: int, progress: bool | None,
                until: Callable[[int], bool] | None = None, score: bool = True,
                stall_after: int | None = STALL_AFTER) -> Exploration:
    """The loop every run shares: ``reset()`` gives the first observation, then the planner
    chooses, ``advance(action)`` moves the world and the estimator updates. At most ``steps``
    steps; ``until(true location)``, if given, ends the run after the first step at which it
    holds (that step recorded). The frame is scored by
    :func:`onlinemap.evaluate.step_metrics` unless ``score`` is False (the sweep engine scores the
    run and trajectory itself: frame None). ``stall_after`` presses in a row that leave the belief
    as it was (:class:`onlinemap.belief.StallWatch`; None: never) are a stall: the run ends there,
    its step in ``stalled_at``, and it is logged as a warning (a stalled run is not run on to
    ``steps``)."""
    n, k = model.n_cells, model.n_labels  # a step's record: action, location, readings, beliefs, true map
    steps = arguments.step_count("steps", steps, minimum=1,
                                 bytes_per_step=8 * (3 + model.n_readings + n + n * k + n), error=InvalidOptionError)
    record = _Record.empty(model, steps)
    watch = StallWatch(stall_after)
    if hasattr(planner, "bind"):  # planners that roll hypotheses out on copies of the live filter
        planner.bind(estimator)
    observation, location, labels = reset()
    belief = estimator.step(None, observation)
    started = time.perf_counter()
    bar = tqdm(total=steps, desc=f"explore ({type(planner).__name__}, {estimator.name})",
               disable=(steps < 200) if progress is None else not progress, leave=False, unit="step")
    for t in range(steps):
        if t > 0:
            record.actions[t] = planner.choose(belief)
            observation, location, labels = advance(record.actions[t])
            belief = estimator.step(int(record.actions[t]), observation)
        record.write(t, location, labels, observation, belief)
        bar.update()
        if until is not None and until(location):
            break
        if watch.update(belief):
            logger.warning("%r with %s stalled at step %d: %d presses left the belief as it was; the run ends",
                           planner, estimator.name, t, watch.after)
            break
    bar.close()
    if t + 1 < steps:  # stopped early: keep the steps taken
        steps = t + 1
        record = record.first(steps)
    seconds = (time.perf_counter() - started) / steps
    run = Run(model, record.actions[1:], record.locations, record.true_maps, record.observations)
    trajectory = Trajectory(record.location_belief, record.map_belief, record.evidence, seconds)
    frame = _scored(record, run, trajectory, repr(planner), estimator.name, watch.stalled_at) if score else None
    return Exploration(frame, run, trajectory, watch.stalled_at)


class _Record(NamedTuple):
    """What a closed loop keeps of each of its T steps (action -1 at step 0)."""

    actions: np.ndarray  # (T,)
    locations: np.ndarray  # (T,)
    observations: np.ndarray  # (T,) + the model's observation shape
    location_belief: np.ndarray  # (T, N)
    map_belief: np.ndarray  # (T, N, K)
    evidence: np.ndarray  # (T,)
    true_maps: np.ndarray  # (T, N)

    @classmethod
    def empty(cls, model: GridModel, steps: int) -> "_Record":
        return cls(np.full(steps, -1, dtype=np.int64), np.empty(steps, dtype=np.int64),
                   np.empty((steps,) + model.observation_shape, dtype=np.int64), np.empty((steps, model.n_cells)),
                   np.empty((steps, model.n_cells, model.n_labels)), np.empty(steps),
                   np.empty((steps, model.n_cells), dtype=np.int64))

    def write(self, t: int, location: int, labels: np.ndarray, observation, belief) -> None:
        """Step t: the true location and labels, the observation, the estimator's belief after it."""
        self.locations[t], self.true_maps[t], self.observations[t] = location, labels, observation
        self.location_belief[t], self.map_belief[t], self.evidence[t] = belief.location, belief.map, belief.log_evidence

    def first(self, steps: int) -> "_Record":
        """The first ``steps`` steps (views)."""
        return _Record(*(array[:steps] for array in self))


def _scored(record: _Record, run: Run, trajectory: Trajectory, planner: str, estimator: str,
            stalled_at: int | None) -> pd.DataFrame:
    """The per-step table (:data:`COLUMNS`) of a closed loop (its ``record``, as ``run`` and
    ``trajectory``), by :func:`onlinemap.evaluate.step_metrics`; its attrs name the planner and
    estimator, the seconds per step and the stall."""
    scores = step_metrics(run, trajectory)
    frame = pd.DataFrame({"t": scores["t"], "action": [None] + [run.model.action_names[a] for a in record.actions[1:]],
                          "true_location": record.locations})
    for column in COLUMNS[3:]:
        frame[column] = scores[column] if column in scores else np.nan
    frame.attrs.update(planner=planner, estimator=estimator, seconds_per_step=trajectory.seconds_per_step,
                       stalled_at=stalled_at)
    return frame


def explore(model: GridModel, true_map, planner: str | Planner = "entropy",
            estimator: str | Estimator = "rbpf", steps: int = 500, seed: SeedLike = None, *,
            estimator_options: dict | None = None, planner_options: dict | None = None,
            progress: bool | None = None, stall_after: int | None = STALL_AFTER) -> pd.DataFrame:
    """Run a closed exploration loop for ``steps`` steps (the first observation included).

    Each step: the planner chooses an action from the estimator's belief, the true world moves
    (:func:`onlinemap.simulate.world_step`: move, map change, observe), the estimator takes the
    action and observation. ``planner`` is a :class:`~policies.planners.Planner` or a name
    (``entropy``, ``random``, ``sweep``, ``info_gain``; a planner with a ``bind`` method is given
    the estimator before the first step); ``estimator`` a fresh estimator or a registry name,
    built with ``estimator_options`` (and a ``seed`` derived from ``seed`` if it takes one).
    A named planner is built with ``planner_options`` (:func:`~policies.planners.make_planner`
    keywords, e.g. ``gamma`` or ``replan_every``) and the planner stream of ``seed``.
    One ``seed`` fixes the world, a named planner and a named estimator.

    Returns a frame with one row per step and the columns ``t``, ``action`` (name, None at
    t = 0), ``true_location``, ``map_error`` (mean over cells of 1 - P(true label)),
    ``location_error`` (1 - P(true cell)), ``location_entropy`` and ``map_entropy``
    (normalised to [0, 1]) and ``door_error`` (``map_error`` over the door cells; NaN if the
    world has none); ``frame.attrs`` holds the planner, the estimator and seconds per step.
    ``progress``: a tqdm bar (None: shown for runs of 200 steps or more). ``stall_after``: the
    run ends after that many presses in a row leave the belief as it was (a stall, :func:`closed_loop`;
    ``frame.attrs["stalled_at"]`` its step; None: never).
    Cost: ``steps`` x (estimator step + planner choice) plus O(steps N K) memory and metrics.
    """
    return exploration(model, true_map, planner, estimator, steps, seed, estimator_options=estimator_options,
                       planner_options=planner_options, progress=progress, stall_after=stall_after).frame


def exploration(model: GridModel, true_map, planner: str | Planner = "entropy",
                estimator: str | Estimator = "rbpf", steps: int = 500, seed: SeedLike = None, *,
                estimator_options: dict | None = None, planner_options: dict | None = None,
                progress: bool | None = None, score: bool = True,
                stall_after: int | None = STALL_AFTER) -> Exploration:
    """:func:`explore` returning the whole :class:`Exploration` (table, true run, beliefs); with
    ``score`` False the frame is None (the sweep engine scores the run and trajectory itself)."""
    world_rng, planner_rng, estimator_seed = seed_streams(seed)
    labels = check_map(model, true_map)
    est = loop_estimator(model, estimator, estimator_options, estimator_seed)
    chooser = loop_planner(model, planner, planner_options, planner_rng)
    state = {"location": model.start, "labels": labels}

    def advance(action: int | None) -> WorldState:
        location, state["labels"], observation = world_step(
            model, state["location"], state["labels"], action, world_rng)
        state["location"] = location
        return observation, location, state["labels"]

    return closed_loop(model, lambda: advance(None), advance, chooser, est, steps, progress, score=score,
                       stall_after=stall_after)


def explore_env(env, planner: str | Planner = "entropy", estimator: str | Estimator = "rbpf",
                steps: int = 500, seed: SeedLike = None, *, estimator_options: dict | None = None,
                planner_options: dict | None = None, progress: bool | None = None) -> pd.DataFrame:
    """:func:`explore` against a gymnasium :class:`onlinemap.envs.DoorWorldEnv` (possibly wrapped):
    ``env.reset(seed=...)`` then ``env.step(action)``; the true state is read from ``info``.
    The episode must last ``steps - 1`` actions (it raises if the env ends it sooner)."""
    model = env.unwrapped.model
    world_seed, planner_rng, estimator_seed = seed_streams(seed)
    est = loop_estimator(model, estimator, estimator_options, estimator_seed)
    chooser = loop_planner(model, planner, planner_options, planner_rng)

    def reset() -> WorldState:
        observation, info = env.reset(seed=int(world_seed.integers(2**31)))
        return _observation(model, observation), info["location"], info["map"]

    def advance(action: int) -> WorldState:
        observation, _, terminated, truncated, info = env.step(int(action))
        if terminated or truncated:
            raise ModelError(f"the environment ended the episode at step {info['t']}; "
                             f"ask for fewer steps or raise its max_episode_steps")
        return _observation(model, observation), info["location"], info["map"]

    return closed_loop(model, reset, advance, chooser, est, steps, progress).frame
