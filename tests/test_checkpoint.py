"""Checkpoints: bit-for-bit continuation in a fresh process, and refusal of bad files.

Reference: the same estimator run without interruption in this process. Every registered
estimator is covered (parametrised at collection time), on a static and a dynamic world.
"""

from __future__ import annotations

import io
import json
import os
import pathlib
import stat
import subprocess
import sys
import threading
import zipfile

import numpy as np
import pytest

import onlinemap as om
from onlinemap import checkpoint
from onlinemap.estimators.base import _keyword_options
from estimator_cases import beliefs, cases, random_run

N_STEPS, SAVE_AT = 30, 12
CASES = cases()
NAMES_WITH_RNG = [name for name in ("rbpf",) if name in om.available_estimators()]
CASE_IDS = [f"{name}-{world_id}" for name, world_id, _ in CASES]

CHILD = r"""
import json, sys, traceback
import numpy as np
import onlinemap as om

for job in json.loads(sys.argv[1]):
    try:
        run = np.load(job["run"])
        est = om.load(job["checkpoint"])
        rows = []
        for t in range(est.t + 1, len(run["observations"])):
            b = est.step(int(run["actions"][t - 1]), int(run["observations"][t]))
            ess = np.nan if b.effective_sample_size is None else b.effective_sample_size
            rows.append((b.location, b.map, b.log_evidence, ess))
        np.savez(job["out"], location=np.array([r[0] for r in rows]), map=np.array([r[1] for r in rows]),
                 log_evidence=np.array([r[2] for r in rows]), ess=np.array([r[3] for r in rows]))
        om.save(est, job["final"])
    except Exception:
        open(job["out"] + ".error", "w").write(traceback.format_exc())
"""


def beliefs_after(est, run, start: int) -> dict[str, np.ndarray]:
    rows = []
    for b in beliefs(est, run, start):
        ess = np.nan if b.effective_sample_size is None else b.effective_sample_size
        rows.append((b.location, b.map, b.log_evidence, ess))
    return {"location": np.array([r[0] for r in rows]), "map": np.array([r[1] for r in rows]),
            "log_evidence": np.array([r[2] for r in rows]), "ess": np.array([r[3] for r in rows])}


@pytest.fixture(scope="module")
def resumed(tmp_path_factory):
    """Run every case uninterrupted here, saving at step SAVE_AT; one fresh child process loads
    every checkpoint and continues. Returns {case id: (expected, got or error text, paths)}."""
    root = tmp_path_factory.mktemp("resume")
    jobs, expected = [], {}
    for case_id, (name, _, model) in zip(CASE_IDS, CASES):
        run = random_run(model, N_STEPS, seed=len(case_id))
        est = om.make_estimator(name, model)
        list(beliefs(est, run, stop=SAVE_AT + 1))
        paths = {key: str(root / f"{case_id}.{key}.npz") for key in ("run", "checkpoint", "out", "final")}
        np.savez(paths["run"], actions=run.actions, observations=run.observations)
        om.save(est, paths["checkpoint"])
        expected[case_id] = (beliefs_after(est, run, SAVE_AT + 1), est.state_dict(), paths)
        jobs.append(paths)
    subprocess.run([sys.executable, "-c", CHILD, json.dumps(jobs)], check=True, timeout=600)
    return expected


@pytest.mark.parametrize("case_id", CASE_IDS)
def test_resume_in_fresh_process_is_bit_identical(resumed, case_id):
    expected, final_state, paths = resumed[case_id]
    error = pathlib.Path(paths["out"] + ".error")
    assert not error.exists(), error.read_text() if error.exists() else ""
    got = np.load(paths["out"])
    for key, want in expected.items():
        assert got[key].dtype == want.dtype and got[key].shape == want.shape, key
        assert got[key].tobytes() == want.tobytes(), f"{key} differs after resuming"
    # the whole state at the end (random generator included) is the same, bit for bit
    assert checkpoint.same_tree(checkpoint.read(paths["final"]), final_state)


