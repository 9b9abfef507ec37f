"""What exact Bayes believes after a few presses into an unmapped, featureless stretch.

A robot starts at the west end of an unmapped corridor (1 cell wide) or of an open room, blocking
walls, cross footprint, ``p_move`` 0.8, and presses east T times. Every reading it gets is the same
whether a press moved it or not, so only the label prior says which: a re-read cell is read as
before (0.9), a new one as the prior predicts it. Under independent labels a new corridor cell
matching "wall, wall, free" is a surprise, so the posterior leans to "the robot stayed". This script
measures that lean on exact posteriors (Fearnhead-Clifford with P >= 2^(T+1) particles keeps every
child: exact Bayes), against the location of a robot told the map
(:func:`onlinemap.run_facts.told_map_location`), over ``--seeds`` seeded runs:

- ``bias``: the posterior mean of the cells moved less the true cells moved (mean +- se);
- ``P(true)`` against ``claimed`` (the mean of sum_i P(i)^2, what the belief expects of itself):
  a gap below 0 is overconfidence, and an exact posterior under the model the world was drawn from
  has none.

Run: ``python examples/slip_bias.py [--seeds 100]`` (a few minutes on one core). The numbers are in
the user guide's Results page ("Why exact Bayes loses the robot in corridors").
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from onlinemap.estimators import make_estimator, run_estimator
from onlinemap.run_facts import told_map_location
from onlinemap.worlds import parse_world

FLOORS = {  # MovingAI maps: '@' a wall, '.' free; the robot starts in row 1 (or 3), column 1
    "corridor": (["@" * 16, "@" + "." * 14 + "@", "@" * 16], 17),
    "open room": (["@" * 16] + ["@" + "." * 14 + "@"] * 5 + ["@" * 16], 49),
}
#: label priors compared (free, wall, open door, closed door): the uniform prior, a building's
#: label frequencies (the 32 x 32 generated buildings), the learned frequencies and the context prior
PRIORS = {"uniform": np.full(4, 0.25), "building frequencies": np.array([0.56, 0.39, 0.04, 0.01]),
          "learn": "learn", "context": "context"}
EAST = 1


def measure(spec: str, presses: int, prior, seeds: int) -> np.ndarray:
    """(seeds, 5) per run: cells moved, posterior mean of the cells moved, P(true cell), sum P^2,
    and the told-map robot's P(true cell) and sum P^2, after ``presses`` presses east."""
    world = parse_world(spec)
    model = world.model
    cols = np.arange(model.n_cells) % model.cols
    rows = []
    for seed in range(seeds):
        run = world.simulate(presses + 1, seed=seed, walk=lambda _model, n, _rng: np.full(n, EAST))
        rbpf = make_estimator("rbpf", model, n_particles=2 ** (presses + 1), label_prior=prior, seed=seed)
        belief = run_estimator(rbpf, run.actions, run.observations).location[-1]
        told = told_map_location(model, run)[-1]
        true = run.locations[-1]
        rows.append((cols[true], belief @ cols, belief[true], belief @ belief, told[true], told @ told))
    return np.array(rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=100)
    parser.add_argument("--presses", type=int, nargs="+", default=[4, 8])
    args = parser.parse_args()
    se = lambda x: x.std(ddof=1) / np.sqrt(len(x))  # noqa: E731
    print("| floor | presses | prior | bias, cells | P(true) | claimed | gap | told the map: P(true) / claimed |")
    print("|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as folder:
        for floor, (lines, start) in FLOORS.items():
            path = Path(folder) / f"{floor.replace(' ', '_')}.map"
            path.write_text(f"type octile\nheight {len(lines)}\nwidth {len(lines[0])}\nmap\n" + "\n".join(lines) + "\n")
            for presses in args.presses:
                for name, prior in PRIORS.items():
                    r = measure(f"layout:{path},start={start}", presses, prior, args.seeds)
                    bias, gap = r[:, 1] - r[:, 0], r[:, 2] - r[:, 3]
                    print(f"| {floor} | {presses} | {name} | {bias.mean():+.2f} +- {se(bias):.2f} | {r[:, 2].mean():.3f} | "
                          f"{r[:, 3].mean():.3f} | {gap.mean():+.3f} +- {se(gap):.3f} | "
                          f"{r[:, 4].mean():.3f} / {r[:, 5].mean():.3f} |", flush=True)


if __name__ == "__main__":
    main()
