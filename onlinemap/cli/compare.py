"""``onlinemap compare``: how close bk, rbpf, online_em and dead reckoning get to exact Bayes."""

from __future__ import annotations

import argparse
from pathlib import Path

from .. import plots
from ..studies.accuracy import (DEFAULT_PARTICLES, DEFAULT_WORLDS, accuracy_study, compare_estimators,
                                error_over_time_figure, error_vs_particles_figure, error_vs_time_figure, summarise)
from ..errors import OnlineMapError
from ..evaluate import TIMING_NOTE
from ..worlds import parse_world, world_help
from .common import (OPTION_HELP, non_negative_int, options_per_estimator, positive_int, print_table, split_list,
                     write_table)


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "compare", help="accuracy of the approximate estimators against exact Bayes on random runs",
        description="Simulate random walks and run exact Bayes next to bk, rbpf (three schemes: FC, the "
                    "default = optimal proposal with Fearnhead-Clifford resampling; optimal+residual; "
                    "transition+residual; each particle count), online_em (if available) and dead_reckoning. Prints, "
                    "per world and estimator, the mean and worst total-variation distance to exact of the "
                    "location and map marginals (over runs and steps), the map error against the truth and "
                    "the time per step. With --out, writes the per-step and summary tables (CSV) and three "
                    "figures: error vs particles, error vs ms per step, and error over time.")
    p.add_argument("--world", action="append", metavar="SPEC",
                   help=f"repeatable, each small enough for exact (default: {' and '.join(DEFAULT_WORLDS)}); "
                        f"{world_help()}")
    p.add_argument("--runs", type=positive_int, default=20, help="random runs per world (default 20)")
    p.add_argument("--steps", type=positive_int, default=100, help="steps per run, first observation included (default 100)")
    p.add_argument("--particles", default=",".join(map(str, DEFAULT_PARTICLES)),
                   help="comma-separated particle counts for rbpf (default 10,50,100,1000)")
    p.add_argument("--seed", type=non_negative_int, default=0, help="seed of maps, walks, noise and particle filters")
    p.add_argument("--workers", type=non_negative_int, default=0,
                   help="0 (default): run in this process; N: on a local dask cluster of N processes")
    p.add_argument("-o", "--option", action="append", default=[], metavar="[NAME.]KEY=VALUE",
                   help="estimator option, repeatable: KEY=VALUE to every compared estimator that has the "
                        f"option KEY, NAME.KEY=VALUE to estimator NAME only; {OPTION_HELP}")
    p.add_argument("--out", metavar="DIR", help="directory for compare_steps.csv, compare_summary.csv and figures "
                                                "(and compare.parts/, the finished runs: a rerun resumes)")
    p.set_defaults(func=compare)


def compare(args: argparse.Namespace) -> int:
    worlds = args.world or list(DEFAULT_WORLDS)
    try:
        particles = [int(n) for n in split_list(args.particles)]
    except ValueError:
        raise OnlineMapError(f"--particles must be comma-separated integers, got {args.particles!r}") from None
    if args.runs < 1 or args.steps < 1 or not particles or min(particles) < 1:
        raise OnlineMapError("--runs, --steps and every particle count must be at least 1")
    if args.workers < 0:
        raise OnlineMapError(f"--workers must be >= 0, got {args.workers}")
    names = ["exact", *dict.fromkeys(name for _, name, _ in compare_estimators(particles))]
    options = options_per_estimator(names, args.option, parse_world(worlds[0]).model)
    out = Path(args.out) if args.out else None
    print(f"{args.runs} runs x {args.steps} steps on {', '.join(worlds)}; rbpf with {particles} particles; "
          f"seed {args.seed}")
    per_step = accuracy_study(worlds, args.runs, args.steps, particles, args.seed, workers=args.workers,
                              out=None if out is None else out / "compare.parts", options=options)
    summary = summarise(per_step)
    print_table(summary)
    print(TIMING_NOTE)
    if out is not None:
        written = [write_table(per_step, out / "compare_steps.csv"), write_table(summary, out / "compare_summary.csv"),
                   plots.save(error_vs_particles_figure(summary), out / "compare_error_vs_particles.png"),
                   plots.save(error_vs_time_figure(summary), out / "compare_error_vs_time.png"),
                   plots.save(error_over_time_figure(per_step), out / "compare_error_over_time.png")]
        print(f"wrote {', '.join(str(p) for p in written)}")
    return 0
