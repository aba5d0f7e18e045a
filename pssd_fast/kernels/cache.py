"""Where compiled kernels are cached, and why they are compiled in a child process.

Numba invalidates a cached kernel only when the file defining it changes, so a kernel that
inlines a helper from ``linalg.py`` or a constant from ``config.py`` would keep stale machine code
after that file changed. The cache folder is therefore keyed by a hash of every kernel source
and of the numba, llvmlite and Python versions (:func:`source_key`): any change gives a new,
empty folder.

A kernel compiled in the calling process does not run the machine code that numba writes to the
cache. Numba compiles the body of each ``prange`` loop as a library of its own, registers it with
the JIT, then links a copy into the kernel and optimises that copy again together with the
kernel. The JIT resolves the kernel's call to the body by name, and finds the first registration:
the body optimised alone. The cached object file holds only the second copy, and a process that
loads it runs that one. With reassociation allowed (``config.FASTMATH``), the two optimisations
sum the neighbour loops in different orders, and results differed by about 1e-11. So every
kernel signature is compiled in a child process that writes the cache, and the calling process
only ever loads it (:class:`Kernel`): fresh and cached runs execute the same object code.
"""
import atexit
import hashlib
import os
import pickle
import shutil
import subprocess
import sys
import tempfile
import threading
import warnings
from pathlib import Path

import llvmlite
import numba
import numpy as np

#: Environment variable naming the folder under which compiled kernels are cached.
CACHE_ENV = "PSSD_FAST_CACHE_DIR"
#: Seconds a child may take to compile one kernel signature; past them that kernel compiles in
#: the calling process (a hung child would otherwise hold every kernel's first call).
CHILD_TIMEOUT = 600.0
_KERNEL_DIR = Path(__file__).resolve().parent
_PACKAGE_PARENT = _KERNEL_DIR.parent.parent


def source_key():
    """Hash of every kernel source file and of the compiler versions (16 hex digits)."""
    digest = hashlib.sha256()
    for path in sorted(_KERNEL_DIR.glob("*.py")):
        digest.update(path.name.encode())
        digest.update(path.read_bytes())
    for version in (numba.__version__, llvmlite.__version__, sys.version):
        digest.update(version.encode())
    return digest.hexdigest()[:16]


def _writable(folder):
    """``folder`` created if needed, or None when it cannot be written."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
        handle, probe = tempfile.mkstemp(dir=folder, prefix=".probe-")
        os.close(handle)
        os.unlink(probe)
    except OSError:
        return None
    return folder


def _user_cache_base():
    """``$PSSD_FAST_CACHE_DIR``, else the per-user cache folder (XDG on every platform)."""
    chosen = os.environ.get(CACHE_ENV)
    if chosen:
        return Path(chosen).expanduser()
    xdg = os.environ.get("XDG_CACHE_HOME")
    return (Path(xdg) if xdg else Path.home() / ".cache") / "pssd_fast"


def _resolve():
    """The cache folder of this process and whether it outlives it.

    A per-user folder when it is writable; else a private temporary folder removed at exit (the
    kernels then compile once per process, but still in a child, so results stay identical);
    else None: kernels compile in memory in this process.
    """
    key = f"kernels-{source_key()}"
    base = _user_cache_base()
    folder = _writable(base / key)
    if folder is not None:
        return folder, True
    try:
        scratch = Path(tempfile.mkdtemp(prefix="pssd_fast-"))
    except OSError:
        warnings.warn(f"pssd_fast: no writable cache folder ({base} and the temporary folder are "
                      f"read-only); kernels are compiled in memory for this process only. Set "
                      f"{CACHE_ENV} to a writable folder to keep them.", RuntimeWarning,
                      stacklevel=3)
        return None, False
    atexit.register(shutil.rmtree, scratch, ignore_errors=True)
    warnings.warn(f"pssd_fast: cache folder {base} is not writable; kernels are compiled for this "
                  f"process only. Set {CACHE_ENV} to a writable folder to keep them.",
                  RuntimeWarning, stacklevel=3)
    return scratch / key, False


CACHE_DIR, PERSISTENT = _resolve()


def compile_kernel(func, **options):
    """``numba.njit(**options)(func)``, caching into :data:`CACHE_DIR` when there is one."""
    if CACHE_DIR is None:
        return numba.njit(cache=False, **options)(func)
    # Numba reads its cache folder when the dispatcher is created; set it only for that moment so
    # that the caller's own numba functions keep their cache where it was.
    previous = numba.config.CACHE_DIR
    numba.config.CACHE_DIR = str(CACHE_DIR)
    try:
        return numba.njit(cache=True, **options)(func)
    finally:
        numba.config.CACHE_DIR = previous


def _type_key(value):
    """What decides the numba type of a kernel argument: an array's dtype, dimensions, layout
    and writability; any other value's Python type (the kernels take int, float and bool)."""
    if isinstance(value, np.ndarray):
        flags = value.flags
        return (value.dtype.str, value.ndim, flags.c_contiguous, flags.f_contiguous,
                flags.writeable, flags.aligned)
    return type(value)


