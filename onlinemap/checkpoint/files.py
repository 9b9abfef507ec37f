"""The checkpoint file format: a state dict (:func:`~onlinemap.checkpoint.protocol.state_dict`)
in an npz file, written atomically and read with guards.

An uncompressed ``.npz``: ``meta`` (UTF-8 JSON as uint8: format name and version, onlinemap
version, estimator name, options, t, model and attribute tree with arrays replaced by keys ``a0,
a1, ...``), ``sha256`` (hex digest of ``meta`` and every array's bytes) and the arrays.
:func:`read` parses it itself: regular files only, no compressed or encrypted entries, every npy
header's declared size equal to its entry's before anything is allocated, metadata nested at most
64 deep. Nothing in a file is ever executed: no pickle, JSON only (the tree is decoded by
:mod:`onlinemap.checkpoint.codec`). The checksum catches truncation, corruption and hand edits; it
is not a signature (whoever can write the file can recompute it), so loading also checks the
restored state against the estimator's invariants
(:func:`~onlinemap.checkpoint.protocol.load_state_dict`). Files are written atomically (temp file
in the same directory, fsync, ``os.replace``, through symlinks, the mode kept): a crash mid-write
leaves the previous file intact.

Cost: a write or read of the state plus one SHA-256 pass.
"""

from __future__ import annotations

import hashlib
import json
import os
import stat
import tokenize
import zipfile
from pathlib import Path

import numpy as np

from ..atomic import atomic_write, create_temporary, file_mode, remove_temporaries
from ..errors import CheckpointError
from .codec import ARRAY_KINDS, TAG, shortened
from .protocol import check_header

_ZIP_MAGIC = b"PK\x03\x04"


def externalise_arrays(node, arrays: dict[str, np.ndarray]):
    """Replace every ndarray in a tree by a reference ``{"$": "ndarray", "key": ...}``."""
    if type(node) is np.ndarray:
        key = f"a{len(arrays)}"
        arrays[key] = node
        return {TAG: "ndarray", "key": key, "dtype": node.dtype.str, "shape": list(node.shape),
                "writeable": bool(node.flags.writeable)}
    if type(node) is list:
        return [externalise_arrays(v, arrays) for v in node]
    if type(node) is dict:
        return {k: externalise_arrays(v, arrays) for k, v in node.items()}
    return node


def _internalise(node, arrays: dict[str, np.ndarray], used: set[str]):
    if type(node) is list:
        return [_internalise(v, arrays, used) for v in node]
    if type(node) is not dict:
        return node
    if node.get(TAG) == "ndarray":
        key = node.get("key")
        if key not in arrays or key in used:
            raise CheckpointError(f"checkpoint refers to a missing or repeated array {key!r}")
        array = arrays[key]
        if array.dtype.str != node.get("dtype") or list(array.shape) != node.get("shape"):
            raise CheckpointError(f"checkpoint array {key}: stored as {array.dtype.str} {list(array.shape)}, "
                                  f"recorded as {node.get('dtype')} {node.get('shape')} (tampered?)")
        used.add(key)
        array.setflags(write=bool(node.get("writeable", True)))
        return array
    return {k: _internalise(v, arrays, used) for k, v in node.items()}


def _array_keys(node, keys: list[str]) -> list[str]:
    """Keys of the arrays a metadata tree refers to, in order of appearance."""
    if type(node) is list:
        for v in node:
            _array_keys(v, keys)
    elif type(node) is dict:
        if node.get(TAG) == "ndarray":
            keys.append(str(node.get("key")))
        else:
            for v in node.values():
                _array_keys(v, keys)
    return keys


def checkpoint_digest(meta: bytes, arrays: dict[str, np.ndarray]) -> str:
    """SHA-256 of the metadata bytes, then every array's key and bytes, in the dict's order."""
    sha = hashlib.sha256(meta)
    for key, array in arrays.items():
        sha.update(key.encode())
        sha.update(np.ascontiguousarray(array).tobytes())
    return sha.hexdigest()


