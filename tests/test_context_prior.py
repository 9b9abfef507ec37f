"""label_prior="context" (onlinemap.label_prior, onlinemap.estimators.rbpf_prior): the context codes
and frozen contexts against a brute-force loop over the grid's coordinates, the learning rule
against the counts and backoff formula computed here, the learned tilt converging to the true
conditional of a neighbour-dependent law (tolerance from the count), the RBPF's pool carrying
``normalise(prior v prod f)`` through moves, the refusals, and the checkpoint round trip."""

from __future__ import annotations

import copy
import itertools

import numpy as np
import pytest

import onlinemap as om
from onlinemap.errors import CheckpointError, InvalidOptionError
from onlinemap.hindsight import path_map, smoothed_rbpf_map, told_location
from onlinemap.label_prior import (ContextState, context_codes, learn_context, neighbour_states, neighbour_table,
                                   unread_marginals)
from estimator_cases import assert_corruption_refused, beliefs, map_given_path, random_run, resumed_bit_for_bit


# --- the brute force: a cell's neighbours and code from its (row, column) ----------------------------------------
def brute_code(labels, read, rows, cols, n_labels, cell):
    """The context of ``cell``: north, south, west, east states (0 off the grid, 1 not read, 2 +
    label), base K + 2, north the most significant digit."""
    r, c = divmod(cell, cols)
    code = 0
    for dr, dc in ((-1, 0), (1, 0), (0, -1), (0, 1)):
        rr, cc = r + dr, c + dc
        if not (0 <= rr < rows and 0 <= cc < cols):
            state = 0
        elif not read[rr * cols + cc]:
            state = 1
        else:
            state = 2 + labels[rr * cols + cc]
        code = code * (n_labels + 2) + state
    return code


def one_hot(labels, n_labels):
    return np.eye(n_labels)[labels]


def revealed(prior, state, labels, read, n_labels):
    """The mixture of a filter that knows the ``read`` cells' labels and nothing of the others."""
    mixture = unread_marginals(prior, state.tilts)
    mixture[read] = one_hot(labels[read], n_labels)
    return mixture


def fresh_state(n_cells, n_labels):
    return ContextState(np.full((n_cells, n_labels), 1.0 / n_labels), np.zeros(n_cells, bool),
                        np.full(n_cells, -1, np.int64), np.full(n_labels, 1.0 / n_labels))


def test_context_codes_are_the_brute_force_codes_on_every_map_of_a_3x4_grid():
    """Every 2-label map of a 3 x 4 grid (a stride of the 4096), each with a read mask drawn from a
    seeded generator: the code of every cell equals the loop's, off-grid edges included."""
    rows, cols, k = 3, 4, 2
    model = om.grid_model(rows, cols, k)
    table = neighbour_table(model)
    rng = np.random.default_rng(0)
    for labels in itertools.islice(itertools.product(range(k), repeat=rows * cols), 0, None, 7):
        labels = np.array(labels)
        read = rng.random(rows * cols) < 0.6
        codes = context_codes(neighbour_states(one_hot(labels, k), read), table, k)
        expected = [brute_code(labels, read, rows, cols, k, i) for i in range(rows * cols)]
        assert codes.tolist() == expected


def test_corner_and_edge_cells_see_off_grid_neighbours():
    model = om.grid_model(3, 4, 2)
    table = neighbour_table(model)
    assert table[0].tolist() == [-1, 4, -1, 1]  # north, south, west, east of the top-left corner
    assert table[11].tolist() == [7, -1, 10, -1]
    assert table[5].tolist() == [1, 9, 4, 6]


def test_frozen_contexts_are_those_of_the_first_read_and_same_batch_cells_do_not_see_each_other():
    """Cells revealed in batches (each cell's batch from a seeded generator, 3 labels): each read
    cell keeps the context the loop computes from the cells read in earlier batches only; an
    unread cell's context (seen through its tilt) follows the current read set."""
    rows, cols, k = 3, 4, 3
    model = om.grid_model(rows, cols, k)
    table, prior = neighbour_table(model), model.label_prior
    alpha = np.full(k, 1.0)
    rng = np.random.default_rng(1)
    for _ in range(40):
        labels = rng.integers(0, k, rows * cols)
        batch = rng.integers(0, 4, rows * cols)  # batch 3: never read
        state = fresh_state(rows * cols, k)
        expected_frozen = np.full(rows * cols, -1)
        for b in range(3):
            before = batch < b
            for i in np.flatnonzero(batch == b):
                expected_frozen[i] = brute_code(labels, before, rows, cols, k, i)
            state = learn_context(revealed(prior, state, labels, batch <= b, k), prior, state, table, alpha)
            assert state.read.tolist() == (batch <= b).tolist()
            assert state.frozen.tolist() == expected_frozen.tolist()


