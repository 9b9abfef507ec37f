"""Writing result tables: CSV or parquet (chosen by the file suffix), atomically, with provenance.

Every table records what produced it (:func:`provenance`: the onlinemap version, the git commit
when the package runs from a checkout, and the command or spec): in the parquet file's schema
metadata under the key ``onlinemap``, and for a CSV in a sidecar ``NAME.csv.json``. Files are
written through :func:`onlinemap.atomic.atomic_write`: a failed write (disk full) keeps the
previous file.
"""

from __future__ import annotations

import functools
import json
import subprocess
import sys
from pathlib import Path

import pandas as pd

from .atomic import atomic_write
from .errors import OnlineMapError

METADATA_KEY = "onlinemap"
SUFFIXES = (".csv", ".parquet", ".pq")


@functools.lru_cache(maxsize=1)
def git_commit() -> str | None:
    """The commit of the checkout onlinemap runs from (``-dirty`` if modified), else None."""
    root = Path(__file__).resolve().parents[1]
    if not (root / ".git").exists():
        return None
    try:
        commit = subprocess.run(["git", "-C", str(root), "describe", "--always", "--dirty", "--abbrev=40"],
                                capture_output=True, text=True, timeout=5)
    except (OSError, subprocess.SubprocessError):
        return None
    return commit.stdout.strip() or None if commit.returncode == 0 else None


def provenance(source: str | None = None) -> dict:
    """What produced a table: onlinemap version, git commit (or None) and ``source`` (a spec's
    text or a command line; default: this process's command line)."""
    from ._version import __version__

    return {"onlinemap_version": __version__, "git_commit": git_commit(),
            "source": source if source is not None else " ".join(["onlinemap", *sys.argv[1:]])}


def check_writable(path: str | Path) -> Path:
    """Refuse an output name early (before any work): a known suffix, and pyarrow for parquet."""
    path = Path(path)
    if path.suffix not in SUFFIXES:
        raise OnlineMapError(f"--out {path}: use a .csv or .parquet file name")
    if path.suffix != ".csv":
        try:
            import pyarrow.parquet  # noqa: F401  (fails early, before any work)
        except ImportError:
            raise OnlineMapError(f"--out {path}: writing parquet needs pyarrow (pip install pyarrow), "
                                 f"or write a .csv") from None
    return path


def write_table(frame: pd.DataFrame, path: str | Path, source: str | None = None) -> Path:
    """Write ``frame`` as CSV or parquet by suffix, atomically, with :func:`provenance`
    (``source``) attached; returns the path. Cost: the frame's serialisation plus two fsyncs."""
    path = check_writable(path)
    meta = provenance(source)
    if path.suffix == ".csv":
        atomic_write(path, lambda file: file.write(frame.to_csv(index=False).encode()))
        atomic_write(path.with_name(path.name + ".json"),
                     lambda file: file.write(json.dumps(meta, indent=1).encode()))
    else:
        import pyarrow as pa
        import pyarrow.parquet as pq

        table = pa.Table.from_pandas(frame, preserve_index=False)
        table = table.replace_schema_metadata({**(table.schema.metadata or {}),
                                               METADATA_KEY.encode(): json.dumps(meta).encode()})
        atomic_write(path, lambda file: pq.write_table(table, file))
    return path


def read_provenance(path: str | Path) -> dict | None:
    """The provenance stored with a table written by :func:`write_table` (None if absent)."""
    path = Path(path)
    if path.suffix == ".csv":
        sidecar = path.with_name(path.name + ".json")
        return json.loads(sidecar.read_text()) if sidecar.exists() else None
    import pyarrow.parquet as pq

    metadata = pq.read_schema(path).metadata or {}
    raw = metadata.get(METADATA_KEY.encode())
    return json.loads(raw) if raw else None
