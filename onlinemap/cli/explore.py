"""``onlinemap explore``: active exploration runs, planners compared on the same seeds, run as a
sweep on the one experiment engine and scored by :mod:`onlinemap.evaluate`."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from ..errors import ModelError
from ..evaluate import HONEST_METRICS, from_steps, metric_legend
from ..worlds import parse_world, world_help
from .common import (OPTION_HELP, non_negative_int, open_unit_interval, options_per_estimator, parse_options, positive_int,
                     print_table, split_list, write_table)
from .views import add_view_arguments, check_view_arguments, first_played, keeper, wanted, write_views

#: the paper's world: the built-in 10 x 10 door world, uniform label prior, p_move 0.8
DEFAULT_WORLD = "door,p_move=0.8"
DEFAULT_PLANNERS = "info_gain,entropy,random,sweep"  # the best planner first, then the baselines
#: printed when the robot starts knowing nothing of the map (a uniform label prior); ``{floor_plan}``:
#: the user's world with the floor plan
HARD = ("the robot knows nothing of the map (uniform label prior): a cell seen for the first time says "
        "nothing about where it is, so it localises only on cells it has already mapped, while its moves "
        "fail with probability 1 - p_move. Expect high location errors (0.5-0.9 in the paper's world, where "
        "info_gain, which re-anchors in a corner, does best). Give it the floor plan with {floor_plan}.")
SUMMARY_METRICS = ("final_map_error", "wrong_cells", "mean_location_error", "late_door_error", *HONEST_METRICS,
                   "ms_per_step")


def add_parser(sub: argparse._SubParsersAction) -> None:
    from policies import PLANNERS

    p = sub.add_parser(
        "explore", help="let planners explore a world (information gain vs entropy vs random walk vs sweep, ...)",
        description="Closed-loop exploration: each planner chooses actions from the estimator's belief, "
                    "the simulated world moves and is observed, the estimator updates. Every planner runs on "
                    "the same seeds (paired), as a sweep (onlinemap.sweeps). Prints, per planner, the final "
                    "map error, the wrong cells (most probable label wrong) at the end, the mean location "
                    "error and, in a world with doors, the late door-state error (mean over the last two "
                    "thirds of the run), the honest metrics (how far off the location belief is, how "
                    "calibrated the location and map beliefs are, the map error of a robot told its path "
                    "and the excess over it; a legend under the table says each in one sentence), each with "
                    "a confidence interval over seeds. With --out DIR, writes "
                    "explore_steps.csv, explore_runs.csv, explore_summary.csv, explore_errors.png and "
                    "explore_visits.png there (and explore.parts/: a rerun resumes).")
    p.add_argument("--world", default=DEFAULT_WORLD,
                   help=f"default {DEFAULT_WORLD} (the paper's: the built-in door world, uniform label prior); "
                        f"{world_help()}")
    p.add_argument("--floor-plan", type=float, default=None, metavar="CONFIDENCE",
                   help="give the robot a label prior from each run's true map: CONFIDENCE on each cell's "
                        "label, door states unknown (onlinemap.worlds.with_floor_plan; also for worlds whose "
                        "map is drawn per seed, unlike the world key floor_plan); default: the world's prior")
    p.add_argument("--planner", default=DEFAULT_PLANNERS,
                   help=f"comma-separated registered planners: {', '.join(PLANNERS)} (default {DEFAULT_PLANNERS})")
    p.add_argument("--estimator", default="rbpf", help="registry name of the estimator (default rbpf)")
    p.add_argument("-o", "--option", action="append", default=[], metavar="KEY=VALUE",
                   help=f"estimator option, repeatable (e.g. -o n_particles=200); {OPTION_HELP}")
    p.add_argument("--steps", type=positive_int, default=500, help="steps per run, first observation included (default 500)")
    p.add_argument("--seed", type=non_negative_int, default=0, help="first seed (default 0)")
    p.add_argument("--repeats", type=positive_int, default=1, help="runs per planner, seeds seed..seed+repeats-1 (default 1)")
    p.add_argument("--confidence", type=open_unit_interval, default=0.95, help="confidence of the intervals (default 0.95)")
    p.add_argument("--workers", type=non_negative_int, default=0,
                   help="0 (default): run in this process; N: on a local dask cluster of N processes")
    p.add_argument("--out", metavar="DIR", help="directory for the tables and figures (nothing is written without it)")
    add_view_arguments(p, "the first planner's run with the first seed")
    p.set_defaults(func=run)


def exploration_spec(args: argparse.Namespace, planners: list[str], model=None) -> dict:
    """The sweep spec of an ``explore`` command line (:func:`onlinemap.studies.exploration.exploration_spec`;
    an option's list value is one value, not a grid); ``model``: the world's, to check the
    options' values on (:func:`~onlinemap.cli.common.options_per_estimator`)."""
    from ..studies.exploration import exploration_spec as spec

    routed = options_per_estimator([args.estimator], args.option, model)[args.estimator]
    options = {key: tuple(value) if isinstance(value, list) else value for key, value in routed.items()}
    return spec(args.world, planners, args.steps, range(args.seed, args.seed + args.repeats),
                estimator=args.estimator, estimator_options=options, floor_plan=args.floor_plan, rows="step")


def run(args: argparse.Namespace) -> int:
    from ..sweeps import summarize, summary_table, sweep

    planners = _check_arguments(args)
    world = parse_world(args.world)
    if args.floor_plan is not None and world.floor_plan is not None:
        raise ModelError(f"--floor-plan {args.floor_plan} and --world {args.world}: give the floor plan once")
    out = Path(args.out) if args.out else None
    _print_setting(args, world, planners)
    spec = exploration_spec(args, planners, world.model)
    kept, on_played = keeper(planners[0], args.seed)
    steps = sweep(spec, workers=args.workers, progress=True, results_dir=None if out is None else out / "explore.parts",
                  on_played=on_played if wanted(args) and args.workers == 0 else None)
    runs = from_steps(steps, ["world", "planner", "seed"])  # the world: counts of cells are bounded by its N
    runs.insert(2, "kind", "explore")
    metrics = [m for m in SUMMARY_METRICS if m in runs]
    summary = summarize(runs, metrics, args.confidence)
    print(f"mean [{args.confidence:.0%} confidence interval] over {args.repeats} seed(s), per planner:")
    print_table(summary_table(summary))
    print("\n".join(metric_legend(metrics)))
    if out is not None:
        _write_tables_and_figures(args, world, steps, runs, summary)
    if wanted(args):
        played = first_played(spec, kept, planners[0], args.seed)
        written = write_views(args, world.model, played.run, played.trajectory,
                              f"{args.world}: {planners[0]}, {args.estimator}, seed {args.seed}")
        print(f"wrote {', '.join(str(p) for p in written)}")
    return 0


def _check_arguments(args: argparse.Namespace) -> list[str]:
    """The planners of ``--planner``, with the numbers and views checked: ModelError for a bad
    count, an unknown planner or a goal planner (it does not explore)."""
    from policies import PLANNERS, planner_options

    if args.steps < 1 or args.repeats < 1 or args.workers < 0:
        raise ModelError("--steps and --repeats must be at least 1, --workers at least 0")
    if not 0 < args.confidence < 1:
        raise ModelError(f"--confidence must be in (0, 1), got {args.confidence}")
    planners = split_list(args.planner)
    unknown = [name for name in planners if name not in PLANNERS]
    if unknown or not planners:
        raise ModelError(f"--planner: unknown {', '.join(unknown) or '(none given)'}; choose from {', '.join(PLANNERS)}")
    goal_planners = [name for name in planners if "goal" in planner_options(name)]
    if goal_planners:
        raise ModelError(f"--planner {', '.join(goal_planners)}: a goal planner goes to a goal, it does not explore; "
                         f"send it to one with onlinemap navigate --goal CELL")
    check_view_arguments(args)
    return planners


def _print_setting(args: argparse.Namespace, world, planners: list[str]) -> None:
    """The world, the robot's label prior (and why a uniform one makes exploring hard), the
    planners and the estimator's options."""
    given = parse_options(args.option)
    options = ", ".join(f"{key}={value}" for key, value in given.items()) or "its default options"
    floor_plan = world.floor_plan if world.floor_plan is not None else args.floor_plan
    uniform = floor_plan is None and np.allclose(world.model.label_prior, 1.0 / world.model.n_labels)
    prior = (f"the floor plan, confidence {floor_plan}" if floor_plan is not None else
             "uniform" if uniform else "the world's own")
    if floor_plan is None and world.model.unknown_label_frequencies:
        prior += (", label frequencies unknown: the rbpf and bk learn them (world key label_prior=uniform or "
                  "--option label_prior=model: the fixed prior)")
    print(f"world {args.world}: {world.model}; label prior: {prior}")
    if uniform:
        # the user's own world with the floor plan: a world key where the map is fixed, else the option
        suggestion = (f"--world {args.world},floor_plan=0.95" if world.true_map is not None else
                      f"--world {args.world} --floor-plan 0.95")
        print("why it is hard: " + HARD.format(floor_plan=suggestion))
    print(f"planners {', '.join(planners)}; estimator {args.estimator} with {options}; {args.steps} steps, "
          f"seeds {args.seed}..{args.seed + args.repeats - 1}")


def _write_tables_and_figures(args: argparse.Namespace, world, steps, runs, summary) -> None:
    """``--out``: the steps, runs and summary tables, the errors over time and the cells visited."""
    from policies import plot_errors, plot_visits

    from .. import plots
    from ..sweeps import played_map

    out = Path(args.out)
    written = [write_table(steps, out / "explore_steps.csv"), write_table(runs, out / "explore_runs.csv"),
               write_table(summary, out / "explore_summary.csv")]
    # the map the runs used: the world's own, or the one drawn for the only seed (with several
    # seeds each run has its own map: the visits are drawn without one)
    true_map = world.true_map if world.true_map is not None or args.repeats > 1 else played_map(args.world, args.seed)
    columns = [c for c in ("map_error", "door_error") if c in steps]
    written += [plots.save(plot_errors(steps, columns=columns), out / "explore_errors.png", dpi=110),
                plots.save(plot_visits(world.model, true_map, steps), out / "explore_visits.png", dpi=110)]
    print(f"wrote {', '.join(str(p) for p in written)}")
