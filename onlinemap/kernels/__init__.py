"""numba kernels, one module per algorithm: ``exact`` (the joint belief's fused motion + sensor
pass and map dynamics), ``rbpf`` and its ``rbpf_*`` modules (the particle filter's maps as
copy-on-write blocks, its children, commits, recovery, threads, resample-move and per-particle
context prior),
``resampling`` (Fearnhead-Clifford's optimal resampling), ``forward_backward`` (the EM
estimators' location HMM) and ``layered`` (layered EM's stretches: forward-backward over start
cells and offsets): the estimators' kernels. The planners' kernels live beside the
planners (:mod:`policies.kernels`) and take the decorators below.

The rule for every kernel here: arrays in, arrays out, no model objects. A kernel takes plain
numpy arrays and scalars, or NamedTuples of them (bundles: the object that holds the arrays
returns its bundle, e.g. the RBPF's ``Pool``; the model's tables are passed as arrays by the
caller), writes its results into arrays it is given, and never allocates per step what the
caller can keep. Every
kernel is ``@njit(cache=True)``: compiled once, cached on disk; an inner loop that allocates
nothing may be a :data:`loop_kernel` (an :data:`inner_kernel` if only kernels call it), and one
that Python threads run at once on disjoint ranges a :data:`thread_kernel` (an entry point that only fills in such a kernel's range and scratch
arrays may then be a plain Python function, sharing the threads' compiled kernel). This package
imports numpy and numba only (and llvmlite, numba's code generator, for :func:`prefetch`),
besides the standard library.
"""

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic

#: An inner loop compiled without reference counting (numba's ``_nrt=False``). It may allocate
#: nothing (its caller, a plain kernel, allocates the few small buffers it needs and passes them
#: in); in exchange numba no longer counts references to the array arguments of the inlined
#: helpers on every call wherever its pruning pass cannot show the counts balanced, atomic
#: operations that cost 1.3-2x the arithmetic of the RBPF's enumeration and commit (measured).
loop_kernel = njit(cache=True, _nrt=False)

#: A :data:`loop_kernel` over a range that releases the GIL when called from Python, so that Python
#: threads run it at once on disjoint ranges (the RBPF's, :mod:`onlinemap.kernels.rbpf_parallel`).
#: A kernel calling it with literal bounds (``0``) gets a copy of its own, specialised to them
#: (numba compiles a callee anew for literal arguments); a plain Python function calling it
#: shares the threads' copy instead (``rbpf_enumerate_cells``: 8 CPU seconds less to compile).
thread_kernel = njit(cache=True, _nrt=False, nogil=True)


#: A :data:`loop_kernel` only other kernels call: compiled without the two wrappers that let Python
#: (and numba's first-class function values) call it, which unbox every array of every bundle
#: argument and are compiled anew with each signature (a third of a second for three bundles of
#: eight arrays, measured). Calling it from Python fails.
inner_kernel = njit(cache=True, _nrt=False, no_cpython_wrapper=True, no_cfunc_wrapper=True)

#: bytes: where numba starts the data of the arrays it allocates (its AVX preference)
ALIGNMENT = 32


def aligned(shape, dtype=np.float64, fill=None):
    """A C-contiguous array of ``shape`` (uninitialised, or every entry ``fill``) whose data starts
    on an :data:`ALIGNMENT`-byte boundary, as numba's own arrays do: for the buffers an entry point
    allocates in Python for its kernels, so that their vector loops see the data aligned as when a
    compiled entry point allocated it (numpy's arrays start wherever malloc puts them, on 16
    bytes). O(size)."""
    dtype = np.dtype(dtype)
    size = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
    raw = np.empty(size + ALIGNMENT, dtype=np.uint8)
    start = -raw.ctypes.data % ALIGNMENT
    out = raw[start:start + size].view(dtype).reshape(shape)
    if fill is not None:
        out.fill(fill)
    return out

#: how many iterations ahead the RBPF's loops ask for the rows they will read (:func:`prefetch`)
PREFETCH_AHEAD = 8


@intrinsic
def prefetch(typingctx, array, index):
    """``prefetch(array, (i, j, ...))``: ask the CPU to bring the cache line of ``array[i, j, ...]``
    (one index per dimension, not checked against the shape) into its caches, and go on. It
    changes no result; a loop over particles whose rows lie anywhere in a large pool asks for
    those of the particle :data:`PREFETCH_AHEAD` iterations on, so that the loads overlap
    (measured: the RBPF's enumeration at 10^5 particles 2.3x faster)."""
    if not isinstance(array, types.Array) or not isinstance(index, types.UniTuple) or index.count != array.ndim:
        return None

    def codegen(context, builder, signature, args):
        array_type = signature.args[0]
        data = context.make_array(array_type)(context, builder, args[0])
        indices = cgutils.unpack_tuple(builder, args[1], array_type.ndim)
        pointer = cgutils.get_item_pointer(context, builder, array_type, data, indices, wraparound=False)
        byte_pointer = ir.IntType(8).as_pointer()
        name = "llvm.prefetch.p0" if str(byte_pointer) == "ptr" else "llvm.prefetch.p0i8"  # opaque or typed pointers
        function = cgutils.get_or_insert_function(builder.module, ir.FunctionType(
            ir.VoidType(), [byte_pointer, ir.IntType(32), ir.IntType(32), ir.IntType(32)]), name)
        read, high_locality, data_cache = (ir.Constant(ir.IntType(32), v) for v in (0, 3, 1))
        builder.call(function, [builder.bitcast(pointer, byte_pointer), read, high_locality, data_cache])
        return context.get_dummy_value()

    return types.void(array, index), codegen
