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


def chunk_body(func):
    """Compile ``func``, the work of one ``prange`` iteration, as a function of its own.

    Written inline in the parallel loop, a body that reallocates its scratch (tables that grow
    on demand) gave wrong results for every block after the first reallocation, under numba's
    parfor transformations; as a function of its own it is plain serial code
    (``tests/test_stages.py`` covers the growth). Only one kernel calls each such function, so
    no other kernel's copy of it can be linked in its place (see :mod:`.cache`).
    """
    return numba.njit(fastmath=FASTMATH)(func)
