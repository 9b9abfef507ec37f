"""Recovery of the RBPF from particle depletion (issue 21 item 1; DESIGN.md section 8).

When no particle explains an observation the filter takes the exact limit of an augmented motion
model (see :class:`onlinemap.estimators.rbpf.RaoBlackwellisedPF`): the robot may, with a vanishing
probability, be relocated by the kernel ``K(l | l') = exp(-d(l, l') / s) / Z(l')`` (d the grid's
step distance, labels ignored) and, more rarely still, the cells it reads be redrawn from their
model marginals. The tests check: a depleted filter keeps going with valid beliefs, counts and
logs its recoveries; the recovered belief equals that limit computed here by brute force from the
particles before the step (scipy's shortest paths, numpy loops over particles and cells); an
observation the model rules out still raises with the state unchanged bit for bit; runs without
depletion equal the filter before recovery existed (arrays it wrote, tests/data); a checkpoint of a
recovered filter resumes bit for bit; the memory guard counts a recovery's children. (Threads give
a recovering run's serial result bit for bit: test_rbpf_threads.py.)
"""

from __future__ import annotations

import logging
import re
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.sparse.csgraph import shortest_path

import onlinemap as om
from onlinemap import checkpoint
from onlinemap.estimators import rbpf as rbpf_module
from onlinemap.estimators import rbpf_memory, rbpf_recovery
from estimator_cases import assert_valid_belief, beliefs

DATA = Path(__file__).parent / "data"
DOOR = om.door_world(blocking=True, footprint="cross")
SCHEMES = {"fc": {}, "transition": dict(resampling="residual", proposal="transition")}
LOGGER = "onlinemap.estimators.rbpf"


def depleting_run():
    """100 steps of a random walk in the blocking + cross door world, uniform label prior. The filter
    before recovery existed raised ImpossibleObservationError on it with 1 and 5 particles, default
    (Fearnhead-Clifford; at step 47 both) and transition + residual (steps 6 and 10: there every
    draw had missed, and the filter now enumerates the successors instead); now each of the four
    relocates its particles at least once (first at step 47)."""
    model, true_map = DOOR
    return om.simulate(model, true_map, steps=100, seed=38)


def pattern_fits(model, cell, readings) -> bool:
    """Whether a robot at ``cell`` can see ``readings``' off-grid pattern (-1 exactly off the grid)."""
    return bool(np.array_equal(model.footprint_cells[cell] < 0, np.asarray(readings) < 0))


@pytest.mark.parametrize("n_particles", [1, 5])
@pytest.mark.parametrize("scheme", SCHEMES)
def test_a_depleted_filter_recovers_keeps_going_and_says_so(n_particles, scheme, caplog):
    """Every step gives a valid distribution; ``recoveries`` counts the beliefs marked recovered,
    one warning names each of those steps; and each recovery happened where the filter had no way
    on: no live particle could stay or make the move into a cell whose off-grid pattern fits the
    readings (the door world's sensor has no zero entry, so that pattern is the clue that ruled
    every particle out)."""
    model = DOOR[0]
    run = depleting_run()
    est = om.make_estimator("rbpf", model, n_particles=n_particles, seed=38, **SCHEMES[scheme])
    recovered = []
    with caplog.at_level(logging.WARNING, logger=LOGGER):
        for t in range(run.n_steps):
            action = None if t == 0 else int(run.actions[t - 1])
            live = est._locations[est._weights > 0].copy()
            belief = est.step(action, run.observations[t])
            assert_valid_belief(belief, model, t, atol=1e-12)
            if belief.recovered:
                recovered.append(t)
                assert action is not None
                successors = np.concatenate([live, model.moves[action, live]])
                assert not any(pattern_fits(model, c, run.observations[t]) for c in successors)
    assert est.recoveries == len(recovered) >= 1
    messages = [r.getMessage() for r in caplog.records if r.name == LOGGER and r.levelno == logging.WARNING]
    assert [int(re.search(r"step (\d+)", m).group(1)) for m in messages] == recovered
    assert all("depletion" in m for m in messages)


# --- the recovered belief against the augmented model's limit, by brute force ------------------------
def distances(model) -> np.ndarray:
    """(N, N) shortest step distance between cells, labels ignored (inf where unreachable)."""
    n = model.n_cells
    linked = np.zeros((n, n))
    for a in range(model.n_actions):
        movers = np.flatnonzero(model.neighbors[:, a] != np.arange(n))
        linked[movers, model.neighbors[movers, a]] = 1.0
    return shortest_path(sp.csr_array(linked), unweighted=True)


