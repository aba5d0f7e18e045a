"""JIT settings shared by every kernel, so that compiler flags change in one place.

No kernel uses fast-math flags: without them LLVM keeps every floating-point operation as
written, so the same source gives the same bits however numba optimises and links it, whether
just compiled or loaded from a cache. Measured, the flags gained nothing: the neighbour loops
gather through index arrays and do not vectorise either way.

Where compiled kernels are cached is not decided here: :class:`Kernel` hands each new
signature to :attr:`Kernel.loader`, which the package's cache (``pssd_fast.jit``) sets. Without
a loader numba compiles in memory, so this package runs on numpy and numba alone.
"""
import threading

import numba
import numpy as np

# Points per parallel task. Fixed (not derived from the thread count) so that each point is
# always computed by the same instruction sequence: output is bit-identical for any n_jobs.
CHUNK = 256


def _type_key(value):
    """What decides the numba type of a kernel argument: an array's dtype, dimensions, layout
    and writability; any other value's Python type (the kernels take int, float and bool)."""
    if isinstance(value, np.ndarray):
        flags = value.flags
        return (value.dtype.str, value.ndim, flags.c_contiguous, flags.f_contiguous,
                flags.writeable, flags.aligned)
    return type(value)


class Kernel:
    """A numba dispatcher that passes each new signature to :attr:`loader` before its first call.

    Attributes such as ``py_func`` and ``signatures`` are the dispatcher's.
    """

    #: ``loader(kernel, types)`` compiles or loads the signature ``types`` (numba types) of
    #: ``kernel``; None: numba compiles it on the call.
    loader = None
    #: Where not None, why no kernel may run in this process: every call raises a
    #: RuntimeError saying so (a forked copy of a process whose thread pools had started).
    refused = None

    def __init__(self, dispatcher):
        self.dispatcher = dispatcher
        self._ready = set()
        self._lock = threading.Lock()
        self.__doc__ = dispatcher.__doc__
        self.__name__ = dispatcher.__name__
        self.__module__ = dispatcher.__module__
        self.__wrapped__ = dispatcher.py_func

    def __getattr__(self, name):
        return getattr(self.dispatcher, name)

    def __call__(self, *args):
        if Kernel.refused is not None:
            raise RuntimeError(Kernel.refused)
        # A cheap key first: numba.typeof of every argument costs about 15 us each, a few
        # milliseconds a run on a small cloud.
        key = tuple(_type_key(a) for a in args)
        if key not in self._ready:
            with self._lock:
                if key not in self._ready:
                    if Kernel.loader is not None:
                        Kernel.loader(self, tuple(numba.typeof(a) for a in args))
                    self._ready.add(key)
        return self.dispatcher(*args)


def parallel_kernel(func):
    """Compile ``func`` as a multi-threaded kernel (``prange`` over point chunks)."""
    return Kernel(numba.njit(parallel=True)(func))


def serial_kernel(func):
    """Compile ``func`` as a single-threaded kernel, for work that is sequential by nature
    (a traversal whose every step depends on the previous ones)."""
    return Kernel(numba.njit(parallel=False)(func))


def helper(func):
    """Compile ``func`` as a function that kernels call; it compiles with the first kernel that
    calls it, and is cached as part of that kernel."""
    return numba.njit(func)
