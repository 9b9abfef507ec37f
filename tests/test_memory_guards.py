"""Options that used to hang or blow up memory (issue 14 item 8), and the RBPF's memory estimate
against the peak resident memory actually measured in a fresh process."""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys

import numpy as np
import pytest

import onlinemap as om
from estimator_cases import assert_state_unchanged, snapshot
from onlinemap.arrays import DEFAULT_MAX_BYTES
from onlinemap.estimators.rbpf_memory import peak_bytes, state_bytes

MEASURE = r"""
import json, sys
import numpy as np
import onlinemap as om

def peak():
    # peak resident memory since the last reset (VmHWM, Linux), in bytes
    with open("/proc/self/status") as status:
        return next(int(line.split()[1]) * 1024 for line in status if line.startswith("VmHWM:"))

n, p, p_change = int(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3])
options = dict(seed=0, resampling="residual", resample_threshold=0.0)  # never resampling: the worst case
warm = om.make_estimator("rbpf", om.corridor(8, p_change=p_change), n_particles=4, **options)  # compile first
warm.step(None, 0), warm.step(1, 1), warm.belief
with open("/proc/self/clear_refs", "w") as clear:
    clear.write("5")  # reset the peak to the current resident size (Linux >= 4.0)
before = peak()
model = om.corridor(n, p_change=p_change, p_move=1.0)
est = om.make_estimator("rbpf", model, n_particles=p, **options)
rng = np.random.default_rng(0)
est.step(None, 0)
for t in range(1, 2 * n):  # there and back without resampling: every particle ends up owning every block
    est.step(1 if t < n else 0, int(rng.integers(2)))
est.belief
print(json.dumps({"measured": peak() - before, "owned": int((est._blocks.refcount > 0).sum())}))
"""


@pytest.mark.skipif(not os.path.exists("/proc/self/clear_refs"), reason="needs Linux /proc to measure peak RSS")
@pytest.mark.parametrize("p_change", [0.0, 0.01], ids=["static", "dynamic"])
def test_rbpf_memory_estimate_bounds_the_measured_peak(p_change):
    """Regression: the guard counted 8 P N (K + 1) bytes, 2.1x less than the peak measured here
    (the block pool grows by doubling, and the old pool lives on while it is copied). Now the
    estimate bounds the measured peak RSS and is within 2x of it, plus the 32 N P bytes of a
    step that recovers from depletion (its N P children's weights)."""
    n, p = 200, 2000
    done = subprocess.run([sys.executable, "-c", MEASURE, str(n), str(p), str(p_change)], capture_output=True,
                          text=True, timeout=300, check=True)
    result = json.loads(done.stdout)
    model = om.corridor(n, p_change=p_change)
    estimate = peak_bytes(model, p)
    assert result["owned"] >= p * 20  # the worst case was reached: every particle owns its 20 blocks
    recovery = 32 * n * p  # the estimate also covers a recovery from depletion, which this run does not reach
    assert result["measured"] <= estimate <= 2 * result["measured"] + recovery, (result, estimate)
    old = 8 * p * n * (model.n_labels + (0 if model.is_static else 1))
    assert old < result["measured"] / 1.5  # what the old guard missed


def test_rbpf_guard_counts_block_cells():
    """Regression: block_cells = 10**7 on a 3 x 3 grid tried to allocate 30 GiB."""
    with pytest.raises(om.InvalidOptionError, match="block_cells must be at most 9"):
        om.make_estimator("rbpf", om.grid_model(3, 3), block_cells=10**7)
    with pytest.raises(om.MemoryLimitError, match="needs 3.65 GB to start"):  # 3.3 GB: (1 + 2 P) rows of 50 cells
        om.make_estimator("rbpf", om.corridor(50), n_particles=2 * 10**6, block_cells=50)


