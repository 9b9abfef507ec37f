"""Progress bars: one rule for the whole library and the command line.

A bar is shown only when the caller asks for one (``progress=True``), stderr is a terminal, and
the environment variable ``ONLINEMAP_PROGRESS`` is not ``0`` (``onlinemap --no-progress`` sets
it). So pipes, CI logs and notebooks get no bars and no tqdm warnings.

``tqdm`` here is the plain console bar (``tqdm.std``; ``tqdm.auto`` warns in notebooks without
ipywidgets) with that rule built in: ``tqdm(items, disable=not progress)`` draws only when
:func:`show_progress` also allows it. Use it for every bar in the library.
"""

from __future__ import annotations

import os
import sys

from tqdm import tqdm as _console_tqdm

PROGRESS_ENV = "ONLINEMAP_PROGRESS"

__all__ = ["PROGRESS_ENV", "show_progress", "tqdm"]


def show_progress(progress: bool = True) -> bool:
    """Whether to draw a bar: ``progress`` and stderr is a terminal and ``ONLINEMAP_PROGRESS != 0``."""
    if not progress or os.environ.get(PROGRESS_ENV, "1").strip().lower() in ("0", "false", "no", "off"):
        return False
    isatty = getattr(sys.stderr, "isatty", None)
    return bool(isatty and isatty())


class tqdm(_console_tqdm):
    """``tqdm.std.tqdm`` that stays silent unless :func:`show_progress` allows a bar."""

    def __init__(self, *args, disable: bool | None = False, **kwargs):
        super().__init__(*args, disable=bool(disable) or not show_progress(), **kwargs)
