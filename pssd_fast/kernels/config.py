"""JIT settings shared by every kernel, so that caching and compiler flags change in one place.

No kernel uses fast-math flags: without them LLVM keeps every floating-point operation as
written, so the same source gives the same bits however numba optimises and links it, whether
just compiled or loaded from the cache (see :mod:`.cache`). Measured, the flags gained nothing:
the neighbour loops gather through index arrays and do not vectorise either way.
"""
import numba

from .cache import Kernel

# Points per parallel task. Fixed (not derived from the thread count) so that each point is
# always computed by the same instruction sequence: output is bit-identical for any n_jobs.
CHUNK = 256


def parallel_kernel(func):
    """Compile ``func`` as a cached, multi-threaded kernel (``prange`` over point chunks)."""
    return Kernel(numba.njit(parallel=True)(func))


def serial_kernel(func):
    """Compile ``func`` as a cached single-threaded kernel, for work that is sequential by nature
    (a traversal whose every step depends on the previous ones)."""
    return Kernel(numba.njit(parallel=False)(func))


def helper(func):
    """Compile ``func`` as a function that kernels call; it compiles with the first kernel that
    calls it, and is cached as part of that kernel."""
    return numba.njit(func)
