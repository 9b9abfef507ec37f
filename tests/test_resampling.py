"""Resamplers: unbiased copy counts (mean copies of particle i = P w_i) within a tolerance
derived from the number of draws, reproducibility, and input checks; filterpy's resamplers (the
real package, ``filterpy.monte_carlo``) against ours: where they agree, and the bias of its
residual resampling."""

import numpy as np
import pytest

from onlinemap.peers import filterpy_resamplers, global_numpy_seed
from onlinemap.kernels.resampling import _heapsort, _optimal_threshold, _sorted_threshold
from onlinemap.resampling import RESAMPLERS, effective_sample_size, optimal_resampling

WEIGHTS = {
    "design example": np.array([0.5, 0.3, 0.15, 0.05]),
    "random 10": np.random.default_rng(7).dirichlet(np.full(10, 0.7)),
    "with zeros": np.array([0.0, 0.2, 0.0, 0.45, 0.35, 0.0]),
}
DRAWS = 4000


def mean_copies(resample, weights, draws, seed):
    rng = np.random.default_rng(seed)
    counts = np.zeros(len(weights))
    for _ in range(draws):
        counts += np.bincount(resample(weights, rng), minlength=len(weights))
    return counts / draws


def copy_tolerance(weights, draws, sigmas=5.0):
    """Per-draw copies of particle i have variance at most P w (1 - w) (multinomial) + 1/2 (a
    stratum-edge allowance covering systematic/stratified/residual); the mean over ``draws``
    independent draws has standard deviation at most sqrt(that / draws)."""
    p = len(weights)
    return sigmas * np.sqrt((p * weights * (1 - weights) + 0.5) / draws)


@pytest.mark.parametrize("scheme", sorted(RESAMPLERS))
@pytest.mark.parametrize("case", sorted(WEIGHTS))
def test_mean_copies_equal_p_times_weight(scheme, case):
    weights = WEIGHTS[case]
    observed = mean_copies(RESAMPLERS[scheme], weights, DRAWS, seed=1)
    expected = len(weights) * weights
    tolerance = copy_tolerance(weights, DRAWS)
    assert np.all(np.abs(observed - expected) <= tolerance), (observed, expected, tolerance)
    assert observed[weights == 0].max(initial=0) == 0  # a zero weight is never copied


@pytest.fixture
def filterpy():
    """filterpy's resamplers by our scheme names (the test extra installs filterpy)."""
    pytest.importorskip("filterpy")
    return filterpy_resamplers()


def filterpy_copies(resample, weights, draws, seed):
    """Mean copies of each particle over ``draws`` calls of a filterpy resampler. filterpy draws
    from numpy's global random state (onlinemap never does): it is seeded here, for this test only,
    and restored afterwards (``global_numpy_seed``), so no other test sees a change."""
    with global_numpy_seed(seed):
        return mean_copies(lambda w, _rng: resample(w), weights, draws, seed)


@pytest.mark.parametrize("scheme", ["systematic", "stratified", "multinomial"])
@pytest.mark.parametrize("case", sorted(WEIGHTS))
def test_filterpy_unbiased_resamplers_agree_with_ours(scheme, case, filterpy):
    """filterpy's systematic, stratified and multinomial resampling copy particle i P w_i times on
    average, as ours do: its mean copies are within ``copy_tolerance`` (5 standard deviations of
    the mean of DRAWS draws) of P w, and differ from ours by at most sqrt(2) times that (two
    independent means: the variances add); a zero weight is never copied."""
    weights = WEIGHTS[case]
    theirs = filterpy_copies(filterpy[scheme], weights, DRAWS, seed=1)
    ours = mean_copies(RESAMPLERS[scheme], weights, DRAWS, seed=1)
    tolerance = copy_tolerance(weights, DRAWS)
    assert np.all(np.abs(theirs - len(weights) * weights) <= tolerance), (theirs, weights, tolerance)
    assert np.all(np.abs(theirs - ours) <= np.sqrt(2) * tolerance), (theirs, ours, tolerance)
    assert theirs[weights == 0].max(initial=0) == 0


def test_filterpy_and_ours_draw_the_same_where_nothing_is_left_to_chance(filterpy):
    """Weights with every P w_i an integer: residual resampling makes floor(P w_i) = P w_i copies
    and draws nothing; each stratum [j/P, (j+1)/P) of systematic and stratified resampling lies
    inside one particle's share of [0, 1), so any uniform picks it. Both libraries: [0, 0, 1, 2]."""
    weights = np.array([0.5, 0.25, 0.25, 0.0])
    for scheme in ("residual", "systematic", "stratified"):
        with global_numpy_seed(0):  # filterpy draws from numpy's global state: seeded here only, restored
            theirs = filterpy[scheme](weights)
        np.testing.assert_array_equal(theirs, [0, 0, 1, 2])
        np.testing.assert_array_equal(RESAMPLERS[scheme](weights, np.random.default_rng(0)), [0, 0, 1, 2])


