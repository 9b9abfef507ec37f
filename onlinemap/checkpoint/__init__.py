"""Checkpoints: save an estimator, load it in another process, continue bit for bit.

Generic over every registered estimator, with no per-estimator code: the state is the
estimator's instance attributes (``vars(est)``), serialised by type. ``om.save(est, path)``
(:func:`save`) writes it, ``om.load(path)`` (:func:`onlinemap.estimators.load`) rebuilds the
estimator from it. Three modules, one job each, imports running one way (``codec`` <-
``protocol`` <- ``files``); every public name is importable from this package:

- :mod:`.codec`: attribute values <-> a tree of JSON values and arrays, by type (the table of
  what is stored how); the registry of state classes (:func:`state_class`, :func:`state_node`);
  the model's tree (:func:`encode_model`, :func:`decode_model`); :func:`same_tree`,
  :func:`first_difference`;
- :mod:`.protocol`: an estimator <-> its state dict (:func:`state_dict`,
  :func:`load_state_dict`), the format version (:data:`FORMAT_VERSION`, :func:`check_header`)
  and the checks of a restored state (:func:`check_state`);
- :mod:`.files`: the npz file format (:func:`write`, :func:`read` with its guards against
  crafted files, the SHA-256 digest, :func:`check_writable`, :func:`save`).

Cost: one copy of every array of the state (O(state size)) for ``state_dict``, and a write or
read of it plus one SHA-256 pass for ``save``/``load``.
"""

from __future__ import annotations

import numpy as np  # noqa: F401  (tests make np.savez fail through checkpoint.np)

from .codec import (STATE_CLASSES, decode_model, decode_options, encode_model, first_difference, same_tree,
                    state_class, state_node)
from .files import check_writable, read, save, write
from .files import checkpoint_digest, externalise_arrays  # noqa: F401  (tests forge files)
from .protocol import (FORMAT, FORMAT_VERSION, OLDEST_FORMAT_VERSION, check_header, check_state, load_state_dict,
                       state_dict)

__all__ = [
    "save", "read", "write", "check_writable", "state_dict", "load_state_dict", "check_header", "check_state",
    "FORMAT", "FORMAT_VERSION", "OLDEST_FORMAT_VERSION", "state_class", "state_node", "STATE_CLASSES",
    "encode_model", "decode_model", "decode_options", "same_tree", "first_difference",
]
