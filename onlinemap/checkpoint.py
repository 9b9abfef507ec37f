"""Checkpoints: save an estimator, load it in another process, continue bit for bit.

Generic over every registered estimator, with no per-estimator code: the state is the
estimator's instance attributes (``vars(est)``), serialised by type.

========================================  =============================================
attribute value                           stored as
========================================  =============================================
``numpy.ndarray`` (numeric, bool, str)    an array in the npz (dtype, shape, C/Fortran order and
                                          read-only flag kept)
``None``, bool, int, float, str           JSON (floats exactly, NaN and infinities included)
numpy scalar                              a 0-d array (dtype kept)
tuple, list, dict with str keys           JSON containers of the above
``numpy.random.Generator``                its ``bit_generator.state`` (PCG64, MT19937, ...)
:class:`~onlinemap.belief.Belief`         its fields
:class:`~onlinemap.model.GridModel`       its tables, rebuilt through the validating constructor
a registered state class (a dataclass,     its fields, by these same rules (e.g. the RBPF's
:func:`state_class`)                      :class:`~onlinemap.estimators.block_pool.BlockPool`)
``numpy.dtype`` or numpy scalar type      its name
function / numba dispatcher / own method  its name only: configuration, re-derived from the options
                                          on construction and checked to be the same on load
anything else                             refused: :class:`CheckpointError` naming the attribute
========================================  =============================================

A class may name buffers whose contents are dead between steps (fully overwritten before being
read) in a class attribute ``scratch_attributes = ("_buffer", ...)``: their dtype and shape are
recorded and checked, their contents are neither saved nor restored (the fresh instance's own
buffers are kept), so they cost nothing in a checkpoint and do not count as state when
comparing two state dicts; a checkpoint written before the class had one of them still loads.
Two attributes holding the same array stay one array after loading; two different writable
arrays sharing memory (views) are refused, since loading could not keep them linked.
``est.model`` and ``est.options`` (the keyword options it was built with, recorded by
:func:`~onlinemap.estimators.register`) are stored apart and checked on load.

File format (``save``/``load``): an uncompressed ``.npz``: ``meta`` (UTF-8 JSON as uint8:
format name and version, onlinemap version, estimator name, options, t, model and attribute
tree with arrays replaced by keys ``a0, a1, ...``), ``sha256`` (hex digest of ``meta`` and every
array's bytes) and the arrays. :func:`read` parses it itself: regular files only, no
compressed or encrypted entries, every npy header's declared size equal to its entry's before
anything is allocated, metadata nested at most 64 deep. Nothing in a file is ever executed: no
pickle, JSON only, whitelisted numpy bit generators, the model re-validated. The checksum
catches truncation, corruption and hand edits; it is not a signature (whoever can write the
file can recompute it), so :func:`load_state_dict` also checks the restored state against the
estimator's invariants (:mod:`onlinemap.state_checks`): no file can make a kernel index outside
its arrays. Compatibility: :data:`FORMAT_VERSION` (see :func:`check_header`). Files are written
atomically (temp file in the same directory, fsync, ``os.replace``, through symlinks, the mode
kept): a crash mid-write leaves the previous file intact.

Note: ``bit_generator.state`` does not include the generator's seed sequence, so after loading,
``Generator.spawn`` gives different children; draws from the generator itself continue exactly.

Cost: one copy of every array of the state (O(state size)) for ``state_dict``, and a write or
read of it plus one SHA-256 pass for ``save``/``load``.
"""

from __future__ import annotations

import dataclasses
import hashlib
import inspect
import json
import os
import stat
import tempfile
import tokenize
import types
import zipfile
from pathlib import Path

import numpy as np

from .atomic import atomic_write, file_mode
from .belief import Belief
from .errors import CheckpointError, OnlineMapError
from .model import DEFINING_FIELDS, OPTIONAL_FIELDS, GridModel, model_difference

