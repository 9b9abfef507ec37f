"""The context priors' pre-learned table (onlinemap.label_prior.ContextTable, context_table; the
RBPF's option ``context_table``): the builder against a brute-force count over the 16 read/unread
masks written here from the grid's coordinates, the filter's tilts and ratios against the
counts-plus-table formula computed here from its mixture, the refusals, the checkpoint round trip,
and the lean towards "the robot stayed" in an unmapped corridor, smaller with a table than
without by more than 3 standard errors of the paired difference (exact posteriors)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

import onlinemap as om
import onlinemap.estimators.rbpf_prior as rbpf_prior
from onlinemap.checkpoint import decode_options, same_tree
from onlinemap.errors import CheckpointError, InvalidOptionError
from onlinemap.estimators import fork, make_estimator, run_estimator
from onlinemap.label_prior import ContextTable, context_table
from onlinemap.worlds import parse_world
from estimator_cases import beliefs, resumed_bit_for_bit

#: the neighbours a context's digits read, north first: (drow, dcol)
DIRECTIONS = ((-1, 0), (1, 0), (0, -1), (0, 1))


# --- the brute force ---------------------------------------------------------------------------------------------
def brute_counts(grids, n_labels, strength):
    """((K + 2)^4, K) the table of ``grids`` (2-d label arrays): every cell, every (hidden N, S, W, E) mask, its
    label counted in the context of digits 0 off the grid, 1 hidden, 2 + label; rows scaled to min(total, strength)."""
    base = n_labels + 2
    counts = np.zeros((base ** 4, n_labels))
    for grid in grids:
        rows, cols = grid.shape
        for r, c, hidden in itertools.product(range(rows), range(cols), itertools.product((False, True), repeat=4)):
            code = 0
            for (dr, dc), masked in zip(DIRECTIONS, hidden):
                inside = 0 <= r + dr < rows and 0 <= c + dc < cols
                code = code * base + (0 if not inside else 1 if masked else 2 + grid[r + dr, c + dc])
            counts[code, grid[r, c]] += 1
    for row in counts:
        if row.sum() > strength:
            row *= strength / row.sum()
    return counts


def as_map(grid, n_labels):
    """(model, labels): a static grid model of ``grid``'s shape and its labels, row-major."""
    return om.grid_model(*grid.shape, n_labels), grid.ravel()


GRID_3X3 = np.array([[0, 1, 2], [1, 0, 0], [2, 2, 1]])
GRID_2X3 = np.array([[1, 1, 0], [2, 0, 1]])


@pytest.mark.parametrize("strength", [1e9, 2.5, 0.3])
def test_the_table_is_the_brute_force_count_over_the_16_masks_scaled_to_the_strength(strength):
    """Two hand-written maps (3 x 3 and 2 x 3, 3 labels): every count, the scaling to min(n_c,
    strength) (none at 1e9, some rows at 2.5, every row at 0.3) and the empty rows."""
    table = context_table([as_map(GRID_3X3, 3), as_map(GRID_2X3, 3)], strength=strength)
    expected = brute_counts([GRID_3X3, GRID_2X3], 3, strength)
    np.testing.assert_allclose(table.counts, expected, rtol=1e-12, atol=0)
    assert table.n_labels == 3 and table.counts.shape == (5 ** 4, 3) and not table.counts.flags.writeable
    totals = expected.sum(axis=1)
    assert (totals == 0).sum() > 500  # most contexts never occur: their rows stay 0
    if strength == 1e9:
        assert totals.sum() == 16 * (9 + 6)  # every cell counted once per mask


def test_a_building_table_counts_each_cell_16_times_per_map():
    """A generated building (its own labels): unscaled, the table holds 16 N counts, and each label's
    column sums to 16 times its cells."""
    model, labels = om.building(12, 12, seed=2)
    table = context_table([(model, labels)], strength=1e9)
    np.testing.assert_allclose(table.counts.sum(axis=0), 16 * np.bincount(labels, minlength=4))


# --- the filter: tilts and ratios against the formula ---------------------------------------------------------------
@pytest.fixture(scope="module")
def buildings_table():
    return context_table([om.building(16, 16, seed=s) for s in range(20, 24)])


def recorded_mixtures(monkeypatch):
    """The particles' mixture at each learning step, recorded as the filter computes it."""
    mixtures = []
    original = rbpf_prior._mixture_map

    def recording(pool, t, weights, threads):
        mixture = original(pool, t, weights, threads)
        mixtures.append(mixture.copy())
        return mixture

    monkeypatch.setattr(rbpf_prior, "_mixture_map", recording)
    return mixtures


