"""The table of notes/paper_loc.md from notes/paper_loc_runs.csv: per configuration and seed set, the mean and
standard error over seeds of the late location error, final map error and location calibration gap, and the
paired difference (same seeds) against the baseline's late location error and map error."""
import os

import numpy as np
import pandas as pd

here = os.path.dirname(os.path.abspath(__file__))
runs = pd.read_csv(os.path.join(here, "paper_loc_runs.csv"))
runs = runs[runs.world == "door,p_move=0.8"].drop_duplicates(["config", "seed"], keep="last")
runs["seeds"] = np.where(runs.seed < 6, "0-5", "6-11")
base = runs[runs.config == "baseline"].set_index("seed")
rows = []
for (config, seeds), group in runs.groupby(["config", "seeds"], sort=False):
    row = {"config": config, "seeds": seeds, "n": len(group)}
    for column, short in (("late_location_error", "late loc"), ("final_map_error", "map"),
                          ("location_calibration_gap", "calib gap"), ("told_location_map_error", "told-loc map")):
        values = group[column].to_numpy()
        row[short] = f"{values.mean():.3f} ± {values.std(ddof=1) / np.sqrt(len(values)):.3f}"
    for column, short in (("late_location_error", "Δ loc vs base"), ("final_map_error", "Δ map vs base")):
        diff = group.set_index("seed")[column] - base[column].reindex(group.seed)
        row[short] = f"{diff.mean():+.3f} ± {diff.std(ddof=1) / np.sqrt(len(diff)):.3f}"
    rows.append(row)
table = pd.DataFrame(rows)
print("| " + " | ".join(table.columns) + " |")
print("|" + "---|" * len(table.columns))
for values in table.itertuples(index=False):
    print("| " + " | ".join(str(v) for v in values) + " |")