FORMAT = "onlinemap-checkpoint"
FORMAT_VERSION = 2  # bump when the file layout or an estimator's state changes incompatibly
OLDEST_FORMAT_VERSION = 1  # the oldest format this code still reads
# version 2: the RBPF's block pool is one attribute (``_blocks``, a BlockPool); version 1 files
# are read through RaoBlackwellisedPF.upgrade_attributes.
_TAG = "$"
_SEPARATE = ("model", "options")  # attributes stored apart from the state tree
_ARRAY_KINDS = "biufcUSmM"  # numpy dtype kinds that npy stores without pickling
_BIT_GENERATORS = ("PCG64", "PCG64DXSM", "MT19937", "Philox", "SFC64")
_ZIP_MAGIC = b"PK\x03\x04"


def _package_version() -> str:
    from . import __version__

    return __version__


#: dataclasses stored field by field: qualified name -> class (see :func:`state_class`)
STATE_CLASSES: dict[str, type] = {}


def state_class(cls: type) -> type:
    """Class decorator: checkpoints store instances of the dataclass ``cls`` field by field (each
    field by the rules of the module docstring) and rebuild them with ``cls(**fields)``; the
    estimator's state checks then validate them. Nothing else about the class is trusted."""
    if not dataclasses.is_dataclass(cls):
        raise TypeError(f"state_class needs a dataclass, got {cls!r}")
    STATE_CLASSES[cls.__qualname__] = cls
    return cls


def state_node(cls: type, fields: dict) -> dict:
    """The encoded-tree node of a :func:`state_class` instance from its fields' nodes (for
    ``upgrade_attributes``)."""
    return {_TAG: "object", "class": cls.__qualname__, "fields": fields}


# --- encoding: Python objects -> tree (JSON values, raw ndarrays, tagged dicts) ----------------------
class _Encoder:
    """Turns attribute values into a tree; remembers arrays to keep aliases and refuse views."""

    def __init__(self) -> None:
        self._arrays: list[tuple[np.ndarray, str]] = []

    def encode(self, value, path: str):
        kind = type(value)
        if value is None or kind in (bool, int, float, str):
            return value
        if kind is np.ndarray:
            return self._array(value, path)
        if isinstance(value, np.generic):
            return {_TAG: "numpy_scalar", "array": self._array(np.asarray(value), path)}
        if kind is list:
            return [self.encode(v, f"{path}[{i}]") for i, v in enumerate(value)]
        if kind is tuple:
            return {_TAG: "tuple", "items": [self.encode(v, f"{path}[{i}]") for i, v in enumerate(value)]}
        if kind is dict:
            bad = [k for k in value if type(k) is not str]
            if bad:
                raise CheckpointError(f"attribute {path}: dict keys must be str, got {bad[0]!r}")
            return {_TAG: "dict", "items": [[k, self.encode(v, f"{path}[{k!r}]")] for k, v in value.items()]}
        if kind is np.random.Generator:
            return {_TAG: "generator", "state": self.encode(value.bit_generator.state, f"{path}.state")}
        if kind is Belief:
            return {_TAG: "belief", "fields": {f.name: self.encode(getattr(value, f.name), f"{path}.{f.name}")
                                              for f in dataclasses.fields(Belief)}}
        if kind is GridModel:
            return encode_model(value)
        if STATE_CLASSES.get(kind.__qualname__) is kind:
            return state_node(kind, {f.name: self.encode(getattr(value, f.name), f"{path}.{f.name}")
                                     for f in dataclasses.fields(value)})
        if isinstance(value, np.dtype):
            return {_TAG: "dtype", "name": value.str}
        if isinstance(value, type) and issubclass(value, np.generic):
            return {_TAG: "scalar_type", "name": np.dtype(value).str}
        name = _callable_name(value)
        if name is not None:
            return {_TAG: "callable", "name": name}
        raise CheckpointError(
            f"attribute {path}: cannot checkpoint a {kind.__module__}.{kind.__qualname__}; supported: numpy "
            f"arrays and scalars, None/bool/int/float/str, tuples, lists, str-keyed dicts, numpy Generators, "
            f"Belief, GridModel, functions (see onlinemap.checkpoint)")

    def _array(self, array: np.ndarray, path: str):
        if array.dtype.kind not in _ARRAY_KINDS or array.dtype.fields is not None:
            raise CheckpointError(f"attribute {path}: arrays of dtype {array.dtype} cannot be stored without pickle")
        for seen, seen_path in self._arrays:
            if seen is array:
                return {_TAG: "same_as", "path": seen_path}
            if array.flags.writeable and seen.flags.writeable and np.may_share_memory(array, seen):
                raise CheckpointError(f"attributes {seen_path} and {path} are writable views of the same memory; "
                                      "a checkpoint cannot keep them linked")
        self._arrays.append((array, path))
        copy = array.copy(order="K")  # keeps C or Fortran order: numpy sums in memory order
        copy.setflags(write=array.flags.writeable)
        return copy


