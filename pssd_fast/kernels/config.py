"""JIT settings shared by every kernel, so that caching and fastmath change in one place."""
import numba

from .cache import Kernel, compile_kernel

# No "nnan"/"ninf": degenerate fits are detected through NaN/Inf comparisons.
# No "afn": approximate library calls may differ between vector and scalar code paths.
FASTMATH = {"nsz", "arcp", "contract", "reassoc"}

# Points per parallel task. Fixed (not derived from the thread count) so that each point is
# always computed by the same instruction sequence: output is bit-identical for any n_jobs.
CHUNK = 256


def parallel_kernel(func):
    """Compile ``func`` as a cached, multi-threaded kernel (``prange`` over point chunks)."""
    return Kernel(compile_kernel(func, parallel=True, fastmath=FASTMATH))


def serial_kernel(func):
    """Compile ``func`` as a cached single-threaded kernel, for work that is sequential by nature
    (a traversal whose every step depends on the previous ones).

    No fastmath: a serial kernel gains nothing from vectorising reductions, and exact IEEE
    arithmetic lets its plain-Python reference reproduce every comparison bit for bit.
    """
    return Kernel(compile_kernel(func, parallel=False))


def helper(func):
    """Compile ``func`` as a scalar helper that numba inlines into every kernel calling it.

    Inlined, a helper has no symbol of its own: a kernel loaded from the cache cannot end up
    calling another kernel's copy of it, optimised in another context (see :mod:`.cache`).
    """
    return numba.njit(inline="always", fastmath=FASTMATH)(func)
