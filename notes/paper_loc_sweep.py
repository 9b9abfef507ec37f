"""The paper's world with the label prior learned: late location error of info_gain under planner and
estimator options (RBPF 1000 particles, 1000 steps, paired seeds). Usage:
    python notes/paper_loc_sweep.py NAME 'PLANNER_OPTIONS_JSON' 'ESTIMATOR_EXTRA_JSON' [SEEDS e.g. 0-5]
Appends one summary row to notes/paper_loc_results.csv and the per-run rows to notes/paper_loc_runs.csv."""
import json
import os
import sys
import time

import numpy as np
import pandas as pd

from onlinemap.studies.exploration import compare_planners
from onlinemap.studies.floors import floor_runs

name, planner_json, estimator_json = sys.argv[1], sys.argv[2], sys.argv[3]
first, last = (int(x) for x in (sys.argv[4] if len(sys.argv) > 4 else "0-5").split("-"))
seeds = range(first, last + 1)
# a list in a sweep spec is a grid of values: give the planner a tuple
planner_options = {k: tuple(v) if isinstance(v, list) else v for k, v in json.loads(planner_json).items()}
estimator_options = {"n_particles": 1000, "label_prior": "learn", **json.loads(estimator_json)}
world = os.environ.get("WORLD", "door,p_move=0.8")
steps = int(os.environ.get("STEPS", "1000"))
start = time.time()
steps_table = compare_planners(world, ["info_gain"], steps=steps, seeds=seeds, estimator_options=estimator_options,
                               planner_options={"info_gain": planner_options}, workers=0, progress=False)
runs = floor_runs(steps_table, {world: world})  # adds late_location_error (mean 1 - P(true cell), second half)
columns = ["final_map_error", "late_location_error", "mean_location_error", "late_location_distance",
           "location_calibration_gap", "told_location_map_error"]
runs = runs.assign(config=name)
here = os.path.dirname(os.path.abspath(__file__))
keep = ["config", "world", "seed", *columns]
runs[keep].to_csv(os.path.join(here, "paper_loc_runs.csv"), mode="a", index=False,
                  header=not os.path.exists(os.path.join(here, "paper_loc_runs.csv")))
row = {"config": name, "world": world, "steps": steps, "seeds": f"{first}-{last}", "planner": planner_json,
       "estimator": estimator_json}
for c in columns:
    values = runs[c].to_numpy(dtype=float)
    row[c] = values.mean()
    row[c + "_se"] = values.std(ddof=1) / np.sqrt(len(values))
row["seconds"] = time.time() - start
path = os.path.join(here, "paper_loc_results.csv")
pd.DataFrame([row]).to_csv(path, mode="a", index=False, header=not os.path.exists(path))
print(runs[keep].to_string(index=False))
print(pd.Series(row).to_string())
