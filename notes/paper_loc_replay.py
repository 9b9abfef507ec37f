"""Is the RBPF's excess over the told-map filter the filter's (1000 particles) or the data's? info_gain's runs
in the paper's world (label prior learned, live RBPF 1000 particles, default planner options) replayed (same
actions and readings) through fresh learned-prior RBPFs of more particles, and through the told-map HMM filter.
Usage: python notes/paper_loc_replay.py SEEDS PARTICLES...   e.g. 0-2 1000 5000 20000"""
import sys

import numpy as np

from onlinemap.estimators import make_estimator, run_estimator
from onlinemap.evaluate import late_mean
from onlinemap.hmm import forward_backward
from onlinemap.metric_names import SECOND_HALF
from onlinemap.worlds import parse_world
from policies.explore import exploration

first, last = (int(x) for x in sys.argv[1].split("-"))
sizes = [int(s) for s in sys.argv[2:]]
world = parse_world("door,p_move=0.8")
model = world.model
results = {name: [] for name in ["live 1000", *[f"replay {s}" for s in sizes], "told map"]}
for seed in range(first, last + 1):
    found = exploration(model, world.true_map, "info_gain", "rbpf", 1000, seed,
                        estimator_options={"n_particles": 1000, "label_prior": "learn"}, progress=False)
    run = found.run
    t = np.arange(len(run.locations))

    def late(location):
        return late_mean(t, 1.0 - location[t, run.locations], SECOND_HALF)

    results["live 1000"].append(late(found.trajectory.location))
    for size in sizes:
        est = make_estimator("rbpf", model, n_particles=size, label_prior="learn", seed=10_000 + seed,
                             max_bytes=2**34)
        results[f"replay {size}"].append(late(run_estimator(est, run.actions, run.observations).location))
    told = forward_backward(model, model.location_prior(), run.actions, run.observations, model.sensor[run.maps[0]])
    results["told map"].append(late(told.filtered))
    print(f"seed {seed}: " + ", ".join(f"{k} {v[-1]:.3f}" for k, v in results.items()), flush=True)
for name, values in results.items():
    values = np.asarray(values)
    print(f"{name}: late location error {values.mean():.3f} +- {values.std(ddof=1) / np.sqrt(len(values)):.3f}")
