"""The RBPF's resample-move step (options ``move_window``, ``move_every``, ``move_lag``; issue 21
item 2): a filter holding the exact posterior is not moved (with room for every child it stays
exact Bayes, bit for bit the filter without moves); the Metropolis-Hastings move leaves the
posterior over paths invariant (a chi-square test against a brute-force path posterior written
here with itertools.product) and leaves each particle's map the exact map given its new path;
refusals name the option; checkpoints resume bit for bit and a format-3 checkpoint still loads;
``est.moves`` counts the windows; the memory guard counts the path history; threads give the same
results."""

import copy
import itertools
import math
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

import onlinemap as om
from onlinemap import checkpoint
from onlinemap.estimators.rbpf_move import MAX_WINDOW
from estimator_cases import RBPF_THREADS, beliefs, exact_trajectory, random_run, small_chunks
from oracles import footprint_reads, grid_targets

DATA = Path(__file__).parent / "data"
PAIR = ((0, 0), (0, 1))  # a footprint reading the robot's cell and the one east of it
SENSOR = np.array([[0.8, 0.2], [0.25, 0.75]])  # no zero entry (the move divides readings out)
PRIOR_6 = np.array([[0.5, 0.5], [0.3, 0.7], [0.6, 0.4], [0.45, 0.55], [0.7, 0.3], [0.2, 0.8]])
AGGRESSIVE = dict(move_window=2, move_every=1, move_lag=0)  # a move at every step, windows up to t


def footprint_world() -> om.GridModel:
    """A corridor of 6 cells with a footprint of two cells (its own, the next east), an asymmetric
    sensor and a per-cell prior (static, no blocking). Off-grid readings tell only the east end
    apart (a 2D grid's edges pin the location down too often for many paths to live)."""
    return om.grid_model(1, 6, 2, p_move=0.7, sensor=SENSOR, label_prior=PRIOR_6, footprint=PAIR)


def path_posterior(rows: int, cols: int, p_move: float, sensor, prior, offsets, start: int, actions,
                   observations) -> dict[tuple, float]:
    """The exact posterior over paths ``x_0..x_T-1`` (the maps summed out) of a static world with
    a footprint and no blocking, by brute force: every stay/move choice per step
    (itertools.product), weighted by the motion and by ``prod_c sum_k prior[c, k] prod O[k, z]``
    over the readings of each cell (an offset off the grid reads -1 with probability 1)."""
    targets, reads = grid_targets(rows, cols), footprint_reads(rows, cols, offsets)
    readings = np.asarray(observations).reshape(len(observations), -1)
    posterior: dict[tuple, float] = {}
    for moved in itertools.product((False, True), repeat=len(actions)):
        path, weight = [start], 1.0
        for a, move in zip(actions, moved):
            target = targets[a, path[-1]]
            if target < 0:
                weight *= 0.0 if move else 1.0
                path.append(path[-1])
            else:
                weight *= p_move if move else 1 - p_move
                path.append(target if move else path[-1])
        seen = [np.ones(prior.shape[1]) for _ in range(len(prior))]
        for l, z in zip(path, readings):
            for cell, reading in zip(reads[l], z):
                if cell is None:
                    weight *= float(reading == -1)
                elif reading < 0:
                    weight = 0.0
                else:
                    seen[cell] = seen[cell] * sensor[:, reading]
        weight *= math.prod(float(prior[c] @ seen[c]) for c in range(len(prior)))
        if weight > 0:
            posterior[tuple(path)] = posterior.get(tuple(path), 0.0) + weight
    total = sum(posterior.values())
    return {path: weight / total for path, weight in posterior.items()}


def map_given_path(path, observations, rows: int, cols: int, sensor, prior, offsets) -> np.ndarray:
    """(N, K) the exact map marginals given a path: ``prior x prod O[:, z]`` per cell, normalised."""
    reads = footprint_reads(rows, cols, offsets)
    out = np.array(prior, dtype=float)
    for l, z in zip(path, np.asarray(observations).reshape(len(observations), -1)):
        for cell, reading in zip(reads[l], z):
            if cell is not None:
                out[cell] = out[cell] * sensor[:, reading]
    return out / out.sum(axis=1, keepdims=True)