def write(state: dict, path: str | os.PathLike) -> Path:
    """Write a :func:`state_dict` to ``path`` atomically (temp file in the same directory, fsync,
    ``os.replace``); returns the path. Missing parent directories are created. A symlink is
    written through (its target is replaced, the link kept); an existing file keeps its
    permission bits, a new one gets ``0o666`` less the umask. Any OS failure (read-only
    directory, full disk, ...) raises :class:`CheckpointError` naming the file, and the previous
    file is left as it was."""
    path = Path(path)
    arrays: dict[str, np.ndarray] = {}
    meta = json.dumps(externalise_arrays(state, arrays), separators=(",", ":")).encode()
    digest = checkpoint_digest(meta, arrays).encode()
    try:
        return atomic_write(path, lambda file: np.savez(file, meta=np.frombuffer(meta, np.uint8),
                                                          sha256=np.frombuffer(digest, np.uint8), **arrays))
    except OSError as error:
        raise CheckpointError(f"cannot write checkpoint {path}: {error.strerror or error}; the previous file "
                              "(if any) is unchanged") from None


def check_writable(path: str | os.PathLike) -> None:
    """Raise :class:`CheckpointError` unless a checkpoint can be written at ``path``: its
    directory exists or can be created, a file can be created in it, and ``path`` (or what it
    links to) is a regular file or does not exist. Creates and removes one empty temp file."""
    target = Path(os.path.realpath(path))
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        file_mode(target)
        fd, tmp = create_temporary(target)
        os.close(fd)
        os.unlink(tmp)
    except OSError as error:
        raise CheckpointError(f"cannot write checkpoint {path}: {error.strerror or error}") from None


_MAX_MEMBERS = 100_000  # zip entries
_MAX_DEPTH = 64  # nesting of the metadata (the state trees nest a few levels deep)
_MAX_NPY_HEADER = 10_000  # bytes, numpy's own default limit


def read(path: str | os.PathLike) -> dict:
    """Read and verify a checkpoint file (regular file, zip structure, npy headers, format
    version, SHA-256 of metadata and arrays, recorded dtypes and shapes); returns the state tree.
    Executes nothing from the file, and allocates nothing larger than the file: every array's
    declared size is checked against its zip entry before it is read. Any defect raises
    :class:`CheckpointError` naming the file and the problem."""
    path = Path(path)
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))  # a FIFO must not block
    except OSError as error:
        raise CheckpointError(f"cannot open checkpoint {path}: {error.strerror or error}") from None
    info = os.fstat(fd)
    if not stat.S_ISREG(info.st_mode):
        os.close(fd)
        raise CheckpointError(f"{path} is not a regular file; refused")
    with os.fdopen(fd, "rb") as file:
        if file.read(4) != _ZIP_MAGIC:
            raise CheckpointError(f"{path} is not an onlinemap checkpoint (not an npz file)")
        file.seek(0)
        try:
            contents = _read_npz(file, info.st_size, path)
        except CheckpointError:
            raise
        except (zipfile.BadZipFile, zipfile.LargeZipFile, OSError, EOFError, KeyError, NotImplementedError,
                RuntimeError, ValueError, TypeError, SyntaxError, RecursionError, MemoryError,
                tokenize.TokenError) as error:
            raise CheckpointError(f"{path} is truncated or corrupt: {type(error).__name__}: "
                                  f"{shortened(str(error))}") from None
    meta_bytes, digest = contents.pop("meta", None), contents.pop("sha256", None)
    if meta_bytes is None or digest is None or meta_bytes.dtype != np.uint8 or digest.dtype != np.uint8:
        raise CheckpointError(f"{path} is not an onlinemap checkpoint (no metadata or checksum)")
    try:
        meta = json.loads(meta_bytes.tobytes().decode())
    except (UnicodeDecodeError, ValueError, RecursionError) as error:
        raise CheckpointError(f"{path}: unreadable metadata: {shortened(str(error))}") from None
    if _depth(meta) > _MAX_DEPTH:
        raise CheckpointError(f"{path}: metadata nested more than {_MAX_DEPTH} levels deep")
    try:
        check_header(meta, allow_newer=True)  # the caller decides about versions (load_state_dict)
    except CheckpointError as error:
        raise CheckpointError(f"{path}: {error}") from None
    keys = _array_keys(meta, [])
    if sorted(keys) != sorted(contents):
        raise CheckpointError(f"{path}: entries {shortened(sorted(contents))} do not match the metadata's "
                              f"{shortened(sorted(keys))}")
    if checkpoint_digest(meta_bytes.tobytes(), {key: contents[key] for key in keys}) != \
            digest.tobytes().decode(errors="replace"):
        raise CheckpointError(f"{path}: checksum mismatch: the file was modified or damaged")
    return _internalise(meta, contents, set())


