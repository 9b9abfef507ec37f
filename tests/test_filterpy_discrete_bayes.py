"""filterpy's discrete Bayes filter (``filterpy.discrete_bayes``, the real package) against
onlinemap's location filters on corridors with walls: where they agree and where they differ.

filterpy's ``predict(pdf, offset, kernel, mode)`` shifts a belief by ``offset`` cells and
convolves it with ``kernel`` (``kernel[j]``: the probability of moving ``offset - 1 + j`` cells),
so a corridor move (to the intended neighbour with ``p = p_move``, else stay) is ``offset = +1``,
``kernel = (1 - p, p, 0)`` to the right and ``offset = -1``, ``kernel = (0, p, 1 - p)`` to the
left. filterpy knows no walls; onlinemap's motion keeps a robot that walks into a wall where it
is. One right move from the same belief b, N cells (a left move mirrors it, with b[0]):

- b[N-1] = 0 (nothing against the wall): filterpy, either mode, gives onlinemap's prediction;
- ``mode='wrap'``: filterpy - onlinemap = p b[N-1] (e_0 - e_{N-1}): what would cross the wall
  comes back at the other end;
- ``mode='constant'``: filterpy - onlinemap = -b[N-1] e_{N-1}: the whole wall cell is lost, both
  the p b[N-1] that would cross and the (1 - p) b[N-1] that stays (the shift by the offset pushes
  the cell off the array before the kernel brings the stay back), so the total is 1 - b[N-1].

``update(likelihood, prior)`` is Bayes' rule, the same in both libraries at every step. The
references: ``dead_reckoning`` (motion only) for predict, the exact filter on a world whose map
is known (a one-hot label prior: its location marginal is then the location-only discrete Bayes
filter) for predict + update. Tolerance: a few ulps of numbers in [0, 1], summed in another
order (1e-15); after the exact filter's normalisation over its joint, 1e-12.
"""

import numpy as np
import pytest

import onlinemap as om
from onlinemap.model import apply_motion

discrete_bayes = pytest.importorskip("filterpy.discrete_bayes")

P_MOVE = 0.8
N = 7
# into the right wall, across the corridor and into the left wall, then off it again
ACTIONS = ["right"] * 7 + ["left"] * 10 + ["right"] * 3
ROUNDING = 1e-15


def filterpy_predict(belief, action, mode):
    """filterpy's prediction of a corridor move (see the module docstring)."""
    offset, kernel = (1, [1 - P_MOVE, P_MOVE, 0.0]) if action == "right" else (-1, [0.0, P_MOVE, 1 - P_MOVE])
    return discrete_bayes.predict(np.array(belief), offset, kernel, mode=mode)


def wall_difference(belief, action, mode):
    """filterpy's prediction minus onlinemap's, as the module docstring states it: (N,)."""
    wall, far = (len(belief) - 1, 0) if action == "right" else (0, len(belief) - 1)
    difference = np.zeros(len(belief))
    if mode == "wrap":
        difference[far] += P_MOVE * belief[wall]
        difference[wall] -= P_MOVE * belief[wall]
    else:
        difference[wall] -= belief[wall]
    return difference


def location_beliefs(name, model, observations):
    """The location beliefs (N,) of estimator ``name`` along ACTIONS with these observations."""
    est = om.make_estimator(name, model)
    return [est.step(None if t == 0 else ACTIONS[t - 1], z).location for t, z in enumerate(observations)]


def test_one_move_into_a_wall_by_hand():
    """One right move from b = [.1, .2, .3, .15, .25]: inside, (1 - p) b[i] + p b[i-1] everywhere;
    at the wall onlinemap keeps b[4] + p b[3] = .37, filterpy's wrap gives .17 there and .22 (not
    .02) at cell 0, filterpy's constant mode .12 there and a total of .75."""
    model = om.corridor(5, p_move=P_MOVE)
    b = np.array([0.1, 0.2, 0.3, 0.15, 0.25])
    ours = apply_motion(model, b, model.action_names.index("right"))
    np.testing.assert_allclose(ours, [0.02, 0.12, 0.22, 0.27, 0.37], rtol=0, atol=ROUNDING)
    np.testing.assert_allclose(filterpy_predict(b, "right", "wrap"), [0.22, 0.12, 0.22, 0.27, 0.17],
                               rtol=0, atol=ROUNDING)
    constant = filterpy_predict(b, "right", "constant")
    np.testing.assert_allclose(constant, [0.02, 0.12, 0.22, 0.27, 0.12], rtol=0, atol=ROUNDING)
    assert constant.sum() == pytest.approx(0.75, abs=ROUNDING)
    for mode in ("wrap", "constant"):
        np.testing.assert_allclose(filterpy_predict(b, "right", mode) - ours, wall_difference(b, "right", mode),
                                   rtol=0, atol=ROUNDING)


@pytest.mark.parametrize("mode", ["wrap", "constant"])
def test_predict_agrees_with_dead_reckoning_inside_and_differs_at_the_walls_as_stated(mode):
    """Along a walk into both walls, every step: filterpy's prediction from dead reckoning's last
    belief minus dead reckoning's next one is exactly the stated wall term (zero inside)."""
    model = om.corridor(N, p_move=P_MOVE, start=2)
    beliefs = location_beliefs("dead_reckoning", model, [0] * (len(ACTIONS) + 1))
    inside = at_wall = 0
    for action, before, ours in zip(ACTIONS, beliefs, beliefs[1:]):
        expected = wall_difference(before, action, mode)
        np.testing.assert_allclose(filterpy_predict(before, action, mode) - ours, expected, rtol=0, atol=ROUNDING)
        inside += not expected.any()
        at_wall += np.abs(expected).max() > 0.1
    assert inside >= 4 and at_wall >= 4  # both cases happen along the walk


@pytest.mark.parametrize("mode", ["wrap", "constant"])
def test_predict_and_update_agree_with_the_exact_filter_on_a_known_map_away_from_the_walls(mode):
    """The exact filter on a world whose map is known: filterpy's ``update`` (likelihood
    ``O[m_i, z]`` of each cell) of onlinemap's own prediction is onlinemap's belief at every step;
    filterpy's full step (its predict, then update) is too while nothing is against a wall, and
    differs once something is (the prediction's wall term, through Bayes' rule)."""
    truth = np.array([0, 1, 1, 0, 1, 0, 0])
    model = om.corridor(N, p_obs=0.9, p_move=P_MOVE, start=2, label_prior=np.eye(2)[truth])
    observations = np.random.default_rng(4).integers(0, 2, len(ACTIONS) + 1)
    beliefs = location_beliefs("exact", model, observations)
    np.testing.assert_allclose(beliefs[0], discrete_bayes.update(model.sensor[truth, observations[0]],
                                                                 model.location_prior()), rtol=0, atol=1e-12)
    inside = differs = 0
    for action, z, before, ours in zip(ACTIONS, observations[1:], beliefs, beliefs[1:]):
        likelihood = model.sensor[truth, z]
        ours_predicted = apply_motion(model, before, model.action_names.index(action))
        np.testing.assert_allclose(discrete_bayes.update(likelihood, ours_predicted), ours, rtol=0, atol=1e-12)
        theirs = discrete_bayes.update(likelihood, filterpy_predict(before, action, mode))
        if not wall_difference(before, action, mode).any():
            np.testing.assert_allclose(theirs, ours, rtol=0, atol=1e-12)
            inside += 1
        else:
            differs += np.abs(theirs - ours).max() > 0.01
    assert inside >= 4 and differs >= 4  # both cases happen along the walk
