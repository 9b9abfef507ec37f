"""Experiment sweeps: worlds x estimators x option grids x seeds, run serially or on
dask.distributed, written incrementally, resumable, summarised with confidence intervals.

A spec is a TOML file (every key but ``worlds`` and ``estimators`` optional)::

    name = "rbpf-vs-particles"        # a label
    worlds = ["corridor:8", "corridor:8,p_change=0.01"]   # world specs (onlinemap.worlds)
    seeds = 20                         # 20 -> seeds 0..19; or a list [0, 4, 7]
    steps = 100                        # steps per run (first observation included); or a list;
                                       # "trip": one there-and-back trip, 2 (N - 1) + 1 steps
    walk = "random"                    # "random", "there_and_back" (corridors) or "scripted_trip"
                                       # (one trip, one slip, noise-free observations); or a list
    rows = "task"                      # "task": one row per task; "step": one per task and step
    reference = "exact"                # also run this estimator on every run and record the
                                       # total variation of each belief to it

    [estimators.exact]                 # one table per registered estimator: its options,
    [estimators.rbpf]                  # each a value or a list of values (a grid)
    n_particles = [10, 30, 100]
    proposal = ["transition", "optimal"]

    [[estimators.online_em]]           # an array of tables: several grids of one estimator
    window = "max"
    [[estimators.online_em]]
    window = [1, 2, 4, 8]
    decay = [0.8, 1.0]

A list is always a grid; a list-valued option is written as a list of lists
(``anneal = [[1.0, 0.9, 0.05]]``). With ``[planners.NAME]`` tables (``entropy``, ``random``,
``sweep`` from the ``policies`` package, options as grids too) every task is an exploration
run instead (:func:`policies.explore`: the planner chooses the actions, the estimator tracks
the belief); ``walk`` and ``reference`` do not apply there, and ``floor_plan = 0.8`` (or a
list) gives the robot a label prior that puts that confidence on the true initial map
(``policies.with_floor_plan``; door cells: a door, state unknown); ``goals = [CELL, ...]`` makes
every task a navigation run to each goal instead. Planner names and options come from the task
kind that plays them (:mod:`.kinds`; ``policies.PLANNERS``), which the engine never imports.

Every task is one cell of the product (world, estimator configuration[, planner
configuration], steps, walk, seed). The spec is checked completely before any task runs:
unknown keys, estimators, planners or options, wrong types, world specs, and every
(world, configuration) pair is built once, so option values an estimator refuses and memory
limits are caught too. Errors name the file, line and key path (:class:`SpecError`).

A task simulates its run from its seed exactly as ``onlinemap run --seed`` does
(``default_rng(seed)`` draws the map, then the walk, then the noise); estimators with a
``seed`` option get one derived from the task's seed (unless the spec sets it). Results:
one ``.npz`` file per finished task (pickle-free; no pyarrow needed), named by a hash of the
task, in a results directory;
rerunning skips the tasks found there, and the final table holds each task of the spec once.
Its columns: the task's description (``task`` hash, ``kind``, ``world``, ``estimator``,
``options`` as text and one ``opt_NAME`` column per option, ``steps``, ``seed``, ...) then the
metrics of :func:`run_task` (:mod:`onlinemap.evaluate`). Cost: the tasks' own, spread over the
workers, plus a few milliseconds of dask overhead per task and seconds to start a local cluster.

The package, one job per module, imports running one way (``tasks`` <- ``spec``, ``runner``,
``store`` <- ``engines``; ``summary`` beside them):

- :mod:`.tasks`: :class:`Task`, :class:`SweepSpec`, expansion of a grid into tasks (counted and
  capped first), a task's rows as plain columns (``TaskRows``);
- :mod:`.spec`: reading and validating TOML specs (:func:`load_spec`, :class:`SpecError`);
- :mod:`.kinds`: the kinds of task played by packages above the engine (``explore``,
  ``navigate``: ``policies``), registered or found through entry points, never imported;
- :mod:`.runner`: one task (:func:`run_task`): simulate and estimate, or play its kind; score;
- :mod:`.store`: the part store (atomic parts, resume, :func:`collect` without the spec) and
  the table of many tasks' rows, built once (``assemble_rows``);
- :mod:`.engines`: :func:`sweep` serially or on dask.distributed (by default serially unless a
  local cluster pays: :func:`prefer_dask`);
- :mod:`.summary`: :func:`summarize`, :func:`summary_table`, :func:`plot_sweep`.
"""

from .engines import SweepError, connect, local_cluster, prefer_dask, sweep
from .runner import derived_seed, played_map, run_task, scripted_trip, simulated_run, walk_actions, world
from .spec import MAX_SEED, MAX_STEPS, SpecError, load_spec, matches_annotation, parse_spec, spec_from_dict
from .store import assemble, collect, default_results_dir, finished_tasks, read_part, write_part
from .kinds import Played, TaskKind, register_kind, task_kind
from .summary import last_steps, plot_sweep, summarize, summary_table, summary_wide
from .tasks import CONFIG_COLUMNS, MAX_TASKS, TASK_COLUMNS, SweepSpec, Task, count_tasks, expand

__all__ = [
    "sweep", "SweepError", "SpecError", "SweepSpec", "Task", "load_spec", "parse_spec", "spec_from_dict",
    "matches_annotation", "run_task", "played_map", "simulated_run", "scripted_trip", "walk_actions", "derived_seed", "world",
    "collect", "assemble", "default_results_dir", "finished_tasks", "read_part", "write_part", "local_cluster",
    "connect", "prefer_dask",
    "summarize", "summary_table", "summary_wide", "plot_sweep", "last_steps", "expand", "count_tasks",
    "TaskKind", "Played", "register_kind", "task_kind",
    "TASK_COLUMNS", "CONFIG_COLUMNS", "MAX_TASKS", "MAX_SEED", "MAX_STEPS",
]
