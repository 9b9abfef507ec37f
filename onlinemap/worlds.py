"""World specs for the command line: ``corridor:8``, ``corridor:10,p_change=0.01,n_labels=3``,
``grid:2x3``, ``door``, ``door,p_door=0.01``, ``door,blocking=1,footprint=cross``,
``grid:3x3,blocking=1,footprint=square``, ``building:32x32,seed=3``,
``building:20x40,seed=1,p_door=0.01,extra_doors=0.5``, ``layout:floors/office.map``,
``layout:maps/lab.yaml,cell_size=0.5``, ``layout:maps/lab.yaml,cell_size=0.25,region=-2:8x-3:5``,
``layout:"floors/a,b.map",cell_rule=any,doorways=0``.

Every kind takes ``p_obs``, ``p_move``, ``start``, ``blocking`` and ``footprint``
(:data:`KIND_KEYS` lists each kind's keys; :func:`world_help` says it in one paragraph, for every
``--world`` option). ``footprint`` takes a preset (cell, cross, square); ``blocking`` is 0/1
(false/true) for door worlds and buildings (walls and closed doors block) and the blocking
labels, joined by ``+``, for corridors and grids (``blocking=1``, ``blocking=1+2``). Worlds
with a fixed map (door, building, layout) take ``floor_plan=C``: the robot's label prior is the
floor plan (:func:`floor_plan_prior`: each cell's true label with confidence C, door cells a door
of unknown state), e.g. ``door,floor_plan=0.95``; or ``label_prior=floor``: the robot's label
prior is the map's own label frequencies, the same for every cell (:func:`frequency_prior`: what
a robot told its building's mix of free cells, walls and doors would assume); or
``label_prior=uniform``: the fixed uniform prior, frequencies known (a building or a layout
otherwise leaves its label frequencies unknown, and estimators learn them: the baseline without
learning). Either key and ``floor_plan`` state the robot's prior: the model's
``unknown_label_frequencies`` is then off. A building
(:func:`onlinemap.buildings.building`; default 32x32, seed 0) blocks and reads a cross unless
told otherwise (``blocking=0``, ``footprint=cell``) and takes ``seed``, ``corridor_width``,
``rooms_deep``, ``extra_doors`` and ``closed_share``. A layout
(:func:`onlinemap.layouts.read_layout`) reads the file named after ``layout:`` (a ``.map``,
``.yaml`` or ``.pgm``; a relative path from the working directory; a path with a comma goes in
double quotes, ``layout:"a,b.map"``), with the same defaults, ``cell_size``, ``cell_rule``
(majority, any, threshold), ``doorways`` (0/1) and ``region=A:BxC:D``: rows A..B and columns
C..D of a ``.map`` or ``.pgm``, or x from A to B and y from C to D metres of a ROS map.

``parse_world(spec) -> WorldSpec`` holds the model and, for door worlds, buildings and layouts,
the map.

Imports: :mod:`.model`, :mod:`.validation`, :mod:`.simulate`, :mod:`.buildings`, :mod:`.layouts`.
"""

from __future__ import annotations

import dataclasses
from typing import Callable, NamedTuple

import numpy as np

from . import arguments
from .buildings import building
from .errors import ModelError, OnlineMapError
from .layouts import read_layout
from .model import CLOSED_DOOR, OPEN_DOOR, GridModel, corridor, door_cells, door_world, grid_model, symmetric_channel
from .rng import SeedLike
from .simulate import Run, random_walk, sample_map
from .simulate import simulate as _simulate
from .validation import check_map

_FLOAT_KEYS = {"p_obs", "p_move", "p_change", "p_door", "extra_doors", "closed_share", "floor_plan"}
_INT_KEYS = {"n_labels", "start", "seed", "corridor_width", "rooms_deep"}
_REAL_KEYS = {"cell_size"}
_FLAG_KINDS = ("door", "building", "layout")  # kinds whose blocking option is a flag
_TEXT_KEYS = {"blocking", "footprint", "cell_rule", "label_prior"}
_FLAG_KEYS = {"doorways"}
_FLAGS = {"1": True, "true": True, "0": False, "false": False}

