"""``onlinemap remap``: the hindsight maps of a recorded run beside the filter's last map.

The run is read from ``--input FILE`` (JSON lines as ``onlinemap track`` reads them,
``{"action": ..., "observation": ...}``, the first line without an action, each line optionally
with ``"location"``, the true cell: with every location given, the told-location map is scored
too), or made afresh from ``--world`` and ``--seed``: a random walk (``--planner random_walk``,
the run ``onlinemap run`` simulates) or an exploration run of a planner of :mod:`policies` with the
``--estimator`` in the loop (``policies.exploration``). The filter (``--estimator``) is run over a
read or random-walk run to give its final map. ``--methods`` also takes
``layered_em_learned_alignment`` (layered EM aligned with learned label statistics, mapped
under the model's prior) and ``rbpf_smoothed`` (the run replayed through an RBPF of
``--particles`` particles, seed ``--seed``, and its genealogy smoother; adds the row
``rbpf_filtered``, that replay's final map). Prints one row per map (:mod:`onlinemap.hindsight`):
``final_map_error``, ``wrong_cells``, ``confidently_wrong`` (P(wrong label) > 0.9), ``seconds``;
``--out DIR`` writes it as ``remap.csv``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from ..errors import InvalidObservationError, OnlineMapError
from ..worlds import world_help
from .common import (add_out_argument, check_table_format, name_list, non_negative_int, positive_int, print_table,
                     world, write_tables)

RANDOM_WALK = "random_walk"


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("remap", help="remap a recorded run with hindsight (flat EM, layered EM, smoothed RBPF, "
                                     "told location)",
                       description="Remap a recorded run after the fact: flat EM (Baum-Welch) and layered EM "
                                   "(Burgard et al. 1999), scored with the filter's final map and the map of a "
                                   "robot told its true path. The run comes from --input (track's JSON lines, "
                                   "optionally with the true 'location' per line) or is made from --world, "
                                   "--planner, --steps and --seed.")
    p.add_argument("--world", default="building:32x32,seed=0", type=world,
                   help=f"{world_help()} (default building:32x32,seed=0); its map is the true map")
    p.add_argument("--input", type=Path, metavar="FILE", help="the run as JSON lines (track's input format)")
    p.add_argument("--planner", default=RANDOM_WALK,
                   help=f"without --input: {RANDOM_WALK} (default) or a planner of policies (info_gain, random, ...)")
    p.add_argument("--estimator", default="rbpf", help="the filter whose final map is compared (default rbpf)")
    p.add_argument("--steps", type=positive_int, default=800, help="steps of a run made afresh (default 800)")
    p.add_argument("--seed", type=non_negative_int, default=0, help="seed of a run made afresh (default 0)")
    p.add_argument("--methods", type=name_list, default=["flat_em", "layered_em"],
                   help="hindsight methods, comma-separated (default flat_em,layered_em): flat_em, layered_em, "
                        "layered_em_learned_alignment, rbpf_smoothed, told_location")
    p.add_argument("--particles", type=positive_int, default=None,
                   help="rbpf_smoothed's particles (default 1000)")
    p.add_argument("--stretch", type=positive_int, default=None,
                   help="layered EM's steps per local map (default: 1 / (2 (1 - p_move)), rounded)")
    p.add_argument("--label-prior", choices=["model", "learn"], default="model",
                   help="layered EM's and the told-location map's label prior: the model's (default) or 'learn' "
                        "(the label frequencies re-estimated in every M-step)")
    add_out_argument(p, "remap.csv (one row per map)")
    p.set_defaults(func=remap)


def read_run(path: Path, model):
    """(actions (T - 1,), observations, locations (T,) or None) from track-style JSON lines.
    Raises InvalidObservationError naming the line of a malformed record."""
    from ..validation import check_sequence

    actions, observations, locations = [], [], []
    with open(path, encoding="utf-8") as lines:
        for number, line in enumerate(lines, 1):
            if not line.strip():
                continue
            try:
                record = json.loads(line)
                observations.append(record["observation"])
            except (ValueError, KeyError, TypeError) as error:
                raise InvalidObservationError(f"{path} line {number}: expected a JSON object with 'observation' "
                                              f"({type(error).__name__}: {error})") from None
            if len(observations) > 1:
                actions.append(record.get("action"))
            locations.append(record.get("location"))
    a_seq, z_seq = check_sequence(model, actions, observations)
    known = all(location is not None for location in locations)
    return a_seq, z_seq, np.array(locations, dtype=np.int64) if known else None


def _run(args: argparse.Namespace):
    """(Run or (actions, observations), true map, the filter's final map or None)."""
    from ..estimators import make_estimator, run_estimator
    from ..simulate import Run

    spec = args.world
    model = spec.model
    if args.input is not None:
        actions, observations, locations = read_run(args.input, model)
        true_map = spec.initial_map(args.seed)
        data = (actions, observations) if locations is None else \
            Run(model, actions, locations, np.broadcast_to(true_map, (len(locations), model.n_cells)), observations)
    elif args.planner == RANDOM_WALK:
        data = spec.simulate(args.steps, args.seed)
        true_map = data.final_map
    else:
        from policies import exploration
        played = exploration(model, spec.initial_map(args.seed), args.planner, args.estimator, args.steps, args.seed,
                             progress=False)
        return played.run, played.run.final_map, played.trajectory.map[-1]
    actions, observations = (data.actions, data.observations) if isinstance(data, Run) else data
    estimator = make_estimator(args.estimator, model, **({"seed": args.seed} if args.estimator == "rbpf" else {}))
    return data, true_map, run_estimator(estimator, actions, observations).map[-1]


def remap(args: argparse.Namespace) -> int:
    from ..hindsight import METHODS, hindsight_map, hindsight_table
    from ..simulate import Run

    check_table_format(args.out, args.format)
    unknown = [m for m in args.methods if m not in METHODS]
    if unknown:
        raise OnlineMapError(f"--methods: unknown {', '.join(unknown)}; choose from {', '.join(METHODS)}")
    data, true_map, filter_map = _run(args)
    model = args.world.model
    maps, seconds = {f"filter ({args.estimator})": filter_map}, {}
    methods = list(args.methods)
    if isinstance(data, Run) and "told_location" not in methods:
        methods.append("told_location")
    for method in methods:
        options = {"stretch": args.stretch} if method in ("layered_em", "layered_em_learned_alignment") else {}
        if args.label_prior == "learn" and method in ("layered_em", "told_location", "rbpf_smoothed"):
            options["label_prior"] = "learn"
        if method == "rbpf_smoothed":
            options.update({"seed": args.seed, **({} if args.particles is None else {"n_particles": args.particles})})
        fit = hindsight_map(model, data, method, **options)
        if fit.filtered is not None:
            maps["rbpf_filtered"] = fit.filtered
        maps[method], seconds[method] = fit.map, fit.seconds
    steps = data.n_steps if isinstance(data, Run) else len(data[1])
    print(f"world {args.world.spec}: {model}; {steps} steps")
    table = hindsight_table(true_map, maps, seconds)
    print_table(table)
    if args.out is not None:
        write_tables({"remap": table}, args.out, args.format)
    return 0
