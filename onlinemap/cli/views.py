"""``--animate FILE`` and ``--mcap FILE`` for the commands that play runs (``explore``, ``navigate``;
``track`` records its own stream): the flags, their checks before any work, the run they show
(the first planner's first seed, kept from the sweep or played again) and writing it."""

from __future__ import annotations

import argparse
import math
from importlib.util import find_spec
from pathlib import Path
from typing import TYPE_CHECKING

from ..errors import InvalidOptionError, MissingDependencyError

if TYPE_CHECKING:
    from ..belief import Belief
    from ..estimators import Trajectory
    from ..model import GridModel
    from ..simulate import Run
    from ..sweeps.kinds import Played

#: an animation of a long run shows about this many frames at most (every k-th step, and the last): 12.5 s at 12 a second
MAX_FRAMES = 150
VIZ_HINT = "pip install foxglove-sdk mcap (in a clone: pip install -e '.[viz]')"


def add_view_arguments(parser: argparse.ArgumentParser, what: str) -> None:
    """``--animate FILE`` and ``--mcap FILE``; ``what`` names the run they show, for the help."""
    parser.add_argument("--animate", type=Path, metavar="FILE",
                        help=f"write an animation of {what}: the location and map belief over time with the true "
                             f"path and map; FILE.gif (pillow) or FILE.mp4 (needs imageio and imageio-ffmpeg); about "
                             f"{MAX_FRAMES} frames at most (every k-th step of a longer run, and the last)")
    parser.add_argument("--mcap", type=Path, metavar="FILE",
                        help=f"record {what} to FILE.mcap for Foxglove (the map and location beliefs as grids, the "
                             f"robot's most likely and true cell and the true map, a goal planner's goal; log time = "
                             f"step x 0.1 s); needs {VIZ_HINT}")


def check_view_arguments(args: argparse.Namespace) -> None:
    """Refuse, before any work, an animation that is not .gif / .mp4 (or .mp4 without its
    packages) and an MCAP recording without its packages or not named .mcap."""
    from ..plots import ANIMATION_FORMATS, MP4_HINT

    if args.animate is not None:
        if args.animate.suffix.lower() not in ANIMATION_FORMATS:
            raise InvalidOptionError(f"--animate {args.animate}: the file name must end in .gif or .mp4")
        if args.animate.suffix.lower() == ".mp4" and (find_spec("imageio") is None or
                                                       find_spec("imageio_ffmpeg") is None):
            raise MissingDependencyError(f"--animate {args.animate}: {MP4_HINT}")
    if args.mcap is not None:
        if args.mcap.suffix.lower() != ".mcap":
            raise InvalidOptionError(f"--mcap {args.mcap}: the file name must end in .mcap")
        if find_spec("foxglove") is None:
            raise MissingDependencyError(f"--mcap {args.mcap}: recording MCAP needs the Foxglove SDK: {VIZ_HINT}")


def wanted(args: argparse.Namespace) -> bool:
    return args.animate is not None or args.mcap is not None


def animation_every(steps: int) -> int:
    """Every how many steps a frame is drawn so that a run of ``steps`` has at most :data:`MAX_FRAMES`
    frames, and the last step (:func:`onlinemap.plots.animation_frames`)."""
    return max(1, math.ceil(steps / MAX_FRAMES))


def keeper(planner: str, seed: int) -> tuple[dict, object]:
    """``(kept, on_played)``: the sweep's ``on_played`` keeps the run of ``planner`` and ``seed`` in ``kept``."""
    kept: dict = {}

    def on_played(task, played) -> None:
        if (task.planner, task.seed) == (planner, seed):
            kept.setdefault("played", played)

    return kept, on_played


def first_played(spec: dict, kept: dict, planner: str, seed: int) -> Played:
    """The run of ``planner`` and ``seed`` in ``spec``: kept from the sweep, or (run on dask, or resumed
    from a results folder) played again in this process, the same run (a task is seeded by its seed)."""
    if "played" in kept:
        return kept["played"]
    from ..sweeps.runner import played_rows
    from ..sweeps.spec import spec_from_dict

    task = next(t for t in spec_from_dict(spec).tasks if (t.planner, t.seed) == (planner, seed))
    return played_rows(task)[0]


