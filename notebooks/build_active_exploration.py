"""Writes notebooks/active_exploration.ipynb, executed with its outputs. Run: python notebooks/build_active_exploration.py"""

import nbformat
from nbformat.v4 import new_code_cell, new_markdown_cell

from nbbuild import notebook, write

CELLS = [
    new_markdown_cell("""\
# Active exploration in a dynamic door world

A robot in the 10 x 10 door world (DESIGN.md section 1) does not know where it is nor the
state of the doors, which open and close at random (`p_door = 0.01` per step). It keeps a
belief with the Rao-Blackwellised particle filter (`rbpf`) and must decide where to go.

The **entropy planner** (DESIGN.md section 4) builds a reward per cell from its belief,

$$R(i) = H(L)\\,(1 - H(m_i)) + (1 - H(L))\\,H(m_i)$$

(normalised entropies: a lost robot is paid to visit cells it knows, a localised one to visit
cells it does not), solves the MDP over cells by policy iteration, and takes the action
maximising $\\sum_l P(l)\\,Q(l, a)$. `entropy_collect` is the same with the reward of the cell the
robot is in counted as collected ($R(i)\\,(1 - P(L = i))$), which stops a robot unsure between
two cells from staying put forever. The baselines are a **random walk** and an open-loop
**sweep** (boustrophedon).

The robot is given the building's floor plan (walls and free space believed with 0.8, door
states unknown, `policies.exploration_world`) and `p_move = 0.9`. With a uniform prior, or at
`p_move = 0.8`, it is lost most of the time whatever it does, and no planner keeps the doors
up to date (try it: change `WORLD` below)."""),
    new_code_cell("""\
STEPS = 400
SEEDS = list(range(8))
N_PARTICLES = 100""", metadata={"tags": ["parameters"]}),
    new_code_cell("""\
%matplotlib inline
import matplotlib.pyplot as plt
import numpy as np
from scipy import stats

import onlinemap as om
import policies

WORLD = dict(p_door=0.01, p_move=0.9, floor_plan=0.8)
model, true_map = policies.exploration_world(**WORLD)
print(model)
print(om.DOOR_WORLD_10X10)"""),
    new_markdown_cell("""\
## What the planner sees

One entropy-planner run, stopped part way: the location belief, the reward it builds from the
belief, and the value of the policy-iteration solution (warm-started from the previous plan)."""),
    new_code_cell("""\
class Recording(policies.EntropyExplorer):
    \"\"\"The entropy planner, keeping the last belief it planned from.\"\"\"

    def choose(self, belief):
        self.last_belief = belief
        return super().choose(belief)


planner = Recording(model)
frame = policies.explore(model, true_map, planner, "rbpf", max(STEPS // 4, 10), seed=0,
                         estimator_options={"n_particles": N_PARTICLES}, progress=False)
belief = planner.last_belief
panels = {"P(L) (true cell: red)": belief.location, "reward R(i)": policies.entropy_reward(belief),
          "value V(i)": planner.plan.value}
fig, axes = plt.subplots(1, 3, figsize=(12, 3.6), layout="constrained")
row, col = divmod(int(frame["true_location"].iloc[-1]), model.cols)
for ax, (title, values) in zip(axes, panels.items()):
    image = ax.imshow(values.reshape(model.shape), cmap="magma")
    ax.set(title=title, xticks=[], yticks=[])
    fig.colorbar(image, ax=ax, shrink=0.8)
axes[0].plot(col, row, "rs", markerfacecolor="none", markersize=14, markeredgewidth=2)
print(f"step {frame['t'].iloc[-1]}: policy iteration took {planner.plan.iterations} evaluation(s)")"""),
    new_markdown_cell("""\
## Planners compared on the same seeds

Every planner runs with the same seeds, so each seed gives a paired comparison (same world
noise stream, same estimator seed)."""),
    new_code_cell("""\
table = policies.compare_planners(model, true_map, ["entropy", "entropy_collect", "random", "sweep"],
                                  "rbpf", STEPS, SEEDS, estimator_options={"n_particles": N_PARTICLES},
                                  progress=False)
summary = policies.summarize(table, model, true_map)
summary.drop(columns="ms_per_step")  # timings differ between runs; the stored outputs must not"""),
    new_code_cell("""\
fig, axes = plt.subplots(1, 2, figsize=(12, 4), layout="constrained")
policies.plot_errors(table, axes=axes);"""),
    new_code_cell("""\
fig, axes = plt.subplots(1, 4, figsize=(16, 3.8), layout="constrained")
policies.plot_visits(model, true_map, table, axes=axes);"""),
    new_markdown_cell("""\
## Paired tests against the random walk

Final map error, and door-state error averaged over the last two thirds of each run (once the
doors have been seen), per seed; one-sided paired t-tests that the planner's error is lower."""),
    new_code_cell("""\
final = table.groupby(["planner", "seed"])["map_error"].last().unstack(0)
late = table[table["t"] >= STEPS // 3].groupby(["planner", "seed"])["door_error"].mean().unstack(0)
for name, errors in (("final map error", final), ("late door error", late)):
    for planner_name in ("entropy", "entropy_collect", "sweep"):
        diff = errors[planner_name] - errors["random"]
        p = stats.ttest_rel(errors[planner_name], errors["random"], alternative="less").pvalue if len(diff) > 1 else np.nan
        print(f"{name:16s} {planner_name:16s} mean difference vs random {diff.mean():+.3f}, "
              f"lower on {(diff < 0).sum()}/{len(diff)} seeds, p = {p:.3g}")"""),
    new_markdown_cell("""\
## Conclusion

On these 8 paired seeds of 400 steps in the dynamic door world (RBPF, 100 particles), the
entropy planner ends with a map error of 0.025 against 0.101 for a random walk (lower on 8 of 8
seeds), and keeps the doors more up to date (door-state error over the last two thirds 0.35
against 0.45): its reward sends it back to doors whose state it has become unsure of, and it
spends about twice the random walk's share of time at doors (9.9% against 5.1% of its steps).
The open-loop sweep covers the building too but does not look at the belief, so it does not
return to doors (door error 0.41). Every planner beats the random walk on both errors in the
paired tests (one-sided p < 0.025).

What none of them achieves is a well-localised robot: the mean location error stays between
0.38 and 0.49 for all four planners, so the door states stay partly stale. Eight seeds are few
for the door-state effect; the README's study, with 64 paired seeds, puts it at about 0.3
standard deviations per seed."""),
]


def build() -> nbformat.NotebookNode:
    return notebook(CELLS)


if __name__ == "__main__":
    write(build(), "active_exploration.ipynb")
