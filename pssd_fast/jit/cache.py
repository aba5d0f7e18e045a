"""Where compiled kernels are cached, and how a process checks that it loaded them.

Numba invalidates a cached kernel only when the file defining it changes, so a kernel calling a
helper from ``linalg.py`` or a constant from ``config.py`` would keep stale machine code after
that file changed. The cache folder is therefore named (:func:`cache_key`) by a hash of every
kernel source, of the numba, llvmlite, numpy and Python versions (numpy's decides how numba
types and lowers its functions), and of the CPU that numba compiles for: any change gives a
new, empty folder, and machines with different CPUs that share a home folder (a cluster) each
fill their own. Numba's files inside are stamped with the sources' hash alone, not with a
source file's path, so every copy of the same package shares them. Folders of other keys stay
until :func:`clear_stale` removes them: only that call removes one, so a long job of an older
install never loses its folder.

Numba's cache classes used here are private, so the cache is used only with the numba versions
it is tested with (:data:`NUMBA_TESTED`, the range ``pyproject.toml`` pins); with any other the
kernels compile in memory, with one warning.

Processes that compile into one folder at once (the workers of a cluster on a cold cache) take
turns per kernel (a lock file in the folder, where the system has ``fcntl``): numba's index of a
kernel is read, extended and written back by each process saving a signature, so two at once
could each drop the other's entry, and the second to come would compile what the first is
saving. Now the second waits, then loads. Where the lock cannot be had (Windows, a file system
without locks) they compile side by side as numba alone would.

Every kernel is compiled without fast-math flags (``pssd_fast/kernels/config.py``), so LLVM may not
reorder, contract or approximate any floating-point operation: whichever copy of a ``prange`` body
a process runs (the one it just compiled, or the one loaded from the cache) computes the same bits.
Kernels therefore compile in the calling process, only when first called with new argument types,
and nothing about the cache can change a result; it changes only the time.

The folder is found on the first kernel call, not at import. A process that finds a kernel
recorded as compiled into its folder (a marker file, written after numba saved it) before asking
numba, and then has numba compile it anyway, warns once, naming the folder: the cache was copied
from a machine numba tells apart, or its index files were removed.
"""
import atexit
import contextlib
import functools
import hashlib
import os
import re
import shutil
import sys
import tempfile
import threading
import time
import warnings
from pathlib import Path

import llvmlite
import numba
import numpy
from numba.core import caching, registry

try:
    import fcntl
except ImportError:  # Windows: processes compile side by side (module notes)
    fcntl = None

#: Environment variable naming the folder under which compiled kernels are cached.
CACHE_ENV = "PSSD_FAST_CACHE_DIR"
#: Days after its last use that :func:`clear_stale` removes another key's ``kernels-*`` folder.
STALE_DAYS = 30
#: The numba versions the cache is tested with, as (major, minor): from the first, up to and
#: without the second; ``pyproject.toml`` pins the same range.
NUMBA_TESTED = ((0, 59), (0, 69))
_KERNEL_DIR = Path(__file__).resolve().parent.parent / "kernels"


def cpu_key():
    """What numba compiles for: target triple, CPU name and CPU features."""
    return registry.cpu_target.target_context.codegen().magic_tuple()


def source_key():
    """Hash of every kernel source file and of the numba, llvmlite, numpy and Python versions
    (16 hex digits): numba's stamp of the sources its cached files were compiled from."""
    digest = hashlib.sha256()
    for path in sorted(_KERNEL_DIR.glob("*.py")):
        digest.update(path.name.encode())
        digest.update(path.read_bytes())
    for version in (numba.__version__, llvmlite.__version__, numpy.__version__, sys.version):
        digest.update(version.encode())
    return digest.hexdigest()[:16]


def cache_key():
    """Hash of :func:`source_key` and :func:`cpu_key` (16 hex digits): the folder's name."""
    digest = hashlib.sha256(source_key().encode())
    for part in cpu_key():
        digest.update(str(part).encode())
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


def numba_tested(version=None):
    """Whether numba ``version`` (default: the one imported) is in :data:`NUMBA_TESTED`."""
    found = re.match(r"(\d+)\.(\d+)", version or numba.__version__)
    if found is None:
        return False
    low, high = NUMBA_TESTED
    return low <= (int(found[1]), int(found[2])) < high