def steps_of(run: om.Run) -> list:
    """(action or None, observation) of every step of ``run``."""
    return [(None if t == 0 else int(run.actions[t - 1]),
             int(run.observations[t]) if run.observations[t].ndim == 0 else run.observations[t])
            for t in range(run.n_steps)]


# --- (a) a filter that holds the exact posterior is not moved ------------------------------------------
EXACT_WORLDS = [
    ("corridor6", lambda: om.corridor(6, 2, p_obs=0.85, p_move=0.7)),
    ("corridor6 footprint", footprint_world),
]


@pytest.mark.parametrize("name,make", EXACT_WORLDS, ids=[w[0] for w in EXACT_WORLDS])
def test_with_room_for_every_child_the_moving_filter_is_exact_bayes(name, make):
    """9 steps have at most 2^8 = 256 trajectories: Fearnhead-Clifford with 256 particles drops no
    child and holds the exact posterior over paths. The exact invariant of the option: moves wait
    until the filter has dropped a child (a move would only add Monte-Carlo noise to an exact
    mixture), so with a move due at every step the filter equals exact Bayes to 1e-12, makes no
    move, and is bit for bit the filter without moves (its random draws included)."""
    model = make()
    run = random_run(model, 9, seed=6)
    exact = exact_trajectory(run)
    moving = om.make_estimator("rbpf", model, n_particles=256, seed=0, **AGGRESSIVE)
    plain = om.make_estimator("rbpf", model, n_particles=256, seed=0)
    for t, (belief, reference) in enumerate(zip(beliefs(moving, run), beliefs(plain, run))):
        np.testing.assert_allclose(belief.location, exact.location[t], atol=1e-12, rtol=0)
        np.testing.assert_allclose(belief.map, exact.map[t], atol=1e-12, rtol=0)
        assert belief.log_evidence == pytest.approx(exact.log_evidence[t], abs=1e-12)
        np.testing.assert_array_equal(belief.map, reference.map)
        np.testing.assert_array_equal(belief.location, reference.location)
        assert not moving.resampled
    assert moving.moves == (0, 0) and np.count_nonzero(moving.weights) >= 16
    assert moving._rng.bit_generator.state == plain._rng.bit_generator.state


def test_the_path_history_holds_the_exact_path_posterior():
    """Each live particle's recorded path, with its weight, is the brute-force posterior over
    paths (the history the move reads: every path once, to 1e-12)."""
    model = footprint_world()
    run = random_run(model, 9, seed=5)
    est = om.make_estimator("rbpf", model, n_particles=256, seed=0, **AGGRESSIVE)
    for step in steps_of(run):
        est.update(*step)
    exact = path_posterior(1, 6, 0.7, SENSOR, PRIOR_6, PAIR, 0, run.actions, run.observations)
    paths = est._history.paths(est.t)
    live = est.weights > 0
    got = {tuple(path): weight for path, weight in zip(paths[live].tolist(), est.weights[live])}
    assert got.keys() == exact.keys() and len(got) == np.count_nonzero(live)
    np.testing.assert_allclose([got[p] for p in exact], list(exact.values()), atol=1e-12, rtol=0)