def recovery_reference(est, action, readings):
    """(location (N,), map (N, K), log evidence increment) of the exact limit of the augmented model,
    from ``est``'s particles before the step: child (p, l) weighs ``w_p K(l | l_p) P(z, l passable |
    l, map_p)`` where each cell the child reads (and l itself, with blocking labels: the robot is put
    down on a passable cell) keeps particle p's marginal at step t unless that marginal rules out
    what the child sees of it, in which case it is redrawn from the model's marginal at step t
    ``label_prior C^t`` (a reset); only the children with the fewest resets count."""
    model = est.model
    t = est.t + 1
    readings = np.atleast_1d(readings)
    maps = est.particle_maps() @ model.change  # every particle's map at step t
    prior = model.label_prior @ np.linalg.matrix_power(model.change, t)
    scale = rbpf_recovery.RELOCATION_SCALE
    d = distances(model)
    children = []  # (resets, log weight, location, map)
    for p in np.flatnonzero(est._weights > 0):
        lp = est._locations[p]
        kernel = np.where(np.isfinite(d[lp]), np.exp(-d[lp] / scale), 0.0)
        kernel /= kernel.sum()
        for l in range(model.n_cells):
            if kernel[l] == 0 or not pattern_fits(model, l, readings):
                continue
            factors = {}  # cell -> (K,) what the child sees of it
            if model.has_blocking:
                factors[l] = (~model.blocking).astype(float)
            for f, c in enumerate(model.footprint_cells[l]):
                if c >= 0:
                    factors[c] = factors.get(c, np.ones(model.n_labels)) * model.sensor[:, readings[f]]
            child, weight, resets = maps[p].copy(), est._weights[p] * kernel[l], 0
            for c, g in factors.items():
                marginal = maps[p, c]
                if marginal @ g == 0:
                    marginal, resets = prior[c], resets + 1
                weight *= marginal @ g
                child[c] = marginal * g / (marginal @ g) if marginal @ g > 0 else np.nan
            if weight > 0:
                children.append((resets, weight, l, child))
    fewest = min(r for r, *_ in children)
    children = [c for c in children if c[0] == fewest]
    total = sum(w for _, w, _, _ in children)
    location, maps_out = np.zeros(model.n_cells), np.zeros((model.n_cells, model.n_labels))
    for _, w, l, child in children:
        location[l] += w / total
        maps_out += w / total * child
    return location, maps_out, np.log(total)


def step_all(est, steps):
    for action, z in steps:
        est.step(action, z)


def assert_recovery_equals_reference(est, action, z):
    location, maps, increment = recovery_reference(est, action, z)
    before, count = est.belief.log_evidence, est.recoveries
    belief = est.step(action, z)
    assert belief.recovered and est.recoveries == count + 1
    np.testing.assert_allclose(belief.location, location, atol=1e-12, rtol=0)
    np.testing.assert_allclose(belief.map, maps, atol=1e-12, rtol=0)
    assert belief.log_evidence - before == pytest.approx(increment, abs=1e-12)
    return belief


GRID_4X4 = dict(p_obs=0.85, p_move=0.75, change=[[0.9, 0.1], [0.2, 0.8]], label_prior=[0.6, 0.4], blocking=[1],
                footprint="cross")


def test_fearnhead_clifford_recovery_with_room_for_every_child_equals_the_limit():
    """4 x 4 grid, blocking label 1, dynamic map, a sensor reading its cell and the one to the north.
    Three moves east along the top row (the north reading -1), then a move east and readings with no
    -1: a robot in the top row cannot see them, so every particle fails; the 12 cells below the top
    row fit. At most 8 live particles x 12 cells = 96 children <= 128 particles: nothing is dropped
    and the belief is the limit exactly."""
    model = om.grid_model(4, 4, 2, **{**GRID_4X4, "footprint": ((0, 0), (-1, 0))})
    run = om.simulate(model, None, ["east"] * 3, seed=1)
    est = om.make_estimator("rbpf", model, n_particles=128, seed=0)
    step_all(est, [(None if t == 0 else int(run.actions[t - 1]), run.observations[t]) for t in range(4)])
    assert np.count_nonzero(est._weights) >= 2  # the trajectories branched: parents at different cells
    belief = assert_recovery_equals_reference(est, 1, np.array([0, 1]))
    assert not est.resampled and np.count_nonzero(belief.location) == 12
    belief = est.step(0, np.array([0, 0]))  # it continues from the recovered particles
    assert_valid_belief(belief, model, 5, atol=1e-12)


