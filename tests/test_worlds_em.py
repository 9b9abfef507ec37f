"""Online and offline EM with sensor footprints and blocking labels (issue 13) against dense
references written here: emission products and per-cell counts by loops over (step, location,
offset), dense motion rebuilt from the grid geometry (tests/oracles.py), one Baum-Welch
iteration, online EM step by step, and closed-form counts when the location is known."""

import numpy as np
import pytest

import onlinemap as om
from estimator_cases import beliefs
from onlinemap.estimators.offline_em import baum_welch
from onlinemap.hmm import forward_backward, forward_filter
from oracles import footprint_reads, grid_targets


def dense_emission(model, emission, observations):
    """(W, N) P(z_t | L = l; B) by loops over offsets (off-grid: -1 with probability 1)."""
    reads = footprint_reads(model.rows, model.cols, model.footprint)
    out = np.ones((len(observations), model.n_cells))
    for t, z in enumerate(observations):
        for l in range(model.n_cells):
            for cell, reading in zip(reads[l], np.atleast_1d(z)):
                out[t, l] *= float(reading == -1) if cell is None else \
                    (0.0 if reading == -1 else emission[cell, reading])
    return out


def dense_counts(model, posterior, observations):
    reads = footprint_reads(model.rows, model.cols, model.footprint)
    counts = np.zeros((model.n_cells, model.n_labels))
    for t, z in enumerate(observations):
        for l in range(model.n_cells):
            for cell, reading in zip(reads[l], np.atleast_1d(z)):
                if cell is not None and reading >= 0:
                    counts[cell, reading] += posterior[t, l]
    return counts


def dense_motion(model, passable):
    """(A, N, N): the intended cell j is reached with p_move passable[j] (1 everywhere: the paper)."""
    targets = grid_targets(model.rows, model.cols)
    table = np.zeros((len(targets), model.n_cells, model.n_cells))
    for a, l in np.ndindex(targets.shape):
        j = targets[a, l]
        p = 0.0 if j < 0 else model.p_move * passable[j]
        table[a, l, l] += 1 - p
        if j >= 0:
            table[a, l, j] += p
    return table


def passability(model, emission):
    """P(cell passable) under the map read off B through the inverse sensor (clipped, renormalised)."""
    maps = np.clip(emission @ np.linalg.inv(model.sensor), 0, 1)
    maps /= maps.sum(axis=1, keepdims=True)
    return np.maximum(maps @ np.array([0.0 if b else 1.0 for b in model.blocking]), 1e-3)  # the E-step's floor


def dense_smoother(motion, prior, actions, likelihoods):
    filtered, norms = [], []
    for t, lik in enumerate(likelihoods):
        p = (prior if t == 0 else filtered[-1] @ motion[actions[t - 1]]) * lik
        norms.append(p.sum())
        filtered.append(p / p.sum())
    beta, posterior = np.ones(len(prior)), [None] * len(likelihoods)
    for t in range(len(likelihoods) - 1, -1, -1):
        posterior[t] = filtered[t] * beta / (filtered[t] * beta).sum()
        if t > 0:
            beta = motion[actions[t - 1]] @ (likelihoods[t] * beta) / norms[t]
    return np.array(filtered), np.array(posterior), float(np.log(norms).sum())


VARIANTS = {"cross": dict(footprint="cross"), "square": dict(footprint="square"),
            "cross-blocking": dict(footprint="cross", blocking=[1])}


def world(variant, rows=3, cols=3):
    return om.grid_model(rows, cols, 2, p_obs=0.85, p_move=0.7, label_prior=[0.75, 0.25], start=4,
                         **VARIANTS[variant])


@pytest.mark.parametrize("variant", VARIANTS)
def test_one_baum_welch_iteration_equals_the_dense_reference(variant):
    model = world(variant)
    run = om.simulate(model, steps=14, seed=2)
    b0 = np.array(model.label_prior) @ model.sensor
    motion = dense_motion(model, passability(model, b0) if model.has_blocking else np.ones(model.n_cells))
    _, posterior, log_lik = dense_smoother(motion, np.eye(model.n_cells)[model.start], run.actions,
                                           dense_emission(model, b0, run.observations))
    counts = dense_counts(model, posterior, run.observations) + 0.1
    expected = counts / counts.sum(axis=1, keepdims=True)
    fit = baum_welch(model, run.actions, run.observations, n_iter=1, pseudo_count=0.1)
    np.testing.assert_allclose(fit.observation_matrix, expected, atol=1e-12)
    assert fit.objectives[0] == pytest.approx(log_lik + 0.1 * np.log(b0).sum(), abs=1e-9)


