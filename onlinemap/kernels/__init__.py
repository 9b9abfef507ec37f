"""numba kernels, one module per algorithm: ``exact`` (the joint belief's fused motion + sensor
pass and map dynamics), ``rbpf`` (particle proposal, commit, resampling bookkeeping and map
mixtures over copy-on-write blocks) and ``forward_backward`` (the EM estimators' location HMM).

The rule for every kernel here: arrays in, arrays out, no model objects. A kernel takes plain
numpy arrays and scalars (the model's tables are passed as arrays by the caller), writes its
results into arrays it is given, and never allocates per step what the caller can keep. Every
kernel is ``@njit(cache=True)``: compiled once, cached on disk. This package imports numpy and
numba only.
"""
