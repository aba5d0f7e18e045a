"""Numba's cache: keyed by every kernel source and the CPU, never different from a fresh
compile, shared by concurrent processes, loud when it misses, optional when nothing is
writable."""
import importlib
import os
import shutil
import subprocess
import sys
import threading
import time

import pytest

from pssd_fast.jit import cache
from pssd_fast.kernels.config import Kernel, _type_key

from .conftest import PACKAGE_PARENT

#: Run in a child: denoise a small cloud with the pipelines named in argv[2] (comma-separated);
#: print how many kernel signatures this process compiled itself and the warnings it saw; write
#: each run's outputs' bytes to ``<argv[1]>/<name>.bin``.
CHILD = """
import sys, warnings, numpy as np, pssd_fast
from pathlib import Path
from pssd_fast import datasets
from pssd_fast.jit import cache
points = datasets.cad_part(n_points=3000, noise=0.005, seed=3).points
runs = {"default": dict(iterations=2), "paper": dict(preset="paper"),
        "bilateral": dict(method="bilateral", k=20, iterations=1),
        "mls": dict(method="mls", k=20, iterations=1)}
with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
    for name in sys.argv[2].split(","):
        r = pssd_fast.denoise(points, **runs[name])
        with open(Path(sys.argv[1]) / f"{name}.bin", "wb") as out:
            for a in (r.points, r.normals, r.likelihood, r.feature_intensity):
                if a is not None:
                    out.write(a.tobytes())
print("compiled here:", cache.stats()["compiled"])
print("warnings:", [str(w.message) for w in caught])
"""
EVERY_RUN = "default,paper,bilateral,mls"
#: The runs of the suite's cold cache: the baselines' kernels compile in seconds, and the
#: mechanism is the same for all (every pipeline: the slow test below).
QUICK_RUNS = "bilateral,mls"


def _child(script, cache_dir, *args, env=None, cwd=None, wait=True):
    env = dict(os.environ if env is None else env, PSSD_FAST_CACHE_DIR=str(cache_dir))
    command = [sys.executable, "-c", script, *map(str, args)]
    cwd = PACKAGE_PARENT if cwd is None else cwd
    if not wait:
        return subprocess.Popen(command, env=env, cwd=cwd, stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True)
    return subprocess.run(command, env=env, cwd=cwd, capture_output=True, text=True, check=True)


def _outputs(folder):
    return {path.stem: path.read_bytes() for path in folder.glob("*.bin")}


def _compiled(stdout):
    return int(stdout.split("compiled here:")[1].split()[0])


def _compile_at_once(folder, runs):
    """Two children that run ``runs`` at once on one empty cache folder: the folder (its base,
    as ``PSSD_FAST_CACHE_DIR``), each child's outputs' bytes and report. Both compile (or load
    what the other has just saved)."""
    base = folder / "cache"
    outs = [folder / f"child{i}" for i in range(2)]
    children = []
    for out in outs:
        out.mkdir()
        children.append(_child(CHILD, base, out, runs, wait=False))
    reports = [child.communicate() for child in children]
    assert [child.returncode for child in children] == [0, 0], reports
    return base, [_outputs(out) for out in outs], [out for out, _ in reports]


@pytest.fixture(scope="module")
def cold(tmp_path_factory):
    """:func:`_compile_at_once` of the quick runs; the tests below share its folder."""
    return _compile_at_once(tmp_path_factory.mktemp("cold"), QUICK_RUNS)


def _check_warm_run(cold, runs, folder):
    base, cold_bytes, cold_reports = cold
    warm = _child(CHILD, base, folder, runs)
    assert set(cold_bytes[0]) == set(runs.split(","))
    assert cold_bytes[0] == cold_bytes[1] == _outputs(folder)
    assert sum(_compiled(report) for report in cold_reports) >= 4
    assert all("warnings: []" in report for report in cold_reports), cold_reports
    assert _compiled(warm.stdout) == 0 and "warnings: []" in warm.stdout
    kernels, = base.glob("kernels-*")
    assert len(list((kernels / "built").iterdir())) >= 4


def test_processes_compiling_into_one_empty_cache_give_a_warm_runs_bytes(cold, tmp_path):
    """Fresh code and cached code compute the same bits (no fast-math flags), and numba's files
    written by two processes at once stay whole."""
    _check_warm_run(cold, QUICK_RUNS, tmp_path)


@pytest.mark.slow
def test_every_pipeline_compiled_at_once_gives_a_warm_runs_bytes(tmp_path):
    (tmp_path / "warm").mkdir()
    _check_warm_run(_compile_at_once(tmp_path, EVERY_RUN), EVERY_RUN, tmp_path / "warm")


