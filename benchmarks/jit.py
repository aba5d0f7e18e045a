"""JIT cost: compile time of each kernel from an empty cache, and a fresh process's first call.

Usage::

    python -m benchmarks.jit

Each measurement runs in a fresh process. "Empty cache" points ``PSSD_FAST_CACHE_DIR`` at a new
temporary folder, so every kernel compiles; the stages are then called one at a time on a small
cloud and each first call's time is its kernel's compile time. "Warm cache" uses the same
folder again, now filled, and reports the import time and the time of ``pssd_fast.warmup()``
(every kernel loaded from the cache): the extra cost of the first call in a new process.
Writes ``benchmarks/results/jit.md`` and ``.json``.
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile
import time


#: Stage (as timed by the child) -> the kernel(s) its first call compiles.
KERNELS = {
    "neighbors": "graph.put_self_first",
    "normals": "normals.pca_normals",
    "mls": "mls.mls_fit",
    "likelihood": "likelihood.sampling_likelihood",
    "feature": "feature.feature_intensity",
    "filter": "bilateral.filter_normals",
    "update": "update.move_points",
    "bilateral (BIL)": "bilateral.filter_points",
    "aware fit (default preset)": "mls.aware_fit",
}


def cold_child():
    """First call of each stage on a small cloud, in pipeline order (all compile)."""
    started = time.perf_counter()
    import pssd_fast
    from pssd_fast import core, datasets
    from pssd_fast.graph import knn_graph
    imported = time.perf_counter() - started
    # A writable copy: read-only arrays (the dataset's) are a separate numba specialisation.
    points = datasets.sphere(n_points=500, seed=0).points.copy()
    times = {}

    def timed(name, func, *args):
        started = time.perf_counter()
        out = func(*args)
        times[name] = time.perf_counter() - started
        return out

    graph = timed("neighbors", knn_graph, points, 25, False)
    nrm, _ = timed("normals", core.pca_normals, points, graph, core.outward_hints(points))
    h = core.default_h(graph)
    proj, resid, _, _ = timed("mls", core.mls_fit, points, nrm, graph, h)
    lik, _ = timed("likelihood", core.sampling_likelihood, resid, "exp")
    radius = 10 * core.mean_spacing(graph)
    feat, _ = timed("feature", core.feature_intensity, points, nrm, graph, radius, 0.2, 0.3, 0.3)
    filtered = timed("filter", core.filter_normals, points, nrm, graph)
    timed("update", core.move, points, proj, filtered, lik, feat, 0.5)
    timed("bilateral (BIL)", core.filter_points, points, nrm, graph, 0.0, 0.0)
    timed("aware fit (default preset)", core.aware_fit, points, filtered, graph, 0.05, None,
          True)
    started = time.perf_counter()
    pssd_fast.warmup()
    rest = time.perf_counter() - started
    print(json.dumps({"import": imported, "kernels": times, "rest_of_warmup": rest}))


def warm_child():
    """Import and ``warmup()`` with every kernel in the cache."""
    started = time.perf_counter()
    import pssd_fast
    imported = time.perf_counter() - started
    warm = pssd_fast.warmup()
    print(json.dumps({"import": imported, "warmup": warm}))


def _run(role, cache):
    env = dict(os.environ, PSSD_FAST_CACHE_DIR=cache)
    out = subprocess.run([sys.executable, "-m", "benchmarks.jit", "--child", role], env=env,
                         capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--child", choices=("cold", "warm"), help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        cold_child() if args.child == "cold" else warm_child()
        return
    # Not at module level: the children must import pssd_fast inside their timers.
    from .stages import RESULTS, machine, write_results

    with tempfile.TemporaryDirectory() as cache:
        cold = _run("cold", cache)
        warm = _run("warm", cache)
    lines = ["| stage | kernel | compile (s) |", "|---|---|---|"]
    lines += [f"| {stage} | `{KERNELS[stage]}` | {seconds:.2f} |"
              for stage, seconds in cold["kernels"].items()]
    total = sum(cold["kernels"].values())
    text = (f"Machine: {machine()}\n\nEmpty cache (each stage's first call compiles its "
            f"kernel and the helpers it calls):\n\n" + "\n".join(lines)
            + f"\n| all | | {total:.2f} |\n\nImport {cold['import']:.2f} s; the remaining "
            f"specialisations of `warmup()` (float32 input, given normals): "
            f"{cold['rest_of_warmup']:.2f} s.\n\nWarm cache (a new process): import "
            f"{warm['import']:.2f} s, `warmup()` {warm['warmup']:.2f} s.\n")
    print(text)
    write_results(RESULTS, "jit", text, {"cold": cold, "warm": warm})


if __name__ == "__main__":
    main()