_EVERY_KIND = ("p_obs", "p_move", "start", "blocking", "footprint")
_DOORS = ("p_door", "floor_plan", "label_prior")
#: the keys each kind of world spec takes, after its own size or path
KIND_KEYS = {
    "corridor": ("n_labels", "p_change", *_EVERY_KIND),
    "grid": ("n_labels", "p_change", *_EVERY_KIND),
    "door": (*_DOORS, *_EVERY_KIND),
    "building": ("seed", "corridor_width", "rooms_deep", "extra_doors", "closed_share", *_DOORS, *_EVERY_KIND),
    "layout": ("cell_size", "cell_rule", "region", "doorways", *_DOORS, *_EVERY_KIND),
}
_KIND_FORMS = {"corridor": "corridor:N", "grid": "grid:RxC", "door": "door", "building": "building:RxC",
               "layout": "layout:PATH"}


def world_help() -> str:
    """One paragraph for every ``--world`` option: each kind with its keys (from :data:`KIND_KEYS`)."""
    kinds = "; ".join(f"{_KIND_FORMS[kind]} ({', '.join(k for k in keys if k not in _EVERY_KIND)})"
                      for kind, keys in KIND_KEYS.items())
    return (f"world spec KIND[,KEY=VALUE...]: {kinds}; every kind also takes {', '.join(_EVERY_KIND)} "
            "(blocking=0/1 for door worlds, labels joined by + otherwise; footprint=cell|cross|square); "
            "floor_plan=C gives the robot the floor plan as its prior (confidence C, door states unknown); "
            "label_prior=floor gives it the map's label frequencies, label_prior=uniform the fixed uniform prior "
            "(buildings and layouts otherwise learn their label frequencies)")


def floor_plan_prior(model: GridModel, true_map, confidence: float = 0.8) -> np.ndarray:
    """(N, K) label prior from a floor plan: ``confidence`` on each cell's true label, the rest
    spread uniformly over the other labels. In a door world, door cells get 1/2 open, 1/2
    closed (the plan shows the door, not its state). Cost O(N K)."""
    labels = check_map(model, true_map)
    k = model.n_labels
    if not 1.0 / k <= float(confidence) <= 1.0:
        raise ModelError(f"confidence must be in [1/K, 1] = [{1 / k:.3g}, 1], got {confidence!r}")
    prior = np.full((model.n_cells, k), (1.0 - confidence) / (k - 1))
    prior[np.arange(model.n_cells), labels] = confidence
    doors = door_cells(model, labels)
    if len(doors):
        prior[doors] = 0.0
        prior[np.ix_(doors, [OPEN_DOOR, CLOSED_DOOR])] = 0.5
    return prior


def frequency_prior(model: GridModel, true_map) -> np.ndarray:
    """(K,) label prior from a map's label frequencies: ``n_k / N``, the share of the N cells of
    ``true_map`` whose label is k (a label the map lacks gets 0). Cost O(N + K)."""
    labels = check_map(model, true_map)
    return np.bincount(labels, minlength=model.n_labels) / labels.size


def with_floor_plan(model: GridModel, true_map, confidence: float = 0.8) -> GridModel:
    """``model`` with the :func:`floor_plan_prior` of ``true_map`` as its label prior (a stated
    prior: the label frequencies are not learned, ``unknown_label_frequencies`` off)."""
    return dataclasses.replace(model, label_prior=floor_plan_prior(model, true_map, confidence),
                               unknown_label_frequencies=False)


def uniform_prior(model: GridModel, true_map=None) -> np.ndarray:
    """(K,) the uniform label prior ``1 / K`` (``true_map`` unused: the signature of
    :func:`frequency_prior`). O(K)."""
    return np.full(model.n_labels, 1.0 / model.n_labels)


#: the label_prior key's values: the (K,) table each states (the frequencies known, not learned)
_STATED_PRIORS = {"floor": frequency_prior, "uniform": uniform_prior}


class WorldSpec(NamedTuple):
    spec: str
    model: GridModel
    true_map: np.ndarray | None  # fixed map (door worlds, buildings, layouts); None = draw one from the prior
    floor_plan: float | None = None  # the floor_plan key: the model's label prior is the map's floor plan
    label_prior: str | None = None  # the label_prior key ("floor": the map's label frequencies; "uniform"), if given

    def initial_map(self, seed: SeedLike = None) -> np.ndarray:
        """The fixed map, or one drawn from the label prior with ``seed``."""
        return self.true_map if self.true_map is not None else sample_map(self.model, seed)

    def simulate(self, n_steps: int, seed: SeedLike = None,
                 walk: Callable[[GridModel, int, np.random.Generator], np.ndarray] | None = None) -> Run:
        """A seeded run of ``n_steps`` steps (first observation included), as ``onlinemap run
        --seed`` makes it: ``rng = default_rng(seed)`` draws the initial map
        (:meth:`initial_map`), then the ``n_steps - 1`` actions (``walk(model, n_actions, rng)``,
        default :func:`~onlinemap.simulate.random_walk`), then the moves and noise
        (:func:`~onlinemap.simulate.simulate`). Cost: O(n_steps N K)."""
        rng = np.random.default_rng(seed)
        true_map = self.initial_map(rng)
        actions = (walk or random_walk)(self.model, max(int(n_steps) - 1, 0), rng)
        return _simulate(self.model, true_map, actions, rng)


