"""Helpers shared by subcommands: writing tables, parsing lists."""

from __future__ import annotations

import sys
from pathlib import Path

import pandas as pd

from ..errors import OnlineMapError


def split_list(text: str) -> list[str]:
    return [item.strip() for item in text.split(",") if item.strip()]


def write_table(frame: pd.DataFrame, path: str | Path) -> Path:
    """Write ``frame`` as CSV or parquet, chosen by the file suffix."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix == ".csv":
        frame.to_csv(path, index=False)
    elif path.suffix in (".parquet", ".pq"):
        frame.to_parquet(path, index=False)
    else:
        raise OnlineMapError(f"--out {path}: use a .csv or .parquet file name")
    return path


def print_table(frame: pd.DataFrame, float_format: str = "{:.4g}") -> None:
    print(frame.to_string(index=False, float_format=float_format.format))
    sys.stdout.flush()
