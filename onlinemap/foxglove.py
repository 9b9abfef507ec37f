"""Beliefs for Foxglove: recorded to an MCAP file, or served live over the Foxglove WebSocket
protocol, through the Foxglove SDK (the ``viz`` extra: ``pip install foxglove-sdk mcap``; imported
only when a logger is built, never by ``import onlinemap``).

Every message is stamped by its step: log time and header time ``t x period`` (default 0.1 s).
Every pose and grid is in the frame ``map``: one grid cell is 1 x 1 (metre), x along the columns,
y up; model row 0 is the top row (as in the figures), so the cell (row, col) has its centre at
``(col + 0.5, rows - row - 0.5)``. Topics:

- ``/belief/map`` (``foxglove.Grid``): per cell, ``p_LABEL`` (float32) for every label, ``label``
  (uint8, the most likely label's index), ``confidence`` (float32, :func:`onlinemap.plots.confidence`)
  and ``red``, ``green``, ``blue``, ``alpha`` (uint8): the colour of :func:`onlinemap.plots.belief_colours`,
  which Foxglove's 3D panel draws with the color mode "RGBA (separate fields)".
- ``/belief/location`` (``foxglove.Grid``): ``probability`` and ``log10_probability`` (float32;
  the logarithm floored at -12) per cell.
- ``/robot/most_likely`` and, where known (a simulation), ``/robot/true`` (``foxglove.PoseInFrame``):
  the centre of the robot's most likely cell and of its true cell.
- ``/world/map`` (``foxglove.Grid``, where known): the true labels, ``label`` and the palette's RGBA.
- ``/planner/target`` (``foxglove.PoseInFrame``) and ``/planner/path`` (``foxglove.PosesInFrame``),
  when a planner has them.
- ``/robot`` (JSON): ``t``, ``most_likely_cell``, ``p_most_likely``, ``true_cell`` and
  ``target_cell`` (null where unknown): the numbers, for Foxglove's plot and raw-message panels.

Cost per step: O(N K) to pack the grids, plus the SDK's encoding and writing.
"""

from __future__ import annotations

import json
import math
import os
from importlib.util import find_spec
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from . import arguments
from .belief import Belief
from .errors import InvalidOptionError, MissingDependencyError, ModelError
from .model import GridModel
from .plots import belief_colours, confidence, label_colours

if TYPE_CHECKING:
    from .estimators import Trajectory
    from .simulate import Run

PERIOD = 0.1  # seconds of log time per step
FRAME = "map"
VIZ_HINT = "pip install foxglove-sdk mcap (in a clone: pip install -e '.[viz]')"
ROBOT_SCHEMA_NAME = "onlinemap.Robot"
ROBOT_SCHEMA = {"type": "object", "properties": {
    "t": {"type": "integer"}, "most_likely_cell": {"type": "integer"}, "p_most_likely": {"type": "number"},
    "true_cell": {"type": ["integer", "null"]}, "target_cell": {"type": ["integer", "null"]}}}


def _sdk():
    if find_spec("foxglove") is None:
        raise MissingDependencyError(f"Foxglove recording and live view need the Foxglove SDK: {VIZ_HINT}")
    import foxglove

    return foxglove


def cell_centre(model: GridModel, cell: int) -> tuple[float, float]:
    """The (x, y) of a cell's centre in the frame ``map`` (row 0 at the top)."""
    row, col = divmod(int(cell), model.cols)
    return col + 0.5, model.rows - row - 0.5


def _rgba(colours: np.ndarray) -> np.ndarray:
    """(N, 3) floats in [0, 1] -> (N, 4) uint8, opaque."""
    out = np.full((len(colours), 4), 255, dtype=np.uint8)
    out[:, :3] = np.round(255 * colours)
    return out


