"""``onlinemap navigate``: goal planners taking the robot through a changing building, against the
omniscient oracle of the same world history (:mod:`onlinemap.studies.navigation`)."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..errors import ModelError
from .common import (non_negative_int, open_unit_interval, options_per_estimator, positive_int, print_table,
                     split_list, write_table)
from .views import add_view_arguments, check_view_arguments, first_played, keeper, wanted, write_views

DEFAULT_WORLD = "door,blocking=1,footprint=cross,p_door=0.05"
DEFAULT_PLANNERS = "goto,static_goto"
SUMMARY_METRICS = ("success", "reached", "steps_to_goal", "oracle_steps", "steps_over_oracle", "mean_location_error",
                   "ms_per_step")


def goal_argument(text: str) -> int | tuple[int, int]:
    """``--goal CELL`` or ``--goal ROW,COL``."""
    parts = text.split(",")
    try:
        numbers = [int(part) for part in parts]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a cell index or ROW,COL, got {text!r}") from None
    if len(numbers) == 1:
        return numbers[0]
    if len(numbers) == 2:
        return numbers[0], numbers[1]
    raise argparse.ArgumentTypeError(f"expected a cell index or ROW,COL, got {text!r}")


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "navigate", help="send the robot to a goal through changing doors (goto vs static_goto vs the oracle)",
        description="Closed-loop navigation: each goal planner chooses actions from the estimator's belief until "
                    "the true robot stands on the goal (or --steps actions). Every planner meets the same doors "
                    "and slips step by step (paired seeds), and so does the oracle, a robot that knows its cell "
                    "and the true map of now. Prints, per planner over the runs where the oracle gets there: the "
                    "share of runs reaching the goal within 4x the oracle's steps (success), the mean steps, the "
                    "oracle's, their ratio, each with a confidence interval over seeds. With --out DIR, writes "
                    "navigate_runs.csv, navigate_summary.csv, navigate_route.png (the first run of the first "
                    "planner drawn on the map) and navigate_vs_oracle.png there.")
    p.add_argument("--world", default=DEFAULT_WORLD,
                   help=f"world spec (see `onlinemap run --help`); default {DEFAULT_WORLD}")
    p.add_argument("--goal", type=goal_argument, default=None, metavar="CELL|ROW,COL",
                   help="the goal cell; default: the free cell farthest from the start with every door open")
    p.add_argument("--floor-plan", type=open_unit_interval, default=0.95, metavar="CONFIDENCE",
                   help="the robot's label prior from the world's own map, CONFIDENCE on each cell's label, door "
                        "states unknown (default 0.95)")
    p.add_argument("--planner", default=DEFAULT_PLANNERS, help=f"comma-separated planners (default {DEFAULT_PLANNERS})")
    p.add_argument("-o", "--option", action="append", default=[], metavar="KEY=VALUE",
                   help="rbpf option, repeatable (default n_particles=500)")
    p.add_argument("--steps", type=positive_int, default=400, help="at most this many actions per run (default 400)")
    p.add_argument("--seed", type=non_negative_int, default=0, help="first seed (default 0)")
    p.add_argument("--repeats", type=positive_int, default=10, help="runs per planner, seeds seed..seed+repeats-1 "
                                                                    "(default 10)")
    p.add_argument("--confidence", type=open_unit_interval, default=0.95, help="confidence of the intervals")
    p.add_argument("--workers", type=non_negative_int, default=0,
                   help="0 (default): run in this process; N: on a local dask cluster of N processes")
    p.add_argument("--out", metavar="DIR", help="directory for the tables and figures (nothing is written without it)")
    add_view_arguments(p, "the first planner's run with the first seed")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..studies.base import summary_of
    from ..studies.navigation import navigation_spec
    from ..sweeps import sweep
    from ..worlds import parse_world

    check_view_arguments(args)
    planners = _goal_planners(split_list(args.planner))
    world = parse_world(args.world)
    goal = _goal(world, args)
    options = options_per_estimator(["rbpf"], args.option, world.model)["rbpf"]
    options.setdefault("n_particles", 500)
    row, col = divmod(goal, world.model.cols)
    print(f"world {args.world} (floor plan {args.floor_plan}); goal cell {goal} (row {row}, col {col}); rbpf with "
          f"{', '.join(f'{k}={v}' for k, v in options.items())}; at most {args.steps} steps, seeds "
          f"{args.seed}..{args.seed + args.repeats - 1}")
    out = Path(args.out) if args.out else None
    spec = navigation_spec(args.world, planners, [goal], range(args.seed, args.seed + args.repeats),
                           max_steps=args.steps, estimator_options=options, floor_plan=args.floor_plan)
    kept, on_played = keeper(planners[0], args.seed)
    runs = sweep(spec, workers=args.workers, progress=True, results_dir=None if out is None else out / "navigate.parts",
                 on_played=on_played if wanted(args) and args.workers == 0 else None)
    judged = runs[runs["oracle_reached"].astype(bool)]
    summary = summary_of(judged, SUMMARY_METRICS, ["planner"], args.confidence)
    _print_summary(args, judged, summary, len(planners), goal)
    if out is not None:
        _write_tables_and_figures(args, world, goal, planners[0], options, runs, summary)
    if wanted(args):
        played = first_played(spec, kept, planners[0], args.seed)
        written = write_views(args, world.model, played.run, played.trajectory,
                              f"{planners[0]} to cell {goal}, seed {args.seed}", goal=goal)
        print(f"wrote {', '.join(str(p) for p in written)}")
    return 0


def _goal_planners(planners: list[str]) -> list[str]:
    """``planners``, checked: known, at least one, each taking a goal (ModelError naming the others)."""
    from policies import PLANNERS, planner_options

    unknown = [name for name in planners if name not in PLANNERS]
    if unknown or not planners:
        raise ModelError(f"--planner: unknown {', '.join(unknown) or '(none given)'}; choose from {', '.join(PLANNERS)}")
    goal_planners = [name for name in PLANNERS if "goal" in planner_options(name)]
    aimless = [name for name in planners if name not in goal_planners]
    if aimless:
        raise ModelError(f"--planner {', '.join(aimless)}: {'does' if len(aimless) == 1 else 'do'} not take a goal; "
                         f"navigate compares goal planners: {', '.join(goal_planners)}")
    return planners


def _goal(world, args: argparse.Namespace) -> int:
    """The goal cell: ``--goal`` checked against the floor plan, else the free cell farthest from
    the start with every door open (ModelError if there is none)."""
    from policies import check_goal, with_floor_plan

    from ..studies.navigation import far_goals, fixed_map

    # a world that draws its map per seed has no fixed map; without blocking labels every cell is
    # reachable on every seed's map, so the first seed's map serves to choose and check the goal
    true_map = world.initial_map(0) if world.true_map is None and not world.model.has_blocking else fixed_map(world)
    if args.goal is None:
        goals = far_goals(world.model, true_map)
        if not goals:
            raise ModelError(f"--world {args.world}: no free cell to send the robot to; give one with --goal CELL")
        return goals[0]
    # checked as the runs will see it, before any run: a wall of the floor plan refuses it
    return check_goal(with_floor_plan(world.model, true_map, args.floor_plan), args.goal)


def _print_summary(args: argparse.Namespace, judged, summary, n_planners: int, goal: int) -> None:
    """The summary table over the runs where the oracle reaches the goal, or why there is none."""
    from ..evaluate import metric_legend
    from ..studies.base import with_intervals

    if judged.empty:
        print(f"the oracle reaches goal cell {goal} within {args.steps} steps in none of the {args.repeats} run(s): "
              f"nothing to compare the planners against; give more --steps or a nearer --goal")
        return
    print(f"mean [{args.confidence:.0%} interval] over the {len(judged) // max(n_planners, 1)} run(s) per "
          f"planner where the oracle reaches the goal; success: within 4x the oracle's steps")
    print_table(with_intervals(summary, SUMMARY_METRICS))
    print("\n".join(metric_legend(SUMMARY_METRICS)))


def _write_tables_and_figures(args: argparse.Namespace, world, goal: int, planner: str, options: dict, runs,
                              summary) -> None:
    """``--out``: the runs and summary tables, the route of ``planner``'s first run (replayed) and
    the planners against the oracle."""
    from policies import navigate, with_floor_plan

    from .. import plots
    from ..studies.navigation import oracle_figure, route_figure
    from ..sweeps import played_map

    out = Path(args.out)
    true_map = played_map(args.world, args.seed)  # the first run's: the route figure replays it
    model = with_floor_plan(world.model, true_map, args.floor_plan)
    first = navigate(model, true_map, goal, planner, "rbpf", max_steps=args.steps, seed=args.seed,
                     estimator_options=options)
    written = [write_table(runs, out / "navigate_runs.csv"), write_table(summary, out / "navigate_summary.csv"),
               plots.save(route_figure(world.model, first.run, goal, f"{planner}, seed {args.seed}"),
                          out / "navigate_route.png", dpi=110),
               plots.save(oracle_figure(runs), out / "navigate_vs_oracle.png", dpi=110)]
    print(f"wrote {', '.join(str(p) for p in written)}")