@pytest.mark.parametrize("p_change", [0.0, 0.1])
def test_sampling_recovery_with_one_cell_that_fits_equals_the_limit(p_change):
    """3 x 3 grid with the cross footprint: only the centre reads no -1. The transition proposal with
    residual resampling, 40 particles (duplicates of few trajectories) along the top row; then
    readings only the centre can give. Every slot has one child (its parent, relocated to the
    centre), so optimal resampling keeps all 40 and the belief is the limit exactly; the slots
    carry different maps, so the map mixture tests the weights."""
    change = [[1 - p_change, p_change], [2 * p_change, 1 - 2 * p_change]]
    model = om.grid_model(3, 3, 2, **{**GRID_4X4, "change": change})
    run = om.simulate(model, None, ["east", "east"], seed=3)
    est = om.make_estimator("rbpf", model, n_particles=40, seed=2, **SCHEMES["transition"])
    step_all(est, [(None if t == 0 else int(run.actions[t - 1]), run.observations[t]) for t in range(3)])
    assert_recovery_equals_reference(est, 1, np.array([1, 0, 0, 1, 0]))


@pytest.mark.parametrize("scheme", SCHEMES)
def test_when_every_map_rules_the_reading_out_the_read_cell_is_reset(scheme):
    """A perfect sensor (p_obs = 1) on a 5-cell corridor with no slips: every particle has read
    label 0 in every cell, so reading 1 is impossible anywhere under every particle's map (but
    possible under the model: the prior gives label 1 probability 0.5). The limit then resets the
    one cell read: that cell's label is 1 and every other cell keeps label 0. Fearnhead-Clifford
    keeps one trajectory (no slips), so its 5 children fit in 8 particles and the belief is the
    limit exactly: the location follows the kernel around cell 2 (a relocation ignores the action).
    The sampling scheme's 8 identical slots have 40 children: its particles are checked one by one."""
    model = om.corridor(5, 2, p_obs=1.0, p_move=1.0)
    est = om.make_estimator("rbpf", model, n_particles=8, seed=0, **SCHEMES[scheme])
    step_all(est, [(None, 0)] + [("right", 0)] * 4 + [("left", 0)] * 2)
    if scheme == "fc":
        belief = assert_recovery_equals_reference(est, 0, 1)
        kernel = np.exp(-np.abs(np.arange(5) - 2) / rbpf_recovery.RELOCATION_SCALE)
        np.testing.assert_allclose(belief.location, kernel / kernel.sum(), atol=1e-12)
    else:
        assert est.step(0, 1).recovered
    maps = est.particle_maps()
    for p in np.flatnonzero(est._weights > 0):
        expected = np.tile([1.0, 0.0], (5, 1))
        expected[est._locations[p]] = [0.0, 1.0]
        np.testing.assert_array_equal(maps[p], expected)


@pytest.mark.parametrize("lazy", [True, False], ids=["lazy", "eager"])
def test_a_reset_in_a_dynamic_world_takes_the_model_marginal_at_that_step(lazy):
    """Label 0 is absorbing (C = [[1, 0], [0.1, 0.9]]) and the sensor perfect: after every cell read
    0, reading 1 is ruled out by every particle's map but not by the model, whose marginal at step
    t gives label 1 probability 0.5 * 0.9^t. The recovery equals the limit (the reset cell drawn
    from that marginal), with lazy dynamics and with C applied to every cell every step."""
    model = om.grid_model(1, 5, 2, p_obs=1.0, p_move=1.0, change=[[1.0, 0.0], [0.1, 0.9]], label_prior=[0.5, 0.5])
    est = om.make_estimator("rbpf", model, n_particles=8, seed=0, lazy_dynamics=lazy)
    step_all(est, [(None, 0)] + [(1, 0)] * 4 + [(0, 0)] * 2)
    belief = assert_recovery_equals_reference(est, 0, 1)
    assert belief.map[:, 1].max() == pytest.approx(belief.location.max(), abs=1e-12)  # label 1 where it stands


