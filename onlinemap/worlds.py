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


def _blocking(spec: str, kind: str, value: str):
    """A door world's flag (0/1/true/false) or the '+'-joined blocking labels of another world."""
    if kind == "door":
        flags = {"1": True, "true": True, "0": False, "false": False}
        if value.lower() not in flags:
            raise ModelError(f"world spec {spec!r}: blocking for a door world is 0 or 1, got {value!r}")
        return flags[value.lower()]
    return [int(label) if label.strip().isdigit() else label.strip() for label in value.split("+")]


def parse_world(spec: str) -> WorldSpec:
    """Parse ``kind[:size][,key=value...]``; kinds: corridor (size N), grid (size RxC), door."""
    head, *pairs = [part.strip() for part in spec.split(",")]
    kind, _, size = head.partition(":")
    options: dict[str, object] = {}
    for pair in pairs:
        key, eq, value = pair.partition("=")
        if not eq:
            raise ModelError(f"world spec {spec!r}: expected key=value, got {pair!r}")
        if key in _FLOAT_KEYS:
            options[key] = float(value)
        elif key in _INT_KEYS:
            options[key] = int(value)
        elif key in _TEXT_KEYS:
            options[key] = value
        else:
            raise ModelError(f"world spec {spec!r}: unknown option {key!r} "
                             f"(known: {', '.join(sorted(_FLOAT_KEYS | _INT_KEYS | _TEXT_KEYS))})")
    if "blocking" in options:
        options["blocking"] = _blocking(spec, kind, str(options["blocking"]))
    try:
        if kind == "corridor":
            return WorldSpec(spec, corridor(int(size or 8), **options), None)
        if kind == "grid":
            rows, _, cols = (size or "2x3").partition("x")
            change = options.pop("p_change", 0.0)
            k = int(options.pop("n_labels", 2))
            return WorldSpec(spec, grid_model(int(rows), int(cols), k, change=symmetric_channel(k, 1 - change),
                                              **options), None)
        if kind == "door":
            if size:
                raise ModelError("door worlds take no size; pass a layout through the Python API")
            model, true_map = door_world(**options)
            return WorldSpec(spec, model, true_map)
    except TypeError as error:
        raise ModelError(f"world spec {spec!r}: {error}") from None
    except ValueError as error:
        if isinstance(error, ModelError):
            raise
        raise ModelError(f"world spec {spec!r}: {error}") from None
    raise ModelError(f"world spec {spec!r}: unknown kind {kind!r} (corridor:N, grid:RxC, door)")