_MAX_SPEC = 1000  # characters


def _whole(spec: str, what: str, text: str) -> int:
    """A size or count written in a spec: decimal digits only (no sign, no 1e3, no 1.5)."""
    text = text.strip()
    if not text.isdigit() or not text.isascii() or len(text) > 12:
        raise ModelError(f"world spec {spec!r}: {what} must be a whole number, got {text!r}")
    return int(text)


def _rows_cols(spec: str, kind: str, size: str) -> tuple[int, int]:
    rows, x, cols = size.partition("x")
    if not x:
        raise ModelError(f"world spec {spec!r}: a {kind}'s size is RxC, got {size!r}")
    return _whole(spec, "rows", rows), _whole(spec, "cols", cols)


def _region(spec: str, text: str) -> tuple[tuple[float, float], tuple[float, float]]:
    """``A:BxC:D`` -> ((A, B), (C, D)), whole numbers as int (cells), others as float (metres)."""
    def number(part: str) -> int | float:
        part = part.strip()
        digits = part.removeprefix("-")
        if digits.isascii() and digits.isdigit() and len(digits) <= 12:
            return int(part)
        try:
            return float(part)
        except ValueError:
            raise ModelError(f"world spec {spec!r}: region is A:BxC:D (rows or x, then cols or y), got {text!r}") \
                from None

    pairs = [pair.split(":") for pair in text.split("x")]
    if len(pairs) != 2 or any(len(pair) != 2 for pair in pairs):
        raise ModelError(f"world spec {spec!r}: region is A:BxC:D (rows or x, then cols or y), got {text!r}")
    return tuple(tuple(number(part) for part in pair) for pair in pairs)


def _value(spec: str, key: str, text: str) -> int | float | str | bool | tuple:
    if key in _TEXT_KEYS:
        return text.strip()
    if key in _FLAG_KEYS:
        if text.strip().lower() not in _FLAGS:
            raise ModelError(f"world spec {spec!r}: {key} is 0 or 1, got {text!r}")
        return _FLAGS[text.strip().lower()]
    if key == "region":
        return _region(spec, text)
    if key in _INT_KEYS:
        return _whole(spec, key, text)
    if key in _REAL_KEYS:
        try:
            return float(text)
        except ValueError:
            raise ModelError(f"world spec {spec!r}: {key} must be a number, got {text!r}") from None
    try:
        value = float(text)
    except ValueError:
        raise ModelError(f"world spec {spec!r}: {key} must be a number, got {text!r}") from None
    return arguments.probability(f"world spec {spec!r}: {key}", value)


def _blocking(spec: str, kind: str, value: str):
    """A door world's or building's flag (0/1/true/false) or the '+'-joined blocking labels of another world."""
    if kind in _FLAG_KINDS:
        if value.lower() not in _FLAGS:
            raise ModelError(f"world spec {spec!r}: blocking for a {kind} world is 0 or 1, got {value!r}")
        return _FLAGS[value.lower()]
    labels = [label.strip() for label in value.split("+")]
    return [int(label) if label.isascii() and label.isdigit() else label for label in labels]  # else a name