@pytest.mark.parametrize("name,world_id,model", CASES, ids=CASE_IDS)
def test_load_state_dict_rewinds_in_process(name, world_id, model):
    """Restore an earlier state into the same object: it retraces its steps exactly (generator too)."""
    run = random_run(model, 20, seed=3)
    est = om.make_estimator(name, model)
    list(beliefs(est, run, stop=8))
    state = est.state_dict()
    first = beliefs_after(est, run, 8)
    assert not checkpoint.same_tree(est.state_dict(), state)  # it moved on; the snapshot did not
    est.load_state_dict(state)
    assert est.t == 7 and checkpoint.same_tree(est.state_dict(), state)
    second = beliefs_after(est, run, 8)
    for key in first:
        assert first[key].tobytes() == second[key].tobytes(), key


@pytest.mark.parametrize("name,world_id,model", CASES[::2], ids=CASE_IDS[::2])
def test_every_estimator_checkpoints_before_the_first_step(name, world_id, model, tmp_path):
    est = om.make_estimator(name, model)
    assert isinstance(est, om.Estimator) and est.options == dict(_keyword_options(type(est)))  # as given
    loaded = om.load(om.save(est, tmp_path / "fresh.npz"))
    assert loaded.t == -1 and loaded.belief is None and type(loaded) is type(est)
    assert checkpoint.same_tree(loaded.state_dict(), est.state_dict())


# --- refusals ---------------------------------------------------------------------------------
@pytest.fixture
def saved(tmp_path):
    est = om.make_estimator("exact", om.corridor(3))
    est.step(None, 0)
    est.step(1, 1)
    return est, om.save(est, tmp_path / "exact.npz")


def rewrite(path, entries):
    with open(path, "wb") as file:
        np.savez(file, **entries)


def entries_of(path):
    with np.load(path) as npz:
        return {name: npz[name] for name in npz.files}


def test_roundtrip_and_continue(saved):
    est, path = saved
    loaded = om.load(path)
    assert loaded.t == 1 and loaded.options == est.options
    assert loaded.step(1, 0).location.tobytes() == est.step(1, 0).location.tobytes()


