"""World specs for the command line: ``corridor:8``, ``corridor:10,p_change=0.01,n_labels=3``,
``grid:2x3``, ``door``, ``door,p_door=0.01``, ``door,blocking=1,footprint=cross``,
``grid:3x3,blocking=1,footprint=square``.

``footprint`` takes a preset (cell, cross, square); ``blocking`` is 0/1 (false/true) for door
worlds (walls and closed doors block) and the blocking labels, joined by ``+``, for corridors and
grids (``blocking=1``, ``blocking=1+2``).

``parse_world(spec) -> WorldSpec`` holds the model and, for door worlds, the layout's map.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import numpy as np

from . import arguments
from .errors import ModelError
from .model import GridModel, corridor, door_world, grid_model, symmetric_channel
from .rng import SeedLike
from .simulate import Run, random_walk, sample_map
from .simulate import simulate as _simulate

_FLOAT_KEYS = {"p_obs", "p_move", "p_change", "p_door"}
_INT_KEYS = {"n_labels", "start"}
_TEXT_KEYS = {"blocking", "footprint"}


class WorldSpec(NamedTuple):
    spec: str
    model: GridModel
    true_map: np.ndarray | None  # fixed map (door worlds); None = draw one from the prior

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


def _value(spec: str, key: str, text: str) -> int | float | str:
    if key in _TEXT_KEYS:
        return text.strip()
    if key in _INT_KEYS:
        return _whole(spec, key, text)
    try:
        value = float(text)
    except ValueError:
        raise ModelError(f"world spec {spec!r}: {key} must be a number, got {text!r}") from None
    return arguments.probability(f"world spec {spec!r}: {key}", value)


def _blocking(spec: str, kind: str, value: str):
    """A door world's flag (0/1/true/false) or the '+'-joined blocking labels of another world."""
    if kind == "door":
        flags = {"1": True, "true": True, "0": False, "false": False}
        if value.lower() not in flags:
            raise ModelError(f"world spec {spec!r}: blocking for a door world is 0 or 1, got {value!r}")
        return flags[value.lower()]
    labels = [label.strip() for label in value.split("+")]
    return [int(label) if label.isascii() and label.isdigit() else label for label in labels]  # else a name


def parse_world(spec: str) -> WorldSpec:
    """Parse ``kind[:size][,key=value...]``; kinds: corridor (size N), grid (size RxC), door.
    Anything malformed raises :class:`ModelError` naming the part at fault."""
    if not isinstance(spec, str) or not spec.strip() or len(spec) > _MAX_SPEC:
        raise ModelError(f"a world spec is a str of at most {_MAX_SPEC} characters like 'corridor:8', "
                         f"got {type(spec).__name__} of length {len(spec) if isinstance(spec, str) else '?'}")
    head, *pairs = [part.strip() for part in spec.split(",")]
    kind, _, size = head.partition(":")
    options: dict[str, object] = {}
    for pair in pairs:
        key, eq, value = pair.partition("=")
        key = key.strip()
        if not eq:
            raise ModelError(f"world spec {spec!r}: expected key=value, got {pair!r}")
        if key not in _FLOAT_KEYS | _INT_KEYS | _TEXT_KEYS:
            raise ModelError(f"world spec {spec!r}: unknown option {key!r} "
                             f"(known: {', '.join(sorted(_FLOAT_KEYS | _INT_KEYS | _TEXT_KEYS))})")
        if key in options:
            raise ModelError(f"world spec {spec!r}: option {key!r} given twice")
        options[key] = _value(spec, key, value)
    if "blocking" in options:
        options["blocking"] = _blocking(spec, kind, str(options["blocking"]))
    try:
        if kind == "corridor":
            return WorldSpec(spec, corridor(_whole(spec, "the corridor's length", size or "8"), **options), None)
        if kind == "grid":
            rows, x, cols = (size or "2x3").partition("x")
            if not x:
                raise ModelError(f"world spec {spec!r}: a grid's size is RxC, got {size!r}")
            rows, cols = _whole(spec, "rows", rows), _whole(spec, "cols", cols)
            change = options.pop("p_change", 0.0)
            k = arguments.integer("n_labels", options.pop("n_labels", 2), minimum=2, maximum=arguments.MAX_LABELS)
            return WorldSpec(spec, grid_model(rows, cols, k, change=symmetric_channel(k, 1 - change),
                                              **options), None)
        if kind == "door":
            if size:
                raise ModelError("door worlds take no size; pass a layout through the Python API")
            model, true_map = door_world(**options)
            return WorldSpec(spec, model, true_map)
    except (TypeError, ValueError) as error:
        if str(error).startswith("world spec"):
            raise
        raise ModelError(f"world spec {spec!r}: {error}") from None
    raise ModelError(f"world spec {spec!r}: unknown kind {kind!r} (corridor:N, grid:RxC, door)")
