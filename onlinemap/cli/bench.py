"""``onlinemap bench``: speed as ratios against a reference measured in the same process."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from ..bench import COLUMNS as STANDARD_COLUMNS
from ..bench import available_benchmarks, benchmark_figures, benchmark_record, run_benchmarks
from ..progress import show_progress
from .common import add_out_argument, check_table_format, print_table, write_tables


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("bench", help="run benchmarks (ratios against same-process references)",
                       description="Run benchmarks and print one table; with no name, all of them "
                                   "(those needing a missing optional peer library are skipped). "
                                   "ratio = ms / reference_ms; a row meets its target when "
                                   f"ratio <= target. Available: {', '.join(available_benchmarks())}.")
    p.add_argument("names", nargs="*", metavar="NAME", type=benchmark_name, help="benchmarks to run (default: all)")
    p.add_argument("--quick", action="store_true", help="small sizes, for a smoke test")
    p.add_argument("--json", metavar="FILE",  # every column, as the benchmarks gave them
                   help="also write the table with machine info, versions, time and git commit as "
                        "JSON; a .jsonl FILE gets one line appended per run (a history)")
    add_out_argument(p, "bench.csv (the table, every column), bench.json (the same with machine info) and "
                        "the figures of benchmarks that draw some (rbpf: rbpf_accuracy.png, TV to exact "
                        "against particles and against ms per step)")
    p.set_defaults(func=bench)


def benchmark_name(text: str) -> str:
    """A registered benchmark's name (argparse type)."""
    if text not in available_benchmarks():
        raise argparse.ArgumentTypeError(f"unknown benchmark {text!r}; available: {', '.join(available_benchmarks())}")
    return text


def readable(table: pd.DataFrame) -> pd.DataFrame:
    """The standard columns, and every benchmark's own extra columns folded into one ``notes``
    column (``name=value`` where set), so that the table stays narrow."""
    extras = [c for c in table.columns if c not in STANDARD_COLUMNS]
    if not extras:
        return table

    def notes(row) -> str:
        return ", ".join(f"{c}={row[c]:.3g}" if isinstance(row[c], float) else f"{c}={row[c]}"
                         for c in extras if row[c] is not None and not (isinstance(row[c], float) and np.isnan(row[c])))

    return table[[c for c in table.columns if c in STANDARD_COLUMNS]].assign(notes=table.apply(notes, axis=1))


def bench(args: argparse.Namespace) -> int:
    check_table_format(args.out, args.format)
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    table = run_benchmarks(args.names, quick=args.quick, progress=show_progress())
    print_table(readable(table))
    judged = table["meets_target"].dropna()
    if len(judged):
        missed = table[table["meets_target"] == False]  # noqa: E712 (object column)
        missed = [f"{row.benchmark} {row.case}" for row in missed.itertuples()]
        print(f"{int(judged.sum())} of {len(judged)} targets met" +
              (f"; missed: {', '.join(missed)}" if len(missed) else ""))
    for name, reason in table.attrs.get("skipped", {}).items():
        print(f"skipped {name}: {reason}", file=sys.stderr)
    record = benchmark_record(table, args.quick) if args.out is not None or args.json else None
    if args.out is not None:
        write_tables({"bench": table}, args.out, args.format)
        (args.out / "bench.json").write_text(json.dumps(record, indent=2))
        print(f"wrote {args.out / 'bench.json'}")
        from ..plots import save

        for stem, fig in benchmark_figures(table).items():
            print(f"wrote {save(fig, args.out / f'{stem}.png')}")
    if args.json:
        path = Path(args.json)
        if path.suffix == ".jsonl":
            with path.open("a") as stream:
                stream.write(json.dumps(record) + "\n")
        else:
            path.write_text(json.dumps(record, indent=2))
        print(f"wrote {path}")
    return 0
