"""The library's OpenMP pools (pykdtree's and numba's) load with a short idle spin, which they
would otherwise spend on each other's cores, without the caller's environment being changed."""
import json
import os
import subprocess
import sys

import pytest

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"),
                                reason="reads the loaded libraries from /proc/self/maps")

# Records GOMP_SPINCOUNT as each pool loads (pykdtree's on import, numba's when its threading
# layer starts), then imports pssd_fast and runs `code`.
SCRIPT = """
import importlib, json, os, sys
import numba
seen = {}
real_import, real_start = importlib.import_module, numba.get_num_threads
def spy_import(name, *args):
    if name == "pykdtree.kdtree" and name not in sys.modules:
        seen["pykdtree"] = os.environ.get("GOMP_SPINCOUNT")
    return real_import(name, *args)
def spy_start():
    if not numba.np.ufunc.parallel._is_initialized:
        seen["numba"] = os.environ.get("GOMP_SPINCOUNT")
    return real_start()
importlib.import_module, numba.get_num_threads = spy_import, spy_start
def gomp():
    return "libgomp" in open("/proc/self/maps").read()
import numpy as np
import pssd_fast
after_import = {"env": "GOMP_SPINCOUNT" in os.environ, "gomp": gomp()}
%s
pools = pssd_fast.configure_threads()
print(json.dumps({"after_import": after_import, "seen": seen, "gomp": gomp(),
                  "env": os.environ.get("GOMP_SPINCOUNT"), "pools": pools}))
"""
DENOISE = ("pssd_fast.denoise(np.random.default_rng(0).normal(size=(500, 3)) * [1, 1, 0.01], "
           "preset='fast')")


def _run(code, **env):
    clean = {k: v for k, v in os.environ.items()
             if k not in ("GOMP_SPINCOUNT", "OMP_WAIT_POLICY")}
    done = subprocess.run([sys.executable, "-c", SCRIPT % code], env={**clean, **env},
                          capture_output=True, text=True, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_import_starts_no_pool_and_leaves_the_environment_alone():
    out = _run("")
    assert out["after_import"] == {"env": False, "gomp": False}


@pytest.mark.parametrize("code", [DENOISE, "pssd_fast.neighbors(np.random.rand(200, 3), k=10)"])
def test_the_pools_load_with_the_short_spin_and_the_environment_is_put_back(code):
    out = _run(code)
    assert out["seen"] == {"pykdtree": "10000", "numba": "10000"}
    assert out["gomp"] and out["env"] is None
    assert out["pools"] == {"spin_count": 10000, "loaded_before": []}


@pytest.mark.parametrize("env", [{"GOMP_SPINCOUNT": "5"}, {"OMP_WAIT_POLICY": "ACTIVE"}])
def test_a_wait_policy_of_the_caller_is_left_to_act(env):
    out = _run(DENOISE, **env)
    assert out["env"] == env.get("GOMP_SPINCOUNT")
    assert set(out["seen"].values()) == {env.get("GOMP_SPINCOUNT")}
    assert out["pools"]["spin_count"] is None


def test_a_pool_loaded_before_the_library_is_reported():
    out = _run("import pykdtree.kdtree\n" + DENOISE)
    assert out["pools"]["loaded_before"] == ["pykdtree"]
    assert out["seen"]["numba"] == "10000"


# Runs a short denoise with an old TBB in the process (simulated where none is installed) and
# reports numba's threading layer and the warnings it gave.
TBB_SCRIPT = """
import json, warnings
import numpy as np
import numba
import pssd_fast
from pssd_fast import _threads
_threads._old_tbb = lambda: True
with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
    pssd_fast.denoise(np.random.default_rng(0).normal(size=(500, 3)) * [1, 1, 0.01],
                      preset="fast")
print(json.dumps({"layer": numba.threading_layer(),
                  "warnings": [str(w.message) for w in caught]}))
"""


@pytest.mark.parametrize("env, layer", [({}, "omp"),
                                        ({"NUMBA_THREADING_LAYER": "workqueue"}, "workqueue")])
def test_an_old_tbb_is_passed_over_unless_the_caller_chose(env, layer):
    """Where the process holds a TBB too old for numba (Open3D's), the library starts numba's
    OpenMP layer rather than letting numba warn and fall back; a layer the caller chose is
    kept."""
    found = json.loads(subprocess.run([sys.executable, "-c", TBB_SCRIPT], env={**os.environ,
                                      **env}, capture_output=True, text=True,
                                      check=True).stdout)
    assert found == {"layer": layer, "warnings": []}


def test_open3d_first_gives_no_tbb_warning():
    """Open3D, imported first, ships a TBB older than numba's TBB layer needs."""
    pytest.importorskip("open3d")
    run = subprocess.run([sys.executable, "-c", "import open3d\nimport numpy as np\n"
                          "import pssd_fast\n" + DENOISE], capture_output=True, text=True,
                         check=True)
    assert "TBB" not in run.stderr


FORK = """
import multiprocessing, numpy as np, pssd_fast
points = np.random.default_rng(0).normal(size=(500, 3)) * [1, 1, 0.01]
def job(_):
    try:
        return pssd_fast.denoise(points, preset="fast").points.shape
    except RuntimeError as exc:
        return str(exc)
if __name__ == "__main__":
    pssd_fast.denoise(points, preset="fast")
    for method in ("fork", "spawn"):
        with multiprocessing.get_context(method).Pool(1) as pool:
            print(method, pool.apply(job, (0,)))
"""


def test_a_forked_worker_is_told_to_spawn_instead_of_killed(tmp_path):
    """A process forked after the parent's first run cannot run the OpenMP pools: its first
    kernel raises, saying how to start workers, where libgomp would kill it; a spawned one
    runs."""
    script = tmp_path / "workers.py"
    script.write_text(FORK)
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                          timeout=300)
    lines = done.stdout.splitlines()
    assert done.returncode == 0, done.stderr
    assert lines[0].startswith("fork this process was forked from one that had run pssd_fast")
    assert "'spawn' or 'forkserver'" in lines[0]
    assert lines[1] == "spawn (500, 3)"