# --- (b) the move leaves the posterior over paths invariant ---------------------------------------------
@pytest.mark.parametrize("window", [3, 8], ids=["window 3", "whole path"])
def test_the_move_leaves_the_path_posterior_invariant(window):
    """Start from the exact weighted set of paths (Fearnhead-Clifford with room for every child,
    checked against the brute force above), draw n = 20,000 particles i.i.d. from it, move each
    once (windows of ``window`` steps anywhere in the 9-step past, ``move_lag`` 0, so some end at
    t): if the Metropolis-Hastings kernel K leaves the posterior pi invariant, the moved paths are
    n i.i.d. draws from ``sum_i pi_i K(i, .) = pi``. Pearson's chi-square against the brute-force
    pi, over the paths whose expected count n pi is at least 5 plus one bin for the rest, then
    follows a chi-square law with (bins - 1) degrees of freedom up to O(1 / n); the test fails
    when its upper tail is below 1e-3 (the false-failure rate). The window of 8 redraws the whole
    path but its start, where the corridor and the footprint make the path read cells it read
    before (the acceptance ratio's revisits). Each moved particle's map must also be the
    exact map given its new path (to 1e-12), and the moves must change many paths."""
    model = footprint_world()
    run = random_run(model, 9, seed=5)
    est = om.make_estimator("rbpf", model, n_particles=256, seed=0, move_window=window, move_lag=0)
    for step in steps_of(run):
        est.update(*step)
    t = est.t
    exact = path_posterior(1, 6, 0.7, SENSOR, PRIOR_6, PAIR, 0, run.actions, run.observations)
    rng = np.random.default_rng(11)
    n = 20_000
    counts = np.bincount(rng.choice(est.n_particles, size=n, p=est.weights), minlength=est.n_particles)
    drawn: dict[tuple, int] = {}
    changed = 0
    for replicate in range(int(counts.max())):
        blocks, history, locations = copy.deepcopy((est._blocks, est._history, est._locations))
        history, blocks = history.move(blocks, locations, est._log_weights, model, t, window, 0,
                                       np.random.default_rng([12, replicate]))
        paths = history.paths(t)
        chosen = np.flatnonzero(counts > replicate)
        before = est._history.paths(t)
        changed += int(np.count_nonzero(np.any(paths[chosen] != before[chosen], axis=1)))
        for i in chosen:
            drawn[tuple(paths[i].tolist())] = drawn.get(tuple(paths[i].tolist()), 0) + 1
        if replicate < 3:  # the maps follow the paths
            maps = blocks.particle_maps(t)
            for i in np.flatnonzero(est.weights > 0):
                expected = map_given_path(paths[i], run.observations, 1, 6, SENSOR, PRIOR_6, PAIR)
                np.testing.assert_allclose(maps[i], expected, atol=1e-12, rtol=0)
            np.testing.assert_array_equal(locations, paths[:, t])
    assert set(drawn) <= set(exact) and sum(drawn.values()) == n
    assert changed > n / 4  # the kernel does move
    big = [p for p in exact if n * exact[p] >= 5]
    observed = [drawn.get(p, 0) for p in big] + [n - sum(drawn.get(p, 0) for p in big)]
    expected = [n * exact[p] for p in big] + [n * (1 - sum(exact[p] for p in big))]
    assert len(big) >= 10
    statistic, p_value = stats.chisquare(observed, expected)
    assert p_value > 1e-3, (statistic, len(big))


# --- (c) refusals --------------------------------------------------------------------------------------
REFUSED_WORLDS = [  # blocking labels and sensors with zeros run: tests/test_rbpf_move_blocking.py
    ("dynamic", lambda: om.corridor(6, p_change=0.05), "static world"),
]


@pytest.mark.parametrize("name,make,reason", REFUSED_WORLDS, ids=[w[0] for w in REFUSED_WORLDS])
def test_worlds_the_move_cannot_handle_are_refused(name, make, reason):
    with pytest.raises(om.InvalidOptionError, match=f"move_window=5: .*{reason}"):
        om.make_estimator("rbpf", make(), move_window=5)
    om.make_estimator("rbpf", make())  # without moves it runs


BAD_OPTIONS = [
    ({"move_window": 0}, "move_window"), ({"move_window": -3}, "move_window"), ({"move_window": 2.5}, "move_window"),
    ({"move_window": "5"}, "move_window"), ({"move_window": True}, "move_window"),
    ({"move_window": MAX_WINDOW + 1}, "move_window"), ({"move_window": 5, "move_every": 0}, "move_every"),
    ({"move_window": 5, "move_every": 1.5}, "move_every"), ({"move_window": 5, "move_lag": -1}, "move_lag"),
    ({"move_lag": "10"}, "move_lag"),
]


@pytest.mark.parametrize("options,name", BAD_OPTIONS, ids=[str(o) for o, _ in BAD_OPTIONS])
def test_bad_option_values_are_named(options, name):
    with pytest.raises(om.InvalidOptionError, match=name):
        om.make_estimator("rbpf", om.corridor(6), **options)