def _scratch_node(value, name: str) -> dict:
    if type(value) is not np.ndarray:
        raise CheckpointError(f"attribute {name}: scratch_attributes must be arrays, got {type(value).__name__}")
    return {_TAG: "scratch", "dtype": value.dtype.str, "shape": list(value.shape)}


def _callable_name(value) -> str | None:
    """``module.qualname`` of a named function (plain, builtin, numpy, numba dispatcher); the name
    of a method bound to an object (``self.method``); None for anything else (instances with
    ``__call__`` and ``functools.partial`` carry state, so they are not accepted)."""
    if isinstance(value, types.MethodType):
        return f"method {type(value.__self__).__qualname__}.{value.__func__.__name__}"
    if isinstance(value, np.ufunc):
        return f"numpy.{value.__name__}"
    if callable(value) and not isinstance(value, type) and isinstance(getattr(value, "__qualname__", None), str):
        return f"{getattr(value, '__module__', None)}.{value.__qualname__}"
    return None


def encode_model(model: GridModel) -> dict:
    """Tree of a model's defining tables (the derived ones are rebuilt by the constructor)."""
    encoder = _Encoder()
    return {_TAG: "model", "fields": {name: encoder.encode(getattr(model, name), name) for name in DEFINING_FIELDS}}


# --- decoding: tree -> fresh Python objects (arrays copied) ------------------------------------------
class _KeepFresh:
    """A function attribute (configuration the fresh instance re-derives; its name is checked) or a
    scratch buffer (its dtype and shape are checked)."""

    def __init__(self, name: str, dtype: str | None = None, shape: list | None = None) -> None:
        self.name, self.dtype, self.shape = name, dtype, shape


class _Decoder:
    def __init__(self) -> None:
        self._arrays: dict[str, np.ndarray] = {}

    def decode(self, node, path: str):
        if node is None or type(node) in (bool, int, float, str):
            return node
        if type(node) is np.ndarray:
            array = node.copy(order="K")
            array.setflags(write=node.flags.writeable)
            self._arrays[path] = array
            return array
        if type(node) is list:
            return [self.decode(v, f"{path}[{i}]") for i, v in enumerate(node)]
        if type(node) is not dict or not isinstance(node.get(_TAG), str):
            raise CheckpointError(f"attribute {path}: malformed checkpoint entry {_short(node)}")
        tag = node[_TAG]
        try:
            if tag == "tuple":
                return tuple(self.decode(v, f"{path}[{i}]") for i, v in enumerate(node["items"]))
            if tag == "dict":
                return {str(k): self.decode(v, f"{path}[{k!r}]") for k, v in node["items"]}
            if tag == "numpy_scalar":
                return self.decode(node["array"], path)[()]
            if tag == "same_as":
                return self._arrays[node["path"]]
            if tag == "generator":
                return _generator(self.decode(node["state"], f"{path}.state"))
            if tag == "belief":
                return Belief(**{k: self.decode(v, f"{path}.{k}") for k, v in node["fields"].items()})
            if tag == "model":
                return decode_model(node)
            if tag == "object":
                return self._object(node, path)
            if tag == "dtype":
                return _dtype(node["name"])
            if tag == "scalar_type":
                return _dtype(node["name"]).type
            if tag == "callable":
                return _KeepFresh(str(node["name"]))
            if tag == "scratch":
                return _KeepFresh("scratch", str(node["dtype"]), list(node["shape"]))
        except CheckpointError:
            raise
        except (KeyError, TypeError, ValueError, AttributeError, OverflowError, IndexError) as error:
            raise CheckpointError(f"attribute {path}: malformed {tag!r} entry: {_short(str(error))}") from None
        raise CheckpointError(f"attribute {path}: unknown entry type {tag!r}")


    def _object(self, node: dict, path: str):
        cls = STATE_CLASSES.get(node["class"]) if isinstance(node["class"], str) else None
        if cls is None:
            raise CheckpointError(f"attribute {path}: unknown state class {_short(node['class'])}")
        names = [f.name for f in dataclasses.fields(cls)]
        given = node["fields"]
        if type(given) is not dict or sorted(given) != sorted(names):
            raise CheckpointError(f"attribute {path}: a {cls.__name__} needs the fields {names}")
        fields = {name: self.decode(given[name], f"{path}.{name}") for name in names}
        if any(isinstance(value, _KeepFresh) for value in fields.values()):
            raise CheckpointError(f"attribute {path}: a {cls.__name__} holds only values, not functions")
        return cls(**fields)


