"""label_prior="particle_context" (onlinemap.label_prior, onlinemap.estimators.rbpf_prior,
onlinemap.kernels.rbpf_context): the learned table against the counts and backoff formula
computed here from a brute-force context (grid coordinates), every live particle's map against
its path rebuilt here (the cells it tilted, when and by which context in its own map, its
readings and presses), the statuses it carries, a raising step taking its tilts back, the
checkpoint round trip, threads, and the refusals."""

from __future__ import annotations

import copy

import numpy as np
import pytest

import onlinemap as om
from onlinemap.errors import ImpossibleObservationError, InvalidOptionError
from onlinemap.hindsight import smoothed_rbpf_map, told_location
from onlinemap.kernels.rbpf_context import context_tilt_count
from onlinemap.label_prior import ContextState, learn_context_ratios, neighbour_table, posterior_frequencies
from estimator_cases import assert_corruption_refused, beliefs, resumed_bit_for_bit, snapshot
from test_context_prior import brute_code

UNTOUCHED, TILTED, READ = 0, 1, 2


def building_run(steps=120, p_obs=0.9, footprint="cross", **options):
    model, true_map = om.building(12, 12, seed=2, footprint=footprint, p_obs=p_obs)
    run = om.simulate(model, true_map, om.random_walk(model, steps - 1, seed=3), seed=3)
    est = om.make_estimator("rbpf", model, n_particles=40, seed=1, label_prior="particle_context", learn_every=4,
                            **options)
    return model, run, est


# --- the learning rule --------------------------------------------------------------------------------------------
def test_the_table_is_each_contexts_backed_off_counts_tempered_by_the_weight():
    """On a 5 x 6 grid with a random mixture and read cells: the contexts of the newly read frozen
    from the cells read before (brute force over coordinates), pi the Dirichlet mean of the read
    cells' mixture, and every context's ratio ``(w (n[c] + K pi) / (sum n[c] + K) + (1 - w) pi) /
    pi``, the counts summed here cell by cell."""
    rows, cols, k = 5, 6, 3
    model = om.grid_model(rows, cols, k)
    n = model.n_cells
    rng = np.random.default_rng(4)
    mixture = rng.dirichlet(np.ones(k), size=n)
    before = rng.random(n) < 0.3
    frozen = np.where(before, rng.integers(0, (k + 2) ** 4, n), -1)
    now = before | (rng.random(n) < 0.4)
    alpha, weight = np.array([0.5, 1.0, 1.5]), 0.3
    state, ratios = learn_context_ratios(mixture, ContextState(None, before, frozen, None), now,
                                         neighbour_table(model), alpha, weight)
    labels = mixture.argmax(axis=1)
    want_frozen = frozen.copy()
    for cell in range(n):
        if now[cell] and not before[cell]:
            want_frozen[cell] = brute_code(labels, before, rows, cols, k, cell)
    np.testing.assert_array_equal(state.frozen, want_frozen)
    np.testing.assert_array_equal(state.read, now)
    pi = posterior_frequencies(alpha, sum(mixture[c] for c in range(n) if now[c]))
    np.testing.assert_allclose(state.frequencies, pi, rtol=1e-12)
    counts = np.zeros(((k + 2) ** 4, k))
    for cell in range(n):
        if now[cell]:
            counts[want_frozen[cell]] += mixture[cell]
    for code in range((k + 2) ** 4):
        v = (counts[code] + k * pi) / (counts[code].sum() + k)
        np.testing.assert_allclose(ratios[code], (weight * v + (1 - weight) * pi) / pi, rtol=1e-12)


