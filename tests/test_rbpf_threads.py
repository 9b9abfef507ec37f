"""The RBPF's ``threads`` option (issue 25): its threaded drivers (``onlinemap/kernels/rbpf_parallel.py``)
give the serial kernels' result bit for bit, beliefs and the whole state, for every resampling
scheme, static and dynamic worlds, blocking labels and sensor footprints; the chunks are made
small here so that a run spans many of them and the children of one chunk are moved behind
another's. (Fearnhead-Clifford's exactness with threads is tested beside the serial case in
test_rbpf.py and test_rbpf_blocking_footprint.py.)"""

import dataclasses
import time

import numba
import numpy as np
import pytest

import onlinemap as om
from estimator_cases import random_run
from onlinemap.kernels import rbpf_parallel

needs_two_threads = pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2,
                                       reason="numba runs one thread here (NUMBA_NUM_THREADS=1)")

WORLDS = {
    "door static": lambda: om.door_world()[0],
    "door dynamic": lambda: om.door_world(p_door=0.05)[0],
    "blocking static": lambda: om.door_world(blocking=True)[0],
    "blocking+cross dynamic": lambda: om.door_world(p_door=0.05, blocking=True, footprint="cross")[0],
    "corridor K=3 dynamic": lambda: om.corridor(12, 3, p_change=0.05),
}
SCHEMES = {"fearnhead_clifford": {}, "optimal+residual": dict(resampling="residual"),
           "transition+systematic": dict(proposal="transition", resampling="systematic", resample_threshold=1.0)}


