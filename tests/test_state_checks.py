"""A crafted checkpoint (valid checksum, edited arrays) is refused or gives a valid estimator:
never a crash, never an out-of-bounds kernel access, never an invalid belief (issue 14 item 1).

Reference for "valid": the invariants hold on every state an estimator reaches by stepping
(checked along random runs), and every belief after loading is a distribution
(``estimator_cases.assert_valid_belief``). The fuzz test edits every array and scalar of every
estimator's state at random (hostile values, wrong shapes, out-of-range indices) with the
checksum recomputed; ``ONLINEMAP_FUZZ=N`` runs N edits per estimator instead of the CI's 60.
"""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

import onlinemap as om
from onlinemap import checkpoint
from onlinemap.model import symmetric_channel
from estimator_cases import CHEAP, NAMES, assert_valid_belief, beliefs, random_run

EDITS = int(os.environ.get("ONLINEMAP_FUZZ", "60"))


def world(name):
    if name == "exact":
        return om.grid_model(1, 3, 2, change=symmetric_channel(2, 0.9))
    return om.grid_model(2, 3, 3, change=symmetric_channel(3, 0.9))


def options(name):
    return {"rbpf": {"n_particles": 12, "seed": 1, "block_cells": 2}, "online_em": {"window": 3}}.get(name, {})


def stepped(name, steps=9, seed=0):
    model = world(name)
    est = om.make_estimator(name, model, **options(name))
    list(beliefs(est, random_run(model, steps, seed)))
    return est


@pytest.mark.parametrize("name", NAMES)
def test_every_registered_estimator_states_its_invariants(name):
    """Each estimator class checks its own state (``check_state``) and names the attributes its
    model and options fix (``CONSTANT_STATE``): each names an attribute (or a state object's field)
    the estimator has."""
    est = stepped(name)
    cls = type(est)
    assert callable(vars(cls)["check_state"]) and type(vars(cls)["CONSTANT_STATE"]) is tuple
    for constant in cls.CONSTANT_STATE:
        head, _, field = constant.partition(".")
        assert head in vars(est) and (not field or hasattr(vars(est)[head], field)), constant


@pytest.mark.parametrize("name", NAMES)
def test_invariants_hold_along_random_runs(name):
    """The checks accept every state the estimator reaches (dynamic world, resampling, pool growth)."""
    for seed, model in enumerate([world(name), om.corridor(7, p_change=0.05)] if name != "exact" else [world(name)]):
        opts = {**options(name), **({"resample_threshold": 0.9} if name == "rbpf" else {})}
        est = om.make_estimator(name, model, **opts)
        checkpoint.check_state(est, {})
        for _ in beliefs(est, random_run(model, 60, seed)):
            checkpoint.check_state(est, {})


def forged(est, edit):
    """``est``'s checkpoint with ``edit(meta, arrays)`` applied and the checksum recomputed, as
    bytes of a file (the attacker's view)."""
    state = est.state_dict()
    arrays: dict[str, np.ndarray] = {}
    meta = checkpoint.externalise_arrays(state, arrays)
    edit(meta, arrays)
    meta_bytes = json.dumps(meta).encode()
    return meta_bytes, arrays


def write_forged(path, meta_bytes, arrays):
    digest = checkpoint.checkpoint_digest(meta_bytes, arrays).encode()
    with open(path, "wb") as file:
        np.savez(file, meta=np.frombuffer(meta_bytes, np.uint8), sha256=np.frombuffer(digest, np.uint8), **arrays)


def node_at(meta, path):
    """The encoded node of an attribute, or of a field of a state object (``_blocks.table``)."""
    attribute, *fields = path.split(".")
    node = meta["attributes"][attribute]
    for field in fields:
        node = node["fields"][field]
    return node


def set_array(meta, arrays, attribute, value):
    node = node_at(meta, attribute)
    arrays[node["key"]] = value
    node.update(dtype=value.dtype.str, shape=list(value.shape))


