"""Experiment sweeps: worlds x estimators x option grids x seeds, run serially or on
dask.distributed, written incrementally, resumable, summarised with confidence intervals.

A spec is a TOML file (every key but ``worlds`` and ``estimators`` optional)::

    name = "rbpf-vs-particles"        # a label
    worlds = ["corridor:8", "corridor:8,p_change=0.01"]   # world specs (onlinemap.worlds)
    seeds = 20                         # 20 -> seeds 0..19; or a list [0, 4, 7]
    steps = 100                        # steps per run (first observation included); or a list;
                                       # "trip": one there-and-back trip, 2 (N - 1) + 1 steps
    walk = "random"                    # "random", "there_and_back" (corridors) or "scripted_trip"
                                       # (one trip, one slip, noise-free observations); or a list
    rows = "task"                      # "task": one row per task; "step": one per task and step
    reference = "exact"                # also run this estimator on every run and record the
                                       # total variation of each belief to it

    [estimators.exact]                 # one table per registered estimator: its options,
    [estimators.rbpf]                  # each a value or a list of values (a grid)
    n_particles = [10, 30, 100]
    proposal = ["transition", "optimal"]

    [[estimators.online_em]]           # an array of tables: several grids of one estimator
    window = "max"
    [[estimators.online_em]]
    window = [1, 2, 4, 8]
    decay = [0.8, 1.0]

A list is always a grid; a list-valued option is written as a list of lists
(``anneal = [[1.0, 0.9, 0.05]]``). With ``[planners.NAME]`` tables (``entropy``, ``random``,
``sweep`` from the ``policies`` package, options as grids too) every task is an exploration
run instead (:func:`policies.explore`: the planner chooses the actions, the estimator tracks
the belief); ``walk`` and ``reference`` do not apply there, and ``floor_plan = 0.8`` (or a
list) gives the robot a label prior that puts that confidence on the true initial map
(``policies.with_floor_plan``; door cells: a door, state unknown).

Every task is one cell of the product (world, estimator configuration[, planner
configuration], steps, walk, seed). The spec is checked completely before any task runs:
unknown keys, estimators, planners or options, wrong types, world specs, and every
(world, configuration) pair is built once, so option values an estimator refuses and memory
limits are caught too. Errors name the file, line and key path (:class:`SpecError`).

A task simulates its run from its seed exactly as ``onlinemap run --seed`` does
(``default_rng(seed)`` draws the map, then the walk, then the noise); estimators with a
``seed`` option get one derived from the task's seed (unless the spec sets it). Results:
one parquet file per finished task, named by a hash of the task, in a results directory;
rerunning skips the tasks found there, and the final table holds each task of the spec once.
Its columns: the task's description (``task`` hash, ``kind``, ``world``, ``estimator``,
``options`` as text and one ``opt_NAME`` column per option, ``steps``, ``seed``, ...) then the
metrics of :func:`run_task`. Cost: the tasks' own, spread over the workers, plus a few
milliseconds of dask overhead per task and seconds to start a local cluster.
"""

from __future__ import annotations

import functools
import hashlib
import inspect
import itertools
import json
import math
import os
import re
import tomllib
import types
import typing
import uuid
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable, NamedTuple

import numpy as np
import pandas as pd
from .progress import tqdm

from . import metrics, plots
from .errors import OnlineMapError
from .estimators import available_estimators, estimator_options, make_estimator, run_estimator
from .estimators.base import Trajectory
from .estimators.base import _lookup as _estimator_class
from .model import GridModel
from .reproduce import LOST_BELOW
from .scenarios import one_slip_corridor
from .simulate import Run, random_walk, there_and_back
from .stats import mean_interval
from .tables import write_table
from .worlds import WorldSpec, parse_world

WALKS = ("random", "there_and_back", "scripted_trip")
ROWS = ("task", "step")
TOP_KEYS = ("name", "worlds", "seeds", "steps", "walk", "rows", "reference", "floor_plan", "estimators",
            "planners")
DASK_HINT = "install dask.distributed with: pip install 'onlinemap[sweeps]'"
# Columns describing a task (the configuration and the seed); everything else is a metric.
TASK_COLUMNS = ("task", "kind", "world", "estimator", "options", "planner", "planner_options", "floor_plan",
                "steps", "walk", "reference", "seed")
CONFIG_COLUMNS = tuple(c for c in TASK_COLUMNS if c not in ("task", "seed"))
TIMING_COLUMNS = ("ms_per_step",)


class SpecError(OnlineMapError):
    """A sweep spec is malformed; the message names the file, line and key."""


class SweepError(OnlineMapError):
    """Some tasks of a sweep failed; the finished ones are kept (rerun to retry the rest)."""


# --- the spec ------------------------------------------------------------------------------
@dataclass(frozen=True)
class Task:
    """One cell of a sweep. ``options`` and ``planner_options`` are sorted (name, value) pairs."""

    world: str
    estimator: str
    options: tuple
    seed: int
    steps: int | str  # "trip": one there-and-back trip, 2 (N - 1) + 1 steps
    walk: str = "random"
    reference: str | None = None
    per_step: bool = False
    planner: str | None = None
    planner_options: tuple = ()
    floor_plan: float | None = None

    @property
    def kind(self) -> str:
        return "explore" if self.planner else "estimate"

    @property
    def key(self) -> str:
        """A stable hash of everything that determines the task's result (16 hex digits); fields
        left at None are not hashed, so adding an optional field keeps existing keys."""
        fields = {k: v for k, v in self.__dict__.items() if v is not None}
        return hashlib.sha256(json.dumps(_plain(fields), sort_keys=True).encode()).hexdigest()[:16]


class SweepSpec(NamedTuple):
    """A validated spec: its tasks in order (seeds innermost), and where it came from."""

    name: str
    tasks: tuple[Task, ...]
    source: str