def test_filterpy_residual_is_biased_and_the_check_catches_it(filterpy):
    """filterpy's residual_resample takes the residuals as w - floor(P w) instead of P w - floor(P w).
    With w = [.5, .3, .15, .05], P = 4 (DESIGN.md section 6): floor(P w) = [2, 1, 0, 0] copies, and
    the one copy left is drawn from the "residuals" [-1.5, -.7, .15, .05] / -2 = [.75, .35, -.075,
    -.025], cumulated to [.75, 1.1, 1.025, 1] (the last forced to 1) and binary-searched as if
    sorted: particle 0 for a uniform below .75, particle 1 above. Mean copies [2.75, 1.25, 0, 0],
    copy shares [.6875, .3125, 0, 0] instead of w. That copy is a Bernoulli(.75) between particles
    0 and 1, so the share of each over ``draws`` draws has standard deviation sqrt(.75 .25 / draws)
    / 4: the tolerance is 5 of them. The unbiasedness check of the tests above refuses it."""
    weights, draws = WEIGHTS["design example"], 2000
    before = np.random.get_state()
    observed = filterpy_copies(filterpy["residual"], weights, draws, seed=1)
    after = np.random.get_state()  # numpy's global state is as it was: the seeding stayed in the test
    assert np.array_equal(before[1], after[1]) and before[2:] == after[2:]
    np.testing.assert_allclose(observed / 4, [0.6875, 0.3125, 0, 0], rtol=0,
                               atol=5 * np.sqrt(0.75 * 0.25 / draws) / 4)
    assert np.all(observed[2:] == 0)  # particles 2 and 3 (P w = .6 and .2 copies) never survive
    assert np.any(np.abs(observed - 4 * weights) > copy_tolerance(weights, draws))
    ours = mean_copies(RESAMPLERS["residual"], weights, draws, seed=1)
    assert np.all(np.abs(ours - 4 * weights) <= copy_tolerance(weights, draws))


@pytest.mark.parametrize("scheme", sorted(RESAMPLERS))
def test_same_seed_same_result_and_shape(scheme):
    weights = WEIGHTS["random 10"]
    a = RESAMPLERS[scheme](weights, np.random.default_rng(3))
    b = RESAMPLERS[scheme](weights, np.random.default_rng(3))
    np.testing.assert_array_equal(a, b)
    assert a.shape == (10,) and a.dtype == np.int64
    assert np.all(np.diff(a) >= 0) and a.min() >= 0 and a.max() < 10
    # unnormalised weights give the same draw as normalised ones
    np.testing.assert_array_equal(RESAMPLERS[scheme](weights * 7.5, np.random.default_rng(3)), a)


@pytest.mark.parametrize("scheme", sorted(RESAMPLERS))
def test_deterministic_cases(scheme):
    rng = np.random.default_rng(0)
    np.testing.assert_array_equal(RESAMPLERS[scheme](np.array([0, 0, 1.0]), rng), [2, 2, 2])
    if scheme != "multinomial":  # equal weights: every particle exactly once
        np.testing.assert_array_equal(RESAMPLERS[scheme](np.full(5, 0.2), rng), np.arange(5))


@pytest.mark.parametrize("bad", [[], [0.0, 0.0], [0.5, -0.1], [np.nan, 1.0], [[0.5, 0.5]]])
def test_bad_weights_are_refused(bad):
    with pytest.raises(ValueError):
        RESAMPLERS["residual"](np.array(bad, dtype=float), np.random.default_rng(0))


def test_effective_sample_size():
    assert effective_sample_size(np.full(8, 0.125)) == pytest.approx(8)
    assert effective_sample_size([0, 0, 3.0]) == pytest.approx(1)
    assert effective_sample_size([1, 1, 0, 0]) == pytest.approx(2)


OPTIMAL_CASES = {  # (weights, n kept)
    "design example, keep 2": (WEIGHTS["design example"], 2),
    "random 10, keep 4": (WEIGHTS["random 10"], 4),
    "with zeros, keep 2": (WEIGHTS["with zeros"], 2),
    "one dominant, keep 3": (np.array([0.9, 0.04, 0.03, 0.02, 0.01]), 3),
    "equal, keep 3 of 7": (np.full(7, 1 / 7), 3),
    "one large, keep 2": (np.array([0.7, 0.1, 0.1, 0.1]), 2),  # c = 0.30, not 1/2 nor 0.3 / 2 (the text)
    "geometric, keep 18 of 22": (2.0 ** -np.arange(22), 18),  # c ~ 7e-6: 8 rounds of the fixed point
    "geometric, keep 22 of 26": (2.0 ** -np.arange(26), 22),  # 9 rounds: past max_rounds, the sort
}


