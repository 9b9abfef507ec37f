"""The ``onlinemap`` command line. Each subcommand is a module here with ``add_parser(subparsers)``
that sets ``func(args) -> int`` on its parser.

Only the module of the command being run is imported (``onlinemap --help`` imports none of
them), so that help and start-up stay fast. Every :class:`~onlinemap.errors.OnlineMapError` and
every usage error ends the process with ONE line on stderr (``onlinemap: error: ...``) and exit
status 2, never a traceback; so do the ``ValueError``, ``TypeError``, ``ArithmeticError`` and
``OSError`` that bad input can still raise from inside the library (``ONLINEMAP_DEBUG=1`` shows
their traceback).
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import sys

from ..errors import OnlineMapError
from .common import PROGRESS_ENV, OneLineErrorParser, fail

DEBUG_ENV = "ONLINEMAP_DEBUG"

# name -> one-line help shown by ``onlinemap --help`` (the module is imported only when chosen)
COMMANDS = {
    "run": "simulate a world and compare estimators on it",
    "bench": "run benchmarks (ratios against same-process references)",
    "track": "run one estimator on a live stream of JSON lines (stdin -> stdout)",
    "reproduce": "reproduce a claim of the literature (corridor: online EM gets lost)",
    "sweep": "run a grid of experiments from a TOML spec (local dask cluster or a scheduler)",
    "compare": "accuracy of the approximate estimators against exact Bayes on random runs",
    "explore": "let planners explore a world (information gain vs entropy vs random walk vs sweep)",
    "navigate": "send the robot to a goal through changing doors (goto vs static_goto vs the oracle)",
    "remap": "remap a recorded run with hindsight (flat EM, layered EM, smoothed RBPF, told location)",
}

EPILOG = ("Conventions: --out DIR writes a command's tables and figures under fixed names (nothing is "
          "written without it); -o/--option KEY=VALUE sets an estimator option (JSON values); --seed makes "
          "every run reproducible; errors are one line on stderr with exit status 2. "
          "`onlinemap COMMAND --help` documents each command.")


def chosen_command(argv: list[str]) -> str | None:
    """The subcommand named in ``argv`` (the first word that is not a global option), if known."""
    for word in argv:
        if not word.startswith("-"):
            return word if word in COMMANDS else None
    return None


def accept_global_options(parser: argparse.ArgumentParser) -> None:
    """Let ``--no-progress`` also follow the command (``onlinemap run --no-progress``)."""
    if "--no-progress" not in parser._option_string_actions:
        parser.add_argument("--no-progress", action="store_true", default=argparse.SUPPRESS,
                            help="no progress bars (same as before the command)")


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The parser; ``command``'s module is imported and adds its full parser, the other commands
    get a stub with their one-line help (``None``: stubs only, enough for ``onlinemap --help``)."""
    from .._version import __version__
    parser = OneLineErrorParser(
        prog="onlinemap", epilog=EPILOG,
        description="Learn grid maps online with a robot that does not know where it is.")
    parser.add_argument("--version", action="version", version=f"onlinemap {__version__}")
    parser.add_argument("--no-progress", action="store_true",
                        help=f"no progress bars (also off when stderr is not a terminal, or with {PROGRESS_ENV}=0)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, summary in COMMANDS.items():
        if name == command:
            importlib.import_module(f"{__name__}.{name}").add_parser(sub)
            accept_global_options(sub.choices[name])
        else:
            sub.add_parser(name, help=summary)
    parser.commands = sub.choices
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the command line on ``argv`` (default ``sys.argv[1:]``); returns the exit status.
    Usage errors raise ``SystemExit(2)`` after one line on stderr, as argparse does."""
    argv = sys.argv[1:] if argv is None else list(argv)
    try:
        parser = build_parser(chosen_command(argv))  # imports the command's module
        args, unknown = parser.parse_known_args(argv)
    except KeyboardInterrupt:
        print("onlinemap: interrupted", file=sys.stderr)
        return 130
    if unknown:  # reported by the command's parser, so that the message points at its --help
        parser.commands[args.command].error(f"unrecognized arguments: {' '.join(unknown)}")
    if args.no_progress:
        os.environ[PROGRESS_ENV] = "0"
    if not logging.getLogger().handlers:  # library warnings (e.g. an estimator skipped) as one line each
        logging.basicConfig(level=logging.WARNING, format="onlinemap: %(levelname)s: %(message)s")
    # dask's scheduler runs in this process and logs every start and stop at INFO through the
    # handler above, and warns when it kills a slow-to-stop worker at the end; a sweep reports its
    # own progress and failures. Read by dask when a sweep first imports it.
    os.environ.setdefault("DASK_LOGGING__DISTRIBUTED", "error")
    try:
        return int(args.func(args) or 0)
    except OnlineMapError as error:
        return fail(error)
    except BrokenPipeError:  # the reader went away (`onlinemap run | head`): stop quietly
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 1
    except (ValueError, TypeError, ArithmeticError, OSError) as error:
        # Bad input that the library has not named yet (a float() of a bad world option, a file
        # that is not UTF-8, ...): still one line; ONLINEMAP_DEBUG=1 shows the traceback.
        if os.environ.get(DEBUG_ENV, "0") not in ("", "0"):
            raise
        return fail(f"{type(error).__name__}: {error} (set {DEBUG_ENV}=1 for the traceback)")
    except MemoryError as error:  # a size too large for this machine, found by numpy
        return fail(f"out of memory ({error or 'allocation failed'}); try a smaller world or fewer steps")
    except KeyboardInterrupt:
        print("onlinemap: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