def code_of(model, states, cell):
    """A cell's context code from ``states`` (N,) of the grid's cells, from its coordinates."""
    r, c, base, code = cell // model.cols, cell % model.cols, model.n_labels + 2, 0
    for dr, dc in DIRECTIONS:
        inside = 0 <= r + dr < model.rows and 0 <= c + dc < model.cols
        code = code * base + (states[(r + dr) * model.cols + c + dc] if inside else 0)
    return code


def expected_predictive(mixture, read, codes, table, alpha):
    """pi = (alpha + sum of the read cells' mixture) / (A + n_read) and every context's predictive
    (n[c] + T[c] + K pi) / (sum (n + T)[c] + K), n[c] the summed mixture of the read cells of code c."""
    k = mixture.shape[1]
    pi = (alpha + mixture[read].sum(axis=0)) / (alpha.sum() + read.sum())
    counts = table.copy()
    for cell in np.flatnonzero(read):
        counts[codes[cell]] += mixture[cell]
    return pi, (counts + k * pi) / (counts.sum(axis=1, keepdims=True) + k)


def building_run(steps):
    model, true_map = om.building(12, 12, seed=2, footprint="cross")
    return model, om.simulate(model, true_map, om.random_walk(model, steps - 1, seed=3), seed=3)


def test_context_tilts_are_the_counts_plus_table_formula_from_the_first_learning_step(monkeypatch, buildings_table):
    """At every learning step (every 3rd, step 0 included) the filter's tilts are v_i = (n[c_i] + T[c_i] + K pi)
    / (sum (n + T)[c_i] + K), computed here from the recorded mixture, the filter's read cells and frozen
    contexts (the unread cells' contexts from the read cells' most probable labels), and T; they differ
    from a filter without the table."""
    model, run = building_run(30)
    mixtures = recorded_mixtures(monkeypatch)
    options = dict(n_particles=40, seed=1, resampling="residual", label_prior="context", learn_every=3)
    est = make_estimator("rbpf", model, context_table=buildings_table, **options)
    for t, _ in enumerate(beliefs(est, run)):
        if t % 3:
            continue
        mixture, read = mixtures[-1], est._context_read
        states = np.where(read, 2 + mixture.argmax(axis=1), 1)
        codes = np.array([est._context_frozen[i] if read[i] else code_of(model, states, i)
                          for i in range(model.n_cells)])
        pi, predictive = expected_predictive(mixture, read, codes, buildings_table.counts, np.ones(4))
        np.testing.assert_allclose(est.label_frequencies, pi, rtol=1e-12)
        np.testing.assert_allclose(est.context_tilts, predictive[codes], rtol=1e-10, atol=1e-13)
        if t == 0:  # the table applies from the learning step after step 0: the unread cells are not at pi
            assert np.abs(est.context_tilts - pi).max() > 0.05
    assert read.sum() > 20
    plain = make_estimator("rbpf", model, **options)
    for _ in beliefs(plain, run):
        pass
    assert np.abs(est.context_tilts - plain.context_tilts).max() > 0.05


def test_particle_context_ratios_are_the_tempered_counts_plus_table_formula(monkeypatch, buildings_table):
    """``"particle_context"``: after each learning step the ratios are (w v[c] + (1 - w) pi) / pi for every
    context, v[c] the counts-plus-table predictive computed here over the filter's read cells."""
    model, run = building_run(24)
    mixtures = recorded_mixtures(monkeypatch)
    est = make_estimator("rbpf", model, n_particles=40, seed=1, label_prior="particle_context", learn_every=4,
                         context_weight=0.7, context_table=buildings_table)
    for t, _ in enumerate(beliefs(est, run)):
        if t % 4:
            continue
        read = est._context_read
        pi, predictive = expected_predictive(mixtures[-1], read, est._context_frozen, buildings_table.counts,
                                             np.ones(4))
        np.testing.assert_allclose(est.context_ratios, (0.7 * predictive + 0.3 * pi) / pi, rtol=1e-10)
    assert read.sum() > 20


# --- refusals ---------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("counts, match", [
    (np.full((6 ** 4, 4), np.nan), "finite"), (-np.ones((6 ** 4, 4)), "non-negative"),
    (np.ones((6 ** 4, 3)), "shape"), (np.ones(6 ** 4), "shape"), ("counts", "array of numbers"),
    (np.zeros((6 ** 4, 0)), "shape")])
def test_a_bad_hand_built_table_is_refused(counts, match):
    before = counts.copy() if isinstance(counts, np.ndarray) else counts
    with pytest.raises(InvalidOptionError, match=match):
        ContextTable(counts)
    if isinstance(counts, np.ndarray):
        np.testing.assert_array_equal(counts, before)
        assert counts.flags.writeable


