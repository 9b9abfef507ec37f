"""``onlinemap track``: one estimator behind a pipe, for a robot loop in another process.

Input, one JSON object per line on stdin: ``{"action": ..., "observation": ...}`` (action by
index or name, omitted or null on the first line; observation by index or label name).
Output, one JSON line per step on stdout: ``t``, the most likely ``location`` and its
probability ``p_location``, the normalised ``location_entropy``, the most likely label of every
cell (``map``), the mean normalised ``map_entropy``, ``log_evidence`` (null where undefined) and
``effective_sample_size`` and ``distinct_locations`` (the distinct cells the particles stand in:
the health signal under Fearnhead-Clifford resampling, whose weights are unequal by design) for
particle filters, ``"recovered": true`` on a step where the RBPF
recovered from particle depletion; with ``--full`` also ``location_marginal`` (N,) and
``map_marginal`` (N x K). Floats are printed to full precision. With ``--planner NAME``
(a registered planner of :mod:`policies`; ``--goal CELL``, an index or ``ROW,COL``, for the goal
planners ``goto`` and ``static_goto``) every line also carries ``action``, the name of the action
the planner chooses from that belief: the robot's next move. The planner is built afresh at
start-up (also on resume) with seed 0; it sees only the beliefs (``info_gain`` is bound to the
estimator, as in ``explore``).

A malformed line (bad JSON, a missing, unknown or repeated key, invalid or impossible action or
observation) gets one JSON line on stderr, ``{"line": n, "error": type, "message": ...}``,
changes nothing, and the process keeps reading. Informational events (start, resume,
checkpoint written) are JSON lines on stderr too, and so are the library's log messages
(``{"event": "log", "level": ..., "logger": ..., "message": ...}``, e.g. the RBPF's warning
when it recovers from depletion); the start (or resume) event names the world's ``actions`` and
``labels`` in index order and its sensor ``footprint``: the (drow, dcol) offsets in the order an
observation lists its readings (``[[0, 0]]``: one reading, a label). When ``--stall-after N``
(default 50; 0: never) steps in a row leave the belief as it was, a ``{"event": "stalled", "t":
step}`` line goes to stderr (once per stall: the robot presses in vain; the process keeps reading).

A line longer than :data:`MAX_LINE` characters, with more than :data:`MAX_BRACKETS` brackets,
or not UTF-8 is refused the same way (memory stays bounded; messages quote at most a short
excerpt of the input). If stdout is closed (``| head -1``), the process exits quietly with
status 0, and with ``--checkpoint`` saves every step whose output was written and not the one
whose output met the closed pipe: the state after the last delivered step is rebuilt from the
last checkpoint (or the start) and the inputs since (:class:`_Delivered`, bit for bit).

With ``--checkpoint FILE``, the state is saved atomically every ``--every K`` steps, at the
end of the input and on SIGTERM or SIGINT. Signals stop the loop between steps, never inside
one nor inside a save (a second signal does the same as the first); every step printed is in
the final checkpoint. From the start of the command on (building the world and the estimator,
resuming from the checkpoint), a signal is recorded the same way: the process emits its start
event and stops before reading input. Only while Python imports the package (``import
onlinemap``, before any of this module runs) do the interpreter's defaults apply. The path is
checked writable at start-up, and temporary files of saves that a ``kill -9`` cut short
(``.NAME.<pid>-<8 hex digits>.tmp`` beside it, of processes gone; nothing else) are removed; a
save that fails later (full disk) reports one JSON error line, keeps the previous file and the
loop goes on (the exit status is 1 if the final save failed). A restarted process finds the file and resumes from it
(the next line is step ``t + 1``), after checking that the world, estimator and options are the
ones it was saved with; a file from another onlinemap version of the same checkpoint format
loads, one of a newer format only with ``--allow-newer-checkpoint``. Cost per line: one
``step`` plus O(N K) for the summary (O(N K) more output with ``--full``), plus the planner's
choice with ``--planner``.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import logging
import math
import os
import signal
import sys
import threading
from pathlib import Path

from .. import checkpoint
from ..atomic import remove_temporaries
from ..belief import STALL_AFTER, Belief, StallWatch
from ..errors import CheckpointError, InvalidActionError, ModelError, OnlineMapError
from ..estimators import fork, load, make_estimator
from ..metrics import map_entropy, normalized_entropy
from ..model import model_difference
from ..worlds import parse_world, world_help
from .common import OPTION_HELP, parse_options
from .views import StreamViews, add_stream_arguments, check_stream_arguments

_KEYS = ("action", "observation")
MAX_LINE = 65536  # characters of one input line (a record is a few dozen)
MAX_BRACKETS = 32  # '[' and '{' in one line: a record needs one


class MalformedLineError(OnlineMapError):
    """An input line is not a JSON object with an ``observation`` and an optional ``action``."""


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("track", help="run one estimator on a live stream of JSON lines (stdin -> stdout)",
                       description="Read {\"action\": A, \"observation\": Z} lines on stdin (A by index or "
                                   "name, omitted on the first line), write one JSON belief summary per step "
                                   "on stdout; errors and events go to stderr as JSON lines.")
    p.add_argument("--world", required=True, help=world_help())
    p.add_argument("--estimator", required=True, help="registry name (exact, dead_reckoning, bk, rbpf, ...)")
    p.add_argument("-o", "--option", action="append", default=[], metavar="KEY=VALUE",
                   help=f"estimator option, repeatable; {OPTION_HELP}")
    p.add_argument("--checkpoint", type=Path, metavar="FILE",
                   help="save the state to FILE atomically; resume from it if it exists")
    p.add_argument("--every", type=int, metavar="K",
                   help="save the checkpoint every K steps (default 100; needs --checkpoint)")
    p.add_argument("--full", action="store_true", help="also print the full location and map marginals")
    p.add_argument("--allow-newer-checkpoint", action="store_true",
                   help="try to resume from a checkpoint written in a newer format than this onlinemap reads")
    p.add_argument("--planner", metavar="NAME",
                   help="a registered planner (goto, static_goto, entropy, ...): each output line carries its "
                        "next action")
    p.add_argument("--goal", metavar="CELL", help="the goal of a goal planner: a cell index or ROW,COL")
    p.add_argument("--stall-after", type=int, default=STALL_AFTER, metavar="N",
                   help=f"report a stall (an event on stderr) after N steps in a row leave the belief as it was "
                        f"(default {STALL_AFTER}; 0: never)")
    add_stream_arguments(p)
    p.set_defaults(func=track)


def _object(pairs: list[tuple[str, object]]) -> dict[str, object]:
    """A JSON object whose keys are all different (``json.loads`` would keep the last of two)."""
    record = dict(pairs)
    if len(record) < len(pairs):
        twice = next(key for i, (key, _) in enumerate(pairs) if key in dict(pairs[:i]))
        raise MalformedLineError(f"{_excerpt(repr(twice), 40)} given twice")
    return record


def parse_line(text: str) -> tuple[object, object]:
    """One input line -> ``(action, observation)``, unvalidated (the estimator checks them). A
    key other than ``action`` and ``observation`` (a timestamp, say), or one given twice, refuses
    the line: nothing a robot sends is silently dropped."""
    brackets = text.count("[") + text.count("{")
    if brackets > MAX_BRACKETS:
        raise MalformedLineError(f"{brackets} brackets; a record is one object like "
                                 "{\"action\": 1, \"observation\": 0}")
    try:
        record = json.loads(text, object_pairs_hook=_object)
    except MalformedLineError:  # a key given twice (a ValueError too: not "invalid JSON")
        raise
    except (ValueError, RecursionError) as error:
        raise MalformedLineError(f"invalid JSON: {_excerpt(str(error))}") from None
    if not isinstance(record, dict):
        raise MalformedLineError(f"expected a JSON object like {{\"action\": 1, \"observation\": 0}}, "
                                 f"got {type(record).__name__}")
    unknown = sorted(set(record) - set(_KEYS))
    if unknown:
        names = ", ".join(_excerpt(repr(key), 40) for key in unknown[:3]) + (", ..." if len(unknown) > 3 else "")
        raise MalformedLineError(f"unknown key(s) {names}; a line has only 'action' and 'observation'")
    if "observation" not in record:
        raise MalformedLineError("missing 'observation'")
    return record.get("action"), record["observation"]


def check_action(t: int, action, model) -> None:
    """The action rule of step ``t`` in the words of the line protocol: none on the first line, one
    on every later line. Raises :class:`InvalidActionError`."""
    if t == 0 and action is not None:
        raise InvalidActionError(f"the first step takes no action (got {_excerpt(repr(action), 40)}): the "
                                 "first line is {\"observation\": Z} alone, before the robot moves")
    if t > 0 and action is None:
        raise InvalidActionError(f"step {t} needs an action: {{\"action\": A, \"observation\": Z}}, A one of "
                                 f"{list(model.action_names)} or its index")


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
    if belief.distinct_locations is not None:
        record["distinct_locations"] = int(belief.distinct_locations)
    if belief.recovered:
        record["recovered"] = True
    if full:
        record["location_marginal"] = belief.location.tolist()
        record["map_marginal"] = belief.map.tolist()
    return record


def _emit(stream, record: dict) -> None:
    stream.write(json.dumps(record, default=repr) + "\n")
    stream.flush()


def _excerpt(text: str, limit: int = 200) -> str:
    """At most ``limit`` characters of an error message (a value may be megabytes long)."""
    return text if len(text) <= limit else f"{text[:limit]}... ({len(text)} characters)"


def _resume(path: Path, name: str, world, options: dict[str, object], allow_newer: bool = False):
    """Load the checkpoint at ``path`` and check it is for this world, estimator and options."""
    est = load(path, allow_newer=allow_newer)
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


def read_lines(stream, stop: "_GracefulStop", limit: int = MAX_LINE):
    """Yield ``(line number, text or error)`` for every line of ``stream`` (text, or binary
    decoded as UTF-8), reading at most ``limit + 1`` characters at a time: a longer line is
    skipped to its end without being stored and yields a :class:`MalformedLineError`. Only the
    wait for input can be interrupted by a stop signal (see :class:`_GracefulStop`)."""
    source = getattr(stream, "buffer", stream)
    number = 0
    while not stop.requested:
        with stop.interruptible():
            line = source.readline(limit + 1)
        if not line:
            return
        number += 1
        if len(line) > limit and not line.endswith(b"\n" if isinstance(line, bytes) else "\n"):
            skipped = len(line)
            while line and not line.endswith(b"\n" if isinstance(line, bytes) else "\n"):
                with stop.interruptible():
                    line = source.readline(limit + 1)
                skipped += len(line)
            yield number, MalformedLineError(f"line longer than {limit} characters ({skipped}); skipped")
            continue
        if isinstance(line, bytes):
            try:
                line = line.decode("utf-8")
            except UnicodeDecodeError as error:
                yield number, MalformedLineError(f"not UTF-8 text: {error.reason} at byte {error.start}")
                continue
        yield number, line


def track(args: argparse.Namespace, stdin=None, stdout=None, stderr=None) -> int:
    stdin, stdout, stderr = stdin or sys.stdin, stdout or sys.stdout, stderr or sys.stderr
    check_stream_arguments(args)
    with _GracefulStop() as stop, _log_as_json(stderr):  # from the start: a signal during start-up
        est, planner, every = _start(args, stderr)        # (resume included) stops cleanly
        delivered, status = _Delivered(est, args.checkpoint), 0
        views = StreamViews(args, est.model)
        if views.port is not None:
            _emit(stderr, {"event": "foxglove", "url": f"ws://localhost:{views.port}", "port": views.port})
        try:
            _loop(est, planner, args, every, stop, stdin, stdout, stderr, delivered, views)
        except BrokenPipeError:  # the reader is gone: save what it was given, not the step it missed
            _quiet_stdout(stdout)
            _emit(stderr, {"event": "stdout closed", "t": delivered.t, "undelivered": est.t - delivered.t})
            if args.checkpoint is not None and delivered.t != delivered.saved_t and \
                    not _save(delivered.state(), args.checkpoint, stderr):
                status = 1
            return status
        finally:
            for path in views.close():
                _emit(stderr, {"event": "written", "path": str(path)})
        if args.checkpoint is not None and est.t != delivered.saved_t and not _save(est, args.checkpoint, stderr):
            status = 1
    if stop.requested is not None:
        _emit(stderr, {"event": "stopped", "signal": signal.Signals(stop.requested).name, "t": est.t})
        return 130 if stop.requested == signal.SIGINT else status
    return status


def _start(args: argparse.Namespace, stderr):
    """Check the arguments, build the estimator (or resume it from the checkpoint) and the
    planner, emit the start event; returns ``(estimator, planner or None, every)``."""
    if args.every is not None and (args.checkpoint is None or args.every < 1):
        raise OnlineMapError("--every K needs --checkpoint FILE and K >= 1")
    every = args.every or 100
    if args.stall_after < 0:
        raise OnlineMapError(f"--stall-after N needs N >= 0 (0: never), got {args.stall_after}")
    world = parse_world(args.world)
    given = parse_options(args.option)
    est = make_estimator(args.estimator, world.model, **given)  # validates the names and values
    options = est.options
    event = "start"
    if args.checkpoint is not None:
        checkpoint.check_writable(args.checkpoint)  # fail now, not after the first K steps
        target = Path(os.path.realpath(args.checkpoint))  # a symlink's temporaries are beside its target
        removed = remove_temporaries(target.parent, target.name)  # of saves a kill -9 cut short
        if removed:
            _emit(stderr, {"event": "removed temporaries", "count": removed, "path": str(args.checkpoint)})
        if os.path.lexists(args.checkpoint):
            est, event = _resume(args.checkpoint, args.estimator, world, options, args.allow_newer_checkpoint), \
                "resume"
    model = world.model
    planner = _planner(args, model, est)
    _emit(stderr, {"event": event, "t": est.t, "world": args.world, "estimator": est.name,
                   "options": getattr(est, "effective_options", options),  # as it runs them
                   "actions": list(model.action_names), "labels": list(model.label_names),
                   "footprint": [list(offset) for offset in model.footprint],
                   **({} if planner is None else {"planner": repr(planner)})})
    return est, planner, every


def _goal(text: str) -> int | tuple[int, int]:
    """``--goal``: ``CELL`` or ``ROW,COL`` (whole numbers), unchecked against the world."""
    parts = text.split(",")
    # ASCII digits only: str.isdigit is true for "²", which int() refuses
    if len(parts) > 2 or not all(part.strip().isascii() and part.strip().isdigit() for part in parts):
        raise ModelError(f"--goal must be a cell index or ROW,COL (whole numbers), got {text!r}")
    numbers = tuple(int(part) for part in parts)
    return numbers[0] if len(numbers) == 1 else numbers


def _planner(args: argparse.Namespace, model, est):
    """The ``--planner`` (with ``--goal``), bound to the estimator if it asks to be; None without."""
    if args.planner is None:
        if args.goal is not None:
            raise OnlineMapError("--goal needs --planner (e.g. --planner goto)")
        return None
    from policies import make_planner, planner_options

    if args.goal is None and "goal" in planner_options(args.planner):
        raise OnlineMapError(f"--planner {args.planner} needs --goal CELL (a cell index or ROW,COL)")
    planner = make_planner(args.planner, model, seed=0, **({} if args.goal is None else {"goal": _goal(args.goal)}))
    if hasattr(planner, "bind"):
        planner.bind(est)
    return planner


class _Delivered:
    """The estimator as of the last step whose output was written: a copy taken at the last
    checkpoint (or at the start) and the inputs stepped since. Replaying them on the copy gives,
    bit for bit, the state the estimator had after that step (as a checkpoint resumes). Memory:
    one copy of the state and the inputs of at most ``--every`` steps (while saves succeed);
    nothing without ``--checkpoint``."""

    def __init__(self, est, path: Path | None) -> None:
        self.t = est.t  # the last step delivered
        self.saved_t = est.t  # the step of the last checkpoint written (or loaded)
        self._base = fork(est) if path is not None else None
        self._inputs: list[tuple[object, object]] = []

    def stepped(self, t: int, action, observation) -> None:
        """Step ``t``, ``(action, observation)``, was delivered."""
        self.t = t
        if self._base is not None:
            self._inputs.append((action, observation))

    def saved(self, est) -> None:
        """``est`` (every step delivered) was saved."""
        self.saved_t = est.t
        self._base, self._inputs = fork(est), []

    def state(self):
        """The estimator after the last delivered step (consumes the copy: call once, at the end)."""
        for action, observation in self._inputs:
            self._base.step(action, observation)
        return self._base


def _loop(est, planner, args, every: int, stop: "_GracefulStop", stdin, stdout, stderr,
          delivered: _Delivered, views: StreamViews) -> None:
    """Step through the input until its end or a stop signal. Every step is printed (with the
    ``planner``'s next action, if any) before any checkpoint that includes it (``delivered``
    keeps track), and shown to the ``views`` (recording, live server, animation)."""
    watch = StallWatch(args.stall_after or None)
    try:
        for number, line in read_lines(stdin, stop):
            if isinstance(line, OnlineMapError):
                _emit(stderr, {"line": number, "error": type(line).__name__, "message": str(line)})
                continue
            text = line.strip()
            if not text:
                continue
            try:
                step = parse_line(text)
                check_action(est.t + 1, step[0], est.model)
                belief = est.step(*step)
            except OnlineMapError as error:
                _emit(stderr, {"line": number, "error": type(error).__name__, "message": _excerpt(str(error))})
                continue
            record = summarize(belief, args.full)
            if planner is not None:
                record["action"] = est.model.action_names[planner.choose(belief)]
            _emit(stdout, record)  # a closed stdout raises BrokenPipeError here
            if watch.update(belief):
                _emit(stderr, {"event": "stalled", "t": belief.t, "unchanged_steps": watch.after})
            delivered.stepped(belief.t, *step)
            views.step(belief, planner)
            if args.checkpoint is not None and (belief.t + 1) % every == 0 and _save(est, args.checkpoint, stderr):
                delivered.saved(est)
    except _Stopped:  # a signal while waiting for input
        pass


def _quiet_stdout(stdout) -> None:
    """Point a broken stdout at /dev/null, so that the interpreter's last flush does not fail."""
    try:
        os.dup2(os.open(os.devnull, os.O_WRONLY), stdout.fileno())
    except (OSError, ValueError, AttributeError, io.UnsupportedOperation):
        pass