# --- what the model rules out still raises, with everything unchanged ---------------------------------
def impossible_cases():
    """(id, model, observation, action): a 3 x 3 grid with the cross footprint whose centre is a wall
    for sure: only the centre reads no -1, and no robot stands in a wall (a relocated one is put down
    on a passable cell); a sensor that never reads label 2; a perfect sensor in a corridor whose
    cells all hold label 0 for sure, reading 1."""
    prior = np.tile([0.6, 0.4], (9, 1))
    prior[4] = [0.0, 1.0]
    walled = om.grid_model(3, 3, 2, p_obs=0.85, label_prior=prior, blocking=[1], footprint="cross")
    never_read = om.grid_model(2, 3, 3, p_obs=0.9, sensor=[[0.9, 0.1, 0], [0.1, 0.9, 0], [0.5, 0.5, 0]])
    certain = om.corridor(4, 2, p_obs=1.0, p_move=0.6, p_change=0.0, label_prior=[1.0, 0.0])
    return [("walled-centre", walled, np.array([0, 0, 0, 0, 0]), 1), ("sensor-column-zero", never_read, 2, 0),
            ("certain-map", certain, 1, 1)]


@pytest.mark.parametrize("scheme", SCHEMES)
@pytest.mark.parametrize("case", impossible_cases(), ids=lambda c: c[0])
def test_an_observation_the_model_rules_out_raises_and_changes_nothing(case, scheme):
    """Every particle fails and no cell, with any labels the model allows at that step, explains
    it: the step raises ImpossibleObservationError (saying so) and the state, generator included,
    is bit for bit what it was (its state_dict)."""
    _, model, z, action = case
    est = om.make_estimator("rbpf", model, n_particles=6, seed=4, **SCHEMES[scheme])
    run = om.simulate(model, None, steps=5, seed=0)
    step_all(est, [(None if t == 0 else int(run.actions[t - 1]), run.observations[t]) for t in range(5)])
    before = est.state_dict()
    with pytest.raises(om.ImpossibleObservationError, match="impossible under the model"):
        est.step(action, z)
    assert checkpoint.first_difference(est.state_dict(), before) is None
    assert est.recoveries == 0


# --- no depletion: the filter before recovery existed, step for step ---------------------------------
NO_DEPLETION = {"fc": dict(n_particles=20), "transition": dict(n_particles=20, **SCHEMES["transition"]),
                "fc-dynamic": dict(n_particles=20)}


def no_depletion_runs():
    """(name, estimator, steps) of the runs stored in tests/data/rbpf_no_depletion.npz: 40 steps of
    the blocking + cross door world (static; and doors that swap with 0.02), 20 particles, seed 0,
    none of which depletes. The file was written by this function with the code of main at 7cd9b32
    (before recovery existed): ``write_no_depletion(path)``."""
    for name, options in NO_DEPLETION.items():
        model, true_map = om.door_world(blocking=True, footprint="cross", p_door=0.02 if "dynamic" in name else 0.0)
        run = om.simulate(model, true_map, steps=40, seed=0)
        steps = [(None if t == 0 else int(run.actions[t - 1]), run.observations[t]) for t in range(run.n_steps)]
        yield name, om.make_estimator("rbpf", model, seed=0, **options), steps


def write_no_depletion(path):
    arrays = {}
    for name, est, steps in no_depletion_runs():
        got = [est.step(*args) for args in steps]
        arrays[f"{name}_location"] = np.array([b.location for b in got])
        arrays[f"{name}_map"] = got[-1].map
        arrays[f"{name}_evidence"] = np.array([b.log_evidence for b in got])
        arrays[f"{name}_ess"] = np.array([b.effective_sample_size for b in got])
        arrays[f"{name}_generator"] = np.array(str(est._rng.bit_generator.state))
    np.savez(path, **arrays)


