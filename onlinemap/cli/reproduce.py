"""``onlinemap reproduce corridor``: the 1D-corridor failure of online EM (DESIGN.md section 5)."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pandas as pd

from .. import plots
from ..errors import OnlineMapError
from ..evaluate import ASTRAY_BELOW, HONEST_METRICS, LOST_BELOW, TIMING_NOTE
from ..scenarios import murphy_corridor
from ..studies import corridor as reproductions
from ..studies.corridor import corridor_table, random_corridor_study, steps_table, with_intervals
from .common import (OPTION_HELP, non_negative_int, open_unit_interval, options_per_estimator, positive_int,
                     print_table, split_list, write_table)

MAPPING_STUDIES = ("loop", "anneal", "blocking")  # onlinemap.studies.mapping.STUDIES, imported lazily
#: the defaults of --runs and --steps per scenario (a flag left out takes its scenario's)
DEFAULTS = {"runs": 200, "steps": 150}
SCENARIO_DEFAULTS = {"floors": {"runs": 3, "steps": 1000}}
FLOOR_METRICS = ("final_map_error", "late_location_error", "late_location_distance", "told_map_location_error",
                 "told_map_location_distance", "excess_location_distance", "location_calibration_gap",
                 "map_calibration_gap", "told_location_map_error", "excess_map_error")
OVERVIEW_ONLINE_EM = "online_em W=max decay=1.0"  # the one online EM row of the overview figure


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "reproduce", help="reproduce a claim of the literature (corridor: online EM gets lost)",
        description="corridor: run Murphy's scripted 8-cell corridor (one slip on the way out) through "
                    "every entry of onlinemap.studies.corridor.CORRIDOR_ESTIMATORS: exact Bayes, dead reckoning, "
                    "online EM (windows 1, 2, 4, 8, max x decays 0.8, 0.9, 0.95, 1.0), offline EM, BK and "
                    "the RBPF (100 particles); print final map error, wrong visited cells, the lowest "
                    "P(true location) on the way back, the final P(true location) and the time per step. "
                    "With --out, also write CSV tables and PNG figures (location posterior and map "
                    "marginals over time per estimator). With --random N, instead run N random "
                    "corridors on the sweep engine (6-12 cells, each length equally often, so N is rounded up to "
                    "a multiple of 7; random labels and slip time) and report how often each "
                    "estimator goes astray on the way back (P(true location) < 0.05), ends lost (< 0.5) or "
                    "with a wrong map, with Wilson confidence intervals.")
    p.add_argument("scenario", choices=["corridor", *MAPPING_STUDIES, "floors"],
                   help="which reproduction; loop, anneal and blocking are the EM-mapping studies of "
                        "onlinemap.studies.mapping (a table with intervals over --runs random runs); floors: "
                        "planners exploring real floors read from files and generated buildings "
                        "(onlinemap.studies.floors: --runs seeds per planner and world, --steps steps, the "
                        "honest metrics and the told-location map error per run; --out DIR resumes)")
    p.add_argument("--out", metavar="DIR", help="directory for CSV tables and PNG figures")
    p.add_argument("--random", metavar="N_RUNS", type=positive_int, default=0,
                   help="run the random-corridor study over N_RUNS runs (rounded up to a multiple of 7) "
                        "instead of the scripted run")
    p.add_argument("--seed", type=non_negative_int, default=0, help="first seed of the random study (default 0)")
    p.add_argument("--workers", type=non_negative_int, default=0,
                   help="random study: 0 (default) runs in this process, N on a local dask cluster of N processes")
    p.add_argument("--confidence", type=open_unit_interval, default=0.95,
                   help="confidence of the intervals, in (0, 1) (default 0.95)")
    p.add_argument("--runs", type=positive_int, default=None,
                   help="loop, anneal, blocking: number of random runs (default 200); floors: seeds per planner "
                        "and world (default 3)")
    p.add_argument("--planners", default="",
                   help="blocking: comma-separated planners of policies.explore run besides the random walk "
                        "(e.g. entropy,info_gain; default none), each closed on rbpf P=200; floors: the planners "
                        "(default info_gain,frontier,random)")
    p.add_argument("--steps", type=positive_int, default=None,
                   help="blocking: steps per run, first observation included (default 150); floors: default 1000")
    p.add_argument("--floors", default="maze,room,random,arena,tb3_world,nav2_depot",
                   help="floors: comma-separated shipped floors (onlinemap.studies.floors.REAL_FLOORS) or "
                        "world specs, whose key=value parts follow them (default all six shipped floors; run from a clone of "
                        "the project)")
    p.add_argument("--buildings", default="32x32,64x64",
                   help="floors: sizes of generated buildings, comma-separated RxC (default 32x32,64x64; '' none)")
    p.add_argument("--building-seeds", default="0", help="floors: building seeds, comma-separated (default 0)")
    p.add_argument("--world-keys", default="",
                   help="floors: world keys added to every world, e.g. label_prior=floor (the robot is told the "
                        "floor's label frequencies), label_prior=uniform (the fixed uniform prior; by default the "
                        "robot learns the frequencies) or p_move=0.95")
    p.add_argument("-o", "--option", action="append", default=[], metavar="KEY=VALUE",
                   help=f"floors: RBPF option, repeatable (default n_particles=1000); {OPTION_HELP}")
    p.set_defaults(func=reproduce)


def scripted(out: Path | None) -> None:
    run = murphy_corridor()
    print(f"Murphy's corridor: labels {run.final_map.tolist()}, true path {run.locations.tolist()}, "
          f"slip at step {int(np.flatnonzero(run.slipped)[0]) + 1}; p_obs 0.9, p_move 0.8")
    table, trajectories = corridor_table(run)
    print_table(table)
    print(TIMING_NOTE)
    if out is None:
        return
    written = [write_table(table, out / "corridor_summary.csv"),
               write_table(steps_table(run, trajectories), out / "corridor_steps.csv")]
    overview = {label: trajectories[label] for label, name, _ in reproductions.CORRIDOR_ESTIMATORS
                if name != "online_em" or label == OVERVIEW_ONLINE_EM}
    written.append(plots.save(plots.estimators_figure(run, overview), out / "corridor_overview.png"))
    for label, trajectory in trajectories.items():
        fig = plots.estimators_figure(run, {label: trajectory})
        written.append(plots.save(fig, out / f"corridor_{plots.slug(label)}.png"))
    print(f"wrote {len(written)} files to {out}/ (corridor_overview.png first)")


def study(n_runs: int, seed: int, confidence: float, out: Path | None, workers: int) -> None:
    per_run, summary = random_corridor_study(n_runs, seed, confidence=confidence, workers=workers,
                                             out=None if out is None else out / "corridor_random.parts")
    print(f"{per_run['seed'].nunique() * per_run['n_cells'].nunique()} random corridors (each length 6-12 "
          f"equally often, uniform binary labels, one slip on the way out), seeds from {seed}")
    print(f"fraction of runs [{confidence:.0%} Wilson interval]; lost: P(true location) < {LOST_BELOW}, "
          f"astray: < {ASTRAY_BELOW}; wrong map: a visited cell's most likely label is wrong")
    print_table(with_intervals(summary))
    if out is None:
        return
    written = [write_table(per_run, out / "corridor_random_runs.csv"),
               write_table(summary, out / "corridor_random_summary.csv"),
               plots.save(plots.study_figure(summary, confidence), out / "corridor_random.png")]
    print(f"wrote {', '.join(str(p) for p in written)}")


def mapping_study(name: str, args: argparse.Namespace, out: Path | None) -> None:
    """Run one study of :mod:`onlinemap.studies.mapping`, print its table, write CSVs under ``out``."""
    from ..studies import mapping as mapping_studies

    study_function, measures, description = mapping_studies.STUDIES[name]
    options = {"confidence": args.confidence}
    if name == "blocking":
        options["policies"] = ("random walk", *[p.strip() for p in args.planners.split(",") if p.strip()])
        options["steps"] = args.steps
    result = study_function(args.runs, args.seed, **options)
    steps = f"; {args.steps} steps" if name == "blocking" else ""
    print(f"{name}: {description}{steps}; {args.runs} runs from seed {args.seed}; mean [{args.confidence:.0%} interval]")
    table = mapping_studies.with_intervals(result.summary, measures)
    errors = table.pop("error") if "error" in table else pd.Series("", index=table.index)
    refused = errors.fillna("") != ""
    print_table(table[~refused])  # an estimator that refused the world: a line below, not a column
    for estimator, error in zip(table.loc[refused, "estimator"], errors[refused]):
        print(f"{estimator}: not run ({error})")
    if out is not None:
        written = [write_table(result.runs, out / f"{name}_runs.csv"),
                   write_table(result.summary, out / f"{name}_summary.csv")]
        print(f"wrote {', '.join(str(p) for p in written)}")


def world_list(text: str) -> list[str]:
    """Comma-separated floor names and world specs: a ``key=value`` part belongs to the spec
    before it (``maze,layout:a.map,cell_size=2,room`` is three)."""
    worlds: list[str] = []
    for part in split_list(text):
        key = part.partition("=")[0]
        if worlds and "=" in part and ":" not in key:
            worlds[-1] += f",{part}"
        else:
            worlds.append(part)
    return worlds


def floors(args: argparse.Namespace, out: Path | None) -> None:
    """Run :func:`onlinemap.studies.floors.floor_study` from the command line: print the summary,
    write the runs and the summary under ``out`` (with its parts, to resume)."""
    from ..studies.base import with_intervals as intervals
    from ..studies.floors import PLANNERS, floor_study

    options = {"n_particles": 1000, **options_per_estimator(["rbpf"], args.option)["rbpf"]}
    particles = options.pop("n_particles")
    planners = split_list(args.planners) or list(PLANNERS)
    seeds = range(args.seed, args.seed + args.runs)
    print(f"floors: {', '.join(planners)} on {args.floors}; buildings {args.buildings or 'none'} (seeds "
          f"{args.building_seeds}); world keys: {args.world_keys or 'none'}; rbpf n_particles={particles} "
          f"{''.join(f' {k}={v}' for k, v in options.items())}; {args.steps} steps; seeds {args.seed}..{args.seed + args.runs - 1}")
    runs, summary = floor_study(world_list(args.floors), buildings=split_list(args.buildings),
                                building_seeds=[int(s) for s in split_list(args.building_seeds)], planners=planners,
                                seeds=seeds, steps=args.steps, n_particles=particles, estimator_options=options,
                                world_keys=args.world_keys, confidence=args.confidence, workers=args.workers,
                                out=None if out is None else out / "floors.parts")
    print(f"mean [{args.confidence:.0%} interval] over seeds; stalled, died: runs")
    shown = ["floor", "planner", "options", "runs", *FLOOR_METRICS, "stalled", "died"]
    print_table(intervals(summary[[c for c in summary if c in shown or c.removesuffix("_low").removesuffix("_high")
                                   in FLOOR_METRICS]], FLOOR_METRICS))
    for name, meaning in HONEST_METRICS.items():
        print(f"{name}: {meaning}")
    if out is not None:
        written = [write_table(runs, out / "floors_runs.csv"), write_table(summary, out / "floors_summary.csv")]
        print(f"wrote {', '.join(str(p) for p in written)}")


def reproduce(args: argparse.Namespace) -> int:
    for name, value in {**DEFAULTS, **SCENARIO_DEFAULTS.get(args.scenario, {})}.items():
        if getattr(args, name) is None:
            setattr(args, name, value)
    if args.scenario == "floors":
        floors(args, Path(args.out) if args.out else None)
        return 0
    if args.scenario in MAPPING_STUDIES:
        mapping_study(args.scenario, args, Path(args.out) if args.out else None)
        return 0
    if args.workers < 0:
        raise OnlineMapError(f"--workers must be >= 0, got {args.workers}")
    out = Path(args.out) if args.out else None
    if args.random:
        study(args.random, args.seed, args.confidence, out, args.workers)
    else:
        scripted(out)
    return 0