def test_rbpf_guard_checks_the_memory_taken_when_the_pool_grows():
    """The guard follows the memory the filter takes (issue 25): a million particles on the 10 x 10
    door world start within a third of the default limit though their worst case (every particle
    owning all 25 map blocks) is 3.7 times it (a run measured 1.07 GB at its peak); a run whose
    particles stop sharing blocks (no resampling) is stopped, unchanged, at the step that would
    grow the pool beyond ``max_bytes``, and goes on as if nothing happened once ``est.max_bytes``
    is raised."""
    model = om.door_world()[0]
    start = state_bytes(model, 10**6, 4, 25, 25 + 2 * 10**6)
    assert start < 0.35 * DEFAULT_MAX_BYTES and peak_bytes(model, 10**6) > 3.5 * DEFAULT_MAX_BYTES

    model = om.corridor(40, p_move=1.0)  # every particle on the same path, each writing its own copies
    run = om.simulate(model, None, [1] * 39, seed=0)
    options = dict(n_particles=30, seed=0, resampling="residual", resample_threshold=0.0, block_cells=4)
    limit = state_bytes(model, 30, 4, 10, 10 + 2 * 30) + 1  # room to start, none to grow
    est = om.make_estimator("rbpf", model, max_bytes=limit, **options)
    twin = om.make_estimator("rbpf", model, max_bytes=10**9, **options)
    steps = [(None if t == 0 else 1, int(run.observations[t])) for t in range(run.n_steps)]
    for t, args in enumerate(steps):
        snap = snapshot(est)
        try:
            est.step(*args)
        except om.MemoryLimitError as error:
            assert f"step {t}:" in str(error) and "est.max_bytes" in str(error)
            break
        twin.step(*args)
    else:
        pytest.fail("the pool never grew")
    assert_state_unchanged(est, snap)
    est.max_bytes = 10**9
    for args in steps[t:]:
        a, b = est.step(*args), twin.step(*args)
        np.testing.assert_array_equal(a.map, b.map)
        np.testing.assert_array_equal(a.location, b.location)


@pytest.mark.parametrize("name", ["exact", "rbpf"])
@pytest.mark.parametrize("max_bytes", [float("nan"), -1, 0, "1e9", 1.5, None, True])
def test_max_bytes_must_be_a_positive_limit(name, max_bytes):
    """Regression: max_bytes=nan switched the memory guards off."""
    with pytest.raises(om.InvalidOptionError, match="max_bytes"):
        om.make_estimator(name, om.corridor(4), max_bytes=max_bytes)
    assert om.make_estimator(name, om.corridor(4), max_bytes=float("inf")).step(None, 0).t == 0


@pytest.mark.parametrize("tol", [float("nan"), -1e-8, float("inf"), "1e-8", None])
def test_offline_em_tolerance_must_be_finite_and_non_negative(tol):
    """Regression: tol=nan or a negative tol was accepted, and EM then never converged."""
    with pytest.raises(om.InvalidOptionError, match="tol"):
        om.make_estimator("offline_em", om.corridor(4), tol=tol)
    with pytest.raises(om.InvalidOptionError, match="tol"):
        om.estimators.offline_em.baum_welch(om.corridor(4), [], [0], tol=tol)



# --- issue 24 item 5: memory no guard bounded ---------------------------------------------------
def test_footprint_cells_times_offsets_is_bounded():
    """Regression: a footprint of 40,000 offsets on 300 x 300 cells built (N, F) tables of
    3.6e9 entries (26.8 GiB) and died with a raw MemoryError. N x F is bounded like N x K
    (``MAX_CELLS``), before anything of that size is built."""
    from onlinemap.arguments import MAX_CELLS

    offsets = [(dr, dc) for dr in range(-100, 100) for dc in range(-100, 100)]
    with pytest.raises(om.ModelError, match=rf"footprint of 40000 offsets on 90000 cells.*at most {MAX_CELLS}"):
        om.grid_model(300, 300, footprint=offsets)
    row = [(0, dc) for dc in range(4096)]  # 4097 x 4096 = MAX_CELLS + 4096
    with pytest.raises(om.ModelError, match="footprint of 4096 offsets on 4097 cells"):
        om.corridor(4097, footprint=row)
    small = om.corridor(4, footprint=row[:3])
    with pytest.raises(om.ModelError, match="footprint of 4096 offsets on 4097 cells"):
        dataclasses.replace(small, cols=4097, neighbors=om.corridor(4097).neighbors, label_prior=[0.5, 0.5],
                            footprint=tuple(row))


@pytest.fixture
def machine_of_1_gib(monkeypatch):
    """This process sees a machine of 1 GiB, whatever the machine running the tests has (small,
    so that a guard failing here allocates little)."""
    from onlinemap import arguments

    monkeypatch.setattr(arguments, "machine_memory", lambda: 2**30)


