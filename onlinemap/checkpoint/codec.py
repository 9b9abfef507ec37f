"""The checkpoint codec: an estimator's attribute values <-> a state tree of JSON values, raw
ndarrays and tagged dicts (``{"$": "tuple", ...}``), serialised by type.

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

Two attributes holding the same array stay one array after decoding; two different writable
arrays sharing memory (views) are refused, since loading could not keep them linked. Scratch
buffers (a class's ``scratch_attributes``) are encoded as their dtype and shape only. Decoding
copies every array, rebuilds the model through its validating constructor, accepts only the
whitelisted numpy bit generators and the classes registered with :func:`state_class` (the
registry, :data:`STATE_CLASSES`), and executes nothing.

Note: ``bit_generator.state`` does not include the generator's seed sequence, so after loading,
``Generator.spawn`` gives different children; draws from the generator itself continue exactly.

Owns the tree format (tags, :func:`same_tree`, :func:`first_difference`); knows nothing of
estimators or files. Cost: one copy of every array encoded or decoded.
"""

from __future__ import annotations

import dataclasses
import types

import numpy as np

from ..belief import Belief
from ..errors import CheckpointError, OnlineMapError
from ..model import DEFINING_FIELDS, OMITTED_AT_DEFAULT, OPTIONAL_FIELDS, GridModel

TAG = "$"  # the key of a tagged node (a tuple, a Generator, an array reference...) in a tree
ARRAY_KINDS = "biufcUSmM"  # numpy dtype kinds that npy stores without pickling (the file checks them again)
_BIT_GENERATORS = ("PCG64", "PCG64DXSM", "MT19937", "Philox", "SFC64")


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
    return {TAG: "object", "class": cls.__qualname__, "fields": fields}


# --- encoding: Python objects -> tree (JSON values, raw ndarrays, tagged dicts) ----------------------
class Encoder:
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
            return {TAG: "numpy_scalar", "array": self._array(np.asarray(value), path)}
        if kind is list:
            return [self.encode(v, f"{path}[{i}]") for i, v in enumerate(value)]
        if kind is tuple:
            return {TAG: "tuple", "items": [self.encode(v, f"{path}[{i}]") for i, v in enumerate(value)]}
        if kind is dict:
            bad = [k for k in value if type(k) is not str]
            if bad:
                raise CheckpointError(f"attribute {path}: dict keys must be str, got {bad[0]!r}")
            return {TAG: "dict", "items": [[k, self.encode(v, f"{path}[{k!r}]")] for k, v in value.items()]}
        if kind is np.random.Generator:
            return {TAG: "generator", "state": self.encode(value.bit_generator.state, f"{path}.state")}
        if kind is Belief:
            return {TAG: "belief", "fields": {f.name: self.encode(getattr(value, f.name), f"{path}.{f.name}")
                                              for f in dataclasses.fields(Belief)}}
        if kind is GridModel:
            return encode_model(value)
        if STATE_CLASSES.get(kind.__qualname__) is kind:
            return state_node(kind, {f.name: self.encode(getattr(value, f.name), f"{path}.{f.name}")
                                     for f in dataclasses.fields(value)})
        if isinstance(value, np.dtype):
            return {TAG: "dtype", "name": value.str}
        if isinstance(value, type) and issubclass(value, np.generic):
            return {TAG: "scalar_type", "name": np.dtype(value).str}
        name = callable_name(value)
        if name is not None:
            return {TAG: "callable", "name": name}
        raise CheckpointError(
            f"attribute {path}: cannot checkpoint a {kind.__module__}.{kind.__qualname__}; supported: numpy "
            f"arrays and scalars, None/bool/int/float/str, tuples, lists, str-keyed dicts, numpy Generators, "
            f"Belief, GridModel, functions (see onlinemap.checkpoint)")

    def _array(self, array: np.ndarray, path: str):
        if array.dtype.kind not in ARRAY_KINDS or array.dtype.fields is not None:
            raise CheckpointError(f"attribute {path}: arrays of dtype {array.dtype} cannot be stored without pickle")
        for seen, seen_path in self._arrays:
            if seen is array:
                return {TAG: "same_as", "path": seen_path}
            if array.flags.writeable and seen.flags.writeable and np.may_share_memory(array, seen):
                raise CheckpointError(f"attributes {seen_path} and {path} are writable views of the same memory; "
                                      "a checkpoint cannot keep them linked")
        self._arrays.append((array, path))
        copy = array.copy(order="K")  # keeps C or Fortran order: numpy sums in memory order
        copy.setflags(write=array.flags.writeable)
        return copy


