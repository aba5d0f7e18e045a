"""The threads of the library: its OpenMP pools, set up when it first starts them, and the
``n_jobs`` convention (how many threads the kernels use, restored afterwards)."""
import contextlib
import ctypes
import importlib
import os
import sys
import threading

import numba

from ._validation import check_int
from .jit import cache, refuse_kernels

#: The idle spin of the OpenMP pools the library loads (``GOMP_SPINCOUNT``): pykdtree and numba's
#: kernels each bring their own OpenMP (libgomp) thread pool, and at libgomp's default of
#: 300,000 rounds an idle pool spins on the cores the other pool's next call needs, a quarter
#: of a run at 30,000 points (docs/DECISIONS.md, "Scan sizes: one fit per surface point, and
#: two thread pools").
SPIN_COUNT = 10_000
_pools_lock = threading.Lock()
_pools = {}
#: What a process forked from one whose pools had loaded is told at its first kernel or
#: neighbour query (:func:`_forked_child`).
FORKED = ("this process was forked from one that had run pssd_fast: the OpenMP thread pools "
          "(GNU libgomp, pykdtree's and numba's) cannot run in a forked copy of a process that "
          "started them; start worker processes with the 'spawn' or 'forkserver' method "
          "(multiprocessing.get_context('spawn'), ProcessPoolExecutor(mp_context=...))")
#: Whether this process is such a child.
_forked = []


def configure_threads(spin_count=SPIN_COUNT):
    """Load the OpenMP thread pools of pykdtree and numba with a short idle spin.

    Each pool reads ``GOMP_SPINCOUNT`` once, when it loads. The library loads both here, with
    ``GOMP_SPINCOUNT`` set to ``spin_count`` while they load, and then puts the environment
    back as it was, so that no other library or subprocess inherits the setting.
    :func:`~pssd_fast.denoise`, the stage functions, the tiled runs and the command line call
    this before their first kernel or neighbour query; only the first call in a process acts.
    A wait policy of the caller's own (``GOMP_SPINCOUNT`` or ``OMP_WAIT_POLICY`` in the
    environment) is left to act instead. A pool that was loaded before the first call (by
    importing pykdtree, or running numba's parallel code, first) keeps the setting it loaded
    with: call this first, or set ``GOMP_SPINCOUNT`` yourself.

    Parameters
    ----------
    spin_count : int
        The idle spin of the pools this call loads.

    Returns
    -------
    dict
        ``spin_count``: the spin the library set (None where the caller's environment decided),
        and ``loaded_before``: the pools that were running before the first call.
    """
    if _forked:
        raise RuntimeError(FORKED)
    with _pools_lock:
        if not _pools:
            caller = "GOMP_SPINCOUNT" in os.environ or "OMP_WAIT_POLICY" in os.environ
            before = [name for name, running in (
                ("pykdtree", "pykdtree.kdtree" in sys.modules),
                ("numba", numba.np.ufunc.parallel._is_initialized)) if running]
            if not caller:
                os.environ["GOMP_SPINCOUNT"] = str(check_int(spin_count, "spin_count"))
            try:
                importlib.import_module("pykdtree.kdtree")  # loads its pool
                _avoid_old_tbb()
                numba.get_num_threads()  # starts numba's threading layer
            finally:
                if not caller:
                    del os.environ["GOMP_SPINCOUNT"]
            _pools.update(spin_count=None if caller else int(spin_count), loaded_before=before)
            os.register_at_fork(after_in_child=_forked_child)
        return dict(_pools)


def _forked_child():
    """In a forked child, every kernel and neighbour query raises (:data:`FORKED`) where
    libgomp would kill the process, or hang it, at the first."""
    _forked.append(True)
    refuse_kernels(FORKED)


#: The oldest TBB numba's TBB layer runs on (``TBB_INTERFACE_VERSION``, TBB 2021 update 6).
TBB_INTERFACE = 12060


def _avoid_old_tbb():
    """Where numba would try TBB first (its default) and the TBB in the process is older than
    it needs (Open3D ships one), numba's OpenMP layer instead (workqueue where there is none):
    numba would warn and then fall back itself. A layer or a priority the caller set
    (``NUMBA_THREADING_LAYER``, ``NUMBA_THREADING_LAYER_PRIORITY`` or ``numba.config``) is
    left as it is, and so is a layer already started."""
    config = numba.config
    if (numba.np.ufunc.parallel._is_initialized or "NUMBA_THREADING_LAYER" in os.environ
            or config.THREADING_LAYER != "default"
            or "NUMBA_THREADING_LAYER_PRIORITY" in os.environ
            or config.THREADING_LAYER_PRIORITY[0] != "tbb" or not _old_tbb()):
        return
    try:
        importlib.import_module("numba.np.ufunc.omppool")
        config.THREADING_LAYER = "omp"
    except ImportError:
        config.THREADING_LAYER = "workqueue"


def _old_tbb():
    """Whether the process loads a TBB older than :data:`TBB_INTERFACE` (False without one)."""
    name = {"win32": "tbb12.dll", "darwin": "libtbb.12.dylib"}.get(sys.platform, "libtbb.so.12")
    try:
        version = ctypes.CDLL(name).TBB_runtime_interface_version
    except (OSError, AttributeError):
        return False
    version.argtypes, version.restype = [], ctypes.c_int
    return version() < TBB_INTERFACE


cache.before_kernels(configure_threads)


def kdtree(points):
    """pykdtree's tree of ``points``, its thread pool set up first (:func:`configure_threads`)."""
    configure_threads()
    from pykdtree.kdtree import KDTree

    return KDTree(points)


def resolve_n_jobs(n_jobs):
    """Number of threads for ``n_jobs``.

    ``None`` or -1 mean every thread numba may use (``NUMBA_NUM_THREADS``, by default the number
    of cores); a positive value asks for that many, capped at that maximum; 0 and values below -1
    are errors.
    """
    limit = numba.config.NUMBA_NUM_THREADS
    n_jobs = check_n_jobs(n_jobs)
    return limit if n_jobs in (None, -1) else min(n_jobs, limit)


def check_n_jobs(n_jobs):
    """``n_jobs`` checked: None, -1 or a positive int; TypeError or ValueError otherwise."""
    if n_jobs is None:
        return None
    n_jobs = check_int(n_jobs, "n_jobs")
    if n_jobs < 1 and n_jobs != -1:
        raise ValueError(f"n_jobs must be a positive integer, -1 or None (all cores); got {n_jobs}")
    return n_jobs


@contextlib.contextmanager
def threads(n_jobs):
    """Run the enclosed kernels with ``n_jobs`` threads, restoring numba's setting on exit."""
    wanted = resolve_n_jobs(n_jobs)
    configure_threads()
    previous = numba.get_num_threads()
    numba.set_num_threads(wanted)
    try:
        yield wanted
    finally:
        numba.set_num_threads(previous)