def _short(node) -> str:
    text = node if isinstance(node, str) else repr(node)
    return text if len(text) <= 80 else text[:77] + "..."


def _dtype(name: str) -> np.dtype:
    dtype = np.dtype(str(name))
    if dtype.kind not in _ARRAY_KINDS:
        raise CheckpointError(f"dtype {name!r} is not allowed in a checkpoint")
    return dtype


def _generator(state: dict) -> np.random.Generator:
    name = state.get("bit_generator") if isinstance(state, dict) else None
    if name not in _BIT_GENERATORS:
        raise CheckpointError(f"unknown bit generator {name!r}; allowed: {', '.join(_BIT_GENERATORS)}")
    bit_generator = getattr(np.random, name)()
    bit_generator.state = state
    return np.random.Generator(bit_generator)


def decode_model(node) -> GridModel:
    """Rebuild a :class:`GridModel` from :func:`encode_model`'s tree (validated by its constructor)."""
    names = set(node.get("fields", ())) if type(node) is dict else set()
    if type(node) is not dict or node.get(_TAG) != "model" or not set(DEFINING_FIELDS) - set(OPTIONAL_FIELDS) <= names <= set(DEFINING_FIELDS):
        raise CheckpointError("the checkpoint's model entry is malformed")
    fields = {name: _Decoder().decode(value, name) for name, value in node["fields"].items()}
    try:
        return GridModel(**fields)
    except (OnlineMapError, TypeError, ValueError) as error:
        raise CheckpointError(f"the checkpoint's model is invalid: {error}") from None


def decode_options(node) -> dict:
    """The estimator options stored by :func:`state_dict` (a dict of plain values)."""
    options = _Decoder().decode(node, "options")
    if type(options) is not dict:
        raise CheckpointError("malformed options entry")
    return options


# --- state_dict / load_state_dict ---------------------------------------------------------------------
def state_dict(est) -> dict:
    """Everything needed to continue ``est`` bit for bit, as a tree of JSON values and array copies:
    ``format``, ``format_version``, ``onlinemap_version``, ``estimator``, ``t``, ``options``,
    ``model`` and ``attributes`` (one entry per instance attribute). Later steps of ``est`` do not
    change it. Cost: one copy of every array."""
    options = getattr(est, "options", None)
    if not isinstance(options, dict):
        raise CheckpointError(f"{type(est).__name__} has no recorded options: build estimators with "
                              "om.make_estimator or a class decorated with om.register")
    if not isinstance(est.model, GridModel):
        raise CheckpointError(f"{type(est).__name__}.model is not a GridModel")
    encoder = _Encoder()
    scratch = set(getattr(type(est), "scratch_attributes", ()))
    attributes = {name: _scratch_node(value, name) if name in scratch else encoder.encode(value, name)
                  for name, value in vars(est).items() if name not in _SEPARATE}
    return {"format": FORMAT, "format_version": FORMAT_VERSION, "onlinemap_version": _package_version(),
            "estimator": est.name, "t": int(est.t), "options": _Encoder().encode(dict(options), "options"),
            "model": encode_model(est.model), "attributes": attributes}


