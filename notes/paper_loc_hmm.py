"""How localised can a robot told the true map be on the same data? For runs of info_gain in the paper's
world (RBPF 1000 particles, label prior learned), the location filtered by a plain HMM forward pass with the
true map (emission[i, z] = sensor[true label of i, z]; the world is static, so this is the exact filter told
the map), against the RBPF's own location.
Usage: [PLANNER=name] python notes/paper_loc_hmm.py 'PLANNER_JSON' 'ESTIMATOR_JSON' SEEDS"""
import json
import os
import sys

import numpy as np

from onlinemap.evaluate import late_mean
from onlinemap.hmm import forward_backward
from onlinemap.metric_names import SECOND_HALF
from onlinemap.worlds import parse_world
from policies.explore import exploration

planner_options = json.loads(sys.argv[1])
planner = os.environ.get("PLANNER", "info_gain")
estimator_options = {"n_particles": 1000, "label_prior": "learn", **json.loads(sys.argv[2])}
first, last = (int(x) for x in sys.argv[3].split("-"))
world = parse_world("door,p_move=0.8")
model = world.model
rows = []
for seed in range(first, last + 1):
    found = exploration(model, world.true_map, planner, "rbpf", 1000, seed, estimator_options=estimator_options,
                        planner_options=planner_options, progress=False)
    run = found.run
    assert np.all(run.maps == run.maps[0]), "a static world"
    emission = model.sensor[run.maps[0]]  # (N, K)
    told = forward_backward(model, model.location_prior(), run.actions, run.observations, emission)
    t = np.arange(len(run.locations))
    error_told = 1.0 - told.filtered[t, run.locations]
    error_rbpf = 1.0 - found.trajectory.location[t, run.locations]
    rows.append((seed, late_mean(t, error_rbpf, SECOND_HALF), late_mean(t, error_told, SECOND_HALF),
                 late_mean(t, 1.0 - told.posterior[t, run.locations], SECOND_HALF)))
    print(f"seed {seed}: late location error rbpf {rows[-1][1]:.3f}, told-map filter {rows[-1][2]:.3f}, "
          f"told-map smoother {rows[-1][3]:.3f}", flush=True)
table = np.array(rows)
se = table.std(axis=0, ddof=1) / np.sqrt(len(table))
print(f"mean: rbpf {table[:, 1].mean():.3f} +- {se[1]:.3f}, told-map filter {table[:, 2].mean():.3f} +- {se[2]:.3f}, "
      f"told-map smoother {table[:, 3].mean():.3f} +- {se[3]:.3f}")
