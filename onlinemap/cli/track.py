"""``onlinemap track``: one estimator behind a pipe, for a robot loop in another process.

Input, one JSON object per line on stdin: ``{"action": ..., "observation": ...}`` (action by
index or name, omitted or null on the first line; observation by index or label name).
Output, one JSON line per step on stdout: ``t``, the most likely ``location`` and its
probability ``p_location``, the normalised ``location_entropy``, the most likely label of every
cell (``map``), the mean normalised ``map_entropy``, ``log_evidence`` (null where undefined) and
``effective_sample_size`` for particle filters; with ``--full`` also ``location_marginal`` (N,)
and ``map_marginal`` (N x K). Floats are printed to full precision.

A malformed line (bad JSON, missing or unknown key, invalid or impossible action or
observation) gets one JSON line on stderr, ``{"line": n, "error": type, "message": ...}``,
changes nothing, and the process keeps reading. Informational events (start, resume,
checkpoint written) are JSON lines on stderr too.

With ``--checkpoint FILE``, the state is saved atomically every ``--every K`` steps, at the
end of the input and on SIGTERM or SIGINT (which stop the loop between steps, never inside
one); a restarted process finds the file and resumes from it (the next line is step ``t + 1``),
after checking that the world, estimator and options are the ones it was saved with. Cost per
line: one ``step`` plus O(N K) for the summary (O(N K) more output with ``--full``).
"""

from __future__ import annotations

import argparse
import json
import math
import signal
import sys
import threading
from pathlib import Path

from .. import checkpoint
from ..belief import Belief
from ..errors import CheckpointError, OnlineMapError
from ..estimators import load, make_estimator
from ..metrics import map_entropy, normalized_entropy
from ..model import model_difference
from ..worlds import parse_world
from .common import OPTION_HELP, parse_options

_KEYS = ("action", "observation")


class MalformedLineError(OnlineMapError):
    """An input line is not a JSON object with an ``observation`` and an optional ``action``."""


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("track", help="run one estimator on a live stream of JSON lines (stdin -> stdout)",
                       description="Read {\"action\": A, \"observation\": Z} lines on stdin (A by index or "
                                   "name, omitted on the first line), write one JSON belief summary per step "
                                   "on stdout; errors and events go to stderr as JSON lines.")
    p.add_argument("--world", required=True,
                   help="world spec: corridor:N[,p_change=..,n_labels=..], grid:RxC, door[,p_door=..]")
    p.add_argument("--estimator", required=True, help="registry name (exact, dead_reckoning, bk, rbpf, ...)")
    p.add_argument("-o", "--option", action="append", default=[], metavar="KEY=VALUE",
                   help=f"estimator option, repeatable; {OPTION_HELP}")
    p.add_argument("--checkpoint", type=Path, metavar="FILE",
                   help="save the state to FILE atomically; resume from it if it exists")
    p.add_argument("--every", type=int, metavar="K",
                   help="save the checkpoint every K steps (default 100; needs --checkpoint)")
    p.add_argument("--full", action="store_true", help="also print the full location and map marginals")
    p.set_defaults(func=track)


def parse_line(text: str) -> tuple[object, object]:
    """One input line -> ``(action, observation)``, unvalidated (the estimator checks them)."""
    try:
        record = json.loads(text)
    except ValueError as error:
        raise MalformedLineError(f"invalid JSON: {error}") from None
    if not isinstance(record, dict):
        raise MalformedLineError(f"expected a JSON object like {{\"action\": 1, \"observation\": 0}}, "
                                 f"got {type(record).__name__}")
    unknown = sorted(set(record) - set(_KEYS))
    if unknown:
        raise MalformedLineError(f"unknown key(s) {', '.join(map(repr, unknown))}; expected 'action', 'observation'")
    if "observation" not in record:
        raise MalformedLineError("missing 'observation'")
    return record.get("action"), record["observation"]


def _number(x: float) -> float | None:
    x = float(x)
    return x if math.isfinite(x) else None


def _fraction(x: float) -> float | None:
    """A normalised entropy, clipped to [0, 1] (rounding can leave it at -1e-16)."""
    x = _number(x)
    return None if x is None else min(max(x, 0.0), 1.0)


