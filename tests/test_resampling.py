"""Resamplers: unbiased copy counts (mean copies of particle i = P w_i) within a tolerance
derived from the number of draws, reproducibility, and input checks."""

import numpy as np
import pytest

from onlinemap.resampling import RESAMPLERS, effective_sample_size

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


def filterpy_residual(weights, rng):
    """filterpy 2.0.0's residual_resample (with an explicit generator): the residuals are taken
    as ``w - floor(P w)`` instead of ``P w - floor(P w)``, which biases the copies."""
    n = len(weights)
    copies = np.floor(n * weights).astype(int)
    indexes = np.repeat(np.arange(n), copies)
    residual = weights - copies
    residual = residual / residual.sum()
    cumulative = np.cumsum(residual)
    cumulative[-1] = 1.0
    rest = np.searchsorted(cumulative, rng.random(n - len(indexes)))
    return np.concatenate([indexes, rest])


@pytest.mark.parametrize("scheme", sorted(RESAMPLERS))
@pytest.mark.parametrize("case", sorted(WEIGHTS))
def test_mean_copies_equal_p_times_weight(scheme, case):
    weights = WEIGHTS[case]
    observed = mean_copies(RESAMPLERS[scheme], weights, DRAWS, seed=1)
    expected = len(weights) * weights
    tolerance = copy_tolerance(weights, DRAWS)
    assert np.all(np.abs(observed - expected) <= tolerance), (observed, expected, tolerance)
    assert observed[weights == 0].max(initial=0) == 0  # a zero weight is never copied


def test_the_check_catches_filterpy_biased_residual():
    weights = WEIGHTS["design example"]
    observed = mean_copies(filterpy_residual, weights, 2000, seed=1)
    np.testing.assert_allclose(observed / 4, [0.69, 0.31, 0, 0], atol=0.02)  # DESIGN.md section 6
    assert np.any(np.abs(observed - 4 * weights) > copy_tolerance(weights, 2000))


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
