"""Sweep specs: reading TOML, checking every key and value, expanding the grid into tasks.

A spec is checked completely before any task runs: unknown keys, estimators, planners or
options, wrong types, world specs, seeds (0 <= seed < 2**63) and steps (at most
:data:`MAX_STEPS`), the number of tasks (counted before any is built, at most ``max_tasks``),
and every (world, configuration) pair is built once, so option values an estimator refuses and
memory limits are caught too. Errors name the file, line and key path (:class:`SpecError`).
Each world string is parsed once here; the task runner parses it once per process.

Specs with ``[planners.NAME]`` tables (exploration; navigation with ``goals``) are checked by
the task kind that plays them (:mod:`.kinds`), which the engine finds without importing it.

Imports: :mod:`.tasks`, :mod:`.kinds`.
"""

from __future__ import annotations

import collections.abc
import inspect
import itertools
import math
import json
import os
import re
import tomllib
import types
import typing
from pathlib import Path
from typing import Callable

from ..errors import OnlineMapError
from ..estimators import available_estimators, estimator_options, make_estimator
from ..estimators.base import estimator_class
from ..worlds import WorldSpec, parse_world
from .kinds import TaskKind, task_kind
from .tasks import MAX_TASKS, SweepSpec, expand, frozen, options_text, plain

WALKS = ("random", "there_and_back", "scripted_trip")
REPEAT = "repeat:"  # walk = "repeat:east,east,south": those actions, over and over
ROWS = ("task", "step")
TOP_KEYS = ("name", "kind", "worlds", "seeds", "steps", "walk", "rows", "reference", "floor_plan", "goals",
            "estimators", "planners")
MAX_SEED = 2**63 - 1  # seeds go through numpy's SeedSequence as int64-sized integers
MAX_STEPS = 10**7  # a run holds its T x N x K beliefs in memory: 10^7 steps of a 2-cell binary world is 320 MB


class SpecError(OnlineMapError):
    """A sweep spec is malformed; the message names the file, line and key."""


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


def load_spec(path: str | os.PathLike, max_tasks: int = MAX_TASKS) -> SweepSpec:
    """Read and validate a TOML spec file (UTF-8; see :mod:`onlinemap.sweeps`)."""
    path = Path(path)
    try:
        text = path.read_bytes().decode("utf-8")
    except OSError as error:
        raise SpecError(f"cannot read sweep spec {path}: {error.strerror or error}") from None
    except UnicodeDecodeError as error:
        line = path.read_bytes()[:error.start].count(b"\n") + 1
        raise SpecError(f"{path}, line {line}: not UTF-8 text (byte {error.object[error.start]:#04x} at "
                        f"offset {error.start}); a TOML spec must be UTF-8") from None
    return parse_spec(text, source=str(path), name=path.stem, max_tasks=max_tasks)


