"""Helpers shared by subcommands: writing tables, parsing lists and ``--option KEY=VALUE``."""

from __future__ import annotations

import json
import sys

import pandas as pd

from ..errors import OnlineMapError
from ..tables import write_table

__all__ = ["OPTION_HELP", "parse_options", "print_table", "split_list", "write_table"]


def split_list(text: str) -> list[str]:
    return [item.strip() for item in text.split(",") if item.strip()]


OPTION_HELP = ("VALUE is read as JSON when it parses (4, 0.9, null, [1, 0.9, 0.01]) and as a string "
               "otherwise (e.g. window=max)")


def parse_options(pairs: list[str]) -> dict[str, object]:
    """``["window=4", "decay=0.9", "window=max"]`` -> dict; JSON values where they parse (lists
    become tuples), strings otherwise."""
    options: dict[str, object] = {}
    for pair in pairs:
        key, eq, text = pair.partition("=")
        if not eq or not key.strip():
            raise OnlineMapError(f"--option {pair!r}: expected KEY=VALUE")
        try:
            value = json.loads(text)
        except ValueError:
            value = text
        options[key.strip()] = tuple(value) if isinstance(value, list) else value
    return options


def print_table(frame: pd.DataFrame, float_format: str = "{:.4g}") -> None:
    print(frame.to_string(index=False, float_format=float_format.format))
    sys.stdout.flush()
