"""numba kernels, one module per algorithm: ``exact`` (the joint belief's fused motion + sensor
pass and map dynamics), ``rbpf`` (particle proposal, commit, resampling bookkeeping and map
mixtures over copy-on-write blocks), ``resampling`` (Fearnhead-Clifford's optimal resampling)
and ``forward_backward`` (the EM estimators' location HMM).

The rule for every kernel here: arrays in, arrays out, no model objects. A kernel takes plain
numpy arrays and scalars (the model's tables are passed as arrays by the caller), writes its
results into arrays it is given, and never allocates per step what the caller can keep. Every
kernel is ``@njit(cache=True)``: compiled once, cached on disk; an inner loop that allocates
nothing may be a :data:`loop_kernel`. This package imports numpy and numba only.
"""

from numba import njit

#: An inner loop compiled without reference counting (numba's ``_nrt=False``). It may allocate
#: nothing (its caller, a plain kernel, allocates the few small buffers it needs and passes them
#: in); in exchange numba no longer counts references to the array arguments of the inlined
#: helpers on every call wherever its pruning pass cannot show the counts balanced, atomic
#: operations that cost 1.3-2x the arithmetic of the RBPF's enumeration and commit (measured).
loop_kernel = njit(cache=True, _nrt=False)
