"""Progress bars: one rule for the whole library and the command line.

A bar is shown only when the caller asks for one (``progress=True``), stderr is a terminal, and
the environment variable ``ONLINEMAP_PROGRESS`` is not ``0`` (``onlinemap --no-progress`` sets
it). So pipes, CI logs and notebooks get no bars and no tqdm warnings.

A sweep of few tasks (at most :data:`FEW_TASKS`, run in this process: ``explore`` or ``navigate``
with one or two planners and seeds) counts steps instead of tasks: the engine hides its task bar
and runs the tasks inside :func:`counting_steps`, and each played run's loop shows its own bar of
steps when :func:`step_bars` says so (a 3-minute building run no longer sits at ``0/1``).

``tqdm`` here is the plain console bar (``tqdm.std``; ``tqdm.auto`` warns in notebooks without
ipywidgets) with that rule built in: ``tqdm(items, disable=not progress)`` draws only when
:func:`show_progress` also allows it. Use it for every bar in the library.
"""

from __future__ import annotations

import contextlib
import contextvars
import os
import sys

from tqdm import tqdm as _console_tqdm

PROGRESS_ENV = "ONLINEMAP_PROGRESS"

__all__ = ["FEW_TASKS", "PROGRESS_ENV", "counting_steps", "show_progress", "step_bars", "tqdm"]

FEW_TASKS = 2  # a sweep of at most this many tasks counts their steps, not the tasks
_STEP_BARS = contextvars.ContextVar("onlinemap_step_bars", default=False)


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


def step_bars() -> bool:
    """Whether a played run's loop should show a bar of its steps (inside :func:`counting_steps`)."""
    return _STEP_BARS.get()


@contextlib.contextmanager
def counting_steps(on: bool = True):
    """Within the block, :func:`step_bars` is ``on`` (the previous setting is restored after)."""
    token = _STEP_BARS.set(bool(on))
    try:
        yield
    finally:
        _STEP_BARS.reset(token)