def test_a_refused_step_or_checkpoint_leaves_a_moving_filter_unchanged():
    """A bad observation and a checkpoint written with other move options each raise and leave
    the moving filter (its path history included) bit for bit as it was."""
    model = om.corridor(8, 2, p_obs=0.85, p_move=0.7)
    run = random_run(model, 30, seed=2)
    est = om.make_estimator("rbpf", model, n_particles=20, seed=0, resampling="residual", move_window=3,
                            move_every=2, move_lag=2)
    for step in steps_of(run):
        est.update(*step)
    assert est.moves.proposed > 0
    before = est.state_dict()
    with pytest.raises(om.InvalidObservationError):
        est.update(0, 7)
    assert checkpoint.first_difference(est.state_dict(), before) is None
    other = om.make_estimator("rbpf", model, n_particles=20, seed=0, resampling="residual", move_window=4,
                              move_every=2, move_lag=2)
    for step in steps_of(run)[:3]:
        other.update(*step)
    with pytest.raises(om.CheckpointError, match="options"):
        est.load_state_dict(other.state_dict())
    assert checkpoint.first_difference(est.state_dict(), before) is None


# --- (d) checkpoints -----------------------------------------------------------------------------------
CHECKPOINT_CASES = [
    ("FC door", lambda: om.door_world(p_move=0.8)[0], {}),
    ("residual cross", lambda: om.door_world(p_move=0.8, footprint="cross")[0], {"resampling": "residual"}),
]


@pytest.mark.parametrize("name,make,options", CHECKPOINT_CASES, ids=[c[0] for c in CHECKPOINT_CASES])
def test_a_moving_filter_resumes_from_its_checkpoint_bit_for_bit(name, make, options, tmp_path):
    model = make()
    run = om.simulate(model, None, steps=70, seed=4)
    steps = steps_of(run)
    settings = dict(n_particles=50, seed=9, move_window=6, move_every=3, move_lag=10, **options)
    straight = om.make_estimator("rbpf", model, **settings)
    expected = [straight.step(*args) for args in steps]
    est = om.make_estimator("rbpf", model, **settings)
    for args in steps[:40]:
        est.update(*args)
    assert est.moves.proposed > 0
    om.save(est, tmp_path / "moving.npz")
    resumed = om.load(tmp_path / "moving.npz")
    assert resumed.moves == est.moves and resumed.options == est.options
    for args, belief in zip(steps[40:], expected[40:]):
        got = resumed.step(*args)
        np.testing.assert_array_equal(got.location, belief.location)
        np.testing.assert_array_equal(got.map, belief.map)
        assert got.log_evidence == belief.log_evidence
    assert resumed.moves == straight.moves
    assert checkpoint.first_difference(resumed.state_dict(), straight.state_dict()) is None


def test_a_format_3_checkpoint_loads_and_continues_as_it_did(tmp_path):
    """tests/data/rbpf_format3.npz was written by the filter before the resample-move step
    (checkpoint format 3; ``write_format_3`` below, run with that code): it loads as a filter
    without moves and the next 6 steps equal those the writing filter took
    (tests/data/rbpf_format3_next.npz), to a few ulps across machines (see test_block_pool's
    format-1 test), and bit for bit once saved in the current format and loaded again."""
    state = checkpoint.read(DATA / "rbpf_format3.npz")
    assert state["format_version"] == 3 and "_history" not in state["attributes"]
    est = om.load(DATA / "rbpf_format3.npz")
    assert est.move_window is None and est.moves == (0, 0) and est._history is None
    om.save(est, tmp_path / "current.npz")
    assert checkpoint.read(tmp_path / "current.npz")["format_version"] == checkpoint.FORMAT_VERSION
    twin = om.load(tmp_path / "current.npz")
    expected = np.load(DATA / "rbpf_format3_next.npz")
    for i, t in enumerate(range(10, 16)):
        action, observation = int(expected["actions"][i]), int(expected["observations"][i])
        belief, again = est.step(action, observation), twin.step(action, observation)
        np.testing.assert_allclose(belief.location, expected[f"location{t}"], rtol=1e-13, atol=1e-15)
        np.testing.assert_allclose(belief.map, expected[f"map{t}"], rtol=1e-13, atol=1e-15)
        assert belief.log_evidence == pytest.approx(float(expected[f"evidence{t}"]), rel=1e-13)
        np.testing.assert_array_equal(again.map, belief.map)
        np.testing.assert_array_equal(again.location, belief.location)