def test_a_hand_built_table_copies_its_counts():
    counts = np.ones((6 ** 4, 4))
    table = ContextTable(counts)
    counts[0, 0] = 5.0
    assert table.counts[0, 0] == 1.0 and not table.counts.flags.writeable


@pytest.mark.parametrize("maps, strength, match", [
    ("none", 100.0, "at least one"), ("grids", 0.0, "strength"), ("grids", np.inf, "strength"),
    ("grids", np.nan, "strength"), ("mixed", 100.0, "map 1 has 2 labels"), ("range", 100.0, "map 0's labels"),
    ("shape", 100.0, "map 0's labels"), ("corridor", 100.0, "4 grid neighbours")])
def test_the_builder_refuses_bad_maps_naming_the_problem(maps, strength, match):
    grid = GRID_3X3.copy()
    given = {"grids": [as_map(grid, 3)], "mixed": [as_map(grid, 3), as_map(GRID_2X3 % 2, 2)],
             "range": [as_map(grid, 2)], "shape": [(om.grid_model(3, 3, 3), grid)],
             "corridor": [(om.corridor(5), np.zeros(5, dtype=np.int64))], "none": []}[maps]
    with pytest.raises(InvalidOptionError, match=match):
        context_table(given, strength=strength)
    np.testing.assert_array_equal(grid, GRID_3X3)


def test_the_filter_refuses_a_bad_option_naming_why(buildings_table):
    model, _ = om.building(10, 10, seed=1)
    before = buildings_table.counts.copy()
    for label_prior in (None, "learn", "model", np.full(4, 0.25)):
        with pytest.raises(InvalidOptionError, match="context_table.*means nothing"):
            make_estimator("rbpf", model, label_prior=label_prior, context_table=buildings_table)
    with pytest.raises(InvalidOptionError, match="must be a ContextTable"):
        make_estimator("rbpf", model, label_prior="context", context_table=buildings_table.counts)
    three = context_table([as_map(GRID_3X3, 3)])
    with pytest.raises(InvalidOptionError, match="counts 3 labels, the model has 4"):
        make_estimator("rbpf", model, label_prior="particle_context", context_table=three)
    with pytest.raises(InvalidOptionError, match="takes no context_table"):
        make_estimator("online_em", model, context_table=buildings_table)
    np.testing.assert_array_equal(buildings_table.counts, before)


# --- checkpoints and copies ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("label_prior", ["context", "particle_context"])
def test_a_filter_with_a_table_resumes_from_its_checkpoint_bit_for_bit(tmp_path, label_prior, buildings_table):
    model, run = building_run(40)
    make = lambda: make_estimator("rbpf", model, n_particles=60, seed=4, label_prior=label_prior,  # noqa: E731
                                  learn_every=4, context_table=buildings_table)
    resumed, saved, straight = resumed_bit_for_bit(make, run, tmp_path / "table.npz", stop=17)
    np.testing.assert_array_equal(resumed.options["context_table"].counts, buildings_table.counts)
    assert not resumed.options["context_table"].counts.flags.writeable
    np.testing.assert_array_equal(resumed.label_frequencies, straight.label_frequencies)
    plain = make_estimator("rbpf", model, n_particles=60, seed=4, label_prior=label_prior, learn_every=4)
    with pytest.raises(CheckpointError, match="options"):
        plain.load_state_dict(saved.state_dict())
    with pytest.raises(CheckpointError, match="options"):
        saved.load_state_dict(plain.state_dict())


def test_a_checkpoint_with_a_corrupted_table_is_refused_and_changes_nothing(buildings_table):
    model, run = building_run(12)
    est = make_estimator("rbpf", model, n_particles=20, seed=4, label_prior="context", context_table=buildings_table)
    for _ in beliefs(est, run):
        pass
    state = est.state_dict()
    before = est.state_dict()
    items = dict(state["options"]["items"])
    fields = items["context_table"]["fields"]
    fields["counts"] = np.full_like(fields["counts"], np.nan)
    with pytest.raises(CheckpointError, match="context_table"):
        est.load_state_dict(state)
    assert same_tree(est.state_dict(), before)