def expected_tilts(labels, read, frozen, rows, cols, k, alpha):
    """The rule computed here: pi = (alpha + label counts of the read) / (A + n_read); counts per
    context of the read cells at their frozen codes; v_i = (n[c_i] + K pi) / (sum n[c_i] + K)
    with c_i frozen if read, else the loop's code from the current read set."""
    pi = alpha + np.bincount(labels[read], minlength=k)
    pi = pi / pi.sum()
    counts = {}
    for i in np.flatnonzero(read):
        counts.setdefault(int(frozen[i]), np.zeros(k))[labels[i]] += 1
    tilts = np.empty((rows * cols, k))
    for i in range(rows * cols):
        code = int(frozen[i]) if read[i] else brute_code(labels, read, rows, cols, k, i)
        n = counts.get(code, np.zeros(k))
        tilts[i] = (n + k * pi) / (n.sum() + k)
    return pi, tilts


def test_the_learning_rule_is_the_counts_and_backoff_formula_on_one_hot_mixtures():
    rows, cols, k = 3, 4, 3
    model = om.grid_model(rows, cols, k)
    table, prior = neighbour_table(model), model.label_prior
    alpha = np.array([0.5, 0.5, 0.5])
    rng = np.random.default_rng(2)
    for _ in range(30):
        labels = rng.integers(0, k, rows * cols)
        batch = rng.integers(0, 4, rows * cols)
        state = fresh_state(rows * cols, k)
        for b in range(3):
            state = learn_context(revealed(prior, state, labels, batch <= b, k), prior, state, table, alpha)
            pi, tilts = expected_tilts(labels, batch <= b, state.frozen, rows, cols, k, alpha)
            np.testing.assert_allclose(state.frequencies, pi, rtol=0, atol=1e-12)
            np.testing.assert_allclose(state.tilts, tilts, rtol=0, atol=1e-12)


def test_the_learned_tilt_converges_to_the_true_conditional_of_a_north_copying_law():
    """Maps drawn row by row: a cell copies its north neighbour's label with probability 0.9,
    else a uniform label (row 0 uniform). Revealed row by row, an interior cell of row r >= 1 is
    read with the context (north = j, south, west, east unread), whose true conditional is
    ``0.9 [k = j] + 0.1 / K``. The learned v there is within 4 binomial standard errors of it,
    plus the backoff's pull ``K / (n + K)``; the frequencies alone (1/K each) are far outside."""
    rows, cols, k, copy_p = 60, 60, 3, 0.9
    model = om.grid_model(rows, cols, k)
    table, prior = neighbour_table(model), model.label_prior
    rng = np.random.default_rng(3)
    labels = np.empty((rows, cols), dtype=np.int64)
    labels[0] = rng.integers(0, k, cols)
    for r in range(1, rows):
        copies = rng.random(cols) < copy_p
        labels[r] = np.where(copies, labels[r - 1], rng.integers(0, k, cols))
    labels = labels.ravel()
    state = fresh_state(rows * cols, k)
    row_of = np.arange(rows * cols) // cols
    for r in range(rows - 1):
        state = learn_context(revealed(prior, state, labels, row_of <= r, k), prior, state, table, np.ones(k))
    column = np.arange(rows * cols) % cols
    cells = np.flatnonzero((row_of >= 1) & (row_of < rows - 1) & (column > 0) & (column < cols - 1))
    for j in range(k):
        with_j = cells[labels[cells - cols] == j]
        n = len(with_j)
        truth = copy_p * (np.arange(k) == j) + (1 - copy_p) / k
        tolerance = 4 * np.sqrt(truth * (1 - truth) / n) + k / (n + k)
        code = ((2 + j) * (k + 2) + 1) * (k + 2) ** 2 + 1 * (k + 2) + 1  # north j, south/west/east unread
        assert np.all(state.frozen[with_j] == code)
        learned = state.tilts[with_j[0]]  # every cell of that frozen context has the same tilt
        assert np.all(np.abs(learned - truth) <= tolerance), (j, learned, truth, tolerance)
        assert np.any(np.abs(state.frequencies - truth) > 0.5)


# --- the filter ----------------------------------------------------------------------------------------------------
def open_grid():
    """A static 10 x 10 grid, 3 labels drawn with a seeded generator, no blocking label, cross footprint: the
    resample-move divides the window's readings out of the stored marginals (no rebuilding)."""
    model = om.grid_model(10, 10, 3, p_obs=0.8, p_move=0.8, footprint="cross")
    return model, np.random.default_rng(5).choice(3, size=model.n_cells, p=[0.6, 0.3, 0.1])