# --- the particles' maps against their paths rebuilt ---------------------------------------------------------------
def rebuilt_map(model, run, slots, locations, tables, frequencies, final_frequencies):
    """(map (N, K), statuses (N,), cells tilted) of the particle whose slot at every step is ``slots`` (T,),
    rebuilt along its path from the model's scalar tables: before each step u >= 1, with the
    table of ratios ``tables[u]`` and frequencies ``frequencies[u]`` the filter held then (None:
    no table yet), every cell of the footprint of the cell the action points at that the path
    has neither read nor tilted takes the ratio of its brute-force context (neighbours read by
    the path, their labels this map's most probable then); then the press (blocking) and the
    readings. The map is ``normalise(prior * pi_T * ratios * prod f)``."""
    n, k = model.n_cells, model.n_labels
    blocks = np.asarray(model.blocking)
    factors, ratio = np.ones((n, k)), np.ones((n, k))
    status = np.zeros(n, dtype=np.int64)
    tilted = 0
    for u in range(run.n_steps):
        here = locations[u][slots[u]]
        if u:
            before = locations[u - 1][slots[u - 1]]
            a = int(run.actions[u - 1])
            target = int(model.neighbors[before, a])
            if tables[u] is not None:
                current = model.label_prior * frequencies[u] * ratio * factors
                labels = current.argmax(axis=1)
                for cell in model.footprint_cells[target]:
                    if cell >= 0 and status[cell] == UNTOUCHED:
                        code = brute_code(labels, status == READ, model.rows, model.cols, k, cell)
                        ratio[cell] = tables[u][code]
                        status[cell] = TILTED
                        tilted += 1
            if target != before:
                factors[target] *= ~blocks if here == target else (1 - model.p_move) + model.p_move * blocks
            status[target] = READ
        for cell, z in zip(model.footprint_cells[here], np.atleast_1d(run.observations[u])):
            if cell >= 0:
                factors[cell] *= model.sensor[:, z]
                status[cell] = READ
    expected = model.label_prior * final_frequencies * ratio * factors
    return expected / expected.sum(axis=1, keepdims=True), status, tilted


@pytest.mark.parametrize("scheme", [{}, {"resampling": "residual"}, {"footprint": "cell"}],
                         ids=["fearnhead-clifford", "residual", "one-cell sensor"])
def test_every_live_particles_map_is_its_path_rebuilt_with_its_own_contexts(scheme):
    """12 x 12 generated building (blocking walls, cross footprint; or the one-cell sensor, where
    a failed press is the only reading of the cell pressed into), 120 steps, 40 particles,
    learning every 4 steps: each live particle's map and cell statuses equal its path's rebuilt
    here (:func:`rebuilt_map`), the path traced back through the genealogy."""
    model, run, est = building_run(**scheme)
    ancestry, locations, tables, frequencies = [], [], [], []
    for t in range(run.n_steps):
        tables.append(None if est.context_ratios is None else est.context_ratios.copy())
        frequencies.append(est.label_frequencies.copy())
        ancestry.append(est.update_with_ancestors(None if t == 0 else int(run.actions[t - 1]), run.observations[t]))
        locations.append(est.particles.copy())
    assert est.recoveries == 0
    assert sum(table is not None for table in tables) > 100
    maps, live = est.particle_maps(), np.flatnonzero(est.weights > 0)
    tilted = 0
    for p in live:
        slots = [p]
        for u in range(run.n_steps - 1, 0, -1):
            slots.append(ancestry[u][slots[-1]])
        want, status, count = rebuilt_map(model, run, slots[::-1], locations, tables, frequencies,
                                          est.label_frequencies)
        np.testing.assert_allclose(maps[p], want, atol=1e-9, err_msg=f"particle {p}")
        np.testing.assert_array_equal(est._particle_cells[p], status, err_msg=f"particle {p}")
        tilted += count
    assert tilted > 10 * len(live)  # every live particle tilted cells


def test_threads_give_the_same_filter_bit_for_bit():
    model, run, serial = building_run(steps=80)
    _, _, threaded = building_run(steps=80, threads=2)
    for one, two in zip(beliefs(serial, run), beliefs(threaded, run)):
        np.testing.assert_array_equal(one.map, two.map)
        np.testing.assert_array_equal(one.location, two.location)
    np.testing.assert_array_equal(serial._particle_cells, threaded._particle_cells)