class _Stopped(Exception):
    """Raised by the signal handler while the loop waits for input."""


class _GracefulStop:
    """SIGTERM and SIGINT end the loop between steps, never inside one, and never inside a
    save: the handler only records the signal, except while the loop waits for input (then it
    raises :class:`_Stopped` to end the wait). A second signal does the same as the first. The
    final checkpoint is then written with the signals still recorded, not acted on. Handlers are
    installed only in the main thread (where Python delivers signals) and restored on exit,
    unless a stop was requested: then both signals are ignored from there on, so that one
    arriving while the interpreter shuts down cannot kill it or print a traceback."""

    def __init__(self) -> None:
        self.requested: int | None = None
        self._waiting = False
        self._previous: dict[int, object] = {}

    def __enter__(self) -> "_GracefulStop":
        if threading.current_thread() is threading.main_thread():
            for number in (signal.SIGTERM, signal.SIGINT):
                self._previous[number] = signal.signal(number, self._handle)
        return self

    def __exit__(self, *exc) -> None:
        for number, handler in self._previous.items():  # once stopping, ignored until the process exits
            signal.signal(number, handler if self.requested is None else signal.SIG_IGN)

    @contextlib.contextmanager
    def interruptible(self):
        """The block (a wait for input) ends with :class:`_Stopped` when a stop signal arrives."""
        if self.requested:
            raise _Stopped
        self._waiting = True
        try:
            yield
        finally:
            self._waiting = False

    def _handle(self, number, frame) -> None:
        self.requested = number
        if self._waiting:
            self._waiting = False
            raise _Stopped