@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("window", [3, "max"])
def test_online_em_equals_the_dense_reference_step_by_step(variant, window):
    model = world(variant)
    run = om.simulate(model, steps=10, seed=5)
    start = np.eye(model.n_cells)[model.start]
    emission = np.array(model.label_prior) @ model.sensor
    stats, history = np.zeros_like(emission), []
    est = om.make_estimator("online_em", model, window=window, pseudo_count=0.1)
    for t, belief in enumerate(beliefs(est, run)):
        passable = passability(model, emission) if model.has_blocking else np.ones(model.n_cells)
        motion = dense_motion(model, passable)
        s = 0 if window == "max" else max(0, t - window + 1)
        prior = start if s == 0 else history[s - 1] @ motion[run.actions[s - 1]]
        obs = run.observations[s:t + 1]
        filtered, posterior, _ = dense_smoother(motion, prior, run.actions[s:t], dense_emission(model, emission, obs))
        stats = stats + dense_counts(model, posterior, obs)
        emission = (stats + 0.1) / (stats + 0.1).sum(axis=1, keepdims=True)
        history.append(filtered[-1])
        np.testing.assert_allclose(belief.location, filtered[-1], atol=1e-12)
        np.testing.assert_allclose(belief.observation_matrix, emission, atol=1e-12)


@pytest.mark.parametrize("name", ["online_em", "offline_em"])
def test_known_location_gives_closed_form_counts_of_every_reading(name):
    """p_move = 1: the location is known, so B is the count of each reading of each cell."""
    model = om.grid_model(3, 4, 3, p_obs=0.8, p_move=1.0, footprint="square", start=5)
    run = om.simulate(model, steps=30, seed=7)
    counts = np.full((model.n_cells, 3), 0.5)
    for location, z in zip(run.locations, run.observations):
        for cell, reading in zip(model.footprint_cells[location], z):
            if cell >= 0:
                counts[cell, reading] += 1
    options = dict(window=1) if name == "online_em" else dict(n_iter=3)
    belief = list(beliefs(om.make_estimator(name, model, pseudo_count=0.5, **options), run))[-1]
    np.testing.assert_allclose(belief.observation_matrix, counts / counts.sum(axis=1, keepdims=True), atol=1e-12)


@pytest.mark.parametrize("variant", [*VARIANTS, "paper"])
def test_forward_filter_is_the_dense_filter_and_forward_backwards_forward_pass(variant):
    """``hmm.forward_filter`` against the dense filter (passability drawn per cell, B random, each
    reading's probability scaled so an observation's is near 1e-260 and every step is rescaled
    against underflow), and bit for bit the
    filtered rows and normalisers of ``hmm.forward_backward`` on the same inputs."""
    model = om.grid_model(3, 4, 3) if variant == "paper" else world(variant)
    run = om.simulate(model, steps=12, seed=8)
    rng = np.random.default_rng(9)
    emission = rng.dirichlet(np.ones(model.n_labels), size=model.n_cells) * 10.0 ** (-260 / model.n_readings)
    passable = rng.uniform(0.2, 1.0, size=model.n_cells) if model.has_blocking else None
    prior = rng.dirichlet(np.ones(model.n_cells))
    fit = forward_filter(model, prior, run.actions, run.observations, emission, passable=passable)
    motion = dense_motion(model, np.ones(model.n_cells) if passable is None else passable)
    filtered, _, log_lik = dense_smoother(motion, prior, run.actions,
                                          dense_emission(model, emission, run.observations))
    np.testing.assert_allclose(fit.filtered, filtered, rtol=0, atol=1e-12)
    assert fit.log_normalizers.sum() == pytest.approx(log_lik, rel=1e-12)
    both = forward_backward(model, prior, run.actions, run.observations, emission, passable=passable)
    assert fit.filtered.tobytes() == both.filtered.tobytes()
    assert fit.log_normalizers.tobytes() == both.log_normalizers.tobytes()


def test_forward_filter_names_the_impossible_step():
    model = om.grid_model(3, 4, 3)
    observations = np.array([0, 1, 0, 1, 2, 0])  # only step 4 reads label 2, which B never gives
    emission = np.tile([0.5, 0.5, 0.0], (model.n_cells, 1))
    with pytest.raises(om.ImpossibleObservationError, match="at step 14 has probability zero"):
        forward_filter(model, np.eye(model.n_cells)[model.start], np.zeros(5, dtype=np.int64), observations,
                       emission, first_step=10)