# --- a raising step takes its tilts back ---------------------------------------------------------------------------
def test_a_step_that_raises_after_its_tilts_leaves_the_filter_as_it_was():
    """A noiseless sensor (p_obs = 1) and a reading of a wall under the robot at a step whose tilts
    write cells: no particle explains it, and with ``recover_from_depletion`` False the step
    raises after tilting. Every attribute, the particles' maps and statuses are as before; the
    true step then runs as a copy's does."""
    model, run, est = building_run(steps=60, p_obs=1.0)
    est.recover_from_depletion = False
    for t in range(run.n_steps - 1):
        est.update(None if t == 0 else int(run.actions[t - 1]), run.observations[t])
    a = int(run.actions[-1])
    assert context_tilt_count(est._locations, est._weights, model.moves[a], model.footprint_cells,
                              est._particle_cells) > 0
    before, twin, maps = snapshot(est), copy.deepcopy(est), est.particle_maps()
    used = np.count_nonzero(est._blocks.refcount)
    observation = run.observations[-1].copy()
    centre = list(model.footprint_cells[run.locations[-1]]).index(run.locations[-1])  # the reading under the robot
    observation[centre] = model.label_names.index("wall")
    with pytest.raises(ImpossibleObservationError):
        est.update(a, observation)
    for name, value in before.items():
        if isinstance(value, np.ndarray):
            np.testing.assert_array_equal(getattr(est, name), value, err_msg=name)
    np.testing.assert_array_equal(est.particle_maps(), maps)
    assert np.count_nonzero(est._blocks.refcount) == used
    type(est).check_state(est)
    np.testing.assert_array_equal(est.step(a, run.observations[-1]).map, twin.step(a, run.observations[-1]).map)
    np.testing.assert_array_equal(est._particle_cells, twin._particle_cells)


def test_a_recovery_relocates_particles_with_their_new_cells_read_and_a_valid_state():
    """A noiseless sensor and a reading that contradicts the cell every particle read there (a
    neighbour's label changed): the step recovers (relocated children), every slot's footprint is
    read, the cells its ancestor had read stay read (a status never goes back), and the state
    passes its checks; the filter then runs on."""
    model, run, start = building_run(steps=60, p_obs=1.0)
    for t in range(run.n_steps - 1):
        start.update(None if t == 0 else int(run.actions[t - 1]), run.observations[t])
    here = run.locations[-1]
    for f in np.flatnonzero((model.footprint_cells[here] >= 0) & (model.footprint_cells[here] != here)):
        est, observation = copy.deepcopy(start), run.observations[-1].copy()
        observation[f] = model.label_names.index("free" if observation[f] else "wall")
        before = est._particle_cells.copy()
        ancestors = est.update_with_ancestors(int(run.actions[-1]), observation)
        if est.recoveries:
            break
    assert est.recoveries == 1 and est.belief.recovered
    status = est._particle_cells
    for p in np.flatnonzero(est.weights > 0):
        cells = model.footprint_cells[est.particles[p]]
        assert np.all(status[p, cells[cells >= 0]] == READ)
        assert np.all(status[p][before[ancestors[p]] == READ] == READ)
    type(est).check_state(est)
    est.update(0, run.observations[-1])


# --- checkpoints ---------------------------------------------------------------------------------------------------
def test_a_particle_context_filter_resumes_from_its_checkpoint_bit_for_bit(tmp_path):
    _, run, _ = building_run(steps=60)
    resumed, _, straight = resumed_bit_for_bit(lambda: building_run(steps=60)[2], run,
                                               tmp_path / "particle_context.npz", stop=27)
    np.testing.assert_array_equal(resumed._particle_cells, straight._particle_cells)
    np.testing.assert_array_equal(resumed.context_ratios, straight.context_ratios)


def corrupt_status(est):
    est._particle_cells[0, 0] = 3


def corrupt_status_shape(est):
    est._particle_cells = est._particle_cells[:, :-1]


def corrupt_ratio(est):
    est._context_ratios[5, 1] = 0.0


def corrupt_tilts_present(est):
    est._context_tilts = np.full((est.model.n_cells, est.model.n_labels), 0.25)


@pytest.mark.parametrize("corrupt, name", [
    (corrupt_status, "_particle_cells"), (corrupt_status_shape, "_particle_cells"), (corrupt_ratio, "_context_ratios"),
    (corrupt_tilts_present, "_context_tilts")])
