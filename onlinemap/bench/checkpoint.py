"""``onlinemap bench checkpoint``: ms to save and to load a checkpoint (``om.save``, ``om.load``)
as a ratio to one step of the estimator: how many steps one checkpoint costs, to choose
``track --every K`` (a ratio of R costs R / K of the run time). For small states a fixed cost
(file creation, fsync, JSON) dominates; for large ones, the SHA-256 and the write of every byte."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from .. import checkpoint
from ..estimators import load, make_estimator
from ..model import corridor, door_world
from ..simulate import random_walk, simulate
from . import benchmark, copy_pass_ms, seconds_per_call


def _state_floats(est) -> int:
    """Number of 8-byte words in the arrays of ``est.state_dict()``."""
    total = 0

    def walk(node):
        nonlocal total
        if isinstance(node, np.ndarray):
            total += node.nbytes
        elif isinstance(node, (list, dict)):
            for value in node if isinstance(node, list) else node.values():
                walk(value)

    walk(est.state_dict())
    return max(1, total // 8)


@benchmark("checkpoint")
def bench_checkpoint(quick: bool) -> list[dict]:
    """Save and load ms, as a ratio to one step of the estimator (informational: no target);
    ``state_MB`` and ``copy_passes`` (ms over one copy of the state's arrays) give the scale."""
    if quick:
        cases = [("exact corridor:8", corridor(8), "exact", {}),
                 ("rbpf 100 corridor:64", corridor(64, p_change=0.01), "rbpf", {"n_particles": 100, "seed": 0})]
    else:
        door = door_world(p_door=0.01)[0]
        cases = [("exact corridor:16", corridor(16), "exact", {}),
                 ("rbpf 1000 door 10x10", door, "rbpf", {"n_particles": 1000, "seed": 0}),
                 ("bk door 10x10", door, "bk", {})]
    rows = []
    with tempfile.TemporaryDirectory() as directory:
        path = Path(directory) / "state.npz"
        for case, model, name, options in cases:
            est = make_estimator(name, model, **options)
            run = simulate(model, None, random_walk(model, 400, seed=1), seed=2)
            est.step(None, run.observations[0])
            steps = iter(zip(run.actions, run.observations[1:]))
            step_ms = 1e3 * seconds_per_call(lambda: est.step(*next(steps)), min_seconds=0.1, max_calls=300)
            floats = _state_floats(est)
            copy_ms = copy_pass_ms(floats)
            save_ms = 1e3 * seconds_per_call(lambda: checkpoint.save(est, path), min_seconds=0.2)
            load_ms = 1e3 * seconds_per_call(lambda: load(path), min_seconds=0.2)
            for operation, ms in (("save", save_ms), ("load", load_ms)):
                rows.append({"case": f"{operation} {case}", "ms": ms, "reference": "one step of the estimator",
                             "reference_ms": step_ms, "target": float("nan"),
                             "state_MB": 8 * floats / 1e6, "copy_passes": ms / copy_ms})
    return rows