@pytest.mark.parametrize("name,attribute,change,words", [
    ("rbpf", "_blocks.table", lambda a: a + 10**6, "_blocks.table holds indices"),
    ("rbpf", "_blocks.table", lambda a: a - 10**6, "_blocks.table holds indices"),
    ("rbpf", "_locations", lambda a: a * 0 - 1, "_locations holds indices"),
    ("rbpf", "_blocks.refcount", lambda a: a + 1, "_blocks.refcount must count"),
    ("rbpf", "_blocks.free_top", lambda a: a + 10**6, "_blocks.free must list"),
    ("rbpf", "_blocks.rows", lambda a: a[:-1], "_blocks.row_block must have shape"),
    ("rbpf", "_blocks.row_block", lambda a: a[::-1], "_blocks.row_block"),
    ("rbpf", "_blocks.rows", lambda a: a * 2, "_blocks.rows"),
    ("rbpf", "_blocks.cell_slot", lambda a: a + 1, "_blocks.cell_slot differs"),
    ("rbpf", "_log_weights", lambda a: a * np.nan, "_log_weights must be finite"),
    ("exact", "_x", lambda a: a[:, :-1], "_x must have shape"),
    ("exact", "_x", lambda a: -a, "_x must be finite and non-negative"),
    ("bk", "_location", lambda a: a[::-1] - 0.5, "_location must hold probabilities"),
    ("online_em", "_observations", lambda a: a + 100, "_observations holds indices"),
    ("online_em", "_filtered", lambda a: a[1:], "_filtered must have shape"),
    ("offline_em", "_actions", lambda a: a - 5, "_actions holds indices"),
])
def test_crafted_checkpoint_is_refused(name, attribute, change, words, tmp_path):
    """Regression (issue 14 item 1): index arrays edited and the SHA-256 recomputed used to load,
    and the next step read and wrote out of bounds (segfault)."""
    if name not in NAMES:
        pytest.skip(f"{name} not registered")
    est = stepped(name)

    def edit(meta, arrays):
        key = node_at(meta, attribute)["key"]
        set_array(meta, arrays, attribute, np.ascontiguousarray(change(arrays[key])))

    path = tmp_path / "forged.npz"
    write_forged(path, *forged(est, edit))
    with pytest.raises(om.CheckpointError, match=words):
        om.load(path)


def test_negative_location_in_a_belief_is_refused(tmp_path):
    """Regression: a dead-reckoning checkpoint with a negative stored location gave a belief with
    probabilities -0.28 and 1.43."""
    est = stepped("dead_reckoning")

    def edit(meta, arrays):
        key = meta["attributes"]["_belief"]["fields"]["location"]["key"]
        arrays[key] = arrays[key].copy()
        arrays[key][:2] = [-0.28, 1.28]

    path = tmp_path / "forged.npz"
    write_forged(path, *forged(est, edit))
    with pytest.raises(om.CheckpointError, match="_belief.location must hold probabilities"):
        om.load(path)


def test_scalar_and_constant_attributes_are_checked():
    est = stepped("rbpf")
    state = est.state_dict()
    fresh = om.make_estimator("rbpf", est.model, **options("rbpf"))
    blocks = state["attributes"]["_blocks"]
    for attribute, value, words in [
            ("_blocks", {**blocks, "fields": {**blocks["fields"], "refresh_cursor": 10**9}},
             "_blocks.refresh_cursor must be an int"),
            ("_blocks", {**blocks, "fields": {**blocks["fields"], "stamped": False}}, "_blocks.stamped differs"),
            ("_blocks", {**blocks, "fields": {k: v for k, v in blocks["fields"].items() if k != "free"}},
             "BlockPool needs the fields"),
            ("_blocks", {**blocks, "class": "Belief"}, "unknown state class"),
            ("_t", -7, "_t must be an int"),
            ("n_particles", 10**6, "n_particles differs"),
            ("_ess", float("nan"), "_ess must be a float")]:
        bad = {**state, "attributes": {**state["attributes"], attribute: value}}
        with pytest.raises(om.CheckpointError, match=words):
            fresh.load_state_dict(bad)
        assert fresh.t == -1  # unchanged


HOSTILE = [np.nan, np.inf, -np.inf, -1, 0, 1, 2**31, -2**40, 1e-320, 0.5, 10**6]


