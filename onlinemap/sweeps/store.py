"""The part store: one file per finished task in a results directory, written atomically
(:func:`onlinemap.atomic.atomic_write`), so an interrupted or crashed sweep resumes where it
stopped; temporaries a killed process left are removed when the store is opened.

A part is a pickle-free ``.npz`` (numpy's own format, so the base install reads and writes it;
no pyarrow): one array per column (numbers and booleans as they are, text as unicode) and a
JSON header naming the columns in order, their kinds and the task's option values. A column of
anything else (text with missing values, mixed types) is stored as JSON. Each part holds its
task's description and its options, so a folder of parts assembles into the final table
without the spec (:func:`collect`). Option columns get one type each: nullable integers
(``Int64``) when every value is an int, floats, booleans or text, and JSON text when values mix
types or are lists. Reading a part never unpickles anything (``allow_pickle=False``).

The same table from tasks held in memory: :func:`assemble` of their frames, or, as the engines
do, :func:`assemble_rows` of their plain rows (one frame built for all of them, not one each).

Imports: :mod:`.tasks`, :mod:`onlinemap.atomic`.
"""

from __future__ import annotations

import json
import os
import zipfile
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np
import pandas as pd

from ..atomic import atomic_write, remove_temporaries
from ..errors import OnlineMapError
from .tasks import OPTION_PREFIXES, TASK_COLUMNS, Task, TaskRows, plain, stacked

PART_SUFFIX = ".npz"
PART_FORMAT = 1
_HEADER = "__part__"  # the entry holding the JSON header
NULLABLE = ("Int64", "boolean", "Float64")  # pandas' nullable types a part restores by name


def default_results_dir(out: str | os.PathLike) -> Path:
    """``results.csv`` -> ``results.parts/``: where finished tasks are kept."""
    out = Path(out)
    return out.with_name(out.stem + ".parts")


def open_store(results_dir: str | os.PathLike) -> Path:
    """Create ``results_dir`` if needed and remove temporaries a killed sweep left there."""
    results_dir = Path(results_dir)
    results_dir.mkdir(parents=True, exist_ok=True)
    remove_temporaries(results_dir)
    return results_dir


def part_path(results_dir: Path, task: Task) -> Path:
    return Path(results_dir) / f"{task.key}{PART_SUFFIX}"


def _is_option(column: str) -> bool:
    return column.startswith(tuple(OPTION_PREFIXES.values()))


def _encode(column: pd.Series) -> tuple[str, np.ndarray | list]:
    """(kind, data) of one column: ``array`` (numpy numbers, booleans), ``text`` (text without
    missing values) or ``json`` (anything else, as a list of JSON values; pandas' nullable types
    keep their name, :data:`NULLABLE`)."""
    if isinstance(column.dtype, np.dtype) and column.dtype.kind in "biuf":
        return "array", column.to_numpy()
    values = column.tolist()
    if pd.api.types.is_string_dtype(column) and all(isinstance(v, str) for v in values):
        return "text", np.array(values, dtype=str)
    return "json", [_json_value(v) for v in values]


def _json_value(value):
    if isinstance(value, np.generic):
        return value.item()
    if value is pd.NA or value is pd.NaT:
        return None
    return plain(value)


def write_part(results_dir: Path, task: Task, frame: pd.DataFrame) -> Path:
    """Write one task's rows atomically: a reader (or a resumed sweep) sees the whole file or none.
    Cost: one pass over the rows (zlib-compressed, so repeated text costs little)."""
    header = {"format": PART_FORMAT, "rows": len(frame), "columns": [], "options": {}}
    arrays: dict[str, np.ndarray] = {}
    for position, name in enumerate(frame.columns):
        if _is_option(name):
            header["options"][name] = _json_value(frame[name].iloc[0]) if len(frame) else None
            continue
        kind, data = _encode(frame[name])
        header["columns"].append([name, kind])
        if kind == "json":
            header.setdefault("json", {})[name] = data
            if str(frame[name].dtype) in NULLABLE:
                header["columns"][-1].append(str(frame[name].dtype))
        else:
            arrays[f"c{position}"] = data
            header["columns"][-1].append(f"c{position}")
    arrays[_HEADER] = np.array(json.dumps(header, allow_nan=True))
    return atomic_write(part_path(results_dir, task), lambda file: np.savez_compressed(file, **arrays))


def read_part(path: str | os.PathLike) -> pd.DataFrame:
    """One part as the task's frame (its columns in order, option columns last, repeated on every
    row as the task wrote them). A damaged part raises :class:`OnlineMapError` naming the file."""
    try:
        with np.load(path, allow_pickle=False) as entries:
            header = json.loads(str(entries[_HEADER][()]))
            if header.get("format") != PART_FORMAT:
                raise ValueError(f"part format {header.get('format')!r}, this onlinemap reads {PART_FORMAT}")
            data = {}
            for name, kind, *entry in header["columns"]:
                if kind == "json":  # entry: the nullable type's name, if any
                    data[name] = pd.Series(pd.array(header["json"][name], dtype=entry[0]) if entry else
                                           header["json"][name])
                else:
                    data[name] = pd.Series(entries[entry[0]])
    except (OSError, ValueError, KeyError, TypeError, zipfile.BadZipFile) as error:
        raise OnlineMapError(f"cannot read sweep part {path}: {error} (delete it to rerun its task)") from None
    frame = pd.DataFrame(data, index=pd.RangeIndex(header["rows"]))
    for name, value in header["options"].items():
        frame[name] = [value] * len(frame)
    return frame


