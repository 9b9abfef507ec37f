"""Progress bars: one rule for the whole library and the command line.

A bar is shown only when the caller asks for one (``progress=True``), stderr is a terminal, and
the environment variable ``ONLINEMAP_PROGRESS`` is not ``0`` (``onlinemap --no-progress`` sets
it). So pipes, CI logs and notebooks get no bars and no tqdm warnings. ``tqdm`` here is the plain
console bar (``tqdm.std``): ``tqdm.auto`` warns in notebooks without ipywidgets.

    for item in tqdm(items, desc="runs", disable=not show_progress(progress)): ...
"""

from __future__ import annotations

import os
import sys

from tqdm import tqdm

PROGRESS_ENV = "ONLINEMAP_PROGRESS"

__all__ = ["PROGRESS_ENV", "show_progress", "tqdm"]


def show_progress(progress: bool = True) -> bool:
    """Whether to draw a bar: ``progress`` and stderr is a terminal and ``ONLINEMAP_PROGRESS != 0``."""
    if not progress or os.environ.get(PROGRESS_ENV, "1").strip().lower() in ("0", "false", "no", "off"):
        return False
    isatty = getattr(sys.stderr, "isatty", None)
    return bool(isatty and isatty())
