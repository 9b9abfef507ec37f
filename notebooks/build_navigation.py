"""Writes notebooks/navigation.ipynb, executed with its outputs. Run: python notebooks/build_navigation.py"""

import nbformat

from nbbuild import notebook, write

CELLS = [
    ("md", """# Getting somewhere while doors open and close

A robot in the 10 x 10 door world must reach a goal. Walls and closed doors block it, its wheels
slip (a move fails with probability 0.2), its cross-shaped sensor reads its cell and the four
around it, and it has the building's floor plan: walls and free space believed with confidence
0.95, door cells known to be doors but their state unknown. The doors open and close on their
own, each flipping with probability `p_door` per step.

Thrun, Burgard and Fox (section 4, *Dealing with dynamic environments*) plan shortest paths on
an occupancy map that integrates the static structure and what changes, and re-plan as it
changes, so the robot takes a detour when a passage closes. Here the robot's belief is that
integrated map: the planner `goto` runs dynamic programming over cells on the belief's label
marginals, with each door's state moved forward by its dynamics to the time the robot would
reach it (a door seen closed may reopen), re-plans at every step and acts under the location
belief. `static_goto` is the same planner on the floor plan alone, never on what the robot has
seen. Both are compared with an *oracle*, a robot that knows its cell and the true state of
every door now, in the same world history: the same doors and slips, step by step."""),
    ("code", """%matplotlib inline
import os

import numpy as np
from IPython.display import display

import onlinemap as om
import policies
from onlinemap.studies import navigation
from onlinemap.studies.base import with_intervals

SEEDS = range(int(os.environ.get("ONLINEMAP_NOTEBOOK_SEEDS", "20")))  # paired runs per setting
N_PARTICLES = 500
model, true_map = om.door_world(blocking=True, footprint="cross", p_door=0.05)
goal = navigation.far_goals(model, true_map)[0]
print(model)
print("goal:", divmod(goal, model.cols))"""),
    ("md", """## Steps to the goal against the oracle

Every planner and the oracle on the same seeds, at two door speeds. *Success*: the goal reached
within 4 times the oracle's steps; the means are over the runs where the oracle gets there, with
95% intervals over seeds; `mean_steps_over_mean_oracle` is the mean steps over the oracle's mean
steps."""),
    ("code", """COLUMNS = ["planner", "runs", "success", "steps_to_goal", "oracle_steps", "steps_over_oracle",
           "mean_steps_over_mean_oracle"]
studies = {p_door: navigation.door_world_study(p_door, seeds=SEEDS, n_particles=N_PARTICLES, progress=False)
           for p_door in (0.02, 0.05)}
for p_door, study in studies.items():
    print(f"p_door = {p_door}")
    table = with_intervals(study.summary, ["success", "steps_to_goal", "oracle_steps", "steps_over_oracle"])
    display(table.assign(mean_steps_over_mean_oracle=table["mean_steps_over_mean_oracle"].round(3))[COLUMNS])"""),
    ("code", """for p_door, study in studies.items():
    figure = navigation.oracle_figure(study.runs)
    figure.axes[0].set_title(f"p_door = {p_door}: steps to the goal, per run")
    display(figure)"""),
    ("md", """## One history, two robots

The run (at `p_door` 0.02) where `static_goto` needed the most steps more than `goto`: the same
doors and slips step by step, drawn on the building as it was at the start. The line is the true
path, circles mark cells where the robot stayed three steps or more (waiting at a door, or
pressing into one)."""),
    ("code", """runs = studies[0.02].runs.pivot(index="seed", columns="planner", values="steps")
seed = int((runs["static_goto"] - runs["goto"]).idxmax())
slow_doors = om.door_world(blocking=True, footprint="cross", p_door=0.02)[0]
robot = policies.with_floor_plan(slow_doors, true_map, 0.95)
oracle = policies.oracle_steps(robot, true_map, goal, max_steps=400, seed=seed)
for planner in ("goto", "static_goto"):
    found = policies.navigate(robot, true_map, goal, planner, max_steps=400, seed=seed,
                              estimator_options={"n_particles": N_PARTICLES})
    print(f"seed {seed}, {planner}: the goal at step {found.reached_at} (the oracle: step {oracle})")
    display(navigation.route_figure(slow_doors, found.run, goal, f"{planner}, p_door 0.02, seed {seed}"))"""),
    ("md", """## What the numbers say

* Both planners reach the goal in every run, at both door speeds (success 20 of 20).
* `goto` takes about the oracle's steps: 1.04 times its mean at `p_door` 0.02, 1.12 times at
  0.05. What is left comes from runs in which the robot waits at a door it saw closed while the
  oracle, which knows the state of doors it cannot see, goes the other way: the price of a sensor
  that sees only around the robot.
* `static_goto`, which plans on the floor plan alone, needs 1.41 times the oracle's mean at 0.02:
  `goto` takes 27% fewer steps. In the run drawn above it pressed against a door that `goto` had
  seen closed and gone round (192 steps against 52). When doors change fast (0.05) what the robot
  saw is soon stale: the two are closer (1.12 against 1.18 times the oracle, 5% fewer steps for
  `goto`), and in this building most routes to the far corner are forced through one door.

`onlinemap navigate` runs the same study from the command line (`--world`, `--goal`,
`--planner goto,static_goto`, `--repeats`, `--out DIR` for the tables and these figures), and
`onlinemap.studies.navigation` holds it for generated buildings too
(`building_navigation_study`)."""),
]


def build() -> nbformat.NotebookNode:
    return notebook(CELLS)


if __name__ == "__main__":
    write(build(), "navigation.ipynb")
