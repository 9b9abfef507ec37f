"""One atomic file writer: a reader (or a crash) sees the old file or the new one, never half.

:func:`atomic_write` writes to a temporary file in the target's directory (named
``.NAME.<pid>-<8 hex digits>.tmp``: :func:`create_temporary`), flushes and fsyncs it, renames it over the target (``os.replace``,
atomic on POSIX and Windows) and fsyncs the directory so the rename survives a power cut. On any
failure (disk full, an exception in the writer, Ctrl-C) the temporary file is removed and the
previous file is left untouched. :func:`remove_temporaries` clears leftovers of a process that
was killed mid-write (call it when a directory of results is opened again): exactly the names
:func:`create_temporary` makes, of processes that are gone, nothing else (a user's
``.NAME.notes.tmp``, another file's temporaries, a live writer's).

A symlink is written through (its target is replaced, the link kept); an existing file keeps its
permission bits, a new one gets ``0o666`` less the umask; a target that exists but is not a
regular file is refused. Used by the result tables (:mod:`onlinemap.tables`), the sweep part store
and checkpoints (:mod:`onlinemap.checkpoint`). Cost: one extra fsync of the file and one of its
directory per write.
"""

from __future__ import annotations

import os
import re
import secrets
import stat
from pathlib import Path
from typing import BinaryIO, Callable

TEMPORARY_SUFFIX = ".tmp"
_TOKEN_BYTES = 4  # the random part of a temporary's name: 8 hex digits


def file_mode(target: Path) -> int:
    """Permission bits for ``target``: those of the file it replaces, or 0o666 less the process
    umask for a new one (temporaries are made 0o600). A target that exists but is not a regular
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
    fd, temporary = create_temporary(target)
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


def create_temporary(target: Path) -> tuple[int, str]:
    """A new empty file ``.NAME.<pid>-<8 hex digits>.tmp`` beside ``target`` (its name NAME, this
    process's id), created exclusively with mode 0o600 (as ``tempfile.mkstemp``, whose names
    :func:`remove_temporaries` could not tell from a user's); returns ``(fd, path)``."""
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_BINARY", 0)
    while True:  # a clash of 32 random bits with a file of the same process: try again
        path = target.parent / f".{target.name}.{os.getpid()}-{secrets.token_hex(_TOKEN_BYTES)}{TEMPORARY_SUFFIX}"
        try:
            return os.open(path, flags, 0o600), str(path)
        except FileExistsError:
            continue


def _writer_gone(pid: int) -> bool:
    """Whether process ``pid`` (the writer of a temporary) has ended. Only POSIX can tell without
    harm (``kill(pid, 0)`` sends nothing); elsewhere every writer but this process counts as gone."""
    if pid == os.getpid():
        return False
    if os.name != "posix":
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    except OSError:  # alive, another user's
        return False
    return False


def remove_temporaries(directory: str | os.PathLike, name: str | None = None) -> int:
    """Delete the temporary files :func:`atomic_write` left in ``directory`` (a killed process's);
    returns how many. Only regular files named exactly as :func:`create_temporary` names them,
    ``.NAME.<pid>-<8 hex digits>.tmp``, whose process has ended, are touched; with ``name`` only
    the temporaries of that file (another process may be writing its own file beside it). O(files
    in the directory)."""
    name_part = ".+" if name is None else re.escape(name)
    pattern = re.compile(rf"\.{name_part}\.(\d+)-[0-9a-f]{{{2 * _TOKEN_BYTES}}}{re.escape(TEMPORARY_SUFFIX)}")
    removed = 0
    try:
        entries = list(os.scandir(directory))
    except OSError:  # gone, or not a directory
        return 0
    for entry in entries:
        match = pattern.fullmatch(entry.name)
        try:
            if match and entry.is_file(follow_symlinks=False) and _writer_gone(int(match.group(1))):
                os.unlink(entry.path)
                removed += 1
        except OSError:
            pass
    return removed