class Kernel:
    """A numba dispatcher whose signatures are compiled in a child process (see module notes).

    Calls go to the dispatcher; the first call with new argument types in this process makes sure
    a child has compiled that signature into the cache (once per cache folder, recorded by a
    marker file), so the dispatcher loads it instead of compiling it here. Attributes such as
    ``py_func`` and ``signatures`` are the dispatcher's.
    """

    _lock = threading.Lock()

    def __init__(self, dispatcher):
        self.dispatcher = dispatcher
        self._ready = set()
        self._child_failed = False
        self.__doc__ = dispatcher.__doc__
        self.__name__ = dispatcher.__name__
        self.__module__ = dispatcher.__module__
        self.__wrapped__ = dispatcher.py_func

    def __getattr__(self, name):
        return getattr(self.dispatcher, name)

    def __call__(self, *args):
        if CACHE_DIR is not None:
            # A cheap key first: numba.typeof of every argument costs about 15 us each, a
            # few milliseconds a run on a small cloud.
            key = tuple(_type_key(a) for a in args)
            if key not in self._ready:
                types = tuple(numba.typeof(a) for a in args)
                with self._lock:
                    self._build(types)
                self._ready.add(key)
        return self.dispatcher(*args)

    def _build(self, types):
        name = f"{self.__module__}.{self.__name__}"
        # Numba's cache serves a kernel only to the file it was compiled from, at that file's
        # modification time and size: a copy of the package elsewhere (another checkout or
        # install) or a rewritten file misses it, and must compile in a child too.
        source = self.dispatcher.py_func.__code__.co_filename
        stamp = os.stat(source)
        built = f"{name}{types}{source}{stamp.st_mtime}{stamp.st_size}"
        marker = CACHE_DIR / "built" / hashlib.sha1(built.encode()).hexdigest()
        if marker.exists() or self._child_failed:
            return
        request = pickle.dumps((self.__module__, self.__name__, types, str(marker)))
        env = dict(os.environ, **{CACHE_ENV: str(CACHE_DIR.parent)})
        try:
            done = subprocess.run([sys.executable, "-m", "pssd_fast.kernels.build"],
                                  input=request, cwd=_PACKAGE_PARENT, env=env,
                                  capture_output=True, check=False, timeout=CHILD_TIMEOUT)
            failure = (None if done.returncode == 0 and marker.exists()
                       else done.stderr.decode(errors="replace").strip()[-300:])
        except (OSError, subprocess.TimeoutExpired) as error:
            # No Python to start (an embedded interpreter), or a child that hangs.
            failure = f"{type(error).__name__}: {error}"
        if failure is not None:
            # This kernel's dispatcher compiles in this process from now on: correct, but see
            # the module notes. The other kernels still try their children.
            self._child_failed = True
            warnings.warn(f"pssd_fast: compiling {name} in a child process failed ({failure}); "
                          f"compiling it in this process", RuntimeWarning, stacklevel=3)