def test_a_copy_of_the_package_sharing_the_cache_gives_identical_bytes(cold, tmp_path):
    """Another checkout or install of the same source finds the same cache folder and loads its
    kernels, also when a kernel file was rewritten with the same contents (a ``git checkout``).
    The MLS baseline alone (its kernels compile in seconds; the mechanism is the same for all)."""
    base, original, _ = cold
    copy = tmp_path / "copy"
    shutil.copytree(PACKAGE_PARENT / "pssd_fast", copy / "pssd_fast",
                    ignore=shutil.ignore_patterns("__pycache__"))
    env = dict(os.environ, PYTHONPATH=str(copy))
    where = "import pssd_fast; print('from', pssd_fast.__file__)\n"
    for run in ("copied", "rewritten"):
        if run == "rewritten":
            kernel = copy / "pssd_fast" / "kernels" / "mls.py"
            os.utime(kernel, ns=(kernel.stat().st_atime_ns, kernel.stat().st_mtime_ns + 10**9))
        out = tmp_path / run
        out.mkdir()
        done = _child(where + CHILD, base, out, "mls", env=env, cwd=tmp_path)
        assert f"from {copy}" in done.stdout and _compiled(done.stdout) == 0, run
        assert _outputs(out) == {"mls": original[0]["mls"]}, run


#: Print the cache key of a process whose numba compiles for a generic x86-64 CPU.
GENERIC = "from pssd_fast.jit import cache; print(cache.cache_key())"


@pytest.mark.slow  # compiles for another CPU (the key's CPU: test_the_folder_name_changes...)
def test_a_cache_copied_across_cpus_is_detected_and_gives_the_same_bytes(cold, tmp_path):
    """Numba keys each cached signature on the CPU. A cache copied to a folder that numba keys
    differently (here: the folder of a process compiling for a generic CPU) misses: the process
    compiles, says so once, naming the folder, and still computes the same bits."""
    base, original, _ = cold
    env = dict(os.environ, NUMBA_CPU_NAME="generic", NUMBA_CPU_FEATURES="")
    generic = _child(GENERIC, base, env=env).stdout.strip()
    folder, = base.glob("kernels-*")
    assert generic != folder.name.removeprefix("kernels-")  # the CPU is part of the key
    copied = tmp_path / "cache" / f"kernels-{generic}"
    shutil.copytree(folder, copied)
    out = tmp_path / "out"
    out.mkdir()
    done = _child(CHILD, copied.parent, out, "mls", env=env)
    assert _compiled(done.stdout) > 0
    warned = done.stdout.split("warnings:")[1]
    assert warned.count("could not load") == 1 and str(copied) in warned
    assert _outputs(out) == {"mls": original[0]["mls"]}


#: Run in a child, one of ``argv[2]`` started at once: wait until all have imported (a flag
#: file each in ``argv[1]``), then call one small kernel on a fresh cache; print how many
#: signatures this process compiled and a hash of the kernel's output.
AT_ONCE = """
import hashlib, os, sys, time
from pathlib import Path
import numpy as np
from pssd_fast.jit import cache
from pssd_fast.kernels import order
flags, children = Path(sys.argv[1]), int(sys.argv[2])
(flags / str(os.getpid())).touch()
while len(list(flags.iterdir())) < children:
    time.sleep(0.001)
points = np.random.default_rng(0).random((1000, 3))
codes = np.zeros(1000, np.uint64)
order.morton_codes(points, points.min(axis=0), 2.0**20, codes)
print(cache.stats()["compiled"], hashlib.sha256(codes.tobytes()).hexdigest())
"""


def test_processes_compiling_one_kernel_at_once_give_no_warning_and_the_same_bytes(tmp_path):
    """Three processes on one empty cache call one kernel together (a cluster's workers on a
    cold cache): none warns that the cache missed, and all compute the same bytes. Where the
    lock exists (``fcntl``), one compiles and the others wait and load what it saved."""
    (tmp_path / "flags").mkdir()
    children = [_child(AT_ONCE, tmp_path / "cache", tmp_path / "flags", 3, wait=False)
                for _ in range(3)]
    reports = [child.communicate(timeout=300) for child in children]
    assert [child.returncode for child in children] == [0] * 3, reports
    assert [err for _, err in reports] == [""] * 3
    compiled, hashes = zip(*(out.split() for out, _ in reports))
    assert len(set(hashes)) == 1
    if cache.fcntl is not None:
        assert sorted(compiled) == ["0", "0", "1"]
    kernels, = (tmp_path / "cache").glob("kernels-*")
    assert len(list((kernels / "built").iterdir())) == 1