def _plain(value):
    """Tuples to lists, recursively (JSON and the hash see the same structure)."""
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (tuple, list)):
        return [_plain(v) for v in value]
    return value


def _frozen(value):
    """Lists to tuples, recursively (hashable option values)."""
    return tuple(_frozen(v) for v in value) if isinstance(value, (list, tuple)) else value


class _Locator:
    """Finds the line of a key path (e.g. ``("estimators", "rbpf", "n_particles")``) in TOML text.

    tomllib keeps no positions, so the text is scanned: table headers (``[a.b]``, ``[[a.b]]``,
    counted per array of tables), keys (dotted keys too) and inline tables' first line. The
    line of the longest matching prefix of the path is reported.
    """

    _HEADER = re.compile(r"^\s*(\[\[?)\s*([^\]]+?)\s*\]\]?\s*(#.*)?$")
    _KEY = re.compile(r"^\s*((?:[A-Za-z0-9_-]+|\"[^\"]*\"|'[^']*')(?:\s*\.\s*(?:[A-Za-z0-9_-]+|\"[^\"]*\"|'[^']*'))*)\s*=")

    def __init__(self, text: str | None, source: str):
        self.source = source
        self.paths: list[tuple[tuple, int]] = []  # (key path, line number)
        if text is None:
            return
        table: tuple = ()
        counts: dict[tuple, int] = {}
        for number, line in enumerate(text.splitlines(), start=1):
            header = self._HEADER.match(line)
            if header:
                table = self._split(header.group(2))
                if header.group(1) == "[[":
                    counts[table] = counts.get(table, -1) + 1
                    table = table + (counts[table],)
                self.paths.append((table, number))
                continue
            key = self._KEY.match(line)
            if key:
                self.paths.append((table + self._split(key.group(1)), number))

    @staticmethod
    def _split(dotted: str) -> tuple:
        parts = re.findall(r"\"[^\"]*\"|'[^']*'|[^.\s]+", dotted)
        return tuple(p[1:-1] if p[:1] in "\"'" else p for p in parts)

    def line(self, path: tuple) -> int | None:
        """The line defining the longest prefix of ``path`` (the first such line), or None."""
        best, best_len = None, 0
        for candidate, number in self.paths:
            if len(candidate) > best_len and tuple(path[:len(candidate)]) == candidate:
                best, best_len = number, len(candidate)
        return best

    def error(self, path: tuple, message: str) -> SpecError:
        line = self.line(path)
        where = f"{self.source}, line {line}" if line else self.source
        dotted = ".".join(str(p) if not isinstance(p, int) else f"[{p}]" for p in path).replace(".[", "[")
        return SpecError(f"{where}: {dotted}: {message}" if dotted else f"{where}: {message}")


def load_spec(path: str | os.PathLike) -> SweepSpec:
    """Read and validate a TOML spec file (see the module docstring)."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as error:
        raise SpecError(f"cannot read sweep spec {path}: {error.strerror or error}") from None
    return parse_spec(text, source=str(path), name=path.stem)


def parse_spec(text: str, source: str = "<spec>", name: str = "sweep") -> SweepSpec:
    """Parse and validate TOML ``text``; ``source`` names it in error messages."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as error:
        line = re.search(r"at line (\d+)", str(error))
        where = f"{source}, line {line.group(1)}" if line else source
        raise SpecError(f"{where}: not valid TOML: {error}") from None
    return spec_from_dict(data, _Locator(text, source), name)


def spec_from_dict(data: dict, locator: _Locator | None = None, name: str = "sweep") -> SweepSpec:
    """Validate a spec already parsed into a dict (errors then name key paths, not lines)."""
    where = locator or _Locator(None, "<spec>")
    for key in data:
        if key not in TOP_KEYS:
            raise where.error((key,), f"unknown key; known keys: {', '.join(TOP_KEYS)}")
    worlds = _worlds(data, where)
    seeds = _seeds(data, where)
    steps = _steps(data, where)
    rows = _choice(data, "rows", ROWS, where, default="task")
    explore = "planners" in data
    if explore:
        for key in ("walk", "reference"):
            if key in data:
                raise where.error((key,), "does not apply to exploration sweeps (with [planners])")
        walks, reference = ["random"], None
        planners = _configs(data, "planners", where, _planner_options, _planner_builder)
        floor_plans = _floor_plans(data, worlds, where)
    else:
        walks = _choices(data, "walk", WALKS, where, default="random")
        reference = data.get("reference")
        if reference is not None and reference not in available_estimators():
            raise where.error(("reference",), f"unknown estimator {reference!r}; "
                                              f"available: {', '.join(available_estimators())}")
        planners = [(None, (), ())]
        if "floor_plan" in data:
            raise where.error(("floor_plan",), "applies to exploration sweeps (with [planners]) only")
        floor_plans = [None]
    estimators = _configs(data, "estimators", where, estimator_options, _estimator_class)
    if "trip" in steps and not set(walks) <= {"there_and_back", "scripted_trip"}:
        raise where.error(("steps",), 'steps = "trip" (one there-and-back trip) needs walk = "there_and_back" '
                                      'or "scripted_trip"')
    if "scripted_trip" in walks and steps != ["trip"]:
        raise where.error(("walk",), 'walk = "scripted_trip" is one trip: it needs steps = "trip"')
    if {"there_and_back", "scripted_trip"} & set(walks):
        bad = [w.spec for w in worlds if w.model.action_names != ("left", "right")
               or ("scripted_trip" in walks and not w.model.is_static)]
        if bad:
            raise where.error(("walk",), f"there_and_back needs corridor worlds (scripted_trip static ones), "
                                         f"not {', '.join(bad)}")
    _check_builds(worlds, estimators, planners, where)
    if reference is not None:
        _check_builds(worlds, [(reference, (), ("reference",))], [(None, (), ())], where)
    tasks, seen = [], set()
    for world, (est, options, _), (planner, planner_opts, _), plan, n_steps, walk, seed in itertools.product(
            worlds, estimators, planners, floor_plans, steps, walks, seeds):
        task = Task(world.spec, est, options, seed, n_steps, walk, reference, rows == "step", planner, planner_opts,
                    plan)
        if task.key not in seen:  # a repeated world or grid value: run once
            seen.add(task.key)
            tasks.append(task)
    label = data.get("name", name)
    if not isinstance(label, str):
        raise where.error(("name",), f"expected a string, got {label!r}")
    return SweepSpec(label, tuple(tasks), where.source)


