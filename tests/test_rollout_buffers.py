"""The footprint rollouts' buffers kept from plan to plan (``plan_rollouts(..., kept=)``, a
:class:`~policies.kernels.rollout_buffers.KeptBuffers`): a plan in reused buffers scores exactly
as one in new buffers, and leaves them empty."""

import numpy as np
import pytest

import onlinemap as om
from onlinemap.estimators.base import ParticleSnapshot
from onlinemap.estimators.rbpf_kernels import world_tables
from policies.kernels import footprint
from policies.kernels.footprint import Agreement, Candidates, plan_rollouts
from policies.kernels.planning import Hypotheses, Scoring
from policies.kernels.rollout_buffers import KeptBuffers
from policies.rollouts import agreement, rollout_tables


def _plan_inputs(model, seed, r_count=16, horizon=7, n_seq=6, worlds=3):
    """A plan's arguments but ``out``, drawn from ``seed``: particles whose maps differ on a third
    of the cells, fixed and closed-loop candidates, random worlds; every cell's label is drawn."""
    rng = np.random.default_rng(seed)
    n = model.n_cells
    maps = np.repeat(rng.dirichlet(np.ones(4), size=n)[None], r_count, axis=0)
    maps[:, ::3] = rng.dirichlet(np.ones(4), size=(r_count, (n + 2) // 3))
    particles = ParticleSnapshot(rng.integers(0, n, r_count), maps, np.log(rng.dirichlet(np.ones(r_count))))
    tables = rollout_tables(model, horizon)
    sequences = rng.integers(0, 4, (n_seq, horizon))
    sequences[n_seq // 2:] = -1  # in closed loop towards random distance fields
    candidates = Candidates(sequences, rng.random((n_seq, n)) * 10, rng.random((n, 4)))
    change = 0 if model.is_static else n
    hypotheses = Hypotheses(rng.integers(0, n, worlds), rng.integers(0, 4, (worlds, n)),
                            rng.random((worlds, horizon, 6)), rng.random((worlds, horizon, change)),
                            rng.random((worlds, horizon, r_count)))
    checkpoints = np.zeros(horizon + 1, dtype=bool)
    checkpoints[[0, 1, 3, horizon]] = True
    return (particles, world_tables(model), tables, candidates, hypotheses, Scoring(2.0, checkpoints),
            Agreement(*agreement(model, particles, horizon, tables)))


def _scores(inputs, threads, kept):
    out = np.zeros((inputs[3].sequences.shape[0], inputs[3].sequences.shape[1] + 1))
    plan_rollouts(*inputs, out, threads, kept)
    return out


def _assert_empty(works):
    """Every overlay of every rollout state empty, no touched cell, the mixture's sums zero."""
    for work in works:
        ov = work.states.overlays
        assert np.all(ov.index == -1) and np.all(ov.n == 0) and not ov.touched.any()
        assert np.all(work.states.n_touched == 0)
        assert np.all(work.mixture.location == 0.0) and np.all(work.mixture.cells == 0.0)


@pytest.mark.parametrize("p_door", [0.0, 0.05])
@pytest.mark.parametrize("threads", [1, 2])
def test_a_plan_in_kept_buffers_scores_as_in_new_ones(p_door, threads):
    """Plans of different particles, worlds and candidates, one after the other in the same kept
    buffers (and one of another horizon between, which takes new ones): each equals, bit for bit,
    the same plan in new buffers; the buffers are the same arrays from plan to plan while the
    shapes are, and every plan leaves them empty."""
    model, _ = om.door_world(blocking=True, footprint="cross", p_door=p_door)
    plans = [_plan_inputs(model, seed) for seed in range(3)]
    longer = _plan_inputs(model, 9, horizon=10)
    kept, index, before = KeptBuffers(), None, None
    for inputs in plans[:2] + [longer] + plans[1:] + plans[:1]:
        fresh = _scores(inputs, threads, None)
        assert np.array_equal(_scores(inputs, threads, kept), fresh)
        _assert_empty(kept.works)
        now = kept.works[0].states.overlays.index
        assert (now is index) == (before is not None and before.shape == inputs[3].sequences.shape)
        index, before = now, inputs[3].sequences
    assert len(kept.works) == threads
    scores = [_scores(inputs, threads, None) for inputs in plans]
    assert not np.array_equal(scores[0], scores[1])  # the plans differ: reusing stale state would show


def test_a_plan_cut_short_drops_the_kept_buffers(monkeypatch):
    """A rollout that raises (its overlays left written) clears ``kept``: the next plan takes new
    buffers and scores as in new ones."""
    model, _ = om.door_world(blocking=True, footprint="cross")
    inputs = _plan_inputs(model, 4)
    kept = KeptBuffers()
    _scores(inputs, 1, kept)
    rolled = footprint.roll_worlds

    def cut_short(*args):
        args[7].states.overlays.index[0, 0, 0] = 0  # a slot left taken
        raise KeyboardInterrupt

    monkeypatch.setattr(footprint, "roll_worlds", cut_short)
    with pytest.raises(KeyboardInterrupt):
        _scores(inputs, 1, kept)
    assert kept.key is None and kept.works == []
    monkeypatch.setattr(footprint, "roll_worlds", rolled)
    assert np.array_equal(_scores(inputs, 1, kept), _scores(inputs, 1, None))