def check_header(state: dict, *, strict_version: bool = False, allow_newer: bool = False) -> None:
    """Refuse a state of another format, of a format version this onlinemap cannot read (older
    than :data:`OLDEST_FORMAT_VERSION`, or newer than :data:`FORMAT_VERSION` unless
    ``allow_newer``) or, with ``strict_version``, written by another onlinemap version.

    Compatibility rests on the format version, not the package version: a patch or minor
    release that keeps the format reads its predecessors' checkpoints."""
    if not isinstance(state, dict) or state.get("format") != FORMAT:
        raise CheckpointError("not an onlinemap checkpoint (missing format marker)")
    version = state.get("format_version")
    if type(version) is not int or version < OLDEST_FORMAT_VERSION:
        raise CheckpointError(f"checkpoint format version {_short(repr(version))}; this onlinemap "
                              f"({_package_version()}) reads versions {OLDEST_FORMAT_VERSION} to {FORMAT_VERSION}")
    if version > FORMAT_VERSION and not allow_newer:
        raise CheckpointError(f"checkpoint format version {version} was written by a newer onlinemap "
                              f"({_short(repr(state.get('onlinemap_version')))}); this one ({_package_version()}) reads "
                              f"up to version {FORMAT_VERSION}: upgrade onlinemap, or pass allow_newer=True "
                              "(track: --allow-newer-checkpoint) to try anyway")
    if strict_version and state.get("onlinemap_version") != _package_version():
        raise CheckpointError(f"checkpoint written by onlinemap {_short(repr(state.get('onlinemap_version')))}, this is "
                              f"{_package_version()}, and strict_version=True asks for the same version")
    for key in ("estimator", "t", "options", "model", "attributes"):
        if key not in state:
            raise CheckpointError(f"checkpoint has no {key!r} entry")


def load_state_dict(est, state: dict, *, strict_version: bool = False, allow_newer: bool = False) -> None:
    """Restore ``est`` from :func:`state_dict`'s output. Checks the format version (see
    :func:`check_header`), the estimator name, the model (bitwise), the options and the attribute
    names and kinds, then the restored state's invariants (see :mod:`onlinemap.state_checks`);
    refuses with :class:`CheckpointError` and leaves ``est`` untouched on any mismatch. An older
    format version's attributes first go through the class's ``upgrade_attributes(attributes,
    version)`` if it has one (it rewrites the encoded tree; :func:`state_node` builds the node of
    a :func:`state_class` instance)."""
    check_header(state, strict_version=strict_version, allow_newer=allow_newer)
    if state["estimator"] != est.name:
        raise CheckpointError(f"checkpoint is for estimator {state['estimator']!r}, not {est.name!r}")
    field = model_difference(decode_model(state["model"]), est.model)
    if field is not None:
        raise CheckpointError(f"checkpoint's model differs from the estimator's model in {field!r}")
    if not same_tree(_with_later_options(state["options"], est), _Encoder().encode(dict(getattr(est, "options", {})),
                                                                                "options")):
        options = _Decoder().decode(state["options"], "options")
        raise CheckpointError(f"checkpoint was written with options {options}, the estimator has {est.options}")
    if type(state["attributes"]) is not dict:
        raise CheckpointError("checkpoint's attributes entry is malformed")
    upgrade = getattr(type(est), "upgrade_attributes", None)
    if upgrade is not None and state["format_version"] < FORMAT_VERSION:
        state = {**state, "attributes": upgrade(dict(state["attributes"]), state["format_version"])}
    current = {name: value for name, value in vars(est).items() if name not in _SEPARATE}
    scratch = set(getattr(type(est), "scratch_attributes", ()))  # not state: a checkpoint may predate one
    missing = sorted(set(current) - set(state["attributes"]) - scratch)
    extra = sorted(set(state["attributes"]) - set(current))
    if missing or extra:
        raise CheckpointError(f"checkpoint does not fit {type(est).__name__}: missing attributes {missing}, "
                              f"unexpected {extra}")
    decoder = _Decoder()
    restored = {}
    try:
        for name, node in state["attributes"].items():
            value = decoder.decode(node, name)
            _check_kind(name, current[name], value)
            if not isinstance(value, _KeepFresh):
                restored[name] = value
    except RecursionError:
        raise CheckpointError("checkpoint's attributes are nested too deeply") from None
    check_state(est, restored)
    vars(est).update(restored)


