"""The one place where softsim's Numba compilation flags live.

``njit`` compiles a serial function (inlined into its callers by LLVM where small);
``njit_parallel`` a driver whose ``prange`` loops run on Numba's thread pool.  Both cache the
machine code on disk (``cache=True``), so a second run does not recompile.  Every jitted function
is a module-level function: Numba cannot cache closures.
"""

import numba

JIT_OPTIONS = dict(cache=True, nogil=True, fastmath=False, error_model="numpy")


def njit(func):
    """Compile ``func`` as a serial, cached Numba function."""
    return numba.njit(**JIT_OPTIONS)(func)


def njit_parallel(func):
    """Compile ``func`` as a cached Numba function whose ``prange`` loops run in parallel."""
    return numba.njit(parallel=True, **JIT_OPTIONS)(func)