def mutate(value: np.ndarray, rng) -> np.ndarray:
    """One random hostile edit of an array: an entry set to a hostile value, a shape change, or
    a few random bits flipped."""
    kind = rng.integers(5)
    if kind == 0 and value.size:  # one entry
        out = value.copy()
        hostile = HOSTILE[rng.integers(len(HOSTILE))]
        try:
            out.flat[rng.integers(value.size)] = hostile
        except (OverflowError, ValueError):
            out.flat[rng.integers(value.size)] = -1
        return out
    if kind == 1:  # shorter or longer along the first axis
        if value.ndim and value.shape[0] > 1 and rng.integers(2):
            return np.ascontiguousarray(value[:-1])
        return np.concatenate([value, value[:1]]) if value.ndim and value.size else value
    if kind == 2 and value.ndim:  # flattened or with an extra axis
        return value.reshape(-1) if rng.integers(2) else value[None]
    if kind == 3 and value.size:  # random bytes
        out = value.copy()
        raw = out.reshape(-1).view(np.uint8)
        raw[rng.integers(raw.size, size=3)] ^= rng.integers(1, 256, size=3, dtype=np.uint8)
        return out
    if value.size and value.dtype.kind in "iu":  # every index shifted
        return value + rng.choice([-1, 1, 2**20])
    return value * rng.choice([-1.0, 2.0, np.nan]) if value.dtype.kind == "f" else value


def leaves(node, path=()):
    """Paths of every array and number in a state tree (the fuzz's targets)."""
    if type(node) is np.ndarray or (type(node) in (int, float) and path and path[0] == "attributes"):
        yield path
    elif type(node) is dict:
        for key, value in node.items():
            if key not in ("model", "options", "format", "format_version", "onlinemap_version", "estimator"):
                yield from leaves(value, path + (key,))
    elif type(node) is list:
        for i, value in enumerate(node):
            yield from leaves(value, path + (i,))


def replaced(node, path, value):
    if not path:
        return value
    if type(node) is dict:
        return {**node, path[0]: replaced(node[path[0]], path[1:], value)}
    copy = list(node)
    copy[path[0]] = replaced(node[path[0]], path[1:], value)
    return copy


def get(node, path):
    for key in path:
        node = node[key]
    return node


@pytest.mark.parametrize("name", NAMES)
def test_fuzz_edited_state_is_refused_or_valid(name, tmp_path):
    """Issue 14 item 1: random edits to every array (and number) of a checkpoint, the checksum
    recomputed: loading raises CheckpointError, or gives an estimator whose next steps are valid
    beliefs (or refused with a specific error). Every 10th edit goes through a file."""
    est = stepped(name, steps=12, seed=5)
    state = est.state_dict()
    targets = list(leaves(state))
    rng = np.random.default_rng(len(name))
    model, run = est.model, random_run(est.model, 20, seed=6)
    refused = 0
    for edit in range(EDITS):
        path = targets[edit % len(targets)]
        value = get(state, path)
        if type(value) is np.ndarray:
            new = mutate(value, rng)
        else:
            new = type(value)(HOSTILE[rng.integers(len(HOSTILE))]) if type(value) is float else \
                int(rng.choice([-1, 2**40, 0, 3]))
        bad = replaced(state, path, new)
        fresh = om.make_estimator(name, model, **options(name))
        try:
            if edit % 10 == 0:
                file = checkpoint.write(bad, tmp_path / "fuzz.npz")
                fresh = om.load(file)
            else:
                fresh.load_state_dict(bad)
        except om.CheckpointError:
            refused += 1
            continue
        for t in range(fresh.t + 1, fresh.t + 4):
            action = None if t == 0 else int(run.actions[t % (run.n_steps - 1)])
            try:
                belief = fresh.step(action, int(run.observations[t % run.n_steps]))
            except om.ImpossibleObservationError:
                continue
            assert_valid_belief(belief, model, t, atol=1e-6)
    assert refused > EDITS // 4, f"only {refused} of {EDITS} edits refused: is the fuzz editing anything?"