def assert_same_state(a, b):
    """Two RBPFs' states equal bit for bit: particles, weights, evidence, generator, block pool."""
    for name in ("_locations", "_log_weights", "_weights"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert a._log_evidence == b._log_evidence and a._ess == b._ess
    assert a._rng.bit_generator.state == b._rng.bit_generator.state
    for field in dataclasses.fields(a._blocks):
        np.testing.assert_array_equal(getattr(a._blocks, field.name), getattr(b._blocks, field.name),
                                      err_msg=field.name)


@needs_two_threads
@pytest.mark.parametrize("n_particles", [40, 700])
@pytest.mark.parametrize("scheme", SCHEMES)
@pytest.mark.parametrize("world", WORLDS)
def test_two_threads_give_the_serial_result_bit_for_bit(world, scheme, n_particles, monkeypatch):
    """60 steps of a random walk (the map drawn from the prior, so blocking walls are anywhere);
    every belief and, at the end, the whole state equal. A step the particles cannot explain
    (depletion, possible with 40 sampled particles and off-grid readings) is recovered from by both
    alike; one the model rules out must be refused by both."""
    monkeypatch.setattr(rbpf_parallel, "CHUNK", 16)
    model = WORLDS[world]()
    run = random_run(model, 60, seed=8)
    serial, threaded = (om.make_estimator("rbpf", model, n_particles=n_particles, seed=3, threads=threads,
                                          **SCHEMES[scheme]) for threads in (1, 2))
    for t in range(run.n_steps):
        z = run.observations[t]
        args = (None if t == 0 else int(run.actions[t - 1]), int(z) if z.ndim == 0 else z)
        try:
            a = serial.step(*args)
        except om.ImpossibleObservationError:
            with pytest.raises(om.ImpossibleObservationError):
                threaded.step(*args)
            break
        b = threaded.step(*args)
        np.testing.assert_array_equal(a.location, b.location)
        np.testing.assert_array_equal(a.map, b.map)
        assert a.log_evidence == b.log_evidence and a.effective_sample_size == b.effective_sample_size
        assert a.recovered == b.recovered
    assert_same_state(serial, threaded)
    assert t > 20


@needs_two_threads
@pytest.mark.parametrize(("scheme", "n_particles"), [("fearnhead_clifford", 5), ("transition+residual", 5),
                                                     ("transition+residual", 20)])
def test_a_recovering_run_gives_the_serial_result_bit_for_bit(scheme, n_particles, monkeypatch):
    """Recovery from depletion with threads: its relocated children carry their own cells (a reset
    cell, or one read from a cell the parent never stood at, does not follow from the parent's map
    at the child's location) and go through the parallel commit as given. The depleting run of
    test_rbpf_recovery (100 steps of the blocking + cross door world, seed 38), chunks of 2
    particles so that every step runs the parallel kernels (each step commits once through
    rbpf_commit_staged_parallel, counted): every belief, its recovered flag, the recovery count
    and the final state equal the serial run's, and the run recovers at least once."""
    monkeypatch.setattr(rbpf_parallel, "CHUNK", 2)
    commits = []
    staged = rbpf_parallel.rbpf_commit_staged_parallel
    monkeypatch.setattr(rbpf_parallel, "rbpf_commit_staged_parallel", lambda *args: commits.append(1) or staged(*args))
    model, true_map = om.door_world(blocking=True, footprint="cross")
    run = om.simulate(model, true_map, steps=100, seed=38)
    options = {"fearnhead_clifford": {}, "transition+residual": dict(proposal="transition", resampling="residual")}
    serial, threaded = (om.make_estimator("rbpf", model, n_particles=n_particles, seed=38, threads=threads,
                                          **options[scheme]) for threads in (1, 2))
    for t in range(run.n_steps):
        args = (None if t == 0 else int(run.actions[t - 1]), run.observations[t])
        a, b = serial.step(*args), threaded.step(*args)
        np.testing.assert_array_equal(a.location, b.location)
        np.testing.assert_array_equal(a.map, b.map)
        assert a.log_evidence == b.log_evidence and a.recovered == b.recovered
    assert len(commits) == run.n_steps
    assert threaded.recoveries == serial.recoveries >= 1
    assert_same_state(serial, threaded)


@needs_two_threads
def test_the_number_of_threads_and_the_chunks_do_not_matter(monkeypatch):
    """The result depends on neither the number of threads nor the chunk size (chunks of 1 to 100
    particles; from one chunk of P or more the serial kernels run), at 2000 particles on the
    dynamic door world."""
    model = om.door_world(p_door=0.05)[0]
    run = random_run(model, 30, seed=2)
    finals = []
    for threads, chunk in ((1, rbpf_parallel.CHUNK), (2, 1), (2, 100), (2, 5000), (None, 64)):
        monkeypatch.setattr(rbpf_parallel, "CHUNK", chunk)
        est = om.make_estimator("rbpf", model, n_particles=2000, seed=4, threads=threads)
        for t in range(run.n_steps):
            belief = est.step(None if t == 0 else int(run.actions[t - 1]), int(run.observations[t]))
        finals.append((belief, est))
    for belief, est in finals[1:]:
        np.testing.assert_array_equal(belief.map, finals[0][0].map)
        np.testing.assert_array_equal(belief.location, finals[0][0].location)
        assert_same_state(est, finals[0][1])


def test_threads_option():
    """``threads`` is 1 to NUMBA_NUM_THREADS (None: all of them); other values are refused with a
    message naming the option and the environment variable that sets the limit."""
    model = om.corridor(4)
    most = numba.config.NUMBA_NUM_THREADS
    assert om.make_estimator("rbpf", model).threads == 1
    assert om.make_estimator("rbpf", model, threads=None).threads == most
    for bad in (0, -1, most + 1, 1.5, "2", True):
        with pytest.raises(om.InvalidOptionError, match="threads.*NUMBA_NUM_THREADS"):
            om.make_estimator("rbpf", model, threads=bad)


def test_an_exception_in_a_thread_reaches_the_caller_once_every_run_has_finished():
    """A run that raises, on the pool's thread or the caller's, raises in the caller, and only
    after the other runs have finished (none still writes into the filter's arrays)."""
    finished = []

    def slow():
        time.sleep(0.2)
        finished.append(True)

    def fails():
        raise ZeroDivisionError("in a run")

    with pytest.raises(ZeroDivisionError, match="in a run"):
        rbpf_parallel.in_threads([lambda: None, fails])
    with pytest.raises(ZeroDivisionError, match="in a run"):
        rbpf_parallel.in_threads([fails, slow])
    assert finished == [True]
    assert rbpf_parallel.in_threads([lambda: 1, lambda: 2, lambda: 3]) == [1, 2, 3]


def test_no_kernel_compiles_with_numba_parallel():
    """The threads are Python threads on ``nogil`` kernels: no kernel of ``onlinemap.kernels`` is
    ``parallel=True`` (numba's parallel kernels took a minute to compile on a fresh clone)."""
    import importlib
    import pkgutil

    import onlinemap.kernels as kernels

    dispatchers = [value for info in pkgutil.iter_modules(kernels.__path__)
                   for value in vars(importlib.import_module(f"onlinemap.kernels.{info.name}")).values()
                   if isinstance(value, numba.core.registry.CPUDispatcher)]
    assert len(dispatchers) > 50
    assert not [d.py_func.__qualname__ for d in dispatchers if d.targetoptions.get("parallel")]
    threaded = {rbpf_parallel.enumerate_run, rbpf_parallel.enumerate_cells_run, rbpf_parallel.propose_run,
                rbpf_parallel.stage_children, rbpf_parallel.stage_children_cells, rbpf_parallel.copy_planned,
                rbpf_parallel.write_planned, rbpf_parallel.row_weights, rbpf_parallel.mixture_blocks}
    assert all(kernel.targetoptions.get("nogil") for kernel in threaded)