def test_runs_without_depletion_equal_the_filter_before_recovery(monkeypatch):
    """Recovery only runs where the filter used to raise: on runs where some particle explains
    every observation, the beliefs equal those the filter wrote before recovery existed and the
    generator has made the same draws (its state equal). Bit for bit on the machine that wrote the
    file; to 1e-13 across machines (numpy and numba pick their floating-point kernels by CPU; see
    test_block_pool's format-1 test). The recovery is patched to fail, so it is never entered."""
    monkeypatch.setattr(rbpf_module.RaoBlackwellisedPF, "_recover",
                        lambda *args: pytest.fail("recovery ran on a run without depletion"))
    stored = np.load(DATA / "rbpf_no_depletion.npz")
    for name, est, steps in no_depletion_runs():
        got = [est.step(*args) for args in steps]
        np.testing.assert_allclose([b.location for b in got], stored[f"{name}_location"], rtol=1e-13, atol=1e-15)
        np.testing.assert_allclose(got[-1].map, stored[f"{name}_map"], rtol=1e-13, atol=1e-15)
        np.testing.assert_allclose([b.log_evidence for b in got], stored[f"{name}_evidence"], rtol=1e-13)
        np.testing.assert_allclose([b.effective_sample_size for b in got], stored[f"{name}_ess"], rtol=1e-12)
        assert str(est._rng.bit_generator.state) == str(stored[f"{name}_generator"])
        assert est.recoveries == 0 and not any(b.recovered for b in got)


# --- checkpoints ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("scheme", SCHEMES)
def test_a_recovered_filter_resumes_from_its_checkpoint_bit_for_bit(scheme, tmp_path):
    model = DOOR[0]
    run = depleting_run()
    steps = [(None if t == 0 else int(run.actions[t - 1]), run.observations[t]) for t in range(run.n_steps)]
    straight = om.make_estimator("rbpf", model, n_particles=5, seed=38, **SCHEMES[scheme])
    expected = [straight.step(*args) for args in steps]
    first = next(t for t, b in enumerate(expected) if b.recovered)
    est = om.make_estimator("rbpf", model, n_particles=5, seed=38, **SCHEMES[scheme])
    step_all(est, steps[:first + 1])
    om.save(est, tmp_path / "recovered.npz")
    resumed = om.load(tmp_path / "recovered.npz")
    assert resumed.recoveries == est.recoveries >= 1 and resumed.belief.recovered
    for args, belief in zip(steps[first + 1:], expected[first + 1:]):
        got = resumed.step(*args)
        np.testing.assert_array_equal(got.location, belief.location)
        np.testing.assert_array_equal(got.map, belief.map)
        assert got.log_evidence == belief.log_evidence and got.recovered == belief.recovered
    assert resumed.recoveries == straight.recoveries
    assert checkpoint.first_difference(resumed.state_dict(), straight.state_dict()) is None


def test_a_checkpoint_from_before_recovery_loads_with_no_recoveries():
    """Format version 2 had no recovery count: such a state loads as a filter that never recovered."""
    model = DOOR[0]
    est = om.make_estimator("rbpf", model, n_particles=5, seed=0)
    run = om.simulate(model, DOOR[1], steps=3, seed=0)
    step_all(est, [(None if t == 0 else int(run.actions[t - 1]), run.observations[t]) for t in range(3)])
    state = est.state_dict()
    old = {**state, "format_version": 2,
           "attributes": {k: v for k, v in state["attributes"].items() if k not in ("_recoveries", "_recovered")}}
    twin = om.make_estimator("rbpf", model, n_particles=5, seed=0)
    twin.load_state_dict(old)
    assert twin.recoveries == 0 and checkpoint.first_difference(twin.state_dict(), state) is None


def test_track_reports_recoveries_on_stdout_and_as_json_on_stderr(monkeypatch, capsys):
    """``onlinemap track`` (a robot loop behind a pipe): a recovered step's record says
    ``"recovered": true``, and the warning arrives on stderr as a JSON event naming the step,
    like every other stderr line."""
    import io
    import json
    import sys

    from onlinemap.cli import main

    run = depleting_run()
    lines = [json.dumps({"observation": run.observations[t].tolist(),
                         **({"action": int(run.actions[t - 1])} if t else {})}) for t in range(run.n_steps)]
    monkeypatch.setattr(sys, "stdin", io.StringIO("\n".join(lines) + "\n"))
    assert main(["track", "--world", "door,blocking=1,footprint=cross", "--estimator", "rbpf",
                 "--option", "n_particles=1", "--option", "seed=38"]) == 0
    out, err = capsys.readouterr()
    recovered = [record["t"] for record in map(json.loads, out.splitlines()) if record.get("recovered")]
    est = om.make_estimator("rbpf", DOOR[0], n_particles=1, seed=38)
    assert recovered == [b.t for b in beliefs(est, run) if b.recovered] and recovered
    events = [json.loads(line) for line in err.splitlines()]
    warned = [e for e in events if e.get("event") == "log" and e["level"] == "WARNING"]
    assert [int(re.search(r"step (\d+)", e["message"]).group(1)) for e in warned] == recovered


