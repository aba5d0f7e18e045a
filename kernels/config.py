"""JIT settings shared by every kernel, so that caching and fastmath change in one place."""
import numba

# No "nnan"/"ninf": degenerate fits are detected through NaN/Inf comparisons.
# No "afn": approximate library calls may differ between vector and scalar code paths.
FASTMATH = {"nsz", "arcp", "contract", "reassoc"}

# Points per parallel task. Fixed (not derived from the thread count) so that each point is
# always computed by the same instruction sequence: output is bit-identical for any n_jobs.
CHUNK = 256


def parallel_kernel(func):
    """Compile ``func`` as a cached, multi-threaded kernel (``prange`` over point chunks)."""
    return numba.njit(parallel=True, cache=True, fastmath=FASTMATH)(func)


def helper(func):
    """Compile ``func`` as a cached scalar helper called from kernels."""
    return numba.njit(cache=True, fastmath=FASTMATH)(func)