def write_views(args: argparse.Namespace, model: GridModel, run: Run, trajectory: Trajectory, title: str,
                goal: int | None = None) -> list[Path]:
    """The animation and the recording asked for, of ``run`` and its ``trajectory``; returns the paths."""
    written = []
    if args.animate is not None:
        from ..plots import animate

        written.append(animate(model, trajectory, args.animate, true_locations=run.locations, true_maps=run.maps,
                               every=animation_every(run.n_steps), title=title))
    if args.mcap is not None:
        from ..foxglove import record_run

        written.append(record_run(args.mcap, model, trajectory, run, goal=goal))
    return written


def add_stream_arguments(parser: argparse.ArgumentParser) -> None:
    """``track``'s views of its stream: ``--animate``, ``--mcap`` and ``--foxglove [PORT]``."""
    parser.add_argument("--animate", type=Path, metavar="FILE",
                        help="at the end of the input, write an animation of the location and map belief of every "
                             "step taken (kept in memory until then): FILE.gif (pillow) or FILE.mp4 (needs imageio "
                             f"and imageio-ffmpeg); about {MAX_FRAMES} frames at most")
    parser.add_argument("--mcap", type=Path, metavar="FILE",
                        help="record every step to FILE.mcap for Foxglove as it is taken (the map and location "
                             "beliefs as grids, the most likely cell, the planner's target and path; log time = "
                             f"step x 0.1 s); needs {VIZ_HINT}")
    parser.add_argument("--foxglove", type=int, nargs="?", const=8765, default=None, metavar="PORT",
                        help="serve the same live to Foxglove on PORT (default 8765; 0 picks a free port, named in "
                             "a JSON event on stderr: open ws://localhost:PORT in Foxglove); needs " + VIZ_HINT)


def check_stream_arguments(args: argparse.Namespace) -> None:
    """:func:`check_view_arguments`, and ``--foxglove`` without the SDK or on a port out of range."""
    check_view_arguments(args)
    if args.foxglove is not None:
        if not 0 <= args.foxglove <= 65535:
            raise InvalidOptionError(f"--foxglove {args.foxglove}: a port is 0 (any free one) to 65535")
        if find_spec("foxglove") is None:
            raise MissingDependencyError(f"--foxglove needs the Foxglove SDK: {VIZ_HINT}")


class StreamViews:
    """What ``track`` shows of its stream as it goes: an MCAP recording and a live Foxglove server
    (:class:`onlinemap.foxglove.BeliefLogger`), each step's belief and the planner's target and path;
    and the beliefs kept for an animation, written by :meth:`close`."""

    def __init__(self, args: argparse.Namespace, model: GridModel):
        self.model, self.animate, self.mcap = model, args.animate, args.mcap
        self.location: list = []
        self.maps: list = []
        self.logger = None
        if args.mcap is not None or args.foxglove is not None:
            from ..foxglove import BeliefLogger

            self.logger = BeliefLogger(model, mcap=args.mcap, port=args.foxglove)

    @property
    def port(self) -> int | None:
        return None if self.logger is None else self.logger.port

    def step(self, belief: Belief, planner=None) -> None:
        """Show the belief of one step (after the planner, if any, chose from it)."""
        if self.animate is not None:
            if not self.location:
                self.first_step = belief.t  # after a resume, not 0
            self.location.append(belief.location)
            self.maps.append(belief.map)
        if self.logger is not None:
            target, path = planner_view(self.model, planner, belief)
            self.logger.log(belief, target=target, path=path)

    def close(self) -> list[Path]:
        """Finish the recording, stop the server, write the animation; returns the files written."""
        written = []
        if self.logger is not None:
            self.logger.close()
            if self.mcap is not None:
                written.append(self.mcap)
        if self.animate is not None and self.location:
            import numpy as np

            from ..estimators import Trajectory
            from ..plots import animate

            trajectory = Trajectory(np.array(self.location), np.array(self.maps), np.zeros(len(self.location)), 0.0)
            written.append(animate(self.model, trajectory, self.animate, every=animation_every(len(self.location)),
                                   first_step=self.first_step))
        return written


def planner_view(model: GridModel, planner, belief: Belief) -> tuple[int | None, list[int] | None]:
    """The planner's target cell and planned path where it has them: a goal planner's goal and the
    path down its plan's expected steps from the most likely cell; a frontier planner's target."""
    if planner is None:
        return None, None
    if getattr(planner, "goal", None) is not None:
        from ..foxglove import descent_path

        value = getattr(planner.plan, "value", None)
        return planner.goal, None if value is None else descent_path(model, value, belief.most_likely_location)
    last = getattr(planner, "last_plan", None)
    targets = getattr(last, "targets", None)
    return (None if targets is None or not len(targets) else int(targets[0])), None
