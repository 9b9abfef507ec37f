"""The engines: run a spec's tasks serially in this process or on dask.distributed, keep each
finished task in the part store as it finishes, and assemble the table.

Imports: :mod:`.tasks`, :mod:`.kinds`, :mod:`.spec`, :mod:`.runner`, :mod:`.store`, :mod:`onlinemap.tables`;
dask.distributed lazily.
"""

from __future__ import annotations

import logging
import os
import time
import warnings
from importlib.util import find_spec
from typing import Callable

import pandas as pd

from ..errors import OnlineMapError
from ..progress import FEW_TASKS, counting_steps, show_progress, tqdm
from ..tables import check_writable, write_table
from . import runner
from .kinds import Played
from .spec import load_spec, spec_from_dict
from .store import assemble_rows, collect, default_results_dir, finished_tasks, open_store, write_part
from .tasks import MAX_TASKS, SweepSpec, Task, TaskRows, options_text

log = logging.getLogger(__name__)
DASK_HINT = "install dask.distributed with: pip install 'dask[distributed]'"


class SweepError(OnlineMapError):
    """Some tasks of a sweep failed; the finished ones are kept (rerun to retry the rest)."""


def sweep(spec, client=None, *, workers: int | None = None, out: str | os.PathLike | None = None,
          results_dir: str | os.PathLike | None = None, progress: bool = True,
          max_tasks: int = MAX_TASKS, on_played: Callable[[Task, Played], None] | None = None) -> pd.DataFrame:
    """Run every task of ``spec`` and return one table (one row per task, or per task and step).

    spec: a path to a TOML file, a :class:`SweepSpec` or a dict. client: a
    ``distributed.Client``, a scheduler address (``"tcp://host:8786"``) or None. With no
    client, ``workers`` = 0 runs the tasks one by one in this process; N >= 1 starts a local
    dask cluster of N processes (closed afterwards); None (the default) picks: the tasks run in
    this process while the work left looks shorter than what a local cluster would save
    (:func:`prefer_dask`), then on a local cluster of one process per CPU (always in this
    process without dask.distributed or with one CPU). out: also write the table (.csv, or .parquet with pyarrow).
    results_dir: where finished tasks are kept (default ``OUT.parts`` beside ``out``; with
    neither, results live only in memory and nothing resumes). Tasks already there are
    skipped. Raises :class:`SweepError` (after keeping every finished task) if tasks failed.
    on_played: called with each task run and what it played (its true run and the estimator's
    beliefs, :class:`~.kinds.Played`), to keep what a figure needs without running it again;
    with ``workers=0`` only (they stay in this process), and not for tasks resumed from
    ``results_dir``. progress: a bar of tasks; when at most
    :data:`~onlinemap.progress.FEW_TASKS` tasks run in this process, a bar of steps per played
    task instead (:func:`onlinemap.progress.counting_steps`).
    """
    if client is not None and workers is not None:
        raise OnlineMapError("workers sizes a local cluster or picks serial mode (0); not with a client")
    if on_played is not None and (client is not None or workers != 0):
        raise OnlineMapError("on_played needs workers=0: what a task played stays in the process that ran it")
    spec = _as_spec(spec, max_tasks)
    if out is not None:
        check_writable(out)
    if results_dir is None and out is not None:
        results_dir = default_results_dir(out)
    store = open_store(results_dir) if results_dir is not None else None
    todo = _tasks_to_run(spec.tasks, finished_tasks(spec.tasks, store) if store is not None else set())
    # few tasks in this process (a serial sweep of FEW_TASKS never moves to dask): their loops count steps
    steps_counted = show_progress(progress) and client is None and workers in (0, None) and len(todo) <= FEW_TASKS
    bar = tqdm(total=len(spec.tasks), initial=len(spec.tasks) - len(todo), desc=f"sweep {spec.name}",
               unit="task", disable=not show_progress(progress) or steps_counted, smoothing=0.1)
    record = _Recorder(store, on_played, bar)
    try:
        _run_tasks(todo, client, workers, record, steps_counted)
    finally:
        bar.close()
    if store is not None:
        table = collect(store, spec.tasks)
    else:
        table = assemble_rows([record.memory[t.key] for t in spec.tasks if t.key in record.memory])
    if out is not None:
        write_table(table, out, source=spec.text or spec.source)
    if record.failures:
        raise _sweep_error(spec.tasks, record.failures)
    return table


