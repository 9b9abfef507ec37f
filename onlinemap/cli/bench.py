"""``onlinemap bench``: speed as ratios against a reference measured in the same process."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from ..bench import available_benchmarks, run_benchmarks
from .common import print_table


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("bench", help="run benchmarks (ratios against same-process references)",
                       description="Run benchmarks and print one table; with no name, all of them. "
                                   f"Available: {', '.join(available_benchmarks())}.")
    p.add_argument("names", nargs="*", metavar="NAME", help="benchmarks to run (default: all)")
    p.add_argument("--quick", action="store_true", help="small sizes, for a smoke test")
    p.add_argument("--json", metavar="FILE", help="also write the table as JSON records")
    p.set_defaults(func=bench)


def bench(args: argparse.Namespace) -> int:
    table = run_benchmarks(args.names, quick=args.quick)
    print_table(table)
    if args.json:
        Path(args.json).write_text(json.dumps(table.to_dict(orient="records"), indent=2, default=str))
        print(f"wrote {args.json}")
    return 0