def write_format_3(out: Path) -> None:
    """Write tests/data/rbpf_format3*.npz (run with the code of the commit before the
    resample-move step, 381f03a, which writes format 3)."""
    from onlinemap.worlds import parse_world
    world = parse_world("door,p_move=0.8")
    run = world.simulate(16, seed=5)
    est = om.make_estimator("rbpf", world.model, n_particles=30, seed=7)
    for t in range(10):
        est.step(None if t == 0 else int(run.actions[t - 1]), int(run.observations[t]))
    om.save(est, out / "rbpf_format3.npz")
    arrays = {"actions": run.actions[9:15], "observations": run.observations[10:16]}
    for t in range(10, 16):
        belief = est.step(int(run.actions[t - 1]), int(run.observations[t]))
        arrays[f"location{t}"], arrays[f"map{t}"] = belief.location, belief.map
        arrays[f"evidence{t}"] = np.array(belief.log_evidence)
    np.savez(out / "rbpf_format3_next.npz", **arrays)


HISTORY_CORRUPTIONS = [
    ("path end", lambda h, t: h.rows.__setitem__((h.table[0, t // h.rows.shape[1]], t % h.rows.shape[1]),
                                                 (h.rows[h.table[0, t // h.rows.shape[1]], t % h.rows.shape[1]] + 1)
                                                 % 8), "_history.rows"),
    ("refcount", lambda h, t: h.refcount.__setitem__(h.table[0, 0], h.refcount[h.table[0, 0]] + 1),
     "_history.refcount"),
    ("action", lambda h, t: h.actions.__setitem__(1, 5), "_history.actions"),
    ("counts", lambda h, t: setattr(h, "accepted", h.proposed + 1), "_history.accepted"),
]


@pytest.mark.parametrize("name,corrupt,words", HISTORY_CORRUPTIONS, ids=[c[0] for c in HISTORY_CORRUPTIONS])
def test_a_checkpoint_with_a_broken_path_history_is_refused(name, corrupt, words):
    model = om.corridor(8, 2, p_obs=0.85, p_move=0.7)
    run = random_run(model, 20, seed=2)
    settings = dict(n_particles=10, seed=0, resampling="residual", move_window=3, move_every=2, move_lag=2)
    est = om.make_estimator("rbpf", model, **settings)
    for step in steps_of(run):
        est.update(*step)
    broken = copy.deepcopy(est)
    corrupt(broken._history, broken.t)
    fresh = om.make_estimator("rbpf", model, **settings)
    before = fresh.state_dict()
    with pytest.raises(om.CheckpointError, match=words):
        fresh.load_state_dict(broken.state_dict())
    assert checkpoint.first_difference(fresh.state_dict(), before) is None


# --- (e) the counts --------------------------------------------------------------------------------------
def test_moves_counts_every_window_proposed_and_accepted():
    """A sampling scheme is never exact, so a move is due at every step t with ``t % every == 0``
    and a window ending ``lag`` steps back (``t - lag - W >= 0``); each moves every particle
    (weights stay finite: a sensor without zeros). With one particle (which resampling never
    replaces) a step changes its past only by the move: an accepted move counts one, and a move
    that changed the path was accepted."""
    model = om.corridor(8, 2, p_obs=0.85, p_move=0.7)
    run = random_run(model, 60, seed=5)
    window, every, lag = 4, 3, 5
    due = [t for t in range(run.n_steps) if t % every == 0 and t - lag - window >= 0]
    est = om.make_estimator("rbpf", model, n_particles=40, seed=1, resampling="residual", move_window=window,
                            move_every=every, move_lag=lag)
    for step in steps_of(run):
        est.update(*step)
    assert est.moves.proposed == 40 * len(due) and 0 < est.moves.accepted <= est.moves.proposed
    single = om.make_estimator("rbpf", model, n_particles=1, seed=1, resampling="residual", move_window=window,
                               move_every=every, move_lag=lag)
    changed = 0
    for t, step in enumerate(steps_of(run)):
        past = single._history.paths(t - 1)[0] if t > 0 else None
        accepted = single.moves.accepted
        single.update(*step)
        assert single.moves.proposed == sum(1 for d in due if d <= t)
        assert single.moves.accepted - accepted in ((0, 1) if t in due else (0,))
        if past is not None and np.any(single._history.paths(t)[0, :t] != past):
            assert t in due and single.moves.accepted == accepted + 1
            changed += 1
    assert changed > 0
    fc = om.make_estimator("rbpf", model, n_particles=8, seed=1, move_window=window, move_every=every,
                           move_lag=lag)
    for step in steps_of(run)[:3]:  # 3 steps: at most 4 children, none dropped
        fc.update(*step)
    assert fc.moves == (0, 0) and om.make_estimator("rbpf", model).moves == (0, 0)


# --- memory and threads -----------------------------------------------------------------------------------
def test_the_memory_guard_counts_the_path_history_and_the_move():
    """With any growth over ``max_bytes``, a step that must grow the pool or the path history
    (for the step or its move's worst case) raises MemoryLimitError naming the path history and
    leaves the filter bit for bit as it was; with the limit raised the same step goes on."""
    model = om.door_world(p_move=0.8)[0]
    steps = steps_of(om.simulate(model, None, steps=200, seed=1))
    est = om.make_estimator("rbpf", model, n_particles=100, seed=0, move_window=20, move_every=5, move_lag=10)
    for args in steps[:100]:
        est.update(*args)
    raised = 0
    for args in steps[100:]:
        est.max_bytes = 1
        before = est.state_dict()
        try:
            est.update(*args)
        except om.MemoryLimitError as error:
            assert "path history of move_window" in str(error)
            assert checkpoint.first_difference(est.state_dict(), before) is None
            raised += 1
            est.max_bytes = 2**31
            est.update(*args)
    assert raised > 0 and est.moves.proposed > 0
    with pytest.raises(om.MemoryLimitError, match="path history of move_window"):
        om.make_estimator("rbpf", model, n_particles=200_000, move_window=20, max_bytes=10**8)


@pytest.mark.parametrize("threads", RBPF_THREADS[1:])
def test_a_moving_filter_gives_the_same_results_on_threads(threads, monkeypatch):
    small_chunks(monkeypatch)
    model = om.door_world(p_move=0.8)[0]
    steps = steps_of(om.simulate(model, None, steps=150, seed=2))
    serial, parallel = (om.make_estimator("rbpf", model, n_particles=100, seed=0, move_window=10, move_lag=20,
                                          threads=n) for n in (1, threads))
    for args in steps:
        one, other = serial.step(*args), parallel.step(*args)
        np.testing.assert_array_equal(one.map, other.map)
        np.testing.assert_array_equal(one.location, other.location)
    assert serial.moves == parallel.moves and serial.moves.proposed > 0


@pytest.mark.parametrize("name", ["corridor", "footprint"])
def test_filter_with_moves_matches_exact_within_monte_carlo_tolerance(name):
    """The whole filter with a move at every step (windows of 2 up to t) once Fearnhead-Clifford
    drops children: 20,000 particles over 30 steps of a slipping robot (2^29 trajectories) stay
    within the Monte-Carlo tolerance of exact Bayes derived in ``tests/test_rbpf.py`` for FC
    without moves (the move keeps the posterior over paths and the weights, so each marginal is
    still a weighted average over ESS effectively independent draws), static corridor and a
    two-cell footprint. The moves did happen: thousands of windows accepted."""
    from test_rbpf import STATIC, assert_within_monte_carlo_error

    model = om.corridor(6, 2, **STATIC) if name == "corridor" else footprint_world()
    run = random_run(model, 30, seed=4)
    exact = exact_trajectory(run)
    est = om.make_estimator("rbpf", model, n_particles=20_000, seed=1, **AGGRESSIVE)
    for t, belief in enumerate(beliefs(est, run)):
        assert_within_monte_carlo_error(belief, exact, t, "fearnhead_clifford")
    assert est.moves.accepted > 1000