def test_the_key_changes_with_any_kernel_source(tmp_path, monkeypatch):
    copy = tmp_path / "kernels"
    shutil.copytree(cache._KERNEL_DIR, copy, ignore=shutil.ignore_patterns("__pycache__"))
    monkeypatch.setattr(cache, "_KERNEL_DIR", copy)
    before = cache.source_key()
    assert before == cache.source_key()
    for name in ("linalg.py", "config.py"):  # inlined helpers and constants, not kernels
        path = copy / name
        original = path.read_text()
        path.write_text(original + "\n# changed\n")
        assert cache.source_key() != before, name
        path.write_text(original)
    assert cache.source_key() == before


@pytest.mark.parametrize("module", ["numpy", "numba", "llvmlite"])
def test_the_key_names_the_versions_of_numpy_numba_and_llvmlite(monkeypatch, module):
    """numpy's version decides how numba types and lowers numpy's functions, so a new numpy
    gets a new folder like a new numba."""
    before = cache.source_key(), cache.cache_key()
    monkeypatch.setattr(getattr(cache, module), "__version__", "99.0.0")
    after = cache.source_key(), cache.cache_key()
    assert after[0] != before[0] and after[1] != before[1]


def test_the_folder_name_changes_with_the_cpu(monkeypatch):
    before = cache.cache_key()
    triple, name, features = cache.cpu_key()
    monkeypatch.setattr(cache, "cpu_key", lambda: (triple, name, features + ",-avx2"))
    assert cache.cache_key() != before


def test_unwritable_cache_folder_falls_back_to_a_private_temporary_one(tmp_path, monkeypatch):
    monkeypatch.setenv(cache.CACHE_ENV, "/proc/pssd_fast_cannot_be_created")
    monkeypatch.setattr(cache.tempfile, "mkdtemp", lambda prefix: str(tmp_path / "scratch"))
    with pytest.warns(RuntimeWarning, match="not writable") as caught:
        folder, persistent = cache._resolve()
    assert len(caught) == 1 and not persistent
    assert folder == tmp_path / "scratch" / f"kernels-{cache.cache_key()}"


def test_nothing_writable_compiles_in_memory(monkeypatch):
    monkeypatch.setenv(cache.CACHE_ENV, "/proc/pssd_fast_cannot_be_created")

    def refuse(prefix):
        raise PermissionError("read-only")

    monkeypatch.setattr(cache.tempfile, "mkdtemp", refuse)
    with pytest.warns(RuntimeWarning, match="compiled in memory") as caught:
        assert cache._resolve() == (None, False)
    assert len(caught) == 1


def test_a_process_with_nothing_writable_runs_with_one_warning(tmp_path):
    """End to end: numba's own locators would raise; the kernels compile in memory instead."""
    script = ("import tempfile, warnings\n"
              "def refuse(*a, **k): raise PermissionError('read-only')\n"
              "tempfile.mkdtemp = refuse\n"
              "warnings.simplefilter('always')\n"
              "with warnings.catch_warnings(record=True) as caught:\n"
              "    import numpy as np, pssd_fast\n"
              "    n = pssd_fast.estimate_normals(np.random.default_rng(0).random((300, 3)))\n"
              "print(len(caught), [str(w.message)[:40] for w in caught], np.isfinite(n).all())\n")
    done = _child(script, "/proc/pssd_fast_cannot_be_created")
    assert done.stdout.startswith("1 ") and done.stdout.rstrip().endswith("True"), done.stdout


def test_the_numba_versions_tested_are_those_pyproject_pins():
    import re

    import numba

    low, high = (".".join(map(str, version)) for version in cache.NUMBA_TESTED)
    assert f'"numba>={low},<{high}"' in (PACKAGE_PARENT / "pyproject.toml").read_text()
    assert cache.numba_tested() and cache.numba_tested(numba.__version__)
    assert re.fullmatch(r"0\.\d+", low) and re.fullmatch(r"0\.\d+", high)
    for version, tested in ((low, True), (f"{low}.1", True), ("0.68.1", True),
                            (f"{high}.0", False), (f"{high}.0rc1", False), ("0.58.1", False),
                            ("1.0.0", False), ("unknown", False)):
        assert cache.numba_tested(version) == tested, version


