"""``onlinemap run``: simulate a world and run estimators side by side."""

from __future__ import annotations

import argparse

import numpy as np
import pandas as pd
from tqdm.auto import tqdm

from .. import metrics
from ..errors import MemoryLimitError
from ..estimators import make_estimator, run_estimator
from ..worlds import parse_world
from .common import print_table, split_list, write_table


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("run", help="simulate a world and compare estimators on it",
                       description="Simulate a random-walk run and run estimators side by side; "
                                   "prints final map error, mean location error and time per step.")
    p.add_argument("--world", default="corridor:8",
                   help="world spec: corridor:N[,p_change=..,n_labels=..], grid:RxC, door[,p_door=..] "
                        "(default corridor:8)")
    p.add_argument("--estimators", default="exact,dead_reckoning",
                   help="comma-separated registry names (default exact,dead_reckoning)")
    p.add_argument("--steps", type=int, default=60, help="number of steps, first observation included")
    p.add_argument("--seed", type=int, default=0, help="seed of the map, the walk and the noise")
    p.add_argument("--out", help="write per-step metrics (one row per estimator and step) to .csv or .parquet")
    p.set_defaults(func=run)


def compare_on_run(run, names: list[str], options: dict[str, dict] | None = None,
                   progress: bool = True) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Run each estimator over ``run``; returns (summary table, per-step table)."""
    options = options or {}
    rows, steps = [], []
    for name in tqdm(names, desc="estimators", disable=not progress, leave=False):
        try:
            estimator = make_estimator(name, run.model, **options.get(name, {}))
        except MemoryLimitError as error:
            print(f"{name}: skipped: {error}")
            continue
        trajectory = run_estimator(estimator, run.actions, run.observations)
        map_err = metrics.map_error(trajectory.map, run.maps)
        loc_err = metrics.location_error(trajectory.location, run.locations)
        rows.append({"estimator": name, "final_map_error": map_err[-1],
                     "mean_location_error": loc_err.mean(), "final_location_error": loc_err[-1],
                     "ms_per_step": 1e3 * trajectory.seconds_per_step})
        steps.append(pd.DataFrame({"estimator": name, "t": np.arange(run.n_steps), "map_error": map_err,
                                   "location_error": loc_err, "log_evidence": trajectory.log_evidence}))
    return pd.DataFrame(rows), pd.concat(steps, ignore_index=True) if steps else pd.DataFrame()


def run(args: argparse.Namespace) -> int:
    world = parse_world(args.world)
    sim = world.simulate(args.steps, args.seed)
    print(f"world {args.world}: {world.model}; {sim.n_steps} steps, {int(sim.slipped.sum())} slips, seed {args.seed}")
    summary, per_step = compare_on_run(sim, split_list(args.estimators))
    print_table(summary)
    if args.out:
        print(f"wrote {write_table(per_step, args.out)}")
    return 0