def parse_spec(text: str, source: str = "<spec>", name: str = "sweep", max_tasks: int = MAX_TASKS) -> SweepSpec:
    """Parse and validate TOML ``text``; ``source`` names it in error messages."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as error:
        line = re.search(r"at line (\d+)", str(error))
        where = f"{source}, line {line.group(1)}" if line else source
        raise SpecError(f"{where}: not valid TOML: {error}") from None
    return spec_from_dict(data, _Locator(text, source), name, max_tasks)._replace(text=text)


def spec_from_dict(data: dict, locator: _Locator | None = None, name: str = "sweep",
                   max_tasks: int = MAX_TASKS) -> SweepSpec:
    """Validate a spec already parsed into a dict (errors then name key paths, not lines) and
    expand it into tasks (at most ``max_tasks``)."""
    where = locator or _Locator(None, "<spec>")
    for key in data:
        if key not in TOP_KEYS:
            raise where.error((key,), f"unknown key; known keys: {', '.join(TOP_KEYS)}")
    worlds = _worlds(data, where)
    seeds = _seeds(data, where)
    steps = _steps(data, where)
    rows = _choice(data, "rows", ROWS, where, default="task")
    kind = _played_kind(data, where)
    if kind is not None:
        for key in ("walk", "reference"):
            if key in data:
                raise where.error((key,), "does not apply to exploration sweeps (with [planners])")
        walks, reference = ["random"], None
        planners = _configs(data, "planners", where, kind.options, kind.option_class, max_tasks)
        floor_plans = _floor_plans(data, worlds, kind, where)
        goals = _goals(data, worlds, where) if kind.name == "navigate" else [None]
    else:
        walks = _walks(data, worlds, where)
        reference = data.get("reference")
        if reference is not None and reference not in available_estimators():
            raise where.error(("reference",), f"unknown estimator {reference!r}; "
                                              f"available: {', '.join(available_estimators())}")
        planners = []
        for key in ("floor_plan", "goals"):
            if key in data:
                raise where.error((key,), "applies to exploration sweeps (with [planners]) only")
        floor_plans, goals = [None], [None]
    estimators = _configs(data, "estimators", where, estimator_options, estimator_class, max_tasks)
    if "trip" in steps and not set(walks) <= {"there_and_back", "scripted_trip"}:
        raise where.error(("steps",), 'steps = "trip" (one there-and-back trip) needs walk = "there_and_back" '
                                      'or "scripted_trip"')
    if "scripted_trip" in walks and steps != ["trip"]:
        raise where.error(("walk",), 'walk = "scripted_trip" is one trip: it needs steps = "trip"')
    if {"there_and_back", "scripted_trip"} & set(walks):
        bad = [w.spec for w in worlds if w.model.action_names != ("left", "right")
               or ("scripted_trip" in walks and not (w.model.is_static and w.model.is_paper_model))]
        if bad:
            raise where.error(("walk",), f"there_and_back needs corridor worlds (scripted_trip static ones whose "
                                         f"sensor reads the robot's own cell, without blocking labels: it writes "
                                         f"the true label as every observation), not {', '.join(bad)}")
    _check_builds(worlds, estimators, planners, kind, goals, where)
    if reference is not None:
        _check_builds(worlds, [(reference, (), ("reference",), None)], [], None, [None], where)
    try:
        tasks = expand([w.spec for w in worlds], [(c[0], c[1], c[3]) for c in estimators],
                       [(c[0], c[1], c[3]) for c in planners] or [(None, (), None)],
                       floor_plans, steps, walks, seeds, reference, rows == "step", max_tasks, goals,
                       kind.name if kind is not None and kind.name not in ("explore", "navigate") else None)
    except OnlineMapError as error:
        raise where.error((), str(error)) from None
    label = data.get("name", name)
    if not isinstance(label, str):
        raise where.error(("name",), f"expected a string, got {label!r}")
    return SweepSpec(label, tasks, where.source, json.dumps(plain(data), sort_keys=True, default=str))


def _played_kind(data: dict, where: _Locator) -> TaskKind | None:
    """The kind of a spec with ``[planners]`` tables: ``kind`` if given (a registered kind, e.g.
    ``replay``), else ``navigate`` with ``goals``, else ``explore`` (None for a spec without
    planners: the engine's own simulate-and-filter tasks)."""
    if "planners" not in data:
        if "kind" in data:
            raise where.error(("kind",), "a task kind plays [planners.NAME] tables: add one")
        return None
    name = data.get("kind", "navigate" if "goals" in data else "explore")
    if not isinstance(name, str):
        raise where.error(("kind",), f"expected the name of a task kind, got {name!r}")
    try:
        kind = task_kind(name)
    except OnlineMapError as error:
        raise where.error(("kind",) if "kind" in data else ("planners",), str(error)) from None
    if "goals" in data and kind.name != "navigate":
        raise where.error(("goals",), f"goals are for navigation; kind {kind.name!r} has none")
    return kind


def _floor_plans(data: dict, worlds: list[WorldSpec], kind: TaskKind, where: _Locator) -> list[float | None]:
    """``floor_plan``: none, a confidence or a list of them (the kind's ``prior``: the robot's
    label prior puts that much on each cell's true label of the initial map)."""
    value = data.get("floor_plan")
    if value is None:
        return [None]
    values = value if isinstance(value, list) else [value]
    if not values or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values):
        raise where.error(("floor_plan",), f"expected a confidence in [1/K, 1] or a list of them, got {value!r}")
    for world in worlds:
        for confidence in values:
            try:
                kind.prior(world.model, world.initial_map(0), float(confidence))
            except OnlineMapError as error:
                raise where.error(("floor_plan",), f"{world.spec}: {error}") from None
    return [float(v) for v in values]