def test_a_numba_outside_the_tested_range_compiles_in_memory_with_one_warning(
        tmp_path, monkeypatch):
    """pip would not install such a numba next to this package, but an environment may force
    one: the kernels still run, compiled in memory, and one warning says why."""
    import numba
    monkeypatch.setenv(cache.CACHE_ENV, str(tmp_path))
    monkeypatch.setattr(numba, "__version__", "0.99.0")
    monkeypatch.setattr(cache, "_state", {})
    with pytest.warns(RuntimeWarning, match="numba 0.99.0 is not among") as caught:
        assert _kernel()(2.0) == 4.0 and _kernel()(3.0) == 6.0
    assert len(caught) == 1 and cache.stats()["folder"] is None
    assert cache.stats()["compiled"] == 2 and list(tmp_path.iterdir()) == []  # two dispatchers


def test_kernel_wrapper_exposes_the_dispatcher():
    from pssd_fast.kernels import normals
    assert normals.pca_normals.py_func.__name__ == "pca_normals"
    assert normals.pca_normals.__doc__.startswith("Unit normals by PCA")
    assert cache.cache_folder().name == f"kernels-{cache.cache_key()}"


def test_the_type_key_tells_apart_what_numba_types_tell_apart():
    import numba
    import numpy as np

    readonly = np.zeros((4, 3))
    readonly.flags.writeable = False
    values = [np.zeros((4, 3)), np.zeros((4, 3), order="F"), np.zeros((4, 6))[:, ::2],
              np.zeros((4, 3), np.float32), np.zeros(4), readonly, 1, 1.0, True, np.int64(1)]
    keys = [_type_key(v) for v in values]
    types = [numba.typeof(v) for v in values]
    # Each key stands for one type (a key may be finer: 1 and np.int64(1) are both int64).
    assert len(set(zip(keys, types))) == len(set(keys)) == len(values)
    assert len(set(types)) == len(values) - 1
    assert _type_key(np.ones((9, 3))) == keys[0] and _type_key(7) == keys[6]


def _twice(x):
    return 2.0 * x


@pytest.fixture
def own_folder(tmp_path, monkeypatch):
    """This process's cache state pointed at an empty folder, for in-process kernels."""
    folder = tmp_path / "kernels-test"
    folder.mkdir()
    monkeypatch.setattr(cache, "_state", dict(folder=folder, persistent=True, stamp="test",
                                              compiled=0, loaded=0, seconds=0.0))
    return folder


def _kernel():
    """A new dispatcher of ``_twice``, as a fresh process would make it."""
    import numba
    return Kernel(numba.njit(_twice))


def test_a_kernel_loads_what_another_compiled_and_warns_once_when_the_cache_misses(own_folder):
    first = _kernel()
    assert first(2.0) == 4.0 and first(3.0) == 6.0
    assert cache.stats()["compiled"] == 1 and len(list((own_folder / "built").iterdir())) == 1
    assert _kernel()(1.5) == 3.0 and cache.stats()["loaded"] == 1  # a later process loads it
    # The index removed, the marker kept: numba compiles again; one warning names the folder.
    for index in own_folder.glob("*.nbi"):
        index.unlink()
    with pytest.warns(RuntimeWarning, match="could not load") as caught:
        assert _kernel()(1.0) == 2.0 and _kernel()(1.0) == 2.0
    assert len(caught) == 1 and str(own_folder) in str(caught[0].message)
    assert cache.stats()["compiled"] == 2


def test_without_the_package_loader_a_kernel_compiles_in_memory(own_folder, monkeypatch):
    """The kernels stand on numba alone: with no loader nothing is cached or counted."""
    monkeypatch.setattr(Kernel, "loader", None)
    assert _kernel()(2.0) == 4.0
    assert cache.stats()["compiled"] == cache.stats()["loaded"] == 0
    assert not (own_folder / "built").exists()