def _floor_plans(data: dict, worlds: list[WorldSpec], where: _Locator) -> list[float | None]:
    """``floor_plan``: none, a confidence or a list of them (``policies.with_floor_plan``: the
    robot's label prior puts that much on each cell's true label of the initial map)."""
    value = data.get("floor_plan")
    if value is None:
        return [None]
    values = value if isinstance(value, list) else [value]
    if not values or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values):
        raise where.error(("floor_plan",), f"expected a confidence in [1/K, 1] or a list of them, got {value!r}")
    for world in worlds:
        for confidence in values:
            try:
                _policies().with_floor_plan(world.model, world.initial_map(0), float(confidence))
            except OnlineMapError as error:
                raise where.error(("floor_plan",), f"{world.spec}: {error}") from None
    return [float(v) for v in values]


def _worlds(data: dict, where: _Locator) -> list[WorldSpec]:
    if "worlds" not in data:
        raise where.error(("worlds",), "missing: give a list of world specs, e.g. worlds = [\"corridor:8\"]")
    specs = data["worlds"]
    specs = [specs] if isinstance(specs, str) else specs
    if not isinstance(specs, list) or not specs or not all(isinstance(s, str) for s in specs):
        raise where.error(("worlds",), f"expected a non-empty list of world spec strings, got {specs!r}")
    worlds = []
    for spec in specs:
        try:
            worlds.append(parse_world(spec))
        except OnlineMapError as error:
            raise where.error(("worlds",), str(error)) from None
    return worlds


def _seeds(data: dict, where: _Locator) -> list[int]:
    seeds = data.get("seeds", 10)
    if _is_int(seeds):
        if seeds < 1:
            raise where.error(("seeds",), f"the number of seeds must be at least 1, got {seeds}")
        return list(range(seeds))
    if isinstance(seeds, list) and seeds and all(_is_int(s) and s >= 0 for s in seeds):
        if len(set(seeds)) != len(seeds):
            raise where.error(("seeds",), "repeated seed")
        return seeds
    raise where.error(("seeds",), f"expected a count (int >= 1) or a non-empty list of seeds "
                                  f"(ints >= 0), got {seeds!r}")


