"""The checkpoint protocol: an estimator <-> its state dict (:func:`state_dict`,
:func:`load_state_dict`), with every check a state passes before an estimator takes it.

The state is the estimator's instance attributes (``vars(est)``), encoded by
:mod:`onlinemap.checkpoint.codec`; ``est.model`` and ``est.options`` (the keyword options it was
built with, recorded by :func:`~onlinemap.estimators.register`) are stored apart and checked on
load. Loading checks the format version (:func:`check_header`; compatibility rests on
:data:`FORMAT_VERSION`, not the package version), the estimator name, the model (bitwise), the
options, the attribute names and kinds, then the restored state's invariants
(:func:`check_state`: the attributes the estimator's class names in ``CONSTANT_STATE`` equal its
own bit for bit, and the class's ``check_state`` accepts the rest; see
:mod:`onlinemap.state_checks`), so that no crafted state can make a kernel index outside its
arrays. A class may name buffers whose contents are dead between steps (fully overwritten before
being read) in a class attribute ``scratch_attributes = ("_buffer", ...)``: their dtype and
shape are recorded and checked, their contents are neither saved nor restored (the fresh
instance's own buffers are kept), so they cost nothing in a checkpoint and do not count as state
when comparing two state dicts; a checkpoint written before the class had one of them still loads,
as does one written before the class had a keyword option (the option takes its default).

Cost: one copy of every array of the state (O(state size)) for ``state_dict``, and one pass over
it for ``load_state_dict``'s checks.
"""

from __future__ import annotations

import inspect
import types

import numpy as np

from ..errors import CheckpointError
from ..model import GridModel, model_difference
from .codec import (Decoder, Encoder, KeepFresh, callable_name, scratch_node, shortened, decode_model,
                    decode_options, encode_model, same_tree)

FORMAT = "onlinemap-checkpoint"
FORMAT_VERSION = 4  # bump when the file layout or an estimator's state changes incompatibly
OLDEST_FORMAT_VERSION = 1  # the oldest format this code still reads
# version 2: the RBPF's block pool is one attribute (``_blocks``, a BlockPool); version 3: the RBPF
# counts its recoveries from depletion (``_recoveries``, ``_recovered``); version 4: the RBPF's
# resample-move step (``_history``, a PathHistory or None; ``move_window``, ``move_every``,
# ``move_lag``). Older files are read through RaoBlackwellisedPF.upgrade_attributes.
_SEPARATE = ("model", "options")  # attributes stored apart from the state tree


