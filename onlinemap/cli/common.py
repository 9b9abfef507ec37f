"""Helpers shared by subcommands: one-line errors, argument types, ``-o/--option KEY=VALUE``,
``--out DIR`` tables, seeds for estimators, and the progress rule.

Conventions every command follows:

* ``--out DIR``: the command writes its tables (and figures) in ``DIR`` under fixed names
  (:func:`add_out_argument`, :func:`write_tables`); nothing is written without it. ``--format
  parquet`` is checked up front (:func:`check_table_format`), never after the work.
* ``-o/--option KEY=VALUE`` (repeatable): estimator options, JSON values (:func:`parse_options`).
* ``--seed`` (:func:`non_negative_int`): every random choice follows from it, the estimators'
  included (``onlinemap.rng.derived_seed(seed, ESTIMATOR_STREAM)``, as in a sweep task).
* errors: one line on stderr, ``onlinemap: error: ...``, exit status 2 (:func:`fail`); argument
  types raise ``argparse.ArgumentTypeError`` so that argparse reports them the same way.
* progress bars: ``show_progress(progress)`` (from :mod:`onlinemap.progress`); the global
  ``--no-progress`` sets ``ONLINEMAP_PROGRESS=0``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from importlib.util import find_spec
from pathlib import Path
from typing import TYPE_CHECKING

from ..errors import InvalidOptionError, OnlineMapError, UnknownEstimatorError
from ..progress import PROGRESS_ENV, show_progress

if TYPE_CHECKING:
    import pandas as pd

    from ..worlds import WorldSpec

__all__ = ["OPTION_HELP", "PROGRESS_ENV", "OneLineErrorParser", "add_out_argument", "check_table_format",
           "fail", "name_list", "non_negative_int", "open_unit_interval", "parse_options",
           "positive_int", "print_table", "probability", "show_progress", "split_list", "world", "write_table",
           "write_tables"]

TABLE_FORMATS = ("csv", "parquet")


def fail(error: BaseException | str, command: str | None = None) -> int:
    """Print ``onlinemap: error: ...`` as ONE line on stderr; returns the exit status 2."""
    message = " ".join(str(error).split()) or type(error).__name__
    print(f"onlinemap: error: {command + ': ' if command else ''}{message}", file=sys.stderr)
    return 2


class OneLineErrorParser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose usage errors are one line on stderr (then ``SystemExit(2)``),
    pointing at ``--help`` instead of printing the usage block. Subparsers inherit it."""

    def error(self, message: str):
        fail(f"{message} (see '{self.prog} --help')")
        sys.exit(2)


# ---------------------------------------------------------------- argument types (argparse ``type=``)

