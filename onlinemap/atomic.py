"""One atomic file writer: a reader (or a crash) sees the old file or the new one, never half.

:func:`atomic_write` writes to a temporary file in the target's directory (named
``.NAME.<random>.tmp``), flushes and fsyncs it, renames it over the target (``os.replace``,
atomic on POSIX and Windows) and fsyncs the directory so the rename survives a power cut. On any
failure (disk full, an exception in the writer, Ctrl-C) the temporary file is removed and the
previous file is left untouched. :func:`remove_temporaries` clears leftovers of a process that
was killed mid-write (call it when a directory of results is opened again).

A symlink is written through (its target is replaced, the link kept); an existing file keeps its
permission bits, a new one gets ``0o666`` less the umask; a target that exists but is not a
regular file is refused. Used by the result tables (:mod:`onlinemap.tables`), the sweep part store
and checkpoints (:mod:`onlinemap.checkpoint`). Cost: one extra fsync of the file and one of its
directory per write.
"""

from __future__ import annotations

import glob
import os
import stat
import tempfile
from pathlib import Path
from typing import BinaryIO, Callable

TEMPORARY_SUFFIX = ".tmp"


def file_mode(target: Path) -> int:
    """Permission bits for ``target``: those of the file it replaces, or 0o666 less the process
    umask for a new one (mkstemp makes 0o600 files). A target that exists but is not a regular
    file raises ``IsADirectoryError`` / ``OSError``."""
    try:
        info = os.stat(target)
    except FileNotFoundError:
        mask = os.umask(0o022)
        os.umask(mask)
        return 0o666 & ~mask
    if not stat.S_ISREG(info.st_mode):
        raise OSError(f"{target} exists and is not a regular file")
    return stat.S_IMODE(info.st_mode)


def atomic_write(path: str | os.PathLike, write: Callable[[BinaryIO], None]) -> Path:
    """Call ``write(file)`` on a temporary binary file beside ``path`` (beside a symlink's target),
    then fsync it and rename it over the target (creating missing parent directories). Returns
    ``path``. OS errors propagate (the previous file is untouched, the temporary removed)."""
    path = Path(path)
    target = Path(os.path.realpath(path))
    target.parent.mkdir(parents=True, exist_ok=True)
    mode = file_mode(target)
    fd, temporary = tempfile.mkstemp(dir=target.parent, prefix=f".{target.name}.", suffix=TEMPORARY_SUFFIX)
    try:
        with os.fdopen(fd, "wb") as file:
            os.fchmod(file.fileno(), mode)
            write(file)
            file.flush()
            os.fsync(file.fileno())
        os.replace(temporary, target)
    except BaseException:
        if os.path.exists(temporary):
            os.unlink(temporary)
        raise
    fsync_directory(target.parent)
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


def remove_temporaries(directory: str | os.PathLike, name: str | None = None) -> int:
    """Delete the temporary files :func:`atomic_write` left in ``directory`` (a killed process's);
    returns how many. Only names ``.*.tmp`` are touched, and with ``name`` only the temporaries
    of that file (``.NAME.*.tmp``: another process may be writing its own file beside it)."""
    directory = Path(directory)
    removed = 0
    if directory.is_dir():
        pattern = f".{glob.escape(name)}.*" if name is not None else ".*"
        for leftover in directory.glob(pattern + TEMPORARY_SUFFIX):
            try:
                leftover.unlink()
                removed += 1
            except OSError:
                pass
    return removed