def _read_npz(file, file_size: int, path: Path) -> dict[str, np.ndarray]:
    """The arrays of an uncompressed, unencrypted npz, each entry's npy header checked (no
    pickled objects, declared size equal to the entry's size) before its data is read."""
    contents: dict[str, np.ndarray] = {}
    with zipfile.ZipFile(file) as archive:
        members = archive.infolist()
        if len(members) > _MAX_MEMBERS:
            raise CheckpointError(f"{path}: {len(members)} zip entries; refused")
        for info in members:
            name = info.filename
            if info.compress_type != zipfile.ZIP_STORED:
                raise CheckpointError(f"{path}: compressed entries ({name!r}); onlinemap writes them uncompressed")
            if info.flag_bits & 0x1:
                raise CheckpointError(f"{path}: entry {name!r} is marked encrypted; refused")
            if not name.endswith(".npy") or name[:-4] in contents or not name[:-4].isidentifier():
                raise CheckpointError(f"{path}: unexpected zip entry {shortened(name)}")
            if info.file_size > file_size:
                raise CheckpointError(f"{path}: entry {name!r} claims {info.file_size} bytes, more than the "
                                      f"file's {file_size}")
            with archive.open(info) as member:
                contents[name[:-4]] = _read_npy(member, info.file_size, f"{path}: entry {name!r}")
    return contents


def _read_npy(member, size: int, where: str) -> np.ndarray:
    """One npy entry of ``size`` bytes; its header's shape and dtype must account for exactly
    the bytes that follow it."""
    fmt = np.lib.format
    version = fmt.read_magic(member)
    if version == (1, 0):
        shape, fortran, dtype = fmt.read_array_header_1_0(member, max_header_size=_MAX_NPY_HEADER)
    elif version in ((2, 0), (3, 0)):
        shape, fortran, dtype = fmt.read_array_header_2_0(member, max_header_size=_MAX_NPY_HEADER)
    else:
        raise CheckpointError(f"{where}: npy format version {version}")
    if dtype.hasobject:
        raise CheckpointError(f"{where} contains a pickled object; refused (nothing was loaded or run)")
    if dtype.kind not in ARRAY_KINDS or dtype.fields is not None or dtype.subdtype is not None:
        raise CheckpointError(f"{where}: dtype {dtype} is not allowed in a checkpoint")
    count = 1
    for extent in shape:
        count *= extent
    need = count * dtype.itemsize
    header = member.tell()
    if need != size - header:
        raise CheckpointError(f"{where}: header declares {shape} {dtype} ({need} bytes), the entry holds "
                              f"{size - header}")
    data = bytearray(need)
    if member.readinto(data) != need or member.read(1):
        raise CheckpointError(f"{where} is truncated")
    return np.frombuffer(data, dtype=dtype).reshape(shape, order="F" if fortran else "C")


def _depth(node) -> int:
    """Nesting depth of a JSON tree, without recursion (a crafted file may nest thousands deep)."""
    deepest, stack = 0, [(node, 1)]
    while stack:
        node, level = stack.pop()
        deepest = max(deepest, level)
        if deepest > _MAX_DEPTH:
            break
        if type(node) is list:
            stack.extend((v, level + 1) for v in node)
        elif type(node) is dict:
            stack.extend((v, level + 1) for v in node.values())
    return deepest


def save(est, path: str | os.PathLike) -> Path:
    """Checkpoint ``est`` (its ``state_dict()``) to ``path``, atomically, first removing the
    temporaries of earlier saves to ``path`` whose process was killed mid-write
    (:func:`~onlinemap.atomic.remove_temporaries`). Returns the path. Anything but an estimator
    raises :class:`CheckpointError` naming it."""
    if not callable(getattr(est, "state_dict", None)):
        raise CheckpointError(f"save checkpoints an estimator (om.make_estimator(...)), not a "
                              f"{type(est).__name__}")
    target = Path(os.path.realpath(path))  # a symlink's temporaries are beside its target
    remove_temporaries(target.parent, target.name)
    return write(est.state_dict(), path)
