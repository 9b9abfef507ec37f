"""``onlinemap run``: simulate a world and run estimators side by side."""

from __future__ import annotations

import argparse

from ..arrays import DEFAULT_MAX_BYTES
from ..errors import MemoryLimitError
from ..estimators import available_estimators
from ..worlds import world_help
from .common import (OPTION_HELP, add_out_argument, check_table_format, name_list, options_per_estimator,
                     non_negative_int, positive_int, print_table, world, write_tables)


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("run", help="simulate a world and compare estimators on it",
                       description="Simulate a random-walk run and run estimators side by side; prints the "
                                   "final map error and the mean and final location error, then the time per "
                                   "step. The same --seed gives the same run and the same tables (estimators "
                                   "that sample, such as rbpf, are seeded from it too).")
    p.add_argument("--world", default="corridor:8", type=world, help=f"{world_help()} (default corridor:8)")
    p.add_argument("--estimators", default="exact,dead_reckoning", type=name_list,
                   help=f"comma-separated registry names (default exact,dead_reckoning; available: "
                        f"{', '.join(available_estimators())})")
    p.add_argument("--steps", type=positive_int, default=60, help="number of steps, first observation included")
    p.add_argument("--seed", type=non_negative_int, default=0,
                   help="seed of the map, the walk, the noise and the estimators (default 0)")
    p.add_argument("-o", "--option", action="append", default=[], metavar="[NAME.]KEY=VALUE",
                   help="estimator option, repeatable: KEY=VALUE goes to every listed estimator that has "
                        f"option KEY, NAME.KEY=VALUE to estimator NAME only; {OPTION_HELP}")
    add_out_argument(p, "summary.csv (one row per estimator) and steps.csv (one row per estimator and step)")
    p.set_defaults(func=run)


def check_run_size(model, n_steps: int, max_bytes: int = DEFAULT_MAX_BYTES) -> None:
    """Refuse a run whose stacked beliefs, (T, N, K + 2) floats per estimator, exceed ``max_bytes``."""
    need = 8 * n_steps * model.n_cells * (model.n_labels + 2)
    if need > max_bytes:
        raise MemoryLimitError(f"{n_steps} steps of {model.n_cells} cells x {model.n_labels} labels need "
                               f"{need / 2**30:.1f} GiB per estimator (limit {max_bytes / 2**30:.0f} GiB); "
                               "use fewer steps or a smaller world")


def run(args: argparse.Namespace) -> int:
    from ..evaluate import compare_on_run, metric_legend  # here: `onlinemap run --help` loads no pandas

    check_table_format(args.out, args.format)
    options = options_per_estimator(args.estimators, args.option)
    spec = args.world
    check_run_size(spec.model, args.steps)
    sim = spec.simulate(args.steps, args.seed)
    print(f"world {spec.spec}: {spec.model}; {sim.n_steps} steps, {int(sim.slipped.sum())} slips, seed {args.seed}")
    summary, per_step = compare_on_run(sim, args.estimators, options, seed=args.seed)
    if not len(summary):
        raise MemoryLimitError(f"none of {', '.join(args.estimators)} fits in memory on {spec.spec} (see the "
                               "warnings above); use an approximate estimator (bk, rbpf)")
    print_table(summary)
    print("\n".join(metric_legend(summary.columns)))
    print("ms per step: " + ", ".join(f"{name} {ms:.3g}" for name, ms in summary.attrs["ms_per_step"].items()))
    if args.out is not None:
        write_tables({"summary": summary, "steps": per_step}, args.out, args.format)
    return 0