def _with_later_options(node, est):
    """The encoded options of a checkpoint, with every keyword option of ``est``'s class that it
    does not name (one added after it was written) at its default: a checkpoint predating an
    option loads into an estimator that has it at its default, and only there."""
    options = decode_options(node)
    defaults = {p.name: p.default for p in inspect.signature(type(est).__init__).parameters.values()
                if p.kind is inspect.Parameter.KEYWORD_ONLY and p.default is not inspect.Parameter.empty}
    return _Encoder().encode({**options, **{k: v for k, v in defaults.items() if k not in options}}, "options")


def check_state(est, restored: dict) -> None:
    """Check the attributes ``restored`` (name -> value) as ``est``'s new state, without changing
    ``est``: the attributes fixed by the model and options equal ``est``'s own, bit for bit, and
    the rest satisfy the estimator's invariants (:mod:`onlinemap.state_checks`; a class may
    define its own ``check_state(view)``). Raises :class:`CheckpointError`."""
    from . import state_checks

    for name in state_checks.CONSTANT.get(est.name, ()):  # "attribute" or "attribute.field"
        head, _, field = name.partition(".")
        if head not in restored:
            continue
        mine, theirs = vars(est)[head], restored[head]
        if field:
            mine, theirs = getattr(mine, field), getattr(theirs, field)
        if not same_tree(_Encoder().encode(theirs, name), _Encoder().encode(mine, name)):
            raise CheckpointError(f"invalid state: attribute {name} differs from what the model and options give")
    check = getattr(type(est), "check_state", None) or state_checks.STATE_CHECKS.get(est.name)
    if check is not None:
        check(types.SimpleNamespace(**{**vars(est), **restored}))


def _kind(value) -> str:
    if isinstance(value, np.ndarray):
        return f"array of {value.dtype} with {value.ndim} dimensions"
    if isinstance(value, (bool, np.bool_)):
        return "bool"
    if isinstance(value, (int, float, np.integer, np.floating)):
        return "number"
    return type(value).__name__


def _check_kind(name: str, current, value) -> None:
    if isinstance(value, _KeepFresh) and value.dtype is not None:
        if type(current) is not np.ndarray or current.dtype.str != value.dtype or list(current.shape) != value.shape:
            raise CheckpointError(f"attribute {name}: checkpoint has a scratch array {value.dtype} {value.shape}, "
                                  f"the estimator a {_kind(current)} {getattr(current, 'shape', '')}")
        return
    if isinstance(value, _KeepFresh):
        if _callable_name(current) != value.name:
            raise CheckpointError(f"attribute {name}: checkpoint has {value.name}, the estimator has "
                                  f"{_callable_name(current) or _kind(current)}")
        return
    if current is None or value is None:
        return
    if _kind(current) != _kind(value):
        raise CheckpointError(f"attribute {name}: checkpoint holds a {_kind(value)}, the estimator a {_kind(current)}")
    if type(current) is np.ndarray and current.flags.c_contiguous and not value.flags.c_contiguous:
        raise CheckpointError(f"attribute {name}: the estimator's array is C-contiguous, the checkpoint's is not")


def same_tree(a, b) -> bool:
    """Bitwise equality of two state trees (e.g. two :func:`state_dict` outputs): same structure,
    same types, arrays of the same dtype, shape and bytes, floats with the same bits (NaN == NaN)."""
    return first_difference(a, b) is None


