"""Exact filter and smoother against brute-force enumeration; dead reckoning against a
hand-written motion-only filter."""

import numpy as np
import pytest

import onlinemap as om
from estimator_cases import beliefs, exact_trajectory, random_run
from oracles import BruteForce, grid_motion

CASES = [
    ("corridor K=2 static", lambda: om.corridor(4, 2, p_obs=0.85, p_move=0.7)),
    ("corridor K=2 dynamic", lambda: om.corridor(4, 2, p_obs=0.85, p_move=0.7, p_change=0.05)),
    ("corridor K=3 static", lambda: om.corridor(3, 3, p_obs=0.8, p_move=0.75, start=1)),
    ("corridor K=3 dynamic", lambda: om.corridor(3, 3, p_obs=0.8, p_move=0.75, p_change=0.1)),
    ("grid 2x3 static", lambda: om.grid_model(2, 3, 2, p_obs=0.8, p_move=0.7, start=4)),
    ("grid 2x3 dynamic", lambda: om.grid_model(2, 3, 2, p_obs=0.8, p_move=0.7,
                                               change=[[0.9, 0.1], [0.2, 0.8]], label_prior=[0.3, 0.7])),
]


@pytest.mark.parametrize("name,make", CASES, ids=[c[0] for c in CASES])
@pytest.mark.parametrize("seed", [0, 1])
def test_exact_filter_equals_brute_force_every_step(name, make, seed):
    model = make()
    run = random_run(model, 9, seed)
    oracle = BruteForce.of(model).filter(run.actions, run.observations)
    est = om.make_estimator("exact", model)
    for t, ((loc, maps, log_ev), belief) in enumerate(zip(oracle, beliefs(est, run), strict=True)):
        assert belief.t == t
        np.testing.assert_allclose(belief.location, loc, atol=1e-10, rtol=0)
        np.testing.assert_allclose(belief.map, maps, atol=1e-10, rtol=0)
        assert belief.log_evidence == pytest.approx(log_ev, abs=1e-10)


@pytest.mark.parametrize("name,make", CASES, ids=[c[0] for c in CASES])
def test_exact_smoother_equals_brute_force(name, make):
    model = make()
    run = random_run(model, 7, 3)
    oracle = BruteForce.of(model).smooth(run.actions, run.observations)
    smoothed = om.exact_smooth(model, run.actions, run.observations)
    for t, (loc, maps) in enumerate(oracle):
        np.testing.assert_allclose(smoothed.location[t], loc, atol=1e-10, rtol=0)
        np.testing.assert_allclose(smoothed.map[t], maps, atol=1e-10, rtol=0)
    filtered = exact_trajectory(run)
    assert smoothed.log_evidence == pytest.approx(filtered.log_evidence[-1], abs=1e-10)
    # the last smoothed step is the last filtered step
    np.testing.assert_allclose(smoothed.location[-1], filtered.location[-1], atol=1e-12)


def test_smoother_accepts_names_and_leading_none():
    run = om.scenarios.murphy_corridor()
    names = [None] + [run.model.action_names[a] for a in run.actions]
    a = om.exact_smooth(run.model, names, run.observations)
    b = om.exact_smooth(run.model, run.actions, run.observations)
    np.testing.assert_array_equal(a.location, b.location)


def test_dead_reckoning_equals_motion_only_filter():
    model = om.grid_model(3, 3, 2, p_move=0.6, start=4, change=[[0.9, 0.1], [0.3, 0.7]])
    run = random_run(model, 20, 5)
    motion = grid_motion(3, 3, 0.6)
    est = om.make_estimator("dead_reckoning", model)
    loc = np.eye(9)[4]
    maps = np.array(model.label_prior)
    change = np.array([[0.9, 0.1], [0.3, 0.7]])
    for t, belief in enumerate(beliefs(est, run)):
        if t:
            loc = loc @ motion[run.actions[t - 1]]
            maps = maps @ change
        np.testing.assert_allclose(belief.location, loc, atol=1e-12)
        np.testing.assert_allclose(belief.map, maps, atol=1e-12)
        assert np.isnan(belief.log_evidence)


def test_exact_beats_dead_reckoning_on_murphy_corridor():
    run = om.scenarios.murphy_corridor()
    exact = exact_trajectory(run)
    dead = om.run_estimator(om.make_estimator("dead_reckoning", run.model), run.actions, run.observations)
    assert exact.location[-1, 0] >= 0.8
    assert om.metrics.wrong_cells(exact.map[-1], run.final_map, cells=np.arange(7)) == 0
    assert om.metrics.map_error(exact.map[-1], run.final_map) < om.metrics.map_error(dead.map[-1], run.final_map)


def test_memory_guard_refuses_before_allocating():
    model = om.corridor(30)
    with pytest.raises(om.MemoryLimitError, match=r"N=30 cells.*max_bytes"):
        om.make_estimator("exact", model)
    small = om.corridor(10)
    with pytest.raises(om.MemoryLimitError):
        om.make_estimator("exact", small, max_bytes=1000)
    with pytest.raises(om.MemoryLimitError, match="smoothing"):
        om.exact_smooth(small, [1] * 9, [0] * 10, max_bytes=10_000)
    om.make_estimator("exact", small, max_bytes=10**7)  # raising the limit works


