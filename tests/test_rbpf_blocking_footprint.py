"""RBPF with blocking labels and sensor footprints (issue 13, DESIGN.md section 7) against a
brute-force enumeration over (location, map) written here from the model's scalars: equal to
1e-12 when Fearnhead-Clifford has room for every trajectory, within Monte-Carlo tolerance with
20,000 particles otherwise; the paper's options are refused where not implemented."""

import functools
import itertools

import numpy as np
import pytest

import onlinemap as om
from estimator_cases import RBPF_THREADS, small_chunks

STATIC_CHANGE = np.eye(2)
DYNAMIC_CHANGE = np.array([[0.9, 0.1], [0.2, 0.8]])
VARIANTS = {"blocking": dict(blocking=[1]), "cross": dict(footprint="cross"),
            "blocking+cross": dict(blocking=[1], footprint="cross"),
            "blocking+pair": dict(blocking=[1], footprint=((0, 0), (0, 1)))}  # reads its cell and the next


def world(shape, variant, dynamic):
    rows, cols = shape
    return om.grid_model(rows, cols, 2, p_obs=0.85, p_move=0.75, change=DYNAMIC_CHANGE if dynamic else STATIC_CHANGE,
                         label_prior=[0.6, 0.4], **VARIANTS[variant])


class BruteForce:
    """P(L_t, M_t | data) over every (l, m), N K^N states, built from DESIGN.md sections 1 and 7:
    the intended neighbour (grid geometry) is entered with ``p_move * [m_j does not block]``, the
    label judged before the step's map change; then every cell changes by C; then each footprint
    offset reads its cell through O, or -1 off the grid."""

    def __init__(self, model):
        self.rows, self.cols, self.k = model.rows, model.cols, model.n_labels
        n = self.rows * self.cols
        self.states = [(l, m) for l in range(n) for m in itertools.product(range(self.k), repeat=n)]
        self.index = {s: i for i, s in enumerate(self.states)}
        self.model = model
        self.moves = [(0, -1), (0, 1)] if self.rows == 1 else [(-1, 0), (0, 1), (1, 0), (0, -1)]
        prior = np.zeros(len(self.states))
        for i, (l, m) in enumerate(self.states):
            if l == model.start:
                prior[i] = np.prod([model.label_prior[c][m[c]] for c in range(n)])
        self.p = prior
        self._transitions = {}

    def cell(self, l, dr, dc):
        r, c = divmod(l, self.cols)
        r, c = r + dr, c + dc
        return r * self.cols + c if 0 <= r < self.rows and 0 <= c < self.cols else -1

    def predict(self, a):
        """p <- p T_a, T_a = motion (given the map before the change) x C on every cell."""
        if a not in self._transitions:
            model, n = self.model, self.rows * self.cols
            maps = list(itertools.product(range(self.k), repeat=n))
            motion = np.zeros((n, len(maps), n))  # [l, m, l2]
            for l, (i, m) in itertools.product(range(n), enumerate(maps)):
                j = self.cell(l, *self.moves[a])
                enter = 0.0 if j < 0 else model.p_move * (not model.blocking[m[j]])
                motion[l, i, l] += 1 - enter
                if enter:
                    motion[l, i, j] += enter
            change = functools.reduce(np.kron, [np.asarray(model.change)] * n)  # [m, m2], cells independent
            self._transitions[a] = np.einsum("lmj,mn->lmjn", motion, change).reshape(len(self.states), -1)
        self.p = self.p @ self._transitions[a]

    def update(self, readings):
        model = self.model
        for i, (l, m) in enumerate(self.states):
            for (dr, dc), z in zip(model.footprint, readings):
                c = self.cell(l, dr, dc)
                self.p[i] *= (z == -1) if c < 0 else (z >= 0) * model.sensor[m[c], z]
        evidence = self.p.sum()
        self.p /= evidence
        return np.log(evidence)

    def marginals(self):
        n = self.rows * self.cols
        location, maps = np.zeros(n), np.zeros((n, self.k))
        for p, (l, m) in zip(self.p, self.states):
            location[l] += p
            maps[np.arange(n), m] += p
        return location, maps


TOURS = {2: ["east", "east", "south", "west", "west", "north", "east", "east"],  # every move possible
         1: ["right"] * 5 + ["left"] * 3}


def run_both(model, n_steps, seed, n_particles, rbpf_seed=0, **options):
    """Yield (belief, exact location, exact map, exact log evidence, est) after each step, on a
    tour of the grid repeated (each intended move exists, so trajectories branch)."""
    tour = TOURS[model.rows]
    run = om.simulate(model, None, (tour * n_steps)[:n_steps - 1], seed=seed)
    est = om.make_estimator("rbpf", model, n_particles=n_particles, seed=rbpf_seed, **options)
    exact = BruteForce(model)
    log_evidence = 0.0
    for t in range(n_steps):
        readings = np.atleast_1d(run.observations[t])
        if t:
            exact.predict(int(run.actions[t - 1]))
        log_evidence += exact.update(readings)
        z = run.observations[t] if model.n_readings > 1 else int(readings[0])
        belief = est.step(None if t == 0 else int(run.actions[t - 1]), z)
        yield (belief, *exact.marginals(), log_evidence, est)


