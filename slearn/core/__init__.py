"""The pure S-learning core: symbols, token tables, views, the context tree, the mixer, the
learning and online kernels, the predictors. Imports only numpy, numba, itself and
``slearn.errors`` (and ``_jit`` numba's code generator llvmlite, for one intrinsic)."""
