"""The ``onlinemap`` command line. Each subcommand is a module here with ``add_parser(subparsers)``
that sets ``func(args) -> int`` on its parser."""

from __future__ import annotations

import argparse
import importlib
import sys

from ..errors import OnlineMapError

COMMANDS = ("run", "bench", "track", "reproduce", "sweep", "compare", "explore")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="onlinemap",
        description="Learn grid maps online with a robot that does not know where it is.")
    from .. import __version__
    parser.add_argument("--version", action="version", version=f"onlinemap {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMANDS:
        importlib.import_module(f"{__name__}.{name}").add_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except OnlineMapError as error:
        print(f"onlinemap {args.command}: error: {error}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
