"""Registered estimators and worlds small enough for each, for tests generic over the registry.

Tests parametrise over :func:`onlinemap.available_estimators` at collection time, so an
estimator is covered as soon as it is registered. ``exact`` gets tiny worlds (its belief is
N x K^N); every other estimator gets small ones. Every estimator is built with its defaults.
"""

from __future__ import annotations

import numba
import numpy as np
import pytest

import onlinemap as om
from onlinemap.model import symmetric_channel
from onlinemap.simulate import world_step

NAMES = om.available_estimators()

# options that make the cheap estimators cheap (only those that exist are used)
CHEAP = {"dead_reckoning": {}, "bk": {}, "rbpf": {"n_particles": 100, "seed": 0}, "online_em": {"window": 4}}
CHEAP_NAMES = tuple(name for name in CHEAP if name in NAMES)


def small_worlds(name: str) -> list[tuple[str, om.GridModel]]:
    """(id, model) pairs, one static and one dynamic, small enough for ``name``."""
    if name == "exact":
        return [("corridor4", om.corridor(4)),
                ("grid2x2-K2-dynamic", om.grid_model(2, 2, 2, change=symmetric_channel(2, 0.95)))]
    return [("corridor8", om.corridor(8)),
            ("grid3x3-K3-dynamic", om.grid_model(3, 3, 3, change=symmetric_channel(3, 0.95)))]


def cases() -> list[tuple[str, str, om.GridModel]]:
    return [(name, world_id, model) for name in NAMES for world_id, model in small_worlds(name)]


def random_run(model: om.GridModel, n_steps: int, seed: int) -> om.Run:
    rng = np.random.default_rng(seed)
    return om.simulate(model, None, om.random_walk(model, n_steps - 1, rng), rng)


def beliefs(est, run: om.Run, start: int = 0, stop: int | None = None):
    """Step ``est`` through steps ``start .. stop - 1`` of ``run`` (all by default), yielding each belief."""
    for t in range(start, run.n_steps if stop is None else stop):
        z = run.observations[t]
        yield est.step(None if t == 0 else int(run.actions[t - 1]), int(z) if z.ndim == 0 else z)


def exact_trajectory(run: om.Run) -> om.Trajectory:
    """The exact filter's trajectory over ``run``."""
    return om.run_estimator(om.make_estimator("exact", run.model), run.actions, run.observations)


def binomial_ok(successes, trials, p, z=4.5):
    """|observed - expected| within z standard deviations of a binomial(trials, p)."""
    return abs(successes - trials * p) <= z * np.sqrt(trials * p * (1 - p))


def stream(model: om.GridModel, true_map, n_steps: int, seed: int):
    """Yield ``(t, action or None, observation)`` of a simulated run without storing it (O(N) memory)."""
    rng = np.random.default_rng(seed)
    location, labels = model.start, np.asarray(true_map)
    for t in range(n_steps):
        action = None if t == 0 else int(rng.integers(model.n_actions))
        location, labels, z = world_step(model, location, labels, action, rng)
        yield t, action, z


def assert_valid_belief(belief: om.Belief, model: om.GridModel, t: int, atol: float = 1e-9) -> None:
    """Finite, in [0, 1], summing to 1 within ``atol``; right shapes and step index."""
    n, k = model.n_cells, model.n_labels
    assert belief.t == t
    assert belief.location.shape == (n,) and belief.map.shape == (n, k)
    for what, p in (("location", belief.location), ("map", belief.map)):
        assert np.all(np.isfinite(p)), f"{what} has NaN or infinite entries at t={t}"
        assert np.all(p >= 0), f"{what} has negative entries at t={t}: {p.min()}"
        assert np.all(p <= 1), f"{what} has entries above 1 at t={t}: {p.max() - 1} too much"
        sums = p.sum(axis=-1)
        assert np.all(np.abs(sums - 1) <= atol), f"{what} sums to {sums} at t={t}"
    assert not belief.log_evidence > 1e-9, f"log evidence {belief.log_evidence} > 0 at t={t}"