@pytest.mark.parametrize("max_bytes", [float("inf"), 10**15])
def test_no_limit_is_capped_at_the_machines_memory(machine_of_1_gib, max_bytes):
    """Regression: max_bytes=inf switched the guards off, and exact on corridor(26) (2 x 14 GB
    tensors) or the RBPF with 10^7 particles on the door world (77 GB at worst) ended in a raw
    MemoryError (or the OOM killer). A limit above the machine's memory now means the machine's
    memory: refused before anything is allocated."""
    with pytest.raises(om.MemoryLimitError, match=r"28\.5 GB .* this machine has 1\.07 GB"):
        om.make_estimator("exact", om.corridor(26), max_bytes=max_bytes)
    with pytest.raises(om.MemoryLimitError, match=r"this machine has 1\.07 GB"):
        om.exact_smooth(om.corridor(22), [1], [0, 0], max_bytes=max_bytes)  # 4 tensors of 0.74 GB
    with pytest.raises(om.MemoryLimitError, match="rbpf with 10000000 particles"):
        om.make_estimator("rbpf", om.door_world()[0], n_particles=10**7, max_bytes=max_bytes)
    assert om.make_estimator("exact", om.corridor(4), max_bytes=max_bytes).step(None, 0).t == 0


def test_machine_memory_against_proc_meminfo():
    """The cap is at most the physical memory Linux reports (MemTotal, /proc/meminfo)."""
    from onlinemap.arguments import machine_memory

    if not os.path.exists("/proc/meminfo"):
        pytest.skip("needs Linux /proc/meminfo")
    with open("/proc/meminfo") as meminfo:
        total = next(int(line.split()[1]) * 1024 for line in meminfo if line.startswith("MemTotal:"))
    assert 0 < machine_memory() <= total


def test_exact_smooth_validates_max_bytes():
    """max_bytes=nan switched exact_smooth's guard off (the filter's was fixed, not the smoother's)."""
    with pytest.raises(om.InvalidOptionError, match="max_bytes"):
        om.exact_smooth(om.corridor(4), [1], [0, 0], max_bytes=float("nan"))


def test_offline_em_iterations_are_bounded():
    """Regression: offline_em(tol=0, n_iter=10**12) was accepted and never returned."""
    from onlinemap.estimators.offline_em import MAX_ITERATIONS, baum_welch

    with pytest.raises(om.InvalidOptionError, match=f"n_iter must be at most {MAX_ITERATIONS}"):
        om.make_estimator("offline_em", om.corridor(4), tol=0, n_iter=10**12)
    with pytest.raises(om.InvalidOptionError, match=f"n_iter must be at most {MAX_ITERATIONS}"):
        baum_welch(om.corridor(4), [1], [0, 1], tol=0, n_iter=MAX_ITERATIONS + 1)
    assert om.make_estimator("offline_em", om.corridor(4), tol=0, n_iter=MAX_ITERATIONS).n_iter == MAX_ITERATIONS


EXACT_MEASURE = r"""
import json, sys
import onlinemap as om

def peak():
    with open("/proc/self/status") as status:
        return next(int(line.split()[1]) * 1024 for line in status if line.startswith("VmHWM:"))

variant, n, steps, what = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
options = {"plain": {}, "both": {"blocking": [1], "footprint": "cross"}}[variant]
for size, length in ((5, 3), (n, steps)):  # compile (and import) first, then measure
    model = om.corridor(size, p_change=0.1, **options)
    run = om.simulate(model, steps=length, seed=0)
    with open("/proc/self/clear_refs", "w") as clear:
        clear.write("5")  # reset the peak to the current resident size (Linux >= 4.0)
    before = peak()
    if what == "smooth":
        om.exact_smooth(model, run.actions, run.observations, max_bytes=float("inf"))
    else:
        om.run_estimator(om.make_estimator("exact", model, max_bytes=float("inf")), run.actions, run.observations)
print(json.dumps(peak() - before))
"""