def _save(est, path: Path, stderr) -> bool:
    """Checkpoint ``est``; on failure report one JSON error line (the previous file is kept).
    Returns whether it was saved."""
    try:
        checkpoint.save(est, path)
    except CheckpointError as error:
        _emit(stderr, {"error": "CheckpointError", "t": est.t, "message": _excerpt(str(error), 400)})
        return False
    _emit(stderr, {"event": "checkpoint", "t": est.t, "path": str(path)})
    return True


class _JsonLines(logging.Handler):
    """A log record as one JSON event line on ``stream``."""

    def __init__(self, stream) -> None:
        super().__init__()
        self.stream = stream

    def emit(self, record: logging.LogRecord) -> None:
        _emit(self.stream, {"event": "log", "level": record.levelname, "logger": record.name,
                            "message": _excerpt(record.getMessage(), 400)})


@contextlib.contextmanager
def _log_as_json(stderr):
    """The warnings of the ``onlinemap`` loggers and of the Foxglove SDK's (``--foxglove``: e.g. a
    client dropped) go to ``stderr`` as JSON lines (not through the root logger's text handler)
    while the loop runs."""
    handler = _JsonLines(stderr)
    handler.setLevel(logging.WARNING)
    loggers = [logging.getLogger(name) for name in ("onlinemap", "foxglove")]
    propagate = [logger.propagate for logger in loggers]
    for logger in loggers:
        logger.addHandler(handler)
        logger.propagate = False
    try:
        yield
    finally:
        for logger, before in zip(loggers, propagate):
            logger.removeHandler(handler)
            logger.propagate = before