def finished_tasks(tasks: Iterable[Task], results_dir: str | os.PathLike) -> set[str]:
    """Keys of the tasks whose result file exists in ``results_dir``."""
    return {task.key for task in tasks if part_path(Path(results_dir), task).exists()}


def collect(results_dir: str | os.PathLike, tasks: Iterable[Task] | None = None) -> pd.DataFrame:
    """One table from the parts in ``results_dir``: those of ``tasks`` (each once, in spec order;
    parts of other tasks, e.g. from an older version of the spec, are left out), or with no
    ``tasks`` every part there (in file-name order): no spec needed. The same table as
    :func:`assemble` of the frames the tasks returned."""
    results_dir = Path(results_dir)
    if tasks is None:
        paths = sorted(results_dir.glob(f"*{PART_SUFFIX}"))
    else:
        paths = [path for path in (part_path(results_dir, t) for t in tasks) if path.exists()]
    return assemble([read_part(path) for path in paths])


def assemble(frames: Sequence[pd.DataFrame]) -> pd.DataFrame:
    """One table from task frames held in memory (as :func:`collect` does for parts): the frames'
    rows in order without their option columns, then one typed column per option
    (:func:`with_options`). The frames of each list of columns (one per configuration of
    options) are concatenated and stripped of their options at once (:func:`in_order`). Cost:
    O(rows x columns), plus about a millisecond per frame."""
    if not frames:
        return pd.DataFrame(columns=TASK_COLUMNS)
    groups: dict[tuple, list[int]] = {}  # each distinct list of columns -> the positions of its frames
    for position, frame in enumerate(frames):
        groups.setdefault(tuple(frame.columns), []).append(position)
    options = _option_names(groups)
    values = [[None] * len(frames) for _ in options]
    parts = []
    for columns, members in groups.items():
        for name, row in zip(options, values):
            if name in columns:
                at = columns.index(name)
                for position in members:
                    row[position] = frames[position].iat[0, at] if len(frames[position]) else None
        parts.append(pd.concat([frames[position] for position in members], ignore_index=True).drop(
            columns=[c for c in columns if c in options]))
    lengths = [len(frame) for frame in frames]
    return with_options(in_order(parts, list(groups.values()), lengths), options, values, lengths)


def assemble_rows(results: Sequence[TaskRows]) -> pd.DataFrame:
    """The table :func:`assemble` makes of the tasks' frames (``TaskRows.frame``), bit for bit,
    without building them: the tasks whose columns have the same names and, in each, values of
    the same type (or arrays of the same dtype) are one frame (:func:`~.tasks.stacked`: pandas
    infers each column's type once, as it does for each task alone), and these frames are
    concatenated as the tasks' would be (:func:`in_order`); a task with a column of any other
    kind of value is a frame of its own. Cost: O(rows x columns), a few microseconds per task."""
    if not results:
        return pd.DataFrame(columns=TASK_COLUMNS)
    groups: dict[tuple, list[int]] = {}
    for position, rows in enumerate(results):
        groups.setdefault(_signature(rows) or (position,), []).append(position)
    parts = [stacked([results[p].columns for p in members], [results[p].n for p in members])
             for members in groups.values()]
    options = _option_names(rows.options for rows in results)
    values = [[rows.options.get(name) if rows.n else None for rows in results] for name in options]
    lengths = [rows.n for rows in results]
    return with_options(in_order(parts, list(groups.values()), lengths), options, values, lengths)


#: the Python types of values whose type pandas infers alike for one value and for many
PLAIN_TYPES = (bool, int, float, str, type(None), np.bool_, np.int64, np.float64)


def _signature(rows: TaskRows) -> tuple | None:
    """The names of a task's columns and the type of each (an array's dtype, a value's Python
    type); None if a column holds anything else (an array of objects, a list, a big integer)."""
    kinds = []
    for value in rows.columns.values():
        if isinstance(value, np.ndarray):
            kind = value.dtype if value.dtype.kind in "biuf" else None
        else:
            kind = type(value) if type(value) in PLAIN_TYPES and not (
                type(value) is int and not -2 ** 63 <= value < 2 ** 63) else None
        if kind is None:
            return None
        kinds.append(kind)
    return tuple(rows.columns), tuple(kinds)


def in_order(parts: list[pd.DataFrame], groups: list[list[int]], lengths: Sequence[int]) -> pd.DataFrame:
    """Concatenate ``parts`` (part g: the rows of the tasks at positions ``groups[g]``, of
    ``lengths`` rows each, in that order) and put the rows back in the tasks' order, with a fresh
    index: the table of concatenating the tasks' frames one by one (a column missing from some
    tasks filled as pandas fills it). Cost: O(rows x columns)."""
    if len(parts) == 1:
        return parts[0]
    order = np.concatenate(groups)  # the tasks in the order their rows were concatenated
    rows = np.argsort(np.repeat(order, np.asarray(lengths, dtype=np.int64)[order]), kind="stable")
    return pd.concat(parts, ignore_index=True).take(rows).reset_index(drop=True)


def _option_names(column_lists) -> list[str]:
    names = {c for columns in column_lists for c in columns if _is_option(c)}
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
