"""Writing result tables: CSV or parquet, chosen by the file suffix."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from .errors import OnlineMapError


def write_table(frame: pd.DataFrame, path: str | Path) -> Path:
    """Write ``frame`` as CSV or parquet, chosen by the file suffix (creating the directory);
    returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix == ".csv":
        frame.to_csv(path, index=False)
    elif path.suffix in (".parquet", ".pq"):
        frame.to_parquet(path, index=False)
    else:
        raise OnlineMapError(f"--out {path}: use a .csv or .parquet file name")
    return path