def _is_int(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _steps(data: dict, where: _Locator) -> list[int | str]:
    value = data.get("steps", 100)
    values = value if isinstance(value, list) else [value]
    if not values or not all((_is_int(v) and v >= 1) or v == "trip" for v in values):
        raise where.error(("steps",), f'expected an int >= 1, "trip" or a list of them, got {value!r}')
    return values


def _choice(data: dict, key: str, allowed: tuple, where: _Locator, default: str) -> str:
    value = data.get(key, default)
    if value not in allowed:
        raise where.error((key,), f"expected one of {', '.join(map(repr, allowed))}, got {value!r}")
    return value


def _choices(data: dict, key: str, allowed: tuple, where: _Locator, default: str) -> list[str]:
    value = data.get(key, default)
    values = value if isinstance(value, list) else [value]
    if not values or any(v not in allowed for v in values):
        raise where.error((key,), f"expected one of {', '.join(map(repr, allowed))} or a list of them, "
                                  f"got {value!r}")
    return values


# --- option grids and their types ------------------------------------------------------------
def _describe(annotation) -> str:
    text = getattr(annotation, "__name__", None) if isinstance(annotation, type) else None
    return text or str(annotation).replace("typing.", "").replace("numpy.random._generator.", "numpy.random.")


def matches_annotation(value, annotation) -> bool:
    """Whether a TOML value fits a parameter annotation (int, float, bool, str, None, unions,
    Literal, tuple[...], list[...], callables). Unknown forms are accepted (the estimator's
    own check, run at validation, decides)."""
    if annotation is inspect.Parameter.empty or annotation is typing.Any:
        return True
    origin = typing.get_origin(annotation)
    args = typing.get_args(annotation)
    if origin in (typing.Union, types.UnionType):
        return any(matches_annotation(value, a) for a in args)
    if origin is typing.Literal:
        return value in args
    if annotation is type(None) or annotation is None:
        return value is None
    if annotation is bool:
        return isinstance(value, bool)
    if annotation is int:
        return _is_int(value)
    if annotation is float:
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if annotation is str:
        return isinstance(value, str)
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            return False
        if len(args) == 2 and args[1] is Ellipsis:
            return all(matches_annotation(v, args[0]) for v in value)
        return not args or (len(value) == len(args) and all(map(matches_annotation, value, args)))
    if origin is list:
        return isinstance(value, (list, tuple)) and all(matches_annotation(v, args[0]) for v in value) \
            if args else isinstance(value, (list, tuple))
    if origin in (Callable, typing.Callable) or annotation in (Callable, typing.Callable) or \
            str(annotation).startswith(("typing.Callable", "collections.abc.Callable")):
        return callable(value)
    if isinstance(annotation, type):
        return isinstance(value, annotation)
    return True


def _expected_type(cls: type, name: str, default):
    """The annotation of ``cls.__init__``'s parameter ``name``, else one inferred from its default."""
    try:
        hints = typing.get_type_hints(cls.__init__)
    except Exception:  # unresolvable forward references: fall back on the default
        hints = {}
    if name in hints:
        return hints[name]
    if default is None or default is inspect.Parameter.empty:
        return inspect.Parameter.empty
    return float if isinstance(default, float) else list if isinstance(default, tuple) else type(default)


def _grid(table, path: tuple, known: dict, cls: type, where: _Locator) -> list[tuple]:
    """All option combinations of one table: a list of sorted (name, value) tuples."""
    if not isinstance(table, dict):
        raise where.error(path, f"expected a table of options, got {table!r}")
    axes = []
    for option, value in table.items():
        if option not in known:
            raise where.error(path + (option,), f"unknown option; the options of {path[1]!r} are: "
                                                f"{', '.join(known) or 'none'}")
        values = value if isinstance(value, list) else [value]
        if not values:
            raise where.error(path + (option,), "empty list: a list is a grid of values, give at least one")
        expected = _expected_type(cls, option, known[option])
        for v in values:
            if not matches_annotation(v, expected):
                hint = " (a list is a grid of values; write a list-valued option as a list of lists)" \
                    if isinstance(value, list) and not isinstance(v, list) else ""
                raise where.error(path + (option,), f"expected {_describe(expected)}, got {v!r}{hint}")
        axes.append([(option, _frozen(v)) for v in values])
    return [tuple(sorted(combo)) for combo in itertools.product(*axes)]


def _configs(data: dict, section: str, where: _Locator, options_of: Callable[[str], dict],
             builder: Callable[[str], type]) -> list[tuple[str, tuple, tuple]]:
    """[(name, options, key path)] for every configuration in ``[section.NAME]`` tables."""
    tables = data.get(section)
    if not isinstance(tables, dict) or not tables:
        kind = section[:-1]
        raise where.error((section,), f"missing or empty: add a [{section}.NAME] table per {kind}")
    configs = []
    for name, body in tables.items():
        try:
            known = options_of(name)
        except OnlineMapError as error:
            raise where.error((section, name), str(error)) from None
        cls = builder(name)
        if isinstance(body, list):  # an array of tables: several grids
            for index, table in enumerate(body):
                path = (section, name, index)
                configs += [(name, combo, path) for combo in _grid(table, path, known, cls, where)]
        else:
            configs += [(name, combo, (section, name)) for combo in _grid(body, (section, name), known, cls, where)]
    return configs


def _policies():
    try:
        import policies
    except ImportError as error:  # pragma: no cover - policies ships with onlinemap
        raise OnlineMapError(f"exploration sweeps need the policies package: {error}") from None
    if not hasattr(policies, "explore"):
        raise OnlineMapError("exploration sweeps need policies.explore, which this install lacks")
    return policies


def _planner_builder(name: str) -> type:
    """The class ``policies.make_planner(name, ...)`` builds (found by building one on a 2 x 2 grid)."""
    from .model import grid_model

    return type(_policies().make_planner(name, grid_model(2, 2), seed=0))


def _planner_options(name: str) -> dict:
    """A planner's options (its class's ``__init__`` parameters after the model, but the seed)."""
    planners = _policies().PLANNERS
    if name not in planners:
        raise OnlineMapError(f"unknown planner {name!r}; available: {', '.join(planners)}")
    params = list(inspect.signature(_planner_builder(name).__init__).parameters.values())[2:]
    return {p.name: p.default for p in params if p.name != "seed"
            and p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)}


def _check_builds(worlds: list[WorldSpec], estimators: list, planners: list, where: _Locator) -> None:
    """Build every (world, configuration) once, so refused values and memory limits show now."""
    for world in worlds:
        for name, options, path in estimators:
            try:
                make_estimator(name, world.model, **dict(options))
            except Exception as error:  # the estimator's own validation, whatever it raises
                raise where.error(path, f"{name}({_options_text(options)}) on {world.spec}: "
                                        f"{type(error).__name__}: {error}") from None
        for name, options, path in planners:
            if name is None:
                continue
            try:
                _policies().make_planner(name, world.model, seed=0, **dict(options))
            except Exception as error:
                raise where.error(path, f"planner {name}({_options_text(options)}) on {world.spec}: "
                                        f"{type(error).__name__}: {error}") from None


def _options_text(options: tuple) -> str:
    return ", ".join(f"{k}={json.dumps(_plain(v))}" for k, v in options)


# --- one task ----------------------------------------------------------------------------------
TASK_METRICS = ("final_map_error", "mean_map_error", "final_location_error", "mean_location_error",
                "max_location_error", "wrong_cells", "lost", "failed", "final_log_evidence", "final_location_tv",
                "mean_location_tv", "final_map_tv", "mean_map_tv", "final_map_entropy",
                "final_location_entropy", "final_door_error", "mean_door_error", "ms_per_step")
STEP_METRICS = ("map_error", "location_error", "log_evidence", "location_tv", "map_tv", "map_entropy",
                "location_entropy", "door_error", "ms_per_step")


def derived_seed(seed: int, stream: int) -> int:
    """An independent 32-bit seed for stream ``stream`` of task seed ``seed``."""
    return int(np.random.SeedSequence([seed, stream]).generate_state(1)[0])


def walk_actions(model: GridModel, walk: str, n_actions: int, rng: np.random.Generator) -> np.ndarray:
    """``random``: uniform actions; ``there_and_back``: right N - 1 times, left N - 1 times,
    repeated and cut to ``n_actions``."""
    if walk == "random":
        return random_walk(model, n_actions, rng)
    trip = there_and_back(model)
    return np.resize(trip, n_actions)