def first_difference(a, b, path: str = "") -> str | None:
    """Where two state trees first differ (a path like ``attributes._rng``), or None if they are
    bitwise equal (see :func:`same_tree`)."""
    if type(a) is not type(b):
        return f"{path or 'root'} ({type(a).__name__} vs {type(b).__name__})"
    if type(a) is np.ndarray:
        same = a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()
    elif type(a) is float:
        same = np.float64(a).tobytes() == np.float64(b).tobytes()
    elif type(a) is list:
        if len(a) != len(b):
            return f"{path} (length {len(a)} vs {len(b)})"
        return next((d for i, (x, y) in enumerate(zip(a, b)) if (d := first_difference(x, y, f"{path}[{i}]"))), None)
    elif type(a) is dict:
        if a.keys() != b.keys():
            return f"{path} (keys {sorted(a.keys() ^ b.keys())})"
        return next((d for k in a if (d := first_difference(a[k], b[k], f"{path}.{k}" if path else k))), None)
    else:
        same = a == b
    return None if same else (path or "root")


# --- files -----------------------------------------------------------------------------------------
def _externalise(node, arrays: dict[str, np.ndarray]):
    """Replace every ndarray in a tree by a reference ``{"$": "ndarray", "key": ...}``."""
    if type(node) is np.ndarray:
        key = f"a{len(arrays)}"
        arrays[key] = node
        return {_TAG: "ndarray", "key": key, "dtype": node.dtype.str, "shape": list(node.shape),
                "writeable": bool(node.flags.writeable)}
    if type(node) is list:
        return [_externalise(v, arrays) for v in node]
    if type(node) is dict:
        return {k: _externalise(v, arrays) for k, v in node.items()}
    return node


def _internalise(node, arrays: dict[str, np.ndarray], used: set[str]):
    if type(node) is list:
        return [_internalise(v, arrays, used) for v in node]
    if type(node) is not dict:
        return node
    if node.get(_TAG) == "ndarray":
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
        if node.get(_TAG) == "ndarray":
            keys.append(str(node.get("key")))
        else:
            for v in node.values():
                _array_keys(v, keys)
    return keys


def _digest(meta: bytes, arrays: dict[str, np.ndarray]) -> str:
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
    meta = json.dumps(_externalise(state, arrays), separators=(",", ":")).encode()
    digest = _digest(meta, arrays).encode()
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
        fd, tmp = tempfile.mkstemp(dir=target.parent, prefix=f".{target.name}.", suffix=".tmp")
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
                                  f"{_short(str(error))}") from None
    meta_bytes, digest = contents.pop("meta", None), contents.pop("sha256", None)
    if meta_bytes is None or digest is None or meta_bytes.dtype != np.uint8 or digest.dtype != np.uint8:
        raise CheckpointError(f"{path} is not an onlinemap checkpoint (no metadata or checksum)")
    try:
        meta = json.loads(meta_bytes.tobytes().decode())
    except (UnicodeDecodeError, ValueError, RecursionError) as error:
        raise CheckpointError(f"{path}: unreadable metadata: {_short(str(error))}") from None
    if _depth(meta) > _MAX_DEPTH:
        raise CheckpointError(f"{path}: metadata nested more than {_MAX_DEPTH} levels deep")
    try:
        check_header(meta, allow_newer=True)  # the caller decides about versions (load_state_dict)
    except CheckpointError as error:
        raise CheckpointError(f"{path}: {error}") from None
    keys = _array_keys(meta, [])
    if sorted(keys) != sorted(contents):
        raise CheckpointError(f"{path}: entries {_short(sorted(contents))} do not match the metadata's "
                              f"{_short(sorted(keys))}")
    if _digest(meta_bytes.tobytes(), {key: contents[key] for key in keys}) != \
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
                raise CheckpointError(f"{path}: unexpected zip entry {_short(name)}")
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
    if dtype.kind not in _ARRAY_KINDS or dtype.fields is not None or dtype.subdtype is not None:
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
    """Checkpoint ``est`` (its ``state_dict()``) to ``path``, atomically. Returns the path."""
    return write(est.state_dict(), path)