def clear_stale(days=STALE_DAYS):
    """Remove the kernel cache folders of other versions and CPUs unused for ``days`` days.

    Each installed version of pssd_fast (and of numba, llvmlite, numpy or Python) and each CPU
    type fills a folder of its own under the cache folder (docs/architecture.md, "The kernel
    cache"), and nothing removes one but this call: run it when no process of an older install
    is running, as a folder removed while in use costs that process its cached kernels.

    Parameters
    ----------
    days : float
        Keep folders whose last use (each process marks its own on its first kernel call) is
        more recent; 0 removes every other folder.

    Returns
    -------
    list of str
        The names of the folders removed.
    """
    return remove_stale(_user_cache_base(), _user_cache_base() / f"kernels-{cache_key()}",
                        days)


def remove_stale(base, keep, days=STALE_DAYS):
    """Remove the ``kernels-*`` folders under ``base`` other than ``keep`` whose last use (the
    folder's modification time) is more than ``days`` ago; return their names."""
    cutoff = time.time() - days * 86400
    removed = []
    for folder in base.glob("kernels-*"):
        try:
            stale = folder != keep and folder.stat().st_mtime < cutoff
        except OSError:
            continue
        if stale:
            shutil.rmtree(folder, ignore_errors=True)
            removed.append(folder.name)
    return removed


def _resolve():
    """The cache folder of this process and whether it outlives it.

    A per-user folder when it is writable; else a private temporary folder removed at exit;
    else None: kernels compile in memory in this process, as they do with a numba outside
    :data:`NUMBA_TESTED`. Results are the same in all three.
    """
    if not numba_tested():
        low, high = (".".join(map(str, version)) for version in NUMBA_TESTED)
        warnings.warn(f"pssd_fast: numba {numba.__version__} is not among the versions its "
                      f"kernel cache is tested with (>={low}, <{high}); kernels are compiled in "
                      f"memory for this process only. Install a numba in that range to cache "
                      f"them.", RuntimeWarning, stacklevel=4)
        return None, False
    key = f"kernels-{cache_key()}"
    base = _user_cache_base()
    folder = _writable(base / key)
    if folder is not None:
        with contextlib.suppress(OSError):
            os.utime(folder)  # its last use, for clear_stale
        return folder, True
    try:
        scratch = Path(tempfile.mkdtemp(prefix="pssd_fast-"))
    except OSError:
        warnings.warn(f"pssd_fast: no writable cache folder ({base} and the temporary folder are "
                      f"read-only); kernels are compiled in memory for this process only. Set "
                      f"{CACHE_ENV} to a writable folder to keep them.", RuntimeWarning,
                      stacklevel=4)
        return None, False
    atexit.register(shutil.rmtree, scratch, ignore_errors=True)
    warnings.warn(f"pssd_fast: cache folder {base} is not writable; kernels are compiled for this "
                  f"process only. Set {CACHE_ENV} to a writable folder to keep them.",
                  RuntimeWarning, stacklevel=4)
    return scratch / key, False


_state_lock = threading.Lock()
_state = {}
#: Called before every kernel signature compiles or loads: numba starts its thread pool when it
#: first loads parallel code, and the Python layer sets that pool up first
#: (``pssd_fast._threads.configure_threads``, which acts once).
_before_kernels = []


def before_kernels(callback):
    """Call ``callback()`` before each kernel signature of this process compiles or loads."""
    _before_kernels.append(callback)


def cache_folder():
    """The folder this process caches kernels in (None: in memory only), found on first use."""
    with _state_lock:
        if "folder" not in _state:
            _state["folder"], _state["persistent"] = _resolve()
            _state["stamp"] = source_key()
            _state["compiled"], _state["loaded"], _state["seconds"] = 0, 0, 0.0
        return _state["folder"]


def stats():
    """Kernel signatures this process has compiled and loaded from the cache, and the seconds
    their first calls spent doing so."""
    cache_folder()
    return {name: _state[name] for name in ("folder", "persistent", "compiled", "loaded",
                                            "seconds")}