class BeliefLogger:
    """Logs a model's beliefs, step by step, to an MCAP file (``mcap``: a path, overwritten) and/or a
    live Foxglove WebSocket server (``port``: a port number, 0 for any free one; ``host``), on channels
    of its own SDK context (so two loggers never mix). Use as a context manager, or call :meth:`close`
    (the file is complete only then). ``period``: seconds of log time per step."""

    def __init__(self, model: GridModel, *, mcap: str | os.PathLike | None = None, port: int | None = None,
                 host: str = "127.0.0.1", period: float = PERIOD, name: str = "onlinemap"):
        if mcap is None and port is None:
            raise InvalidOptionError("a BeliefLogger needs an MCAP path, a server port, or both")
        self.period = arguments.real("period", period, low=0.0, low_open=True, error=InvalidOptionError)
        if port is not None:
            port = arguments.integer("port", port, minimum=0, maximum=65535, error=InvalidOptionError)
        foxglove = _sdk()
        from foxglove import messages
        from foxglove.channels import GridChannel, PoseInFrameChannel, PosesInFrameChannel

        self.model = model
        self._messages = messages
        numeric = messages.PackedElementFieldNumericType
        self._numeric = {"|u1": numeric.Uint8, "<f4": numeric.Float32}
        self.context = context = foxglove.Context()  # held: channels close when their context goes
        self.map_channel = GridChannel("/belief/map", context=context)
        self.location_channel = GridChannel("/belief/location", context=context)
        self.world_channel = GridChannel("/world/map", context=context)
        self.likely_channel = PoseInFrameChannel("/robot/most_likely", context=context)
        self.true_channel = PoseInFrameChannel("/robot/true", context=context)
        self.target_channel = PoseInFrameChannel("/planner/target", context=context)
        self.path_channel = PosesInFrameChannel("/planner/path", context=context)
        self.robot_channel = foxglove.Channel("/robot", message_encoding="json", context=context, schema=foxglove.Schema(
            name=ROBOT_SCHEMA_NAME, encoding="jsonschema", data=json.dumps(ROBOT_SCHEMA).encode()))
        names = [f"p_{name}" for name in model.label_names]
        if len(set(names)) < len(names):
            raise ModelError(f"label names {model.label_names} are not distinct")
        self._map_dtype = np.dtype([*((name, "<f4") for name in names), ("confidence", "<f4"), ("label", "u1"),
                                    ("red", "u1"), ("green", "u1"), ("blue", "u1"), ("alpha", "u1")])
        self._location_dtype = np.dtype([("probability", "<f4"), ("log10_probability", "<f4")])
        self._world_dtype = np.dtype([("label", "u1"), ("red", "u1"), ("green", "u1"), ("blue", "u1"),
                                      ("alpha", "u1")])
        self._palette = _rgba(label_colours(model))
        self.writer = self.server = None
        try:
            if mcap is not None:
                Path(mcap).parent.mkdir(parents=True, exist_ok=True)
                self.writer = foxglove.open_mcap(mcap, allow_overwrite=True, context=context)
            if port is not None:
                try:
                    self.server = foxglove.start_server(name=name, host=host, port=port, context=context)
                except RuntimeError as error:  # the SDK's error for a port in use or a host it cannot bind
                    raise InvalidOptionError(f"cannot serve Foxglove on {host}:{port}: {error}") from None
        except BaseException:
            self.close()
            raise

    @property
    def port(self) -> int | None:
        """The live server's port (the one chosen when asked for 0); None without a server."""
        return None if self.server is None else self.server.port

    def _stamp(self, t: int) -> tuple[int, object]:
        nanoseconds = round(t * self.period * 1e9)
        return nanoseconds, self._messages.Timestamp(sec=nanoseconds // 10**9, nsec=nanoseconds % 10**9)

    def _pose(self, cell: int):
        m = self._messages
        x, y = cell_centre(self.model, cell)
        return m.Pose(position=m.Vector3(x=x, y=y, z=0.0), orientation=m.Quaternion(x=0.0, y=0.0, z=0.0, w=1.0))

    def _grid(self, stamp, values: np.ndarray):
        """A ``foxglove.Grid`` of a structured (N,) array, rows written bottom first (y up)."""
        m = self._messages
        model = self.model
        fields = [m.PackedElementField(name=name, offset=offset, type=self._numeric[dtype.str])
                  for name, (dtype, offset) in values.dtype.fields.items()]
        data = values.reshape(model.shape)[::-1].tobytes()
        return m.Grid(timestamp=stamp, frame_id=FRAME, pose=self._pose_at_origin(), column_count=model.cols,
                      cell_size=m.Vector2(x=1.0, y=1.0), row_stride=model.cols * values.dtype.itemsize,
                      cell_stride=values.dtype.itemsize, fields=fields, data=data)

    def _pose_at_origin(self):
        m = self._messages
        return m.Pose(position=m.Vector3(x=0.0, y=0.0, z=0.0), orientation=m.Quaternion(x=0.0, y=0.0, z=0.0, w=1.0))

    def log(self, belief: Belief, *, true_location: int | None = None, true_map: np.ndarray | None = None,
            target: int | None = None, path=None) -> None:
        """Log the belief after step ``belief.t`` and, where given, the true cell and map and the
        planner's ``target`` cell and ``path`` (cells, in order)."""
        model = self.model
        if belief.map.shape != (model.n_cells, model.n_labels):
            raise ModelError(f"a belief over {belief.n_cells} cells x {belief.n_labels} labels does not fit {model}")
        m = self._messages
        log_time, stamp = self._stamp(belief.t)
        cells = np.zeros(model.n_cells, dtype=self._map_dtype)
        for k, name in enumerate(model.label_names):
            cells[f"p_{name}"] = belief.map[:, k]
        cells["label"] = belief.map_estimate
        cells["confidence"] = confidence(belief.map)
        colours = _rgba(belief_colours(model, belief.map))
        for i, channel in enumerate(("red", "green", "blue", "alpha")):
            cells[channel] = colours[:, i]
        self.map_channel.log(self._grid(stamp, cells), log_time=log_time)
        where = np.zeros(model.n_cells, dtype=self._location_dtype)
        where["probability"] = belief.location
        where["log10_probability"] = np.log10(np.maximum(belief.location, 1e-12))
        self.location_channel.log(self._grid(stamp, where), log_time=log_time)
        likely = belief.most_likely_location
        self.likely_channel.log(m.PoseInFrame(timestamp=stamp, frame_id=FRAME, pose=self._pose(likely)),
                                log_time=log_time)
        if true_location is not None:
            self.true_channel.log(m.PoseInFrame(timestamp=stamp, frame_id=FRAME, pose=self._pose(true_location)),
                                  log_time=log_time)
        if true_map is not None:
            world = np.zeros(model.n_cells, dtype=self._world_dtype)
            world["label"] = true_map
            for i, channel in enumerate(("red", "green", "blue", "alpha")):
                world[channel] = self._palette[np.asarray(true_map), i]
            self.world_channel.log(self._grid(stamp, world), log_time=log_time)
        if target is not None:
            self.target_channel.log(m.PoseInFrame(timestamp=stamp, frame_id=FRAME, pose=self._pose(target)),
                                    log_time=log_time)
        if path is not None and len(path):
            self.path_channel.log(m.PosesInFrame(timestamp=stamp, frame_id=FRAME,
                                                 poses=[self._pose(cell) for cell in path]), log_time=log_time)
        self.robot_channel.log({"t": belief.t, "most_likely_cell": likely,
                                "p_most_likely": float(belief.location[likely]),
                                "true_cell": None if true_location is None else int(true_location),
                                "target_cell": None if target is None else int(target)}, log_time=log_time)

    def close(self) -> None:
        """Finish the MCAP file and stop the server (idempotent)."""
        writer, server, self.writer, self.server = self.writer, self.server, None, None
        try:
            if writer is not None:
                writer.close()
        finally:
            if server is not None:
                server.stop()

    def __enter__(self) -> BeliefLogger:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def record_run(path: str | os.PathLike, model: GridModel, trajectory: Trajectory, run: Run | None = None, *,
               goal: int | None = None, period: float = PERIOD) -> Path:
    """Write a run's beliefs to the MCAP file ``path`` (:class:`BeliefLogger`): every step of
    ``trajectory``, with the true cell and map of ``run`` where given and ``goal`` as the planner's
    target. Returns the path. Cost: T x :meth:`BeliefLogger.log`."""
    if run is not None and run.n_steps != trajectory.n_steps:
        raise ModelError(f"a run of {run.n_steps} steps and a trajectory of {trajectory.n_steps} do not match")
    with BeliefLogger(model, mcap=path, period=period) as logger:
        for t in range(trajectory.n_steps):
            logger.log(trajectory.belief(t), true_location=None if run is None else int(run.locations[t]),
                       true_map=None if run is None else run.maps[t], target=goal)
    return Path(path)


def descent_path(model: GridModel, value: np.ndarray, start: int, limit: int | None = None) -> list[int]:
    """The cells from ``start`` down a plan's expected steps to the goal, ``value`` (N,) (0 at the
    goal, inf where unreachable): each step to the neighbour of lowest value while it falls; at most
    ``limit`` cells (default N). The path a goal planner means to take, for display. O(length x A)."""
    limit = model.n_cells if limit is None else limit
    path = [int(start)]
    while len(path) < limit and value[path[-1]] > 0:
        neighbours = model.neighbors[path[-1]]
        best = int(neighbours[np.argmin(value[neighbours])])
        if not value[best] < value[path[-1]] or not math.isfinite(value[best]):
            break
        path.append(best)
    return path