def test_truncated_file_is_refused(saved):
    _, path = saved
    data = path.read_bytes()
    for size in (0, 10, len(data) // 2, len(data) - 1):
        path.write_bytes(data[:size])
        with pytest.raises(om.CheckpointError, match="truncated|corrupt|not an npz|not an onlinemap"):
            om.load(path)


def key_of(path, attribute):
    """The npz entry holding an attribute's array."""
    return json.loads(entries_of(path)["meta"].tobytes())["attributes"][attribute]["key"]


def test_changed_value_is_refused(saved):
    _, path = saved
    entries, key = entries_of(path), key_of(path, "_x")
    entries[key] = entries[key].copy()
    entries[key].flat[0] += 1e-12
    rewrite(path, entries)
    with pytest.raises(om.CheckpointError, match="checksum mismatch"):
        om.load(path)


def test_changed_array_shape_is_refused(saved):
    _, path = saved
    entries, key = entries_of(path), key_of(path, "_x")
    entries[key] = entries[key].reshape(-1)[None]
    rewrite(path, entries)
    with pytest.raises(om.CheckpointError, match="tampered|checksum"):
        om.load(path)


def rewrite_meta(path, change):
    """Rewrite the metadata with ``change`` applied and a valid checksum (a careful forger)."""
    entries = entries_of(path)
    meta = json.loads(entries["meta"].tobytes())
    change(meta)
    meta_bytes = json.dumps(meta).encode()
    arrays = {k: v for k, v in entries.items() if k not in ("meta", "sha256")}
    entries["meta"] = np.frombuffer(meta_bytes, np.uint8)
    entries["sha256"] = np.frombuffer(checkpoint.checkpoint_digest(meta_bytes, arrays).encode(), np.uint8)
    rewrite(path, entries)


def test_versions_compatibility_rests_on_the_format_version(saved):
    """Issue 15 item 7: another onlinemap version with the same format loads (a patch bump must
    not lock users out); a newer format is refused unless allow_newer; strict_version asks for
    the same package version."""
    _, path = saved
    rewrite_meta(path, lambda meta: meta.update(onlinemap_version="0.1.1"))
    assert om.load(path).t == 1
    with pytest.raises(om.CheckpointError, match="written by onlinemap '0.1.1'.*strict_version"):
        om.load(path, strict_version=True)
    rewrite_meta(path, lambda meta: meta.update(format_version=checkpoint.FORMAT_VERSION + 1))
    with pytest.raises(om.CheckpointError,
                       match=f"format version {checkpoint.FORMAT_VERSION + 1} was written by a newer onlinemap.*allow_newer"):
        om.load(path)
    assert om.load(path, allow_newer=True).t == 1
    for bad in (0, "1", True, None, 1.0):
        rewrite_meta(path, lambda meta: meta.update(format_version=bad))
        with pytest.raises(om.CheckpointError, match="format version"):
            om.load(path)


def test_forged_shape_in_metadata_is_refused(saved):
    _, path = saved
    rewrite_meta(path, lambda meta: meta["attributes"]["_x"].update(shape=[1, 999]))
    with pytest.raises(om.CheckpointError, match="recorded as"):
        om.load(path)


def test_model_and_options_mismatch_are_refused(saved):
    est, _ = saved
    state = est.state_dict()
    other = om.make_estimator("exact", om.corridor(3, p_obs=0.8))
    with pytest.raises(om.CheckpointError, match="model differs .* 'sensor'"):
        other.load_state_dict(state)
    assert other.t == -1  # untouched
    with pytest.raises(om.CheckpointError, match="options"):
        om.make_estimator("exact", om.corridor(3), max_bytes=10**6).load_state_dict(state)
    with pytest.raises(om.CheckpointError, match="for estimator 'exact', not 'dead_reckoning'"):
        om.make_estimator("dead_reckoning", om.corridor(3)).load_state_dict(state)


class Boom:
    """Pickling this runs code on load: what a malicious checkpoint would try."""

    def __init__(self, marker):
        self.marker = marker

    def __reduce__(self):
        return (pathlib.Path.touch, (pathlib.Path(self.marker),))


def test_pickled_object_is_refused_and_never_executed(saved, tmp_path):
    _, path = saved
    marker = tmp_path / "executed"
    entries, key = entries_of(path), key_of(path, "_x")
    entries[key] = np.array([Boom(str(marker))], dtype=object)
    rewrite(path, entries)  # numpy pickles object arrays when saving
    with pytest.raises(om.CheckpointError, match="pickled object"):
        om.load(path)
    assert not marker.exists()
    # a bare pickle under a checkpoint's name
    import pickle
    path.write_bytes(pickle.dumps(Boom(str(marker))))
    with pytest.raises(om.CheckpointError, match="not an npz"):
        om.load(path)
    assert not marker.exists()


def test_compressed_entries_are_refused(saved):
    _, path = saved
    entries = entries_of(path)
    with open(path, "wb") as file:
        np.savez_compressed(file, **entries)
    with pytest.raises(om.CheckpointError, match="compressed entries"):
        om.load(path)


def test_extra_entry_is_refused(saved):
    _, path = saved
    entries = entries_of(path)
    entries["payload"] = np.zeros(3)
    rewrite(path, entries)
    with pytest.raises(om.CheckpointError, match="do not match the metadata"):
        om.load(path)


def test_missing_file_is_a_clear_error(tmp_path):
    with pytest.raises(om.CheckpointError, match="cannot open"):
        om.load(tmp_path / "nope.npz")


def test_crash_mid_write_keeps_the_last_good_checkpoint(saved, monkeypatch):
    est, path = saved
    before = path.read_bytes()
    est.step(0, 0)

    def crash(file, **entries):
        file.write(b"PK\x03\x04 half a checkpoint")
        raise OSError("disk full")

    monkeypatch.setattr(checkpoint.np, "savez", crash)
    with pytest.raises(om.CheckpointError, match=f"cannot write checkpoint {path}: disk full; the previous file"):
        om.save(est, path)
    assert path.read_bytes() == before
    assert list(path.parent.glob(".*tmp")) == []  # the temp file is cleaned up
    monkeypatch.undo()
    assert om.load(path).t == 1


# --- the generic encoder, on a stand-in estimator (not registered) ------------------------------------
class Stub:
    name = "stub"
    scratch_attributes = ("_buffer",)

    def __init__(self):
        self.model = om.corridor(3)
        self.options = {"anneal": (1.0, 0.5), "window": "max"}
        self.t = 4
        self._rng = np.random.default_rng(5)
        self._mt = np.random.Generator(np.random.MT19937(3))
        self._shared = np.arange(4.0)
        self._alias = self._shared
        self._fortran = np.asfortranarray(np.arange(6.0).reshape(2, 3))
        self._frozen = np.ones(2)
        self._frozen.setflags(write=False)
        self._scalars = [np.float32(1.5), np.int64(-3), 2**70, float("nan"), None, True, "x"]
        self._nested = {"a": (1, [2.0, {"b": np.zeros((2, 0))}]), "$": "tag-like key"}
        self._dtype = np.dtype(np.float32)
        self._kind = np.float32
        self._fn = np.cumsum
        self._method = self.helper
        self._buffer = np.zeros((2, 3))
        self._belief = om.Belief(2, np.array([0.5, 0.5, 0.0]), np.full((3, 2), 0.5), -1.0,
                                 effective_sample_size=3.0)

    def helper(self):
        return 1


def test_generic_encoder_roundtrip(tmp_path):
    stub = Stub()
    stub._rng.random(3)
    path = checkpoint.write(checkpoint.state_dict(stub), tmp_path / "stub.npz")
    fresh = Stub()
    checkpoint.load_state_dict(fresh, checkpoint.read(path))
    assert fresh._rng.random() == stub._rng.random() and fresh._mt.random() == stub._mt.random()
    assert fresh._alias is fresh._shared and fresh._alias is not stub._shared
    assert not fresh._frozen.flags.writeable and fresh._shared.flags.writeable
    assert fresh._fortran.flags.f_contiguous and not fresh._fortran.flags.c_contiguous  # numpy sums in memory order
    assert [type(x) for x in fresh._scalars] == [type(x) for x in stub._scalars]
    assert fresh._scalars[0].dtype == np.float32 and fresh._scalars[2] == 2**70 and np.isnan(fresh._scalars[3])
    assert fresh._nested["a"][1][1]["b"].shape == (2, 0) and fresh._nested["$"] == "tag-like key"
    assert fresh._dtype == np.float32 and fresh._kind is np.float32 and fresh._fn is np.cumsum
    assert fresh._method.__self__ is fresh
    assert fresh._belief.location.tobytes() == stub._belief.location.tobytes()
    assert fresh._belief.effective_sample_size == 3.0
    assert checkpoint.same_tree(checkpoint.state_dict(fresh), checkpoint.state_dict(stub))


def test_scratch_buffers_are_checked_but_not_stored():
    stub = Stub()
    stub._buffer += 7.0
    state = checkpoint.state_dict(stub)
    assert state["attributes"]["_buffer"] == {"$": "scratch", "dtype": "<f8", "shape": [2, 3]}
    fresh = Stub()
    own = fresh._buffer
    checkpoint.load_state_dict(fresh, state)
    assert fresh._buffer is own and not own.any()
    fresh._buffer = np.zeros(4)
    with pytest.raises(om.CheckpointError, match="_buffer: checkpoint has a scratch array <f8 \\[2, 3\\]"):
        checkpoint.load_state_dict(fresh, state)


def test_a_checkpoint_predating_an_option_or_a_scratch_buffer_loads():
    """An RBPF checkpoint written before the ``threads`` option and the scratch buffers existed (as
    any written before issue 25): the option takes its default, the buffers are the fresh
    filter's, and it continues as the filter that wrote it. Written with another value of the
    option, it does not load."""
    model = om.corridor(6, p_change=0.05)
    run = om.simulate(model, None, [1, 1, 0, 1, 1, 1, 0, 0, 1], seed=1)
    est = om.make_estimator("rbpf", model, n_particles=20, seed=0)
    for t in range(5):
        est.step(None if t == 0 else int(run.actions[t - 1]), int(run.observations[t]))
    state = checkpoint.state_dict(est)
    options = [item for item in state["options"]["items"] if item[0] != "threads"]
    old = {**state, "options": {**state["options"], "items": options},
           "attributes": {k: v for k, v in state["attributes"].items() if not k.startswith("_scratch")}}
    twin = om.make_estimator("rbpf", model, n_particles=20, seed=0)
    checkpoint.load_state_dict(twin, old)
    for t in range(5, run.n_steps):
        args = (int(run.actions[t - 1]), int(run.observations[t]))
        np.testing.assert_array_equal(twin.step(*args).map, est.step(*args).map)
    other = {**old, "options": {**old["options"], "items": old["options"]["items"] + [["threads", 2]]}}
    with pytest.raises(om.CheckpointError, match="options"):
        checkpoint.load_state_dict(om.make_estimator("rbpf", model, n_particles=20, seed=0), other)


def test_unsupported_attribute_is_named():
    stub = Stub()
    stub._handle = object()
    with pytest.raises(om.CheckpointError, match="attribute _handle: cannot checkpoint a builtins.object"):
        checkpoint.state_dict(stub)
    stub._handle = np.array([object()])
    with pytest.raises(om.CheckpointError, match="_handle: arrays of dtype object"):
        checkpoint.state_dict(stub)


def test_writable_views_are_refused():
    stub = Stub()
    stub._view = stub._shared[1:]
    with pytest.raises(om.CheckpointError, match="_shared and _view are writable views"):
        checkpoint.state_dict(stub)


def test_changed_function_is_refused(tmp_path):
    state = checkpoint.state_dict(Stub())
    other = Stub()
    other._fn = np.cumprod
    with pytest.raises(om.CheckpointError, match="_fn: checkpoint has numpy.cumsum"):
        checkpoint.load_state_dict(other, state)


def test_malformed_zip_member_is_refused(saved):
    _, path = saved
    data, key = bytearray(path.read_bytes()), key_of(path, "_x")
    with zipfile.ZipFile(path) as archive:
        info = archive.getinfo(f"{key}.npy")
    offset = info.header_offset + 30 + len(info.filename) + 200  # inside a0's data
    data[offset] ^= 0xFF
    path.write_bytes(bytes(data))
    with pytest.raises(om.CheckpointError, match="corrupt|checksum"):
        om.load(path)


def test_any_flipped_byte_is_refused_or_harmless(tmp_path):
    """Fuzz: flip one random byte anywhere (zip headers, npy headers, metadata, arrays, checksum):
    loading either refuses with CheckpointError or, where the byte is not part of the content
    (e.g. a zip timestamp), gives exactly the saved state. Never another exception."""
    est = om.make_estimator(NAMES_WITH_RNG[0] if NAMES_WITH_RNG else "exact", om.corridor(5, p_change=0.05))
    est.step(None, 0)
    est.step(1, 1)
    path = om.save(est, tmp_path / "ck.npz")
    good, reference = path.read_bytes(), est.state_dict()
    rng = np.random.default_rng(0)
    refused = 0
    for _ in range(400):
        data = bytearray(good)
        data[int(rng.integers(len(data)))] ^= int(rng.integers(1, 256))
        path.write_bytes(bytes(data))
        try:
            loaded = om.load(path)
        except om.CheckpointError:
            refused += 1
            continue
        assert checkpoint.same_tree(loaded.state_dict(), reference)
    assert refused > 300


# --- hostile files (issue 14 item 7): every defect is a CheckpointError naming the file ------------------
def test_encrypted_flag_is_refused(saved):
    """Regression: a flipped zip "encrypted" flag raised RuntimeError."""
    _, path = saved
    data = bytearray(path.read_bytes())
    central = data.index(b"PK\x01\x02")
    data[central + 8] |= 0x1  # general purpose flag bits of the first central directory entry
    path.write_bytes(bytes(data))
    with pytest.raises(om.CheckpointError, match=f"{path.name}.*marked encrypted"):
        om.load(path)


def npz_with_member(path, name, payload: bytes):
    """``path``'s entries plus one raw member ``name`` (stored)."""
    with zipfile.ZipFile(path, "a", compression=zipfile.ZIP_STORED) as archive:
        archive.writestr(name, payload)


def test_member_that_is_not_npy_is_refused(saved):
    """Regression: a member that is not an npy file raised AttributeError."""
    _, path = saved
    npz_with_member(path, "notes.txt", b"hello")
    with pytest.raises(om.CheckpointError, match="unexpected zip entry"):
        om.load(path)


def test_garbage_npy_member_is_refused(saved):
    est, path = saved
    npz_with_member(path, "a99.npy", b"\x93NUMPY garbage")
    with pytest.raises(om.CheckpointError, match="a99.npy': npy format version"):
        om.load(path)
    om.save(est, path)
    npz_with_member(path, "a98.npy", b"\x93NUMPY\x01\x00\x10\x00{'descr': <f8}    ")
    with pytest.raises(om.CheckpointError, match="truncated or corrupt"):
        om.load(path)


def test_huge_declared_array_is_refused_before_allocating(saved):
    """Regression: a header declaring 8 TiB raised MemoryError before the checksum was checked."""
    _, path = saved
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(header, {"descr": "<f8", "fortran_order": False, "shape": (2**40,)})
    npz_with_member(path, "a99.npy", header.getvalue() + b"\0" * 64)
    with pytest.raises(om.CheckpointError, match=r"declares \(1099511627776,\) float64"):
        om.load(path)


def test_deeply_nested_metadata_is_refused(saved):
    """Regression: a 500-deep list in the metadata raised RecursionError."""
    _, path = saved
    deep = []
    for _ in range(500):
        deep = [deep]
    rewrite_meta(path, lambda meta: meta.update(extra=deep))
    with pytest.raises(om.CheckpointError, match="nested more than"):
        om.load(path)


def test_fifo_is_refused_without_blocking(tmp_path):
    """Regression: om.load on a FIFO blocked forever."""
    fifo = tmp_path / "pipe.npz"
    os.mkfifo(fifo)
    outcome = []
    worker = threading.Thread(target=lambda: outcome.append(pytest.raises(om.CheckpointError, om.load, fifo)),
                              daemon=True)
    worker.start()
    worker.join(20)
    assert not worker.is_alive(), "om.load blocked on a FIFO"
    assert "not a regular file" in str(outcome[0].value)


def test_save_writes_through_a_symlink_and_keeps_the_mode(saved, tmp_path):
    """Regression: om.save onto a symlink replaced the link; the file's mode was not kept."""
    est, path = saved
    path.chmod(0o640)
    link = tmp_path / "link.npz"
    link.symlink_to(path)
    est.step(0, 0)
    om.save(est, link)
    assert link.is_symlink() and om.load(path).t == est.t
    assert stat.S_IMODE(path.stat().st_mode) == 0o640


def test_save_to_an_unwritable_place_is_a_checkpoint_error(saved, tmp_path):
    """Regression: om.save raised a bare OSError."""
    est, _ = saved
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(om.CheckpointError, match=f"cannot write checkpoint {blocker / 'ck.npz'}"):
        om.save(est, blocker / "ck.npz")
    with pytest.raises(om.CheckpointError, match="not a regular file"):
        om.save(est, tmp_path)


KILLED_MID_SAVE = """\
import os, signal, sys
import numpy as np
import onlinemap as om

def killed(file, **arrays):  # half the file written, then kill -9: no chance to clean up
    file.write(b"PK half a checkpoint")
    file.flush()
    os.kill(os.getpid(), signal.SIGKILL)

np.savez = killed
est = om.make_estimator("bk", om.grid_model(2, 2, 3))
est.step(None, 0)
om.save(est, sys.argv[1])
"""


def test_a_save_killed_mid_write_leaves_temporaries_the_next_save_removes(tmp_path):
    """Issue 43 item 12: ``om.save`` killed mid-write left its temporaries (7 files, 278 MB
    after 15 kills); only ``track`` cleaned up. The next save to the same path removes them, and
    only them: a user's ``.ck.npz.my-notes.tmp`` and another file's temporaries stay."""
    ck = tmp_path / "ck.npz"
    for _ in range(3):
        child = subprocess.run([sys.executable, "-c", KILLED_MID_SAVE, str(ck)], capture_output=True)
        assert child.returncode == -9, child.stderr.decode()
    left = sorted(p.name for p in tmp_path.iterdir())  # each save removed the one killed before it
    assert len(left) == 1 and left[0].startswith(".ck.npz.") and left[0].endswith(".tmp"), left
    keep = [tmp_path / ".ck.npz.my-notes.tmp", tmp_path / ".other.npz.1-0a1b2c3d.tmp"]
    for path in keep:
        path.write_text("mine")
    est = om.make_estimator("bk", om.grid_model(2, 2, 3))
    est.step(None, 0)
    om.save(est, ck)
    assert sorted(tmp_path.iterdir()) == sorted([ck, *keep])
    assert om.load(ck).t == 0


@pytest.mark.parametrize("thing", [om.grid_model(2, 2, 3), None, "est", {"t": 0}])
def test_save_of_something_not_an_estimator_says_so(thing, tmp_path):
    """Issue 42 item 7: ``om.save(model, ...)`` raised a raw ``AttributeError`` (no
    ``state_dict``). Now a CheckpointError names what it was given; nothing is written."""
    with pytest.raises(om.CheckpointError, match=f"an estimator .*not a {type(thing).__name__}$"):
        om.save(thing, tmp_path / "ck.npz")
    assert not list(tmp_path.iterdir())