def _goals(data: dict, worlds: list[WorldSpec], where: _Locator) -> list[int]:
    """``goals``: a cell index, ``[row, col]``, or a list of them (each a cell of every world)."""
    value = data["goals"]
    values = value if isinstance(value, list) and not (len(value) == 2 and all(map(_is_int, value))) else [value]
    cells = []
    for goal in values:
        found = set()
        for world in worlds:
            model = world.model
            if _is_int(goal) and 0 <= goal < model.n_cells:
                found.add(goal)
            elif isinstance(goal, list) and len(goal) == 2 and all(map(_is_int, goal)) \
                    and 0 <= goal[0] < model.rows and 0 <= goal[1] < model.cols:
                found.add(goal[0] * model.cols + goal[1])
            else:
                raise where.error(("goals",), f"expected cell indices or [row, col] pairs on {world.spec} "
                                              f"({model.rows} x {model.cols}), got {goal!r}")
        if len(found) > 1:
            raise where.error(("goals",), f"{goal!r} is a different cell in each world; give a cell index")
        cells.append(found.pop())
    if not cells:
        raise where.error(("goals",), "empty list: give at least one goal")
    return cells


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
        except (OnlineMapError, ValueError) as error:
            raise where.error(("worlds",), str(error)) from None
    return worlds


def _seeds(data: dict, where: _Locator) -> range | list[int]:
    """``seeds = n`` -> range(n) (lazy: counted before anything is built); or a list of seeds."""
    seeds = data.get("seeds", 10)
    if _is_int(seeds):
        if not 1 <= seeds <= MAX_SEED:
            raise where.error(("seeds",), f"the number of seeds must be in [1, 2**63 - 1], got {seeds}")
        return range(seeds)
    if isinstance(seeds, list) and seeds and all(_is_int(s) and 0 <= s <= MAX_SEED for s in seeds):
        if len(set(seeds)) != len(seeds):
            raise where.error(("seeds",), "repeated seed")
        return seeds
    raise where.error(("seeds",), f"expected a count (int >= 1) or a non-empty list of seeds "
                                  f"(ints in [0, 2**63 - 1]), got {seeds!r}")


