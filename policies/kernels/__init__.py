"""numba kernels of the planners, beside the planners that call them: ``planning`` (information
gain's rollouts through a thinned particle belief in the paper's world, and the bundles and world
step the rollouts share), ``footprint`` (the same for any footprint and blocking labels),
``mixture`` (the footprint rollouts' uncertainty), ``paths`` (shortest expected paths),
``navigation`` (the goal planner's value iteration over (cell, step)) and ``mdp`` (policy
iteration's system and greedy improvement). The rule of :mod:`onlinemap.kernels` holds here too:
arrays in, arrays out, no model objects, every kernel ``@njit(cache=True)`` (inner loops that
allocate nothing :data:`onlinemap.kernels.loop_kernel`s, those only kernels call
:data:`onlinemap.kernels.inner_kernel`s); many arrays travel as a few NamedTuple bundles, the
model's tables as the RBPF's ``World``. The rollouts' entry points are Python functions that
allocate and call one loop kernel: a compiled entry point compiles all its callees' code again. This package imports numpy, numba, those
decorators and the RBPF's ``carried`` (a marginal carried by ``C^d``).
"""