def scripted_trip(model: GridModel, labels: np.ndarray, rng: np.random.Generator) -> Run:
    """The literature's corridor run (DESIGN.md section 5.1) on a static corridor ``model`` with
    the given labels: right N - 1 times, left N - 1 times, exactly one slip at an outward move
    drawn uniformly in 1..N-1, every observation the true label
    (:func:`onlinemap.scenarios.scripted_corridor`, with ``model`` as the robot's model)."""
    return one_slip_corridor(labels, rng, model=model)[0]


@functools.lru_cache(maxsize=16)
def simulated_run(world: str, steps: int | str, walk: str, seed: int) -> Run:
    """The run of a task (memoised per process: every estimator of a sweep sees the same run):
    ``default_rng(seed)`` draws the map, then the walk (``steps`` - 1 actions, or one trip),
    then the noise (:meth:`WorldSpec.simulate`); ``scripted_trip`` draws its slip instead."""
    spec = parse_world(world)
    model = spec.model
    if walk == "scripted_trip":
        rng = np.random.default_rng(seed)
        return scripted_trip(model, spec.initial_map(rng), rng)
    n_steps = 2 * (model.n_cells - 1) + 1 if steps == "trip" else steps
    return spec.simulate(n_steps, seed, walk=lambda model, n_actions, rng: walk_actions(model, walk, n_actions, rng))


@functools.lru_cache(maxsize=16)
def reference_trajectory(world: str, steps: int | str, walk: str, seed: int, reference: str) -> Trajectory:
    """The reference estimator's trajectory on the task's run (memoised per process, so a
    sweep runs it once per run and process, not once per task)."""
    run = simulated_run(world, steps, walk, seed)
    return run_estimator(_make(reference, run.model, (), seed), run.actions, run.observations)


def run_task(task: Task) -> pd.DataFrame:
    """Simulate the task's run and return its metrics: one row, or one row per step.

    Metrics: map error (mean over cells of 1 - P(true label)) and location error
    (1 - P(true cell)), final and mean over steps, and the worst location error;
    ``wrong_cells`` (visited cells whose most likely final label is wrong); ``lost`` (final
    P(true cell) < ``reproduce.LOST_BELOW`` = 0.5); ``failed`` (lost or a wrong cell); time
    per step; with a reference estimator the total variation to its beliefs (location, and per
    cell averaged over cells); for exploration the entropies and door error.
    Cost: the estimator's run, plus (unless this process has just had them for another task)
    one simulation and the reference's run (:func:`simulated_run`, :func:`reference_trajectory`).
    """
    if task.kind == "explore":
        return _run_explore(task)
    run = simulated_run(task.world, task.steps, task.walk, task.seed)
    model = run.model
    estimator = _make(task.estimator, model, task.options, task.seed, run)
    trajectory = run_estimator(estimator, run.actions, run.observations)
    steps = {
        "map_error": metrics.map_error(trajectory.map, run.maps),
        "location_error": metrics.location_error(trajectory.location, run.locations),
        "log_evidence": trajectory.log_evidence,
    }
    if task.reference is not None:
        # the reference estimator itself, unconfigured: its own trajectory (distance 0)
        reference = trajectory if (task.estimator, task.options) == (task.reference, ()) else \
            reference_trajectory(task.world, task.steps, task.walk, task.seed, task.reference)
        steps["location_tv"] = metrics.total_variation(trajectory.location, reference.location)
        steps["map_tv"] = metrics.total_variation(trajectory.map, reference.map).mean(axis=-1)
    ms = 1e3 * trajectory.seconds_per_step
    if task.per_step:
        return _task_frame(task, pd.DataFrame({"t": np.arange(run.n_steps), **steps, "ms_per_step": ms}),
                           run.n_steps)
    visited = np.unique(run.locations)
    wrong = metrics.wrong_cells(trajectory.map[-1], run.maps[-1], visited)
    lost = bool(1.0 - steps["location_error"][-1] < LOST_BELOW)
    row = {"final_map_error": steps["map_error"][-1], "mean_map_error": steps["map_error"].mean(),
           "final_location_error": steps["location_error"][-1],
           "mean_location_error": steps["location_error"].mean(),
           "max_location_error": steps["location_error"].max(),
           "wrong_cells": wrong, "lost": lost, "failed": lost or wrong > 0,
           "final_log_evidence": steps["log_evidence"][-1]}
    if task.reference is not None:
        row.update(final_location_tv=steps["location_tv"][-1], mean_location_tv=steps["location_tv"].mean(),
                   final_map_tv=steps["map_tv"][-1], mean_map_tv=steps["map_tv"].mean())
    row["ms_per_step"] = ms
    return _task_frame(task, pd.DataFrame([row]), run.n_steps)


_WARMED: set = set()


def _make(name: str, model: GridModel, options: tuple, seed: int, run=None):
    """The task's estimator; the first time in this process for (name, options, world size),
    it first takes up to 20 steps of ``run`` on a throwaway copy, so that compiling or loading
    numba kernels is not counted in the time per step."""
    options = dict(options)
    if "seed" in estimator_options(name):
        options.setdefault("seed", derived_seed(seed, 1))
    warm = (name, _options_text(tuple(sorted((k, v) for k, v in options.items() if k != "seed"))),
            model.n_cells, model.n_labels, model.n_actions, model.is_static)
    if run is not None and warm not in _WARMED and run.n_steps > 1:
        warm_steps = min(run.n_steps, 20)
        run_estimator(make_estimator(name, model, **options), run.actions[:warm_steps - 1],
                      run.observations[:warm_steps])
        _WARMED.add(warm)
    return make_estimator(name, model, **options)