def run_building(steps=120, world=None, **options):
    model, true_map = om.building(12, 12, seed=2, footprint="cross") if world is None else world
    run = om.simulate(model, true_map, om.random_walk(model, steps - 1, seed=3), seed=3)
    est = om.make_estimator("rbpf", model, n_particles=40, seed=1, resampling="residual", label_prior="context",
                            **options)
    return model, run, est


@pytest.mark.parametrize("world", [None, "open"], ids=["building rebuilds", "open grid divides"])
def test_every_particle_map_is_the_prior_tilted_by_v_times_its_paths_factors_through_moves(world):
    """12 x 12 generated building (blocking walls, cross footprint; the move rebuilds maps from the
    history), and an open grid (the move divides readings out), 120 steps, 40 particles,
    resample-move every 5 steps: each live particle's map equals ``normalise(prior_i v_i prod f)``
    over its path's readings and presses, rebuilt here from the path history (the model's tables
    only), v the filter's current per-cell tilt."""
    model, run, est = run_building(world=None if world is None else open_grid(), move_window=6, move_every=5,
                                   move_lag=10)
    for t in range(run.n_steps):
        est.update(None if t == 0 else int(run.actions[t - 1]), run.observations[t])
    assert est.recoveries == 0 and est.moves.proposed > 100 and est.moves.accepted > 0
    v = est.context_tilts
    assert np.ptp(v, axis=0).max() > 0.1  # the cells' tilts differ: the check is per cell
    paths, maps = est._history.paths(est.t), est.particle_maps()
    readings = run.observations.reshape(run.n_steps, -1)
    for p in np.flatnonzero(est.weights > 0)[:8]:
        expected = map_given_path(model, paths[p], run.actions, readings, v)
        np.testing.assert_allclose(maps[p], expected, atol=1e-9, rtol=0)


def test_the_filter_learns_every_learn_every_steps_from_its_mixture_with_its_options(monkeypatch):
    """The filter's state after each learning step (every 5th step, step 0 included) is the pure
    rule applied to the state before it and the particles' mixture at that step (recorded here),
    the model's prior, the grid's neighbours and alpha = prior_strength / K; the frozen contexts
    and read cells carry over between learning steps."""
    import onlinemap.estimators.rbpf_prior as rbpf_module
    calls = []
    original = rbpf_module.learn_context_in_pool

    def recording(pool, model, t, weights, state, table, alpha, threads=1, pretrained=None):
        mixture = pool.mixture(t, weights, threads)
        calls.append((t, mixture / mixture.sum(axis=1, keepdims=True), copy.deepcopy(state)))
        return original(pool, model, t, weights, state, table, alpha, threads, pretrained)

    monkeypatch.setattr(rbpf_module, "learn_context_in_pool", recording)
    model, run, est = run_building(steps=36, learn_every=5, prior_strength=2.0)
    for t in range(run.n_steps):
        est.update(None if t == 0 else int(run.actions[t - 1]), run.observations[t])
        if t % 5 == 0:
            step, mixture, before = calls[-1]
            assert step == t
            want = learn_context(mixture, model.label_prior, before, neighbour_table(model), np.full(4, 0.5))
            np.testing.assert_array_equal(est.context_tilts, want.tilts)
            np.testing.assert_array_equal(est.label_frequencies, want.frequencies)
            assert est._context_read.tolist() == want.read.tolist()
            assert est._context_frozen.tolist() == want.frozen.tolist()
    assert len(calls) == 8 and est._context_read.sum() > 20


# --- refusals --------------------------------------------------------------------------------------------------------
def test_a_dynamic_world_and_a_corridor_are_refused():
    with pytest.raises(InvalidOptionError, match="context.*static world"):
        om.make_estimator("rbpf", om.door_world(p_door=0.05)[0], label_prior="context")
    with pytest.raises(InvalidOptionError, match="4 grid neighbours"):
        om.make_estimator("rbpf", om.corridor(8, 3), label_prior="context")


@pytest.mark.parametrize("name", ["bk", "exact"])
def test_the_other_filters_refuse_it_naming_the_rbpf(name):
    with pytest.raises(InvalidOptionError, match="RBPF's only"):
        om.make_estimator(name, om.grid_model(2, 2, 2), label_prior="context")


@pytest.mark.parametrize("name", ["online_em", "offline_em"])
def test_the_em_estimators_refuse_it(name):
    with pytest.raises(InvalidOptionError, match="label_prior"):
        om.make_estimator(name, om.grid_model(2, 2, 2), label_prior="context")