def brute_threshold(weights, n):
    """c with sum_i min(1, w_i / c) = n, by bisection (independent of the sort in the library)."""
    lo, hi = 0.0, 1.0
    for _ in range(200):
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if np.minimum(1, weights / mid).sum() > n else (lo, mid)
    return hi


def test_threshold_of_one_large_child_by_hand():
    """[0.7, 0.1, 0.1, 0.1], keep 2: 0.7 is kept, the three 0.1 share the other place, c = 0.3 (1 +
    3 x 0.1 / 0.3 = 2). A c of 1/2 (the fixed point's start), or 0.3 / 2 (dividing the rest by n
    instead of n - 1), would give 1.6 or 3."""
    kept = optimal_resampling(np.array([0.7, 0.1, 0.1, 0.1]), 2, np.random.default_rng(0))
    assert kept.threshold == pytest.approx(0.3, abs=1e-15)
    assert kept.indices[0] == 0 and kept.indices[1] in (1, 2, 3)
    np.testing.assert_allclose(kept.weights, [0.7, 0.3], rtol=0, atol=1e-15)


@pytest.mark.parametrize("case", sorted(OPTIMAL_CASES))
def test_threshold_solves_sum_of_min_1_w_over_c_equals_n(case):
    """The defining equation, checked directly on c as the library returns it (from
    optimal_resampling, and from both of its solvers: the fixed point and the sort), and the
    count of children at or above c it reports."""
    weights, n = OPTIMAL_CASES[case]
    w = weights / weights.sum()
    assert np.count_nonzero(w) > n  # a threshold only when children must be dropped
    found = [optimal_resampling(w, n, np.random.default_rng(0)).threshold]
    for solver in (_optimal_threshold, _sorted_threshold):
        c, n_large = solver(w, n)
        assert n_large == np.count_nonzero(w >= c) < n
        found.append(c)
    for c in found:
        assert abs(np.minimum(1.0, w / c).sum() - n) <= 1e-12, (c, np.minimum(1.0, w / c).sum())


@pytest.mark.parametrize("walk", ["index order", "shuffled order"])
@pytest.mark.parametrize("case", sorted(OPTIMAL_CASES))
def test_optimal_resampling_is_unbiased_keeps_large_children_and_none_twice(case, walk):
    """Fearnhead-Clifford: the mean new weight of each child over many draws equals its weight (a
    child below c gets weight c with probability w / c: per-draw variance w (c - w), so the mean of
    ``draws`` draws has standard deviation sqrt(w (c - w) / draws)); every child with w >= c is
    kept every time with its own weight; none is kept twice; at most n are kept, exactly n when
    more than n are positive; zero weights are never kept."""
    weights, n = OPTIMAL_CASES[case]
    weights = weights / weights.sum()
    c = brute_threshold(weights, n)
    rng = np.random.default_rng(2)
    draws = 5000
    large = weights >= c
    order = np.arange(len(weights)) if walk == "index order" else np.random.default_rng(5).permutation(len(weights))
    position = np.argsort(order)  # each child's position in the walk
    count = min(n, np.count_nonzero(weights))
    new_weight = np.zeros((draws, len(weights)))  # draw by draw, each child's new weight
    for draw in range(draws):
        kept = optimal_resampling(weights, n, rng, order)
        walked = position[kept.indices]  # increasing: in walk order, and so none twice
        assert len(walked) == count and np.all(walked[1:] > walked[:-1])
        assert abs(kept.threshold - c) <= 1e-9 * c and abs(kept.weights.sum() - 1) <= 1e-12
        new_weight[draw, kept.indices] = kept.weights
    assert np.array_equal(new_weight[:, large], np.broadcast_to(weights[large], (draws, large.sum())))  # own weight
    small = new_weight[:, ~large]
    assert np.all(np.abs(small - c) <= 1e-9 * c, where=small > 0)
    mean_weight = new_weight.mean(axis=0)
    tolerance = 5 * np.sqrt(weights * np.maximum(c - weights, 0) / draws) + 1e-12
    assert np.all(np.abs(mean_weight - weights) <= tolerance), (mean_weight, weights, tolerance)


