"""``onlinemap sweep``: run an experiment grid (worlds x estimators x options x seeds) serially
or on dask.distributed, resumable; ``--summary`` prints means with confidence intervals."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import pandas as pd

from ..errors import OnlineMapError
from ..evaluate import metric_legend
from ..sweeps import MAX_TASKS, collect, finished_tasks, load_spec, plot_sweep, summarize, summary_table, sweep
from ..tables import check_writable
from .common import open_unit_interval, print_table, split_list


RESULTS = "results"  # DIR/results.csv or DIR/results.parquet
PARTS = "parts"  # DIR/parts/: one file per finished task


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "sweep", help="run a grid of experiments from a TOML spec (local dask cluster or a scheduler)",
        description="Run every task of a sweep spec (see examples/*.toml and onlinemap/sweeps.py): "
                    "one per world, estimator configuration, steps, walk and seed. Finished tasks are "
                    "kept in OUT/parts/ as they finish, so an interrupted sweep resumes where it "
                    "stopped; the table (one row per task, or per task and step with rows = \"step\") "
                    "is written to OUT/results.csv (or .parquet) and summarised.")
    p.add_argument("spec", nargs="?", help="the sweep spec (.toml)")
    p.add_argument("--out", metavar="DIR", help="directory for results.csv (or results.parquet with --format "
                   "parquet) and the finished tasks (DIR/parts/); default: SPEC_NAME/ in the current directory")
    p.add_argument("--format", choices=("csv", "parquet"), default="csv",
                   help="format of DIR/results (default csv; parquet needs pyarrow)")
    p.add_argument("--workers", type=int,
                   help="N: a local dask cluster of N worker processes; 0: the tasks one by one in this process, "
                        "without dask; default: in this process while the work left looks shorter than what a "
                        "local cluster (one process per CPU) would save, then on one")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="use an existing dask scheduler (e.g. tcp://10.0.0.5:8786) instead of a local "
                        "cluster; its workers need onlinemap installed")
    p.add_argument("--check", action="store_true", help="validate the spec, count the tasks, run nothing")
    p.add_argument("--summary", metavar="RESULTS",  # a table file, or a sweep's --out DIR
                   help="print means with confidence intervals per configuration from a results table")
    p.add_argument("--metrics", type=split_list,
                   help="comma-separated metrics for the summary (default: map and location errors, "
                        "failed, distances to the reference, door error, ms per step, those present)")
    p.add_argument("--confidence", type=open_unit_interval, default=0.95,
                   help="confidence level, in (0, 1) (default 0.95)")
    p.add_argument("--max-tasks", type=int, default=MAX_TASKS,
                   help=f"refuse specs with more tasks than this (default {MAX_TASKS:,})")
    p.add_argument("--plot", metavar="PNG", help="with --summary (or after a run): plot the metrics "
                                                 "against --x with confidence intervals")
    p.add_argument("--x", help="for --plot: an option (e.g. n_particles) or column (world, steps) on "
                               "the horizontal axis")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def _read(path: str) -> pd.DataFrame:
    """A results table: a .csv / .parquet file, or a sweep's ``--out`` directory (its results
    table, or, for an unfinished sweep, the parts finished so far)."""
    path = Path(path)
    if not path.exists():  # before choosing a reader: a missing .parquet is not a missing pyarrow
        raise OnlineMapError(f"--summary {path}: not found (give a results .csv / .parquet or a sweep's --out "
                             "directory)")
    if path.is_dir():
        tables = [path / f"{RESULTS}{suffix}" for suffix in (".csv", ".parquet")]
        existing = [table for table in tables if table.exists()]
        if existing:  # the newer of the two, if a sweep wrote both
            path = max(existing, key=lambda table: table.stat().st_mtime_ns)
        elif (path / PARTS).is_dir():
            return collect(path / PARTS)
        else:
            raise OnlineMapError(f"{path} holds no sweep results ({RESULTS}.csv, {RESULTS}.parquet or {PARTS}/)")
    try:
        return pd.read_csv(path) if path.suffix == ".csv" else pd.read_parquet(path)
    except ImportError:
        raise OnlineMapError(f"reading {path} needs pyarrow: pip install pyarrow") from None
    except (OSError, ValueError) as error:
        raise OnlineMapError(f"cannot read results table {path}: {error}") from None


# printed when --metrics is not given (those the table has): per-task and per-step names
DEFAULT_METRICS = ("final_map_error", "final_location_error", "failed", "mean_map_tv", "mean_location_tv",
                   "late_door_error", "map_error", "location_error", "map_tv", "location_tv", "door_error",
                   "ms_per_step")


def _print_summary(table: pd.DataFrame, args: argparse.Namespace) -> None:
    if not args.metrics:
        args.metrics = [m for m in DEFAULT_METRICS if m in table.columns]
    summary = summarize(table, args.metrics, args.confidence)
    step_note = " at each task's last step" if "t" in table.columns else ""
    print(f"mean [{args.confidence:.0%} confidence interval] over seeds, per configuration{step_note}:")
    print_table(summary_table(summary))
    print("\n".join(metric_legend(summary["metric"]) if len(summary) else []))
    if args.plot:
        if not args.x:
            raise OnlineMapError("--plot needs --x (an option such as n_particles, or world, steps)")
        plot_sweep(table, args.x, args.metrics or ["final_map_error"], args.plot, args.confidence)
        print(f"wrote {args.plot}")


def check_writable_figure(path: str) -> None:
    if Path(path).suffix.lower() not in (".png", ".pdf", ".svg"):
        raise OnlineMapError(f"--plot {path}: use a .png, .pdf or .svg file name")


def run(args: argparse.Namespace) -> int:
    if args.summary:
        if args.spec:
            raise OnlineMapError("give either a spec to run or --summary RESULTS, not both")
        _print_summary(_read(args.summary), args)
        return 0
    if not args.spec:
        raise OnlineMapError("give a sweep spec (.toml) to run, or --summary RESULTS")
    if args.workers is not None and args.workers < 0:
        raise OnlineMapError(f"--workers must be >= 0, got {args.workers}")
    if args.scheduler and args.workers is not None:
        raise OnlineMapError("--workers sizes a local cluster; with --scheduler the cluster is already there")
    directory = Path(args.out or Path(args.spec).stem)
    if directory.exists() and not directory.is_dir():
        raise OnlineMapError(f"--out {directory}: a directory is expected (the sweep writes "
                             f"{RESULTS}.{args.format} and {PARTS}/ in it)")
    out = check_writable(directory / f"{RESULTS}.{args.format}")
    if args.plot:
        check_writable_figure(args.plot)
    spec = load_spec(args.spec, args.max_tasks)
    results_dir = directory / PARTS
    done = len(finished_tasks(spec.tasks, results_dir)) if results_dir.exists() else 0
    print(f"sweep {spec.name!r}: {len(spec.tasks)} tasks" +
          (f", {done} already finished in {results_dir}" if done else ""))
    if args.check:
        return 0
    try:
        table = sweep(spec, args.scheduler, workers=args.workers, out=out, results_dir=results_dir,
                      progress=not args.no_progress, max_tasks=args.max_tasks)
    except KeyboardInterrupt:
        done = len(finished_tasks(spec.tasks, results_dir))
        print(f"\ninterrupted: {done} of {len(spec.tasks)} tasks finished and kept in {results_dir}; "
              f"rerun the same command to finish", file=sys.stderr)
        return 130
    print(f"wrote {out} ({len(table)} rows); finished tasks are in {results_dir}")
    _print_summary(table, args)
    return 0