def test_without_the_option_options_and_checkpoints_are_as_before(buildings_table):
    """A checkpoint stores no ``context_table`` while it is None (checkpoints as before the option), nor does
    ``repr`` show it; None given explicitly is the same filter; a fork shares the immutable table."""
    model, run = building_run(8)
    given = make_estimator("rbpf", model, n_particles=10, seed=2, label_prior="context", context_table=None)
    default = make_estimator("rbpf", model, n_particles=10, seed=2, label_prior="context")
    for _ in zip(beliefs(given, run), beliefs(default, run)):
        pass
    state = given.state_dict()
    assert "context_table" not in decode_options(state["options"]) and "context_table" not in repr(given)
    assert given.options["context_table"] is None and same_tree(state, default.state_dict())
    with_table = make_estimator("rbpf", model, n_particles=10, seed=2, label_prior="context",
                                context_table=buildings_table)
    assert fork(with_table).options["context_table"] is buildings_table


# --- the named table -----------------------------------------------------------------------------------------------
def test_the_name_buildings_is_the_table_of_generated_buildings_20_to_29_and_the_same_filter():
    """``context_table="buildings"`` stands for the table of the 32 x 32 generated buildings of seeds 20-29 at the
    default strength (as the docs say), and a filter given the name steps as one given that table, bit for bit;
    the name is what its options and checkpoint keep, and it resumes bit for bit."""
    explicit = context_table(om.building(32, 32, seed=s) for s in range(20, 30))
    np.testing.assert_array_equal(rbpf_prior.named_table("buildings").counts, explicit.counts)
    model, run = building_run(30)
    named = make_estimator("rbpf", model, n_particles=40, seed=5, label_prior="particle_context", learn_every=3,
                           context_table="buildings")
    given = make_estimator("rbpf", model, n_particles=40, seed=5, label_prior="particle_context", learn_every=3,
                           context_table=explicit)
    for a, b in zip(beliefs(named, run), beliefs(given, run)):
        np.testing.assert_array_equal(a.location, b.location)
        np.testing.assert_array_equal(a.map, b.map)
    assert decode_options(named.state_dict()["options"])["context_table"] == "buildings"


def test_a_named_table_resumes_from_its_checkpoint_bit_for_bit(tmp_path):
    model, run = building_run(30)
    make = lambda: make_estimator("rbpf", model, n_particles=40, seed=6, label_prior="context",  # noqa: E731
                                  learn_every=4, context_table="buildings")
    resumed, _, _ = resumed_bit_for_bit(make, run, tmp_path / "named.npz", stop=13)
    assert resumed.options["context_table"] == "buildings"


def test_a_bad_name_or_a_model_of_other_labels_is_refused_naming_why():
    model, _ = om.building(10, 10, seed=1)
    with pytest.raises(InvalidOptionError, match=r"context_table must be one of \('buildings',\), got str 'house'"):
        make_estimator("rbpf", model, label_prior="context", context_table="house")
    with pytest.raises(InvalidOptionError, match="counts 4 labels, the model has 2"):
        make_estimator("rbpf", om.grid_model(6, 6, 2), label_prior="context", context_table="buildings")
    with pytest.raises(InvalidOptionError, match="means nothing"):
        make_estimator("rbpf", model, label_prior="learn", context_table="buildings")


# --- the statistical property ---------------------------------------------------------------------------------------
def test_a_table_from_buildings_shrinks_the_stayed_lean_in_an_unmapped_corridor(tmp_path):
    """examples/slip_bias.py's 3 x 16 corridor, 6 presses east, exact posteriors (Fearnhead-Clifford with
    2^7 particles), learning every step, 40 seeds: the mean lean towards "stayed" (true column less the
    posterior mean column) with a table from generated buildings 20-29 is smaller than without, by more
    than 3 standard errors of the paired difference (measured: about 1.1 cells, 10 se)."""
    lines = ["@" * 16, "@" + "." * 14 + "@", "@" * 16]
    path = tmp_path / "corridor.map"
    path.write_text("type octile\nheight 3\nwidth 16\nmap\n" + "\n".join(lines) + "\n")
    world = parse_world(f"layout:{path},start=17")
    model, presses = world.model, 6
    table = context_table([om.building(32, 32, seed=s) for s in range(20, 30)])
    cols = np.arange(model.n_cells) % model.cols
    leans = np.zeros((2, 40))
    for seed in range(40):
        run = world.simulate(presses + 1, seed=seed, walk=lambda _model, n, _rng: np.full(n, 1))
        for arm, extra in enumerate(({}, {"context_table": table})):
            est = make_estimator("rbpf", model, n_particles=2 ** (presses + 1), label_prior="context", learn_every=1,
                                 seed=seed, **extra)
            location = run_estimator(est, run.actions, run.observations).location[-1]
            leans[arm, seed] = cols[run.locations[-1]] - location @ cols
    difference = leans[0] - leans[1]
    se = difference.std(ddof=1) / np.sqrt(len(difference))
    assert leans[0].mean() > 0 and difference.mean() > 3 * se