def test_optimal_resampling_keeps_everything_when_few_children():
    weights = np.array([0.0, 3.0, 1.0, 0.0])
    kept = optimal_resampling(weights, 2, np.random.default_rng(0))
    np.testing.assert_array_equal(kept.indices, [1, 2])
    np.testing.assert_array_equal(kept.weights, [3.0, 1.0])
    assert kept.threshold == 0
    scaled = optimal_resampling(weights * 0 + [1, 1, 1, 1], 2, np.random.default_rng(0))
    assert scaled.weights.sum() == pytest.approx(4.0) and len(scaled.indices) == 2


@pytest.mark.parametrize("bad,n,order", [([], 1, None), ([0.0, 0.0], 1, None), ([0.5, -0.1], 1, None),
                                         ([1.0, 1.0], 0, None), ([1.0], 1.5, None), ([1.0, 1.0], 1, [0, 0]),
                                         ([1.0, 1.0], 1, [0]), ([1.0, 1.0], 1, [0.0, 1.0])])
def test_optimal_resampling_refuses_bad_input(bad, n, order):
    with pytest.raises(ValueError):
        optimal_resampling(np.array(bad, dtype=float), n, np.random.default_rng(0), order)


def test_optimal_resampling_with_children_below_rounding():
    """Regression (blocking door world, rbpf): when the children below c weigh less than the
    rounding of the others, the threshold search ends with n large children; the kernel divided
    by zero. Now it keeps the n largest and drops mass below float resolution."""
    w = np.array([0.5, 0.5 - 1e-17, 1e-300, 1e-300, 1e-300])
    kept = optimal_resampling(w, 2, np.random.default_rng(0))
    assert sorted(kept.indices.tolist()) == [0, 1]
    assert kept.weights.sum() == pytest.approx(1.0, abs=1e-15)


def test_the_threshold_sort_is_numpys_sort_and_cumulative_sum():
    """``_sorted_threshold`` sorts with its own heapsort (numba's ``np.sort`` costs seconds to
    compile): on arrays with ties, zeros and one element, the heapsort gives ``np.sort``'s array
    and the threshold the one computed from ``np.sort`` and ``np.cumsum`` directly."""
    rng = np.random.default_rng(5)
    cases = [np.array([0.5]), np.zeros(4), rng.random(1), rng.integers(0, 3, 40).astype(float), rng.random(1001),
             np.repeat(rng.random(7), 5), rng.random(64) ** 8]
    for a in cases:
        sorted_ = a.copy()
        _heapsort(sorted_)
        assert np.array_equal(sorted_, np.sort(a))
    for a in cases[3:]:
        w = a / a.sum()
        for n in (1, 2, max(1, w.size // 3)):
            ascending = np.sort(w)
            below = np.cumsum(ascending)
            m = w.size
            expected = next(((below[m - 1 - k] / (n - k), k) for k in range(n)
                             if ascending[m - 1 - k] < below[m - 1 - k] / (n - k)), (ascending[m - n], n))
            assert _sorted_threshold(w, n) == expected


def test_draw_labels_is_inversion_by_numpy_cumsum_and_draws_the_marginals():
    """draw_labels (the draw_by_inversion kernel) gives the labels of numpy's inversion expression
    for the same uniforms: rows not summing to 1, zeros, a read-only broadcast; and over 4000
    draws each label's share is its marginal within 4.5 standard errors."""
    from onlinemap.estimators.base import draw_labels

    def by_numpy(marginals, rng):
        cdf = np.cumsum(marginals, axis=-1)
        u = rng.random(marginals.shape[:-1])[..., None] * cdf[..., -1:]
        return np.minimum((u >= cdf).sum(axis=-1), marginals.shape[-1] - 1).astype(np.int64)

    rng = np.random.default_rng(2)
    for shape in [(3, 7, 2), (5, 50, 4), (0, 3, 2)]:
        marginals = rng.dirichlet(np.ones(shape[-1]), size=shape[:-1])
        if shape[0]:
            marginals[0, 0] = [0.0] + [1.0] * (shape[-1] - 1)
            marginals[-1] *= 3.7
        for m in (marginals, np.broadcast_to(marginals[:1], marginals.shape)):
            got = draw_labels(m, np.random.default_rng(7))
            assert np.array_equal(got, by_numpy(m, np.random.default_rng(7))) and got.dtype == np.int64
    p = np.array([0.1, 0.6, 0.0, 0.3])
    draws = draw_labels(np.broadcast_to(p, (1, 4000, 4)), np.random.default_rng(3))[0]
    share = np.bincount(draws, minlength=4) / 4000
    assert np.all(np.abs(share - p) <= 4.5 * np.sqrt(p * (1 - p) / 4000)) and share[2] == 0.0