CASES = [(shape, variant, dynamic) for shape in ((2, 3), (1, 6)) for variant in VARIANTS for dynamic in (False, True)]


@pytest.mark.parametrize("threads", RBPF_THREADS)
@pytest.mark.parametrize("shape,variant,dynamic", CASES,
                         ids=[f"{r}x{c}-{v}-{'dynamic' if d else 'static'}" for (r, c), v, d in CASES])
def test_fearnhead_clifford_with_room_for_every_child_equals_brute_force(shape, variant, dynamic, threads,
                                                                         monkeypatch):
    """8 moves: at most 2^8 trajectories, 256 particles: nothing is dropped, exact to 1e-12. (On
    the 2 x 3 grid the cross's off-grid readings tell every cell apart, so one trajectory is
    left: the test then checks the five-cell map update.) Serial and parallel kernels (in chunks
    of 16 particles)."""
    small_chunks(monkeypatch)
    model = world(shape, variant, dynamic)
    live = 0
    for belief, location, maps, log_evidence, est in run_both(model, 9, seed=6, n_particles=256,
                                                              threads=threads):
        np.testing.assert_allclose(belief.location, location, atol=1e-12, rtol=0)
        np.testing.assert_allclose(belief.map, maps, atol=1e-12, rtol=0)
        assert belief.log_evidence == pytest.approx(log_evidence, abs=1e-12)
        assert not est.resampled
        live = max(live, np.count_nonzero(est._weights))
    if not (shape == (2, 3) and "cross" in variant):
        assert live >= 3  # the run branched


MONTE_CARLO = [((1, 6), "blocking", True, {}), ((2, 3), "blocking+pair", True, {}), ((1, 6), "blocking+cross", True, {}),
               ((2, 3), "blocking+pair", True, {"resampling": "residual"}),
               ((1, 6), "blocking+cross", True, {"resampling": "systematic", "proposal": "transition"})]


@pytest.mark.parametrize("shape,variant,dynamic,options", MONTE_CARLO,
                         ids=[f"{r}x{c}-{v}-{o.get('proposal', 'optimal')}-{o.get('resampling', 'fc')}"
                              for (r, c), v, d, o in MONTE_CARLO])
def test_many_particles_match_brute_force_within_monte_carlo_tolerance(shape, variant, dynamic, options):
    """20000 particles over 45 steps (more trajectories than particles, so children are dropped):
    6 standard errors at the step's effective sample size plus 1 / ESS, as for the paper's model;
    the default and the sampling schemes (which draw one of the same children per particle)."""
    model = world(shape, variant, dynamic)
    dropped = False
    for belief, location, maps, log_evidence, est in run_both(model, 45, seed=4, n_particles=20_000, rbpf_seed=1,
                                                              **options):
        dropped |= est.resampled
        ess = belief.effective_sample_size
        for estimate, truth in ((belief.location, location), (belief.map, maps)):
            spread = np.clip(truth * (1 - truth), 0, None)  # rounding can put truth a hair above 1
            tolerance = 6 * np.sqrt(spread / ess) + 1 / ess
            assert np.all(np.abs(estimate - truth) <= tolerance), np.abs(estimate - truth).max()
    assert dropped or "resampling" in options
    assert belief.log_evidence == pytest.approx(log_evidence, abs=5 * np.sqrt(45 / ess))


def test_eager_dynamics_is_refused_with_blocking_or_footprint():
    model = world((2, 3), "blocking+cross", True)
    with pytest.raises(om.ModelError, match="eager"):
        om.make_estimator("rbpf", model, lazy_dynamics=False)


def test_bad_or_impossible_footprint_reading_keeps_everything():
    from estimator_cases import assert_state_unchanged, snapshot

    model = world((2, 3), "blocking+cross", True)
    est = om.make_estimator("rbpf", model, n_particles=20, seed=0)
    run = om.simulate(model, None, steps=4, seed=1)
    for t in range(4):
        est.step(None if t == 0 else int(run.actions[t - 1]), run.observations[t])
    snap = snapshot(est)
    z = np.array(run.observations[3])
    for bad in (z[:3], np.where(z >= 0, 7, z), np.where(z >= 0, -1, z)):
        with pytest.raises(om.InvalidObservationError):
            est.step(0, bad)
    assert_state_unchanged(est, snap)


def test_checkpoint_resume_is_bit_identical(tmp_path):
    model = world((2, 3), "blocking+pair", True)
    run = om.simulate(model, None, (TOURS[2] * 3)[:19], seed=2)
    steps = [(None if t == 0 else int(run.actions[t - 1]), run.observations[t]) for t in range(20)]
    straight = om.make_estimator("rbpf", model, n_particles=16, seed=3)
    expected = [straight.step(*args) for args in steps]
    est = om.make_estimator("rbpf", model, n_particles=16, seed=3)
    for args in steps[:11]:
        est.step(*args)
    om.save(est, tmp_path / "blocking.npz")
    resumed = om.load(tmp_path / "blocking.npz")
    for args, belief in zip(steps[11:], expected[11:]):
        got = resumed.step(*args)
        np.testing.assert_array_equal(got.location, belief.location)
        np.testing.assert_array_equal(got.map, belief.map)
