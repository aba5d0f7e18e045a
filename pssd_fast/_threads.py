"""The ``n_jobs`` convention: how many threads the kernels use, restored afterwards."""
import contextlib

import numba

from ._validation import check_int


def resolve_n_jobs(n_jobs):
    """Number of threads for ``n_jobs``.

    ``None`` or -1 mean every thread numba may use (``NUMBA_NUM_THREADS``, by default the number
    of cores); a positive value asks for that many, capped at that maximum; 0 and values below -1
    are errors.
    """
    limit = numba.config.NUMBA_NUM_THREADS
    if n_jobs is None:
        return limit
    n_jobs = check_int(n_jobs, "n_jobs")
    if n_jobs == -1:
        return limit
    if n_jobs < 1:
        raise ValueError(f"n_jobs must be a positive integer, -1 or None (all cores); got {n_jobs}")
    return min(n_jobs, limit)


@contextlib.contextmanager
def threads(n_jobs):
    """Run the enclosed kernels with ``n_jobs`` threads, restoring numba's setting on exit."""
    wanted = resolve_n_jobs(n_jobs)
    previous = numba.get_num_threads()
    numba.set_num_threads(wanted)
    try:
        yield wanted
    finally:
        numba.set_num_threads(previous)
