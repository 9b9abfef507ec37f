"""Writes notebooks/rbpf_vs_bk.ipynb, executed with its outputs. Run: python notebooks/build_rbpf_vs_bk.py"""

import nbformat

from nbbuild import notebook, write

CELLS = [
    ("md", """# Approximate Bayes: Rao-Blackwellised particles against Boyen-Koller

Exact Bayes over a robot's location and a map of N cells with K labels keeps N x K^N numbers:
fine for 10 cells, hopeless for 100. Two ways to approximate it:

* **Boyen-Koller (BK)** keeps one marginal per variable, `P(L) * prod_i P(m_i)`, does the exact
  update from that product and projects back. Cheap (O(N K) per step) but it forgets that
  *where the robot is* and *what the map says* are correlated: "if I slipped at step 4, cell 3
  is a 1; if I did not, cell 4 is".
* **The Rao-Blackwellised particle filter (RBPF)** samples the robot's trajectory (a particle
  = one hypothesis of where it has been) and, given a trajectory, computes the map *exactly*:
  the cells are then independent, so each particle holds N marginals. The correlation lives
  in the population of particles. By default (`resampling="fearnhead_clifford"`) nothing is
  sampled twice: each step enumerates every particle's successors (stay or move) with their
  exact weights and keeps P of them by optimal resampling (Fearnhead and Clifford 2003). The
  sampling schemes remain: the `optimal` proposal samples the next location given the
  observation, `transition` samples the motion model and lets the weights sort it out, each
  with `resampling="residual"` (or systematic, stratified, multinomial).

Both are in the streaming API (`om.make_estimator("bk", model)`,
`om.make_estimator("rbpf", model, n_particles=100, seed=0)`)."""),
    ("code", """%matplotlib inline
import os

import numpy as np
from IPython.display import display
from matplotlib.figure import Figure

import onlinemap as om
from onlinemap import plots
from onlinemap.estimators.rbpf import SCHEMES
from onlinemap.evaluate import step_metrics
from onlinemap.studies import accuracy as compare

N_RUNS = int(os.environ.get("ONLINEMAP_NOTEBOOK_RUNS", "10"))  # random runs per world in the study
N_STEPS = int(os.environ.get("ONLINEMAP_NOTEBOOK_STEPS", "60"))
N_SEEDS = int(os.environ.get("ONLINEMAP_NOTEBOOK_SEEDS", "10"))  # filter seeds per particle count"""),
    ("md", """## The scripted corridor

Murphy's run: 8 cells coloured `0 1 0 1 0 1 0 1`, right 7 times then left 7 times, the fourth
move slips. Each estimator's location belief (left) and its P(colour 1) per cell (right)."""),
    ("code", """run = om.scenarios.murphy_corridor()
estimators = {"exact": om.make_estimator("exact", run.model),
              "bk": om.make_estimator("bk", run.model),
              "rbpf (100 particles)": om.make_estimator("rbpf", run.model, n_particles=100, seed=0)}
trajectories = {name: om.run_estimator(est, run.actions, run.observations) for name, est in estimators.items()}
display(plots.estimators_figure(run, trajectories))"""),
    ("md", """How far each is from exact, step by step: the total-variation distance of the location
belief, and of the map marginals (mean over cells). BK equals exact for two steps (the location
is still known) and then drifts when the slip makes location and map depend on each other."""),
    ("code", """exact = trajectories["exact"]
fig = Figure(figsize=(10, 3.2), layout="constrained")
ax_loc, ax_map = fig.subplots(1, 2)
for name in ("bk", "rbpf (100 particles)"):
    scores = step_metrics(run, trajectories[name], reference=exact)  # location_tv, map_tv: onlinemap.evaluate
    ax_loc.plot(scores["location_tv"], "o-", label=name)
    ax_map.plot(scores["map_tv"], "o-", label=name)
ax_loc.set(title="location: TV distance to exact", xlabel="step t")
ax_map.set(title="map: mean TV distance to exact", xlabel="step t")
ax_map.legend()
fig"""),
    ("md", """## Particles: how many, and which scheme

The sampling schemes' error shrinks like 1/sqrt(P). `N_SEEDS` filter seeds per particle count
on the scripted run, for the default (Fearnhead-Clifford) and the two proposals with residual
resampling."""),
    ("code", """rows = []
for scheme, options in SCHEMES.items():  # the rbpf's named schemes: FC (its default) and two sampling ones
    for n in (10, 30, 100, 300, 1000):
        for seed in range(N_SEEDS):
            est = om.make_estimator("rbpf", run.model, n_particles=n, seed=seed, **options)
            t = om.run_estimator(est, run.actions, run.observations)
            rows.append((scheme, n, step_metrics(run, t, reference=exact)["map_tv"].mean()))
import pandas as pd
particles = pd.DataFrame(rows, columns=["scheme", "particles", "map_tv"]).groupby(
    ["scheme", "particles"], sort=False).map_tv.mean().unstack(0)
bk_tv = step_metrics(run, trajectories["bk"], reference=exact)["map_tv"].mean()
fig = Figure(figsize=(5, 3.5), layout="constrained")
ax = fig.subplots()
particles.plot(ax=ax, marker="o", logx=True, logy=True)
ax.axhline(bk_tv, color="C3", linestyle="--", label="bk")
ax.set(xlabel="particles", ylabel="mean map TV distance to exact")
ax.legend()
display(fig)
particles.assign(bk=bk_tv)"""),
    ("md", """The optimal proposal looks at the observation before choosing where the robot went, so
fewer particles are wasted on locations the observation rules out: its weights vary less.
With the same resampling for both (residual, every step), the effective sample size after each
step measures that directly."""),
    ("code", """def mean_ess(proposal, seed):
    est = om.make_estimator("rbpf", run.model, n_particles=200, proposal=proposal, resampling="residual",
                            resample_threshold=1.0, seed=seed)
    return np.mean([est.step(None if t == 0 else run.actions[t - 1], run.observations[t]).effective_sample_size
                    for t in range(run.n_steps)])

{proposal: np.mean([mean_ess(proposal, seed) for seed in range(N_SEEDS)])
 for proposal in ("optimal", "transition")}"""),
    ("md", """## Random runs

The same comparison on random walks (`onlinemap compare` runs it from the command line): a
10-cell corridor and a 3 x 3 grid, static and with labels that change (p_change = 0.02), against
exact Bayes. Mean distance to exact over runs and steps, per estimator and rbpf scheme: `rbpf FC`
is the default (optimal proposal, Fearnhead-Clifford resampling), `rbpf optimal+residual` samples
the same proposal with residual resampling, `rbpf transition+residual` samples the motion model.
The second figure puts the distance against the milliseconds per step."""),
    ("code", """per_step = compare.accuracy_study(compare.DEFAULT_WORLDS, n_runs=N_RUNS, n_steps=N_STEPS,
                                  particles=(10, 100, 1000), progress=False)
summary = compare.summarise(per_step)
display(compare.error_vs_particles_figure(summary))
display(compare.error_vs_time_figure(summary))
display(compare.error_over_time_figure(per_step))
summary.pivot(index="estimator", columns="world", values="mean_map_tv").round(4)"""),
    ("md", """## Conclusion

* **The RBPF tracks exact Bayes, and more particles bring it closer.** On the scripted corridor
  the default (Fearnhead-Clifford) is 0.018 from exact in mean map distance with 10 particles,
  0.00057 with 100 and 0.000005 with 1000: the run has few plausible trajectories, and it keeps
  each of them at most once. Sampling with the optimal proposal and residual resampling gives
  0.043, 0.015 and 0.0056. BK stays at 0.069, 120 times the error of 100 default particles:
  after the slip, *where the robot is* and *what the map says* depend on each other, and a
  product of marginals cannot hold that dependence.
* **Among the sampling schemes, the optimal proposal pays off with few particles** (0.043
  against 0.068 for the transition proposal at 10 particles); from about 300 particles on the
  two are alike. Here its effective sample size is higher (190 against 173 of 200 particles).
* **On random walks** (10 runs of 60 steps per world) 100 default particles are 1.9 to 3.9 times
  closer to exact than BK in every world, static or changing (the transition proposal with
  residual resampling: 1.0 to 1.35 times), and 1000 particles closer still. BK is about as close
  as a 10-particle filter there, because walks that revisit cells repair the correlation it
  drops; online EM and dead reckoning are 3 to 7 times further from exact than BK.

So: `rbpf` with 100 particles and its defaults is the estimator to reach for when exact Bayes is
too large; BK is a cheap baseline that fails precisely when the robot must use the map
to find out where it is."""),
]


def build() -> nbformat.NotebookNode:
    return notebook(CELLS)


if __name__ == "__main__":
    write(build(), "rbpf_vs_bk.ipynb")
