"""``onlinemap explore``: active exploration runs, planners compared on the same seeds."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..errors import ModelError
from ..plots import save
from ..worlds import parse_world
from .common import OPTION_HELP, parse_options, print_table, split_list, write_table

DEFAULT_WORLD = "door,p_door=0.01,p_move=0.9"


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "explore", help="let planners explore a world (entropy policy vs random walk vs sweep)",
        description="Closed-loop exploration: each planner chooses actions from the estimator's belief, "
                    "the simulated world moves and is observed, the estimator updates. Prints one summary "
                    "row per planner (averaged over seeds) and writes two figures: map and door-state "
                    "error over time, and the world with the visit counts.")
    p.add_argument("--world", default=DEFAULT_WORLD,
                   help=f"world spec (see `onlinemap run --help`); default {DEFAULT_WORLD}")
    p.add_argument("--floor-plan", default=None, metavar="CONFIDENCE",
                   help="label prior from the world's own map: CONFIDENCE on each cell's label, door state "
                        "unknown (policies.floor_plan_prior), or 'none' for the uniform prior; default 0.8 "
                        "for door worlds, none otherwise")
    p.add_argument("--planner", default="entropy,random,sweep",
                   help="comma-separated: entropy, entropy_collect, random, sweep (default entropy,random,sweep)")
    p.add_argument("--estimator", default="rbpf", help="registry name of the estimator (default rbpf)")
    p.add_argument("--option", action="append", default=[], metavar="KEY=VALUE",
                   help=f"estimator option, repeatable (e.g. --option n_particles=200); {OPTION_HELP}")
    p.add_argument("--steps", type=int, default=500, help="steps per run, first observation included (default 500)")
    p.add_argument("--seed", type=int, default=0, help="first seed (default 0)")
    p.add_argument("--repeats", type=int, default=1, help="runs per planner, seeds seed..seed+repeats-1 (default 1)")
    p.add_argument("--out", help="write the per-step table (planner, seed, t, ...) to .csv or .parquet")
    p.add_argument("--figures", default=".", metavar="DIR",
                   help="directory for explore_errors.png and explore_visits.png (default: current directory)")
    p.add_argument("--no-figures", action="store_true", help="do not write figures")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from policies import PLANNERS, compare_planners, plot_errors, plot_visits, summarize, with_floor_plan

    if args.steps < 1 or args.repeats < 1:
        raise ModelError("--steps and --repeats must be at least 1")
    planners = split_list(args.planner)
    unknown = [name for name in planners if name not in PLANNERS]
    if unknown or not planners:
        raise ModelError(f"--planner: unknown {', '.join(unknown) or '(none given)'}; choose from {', '.join(PLANNERS)}")
    world = parse_world(args.world)
    model, true_map = world.model, world.initial_map(args.seed)
    floor_plan = args.floor_plan
    if floor_plan is None:
        floor_plan = "0.8" if world.true_map is not None and model.rows > 1 else "none"
    if floor_plan != "none":
        try:
            model = with_floor_plan(model, true_map, float(floor_plan))
        except ValueError as error:
            raise ModelError(f"--floor-plan {floor_plan}: {error}") from None
    seeds = list(range(args.seed, args.seed + args.repeats))
    print(f"world {args.world} (floor plan: {floor_plan}): {model}; estimator {args.estimator}, "
          f"{args.steps} steps, seeds {seeds[0]}..{seeds[-1]}")
    table = compare_planners(model, true_map, planners, args.estimator, args.steps, seeds,
                             estimator_options=parse_options(args.option))
    print_table(summarize(table, model, true_map))
    if args.out:
        print(f"wrote {write_table(table, args.out)}")
    if not args.no_figures:
        for name, figure in (("explore_errors.png", plot_errors(table)),
                             ("explore_visits.png", plot_visits(model, true_map, table))):
            print(f"wrote {save(figure, Path(args.figures) / name, dpi=110)}")
    return 0
