"""Writes notebooks/active_exploration.ipynb, executed with its outputs. Run: python notebooks/build_active_exploration.py"""

import nbformat
from nbformat.v4 import new_code_cell, new_markdown_cell

from nbbuild import notebook, write

CELLS = [
    new_markdown_cell("""\
# Active exploration from nothing: why the paper's reward stays lost, and information gain

A robot in the 10 x 10 door world (DESIGN.md section 1) knows neither where it is nor the map:
uniform label prior, `p_move = 0.8` (one press in five fails), `p_obs = 0.9`. It keeps a belief
with the Rao-Blackwellised particle filter (`rbpf`) and must decide where to go. Nothing but the
grid's edges and the cells it has already mapped can tell it where it is.

**The paper's planner** (`entropy`, DESIGN.md section 4) builds a reward per cell,
$R(i) = H(L)\\,(1 - H(m_i)) + (1 - H(L))\\,H(m_i)$, solves the MDP over cells by policy iteration
and takes $\\arg\\max_a \\sum_l P(l)\\,Q(l, a)$. This Q-MDP rule values each action as if the
location uncertainty vanished after one step, so it cannot value an action whose payoff *is*
knowing where the robot is: pressing against a wall, going back to a distinctive cell. In this
world the robot never relocalises, and its map smears.

**Information gain** (`info_gain`, Stachniss, Grisetti and Burgard 2005) scores macro-actions
(press one direction k times; follow the policy-iteration path of a per-cell information reward)
by the expected drop of the belief's uncertainty $U = w\\,H(L) + \\sum_i H(m_i)$ (nats), minus a
cost per step. The expectation is taken by simulation: draw a world (a particle's location and a
map from its marginals), roll the macro-action out in it, feed the simulated observations to a
copy of the filter, measure its uncertainty. A long press into a wall is worth a lot to a lost
robot; a path into unmapped cells is worth a lot to a localised one. The live filter is never
touched (`onlinemap.estimators.fork`, or a thinned particle copy rolled out in numba).

An expected-entropy score trusts the belief, though: once every particle agrees on a wrong
trajectory, it sees nothing left to learn about the location. So every `anchor_every` = 60
steps the planner presses into the nearest corner, which puts the true robot in a known cell
whatever the particles believed."""),
    new_code_cell("""\
STEPS = 600
SEEDS = list(range(6))
N_PARTICLES = 300""", metadata={"tags": ["parameters"]}),
    new_code_cell("""\
%matplotlib inline
import matplotlib.pyplot as plt
import numpy as np
from scipy import stats

import onlinemap as om
import policies

model, true_map = policies.exploration_world(p_door=0.0, p_move=0.8, floor_plan=None)  # the paper's world
print(model)
print(om.DOOR_WORLD_10X10)"""),
    new_markdown_cell("""\
## One decision, looked at

A short `info_gain` run, stopped: the location belief, and what the planner expects each
macro-action to teach it (expected uncertainty drop in nats, for each number of steps). The
chosen macro-action has the best gain minus `step_cost` per step."""),
    new_code_cell("""\
planner = policies.make_planner("info_gain", model, seed=0)
frame = policies.explore(model, true_map, planner, "rbpf", max(STEPS // 10, 12), seed=0,
                         estimator_options={"n_particles": N_PARTICLES}, progress=False)
plan = planner.plan(planner.estimator.belief)
c, j = plan.chosen
print(f"step {frame['t'].iloc[-1]}: location error {frame['location_error'].iloc[-1]:.2f}, "
      f"chosen: {plan.names[c]} x {plan.lengths[j]}")
fig, axes = plt.subplots(1, 2, figsize=(11, 3.8), layout="constrained")
image = axes[0].imshow(planner.estimator.belief.location.reshape(model.shape), cmap="magma")
row, col = divmod(int(frame["true_location"].iloc[-1]), model.cols)
axes[0].plot(col, row, "rs", markerfacecolor="none", markersize=14, markeredgewidth=2)
axes[0].set(title="P(L) (true cell: red)", xticks=[], yticks=[])
fig.colorbar(image, ax=axes[0], shrink=0.8)
for name, gain in zip(plan.names, plan.gain):
    axes[1].plot(plan.lengths, gain, "o-", label=name)
axes[1].set(title="expected uncertainty drop", xlabel="steps of the macro-action", ylabel="nats")
axes[1].grid(alpha=0.3)
axes[1].legend();"""),
    new_markdown_cell("""\
## Planners compared on the same seeds

Every planner runs with the same seeds (paired: same world noise stream, same estimator seed).
Map error and location error over time, mean over seeds with a band of one standard error."""),
    new_code_cell("""\
planners = ["info_gain", "entropy", "random", "sweep"]
from onlinemap.studies.exploration import compare_planners, summarize_planners

table = compare_planners("door,p_move=0.8", planners, "rbpf", STEPS, SEEDS,  # the same world, by spec
                         estimator_options={"n_particles": N_PARTICLES}, progress=False)
summarize_planners(table, model, true_map).drop(columns="ms_per_step")  # timings change from run to run"""),
    new_code_cell("""\
fig, axes = plt.subplots(1, 2, figsize=(12, 4), layout="constrained")
policies.plot_errors(table, axes=axes, columns=("map_error", "location_error"));"""),
    new_markdown_cell("""\
## Where the robot goes

Visits summed over seeds. `info_gain` spends its time along the walls and in the corners,
where it relocalises, and strikes out into the interior from there; `entropy`, lost, drifts."""),
    new_code_cell("""\
fig, axes = plt.subplots(1, 4, figsize=(16, 3.8), layout="constrained")
policies.plot_visits(model, true_map, table, axes=axes);"""),
    new_markdown_cell("""\
## What the data could teach

The same planners and seeds through `onlinemap.studies.exploration.paper_world_study` (the same
sweep tasks, so the same runs as above, scored per run), which also scores, for each run, the map
a robot *told its location* at every step would build from the same observations
(`onlinemap.evaluate.told_location_map`): what the planner's data could teach at best. Wrong
cells: the most probable label is not the true one."""),
    new_code_cell("""\
from onlinemap.studies.exploration import paper_world_study

study = paper_world_study(planners, seeds=SEEDS, steps=STEPS, n_particles=N_PARTICLES, progress=False)
study.summary[["planner", "final_map_error", "wrong_cells", "mean_location_error",
               "told_location_map_error", "told_location_wrong"]].round(3)"""),
    new_markdown_cell("""\
## Paired test against the paper's planner

Final map error per seed; one-sided paired t-test that `info_gain` ends lower than `entropy`.
(The full-size study, 20 seeds of 1000 steps with 1000 particles, is
`onlinemap.studies.exploration.paper_world_study()`; its numbers are in the README.)"""),
    new_code_cell("""\
final = table.groupby(["planner", "seed"])["map_error"].last().unstack(0)
diff = final["info_gain"] - final["entropy"]
p = stats.ttest_rel(final["info_gain"], final["entropy"], alternative="less").pvalue if len(diff) > 1 else np.nan
print(f"final map error: info_gain {final['info_gain'].mean():.3f}, entropy {final['entropy'].mean():.3f}; "
      f"info_gain lower on {(diff < 0).sum()}/{len(diff)} seeds, p = {p:.3g}")"""),
    new_markdown_cell("""\
## Conclusion

Starting from nothing (uniform map prior, one press in five failing), the paper's `entropy`
planner stays lost: over these 6 seeds of 600 steps its mean location error is 0.91, no better
than a random walk (0.89) or the sweep (0.94). Information gain values the moves whose payoff is
knowing where the robot is (pressing along walls, returning to cells it has mapped), which the
Q-MDP rule cannot, and with a press into the nearest corner every 60 steps it is the only
planner here that keeps some idea of where it is: mean location error 0.51. Its map is better:
a final map error of 0.41 against 0.50 for `entropy` and 0.51-0.56 for the random walk and the
sweep, lower than `entropy` on 5 of 6 seeds (one-sided paired p = 0.02).

The study table says where the rest is lost. A robot told its location would have mapped the
same observations to 0.07-0.19: what separates that from the filter's map is the location,
which the particles lose and cannot see they lost (the README's `replay_study` feeds the same
data to 20 times as many particles: a third of the error goes). At this short length the
anchors also cost coverage (told-location error 0.17 for `info_gain`, 0.07 for the sweep). The
full-size study (1000 steps, 1000 particles, 20 seeds; README) gives `info_gain` a map error of
0.28 and a location error of 0.53, short of the issue's targets (0.15 and 0.3). Door states stay
mostly wrong for every planner (late door error 0.70-0.89): even the information-gain robot is
too often unsure where it is for a door it sees to be placed."""),
]


def build() -> nbformat.NotebookNode:
    return notebook(CELLS)


if __name__ == "__main__":
    write(build(), "active_exploration.ipynb")