def _run_explore(task: Task) -> pd.DataFrame:
    policies = _policies()
    world = parse_world(task.world)
    true_map = world.initial_map(np.random.default_rng(derived_seed(task.seed, 3)))
    model = world.model if task.floor_plan is None else policies.with_floor_plan(world.model, true_map,
                                                                                 task.floor_plan)
    frame = policies.explore(model, true_map, task.planner, task.estimator, task.steps, task.seed,
                             estimator_options=dict(task.options), planner_options=dict(task.planner_options),
                             progress=False)
    ms = 1e3 * frame.attrs["seconds_per_step"]
    columns = ["map_error", "location_error", "map_entropy", "location_entropy", "door_error"]
    if task.per_step:
        return _task_frame(task, frame[["t"] + columns].assign(ms_per_step=ms), len(frame))
    last = frame.iloc[-1]
    row = {"final_map_error": last["map_error"], "mean_map_error": frame["map_error"].mean(),
           "final_location_error": last["location_error"], "mean_location_error": frame["location_error"].mean(),
           "final_map_entropy": last["map_entropy"], "final_location_entropy": last["location_entropy"],
           "final_door_error": last["door_error"], "mean_door_error": frame["door_error"].mean(),
           "ms_per_step": ms}
    return _task_frame(task, pd.DataFrame([row]), len(frame))


def _task_frame(task: Task, frame: pd.DataFrame, n_steps: int) -> pd.DataFrame:
    """Prefix the task's description columns (those of its kind; ``steps``: the run's actual
    number of steps)."""
    described = {"task": task.key, "kind": task.kind, "world": task.world}
    if task.kind == "explore":
        described.update(planner=task.planner, planner_options=_options_text(task.planner_options),
                         floor_plan=np.nan if task.floor_plan is None else task.floor_plan)
    described.update(estimator=task.estimator, options=_options_text(task.options), steps=n_steps)
    if task.kind == "estimate":
        described.update(walk=task.walk, reference=task.reference or "")
    described["seed"] = task.seed
    for position, (column, value) in enumerate(described.items()):
        frame.insert(position, column, value)
    return frame


# --- storage ----------------------------------------------------------------------------------
def default_results_dir(out: str | os.PathLike) -> Path:
    """``results.parquet`` -> ``results.parts/``: where finished tasks are kept."""
    out = Path(out)
    return out.with_name(out.stem + ".parts")


def _part_path(results_dir: Path, task: Task) -> Path:
    return results_dir / f"{task.key}.parquet"


def _write_part(results_dir: Path, task: Task, frame: pd.DataFrame) -> None:
    """Atomically: a reader (or a resumed sweep) sees the whole file or none."""
    path = _part_path(results_dir, task)
    temporary = path.with_name(f".{path.name}.{uuid.uuid4().hex}.tmp")
    frame.to_parquet(temporary, index=False)
    os.replace(temporary, path)


def finished_tasks(tasks: Iterable[Task], results_dir: str | os.PathLike) -> set[str]:
    """Keys of the tasks whose result file exists in ``results_dir``."""
    results_dir = Path(results_dir)
    return {task.key for task in tasks if _part_path(results_dir, task).exists()}


def collect(tasks: Iterable[Task], results_dir: str | os.PathLike) -> pd.DataFrame:
    """One table from the result files of ``tasks`` (each task once, in spec order), with a
    column ``opt_NAME`` per option (and ``planner_opt_NAME`` per planner option). Files of
    tasks not in ``tasks`` (an older version of the spec) are left out."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    results_dir = Path(results_dir)
    done = [t for t in tasks if _part_path(results_dir, t).exists()]
    parts = [pq.read_table(_part_path(results_dir, t)) for t in done]  # pyarrow: ~3x faster than pandas
    if not parts:
        return _assemble([], pd.DataFrame(columns=TASK_COLUMNS), np.empty(0, dtype=np.int64))
    try:
        table = pa.concat_tables(parts, promote_options="permissive").to_pandas()
    except (pa.ArrowInvalid, pa.ArrowTypeError):  # columns whose types differ between tasks
        table = pd.concat([part.to_pandas() for part in parts], ignore_index=True)
    return _assemble(done, table, np.array([part.num_rows for part in parts]))


def _assemble(tasks: list[Task], table: pd.DataFrame, repeats: np.ndarray) -> pd.DataFrame:
    """Add the option columns to ``table``, whose rows are ``repeats[i]`` rows per task i."""
    for prefix, field in (("opt_", "options"), ("planner_opt_", "planner_options")):
        names = sorted({name for t in tasks for name, _ in getattr(t, field)})
        for name in names:
            values = [dict(getattr(t, field)).get(name) for t in tasks]
            present = [v for v in values if v is not None]
            kinds = {type(v) for v in present}
            numeric = kinds <= {int, float}
            if (not numeric and len(kinds) > 1) or kinds & {tuple, list}:  # one readable type per column
                values = [None if v is None else json.dumps(_plain(v)) for v in values]
            column = pd.Series(np.repeat(np.array(values, dtype=object), repeats))
            if numeric:
                column = pd.to_numeric(column)  # missing -> NaN
            table[prefix + name] = column
    return table


# --- running ----------------------------------------------------------------------------------
def sweep(spec, client=None, *, workers: int | None = None, out: str | os.PathLike | None = None,
          results_dir: str | os.PathLike | None = None, progress: bool = True) -> pd.DataFrame:
    """Run every task of ``spec`` and return one table (one row per task, or per task and step).

    spec: a path to a TOML file, a :class:`SweepSpec` or a dict. client: a
    ``distributed.Client``, a scheduler address (``"tcp://host:8786"``) or None. With no
    client, ``workers`` = 0 runs the tasks one by one in this process; otherwise a local
    dask cluster of ``workers`` processes (default: one per CPU, at most one per task) is
    started and closed afterwards. out: also write the table (.parquet or .csv).
    results_dir: where finished tasks are kept (default ``OUT.parts`` beside ``out``; with
    neither, results live only in memory and nothing resumes). Tasks already there are
    skipped. Raises :class:`SweepError` (after keeping every finished task) if tasks failed.
    """
    if client is not None and workers is not None:
        raise OnlineMapError("workers sizes a local cluster or picks serial mode (0); not with a client")
    spec = _as_spec(spec)
    if results_dir is None and out is not None:
        results_dir = default_results_dir(out)
    store = Path(results_dir) if results_dir is not None else None
    memory: dict[str, pd.DataFrame] = {}
    if store is not None:
        store.mkdir(parents=True, exist_ok=True)
        done = finished_tasks(spec.tasks, store)
    else:
        done = set()
    todo = [t for t in spec.tasks if t.key not in done]
    # tasks sharing a run one after the other, so the memoised run and reference are reused
    first: dict[tuple, int] = {}
    for task in todo:
        first.setdefault(_run_key(task), len(first))
    todo.sort(key=lambda task: first[_run_key(task)])
    failures: list[tuple[Task, BaseException]] = []

    def record(task: Task, frame: pd.DataFrame) -> None:
        if store is not None:
            _write_part(store, task, frame)
        else:
            memory[task.key] = frame
        bar.update()

    bar = tqdm(total=len(spec.tasks), initial=len(spec.tasks) - len(todo), desc=f"sweep {spec.name}",
               unit="task", disable=not progress, smoothing=0.1)
    try:
        if todo and client is None and workers == 0:
            for task in todo:
                try:
                    record(task, run_task(task))
                except Exception as error:  # keep going; report every failure at the end
                    failures.append((task, error))
        elif todo:
            _run_dask(todo, client, workers, record, failures)
    finally:
        bar.close()
    if store is not None:
        table = collect(spec.tasks, store)
    else:
        finished = [t for t in spec.tasks if t.key in memory]
        frames = [memory[t.key] for t in finished]
        table = _assemble(finished, pd.concat(frames, ignore_index=True) if frames else
                          pd.DataFrame(columns=TASK_COLUMNS), np.array([len(f) for f in frames], dtype=np.int64))
    if out is not None:
        write_table(table, out)
    if failures:
        position = {t.key: i for i, t in enumerate(spec.tasks)}
        task, error = min(failures, key=lambda failure: position[failure[0].key])  # first in spec order
        raise SweepError(f"{len(failures)} of {len(spec.tasks)} tasks failed (the others are kept; rerun to "
                         f"retry); first: {task.estimator}({_options_text(task.options)}) on {task.world}, "
                         f"seed {task.seed}: {type(error).__name__}: {error}")
    return table


def _run_key(task: Task) -> tuple:
    """What determines a task's simulated run (and its reference trajectory)."""
    return task.world, task.steps, task.walk, task.seed, task.reference, task.planner is None