def parse_world(spec: str) -> WorldSpec:
    """Parse ``kind[:size][,key=value...]``; kinds: corridor (size N), grid (size RxC), door,
    building (size RxC), layout (a file name); each takes the keys :data:`KIND_KEYS` lists.
    Anything malformed raises :class:`ModelError` naming the part at fault."""
    if not isinstance(spec, str) or not spec.strip() or len(spec) > _MAX_SPEC:
        raise ModelError(f"a world spec is a str of at most {_MAX_SPEC} characters like 'corridor:8', "
                         f"got {type(spec).__name__} of length {len(spec) if isinstance(spec, str) else '?'}")
    head, pairs = _split(spec)
    kind, _, size = head.partition(":")
    if kind not in KIND_KEYS:
        raise ModelError(f"world spec {spec!r}: unknown kind {kind!r} ({', '.join(_KIND_FORMS.values())})")
    options: dict[str, object] = {}
    for pair in pairs:
        key, eq, value = pair.partition("=")
        key = key.strip()
        if not eq:
            hint = (f"; a layout path with a comma goes in double quotes: layout:\"{size},{pair}\""
                    if kind == "layout" else "")
            raise ModelError(f"world spec {spec!r}: expected key=value, got {pair!r}{hint}")
        if key not in KIND_KEYS[kind]:
            hint = (" (only worlds with a fixed map take a floor plan: door, building, layout; for maps "
                    "drawn per seed use explore --floor-plan or a sweep's floor_plan)") if key == "floor_plan" else ""
            raise ModelError(f"world spec {spec!r}: unknown option {key!r} for a {kind} world{hint} "
                             f"(known: {', '.join(KIND_KEYS[kind])})")
        if key in options:
            raise ModelError(f"world spec {spec!r}: option {key!r} given twice")
        options[key] = _value(spec, key, value)
    if "blocking" in options:
        options["blocking"] = _blocking(spec, kind, str(options["blocking"]))
    floor_plan = options.pop("floor_plan", None)
    label_prior = options.pop("label_prior", None)
    if label_prior is not None and label_prior not in _STATED_PRIORS:
        raise ModelError(f"world spec {spec!r}: label_prior takes 'floor' (the map's own label frequencies) or "
                         f"'uniform' (the fixed uniform prior), got {label_prior!r}")
    if label_prior is not None and floor_plan is not None:
        raise ModelError(f"world spec {spec!r}: floor_plan and label_prior both set the label prior; give one")
    try:
        world = _build(spec, kind, size, options)
        if label_prior is not None:
            table = _STATED_PRIORS[label_prior](world.model, world.true_map)
            world = world._replace(model=dataclasses.replace(world.model, label_prior=table,
                                                             unknown_label_frequencies=False), label_prior=label_prior)
        if floor_plan is not None:
            try:
                world = world._replace(model=with_floor_plan(world.model, world.true_map, floor_plan),
                                       floor_plan=floor_plan)
            except ModelError as error:
                raise ModelError(f"world spec {spec!r}: floor_plan={floor_plan}: {error}") from None
        return world
    except OnlineMapError as error:  # keeps its class (a FloorFileError stays one)
        if str(error).startswith("world spec"):
            raise
        raise type(error)(f"world spec {spec!r}: {error}") from None
    except (TypeError, ValueError, ArithmeticError, MemoryError, RecursionError) as error:
        raise ModelError(f"world spec {spec!r}: {type(error).__name__}: {error}") from None


def _split(spec: str) -> tuple[str, list[str]]:
    """``kind[:size]`` and the ``key=value`` parts of a spec; a layout path may be in double quotes
    (then it may hold commas)."""
    text = spec.strip()
    if not text.startswith('layout:"'):
        head, *pairs = [part.strip() for part in text.split(",")]
        return head, pairs
    end = text.find('"', len('layout:"'))
    if end < 0:
        raise ModelError(f"world spec {spec!r}: the layout path's closing double quote is missing")
    rest = text[end + 1:].strip()
    if rest and not rest.startswith(","):
        raise ModelError(f"world spec {spec!r}: expected a comma after the quoted path, got {rest[:20]!r}")
    return "layout:" + text[len('layout:"'):end], [part.strip() for part in rest[1:].split(",")] if rest else []


def _build(spec: str, kind: str, size: str, options: dict) -> WorldSpec:
    """The world of a parsed spec (``kind`` known, ``options`` checked against its keys)."""
    if kind == "corridor":
        return WorldSpec(spec, corridor(_whole(spec, "the corridor's length", size or "8"), **options), None)
    if kind == "grid":
        rows, cols = _rows_cols(spec, "grid", size or "2x3")
        change = options.pop("p_change", 0.0)
        k = arguments.integer("n_labels", options.pop("n_labels", 2), minimum=2, maximum=arguments.MAX_LABELS)
        return WorldSpec(spec, grid_model(rows, cols, k, change=symmetric_channel(k, 1 - change),
                                          **options), None)
    if kind == "door":
        if size:
            raise ModelError("door worlds take no size; read a floor from a file with layout:PATH")
        model, true_map = door_world(**options)
        return WorldSpec(spec, model, true_map)
    if kind == "building":
        model, true_map = building(*_rows_cols(spec, "building", size or "32x32"),
                                   **{"seed": 0} | options)
        return WorldSpec(spec, model, true_map)
    if not size:  # a layout
        raise ModelError(f"world spec {spec!r}: a layout names its file, layout:PATH")
    model, true_map = read_layout(size, **options)
    return WorldSpec(spec, model, true_map)