def test_a_corrupted_particle_context_state_is_refused(corrupt, name):
    _, run, est = building_run(steps=25)
    assert_corruption_refused(est, run, corrupt, name)


def test_other_filters_hold_no_particle_context_state():
    model, _ = om.building(10, 10, seed=1)
    for options in ({}, {"label_prior": "learn"}, {"label_prior": "context"}):
        est = om.make_estimator("rbpf", model, n_particles=10, **options)
        assert not {"_particle_cells", "_context_ratios"} & set(vars(est))
        assert "context_weight" not in repr(est)
    est = om.make_estimator("rbpf", model, n_particles=10, label_prior="particle_context")
    assert "context_weight=0.5" in repr(est) and est.context_ratios is None


# --- refusals ------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("options, match", [
    ({"label_prior": "particle_context", "move_window": 5}, "move_window"),
    ({"label_prior": "learn", "context_weight": 0.5}, "context_weight"),
    ({"context_weight": 0.5}, "context_weight"),
    ({"label_prior": "particle_context", "context_weight": 0.0}, "context_weight"),
    ({"label_prior": "particle_context", "context_weight": 1.5}, "context_weight"),
    ({"label_prior": "particle_context", "context_weight": True}, "context_weight"),
    ({"label_prior": "particle_context", "context_weight": "half"}, "context_weight"),
])
def test_bad_particle_context_options_are_refused(options, match):
    model, _ = om.building(10, 10, seed=1)
    with pytest.raises(InvalidOptionError, match=match):
        om.make_estimator("rbpf", model, n_particles=10, **options)


def test_a_world_it_cannot_serve_is_refused():
    dynamic, _ = om.door_world(p_door=0.05)
    with pytest.raises(InvalidOptionError, match="static world"):
        om.make_estimator("rbpf", dynamic, n_particles=10, label_prior="particle_context")
    with pytest.raises(InvalidOptionError, match="grid"):
        om.make_estimator("rbpf", om.corridor(8), n_particles=10, label_prior="particle_context")
    model, _ = om.building(10, 10, seed=1)
    for name in ("exact", "bk"):
        with pytest.raises(InvalidOptionError, match="RBPF's only"):
            om.make_estimator(name, model, label_prior="particle_context")
    with pytest.raises(InvalidOptionError, match="context_weight"):
        om.make_estimator("online_em", model, context_weight=0.5)
    run = om.simulate(model, om.building(10, 10, seed=1)[1], om.random_walk(model, 11, seed=0), seed=0)
    for fit in (lambda: told_location(model, run, label_prior="particle_context"),
                lambda: smoothed_rbpf_map(model, run.actions, run.observations, n_particles=10,
                                          label_prior="particle_context")):
        with pytest.raises(InvalidOptionError, match="RBPF's only"):
            fit()


def test_a_full_weight_filter_runs_and_differs_from_the_tempered_one():
    """``context_weight`` reaches the table: w = 1 gives other ratios than the default 0.5."""
    _, run, half = building_run(steps=30)
    _, _, full = building_run(steps=30, context_weight=1.0)
    for _ in zip(beliefs(half, run), beliefs(full, run)):
        pass
    assert not np.allclose(half.context_ratios, full.context_ratios)


def smallest_limit(model, **options) -> int:
    """The least ``max_bytes`` with which the RBPF starts (bisection on MemoryLimitError)."""
    low, high = 0, 1 << 32
    while high - low > 1:
        middle = (low + high) // 2
        try:
            om.make_estimator("rbpf", model, n_particles=50, max_bytes=middle, **options)
        except om.MemoryLimitError:
            low = middle
        else:
            high = middle
    return high


def test_the_memory_guard_counts_the_particles_cell_statuses():
    """A particle_context filter needs P N bytes more to start than a learning one (its statuses)."""
    model, _ = om.building(10, 10, seed=1)
    assert smallest_limit(model, label_prior="particle_context") - smallest_limit(model, label_prior="learn") \
        == 50 * model.n_cells
