"""One atomic file writer: a reader (or a crash) sees the old file or the new one, never half.

:func:`atomic_write` writes to a temporary file in the target's directory (named
``.NAME.<random>.tmp``), flushes and fsyncs it, renames it over the target (``os.replace``,
atomic on POSIX and Windows) and fsyncs the directory so the rename survives a power cut. On any
failure (disk full, an exception in the writer, Ctrl-C) the temporary file is removed and the
previous file is left untouched. :func:`remove_temporaries` clears leftovers of a process that
was killed mid-write (call it when a directory of results is opened again).

Used by the result tables (:mod:`onlinemap.tables`) and the sweep part store; checkpoints keep
the same guarantees. Cost: one extra fsync of the file and one of its directory per write.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import BinaryIO, Callable

TEMPORARY_SUFFIX = ".tmp"


def _file_mode() -> int:
    """0o666 less the process umask (mkstemp makes 0o600 files; a table should be readable)."""
    mask = os.umask(0)
    os.umask(mask)
    return 0o666 & ~mask


def atomic_write(path: str | os.PathLike, write: Callable[[BinaryIO], None]) -> Path:
    """Call ``write(file)`` on a temporary binary file beside ``path``, then fsync it and rename
    it to ``path`` (creating missing parent directories). Returns ``path``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, temporary = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=TEMPORARY_SUFFIX)
    try:
        with os.fdopen(fd, "wb") as file:
            write(file)
            file.flush()
            os.fchmod(file.fileno(), _file_mode())
            os.fsync(file.fileno())
        os.replace(temporary, path)
    except BaseException:
        if os.path.exists(temporary):
            os.unlink(temporary)
        raise
    fsync_directory(path.parent)
    return path


def fsync_directory(directory: str | os.PathLike) -> None:
    """Make a rename in ``directory`` durable (POSIX); a no-op where directories cannot be opened."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def remove_temporaries(directory: str | os.PathLike) -> int:
    """Delete the temporary files :func:`atomic_write` left in ``directory`` (a killed process's);
    returns how many. Only names ``.*.tmp`` are touched."""
    directory = Path(directory)
    removed = 0
    if directory.is_dir():
        for leftover in directory.glob(f".*{TEMPORARY_SUFFIX}"):
            try:
                leftover.unlink()
                removed += 1
            except OSError:
                pass
    return removed