@pytest.mark.skipif(not os.path.exists("/proc/self/clear_refs"), reason="needs Linux /proc to measure peak RSS")
@pytest.mark.parametrize("what", ["filter", "smooth"])
@pytest.mark.parametrize("variant", ["plain", "both"])
def test_exact_memory_estimate_bounds_the_measured_peak(variant, what):
    """Regression: the exact guard counted 2 tensors (N, K^N) for the filter and T + 2 for the
    smoother; with blocking labels and a footprint (the numpy path) the filter's steps peak at
    8.1 tensors, and the smoother at about T + 7 (paper's model) or T + 9.3. The estimate now
    bounds the peak RSS measured in a fresh process (up to 1 MiB of small arrays and the
    interpreter's own allocations) and is within 2x of it."""
    from onlinemap.estimators.exact import filter_bytes, smooth_bytes, tensor_bytes

    # tensors of 17.8 MB (filter) and 1.8 MB (the smoother, slow at 17 cells: 16-axis tensordots)
    n, steps = (17, 5) if what == "filter" else (14, 3)
    done = subprocess.run([sys.executable, "-c", EXACT_MEASURE, variant, str(n), str(steps), what],
                          capture_output=True, text=True, timeout=300, check=True)
    measured = json.loads(done.stdout)
    model = om.corridor(n, p_change=0.1, **({} if variant == "plain" else {"blocking": [1], "footprint": "cross"}))
    estimate = filter_bytes(model) if what == "filter" else smooth_bytes(model, steps)
    assert measured <= estimate + 2**20 and estimate <= 2 * measured, (measured, estimate)
    old = tensor_bytes(model, 2 if what == "filter" else steps + 2)
    if variant == "both" or what == "smooth":
        assert old < measured / 1.5  # what the old guard missed


def test_an_address_space_limit_below_physical_memory_is_a_memory_limit_error():
    """``ulimit -v`` (RLIMIT_AS) caps what the process may map whatever the machine has: with
    ``max_bytes=inf`` a filter beyond it is refused with MemoryLimitError, never a raw
    MemoryError (issue 43, section 2, item 13). Run in a child process: the limit is for life."""
    import subprocess
    import sys
    import textwrap
    script = textwrap.dedent("""
        import resource, onlinemap as om
        model, _ = om.building(64, 64, seed=0)
        with open("/proc/self/statm") as f:
            mapped = int(f.read().split()[0]) * resource.getpagesize()
        resource.setrlimit(resource.RLIMIT_AS, (mapped + 1_500_000_000, resource.RLIM_INFINITY))
        try:
            om.make_estimator("rbpf", model, n_particles=3_000_000, max_bytes=float("inf"), seed=0)
            print("built")
        except om.MemoryLimitError as exc:
            print("MemoryLimitError", "1.5 GB" in str(exc) or "GB" in str(exc))
        except MemoryError:
            print("raw MemoryError")
    """)
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    assert out.stdout.strip() == "MemoryLimitError True", out.stdout + out.stderr


def test_the_resample_move_scratch_is_counted_before_the_step_is_taken():
    """A move's scratch, about 48 (W + 1) N bytes, is counted by max_bytes: a limit that holds the
    filter but not the scratch is refused when the filter is built, before any step (issue 43,
    section 2, item 3), and the scratch's size is the sum of its arrays, counted by hand here."""
    from onlinemap.estimators.rbpf_move import move_scratch_bytes
    from onlinemap.kernels.rbpf_move import MoveScratch
    model = om.corridor(50)
    window = 30
    n, k, width, f = 50, 2, window + 1, 1
    by_hand = 8 * (2 * n * k + 5 * n + 2 * n + width * n + width + width * n + 2 * width * n + 2 * width * n
                   + 2 * width + 2 * 2 * n + 2 * width * (f + 1) + k)
    assert move_scratch_bytes(model, window) == by_hand
    assert len(MoveScratch._fields) == 17  # the arrays counted above: a new one must be counted too
    from onlinemap.estimators.block_pool import block_shape
    from onlinemap.estimators.rbpf_memory import state_bytes
    from onlinemap.estimators.rbpf_move import new_history_bytes
    size, n_blocks = block_shape(model, None)
    without = state_bytes(model, 4, size, n_blocks, n_blocks + 8, 0, True, 1) + new_history_bytes(model, 4)
    scratch = move_scratch_bytes(model, window)
    with pytest.raises(om.MemoryLimitError, match="move_window"):
        om.make_estimator("rbpf", model, n_particles=4, seed=0, move_window=window, max_bytes=without + scratch // 2)
    om.make_estimator("rbpf", model, n_particles=4, seed=0, move_window=window, max_bytes=without + scratch)
