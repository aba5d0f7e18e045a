"""Numba's cache: keyed by every kernel source, never different from a fresh compile, and
optional when nothing is writable."""
import os
import shutil
import subprocess
import sys

import pytest

from pssd_fast.kernels import cache

from .conftest import PACKAGE_PARENT

#: Run in a child: denoise a small cloud with the pipelines named in argv[2] (comma-separated);
#: print whether this process compiled any kernel itself; write each run's outputs' bytes to
#: ``<argv[1]>/<name>.bin``.
CHILD = """
import sys, numpy as np, pssd_fast
from pathlib import Path
from pssd_fast import datasets, kernels
from pssd_fast.kernels.cache import Kernel
points = datasets.cad_part(n_points=3000, noise=0.005, seed=3).points
runs = {"default": dict(iterations=2), "paper": dict(preset="paper"),
        "bilateral": dict(method="bilateral", k=20, iterations=1),
        "mls": dict(method="mls", k=20, iterations=1)}
for name in sys.argv[2].split(","):
    r = pssd_fast.denoise(points, **runs[name])
    with open(Path(sys.argv[1]) / f"{name}.bin", "wb") as out:
        for a in (r.points, r.normals, r.likelihood, r.feature_intensity):
            if a is not None:
                out.write(a.tobytes())
compiled_here = sum(sum(k.stats.cache_misses.values())
                    for m in kernels.__all__ for k in vars(getattr(kernels, m)).values()
                    if isinstance(k, Kernel))
print("compiled here:", compiled_here)
"""
EVERY_RUN = "default,paper,bilateral,mls"


def _child(script, cache_dir, *args, env=None, cwd=None):
    env = dict(os.environ if env is None else env, PSSD_FAST_CACHE_DIR=str(cache_dir))
    return subprocess.run([sys.executable, "-c", script, *map(str, args)], env=env,
                          cwd=PACKAGE_PARENT if cwd is None else cwd, capture_output=True,
                          text=True, check=True)


def _outputs(folder):
    return {path.stem: path.read_bytes() for path in folder.glob("*.bin")}


@pytest.fixture(scope="module")
def cold(tmp_path_factory):
    """A child's run of every pipeline on an empty cache folder: the folder (its base, as
    ``PSSD_FAST_CACHE_DIR``), the outputs' bytes by run and the child's report.

    Compiling every kernel takes most of two minutes on CI, and the tests below share it. While
    this process's own cache folder is still empty (a fresh clone, as on CI), the cold run
    compiles into it, so the rest of the suite loads what it compiled instead of compiling it
    again; otherwise into a folder of its own.
    """
    folder = tmp_path_factory.mktemp("cold")
    own = cache.CACHE_DIR
    fresh = cache.PERSISTENT and not any((own / "built").glob("*"))  # no kernel built yet
    base = own.parent if fresh else folder / "cache"
    done = _child(CHILD, base, folder, EVERY_RUN)
    return base, _outputs(folder), done.stdout


def test_empty_and_warm_cache_give_identical_bytes(cold, tmp_path):
    base, cold_bytes, cold_stdout = cold
    warm = _child(CHILD, base, tmp_path, EVERY_RUN)
    assert set(cold_bytes) == set(EVERY_RUN.split(",")) and cold_bytes == _outputs(tmp_path)
    # The calling process only ever loads kernels: children compiled them into the cache.
    assert "compiled here: 0" in cold_stdout and "compiled here: 0" in warm.stdout
    assert len(list(base.glob(f"kernels-{cache.source_key()}/built/*"))) >= 9


def test_a_copy_of_the_package_sharing_the_cache_gives_identical_bytes(cold, tmp_path):
    """Another checkout or install of the same source finds the same cache folder, but numba
    serves a kernel only to the file it was compiled from, as it was then: the copy, and the
    copy with a rewritten kernel file, still load their kernels instead of compiling them.
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
        assert f"from {copy}" in done.stdout and "compiled here: 0" in done.stdout, run
        assert _outputs(out) == {"mls": original["mls"]}, run


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


def test_unwritable_cache_folder_falls_back_to_a_private_temporary_one(tmp_path, monkeypatch):
    monkeypatch.setenv(cache.CACHE_ENV, "/proc/pssd_fast_cannot_be_created")
    monkeypatch.setattr(cache.tempfile, "mkdtemp", lambda prefix: str(tmp_path / "scratch"))
    with pytest.warns(RuntimeWarning, match="not writable") as caught:
        folder, persistent = cache._resolve()
    assert len(caught) == 1 and not persistent
    assert folder == tmp_path / "scratch" / f"kernels-{cache.source_key()}"


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


def test_kernel_wrapper_exposes_the_dispatcher():
    from pssd_fast.kernels import normals
    assert normals.pca_normals.py_func.__name__ == "pca_normals"
    assert normals.pca_normals.__doc__.startswith("Unit normals by PCA")
    assert cache.CACHE_DIR.name == f"kernels-{cache.source_key()}"


def test_the_type_key_tells_apart_what_numba_types_tell_apart():
    import numba
    import numpy as np

    readonly = np.zeros((4, 3))
    readonly.flags.writeable = False
    values = [np.zeros((4, 3)), np.zeros((4, 3), order="F"), np.zeros((4, 6))[:, ::2],
              np.zeros((4, 3), np.float32), np.zeros(4), readonly, 1, 1.0, True, np.int64(1)]
    keys = [cache._type_key(v) for v in values]
    types = [numba.typeof(v) for v in values]
    # Each key stands for one type (a key may be finer: 1 and np.int64(1) are both int64).
    assert len(set(zip(keys, types))) == len(set(keys)) == len(values)
    assert len(set(types)) == len(values) - 1
    assert cache._type_key(np.ones((9, 3))) == keys[0] and cache._type_key(7) == keys[6]


def _twice(x):
    return 2.0 * x


def _thrice(x):
    return 3.0 * x


def test_a_failed_or_hung_child_moves_only_its_kernel_into_this_process(tmp_path, monkeypatch):
    """A child that hangs past the timeout (or cannot start) makes its own kernel compile in
    this process, with a warning naming it; the next kernel still asks its child."""
    import numba

    monkeypatch.setattr(cache, "CACHE_DIR", tmp_path / "kernels-test")
    asked = []

    def run(command, *, timeout, **kwargs):
        asked.append(timeout)
        if len(asked) == 1:
            raise subprocess.TimeoutExpired(command, timeout)
        raise FileNotFoundError(2, "No such file or directory", command[0])

    monkeypatch.setattr(cache.subprocess, "run", run)
    # In-memory dispatchers: what this process compiles never reaches a cache.
    hung = cache.Kernel(numba.njit(cache=False)(_twice))
    other = cache.Kernel(numba.njit(cache=False)(_thrice))
    with pytest.warns(RuntimeWarning, match=r"_twice in a child process failed \(Timeout"):
        assert hung(2.0) == 4.0
    assert hung(1.0) == 2.0 and hung(3) == 6.0  # new types: no second child for this kernel
    assert asked == [cache.CHILD_TIMEOUT]
    with pytest.warns(RuntimeWarning, match=r"_thrice in a child process failed \(FileNotF"):
        assert other(2.0) == 6.0
    assert asked == [cache.CHILD_TIMEOUT] * 2