class _Recorder:
    """Keeps each finished task: its rows in the part store (or in ``memory`` without one), what
    it played to ``on_played``, a tick of the bar; a failed task (or one whose part cannot be
    written, e.g. a full disk) joins ``failures`` and the sweep goes on."""

    def __init__(self, store, on_played: Callable[[Task, Played], None] | None, bar) -> None:
        self.store, self.on_played, self.bar = store, on_played, bar
        self.memory: dict[str, TaskRows] = {}
        self.failures: list[tuple[Task, str]] = []

    def __call__(self, task: Task, outcome: runner.Outcome) -> None:
        if outcome.error is not None:  # keep going; every failure is reported at the end
            self.failures.append((task, outcome.error))
            return
        if self.store is not None:
            try:
                write_part(self.store, task, outcome.rows.frame())
            except OSError as error:
                self.failures.append((task, f"{type(error).__name__}: {error}"))
                return
        else:
            self.memory[task.key] = outcome.rows
        if self.on_played is not None:
            self.on_played(task, outcome.played)
        self.bar.update()


def _run_tasks(todo: list[Task], client, workers: int | None, record: _Recorder, steps_counted: bool) -> None:
    """Run ``todo`` in the mode :func:`sweep` describes, each outcome to ``record``: one by one in
    this process (counting steps when ``steps_counted``), by :func:`_run_auto`, or on dask."""
    keep = record.on_played is not None
    if todo and steps_counted:
        with counting_steps():
            for task in todo:
                record(task, runner.attempt(task, keep=keep))
    elif todo and client is None and workers == 0:
        for task in todo:
            record(task, runner.attempt(task, keep=keep))
    elif todo and client is None and workers is None:
        _run_auto(todo, record)
    elif todo:
        _run_dask(todo, client, workers, record)


def _tasks_to_run(tasks: tuple[Task, ...], done: set) -> list[Task]:
    """The tasks not ``done``, those sharing a run one after the other (in the order their runs
    first appear), so that the memoised run and reference are reused. O(tasks log tasks)."""
    todo = [t for t in tasks if t.key not in done]
    first: dict[tuple, int] = {}
    for task in todo:
        first.setdefault(_run_key(task), len(first))
    todo.sort(key=lambda task: first[_run_key(task)])
    return todo


def _sweep_error(tasks: tuple[Task, ...], failures: list[tuple[Task, str]]) -> SweepError:
    """The error of a sweep whose ``failures`` (task, message) are not empty: how many, and the
    first in the spec's order, so that a rerun meets it first too."""
    position = {t.key: i for i, t in enumerate(tasks)}
    task, error = min(failures, key=lambda failure: position[failure[0].key])
    return SweepError(f"{len(failures)} of {len(tasks)} tasks failed (the others are kept; rerun to "
                      f"retry); first: {task.estimator}({options_text(task.options)}) on {task.world}, "
                      f"seed {task.seed}: {error}")


#: seconds a local cluster costs before it pays: start the processes, import onlinemap and load the
#: kernels in each, close them (11-13 s measured on the shared, loaded 2-core machine)
DASK_START_SECONDS = 12.0


def prefer_dask(seconds: list[float], remaining: int, cpus: int, start: float = DASK_START_SECONDS) -> bool:
    """Whether a local cluster of ``min(cpus, remaining)`` processes would finish the ``remaining``
    tasks sooner than this process, given the ``seconds`` the tasks run here so far took. The
    first task is left out of the estimate (it compiles the kernels); with P processes the
    cluster saves ``(1 - 1/P)`` of the serial time and costs ``start`` seconds. Needs two tasks."""
    workers = min(cpus, remaining)
    if len(seconds) < 2 or workers < 2:
        return False
    serial = sum(seconds[1:]) / (len(seconds) - 1) * remaining
    return serial * (1 - 1 / workers) > start


