"""Process-wide compute settings: which implementation of the hot loops runs, on how many threads,
and whether numba's compiled kernels are cached.

- :mod:`~planbench.runtime.backend`: numba or numpy for the field and the IK loop.
- :mod:`~planbench.runtime.threads`: thread pools of numba, OpenMP and BLAS in this process.
- :mod:`~planbench.runtime.compile_cache`: numba's on-disk cache of the kernels that plugins declare.
"""
