"""``onlinemap bench em``: the EM estimators' E-step (sparse forward-backward, numba) against one
read+write pass over an array of the window's size (W x N floats).

Cases: an online EM step with a full window W (forward-backward over W steps, counts, M-step,
map read-off) and one Baum-Welch iteration over T steps, on a 1000-cell corridor and a 30 x 30
grid. Per element and step the forward-backward kernel makes about 20 loads and stores (motion
gather, emission, normalisation, backward message, posterior) where a copy makes 2, and its
gathers follow the motion graph: the target is 25 copy passes. Quick sizes are dominated by the
fixed Python cost of a step (about 0.1 ms) and have no target."""

from __future__ import annotations

import math

from ..estimators import make_estimator
from ..hmm import emission_from_counts, expected_counts, forward_backward, prior_emission
from ..model import grid_model
from ..simulate import random_walk, simulate
from . import benchmark, copy_pass_ms, seconds_per_call

TARGET_PASSES = 25.0


@benchmark("em")
def bench_em(quick: bool) -> list[dict]:
    rows = []
    shapes = ((1, 200), (10, 10)) if quick else ((1, 1000), (30, 30))
    window, steps = (16, 64) if quick else (64, 400)
    for n_rows, n_cols in shapes:
        model = grid_model(n_rows, n_cols, 2)
        run = simulate(model, None, random_walk(model, steps - 1, seed=1), seed=2)
        n = model.n_cells
        estimator = make_estimator("online_em", model, window=window)
        for t in range(window):  # fill the window (and compile)
            estimator.step(None if t == 0 else run.actions[t - 1], run.observations[t])
        remaining = iter(zip(run.actions[window - 1:], run.observations[window:]))

        def online_step():
            estimator.step(*next(remaining))

        ms = 1e3 * seconds_per_call(online_step, min_seconds=0.3, max_calls=steps - window)
        reference = copy_pass_ms(window * n)
        rows.append({"case": f"online_em step {n_rows}x{n_cols} W={window}", "ms": ms,
                     "reference": "copy of W*N floats", "reference_ms": reference,
                     "target": math.nan if quick else TARGET_PASSES})

        prior, fallback = model.location_prior(), prior_emission(model)

        buffers = forward_backward(model, prior, run.actions, run.observations, fallback)

        def baum_welch_iteration():  # as in offline_em.baum_welch: buffers reused across iterations
            fit = forward_backward(model, prior, run.actions, run.observations, fallback, out=buffers)
            emission_from_counts(expected_counts(fit.posterior, run.observations, 2), 0.1, fallback)

        ms = 1e3 * seconds_per_call(baum_welch_iteration, min_seconds=0.3)
        reference = copy_pass_ms(steps * n)
        rows.append({"case": f"Baum-Welch iteration {n_rows}x{n_cols} T={steps}", "ms": ms,
                     "reference": "copy of T*N floats", "reference_ms": reference,
                     "target": math.nan if quick else TARGET_PASSES})
    return rows