def test_the_hindsight_fits_refuse_it_naming_the_rbpf():
    model, _ = om.building(10, 10, seed=1)
    run = random_run(model, 12, seed=0)
    with pytest.raises(InvalidOptionError, match="RBPF's only"):
        told_location(model, run, label_prior="context")
    with pytest.raises(InvalidOptionError, match="RBPF's only"):
        path_map(model, run.locations, run.actions, run.observations, label_prior="context")
    with pytest.raises(InvalidOptionError, match="RBPF's only"):
        om.fit_layered_map(model, run.actions, run.observations, label_prior="context")
    with pytest.raises(InvalidOptionError, match="RBPF's only"):
        smoothed_rbpf_map(model, run.actions, run.observations, n_particles=10, label_prior="context")


@pytest.mark.parametrize("fault", ["readings", "action"])
def test_a_step_that_raises_leaves_the_context_state_unchanged(fault):
    """A bad observation, and a bad action, at a learning step (t = 40)."""
    model, run, est = run_building(steps=41)
    for t in range(run.n_steps - 1):
        est.update(None if t == 0 else int(run.actions[t - 1]), run.observations[t])
    before = copy.deepcopy(est)
    action, observation = int(run.actions[-1]), run.observations[-1]
    if fault == "readings":
        observation = np.full(model.n_readings + 1, 0)
    else:
        action = model.n_actions
    with pytest.raises(om.OnlineMapError):
        est.update(action, observation)
    for name in ("_context_tilts", "_context_read", "_context_frozen", "_label_frequencies", "_locations",
                 "_log_weights"):
        np.testing.assert_array_equal(getattr(est, name), getattr(before, name))
    np.testing.assert_array_equal(est.particle_maps(), before.particle_maps())
    assert est.t == before.t
    est.update(int(run.actions[-1]), run.observations[-1])  # the learning step then runs as the copy's does
    before.update(int(run.actions[-1]), run.observations[-1])
    np.testing.assert_array_equal(est.context_tilts, before.context_tilts)


# --- checkpoints -----------------------------------------------------------------------------------------------------
def test_a_context_filter_resumes_from_its_checkpoint_bit_for_bit(tmp_path):
    options = dict(steps=60, learn_every=4, move_window=4, move_every=5, move_lag=5)
    _, run, _ = run_building(**options)
    resumed, _, straight = resumed_bit_for_bit(lambda: run_building(**options)[2], run, tmp_path / "context.npz",
                                                 stop=27)
    np.testing.assert_array_equal(resumed.context_tilts, straight.context_tilts)
    np.testing.assert_array_equal(resumed._context_frozen, straight._context_frozen)
    np.testing.assert_array_equal(resumed.label_frequencies, straight.label_frequencies)


def test_filters_without_the_option_keep_their_state():
    model, _ = om.building(10, 10, seed=1)
    for options in ({}, {"label_prior": "learn"}, {"label_prior": "model"}):
        est = om.make_estimator("rbpf", model, n_particles=10, **options)
        assert not {"_context_tilts", "_context_read", "_context_frozen"} & set(vars(est))
        assert est.context_tilts is None


def corrupt_tilts_zero(est):
    est._context_tilts[3] = [1.0, 0.0, 0.0, 0.0]


def corrupt_tilts_sum(est):
    est._context_tilts[3] *= 2


def corrupt_frozen_unread(est):
    est._context_frozen[np.flatnonzero(~est._context_read)[0]] = 5


def corrupt_frozen_range(est):
    est._context_frozen[np.flatnonzero(est._context_read)[0]] = 6 ** 4


def corrupt_read_dtype(est):
    est._context_read = est._context_read.astype(np.int64)


def corrupt_missing(est):
    est._context_frozen = None


def corrupt_frequencies_missing(est):
    est._label_frequencies = None


@pytest.mark.parametrize("corrupt, name", [
    (corrupt_tilts_zero, "_context_tilts"), (corrupt_tilts_sum, "_context_tilts"),
    (corrupt_frozen_unread, "_context_frozen"), (corrupt_frozen_range, "_context_frozen"),
    (corrupt_read_dtype, "_context_read"), (corrupt_missing, "_context_frozen"),
    (corrupt_frequencies_missing, "_label_frequencies")])
def test_a_corrupted_context_state_is_refused(corrupt, name):
    model, run, est = run_building(steps=25)
    assert_corruption_refused(est, run, corrupt, name)


def test_a_learning_filter_with_context_attributes_is_refused():
    model, _ = om.building(10, 10, seed=1)
    est = om.make_estimator("rbpf", model, n_particles=10, label_prior="learn")
    est._context_tilts = np.full((model.n_cells, model.n_labels), 0.25)
    with pytest.raises(CheckpointError, match="_context_tilts"):
        type(est).check_state(est)