def _run_auto(todo: list[Task], record) -> None:
    """Run ``todo`` in this process until :func:`prefer_dask` says a local cluster would finish
    the rest sooner, then the rest on one (17.2 s on a cluster against 7.0 s serial for a spec of
    50 small tasks is what this avoids)."""
    cpus = os.cpu_count() or 1
    parallel = cpus > 1 and find_spec("distributed") is not None
    seconds: list[float] = []
    for position, task in enumerate(todo):
        started = time.perf_counter()
        record(task, runner.attempt(task))
        seconds.append(time.perf_counter() - started)
        rest = todo[position + 1:]
        if parallel and rest and prefer_dask(seconds, len(rest), cpus, DASK_START_SECONDS):
            log.info("sweep: %d tasks left, about %.0f s of work here: on a local dask cluster", len(rest),
                     sum(seconds[1:]) / (len(seconds) - 1) * len(rest))
            _run_dask(rest, None, None, record)
            return


def _run_key(task: Task) -> tuple:
    """What determines a task's simulated run (and its reference trajectory)."""
    return task.world, task.steps, task.walk, task.seed, task.reference, task.planner is None


def _as_spec(spec, max_tasks: int = MAX_TASKS) -> SweepSpec:
    if isinstance(spec, SweepSpec):
        return spec
    if isinstance(spec, dict):
        return spec_from_dict(spec, max_tasks=max_tasks)
    if isinstance(spec, (str, os.PathLike)):
        return load_spec(spec, max_tasks)
    raise TypeError(f"spec must be a path, a dict or a SweepSpec, got {type(spec).__name__}")


def _dask():
    try:
        import distributed
    except ImportError:
        raise OnlineMapError(f"running a sweep on dask needs dask.distributed; {DASK_HINT} "
                             f"(or run serially with workers=0 / --workers 0)") from None
    return distributed


def local_cluster(workers: int | None = None, n_tasks: int | None = None):
    """A dask ``LocalCluster`` of worker processes, one thread each (the numerics hold the GIL
    or are numba kernels): ``workers`` processes, default one per CPU (at most one per task)."""
    distributed = _dask()
    count = workers or max(1, min(os.cpu_count() or 1, n_tasks or os.cpu_count() or 1))
    with warnings.catch_warnings():  # another cluster on this machine holds the default HTTP port
        warnings.filterwarnings("ignore", message="Port .* is already in use", category=UserWarning)
        return distributed.LocalCluster(n_workers=count, threads_per_worker=1, processes=True,
                                        dashboard_address=None, silence_logs=logging.CRITICAL)


def _run_dask(todo: list[Task], client, workers: int | None, record) -> None:
    distributed = _dask()
    owned, futures = [], []
    if client is None:
        cluster = local_cluster(workers, len(todo))
        client = distributed.Client(cluster)
        owned = [client, cluster]
    elif isinstance(client, str):
        client = connect(client)
        owned = [client]
    try:
        futures = client.map(runner.attempt, todo, pure=False)  # a task's error comes back as a value
        by_key = {future.key: task for future, task in zip(futures, todo)}
        completed = distributed.as_completed(futures)
        for future in completed:
            task = by_key[future.key]
            try:
                outcome = future.result()
            except Exception as error:  # the worker itself failed (killed, out of memory)
                if future.status in ("lost", "pending"):  # its worker died after it finished: recomputed
                    completed.add(future)
                    continue
                outcome = runner.Outcome(None, f"{type(error).__name__}: {error}")
            record(task, outcome)
            future.release()
    except BaseException:
        client.cancel(futures)
        raise
    finally:
        for resource in owned:
            resource.close()




def connect(address: str, timeout: float = 10.0):
    """A ``distributed.Client`` on the scheduler at ``address`` (``tcp://host:8786``); an
    address that does not parse or answer within ``timeout`` seconds raises OnlineMapError."""
    distributed = _dask()
    if "://" not in address and ":" not in address:
        raise OnlineMapError(f"--scheduler {address!r}: expected a scheduler address such as tcp://host:8786")
    try:
        return distributed.Client(address, timeout=timeout)
    except Exception as error:  # ValueError, OSError, TimeoutError: whatever the comm layer raises
        raise OnlineMapError(f"--scheduler {address!r}: cannot connect: {type(error).__name__}: {error}") from None