def _integer(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None


def non_negative_int(text: str) -> int:
    """An integer >= 0 (seeds, counts that may be zero)."""
    value = _integer(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {text}")
    return value


def positive_int(text: str) -> int:
    """An integer >= 1 (steps, runs, particles)."""
    value = _integer(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {text}")
    return value


def _real(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text}")
    return value


def probability(text: str) -> float:
    """A probability in [0, 1]."""
    value = _real(text)
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"expected a probability in [0, 1], got {text}")
    return value


def open_unit_interval(text: str) -> float:
    """A number in (0, 1), e.g. a confidence level."""
    value = _real(text)
    if not 0.0 < value < 1.0:
        raise argparse.ArgumentTypeError(f"expected a number strictly between 0 and 1, got {text}")
    return value


def split_list(text: str) -> list[str]:
    return [item.strip() for item in text.split(",") if item.strip()]


def name_list(text: str) -> list[str]:
    """A non-empty comma-separated list of names (``exact,rbpf``)."""
    names = split_list(text)
    if not names:
        raise argparse.ArgumentTypeError(f"expected a comma-separated list of names, got {text!r}")
    return names


def world(text: str) -> WorldSpec:
    """A world spec (``corridor:8``, ``grid:2x3``, ``door,p_door=0.01``, ``building:32x32,seed=3``,
    ``layout:PATH``) parsed and checked."""
    from ..worlds import parse_world
    try:
        return parse_world(text)
    except OnlineMapError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


# ---------------------------------------------------------------- estimator options and seeds

OPTION_HELP = ("VALUE is read as JSON when it parses (4, 0.9, null, [1, 0.9, 0.01]) and as a string "
               "otherwise (e.g. window=max)")


MAX_OPTION_DEPTH = 8  # lists in an option value nest at most this deep (options hold flat lists)


def _nesting(value) -> int:
    """How deep lists and objects nest in a JSON value (1: none), without recursion."""
    deepest, stack = 0, [(value, 1)]
    while stack and deepest <= MAX_OPTION_DEPTH:
        node, level = stack.pop()
        deepest = max(deepest, level)
        if isinstance(node, list):
            stack.extend((item, level + 1) for item in node)
        elif isinstance(node, dict):
            stack.extend((item, level + 1) for item in node.values())
    return deepest


def parse_options(pairs: list[str]) -> dict[str, object]:
    """``["window=4", "decay=0.9", "window=max"]`` -> dict; JSON values where they parse (lists
    become tuples), strings otherwise. A value nested deeper than :data:`MAX_OPTION_DEPTH`
    raises OnlineMapError (no option takes one; a hostile one would exhaust the stack)."""
    options: dict[str, object] = {}
    for pair in pairs:
        key, eq, text = pair.partition("=")
        if not eq or not key.strip():
            raise OnlineMapError(f"--option {pair!r}: expected KEY=VALUE")
        try:
            value = json.loads(text)
            too_deep = _nesting(value) > MAX_OPTION_DEPTH
        except ValueError:
            value, too_deep = text, False
        except RecursionError:  # thousands of nested brackets: deeper than any option
            too_deep = True
        if too_deep:
            raise OnlineMapError(f"--option {key.strip()}: its value nests lists more than {MAX_OPTION_DEPTH} deep")
        options[key.strip()] = tuple(value) if isinstance(value, list) else value
    return options


# ---------------------------------------------------------------- tables

def add_out_argument(parser: argparse.ArgumentParser, written: str) -> None:
    """``--out DIR`` and ``--format csv|parquet``; ``written`` names the files, for the help."""
    parser.add_argument("--out", metavar="DIR", type=Path,
                        help=f"write {written} in directory DIR (created if needed); nothing is written without it")
    parser.add_argument("--format", choices=TABLE_FORMATS, default="csv",
                        help="table format under --out (parquet needs pyarrow; default csv)")


def check_table_format(out: Path | None, table_format: str) -> None:
    """Refuse, before any work, an ``--out`` that names a file, or parquet without pyarrow."""
    if out is None:
        return
    if out.suffix in (".csv", ".parquet", ".pq") or out.is_file():
        raise OnlineMapError(f"--out {out}: expected a directory (the tables are written in it under "
                             f"fixed names; choose the format with --format)")
    if table_format == "parquet" and find_spec("pyarrow") is None:
        raise OnlineMapError("--format parquet needs pyarrow: pip install pyarrow (or use --format csv)")


def write_tables(tables: dict[str, pd.DataFrame], out: Path, table_format: str = "csv") -> list[Path]:
    """Write ``{stem: frame}`` as ``out/STEM.csv`` (or ``.parquet``); returns the paths, and says so."""
    paths = [write_table(frame, out / f"{stem}.{table_format}") for stem, frame in tables.items()]
    for path in paths:
        print(f"wrote {path}")
    return paths


def write_table(frame: pd.DataFrame, path: str | Path) -> Path:
    """Write ``frame`` as CSV or parquet, chosen by the suffix (:func:`onlinemap.tables.write_table`)."""
    from ..tables import write_table as write
    return write(frame, path)


def print_table(frame: pd.DataFrame, float_format: str = "{:.4g}") -> None:
    print(frame.to_string(index=False, float_format=float_format.format))
    sys.stdout.flush()


def options_per_estimator(names: list[str], pairs: list[str], model=None) -> dict[str, dict[str, object]]:
    """Route ``-o`` options: ``KEY=V`` to every estimator in ``names`` with option KEY, ``NAME.KEY=V``
    to NAME. Unknown names and keys that no listed estimator takes raise ``UnknownEstimatorError``;
    a value of the wrong type (the sweep spec's check, :func:`onlinemap.sweeps.spec.matches_annotation`)
    raises ``InvalidOptionError`` naming the ``-o`` option, before any spec or estimator is built.
    A whole float for an int option (``move_window=5.0``) is that int, as ``make_estimator`` takes
    it. With ``model``, each estimator given options is built once on it, so that a value its
    own check refuses (``seed=-1``) is reported as an ``--option`` error, not from a sweep's task."""
    # lazily: ``onlinemap --help`` imports no estimator
    from ..estimators import estimator_class, estimator_options, make_estimator
    from ..sweeps.spec import describe_type, expected_type, matches_annotation

    known = {name: estimator_options(name) for name in names}  # raises for an unknown name
    routed: dict[str, dict[str, object]] = {name: {} for name in names}
    for key, value in parse_options(pairs).items():
        target, dot, option = key.rpartition(".")
        if dot and target not in known:
            raise UnknownEstimatorError(f"--option {key}: {target!r} is not one of the estimators run "
                                        f"({', '.join(names)})")
        takers = [target] if dot else [name for name in names if option in known[name]]
        if not takers or option not in known[takers[0]]:
            raise UnknownEstimatorError(f"--option {key}: no estimator in {', '.join(takers or names)} "
                                        f"has an option {option!r}")
        for name in takers:
            expected = expected_type(estimator_class(name), option, known[name][option])
            if isinstance(value, float) and value.is_integer() and not matches_annotation(value, expected) \
                    and matches_annotation(int(value), expected):
                value = int(value)
            if not matches_annotation(value, expected):
                raise InvalidOptionError(f"--option {key}={json.dumps(value)}: {name}'s {option} must be "
                                         f"{describe_type(expected)}")
            routed[name][option] = value
    for name, options in routed.items():
        if model is not None and options:
            try:
                make_estimator(name, model, **options)
            except InvalidOptionError as error:
                raise InvalidOptionError(f"--option: {name}'s {error}") from None
    return routed