@functools.cache
def _cache_class():
    """Numba's function cache, filed in :func:`cache_folder`. Its classes are numba's private
    ones, so they are made only once the version is known to be tested (:func:`_resolve`)."""

    class Locator(caching._CacheLocator):
        """Numba's files of one kernel: in ``folder``, stamped with :func:`source_key`.

        Numba's own locators file a function under its source file's path and stamp it with
        that file's contents only; here every copy of the same package (a second checkout, an
        install) shares the compiled code, and a change to any kernel source invalidates it.
        """

        def __init__(self, folder, stamp, py_func):
            self._folder = folder
            self._stamp = stamp
            self._lineno = py_func.__code__.co_firstlineno

        def get_cache_path(self):
            return str(self._folder)

        def get_source_stamp(self):
            return self._stamp

        def get_disambiguator(self):
            return str(self._lineno)

    class Impl(caching.CompileResultCacheImpl):
        """Numba's compile-result serialisation, filed by ``Locator``."""

        def __init__(self, py_func):
            # Not numba's __init__: it would pick a locator from its own list, or from
            # NUMBA_CACHE_LOCATOR_CLASSES, which must not move these kernels.
            self._lineno = py_func.__code__.co_firstlineno
            self._locator = Locator(cache_folder(), _state["stamp"], py_func)
            module = Path(py_func.__code__.co_filename).stem
            self._filename_base = self.get_filename_base(f"{module}.{py_func.__qualname__}",
                                                         getattr(sys, "abiflags", ""))

    class Cache(caching.FunctionCache):
        _impl_class = Impl

    return Cache


def prepare(kernel, types):
    """Compile or load the signature ``types`` of ``kernel`` (a
    :class:`pssd_fast.kernels.config.Kernel`) in :func:`cache_folder`; record it, or warn that
    the cache missed. Installed as the kernels' loader by ``pssd_fast.jit``."""
    for callback in _before_kernels:
        callback()
    folder = cache_folder()
    dispatcher = kernel.dispatcher
    if folder is None:
        _compile(dispatcher, types)
        return
    if isinstance(dispatcher._cache, caching.NullCache):
        dispatcher._cache = _cache_class()(dispatcher.py_func)
    name = f"{kernel.__module__}.{kernel.__name__}"
    marker = folder / "built" / hashlib.sha1(f"{name}{types}".encode()).hexdigest()
    with _taking_turns(folder / "locks" / name):
        # Looked at before numba, which saves a signature before its marker is written: a
        # marker that appears meanwhile is another process's compile, not a miss.
        recorded = marker.exists()
        compiled = _compile(dispatcher, types)
        if compiled and not recorded:
            with contextlib.suppress(OSError):  # a cache that cannot record costs only time
                marker.parent.mkdir(parents=True, exist_ok=True)
                marker.touch()
    if compiled and recorded:
        _warn_missed(folder)


def _compile(dispatcher, types):
    """``dispatcher`` compiled for ``types``, or loaded from its cache; whether it compiled."""
    misses = sum(dispatcher.stats.cache_misses.values())
    started = time.perf_counter()
    dispatcher.compile(types)
    compiled = sum(dispatcher.stats.cache_misses.values()) > misses
    with _state_lock:
        _state["seconds"] += time.perf_counter() - started
        _state["compiled" if compiled else "loaded"] += 1
    return compiled


@contextlib.contextmanager
def _taking_turns(path):
    """Hold an exclusive lock on the file ``path`` (created if needed) while in the block,
    where the system and the file system allow one; else go on without (module notes)."""
    handle = None
    if fcntl is not None:
        with contextlib.suppress(OSError):
            path.parent.mkdir(exist_ok=True)
            handle = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
    try:
        if handle is not None:
            with contextlib.suppress(OSError):
                fcntl.flock(handle, fcntl.LOCK_EX)  # released by the close, or at exit
        yield
    finally:
        if handle is not None:
            os.close(handle)


def _warn_missed(folder):
    """Once per process: kernels recorded in ``folder`` were compiled again instead of loaded."""
    with _state_lock:
        if _state.get("warned"):
            return
        _state["warned"] = True
    warnings.warn(f"pssd_fast: the kernel cache {folder} records kernels that numba could not "
                  f"load here (a copy from a machine with another CPU, or its index files were "
                  f"removed), so they were compiled again; results are the same. Remove the "
                  f"folder, or set {CACHE_ENV} to a folder of this machine's own.",
                  RuntimeWarning, stacklevel=4)
