"""``onlinemap bench exact``: ms per exact filter step on binary corridors of 12, 16 and 20
cells, static and dynamic, against one read+write pass over an array of the belief's size.
Targets: static <= 3 passes, dynamic <= N + 3 passes."""

from __future__ import annotations

from itertools import cycle

from ..estimators import make_estimator
from ..model import corridor
from ..simulate import random_walk, simulate
from . import benchmark, copy_pass_ms, seconds_per_call


@benchmark("exact")
def bench_exact(quick: bool) -> list[dict]:
    rows = []
    for n in (8, 12) if quick else (12, 16, 20):
        reference = copy_pass_ms(n * 2**n)
        for p_change in (0.0, 0.01):
            model = corridor(n, p_change=p_change)
            run = simulate(model, None, random_walk(model, 200, seed=1), seed=2)
            estimator = make_estimator("exact", model)
            steps = cycle(zip(run.actions, run.observations[1:]))  # p_obs < 1: no observation is impossible
            estimator.step(None, run.observations[0])  # compiles the kernels
            for _ in range(3):  # touches both buffers
                estimator.step(*next(steps))

            def one_step():
                estimator.step(*next(steps))

            ms = 1e3 * seconds_per_call(one_step, min_seconds=0.5, max_calls=200 if n < 20 else 20)
            kind = "static" if p_change == 0 else "dynamic"
            rows.append({"case": f"corridor:{n} {kind}", "ms": ms, "reference": "copy of N*2^N floats",
                         "reference_ms": reference,
                         "target": 3.0 if p_change == 0 else n + 3.0})
    return rows