def test_threads_calling_a_new_kernel_at_once_compile_it_once(own_folder):
    kernel = _kernel()
    results = []
    threads = [threading.Thread(target=lambda x=x: results.append(kernel(float(x))))
               for x in range(8)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert sorted(results) == [2.0 * x for x in range(8)]
    assert cache.stats()["compiled"] + cache.stats()["loaded"] == 1
    assert len(list((own_folder / "built").iterdir())) == 1


def test_stale_folders_of_other_keys_are_removed(tmp_path):
    old = time.time() - (cache.STALE_DAYS + 1) * 86400
    folders = {}
    for name, used in (("kernels-keep", old), ("kernels-old", old),
                       ("kernels-recent", time.time()), ("other-old", old)):
        folders[name] = tmp_path / name
        (folders[name] / "built").mkdir(parents=True)
        os.utime(folders[name], (used, used))
    assert cache.remove_stale(tmp_path, folders["kernels-keep"]) == ["kernels-old"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["kernels-keep", "kernels-recent",
                                                          "other-old"]


def test_stale_folders_go_only_when_clear_stale_is_called(tmp_path, monkeypatch):
    """A process never removes another key's folder (a long job of an older install may be
    using it); ``pssd_fast.jit.clear_stale()``, which the README names, does."""
    import pssd_fast.jit
    monkeypatch.setenv(cache.CACHE_ENV, str(tmp_path))
    old = time.time() - (cache.STALE_DAYS + 1) * 86400
    for name in ("kernels-old", f"kernels-{cache.cache_key()}"):
        (tmp_path / name).mkdir()
        os.utime(tmp_path / name, (old, old))
    folder, persistent = cache._resolve()
    assert persistent and sorted(p.name for p in tmp_path.iterdir()) == [
        f"kernels-{cache.cache_key()}", "kernels-old"]
    assert pssd_fast.jit.clear_stale() == ["kernels-old"]
    assert [p.name for p in tmp_path.iterdir()] == [folder.name]
    assert pssd_fast.jit.clear_stale(days=0) == []


def test_a_process_marks_its_folder_used(tmp_path):
    done = _child("from pssd_fast.jit import cache; print(cache.cache_folder())", tmp_path)
    folder = tmp_path / done.stdout.strip().rsplit("/", 1)[1]
    assert folder.is_dir() and time.time() - folder.stat().st_mtime < 600


def test_no_kernel_or_function_they_call_uses_fast_math():
    """Fresh and cached code agree because LLVM may not reorder floating-point operations; with
    fast-math flags the two copies of a ``prange`` body numba makes can sum in other orders
    (see ``pssd_fast/jit/cache.py``)."""
    import importlib
    import pkgutil

    from numba.core.registry import CPUDispatcher

    import pssd_fast.kernels

    checked = []
    for info in pkgutil.iter_modules(pssd_fast.kernels.__path__):
        module = importlib.import_module(f"pssd_fast.kernels.{info.name}")
        for name, obj in vars(module).items():
            dispatcher = obj.dispatcher if isinstance(obj, Kernel) else obj
            if isinstance(dispatcher, CPUDispatcher) and obj.__module__ == module.__name__:
                assert not dispatcher.targetoptions.get("fastmath"), f"{info.name}.{name}"
                checked.append(name)
    assert {"mls_fit", "aware_fit", "sym3_eigh", "_feature_chunk"} <= set(checked)


def test_the_fit_compiled_ahead_is_the_signature_every_run_of_the_default_calls(monkeypatch):
    """``warmup.fits`` (what ``compile_ahead`` runs beside a first ``python -m pssd_fast``)
    calls the feature-aware fit with the argument types of every call the default's runs make:
    the means' fits, the points' own fits and the refinement, float32 input and given normals
    included. A type of its own would compile a signature no run loads."""
    import numba

    import pssd_fast
    from pssd_fast import datasets, kernels

    warmup = importlib.import_module("pssd_fast.warmup")  # the package exports its function
    seen = []
    fit = kernels.mls.aware_fit

    def recording(*args):
        seen.append(tuple(numba.typeof(a) for a in args))
        return fit(*args)

    monkeypatch.setattr(kernels.mls, "aware_fit", recording)
    warmup.fits()
    ahead = set(seen)
    seen.clear()
    cloud = datasets.cad_part(n_points=3000, noise=0.005, seed=3)
    result = pssd_fast.denoise(cloud.points)
    assert result.stats["iterations"][-1]["refined"] > 0
    pssd_fast.denoise(cloud.points.astype("float32"), result.normals, preset="fast")
    assert len(ahead) == 1 and set(seen) == ahead


def test_compile_ahead_starts_only_on_an_empty_cache_kept_on_disk(tmp_path, monkeypatch):
    warmup = importlib.import_module("pssd_fast.warmup")
    started = []
    monkeypatch.setattr(warmup.subprocess, "Popen", lambda *a, **kw: started.append(a) or "p")
    monkeypatch.setattr(cache, "cache_folder", lambda: tmp_path)
    monkeypatch.setattr(cache, "stats", lambda: {"persistent": True})
    assert warmup.compile_ahead() == "p" and "fits()" in started[0][0][-1]
    (tmp_path / "built").mkdir()
    (tmp_path / "built" / "marker").touch()
    assert warmup.compile_ahead() is None
    monkeypatch.setattr(cache, "stats", lambda: {"persistent": False})
    (tmp_path / "built" / "marker").unlink()
    assert warmup.compile_ahead() is None
    monkeypatch.setattr(cache, "cache_folder", lambda: None)
    assert warmup.compile_ahead() is None
