"""sphcore: the physics of the SPH simulator (state, kernels, neighbour grid, solvers, boundaries).

No networking here. Importing this package compiles nothing; numba compiles each stage on first use
and caches it on disk.
"""
__version__ = "0.1.0"