def _package_version() -> str:
    from .._version import __version__

    return __version__


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
    encoder = Encoder()
    scratch = set(getattr(type(est), "scratch_attributes", ()))
    attributes = {name: scratch_node(value, name) if name in scratch else encoder.encode(value, name)
                  for name, value in vars(est).items() if name not in _SEPARATE}
    return {"format": FORMAT, "format_version": FORMAT_VERSION, "onlinemap_version": _package_version(),
            "estimator": est.name, "t": int(est.t), "options": Encoder().encode(stored_options(est), "options"),
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
        raise CheckpointError(f"checkpoint format version {shortened(repr(version))}; this onlinemap "
                              f"({_package_version()}) reads versions {OLDEST_FORMAT_VERSION} to {FORMAT_VERSION}")
    if version > FORMAT_VERSION and not allow_newer:
        raise CheckpointError(f"checkpoint format version {version} was written by a newer onlinemap "
                              f"({shortened(repr(state.get('onlinemap_version')))}); this one "
                              f"({_package_version()}) reads up to version {FORMAT_VERSION}: upgrade onlinemap, "
                              "or pass allow_newer=True (track: --allow-newer-checkpoint) to try anyway")
    if strict_version and state.get("onlinemap_version") != _package_version():
        written = shortened(repr(state.get("onlinemap_version")))
        raise CheckpointError(f"checkpoint written by onlinemap {written}, this is {_package_version()}, and "
                              "strict_version=True asks for the same version")
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
    if not same_tree(_with_later_options(state["options"], est), Encoder().encode(stored_options(est), "options")):
        options = Decoder().decode(state["options"], "options")
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
    decoder = Decoder()
    restored = {}
    try:
        for name, node in state["attributes"].items():
            value = decoder.decode(node, name)
            _check_kind(name, current[name], value)
            if not isinstance(value, KeepFresh):
                restored[name] = value
    except RecursionError:
        raise CheckpointError("checkpoint's attributes are nested too deeply") from None
    check_state(est, restored)
    vars(est).update(restored)


def stored_options(est) -> dict:
    """``est.options`` as a checkpoint stores them (a fresh dict): without the options its class's
    ``checkpoint_omitted_options`` names while they are None, their default (options added
    later: the checkpoints of an estimator without them stay as they were, byte for byte)."""
    omitted = getattr(type(est), "checkpoint_omitted_options", ())
    return {name: value for name, value in getattr(est, "options", {}).items()
            if name not in omitted or value is not None}


def _with_later_options(node, est):
    """The encoded options of a checkpoint, with every keyword option of ``est``'s class that it
    does not name (one added after it was written) at its default, in the order of the class's
    signature (``est.options``'): a checkpoint predating an option loads into an estimator that
    has it at its default, and only there (those of :func:`stored_options`, left out at None,
    stay out)."""
    options = decode_options(node)
    omitted = getattr(type(est), "checkpoint_omitted_options", ())
    defaults = {p.name: p.default for p in inspect.signature(type(est).__init__).parameters.values()
                if p.kind is inspect.Parameter.KEYWORD_ONLY and p.default is not inspect.Parameter.empty
                and p.name not in omitted}
    merged = {**defaults, **options}  # the signature's order, then any option it does not name
    return Encoder().encode(merged, "options")


def check_state(est, restored: dict) -> None:
    """Check the attributes ``restored`` (name -> value) as ``est``'s new state, without changing
    ``est``: the attributes its class names in ``CONSTANT_STATE`` (fixed by the model and options)
    equal ``est``'s own, bit for bit, and the class's ``check_state(view)`` accepts the rest (the
    estimator's invariants, written with :mod:`onlinemap.state_checks`). A class that defines
    neither is loaded unchecked. Raises :class:`CheckpointError`."""
    cls = type(est)
    for name in getattr(cls, "CONSTANT_STATE", ()):  # "attribute" or "attribute.field"
        head, _, field = name.partition(".")
        if head not in restored:
            continue
        mine, theirs = vars(est)[head], restored[head]
        if field:
            mine, theirs = getattr(mine, field), getattr(theirs, field)
        if not same_tree(Encoder().encode(theirs, name), Encoder().encode(mine, name)):
            raise CheckpointError(f"invalid state: attribute {name} differs from what the model and options give")
    check = getattr(cls, "check_state", None)
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
    if isinstance(value, KeepFresh) and value.dtype is not None:
        if type(current) is not np.ndarray or current.dtype.str != value.dtype or list(current.shape) != value.shape:
            raise CheckpointError(f"attribute {name}: checkpoint has a scratch array {value.dtype} {value.shape}, "
                                  f"the estimator a {_kind(current)} {getattr(current, 'shape', '')}")
        return
    if isinstance(value, KeepFresh):
        if callable_name(current) != value.name:
            raise CheckpointError(f"attribute {name}: checkpoint has {value.name}, the estimator has "
                                  f"{callable_name(current) or _kind(current)}")
        return
    if current is None or value is None:
        return
    if _kind(current) != _kind(value):
        raise CheckpointError(f"attribute {name}: checkpoint holds a {_kind(value)}, the estimator a {_kind(current)}")
    if type(current) is np.ndarray and current.flags.c_contiguous and not value.flags.c_contiguous:
        raise CheckpointError(f"attribute {name}: the estimator's array is C-contiguous, the checkpoint's is not")

