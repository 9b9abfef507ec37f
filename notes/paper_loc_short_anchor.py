"""Prototype (not in the library): an anchor of as many presses along each axis as bring the robot to the edge
with probability >= CONFIDENCE under the current location belief (the axes move independently: presses along
the columns do not change the row), instead of the fixed press_lengths[-1] presses per axis. Patched into
policies.info_gain for one sweep run: python notes/paper_loc_short_anchor.py NAME PLANNER_JSON ESTIMATOR_JSON SEEDS"""
import os
import runpy
import sys

import numpy as np
from scipy.stats import binom

import policies.info_gain as info_gain

CONFIDENCE = float(os.environ.get("CONFIDENCE", "0.99"))
original = info_gain.anchor_actions


def short_anchor(model, belief, presses):
    full = original(model, belief, presses)
    rows, cols = np.divmod(np.arange(model.n_cells), model.cols)
    out = []
    for axis, (coordinate, size) in enumerate(((cols, model.cols), (rows, model.rows))):
        action = int(full[axis * presses])
        edge = coordinate[model.neighbors[:, action] == np.arange(model.n_cells)][0]  # the cells it keeps in place
        distance = np.abs(coordinate - edge)
        for k in range(1, presses + 1):  # P(at the edge after k presses) = P(Binomial(k, p_move) >= distance)
            if belief.location @ binom.sf(distance - 1, k, model.p_move) >= CONFIDENCE:
                break
        out += [action] * k
    return np.asarray(out, dtype=np.int64)


info_gain.anchor_actions = short_anchor
sys.argv = [os.path.join(os.path.dirname(__file__), "paper_loc_sweep.py"), *sys.argv[1:]]
runpy.run_path(sys.argv[0], run_name="__main__")