@pytest.mark.parametrize("scheme", SCHEMES)
def test_with_recovery_off_a_depleted_step_raises_and_changes_nothing(scheme):
    """``recover_from_depletion = False``: the step that recovers in the reset test raises instead,
    saying the particles may have lost the trajectory, and the state is bit for bit unchanged; the
    switch is part of the checkpointed state."""
    model = om.corridor(5, 2, p_obs=1.0, p_move=1.0)
    est = om.make_estimator("rbpf", model, n_particles=8, seed=0, **SCHEMES[scheme])
    step_all(est, [(None, 0)] + [("right", 0)] * 4 + [("left", 0)] * 2)
    est.recover_from_depletion = False
    before = est.state_dict()
    with pytest.raises(om.ImpossibleObservationError, match="particle depletion"):
        est.step(0, 1)
    assert checkpoint.first_difference(est.state_dict(), before) is None
    assert before["attributes"]["recover_from_depletion"] is False


@pytest.mark.parametrize("scheme", SCHEMES)
def test_the_memory_guard_counts_a_recoverys_children(scheme):
    """``max_bytes`` guards what the filter takes (its pool, table and buffers, ``state_bytes``) and,
    before a recovery, the 32 N P bytes of its N P children (their weights, the order the
    resampling walks them, a sort at worst: ``recovery_bytes``). The reset test's depleted step
    with the limit one byte short of both raises MemoryLimitError naming the depletion, the state
    bit for bit unchanged; with the limit at both it recovers exactly as a filter without a limit."""
    model = om.corridor(5, 2, p_obs=1.0, p_move=1.0)
    steps = [(None, 0)] + [("right", 0)] * 4 + [("left", 0)] * 2
    est, twin = (om.make_estimator("rbpf", model, n_particles=8, seed=0, **SCHEMES[scheme]) for _ in range(2))
    step_all(est, steps)
    step_all(twin, steps)
    pool = est._blocks
    assert pool.rows_to_hold(rbpf_memory.cells_written(model) * 8) == len(pool.rows)  # the step does not grow it
    n_blocks, size = pool.block_members.shape
    held = rbpf_memory.state_bytes(model, 8, size, n_blocks, len(pool.rows))
    assert rbpf_memory.recovery_bytes(model, 8) == 32 * model.n_cells * 8
    est.max_bytes = held + 32 * model.n_cells * 8 - 1
    before = est.state_dict()
    with pytest.raises(om.MemoryLimitError, match="particle depletion.*raise est.max_bytes"):
        est.step(0, 1)
    assert checkpoint.first_difference(est.state_dict(), before) is None and est.recoveries == 0
    est.max_bytes = held + 32 * model.n_cells * 8
    got, expected = est.step(0, 1), twin.step(0, 1)
    assert got.recovered and expected.recovered
    np.testing.assert_array_equal(got.location, expected.location)
    np.testing.assert_array_equal(got.map, expected.map)
    assert got.log_evidence == expected.log_evidence


def test_planning_gives_observations_the_particles_rule_out_probability_zero():
    """``policies.expected_uncertainty`` enumerates every observation of the next steps through
    forks of the filter, weighting each by the filter's predictive probability; those the particles
    rule out must weigh zero (skipped), not be recovered from. With a perfect sensor some are ruled
    out; with room for every trajectory the RBPF is exact Bayes, so its expectation equals the exact
    estimator's (tested against brute force in test_info_gain)."""
    from policies import expected_uncertainty

    model = om.corridor(4, 2, p_obs=1.0, p_move=0.7)
    rbpf = om.make_estimator("rbpf", model, n_particles=256, seed=0)
    exact = om.make_estimator("exact", model)
    for est in (rbpf, exact):
        est.step(None, 0)  # at cell 0, which holds 0: "left" (into the wall) then reading 1 is ruled out
    for actions in ([0], [0, 1], [1, 0, 0]):
        np.testing.assert_allclose(expected_uncertainty(rbpf, actions), expected_uncertainty(exact, actions),
                                   rtol=1e-10, atol=1e-12)
    assert rbpf.recoveries == 0 and rbpf.recover_from_depletion