def snapshot(est) -> dict:
    """Every attribute of an estimator, arrays copied, the random generator by its state; the
    ``scratch_attributes`` (buffers every step overwrites, not state) only by dtype and shape."""
    scratch = set(getattr(type(est), "scratch_attributes", ()))
    return {name: ((value.dtype, value.shape) if name in scratch else
                   value.copy() if isinstance(value, np.ndarray) else
                   value.bit_generator.state if isinstance(value, np.random.Generator) else value)
            for name, value in vars(est).items()}


def assert_state_unchanged(est, before: dict) -> None:
    """The estimator's attributes equal the :func:`snapshot` taken before (arrays bit for bit)."""
    now = snapshot(est)
    assert now.keys() == before.keys()
    for name, value in before.items():
        if isinstance(value, np.ndarray):
            np.testing.assert_array_equal(now[name], value, err_msg=name)
        else:
            assert now[name] is value or now[name] == value, name


#: the RBPF's ``threads`` for tests run both ways: its serial kernels and its parallel ones (these
#: skipped where numba runs one thread); see :func:`small_chunks`
RBPF_THREADS = [1, pytest.param(2, marks=pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2,
                                                             reason="numba runs one thread here"))]


def small_chunks(monkeypatch, size: int = 16) -> None:
    """Make the RBPF's parallel kernels work in chunks of ``size`` particles, so that a test with a
    few hundred particles spans many chunks."""
    from onlinemap.kernels import rbpf_parallel

    monkeypatch.setattr(rbpf_parallel, "CHUNK", size)


def dead_pid() -> int:
    """The id of a process that has ended (a child run to its end and reaped)."""
    import subprocess
    import sys

    child = subprocess.Popen([sys.executable, "-c", "pass"])
    child.wait()
    return child.pid


def resumed_bit_for_bit(make, run: om.Run, path, stop: int):
    """Two filters ``make()``: one run straight through ``run``, one to ``stop``, saved to ``path``
    and loaded; the loaded one's beliefs from ``stop`` on equal the straight one's bit for bit.
    Returns (loaded at the end, saved at ``stop``, straight)."""
    straight, est = make(), make()
    expected = list(beliefs(straight, run))
    for _ in beliefs(est, run, stop=stop):
        pass
    om.save(est, path)
    resumed = om.load(path)
    for got, want in zip(beliefs(resumed, run, start=stop), expected[stop:]):
        np.testing.assert_array_equal(got.map, want.map)
        np.testing.assert_array_equal(got.location, want.location)
        assert got.log_evidence == want.log_evidence
    return resumed, est, straight


def assert_corruption_refused(est, run: om.Run, corrupt, name: str) -> None:
    """Step ``est`` through ``run``: its state passes its checks; after ``corrupt(est)`` the checks
    raise :class:`~onlinemap.errors.CheckpointError` naming ``name``."""
    from onlinemap.errors import CheckpointError

    for _ in beliefs(est, run):
        pass
    type(est).check_state(est)  # the good state passes
    corrupt(est)
    with pytest.raises(CheckpointError, match=name):
        type(est).check_state(est)


def map_given_path(model: om.GridModel, path, actions, readings, tilt) -> np.ndarray:
    """(N, K) the exact map of a static world given a path: ``normalise(label_prior * tilt * prod f)``
    over the path's readings ``readings`` (T, F) and, with blocking labels, its presses (entered:
    ``[k passable]``; stayed: ``1 - p_move [k passable]``), written out here from the model's
    scalar tables step by step; ``tilt`` (K,) or (N, K)."""
    blocks = np.zeros(model.n_labels, bool) if model.blocking is None else np.asarray(model.blocking)
    expected = model.label_prior * tilt
    for u, location in enumerate(path):
        if u:
            here = path[u - 1]
            target = int(model.neighbors[here, int(actions[u - 1])])
            if target != here:
                expected[target] *= ~blocks if location == target else (1 - model.p_move) + model.p_move * blocks
        for cell, z in zip(model.footprint_cells[location], readings[u]):
            if cell >= 0:
                expected[cell] *= model.sensor[:, z]
        expected /= expected.sum(axis=1, keepdims=True)
    return expected
