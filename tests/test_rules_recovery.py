"""The RBPF's recovery from depletion (the class docstring of RaoBlackwellisedPF) on corridors small
enough to work out by hand (issue 43 section 3): the relocation kernel ``exp(-d / 3) / Z`` with Z
over the cells reachable from the particle's last cell, the children needing the fewest reset
cells and no others, and resample-move windows that never start before the step that recovered.

The scale 3 and every expected value are written here, never read from the module.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import onlinemap as om

E1, E2 = math.exp(-1 / 3), math.exp(-2 / 3)  # the kernel at one and two moves, scale 3 cells
Z_FROM_2 = 1 + 2 * E1 + 2 * E2  # Z from cell 2 of a 5-cell corridor: distances 2, 1, 0, 1, 2
LEFT, RIGHT = 0, 1


def walk(est, steps):
    for action, z in steps:
        belief = est.step(action, z)
    return belief


def one_hot(n, cell):
    out = np.zeros(n)
    out[cell] = 1.0
    return out


# --- the relocation kernel ----------------------------------------------------------------------------
def one_cell_corridor():
    """1 x 5 corridor, K = 2, perfect sensor (own cell) and wheels, uniform prior. The robot reads 0 at
    cells 0, 1, 2 (moving right), so the one trajectory knows cells 0-2 hold 0; then it moves left
    (to cell 1, surely) and reads 1, which its map rules out: depletion."""
    model = om.corridor(5, 2, p_obs=1.0, p_move=1.0)
    return model, [(None, 0), (RIGHT, 0), (RIGHT, 0)], (LEFT, 1)


@pytest.mark.parametrize("n_particles", [2, 8])
def test_the_recovered_location_follows_the_kernel_over_the_cells_that_explain_the_reading(n_particles):
    """Relocated from cell 2, a child at cell l weighs K(l | 2) P(z = 1 | l): at cells 0-2 the reading
    needs a reset (ruled out while children without one exist), at cells 3 and 4 (never read) it has
    probability 1/2. So P(3) = e^(-1/3) / (e^(-1/3) + e^(-2/3)) = 0.583, P(4) = 0.417, and the log
    evidence grows by log(1/2 (e^(-1/3) + e^(-2/3)) / Z), Z = 1 + 2 e^(-1/3) + 2 e^(-2/3) (the
    kernel's total over the 5 cells). Both children fit in the slots (one live trajectory)."""
    model, steps, depleting = one_cell_corridor()
    est = om.make_estimator("rbpf", model, n_particles=n_particles, seed=0)
    before = walk(est, steps)
    assert before.location.tolist() == [0, 0, 1, 0, 0]
    after = est.step(*depleting)
    assert after.recovered and est.recoveries == 1
    p3 = E1 / (E1 + E2)
    np.testing.assert_allclose(after.location, [0, 0, 0, p3, 1 - p3], atol=1e-12)
    assert after.log_evidence - before.log_evidence == pytest.approx(math.log(0.5 * (E1 + E2) / Z_FROM_2), abs=1e-12)
    # the map: cells 0-2 still 0 for sure; the child's own cell holds 1, the other unknown cell 1/2
    np.testing.assert_allclose(after.map[:3], [[1, 0]] * 3, atol=1e-12)
    np.testing.assert_allclose(after.map[3], [(1 - p3) * 0.5, p3 + (1 - p3) * 0.5], atol=1e-12)
    np.testing.assert_allclose(after.map[4], [p3 * 0.5, 1 - p3 + p3 * 0.5], atol=1e-12)


def test_one_particle_keeps_one_child_and_the_evidence_sums_the_kernel():
    """With one particle one child is kept (at 3 or 4), but the evidence is the total weight of the
    children: the same log(1/2 (e^(-1/3) + e^(-2/3)) / Z) as with room for both; over seeds the
    child stands at 3 about 58% of the time."""
    model, steps, depleting = one_cell_corridor()
    at_three = 0
    for seed in range(200):
        est = om.make_estimator("rbpf", model, n_particles=1, seed=seed)
        before = walk(est, steps)
        after = est.step(*depleting)
        assert after.recovered
        assert after.log_evidence - before.log_evidence == pytest.approx(math.log(0.5 * (E1 + E2) / Z_FROM_2),
                                                                         abs=1e-12)
        assert after.location.tolist() in ([0, 0, 0, 1, 0], [0, 0, 0, 0, 1])
        at_three += after.location[3] == 1
    p3 = E1 / (E1 + E2)
    assert abs(at_three / 200 - p3) < 4 * math.sqrt(p3 * (1 - p3) / 200)  # 4 standard errors


def test_the_kernel_is_normalised_over_the_cells_reachable_from_the_last_cell():
    """A 2 x 3 grid, K = 2, perfect sensor and wheels, the robot reading 0 at (0, 0) and (0, 1)
    (moving east). Then it moves west (to (0, 0), known 0) and reads 1: the children that need no
    reset stand on the 4 cells never read, (0, 2), (1, 0), (1, 1), (1, 2), at 1, 2, 1, 2 moves from
    (0, 1). Z sums over all 6 cells: 1 + 3 e^(-1/3) + 2 e^(-2/3)."""
    model = om.grid_model(2, 3, 2, p_obs=1.0, p_move=1.0)
    east, west = model.action_names.index("east"), model.action_names.index("west")
    est = om.make_estimator("rbpf", model, n_particles=8, seed=0)
    before = walk(est, [(None, 0), (east, 0)])
    after = est.step(west, 1)
    weights = {2: E1, 3: E2, 4: E1, 5: E2}
    total = sum(weights.values())
    np.testing.assert_allclose(after.location, [0, 0] + [weights[c] / total for c in (2, 3, 4, 5)], atol=1e-12)
    z = 1 + 3 * E1 + 2 * E2
    assert after.log_evidence - before.log_evidence == pytest.approx(math.log(0.5 * total / z), abs=1e-12)


# --- children needing different numbers of reset cells -----------------------------------------------
def test_only_the_children_needing_the_fewest_reset_cells_are_kept():
    """1 x 5 corridor, the sensor reading the robot's cell and its right neighbour (-1 off the grid),
    perfect sensor and wheels. Reading [0, 0] at cells 0, 1, 2 (moving right), the trajectory knows
    cells 0-3 hold 0. Then it moves left and reads [1, 1]. A child at 0, 1 or 2 reads two known
    cells: 2 resets; at 3, the known cell 3 and the unknown 4: 1 reset; at 4 the right reading
    would be -1: impossible. Only the child at 3 (1 reset) counts: location = cell 3; its weight
    K(3 | 2) P(1 | reset to the prior) P(1 | cell 4 unknown) = e^(-1/3) / Z / 4 is the evidence."""
    model = om.corridor(5, 2, p_obs=1.0, p_move=1.0, footprint=((0, 0), (0, 1)))
    zero = np.array([0, 0])
    est = om.make_estimator("rbpf", model, n_particles=16, seed=0)
    before = walk(est, [(None, zero), (RIGHT, zero), (RIGHT, zero)])
    np.testing.assert_allclose(before.map[:4], [[1, 0]] * 4, atol=1e-12)
    after = est.step(LEFT, np.array([1, 1]))
    assert after.recovered
    np.testing.assert_allclose(after.location, one_hot(5, 3), atol=1e-12)
    np.testing.assert_allclose(after.map, [[1, 0]] * 3 + [[0, 1]] * 2, atol=1e-12)
    assert after.log_evidence - before.log_evidence == pytest.approx(math.log(E1 / Z_FROM_2 / 4), abs=1e-12)


def test_children_with_one_reset_lose_to_children_with_none_whatever_their_kernel_weight():
    """The one-cell corridor, but the cells 3 and 4 that need no reset are far: relocated from cell 0
    (the robot read 0 at cell 0 only, then at cell 1 by moving right and back left, p_move 1) the
    children at 2, 3, 4 need no reset; at 0 and 1 (known 0) one each, and however much nearer,
    they get nothing: P(2) : P(3) : P(4) = e^(-2/3) : e^(-1) : e^(-4/3)."""
    model = om.corridor(5, 2, p_obs=1.0, p_move=1.0)
    est = om.make_estimator("rbpf", model, n_particles=8, seed=0)
    before = walk(est, [(None, 0), (RIGHT, 0), (LEFT, 0)])
    assert before.location.tolist() == [1, 0, 0, 0, 0]
    after = est.step(RIGHT, 1)  # to cell 1 (known 0): reading 1 is ruled out
    kernel = np.exp(-np.arange(5) / 3)  # from cell 0: distances 0..4
    expected = np.r_[0, 0, kernel[2:]] / kernel[2:].sum()
    np.testing.assert_allclose(after.location, expected, atol=1e-12)
    assert after.log_evidence - before.log_evidence == pytest.approx(
        math.log(0.5 * kernel[2:].sum() / kernel.sum()), abs=1e-12)


# --- resample-move windows after a recovery -----------------------------------------------------------
def paths(est) -> np.ndarray:
    """(P, t + 1) every particle's path, from the filter's checkpointed path history."""
    return est._history.paths(est.t)


def test_move_windows_never_start_before_the_step_that_recovered():
    """1 x 8 corridor, the sensor reading the robot's cell and its right neighbour (p_obs 0.9; -1 off
    the grid), p_move 0.8, one particle, moves every step with windows of 2 steps ending at t (lag
    0). From cell 5 the robot presses right twice; the particle keeps "it slipped" at step 1 (seed 0:
    path 5, 5), so the readings of step 2, with -1 on the right (only cell 7 gives that), are
    beyond its reach: it recovers at step 2 (path 5, 5, 7). The robot then presses right into the
    end of the corridor. A window starting at step 0 could explain the relocation by motion (5, 6,
    7: one press that moved instead of slipping) and redraw step 1; windows start at or after the
    step that recovered, so the path up to step 2 stays 5, 5, 7 while later windows are proposed
    and accepted."""
    model = om.corridor(8, 2, p_obs=0.9, p_move=0.8, footprint=((0, 0), (0, 1)), start=5)
    est = om.make_estimator("rbpf", model, n_particles=1, seed=0, move_window=2, move_every=1, move_lag=0)
    walk(est, [(None, np.array([0, 0])), (RIGHT, np.array([0, 0]))])
    assert est.particles.tolist() == [5]
    assert est.step(RIGHT, np.array([0, -1])).recovered and est.particles.tolist() == [7]
    assert paths(est).tolist() == [[5, 5, 7]]
    rng = np.random.default_rng(0)
    for _ in range(30):
        est.step(RIGHT, np.array([int(rng.integers(0, 2)), -1]))
        assert paths(est)[0, :3].tolist() == [5, 5, 7], "a window redrew a step before the recovery"
    assert est.recoveries == 1 and est.moves.proposed >= 28 and est.moves.accepted > 0


def test_a_relocated_robot_is_put_down_on_a_passable_cell():
    """1 x 5 corridor, labels 0, 1 passable and 2 blocking, p_obs 0.9 (0.05 for each other label),
    perfect wheels, the sensor reading the robot's cell and its right neighbour. The floor plan
    says cells 0-3 hold 0; cell 4 is unknown (1/3 each). From cell 2 the robot presses right and
    reads [0, -1]: only cell 4 reads -1 on the right, and no particle can be there. The one child
    at cell 4 weighs K(4 | 2) P(cell 4 passable and reads 0) = e^(-2/3) / Z (0.9 + 0.05 + 0) / 3
    (a blocking label holds no robot), and cell 4's marginal becomes [0.9, 0.05, 0] / 0.95."""
    prior = [[1.0, 0.0, 0.0]] * 4 + [[1 / 3] * 3]
    model = om.corridor(5, 3, p_obs=0.9, p_move=1.0, blocking=[2], label_prior=prior,
                        footprint=((0, 0), (0, 1)))
    zero = np.array([0, 0])
    est = om.make_estimator("rbpf", model, n_particles=4, seed=0)
    before = walk(est, [(None, zero), (RIGHT, zero), (RIGHT, zero)])
    assert before.location.tolist() == [0, 0, 1, 0, 0]
    after = est.step(RIGHT, np.array([0, -1]))
    assert after.recovered
    np.testing.assert_allclose(after.location, one_hot(5, 4), atol=1e-12)
    np.testing.assert_allclose(after.map[4], [0.9 / 0.95, 0.05 / 0.95, 0.0], atol=1e-12)
    assert after.log_evidence - before.log_evidence == pytest.approx(math.log(E2 / Z_FROM_2 * 0.95 / 3), abs=1e-12)