def summarize(belief: Belief, full: bool = False) -> dict[str, object]:
    """The JSON record of one step. Cost O(N K)."""
    where = belief.most_likely_location
    record = {
        "t": belief.t,
        "location": where,
        "p_location": float(belief.location[where]),
        "location_entropy": _fraction(normalized_entropy(belief.location)),
        "map": belief.map_estimate.tolist(),
        "map_entropy": _fraction(map_entropy(belief.map)),
        "log_evidence": _number(belief.log_evidence),
    }
    if belief.effective_sample_size is not None:
        record["effective_sample_size"] = float(belief.effective_sample_size)
    if full:
        record["location_marginal"] = belief.location.tolist()
        record["map_marginal"] = belief.map.tolist()
    return record


def _emit(stream, record: dict) -> None:
    stream.write(json.dumps(record, default=repr) + "\n")
    stream.flush()


def _resume(path: Path, name: str, world, options: dict[str, object]):
    """Load the checkpoint at ``path`` and check it is for this world, estimator and options."""
    est = load(path)
    if est.name != name:
        raise CheckpointError(f"checkpoint {path} holds a {est.name!r} estimator, not {name!r}")
    field = model_difference(est.model, world.model)
    if field is not None:
        raise CheckpointError(f"checkpoint {path} was written for another world ({field!r} differs from "
                              f"--world {world.spec})")
    if est.options != options:
        raise CheckpointError(f"checkpoint {path} was written with options {est.options}, the command line "
                              f"asks for {options}")
    return est


def track(args: argparse.Namespace, stdin=None, stdout=None, stderr=None) -> int:
    stdin, stdout, stderr = stdin or sys.stdin, stdout or sys.stdout, stderr or sys.stderr
    if args.every is not None and (args.checkpoint is None or args.every < 1):
        raise OnlineMapError("--every K needs --checkpoint FILE and K >= 1")
    every = args.every or 100
    world = parse_world(args.world)
    given = parse_options(args.option)
    est = make_estimator(args.estimator, world.model, **given)  # validates the names and values
    options = est.options
    event = "start"
    if args.checkpoint is not None and args.checkpoint.exists():
        est, event = _resume(args.checkpoint, args.estimator, world, options), "resume"
    model = world.model
    _emit(stderr, {"event": event, "t": est.t, "world": args.world, "estimator": est.name,
                   "options": options,
                   "actions": list(model.action_names), "labels": list(model.label_names)})
    unsaved = 0
    with _GracefulStop() as stop:
        try:
            for number, line in enumerate(stdin, 1):
                text = line.strip()
                if not text:
                    continue
                stop.busy = True
                try:
                    belief = est.step(*parse_line(text))
                except OnlineMapError as error:
                    _emit(stderr, {"line": number, "error": type(error).__name__, "message": str(error)})
                else:
                    unsaved += 1
                    _emit(stdout, summarize(belief, args.full))
                    if args.checkpoint is not None and (belief.t + 1) % every == 0:
                        _save(est, args.checkpoint, stderr)
                        unsaved = 0
                finally:
                    stop.busy = False
                if stop.requested:
                    break
        except _Stopped:
            pass
        finally:
            if args.checkpoint is not None and unsaved:
                _save(est, args.checkpoint, stderr)
    if stop.requested is not None:
        _emit(stderr, {"event": "stopped", "signal": signal.Signals(stop.requested).name, "t": est.t})
        return 130 if stop.requested == signal.SIGINT else 0
    return 0


class _Stopped(Exception):
    """Raised by the signal handler while the loop waits for input."""


class _GracefulStop:
    """SIGTERM and SIGINT end the loop between steps, never inside one: a step cut half-way
    through its commit could leave an inconsistent state to be checkpointed. While waiting for
    input the loop stops at once; during a step, right after it. Handlers are restored on exit
    (installed only in the main thread, where Python delivers signals)."""

    def __init__(self) -> None:
        self.busy = False
        self.requested: int | None = None
        self._previous: dict[int, object] = {}

    def __enter__(self) -> "_GracefulStop":
        if threading.current_thread() is threading.main_thread():
            for number in (signal.SIGTERM, signal.SIGINT):
                self._previous[number] = signal.signal(number, self._handle)
        return self

    def __exit__(self, *exc) -> None:
        for number, handler in self._previous.items():
            signal.signal(number, handler)

    def _handle(self, number, frame) -> None:
        self.requested = number
        if not self.busy:
            raise _Stopped


def _save(est, path: Path, stderr) -> None:
    checkpoint.save(est, path)
    _emit(stderr, {"event": "checkpoint", "t": est.t, "path": str(path)})