def _as_spec(spec) -> SweepSpec:
    if isinstance(spec, SweepSpec):
        return spec
    if isinstance(spec, dict):
        return spec_from_dict(spec)
    if isinstance(spec, (str, os.PathLike)):
        return load_spec(spec)
    raise TypeError(f"spec must be a path, a dict or a SweepSpec, got {type(spec).__name__}")


def _dask():
    try:
        import distributed
    except ImportError:
        raise OnlineMapError(f"running a sweep on dask needs dask.distributed; {DASK_HINT} "
                             f"(or run serially with workers=0 / --workers 0)") from None
    return distributed


def local_cluster(workers: int | None = None, n_tasks: int | None = None):
    """A dask ``LocalCluster`` of worker processes, one thread each (the numerics hold the GIL
    or are numba kernels): ``workers`` processes, default one per CPU (at most one per task)."""
    distributed = _dask()
    count = workers or max(1, min(os.cpu_count() or 1, n_tasks or os.cpu_count() or 1))
    with warnings.catch_warnings():  # another cluster on this machine holds the default HTTP port
        warnings.filterwarnings("ignore", message="Port .* is already in use", category=UserWarning)
        return distributed.LocalCluster(n_workers=count, threads_per_worker=1, processes=True,
                                        dashboard_address=None, silence_logs=40)


def _run_dask(todo: list[Task], client, workers: int | None, record, failures: list) -> None:
    distributed = _dask()
    owned, futures = [], []
    if client is None:
        cluster = local_cluster(workers, len(todo))
        client = distributed.Client(cluster)
        owned = [client, cluster]
    elif isinstance(client, str):
        client = distributed.Client(client)
        owned = [client]
    try:
        futures = client.map(run_task, todo, pure=False)
        by_key = {future.key: task for future, task in zip(futures, todo)}
        completed = distributed.as_completed(futures)
        for future in completed:
            task = by_key[future.key]
            try:
                frame = future.result()
            except Exception as error:
                if future.status in ("lost", "pending"):  # its worker died after it finished: recomputed
                    completed.add(future)
                    continue
                failures.append((task, error))
            else:
                record(task, frame)
            future.release()
    except BaseException:
        client.cancel(futures)
        raise
    finally:
        for resource in owned:
            resource.close()


# --- summaries --------------------------------------------------------------------------------
def last_steps(table: pd.DataFrame) -> pd.DataFrame:
    """A per-step table (with a ``t`` column) cut to each task's last step; others unchanged."""
    if "t" in table.columns:
        table = table.sort_values("t").groupby("task", sort=False).tail(1)
    return table


