"""onlinemap.estimators.block_pool: the RBPF's copy-on-write map blocks keep their invariants
along random runs (checked against counts recomputed from the table), every broken invariant
is refused with a message naming it, growing the pool changes nothing but its size, and a
checkpoint of format version 1 (the pool as loose attributes) still loads and continues bit
for bit."""

import copy
from pathlib import Path

import numpy as np
import pytest

import onlinemap as om
from onlinemap.errors import CheckpointError
from onlinemap.estimators.block_pool import BlockPool
from onlinemap.model import symmetric_channel
from estimator_cases import random_run

DATA = Path(__file__).parent / "data"


def recount(pool: BlockPool) -> None:
    """The bookkeeping, recomputed by brute force from the table."""
    rows = len(pool.rows)
    uses = np.zeros(rows, dtype=np.int64)
    for particle in range(pool.table.shape[0]):
        for block, row in enumerate(pool.table[particle]):
            uses[row] += 1
            assert pool.row_block[row] == block
    np.testing.assert_array_equal(pool.refcount, uses)
    free = pool.free[:pool.free_top[0]]
    assert sorted(free) == [r for r in range(rows) if uses[r] == 0] and len(set(free)) == len(free)


def test_bookkeeping_after_many_resampling_steps():
    """After 80 steps of multinomial resampling every step: the counts match the table, the pool
    grew beyond its initial size, and the belief is still the weighted mean of the particle maps."""
    model = om.corridor(30, 2, p_obs=0.9, p_move=0.8, p_change=0.01)
    run = random_run(model, 80, seed=11)
    est = om.make_estimator("rbpf", model, n_particles=50, block_cells=4, resample_threshold=1.0,
                            resampling="multinomial", seed=1)
    initial_rows = len(est._blocks.rows)
    for t in range(run.n_steps):
        est.update(None if t == 0 else run.actions[t - 1], run.observations[t])
        recount(est._blocks)
        est._blocks.check(50, 2, t)
    assert len(est._blocks.rows) > initial_rows
    maps = est.particle_maps()
    np.testing.assert_allclose(np.exp(est._log_weights) @ maps.reshape(50, -1), est.belief.map.ravel(), atol=1e-14)


def test_particle_maps_of_some_particles_are_those_rows_of_all_and_bad_indices_are_refused():
    """The planners read the maps of the particles they draw only (12 + 64 of 1000): the same rows,
    bit for bit, in the order asked (repeats included); indices that name no particle are refused."""
    model = om.grid_model(3, 4, 3, p_obs=0.8, p_move=0.7, change=symmetric_channel(3, 0.95))
    run = random_run(model, 30, seed=4)
    est = om.make_estimator("rbpf", model, n_particles=20, block_cells=4, seed=2)
    for t in range(run.n_steps):
        est.update(None if t == 0 else run.actions[t - 1], run.observations[t])
    every = est.particle_maps()
    which = np.array([19, 0, 7, 7, 3])
    np.testing.assert_array_equal(est.particle_maps(which), every[which])
    assert est.particle_maps(np.array([], dtype=np.int64)).shape == (0, model.n_cells, 3)
    for bad in ([20], [-1], [[0, 1]], [0.0], np.array([1.5])):
        with pytest.raises(om.ModelError, match="particle indices in 0..19"):
            est.particle_maps(bad)
    np.testing.assert_array_equal(est.particle_maps(), every)


WORLDS = {
    "static grid": lambda: (om.grid_model(3, 4, 3, p_obs=0.8, p_move=0.7), None),
    "dynamic grid": lambda: (om.grid_model(3, 4, 3, p_obs=0.8, p_move=0.7, change=symmetric_channel(3, 0.95)), None),
    "blocking doors": lambda: om.door_world(".o.#\n#c..\n..o.\n", p_door=0.05, blocking=True),
    "cross footprint": lambda: om.door_world(".o.#\n#c..\n..o.\n", p_door=0.05, footprint="cross"),
}


@pytest.mark.parametrize("options", [{}, {"resampling": "residual", "block_cells": 2},
                                     {"proposal": "transition", "block_cells": 1}])
@pytest.mark.parametrize("world", list(WORLDS))
def test_invariants_hold_along_random_runs(world, options):
    model, true_map = WORLDS[world]()
    est = om.make_estimator("rbpf", model, n_particles=16, seed=3, **options)
    run = om.simulate(model, true_map, np.random.default_rng(4).integers(model.n_actions, size=60), seed=5)
    for t in range(run.n_steps):
        est.update(None if t == 0 else int(run.actions[t - 1]), run.observations[t])
        est._blocks.check(16, model.n_labels, t)
        recount(est._blocks)


def stepped_pool():
    model = om.grid_model(3, 4, 3, p_obs=0.8, p_move=0.7, change=symmetric_channel(3, 0.95))
    est = om.make_estimator("rbpf", model, n_particles=12, seed=0, block_cells=4, resampling="residual")
    run = random_run(model, 30, seed=2)
    for t in range(run.n_steps):
        est.update(None if t == 0 else run.actions[t - 1], run.observations[t])
    return est._blocks, est.t


def _used_row(pool):
    return int(pool.table[0, 0])