def scratch_node(value, name: str) -> dict:
    """The tree of a scratch array attribute: its dtype and shape only (the loader makes a fresh
    one); CheckpointError naming ``name`` if it is not an ndarray."""
    if type(value) is not np.ndarray:
        raise CheckpointError(f"attribute {name}: scratch_attributes must be arrays, got {type(value).__name__}")
    return {TAG: "scratch", "dtype": value.dtype.str, "shape": list(value.shape)}


def callable_name(value) -> str | None:
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
    """Tree of a model's defining tables (the derived ones are rebuilt by the constructor; the
    fields of :data:`~onlinemap.model.OMITTED_AT_DEFAULT` at their default are left out, as older
    checkpoints have them)."""
    encoder = Encoder()
    return {TAG: "model", "fields": {name: encoder.encode(getattr(model, name), name) for name in DEFINING_FIELDS
                                     if name not in OMITTED_AT_DEFAULT
                                     or getattr(model, name) != OMITTED_AT_DEFAULT[name]}}


# --- decoding: tree -> fresh Python objects (arrays copied) ------------------------------------------
class KeepFresh:
    """A function attribute (configuration the fresh instance re-derives; its name is checked) or a
    scratch buffer (its dtype and shape are checked)."""

    def __init__(self, name: str, dtype: str | None = None, shape: list | None = None) -> None:
        self.name, self.dtype, self.shape = name, dtype, shape


class Decoder:
    """Turns a tree back into fresh Python objects (arrays copied, aliases restored)."""

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
        if type(node) is not dict or not isinstance(node.get(TAG), str):
            raise CheckpointError(f"attribute {path}: malformed checkpoint entry {shortened(node)}")
        tag = node[TAG]
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
                return KeepFresh(str(node["name"]))
            if tag == "scratch":
                return KeepFresh("scratch", str(node["dtype"]), list(node["shape"]))
        except CheckpointError:
            raise
        except (KeyError, TypeError, ValueError, AttributeError, OverflowError, IndexError) as error:
            raise CheckpointError(f"attribute {path}: malformed {tag!r} entry: {shortened(str(error))}") from None
        raise CheckpointError(f"attribute {path}: unknown entry type {tag!r}")


    def _object(self, node: dict, path: str):
        cls = STATE_CLASSES.get(node["class"]) if isinstance(node["class"], str) else None
        if cls is None:
            raise CheckpointError(f"attribute {path}: unknown state class {shortened(node['class'])}")
        names = [f.name for f in dataclasses.fields(cls)]
        given = node["fields"]
        if type(given) is not dict or sorted(given) != sorted(names):
            raise CheckpointError(f"attribute {path}: a {cls.__name__} needs the fields {names}")
        fields = {name: self.decode(given[name], f"{path}.{name}") for name in names}
        if any(isinstance(value, KeepFresh) for value in fields.values()):
            raise CheckpointError(f"attribute {path}: a {cls.__name__} holds only values, not functions")
        return cls(**fields)


def shortened(node) -> str:
    """``node`` (a str as it is, anything else by ``repr``) cut to 80 characters, for error
    messages about crafted files."""
    text = node if isinstance(node, str) else repr(node)
    return text if len(text) <= 80 else text[:77] + "..."


def _dtype(name: str) -> np.dtype:
    dtype = np.dtype(str(name))
    if dtype.kind not in ARRAY_KINDS:
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
    if type(node) is not dict or node.get(TAG) != "model" or not set(DEFINING_FIELDS) - set(OPTIONAL_FIELDS) <= names <= set(DEFINING_FIELDS):
        raise CheckpointError("the checkpoint's model entry is malformed")
    fields = {name: Decoder().decode(value, name) for name, value in node["fields"].items()}
    try:
        return GridModel(**fields)
    except (OnlineMapError, TypeError, ValueError) as error:
        raise CheckpointError(f"the checkpoint's model is invalid: {error}") from None


def decode_options(node) -> dict:
    """The estimator options stored by :func:`state_dict` (a dict of plain values)."""
    options = Decoder().decode(node, "options")
    if type(options) is not dict:
        raise CheckpointError("malformed options entry")
    return options


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

