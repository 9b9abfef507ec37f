"""The part store: one parquet file per finished task in a results directory, written
atomically (:func:`onlinemap.atomic.atomic_write`), so an interrupted or crashed sweep resumes
where it stopped; temporaries a killed process left are removed when the store is opened.

Each part holds its task's description and typed ``opt_NAME`` columns, so a folder of parts
assembles into the final table without the spec (:func:`collect`). Option columns get one
type each: nullable integers (``Int64``) when every value is an int, floats, booleans or text,
and JSON text when values mix types or are lists.

Imports: :mod:`.tasks`, :mod:`onlinemap.atomic`; pyarrow.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np
import pandas as pd

from ..atomic import atomic_write, remove_temporaries
from ..errors import OnlineMapError
from .tasks import OPTION_PREFIXES, TASK_COLUMNS, Task, plain

PART_SUFFIX = ".parquet"


def _pyarrow():
    try:
        import pyarrow
        import pyarrow.parquet
    except ImportError:
        raise OnlineMapError("keeping sweep results on disk needs pyarrow: pip install 'onlinemap[sweeps]' "
                             "(or run without --out / results_dir)") from None
    return pyarrow


def default_results_dir(out: str | os.PathLike) -> Path:
    """``results.parquet`` -> ``results.parts/``: where finished tasks are kept."""
    out = Path(out)
    return out.with_name(out.stem + ".parts")


def open_store(results_dir: str | os.PathLike) -> Path:
    """Create ``results_dir`` if needed and remove temporaries a killed sweep left there."""
    _pyarrow()
    results_dir = Path(results_dir)
    results_dir.mkdir(parents=True, exist_ok=True)
    remove_temporaries(results_dir)
    return results_dir


def part_path(results_dir: Path, task: Task) -> Path:
    return Path(results_dir) / f"{task.key}{PART_SUFFIX}"


def write_part(results_dir: Path, task: Task, frame: pd.DataFrame) -> Path:
    """Write one task's rows atomically: a reader (or a resumed sweep) sees the whole file or none."""
    return atomic_write(part_path(results_dir, task), lambda file: frame.to_parquet(file, index=False))


def finished_tasks(tasks: Iterable[Task], results_dir: str | os.PathLike) -> set[str]:
    """Keys of the tasks whose result file exists in ``results_dir``."""
    return {task.key for task in tasks if part_path(Path(results_dir), task).exists()}


def collect(results_dir: str | os.PathLike, tasks: Iterable[Task] | None = None) -> pd.DataFrame:
    """One table from the parts in ``results_dir``: those of ``tasks`` (each once, in spec order;
    parts of other tasks, e.g. from an older version of the spec, are left out), or with no
    ``tasks`` every part there (in file-name order): no spec needed."""
    pa = _pyarrow()
    results_dir = Path(results_dir)
    if tasks is None:
        paths = sorted(results_dir.glob(f"*{PART_SUFFIX}"))
    else:
        paths = [path for path in (part_path(results_dir, t) for t in tasks) if path.exists()]
    parts = [pa.parquet.read_table(path) for path in paths]  # pyarrow: ~3x faster than pandas
    options = _option_names(part.column_names for part in parts)
    values = [[part.column(name)[0].as_py() if name in part.column_names and part.num_rows else None
               for part in parts] for name in options]
    bases = [part.drop_columns([c for c in part.column_names if c in options]) for part in parts]
    if not bases:
        table = pd.DataFrame(columns=TASK_COLUMNS)
    else:
        try:
            table = pa.concat_tables(bases, promote_options="permissive").to_pandas()
        except (pa.ArrowInvalid, pa.ArrowTypeError):  # columns whose types differ between tasks
            table = pd.concat([base.to_pandas() for base in bases], ignore_index=True)
    return with_options(table, options, values, [part.num_rows for part in parts])


def assemble(frames: Sequence[pd.DataFrame]) -> pd.DataFrame:
    """One table from task frames held in memory (as :func:`collect` does for parts)."""
    options = _option_names(frame.columns for frame in frames)
    values = [[frame[name].iloc[0] if name in frame and len(frame) else None for frame in frames]
              for name in options]
    bases = [frame.drop(columns=[c for c in frame.columns if c in options]) for frame in frames]
    table = pd.concat(bases, ignore_index=True) if bases else pd.DataFrame(columns=TASK_COLUMNS)
    return with_options(table, options, values, [len(frame) for frame in frames])


def _option_names(column_lists) -> list[str]:
    names = {c for columns in column_lists for c in columns if c.startswith(tuple(OPTION_PREFIXES.values()))}
    return sorted(names, key=lambda c: (c.startswith("planner_"), c))


def with_options(table: pd.DataFrame, names: list[str], values: list[list], repeats: list[int]) -> pd.DataFrame:
    """Append one typed column per option name: ``values[i][j]`` is option i of part j (None if
    the part has no such option), repeated over the part's ``repeats[j]`` rows."""
    repeats = np.asarray(repeats, dtype=np.int64)
    for name, column in zip(names, values):
        table[name] = option_column(column, repeats)
    return table


def option_column(values: list, repeats: np.ndarray) -> pd.Series:
    """One readable, typed column: Int64 / float / boolean / text, else JSON text."""
    values = [v.tolist() if isinstance(v, np.ndarray) else v.item() if isinstance(v, np.generic) else v
              for v in values]
    present = [v for v in values if v is not None]
    kinds = {type(v) for v in present}
    if kinds <= {bool}:
        dtype = pd.BooleanDtype()
    elif kinds <= {int}:
        dtype = pd.Int64Dtype()
    elif kinds <= {int, float}:
        dtype, values = np.float64, [np.nan if v is None else float(v) for v in values]
    elif kinds <= {str}:
        dtype = object
    else:  # mixed types or lists: one readable type per column
        dtype, values = object, [None if v is None else json.dumps(plain(v)) for v in values]
    return pd.Series(pd.array(np.repeat(np.array(values, dtype=object), repeats), dtype=dtype))