def _is_int(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _steps(data: dict, where: _Locator) -> list[int | str]:
    value = data.get("steps", 100)
    values = value if isinstance(value, list) else [value]
    if not values or not all((_is_int(v) and 1 <= v <= MAX_STEPS) or v == "trip" for v in values):
        raise where.error(("steps",), f'expected an int in [1, {MAX_STEPS:,}] (a run keeps its beliefs in '
                                      f'memory), "trip" or a list of them, got {value!r}')
    return values


def _walks(data: dict, worlds: list[WorldSpec], where: _Locator) -> list[str]:
    """``walk``: one of :data:`WALKS`, ``"repeat:NAME,NAME,..."`` (those actions over and over,
    each name an action of every world), or a list of them."""
    value = data.get("walk", "random")
    values = value if isinstance(value, list) else [value]
    for walk in values:
        if isinstance(walk, str) and walk.startswith(REPEAT):
            names = walk[len(REPEAT):].split(",")
            for world in worlds:
                unknown = [n for n in names if n not in world.model.action_names]
                if unknown:
                    raise where.error(("walk",), f"{walk!r}: {', '.join(map(repr, unknown))} not actions of "
                                                 f"{world.spec} ({', '.join(world.model.action_names)})")
        elif walk not in WALKS:
            raise where.error(("walk",), f"expected one of {', '.join(map(repr, WALKS))}, \"{REPEAT}NAME,...\" "
                                         f"or a list of them, got {value!r}")
    if not values:
        raise where.error(("walk",), "empty list: give at least one walk")
    return values


def _choice(data: dict, key: str, allowed: tuple, where: _Locator, default: str) -> str:
    value = data.get(key, default)
    if value not in allowed:
        raise where.error((key,), f"expected one of {', '.join(map(repr, allowed))}, got {value!r}")
    return value


# --- option grids and their types ------------------------------------------------------------
def describe_type(annotation) -> str:
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
    if annotation is type(None):  # get_type_hints turns a None annotation into NoneType
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
    if origin is collections.abc.Callable or annotation is collections.abc.Callable:
        return callable(value)
    if isinstance(annotation, type):
        return isinstance(value, annotation)
    return True


def expected_type(cls: type, name: str, default):
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


def _grid(table, path: tuple, known: dict, cls: type, where: _Locator, max_tasks: int) -> list[tuple]:
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
        expected = expected_type(cls, option, known[option])
        for v in values:
            if not matches_annotation(v, expected):
                hint = " (a list is a grid of values; write a list-valued option as a list of lists)" \
                    if isinstance(value, list) and not isinstance(v, list) else ""
                raise where.error(path + (option,), f"expected {describe_type(expected)}, got {v!r}{hint}")
        axes.append([(option, frozen(v)) for v in values])
    size = math.prod(len(axis) for axis in axes)
    if size > max_tasks:
        raise where.error(path, f"a grid of {size:,} configurations exceeds the cap of {max_tasks:,} tasks "
                                f"(max_tasks / --max-tasks raises it)")
    return [tuple(sorted(combo)) for combo in itertools.product(*axes)]


def _configs(data: dict, section: str, where: _Locator, options_of: Callable[[str], dict],
             builder: Callable[[str], type], max_tasks: int) -> list[tuple[str, tuple, tuple, str | None]]:
    """[(name, options, key path, label)] for every configuration in ``[section.NAME]`` tables.
    A table's ``label`` (a string, not an option) names its configurations in the results
    (column ``label`` or ``planner_label``), so a study reads its groups as data."""
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
        grids = [((section, name, index), table) for index, table in enumerate(body)] if isinstance(body, list) \
            else [((section, name), body)]
        for path, table in grids:
            label = None
            if isinstance(table, dict) and "label" in table and "label" not in known:
                table = dict(table)
                label = table.pop("label")
                if not isinstance(label, str) or not label:
                    raise where.error(path + ("label",), f"expected a non-empty string, got {label!r}")
            configs += [(name, combo, path, label) for combo in _grid(table, path, known, cls, where, max_tasks)]
    return configs


def _check_builds(worlds: list[WorldSpec], estimators: list, planners: list, kind: TaskKind | None,
                  goals: list, where: _Locator) -> None:
    """Build every (world, configuration) once, so refused values and memory limits show now
    (a planner with every goal, which is one of its options)."""
    for world in worlds:
        for name, options, path, _ in estimators:
            try:
                make_estimator(name, world.model, **dict(options))
            except Exception as error:  # the estimator's own validation, whatever it raises
                raise where.error(path, f"{name}({options_text(options)}) on {world.spec}: "
                                        f"{type(error).__name__}: {error}") from None
        for name, options, path, _ in planners:
            for goal in goals:
                chosen = dict(options) if goal is None else {**dict(options), "goal": goal}
                try:
                    kind.build(world.model, name, chosen)
                except Exception as error:
                    raise where.error(path, f"planner {name}({options_text(tuple(sorted(chosen.items())))}) on "
                                            f"{world.spec}: {type(error).__name__}: {error}") from None