def test_joint_is_normalised_and_matches_marginals():
    run = om.scenarios.murphy_corridor()
    est = om.make_estimator("exact", run.model)
    om.run_estimator(est, run.actions, run.observations)
    joint = est.joint()
    assert joint.sum() == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(joint.reshape(8, -1).sum(1), est.belief.location, atol=1e-12)


def test_belief_is_read_only():
    est = om.make_estimator("exact", om.corridor(4))
    belief = est.step(None, 0)
    with pytest.raises(ValueError):
        belief.location[0] = 1.0
    with pytest.raises(ValueError):
        belief.map[0, 0] = 1.0


@pytest.mark.parametrize("k,n", [(2, 1), (2, 5), (2, 12), (2, 13), (3, 4), (3, 7), (3, 8)])
def test_change_kernel_equals_tensordot_on_every_axis(k, n):
    """Sizes past one cache block (2^11 binary, 3^6 ternary maps) take the outer-axis paths."""
    from onlinemap.arrays import frozen
    from onlinemap.kernels.exact import change_every_axis

    rng = np.random.default_rng(n)
    change = rng.random((k, k))
    change /= change.sum(axis=1, keepdims=True)
    x = rng.random((n, k**n))
    expected = x.reshape((n,) + (k,) * n)
    for axis in range(1, n + 1):
        expected = np.moveaxis(np.tensordot(expected, change, axes=([axis], [0])), -1, axis)
    change_every_axis(x, frozen(change))  # as the estimator passes it
    np.testing.assert_allclose(x, expected.reshape(n, -1), atol=1e-13, rtol=0)


@pytest.mark.parametrize("p_change", [0.0, 0.02])
def test_exact_filter_on_a_corridor_larger_than_a_cache_block(p_change):
    """13 binary cells (2^13 maps > one 2^11 block): the fused kernel against the per-axis
    numpy operations the smoother uses (motion along the location axis, C along each map
    axis, the sensor along each slice)."""
    from onlinemap.estimators.exact import change_tensor, observe_tensor, prior_tensor
    from onlinemap.model import apply_motion

    model = om.corridor(13, p_change=p_change, start=6)
    run = random_run(model, 6, 2)
    est = om.make_estimator("exact", model)
    x = observe_tensor(model, prior_tensor(model), run.observations[0])
    est.step(None, run.observations[0])
    for t in range(1, run.n_steps):
        x = observe_tensor(model, change_tensor(model, apply_motion(model, x, run.actions[t - 1])),
                           run.observations[t])
        x /= x.sum()
        belief = est.step(run.actions[t - 1], run.observations[t])
        np.testing.assert_allclose(belief.location, x.sum(axis=1), atol=1e-12)
        maps = np.stack([x.reshape((13,) + (2,) * 13).sum(axis=tuple(a for a in range(14) if a != i + 1))
                         for i in range(13)])
        np.testing.assert_allclose(belief.map, maps, atol=1e-12)


@pytest.mark.parametrize("footprint,blocking", [("cell", [1]), ("cross", None), ("square", [1])])
def test_blocking_and_footprint_marginals_stay_at_most_one(footprint, blocking):
    """Regression (found with issue 24 item 8): the numpy path of blocking labels and footprints
    and the smoother did not clip rounding as the paper's filter does; map marginals reached
    1 + 5.1e-15 (a 2 x 3 grid, K = 3, blocking, at t = 0)."""
    from onlinemap.model import symmetric_channel

    model = om.grid_model(2, 3, 3, blocking=blocking, footprint=footprint, p_obs=1.0,
                          change=symmetric_channel(3, 0.9))
    for seed in range(3):
        run = om.simulate(model, steps=30, seed=seed)
        est = om.make_estimator("exact", model)
        smooth = om.exact_smooth(model, run.actions, run.observations)  # reached 1 + 6.7e-16
        for t, belief in enumerate(beliefs(est, run)):
            for p in (belief.location, belief.map, smooth.location[t], smooth.map[t]):
                assert 0 <= p.min() and p.max() <= 1, (seed, t, p.min(), p.max() - 1)
                np.testing.assert_allclose(p.sum(axis=-1), 1.0, rtol=0, atol=1e-12)


def test_the_exact_kernels_compile_once_whatever_the_step(tmp_path):
    """Static and dynamic steps, the first step (no action), an observation rescaled for underflow,
    and a restored checkpoint (whose constant arrays come back writable) all call the kernels with
    the same argument types (``arrays.frozen``): one compiled version each, not one per write flag
    and layout (numba compiled ``motion_observe`` six times before)."""
    from onlinemap.arrays import frozen
    from onlinemap.kernels.exact import change_every_axis, motion_observe

    assert not frozen(np.zeros(3)).flags.writeable and frozen(np.zeros((3, 2)).T).flags.c_contiguous
    for model in (om.corridor(5, 2), om.corridor(5, 2, p_change=0.05)):
        est = om.make_estimator("exact", model)
        run = random_run(model, 6, seed=1)
        list(beliefs(est, run))
        om.save(est, tmp_path / "exact.npz")
        restored = om.load(tmp_path / "exact.npz")
        restored.step(0, 1)
    tiny = om.grid_model(1, 3, 2, sensor=[[1.0, 1e-300], [0.0, 1.0]], label_prior=[1.0, 0.0])
    om.make_estimator("exact", tiny).step(None, 1)  # probability 1e-300: the rescaled branch
    assert len(motion_observe.signatures) == 1 and len(change_every_axis.signatures) == 1