def summarize(table: pd.DataFrame, metrics_: Iterable[str] | None = None, confidence: float = 0.95) -> pd.DataFrame:
    """Per configuration (every task column but the seed), for each metric: n, mean and a
    ``confidence`` interval over seeds (see :func:`mean_interval`). A per-step table is
    summarised at each task's last step. One row per configuration and metric."""
    table = last_steps(table)
    known = tuple(dict.fromkeys(TASK_METRICS + STEP_METRICS))
    chosen = [m for m in dict.fromkeys(metrics_ or known) if m in table.columns]
    missing = [m for m in (metrics_ or ()) if m not in table.columns]
    if missing:
        raise OnlineMapError(f"no metric {', '.join(missing)} in the table; it has: "
                             f"{', '.join(m for m in known if m in table.columns)}")
    config = [c for c in CONFIG_COLUMNS if c in table.columns and table[c].nunique(dropna=False) > 1] or \
        [c for c in ("estimator",) if c in table.columns]
    rows = []
    for keys, group in table.groupby(config, sort=False, dropna=False):
        keys = keys if isinstance(keys, tuple) else (keys,)
        for metric in chosen:
            column = group[metric]
            interval = mean_interval(column.to_numpy(dtype=np.float64), confidence,
                                     proportion=pd.api.types.is_bool_dtype(column))
            if math.isnan(interval.mean):
                continue
            rows.append({**dict(zip(config, keys)), "metric": metric, "n": len(group),
                         "mean": interval.mean, "low": interval.low, "high": interval.high})
    return pd.DataFrame(rows)


def summary_table(summary: pd.DataFrame) -> pd.DataFrame:
    """The long summary pivoted for reading: one row per configuration, one column per metric
    holding ``mean [low, high]``."""
    if summary.empty:
        return summary
    config = [c for c in summary.columns if c not in ("metric", "n", "mean", "low", "high")]

    def cell(row) -> str:
        if np.isnan(row["low"]):
            return f"{row['mean']:.4g}"
        return f"{row['mean']:.4g} [{row['low']:.4g}, {row['high']:.4g}]"

    summary = summary.assign(cell=summary.apply(cell, axis=1))
    wide = summary.pivot_table(index=config + ["n"], columns="metric", values="cell", aggfunc="first", sort=False)
    order = [m for m in dict.fromkeys(summary["metric"]) if m in wide.columns]
    return wide[order].reset_index().rename_axis(columns=None)


def plot_sweep(table: pd.DataFrame, x: str, metrics_: Iterable[str], path: str | os.PathLike | None = None,
               confidence: float = 0.95):
    """One panel per metric: its mean over seeds against ``x`` (an option name, e.g.
    ``n_particles``, or a task column such as ``world`` or ``steps``) with ``confidence``
    intervals as error bars, one line per remaining configuration. A per-step table is read at
    each task's last step. Saves to ``path`` if given; returns the matplotlib figure."""
    import matplotlib.pyplot as plt

    table = last_steps(table)
    column = x if x in table.columns else f"opt_{x}"
    if column not in table.columns:
        options = sorted(c[4:] for c in table.columns if c.startswith("opt_"))
        raise OnlineMapError(f"--x {x!r}: not an option or column of the table; options: {', '.join(options)}")
    metrics_ = [m for m in metrics_ if m in table.columns] or ["final_map_error"]
    varying = [c for c in ("world", "estimator", "planner", "walk", "steps", "reference")
               if c in table.columns and c != column and table[c].nunique() > 1]
    varying += [c for c in table.columns if c.startswith(("opt_", "planner_opt_")) and c != column
                and table[c].nunique() > 1]

    def label(row) -> str:
        parts = [f"{c.removeprefix('planner_opt_').removeprefix('opt_')}={row[c]}" if c.startswith(("opt_", "planner_opt_"))
                 else str(row[c]) for c in varying if pd.notna(row[c]) and row[c] != ""]
        return ", ".join(parts) or "all"

    table = table.assign(_line=table.apply(label, axis=1) if len(table) else [])
    flat = table[table[column].isna()]  # configurations without that option: horizontal lines
    table = table[table[column].notna()]
    numeric = pd.api.types.is_numeric_dtype(table[column])
    positions = None if numeric else {v: i for i, v in enumerate(dict.fromkeys(table[column]))}
    figure, axes = plt.subplots(1, len(metrics_), figsize=(5 * len(metrics_), 3.8), squeeze=False)
    for axis, metric in zip(axes[0], metrics_):
        proportion = pd.api.types.is_bool_dtype(table[metric])
        for line, group in table.groupby("_line", sort=False):
            points = [(value, mean_interval(g[metric].to_numpy(dtype=np.float64), confidence, proportion))
                      for value, g in group.groupby(column, sort=True)]
            xs = np.array([v if numeric else positions[v] for v, _ in points], dtype=np.float64)
            means = np.array([i.mean for _, i in points])
            errors = np.array([[i.mean - i.low, i.high - i.mean] for _, i in points]).T
            axis.errorbar(xs, means, yerr=np.nan_to_num(errors), marker="o", capsize=3, label=line)
        for style, (line, group) in zip(itertools.cycle(("--", ":", "-.")), flat.groupby("_line", sort=False)):
            level = mean_interval(group[metric].to_numpy(dtype=np.float64), confidence, proportion)
            axis.axhline(level.mean, linestyle=style, color="gray", label=f"{line} (no {x})")
        if numeric and table[column].min() > 0 and table[column].max() / table[column].min() >= 20:
            axis.set_xscale("log")
        if positions is not None:
            axis.set_xticks(range(len(positions)), list(positions), rotation=20)
        axis.set_xlabel(x)
        axis.set_ylabel(metric)
        axis.grid(alpha=0.3)
    handles, labels = axes[0][0].get_legend_handles_labels()
    columns = min(3, max(1, len(labels)))
    rows = math.ceil(len(labels) / columns)
    figure.set_figheight(3.8 + 0.2 * rows)
    figure.legend(handles, labels, loc="lower center", ncol=columns, fontsize=7, frameon=False)
    figure.suptitle(f"mean over seeds with {confidence:.0%} intervals")
    figure.tight_layout(rect=(0, 0.2 * rows / (3.8 + 0.2 * rows) + 0.02, 1, 1))
    if path is not None:
        plots.save(figure, path, dpi=120)
    return figure