CORRUPTIONS = [
    ("table", lambda p: p.table.__setitem__((0, 0), len(p.rows)), "_blocks.table holds indices"),
    ("row_block", lambda p: p.row_block.__setitem__(_used_row(p), p.row_block[_used_row(p)] + 1),
     "_blocks.row_block must name the block"),
    ("refcount", lambda p: p.refcount.__setitem__(_used_row(p), p.refcount[_used_row(p)] + 1),
     "_blocks.refcount must count"),
    ("free", lambda p: p.free.__setitem__(0, _used_row(p)), "_blocks.free must list exactly"),
    ("free_top", lambda p: p.free_top.__setitem__(0, p.free_top[0] - 1), "_blocks.free must list exactly"),
    ("rows", lambda p: p.rows.__setitem__((_used_row(p), 0, 0), -0.5), "_blocks.rows must hold probabilities"),
    ("rows sum", lambda p: p.rows.__setitem__((_used_row(p), 0), 0.9), "_blocks.rows rows must sum to 1"),
    ("stamps", lambda p: p.stamps.__setitem__((_used_row(p), 0), -10**6), "_blocks.stamps holds indices"),
    ("refresh_cursor", lambda p: setattr(p, "refresh_cursor", len(p.rows)), "_blocks.refresh_cursor must be an int"),
    ("stamped", lambda p: setattr(p, "stamped", 1), "_blocks.stamped must be a bool"),
    ("table dtype", lambda p: setattr(p, "table", p.table.astype(np.int32)), "_blocks.table must be an array of int64"),
    ("order", lambda p: setattr(p, "rows", np.asfortranarray(p.rows)), "_blocks.rows must be a C-contiguous"),
    ("read-only", lambda p: p.refcount.setflags(write=False), "_blocks.refcount must be writable"),
]


@pytest.mark.parametrize("field,corrupt,words", CORRUPTIONS, ids=[c[0] for c in CORRUPTIONS])
def test_each_broken_invariant_is_named(field, corrupt, words):
    pool, t = stepped_pool()
    pool.check(12, 3, t)
    broken = copy.deepcopy(pool)
    corrupt(broken)
    with pytest.raises(CheckpointError, match=words):
        broken.check(12, 3, t)


def test_reserved_grows_by_doubling_and_changes_nothing_else():
    pool, t = stepped_pool()
    before = copy.deepcopy(pool)
    assert pool.reserved(int(pool.free_top[0])) is pool
    grown = pool.reserved(int(pool.free_top[0]) + 1)
    rows = len(pool.rows)
    assert len(grown.rows) == 2 * rows and grown.free_top[0] == pool.free_top[0] + rows
    for field in ("rows", "stamps", "row_block", "refcount"):
        np.testing.assert_array_equal(getattr(grown, field)[:rows], getattr(pool, field))
        assert not getattr(grown, field)[rows:].any()
        np.testing.assert_array_equal(getattr(pool, field), getattr(before, field))  # the original untouched
    assert grown.table is pool.table and grown.powers is pool.powers
    grown.check(12, 3, t)
    np.testing.assert_array_equal(grown.particle_maps(t), pool.particle_maps(t))


def test_a_format_1_checkpoint_loads_and_continues_as_it_did(tmp_path):
    """tests/data/rbpf_format1.npz was written before the pool was a class (13 loose attributes):
    it loads (its attributes gathered into ``_blocks``) and the next 5 steps equal those the
    writing filter took (tests/data/rbpf_format1_next.npz) to a few ulps: numpy, OpenBLAS and
    numba pick their kernels by CPU, so sums may differ in the last bit from one machine to
    another (seen: 3 of 6 location probabilities, 1 ulp each). On one machine it is bit for
    bit: the upgraded filter, saved in the current format and loaded again, continues exactly
    like the one that was not."""
    state = om.checkpoint.read(DATA / "rbpf_format1.npz")
    assert state["format_version"] == 1 and "_pool" in state["attributes"]
    est = om.load(DATA / "rbpf_format1.npz")
    est._blocks.check(est.n_particles, est.model.n_labels, est.t)
    om.save(est, tmp_path / "format2.npz")
    twin = om.load(tmp_path / "format2.npz")
    assert om.checkpoint.read(tmp_path / "format2.npz")["format_version"] == om.checkpoint.FORMAT_VERSION
    expected = np.load(DATA / "rbpf_format1_next.npz")
    for i, t in enumerate(range(10, 15)):
        action, observation = int(expected["actions"][i]), int(expected["observations"][i])
        belief, again = est.step(action, observation), twin.step(action, observation)
        np.testing.assert_allclose(belief.location, expected[f"location{t}"], rtol=1e-13, atol=1e-15)
        np.testing.assert_allclose(belief.map, expected[f"map{t}"], rtol=1e-13, atol=1e-15)
        assert belief.log_evidence == pytest.approx(float(expected[f"evidence{t}"]), rel=1e-13)
        for got, want in ((again.location, belief.location), (again.map, belief.map)):
            np.testing.assert_array_equal(got, want)
        assert again.log_evidence == belief.log_evidence
    assert est.state_dict()["format_version"] == om.checkpoint.FORMAT_VERSION
